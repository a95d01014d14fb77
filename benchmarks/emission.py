"""``warp-sph bench emission``: what emitters and sinks cost per particle-step.

The goal (issue #29): emission and removal add at most 5 % to the cost per particle-step of the same scene.

**In the run (the goal's measure).** A scene with ``[[emitters]]`` and ``[[sinks]]`` runs its first frames
for each solver at two sizes (the scene's particle radius and half of it: 8x the particles); the flow's
own work is timed inside that run with the step graph's timers (``StepGraph.timed``: the per-frame stages
``flow_sinks``, ``flow_emitters``, ``flow_count``, run.json ``frame_stage_times``), in process CPU time, as
are the frames. Nothing else runs for the flow: no density refresh and no extra neighbour search or sort
(``ParticleFlow.begin_frame``). Over the frames after the first (its kernels load): *flow ms/frame* and
*run ms/frame* (the frames' whole CPU time, flow included), and the *share* flow / (run - flow): the cost
the flow adds per particle-step, the same particle-steps with and without that work.

**Side by side (a second column).** The same scene without its emitters and sinks (``emitters=[]``,
``sinks=[]``), each in a fresh process, CPU ns per particle-step of each. The two are different flows (the
inflow's jet has other neighbour counts and substeps than a channel at rest), so the difference mixes the
flow's cost with the physics' and is not the goal's measure.

Every case runs ``repeats`` times, alternating; per case the fastest repeat (least CPU per particle-step)
counts, and the table shows every repeat's share.
"""
from __future__ import annotations

#: the issue's goal: emitters and sinks cost at most this much more per particle-step
GOAL = 0.05


def radii(scene, text: str | None = None) -> list[float]:
    """The particle radii [m] of the cases: ``text`` (comma separated), default the scene's and half of it."""
    if text:
        return [float(v) for v in text.split(",") if v.strip()]
    return [float(scene.particle_radius), 0.5 * float(scene.particle_radius)]


def specs(scene_name: str, frames: int, repeats: int, solvers=None, radius_text: str | None = None,
          fixed: bool = True, device=None, overrides=()) -> list:
    """RunSpecs: repeats x radii x solvers (default: every solver) x (flow[, fixed]), alternating."""
    from warp_sph.scene import load_scene

    from .cases import RunSpec
    from .records import solver_names

    solvers = list(solvers or solver_names())
    scene = load_scene(scene_name, overrides=list(overrides))
    if not (scene.emitters or scene.sinks):
        from warp_sph.core.errors import WarpSphError

        raise WarpSphError(f"bench emission: --scene: scene {scene_name!r} has no [[emitters]] or [[sinks]]; expected "
                           "a scene with either, e.g. river or faucet")
    variants = [("flow", [])] + ([("fixed", ["emitters=[]", "sinks=[]"])] if fixed else [])
    out = []
    for k in range(max(1, int(repeats))):
        for r in radii(scene, radius_text):
            for solver in solvers:
                for variant, extra in variants:
                    out.append(RunSpec(scene=scene_name, overrides=list(overrides) + [f"solver={solver}",
                                                                                      f"particle_radius={r:g}"] + extra,
                                       frames=frames, device=device, kind="emission", name="emission",
                                       params={"scene": scene.name, "solver": solver, "particle_radius": r,
                                               "variant": variant, "repeat": k + 1}))
    return out


def particle_steps(record: dict, first: int = 1) -> int:
    """Sum over the frames from ``first`` of substeps x active particles (the count is fixed during a frame;
    series index 0 is the initial state)."""
    series = record.get("series") or {}
    steps, particles = series.get("steps") or [], series.get("particles") or []
    return int(sum(s * n for s, n in list(zip(steps, particles))[first:]))


#: runs whose frames so far measure the cost: completed, or stopped by the watchdog or the time limit
MEASURED = ("ok", "unstable", "time_limit")


def in_run(record: dict) -> dict | None:
    """The flow's cost measured in its own run, over the frames after the first (of a run the watchdog
    stopped: the frames it completed): {flow_ms, run_ms (per frame, process CPU), share = flow / (run - flow),
    ns (run CPU per particle-step), particles (frame 2, last), steps_per_frame, frames, stages: {name: CPU ms
    per call after the first}}; None without the figures."""
    s = record.get("series") or {}
    cpu, flow = s.get("cpu") or [], s.get("frame_stage_cpu") or []
    frames = len(cpu) - 2  # after the initial state and the first frame
    if record.get("status") not in MEASURED or frames < 1 or None in (cpu[1], cpu[-1], flow[1], flow[-1]):
        return None
    run, own = cpu[-1] - cpu[1], flow[-1] - flow[1]
    ps = particle_steps(record, first=2)
    if run <= own or not ps:
        return None
    stages = {t["stage"]: t["cpu_ms_per_call"] for t in record.get("frame_stage_times") or []}
    n = s.get("particles") or [None]
    return {"flow_ms": 1e3 * own / frames, "run_ms": 1e3 * run / frames, "share": own / (run - own),
            "ns": 1e9 * run / ps, "particles": (n[2] if len(n) > 2 else n[-1], n[-1]), "frames": frames + 1,
            "steps_per_frame": sum((s.get("steps") or [])[2:]) / frames, "stages": stages,
            "status": record.get("status")}


def side_ns(record: dict) -> float | None:
    """CPU ns per particle-step over the frames after the first (the side-by-side column)."""
    s = record.get("series") or {}
    cpu = s.get("cpu") or []
    ps = particle_steps(record, first=2)
    if record.get("status") != "ok" or len(cpu) < 3 or None in (cpu[1], cpu[-1]) or not ps:
        return None
    return 1e9 * (cpu[-1] - cpu[1]) / ps


def _case(r: dict) -> tuple:
    p = r.get("params") or {}
    return p.get("solver"), p.get("particle_radius")


def summary(records: list[dict]) -> list[dict]:
    """Per (solver, radius), in the records' order: the fastest flow repeat's in-run figures, every repeat's
    share, the fastest fixed repeat's ns per particle-step and the side-by-side difference, the verdict."""
    cases: dict[tuple, dict] = {}
    for r in records:
        p = r.get("params") or {}
        c = cases.setdefault(_case(r), {"solver": p.get("solver"), "particle_radius": p.get("particle_radius"),
                                        "best": None, "shares": [], "fixed_ns": None})
        if p.get("variant") == "flow":
            m = in_run(r)
            if m is not None:
                c["shares"].append(m["share"])
                if c["best"] is None or m["ns"] < c["best"]["ns"]:
                    c["best"] = m
        elif p.get("variant") == "fixed":
            ns = side_ns(r)
            if ns is not None and (c["fixed_ns"] is None or ns < c["fixed_ns"]):
                c["fixed_ns"] = ns
    out = []
    for c in cases.values():
        b = c["best"]
        c["side_by_side"] = b["ns"] / c["fixed_ns"] - 1.0 if b and c["fixed_ns"] else None
        c["met"] = None if b is None else b["share"] <= GOAL
        out.append(c)
    return out


def section(records: list[dict], fmt, head) -> list[str]:
    """Markdown of the latest ``bench emission`` run: per solver and size the in-run share (the goal's
    measure), the side-by-side column, and the verdict."""
    if not records:
        return []
    scene = (records[0].get("params") or {}).get("scene", "?")
    lines = ["## Emitters and sinks: their cost per particle-step", ""] + head(records)
    lines += [f"Scene `{scene}` with its emitters and sinks, each solver at two particle radii, CPU time (process). "
              "*In the run* (the goal's measure): the flow's own stages (`flow_sinks`, `flow_emitters`, "
              "`flow_count`: the sink test and the stable gather, the new layers, the active count's views) timed "
              "with the step graph's timers inside the run, over the frames after the first; *share* = flow / "
              "(run - flow), the cost they add per particle-step (the same particle-steps with and without that "
              "work; nothing else runs for them: no density refresh, no extra neighbour search or sort). "
              "*Side by side*: the same scene without emitters and sinks in its own process, CPU ns per "
              "particle-step; a different flow (other neighbour counts and substeps), so that column mixes the "
              "flow's cost with the physics'. Fastest repeat per case; *shares* lists every repeat's. A run the "
              "watchdog stopped counts over the frames it completed (its error below).", ""]
    header = ["solver", "r [m]", "frames", "particles (frame 2, last)", "substeps/frame", "flow ms/frame", "run ms/frame",
              "share", "shares (repeats)", "ns/particle-step", "without: ns/particle-step", "side by side", "goal"]
    rows = []
    for c in summary(records):
        b = c["best"] or {}
        n = b.get("particles") or (None, None)
        frames = fmt(b.get("frames")) + ("" if b.get("status", "ok") == "ok" else f" ({b['status']})")
        rows.append([str(c["solver"]), fmt(c["particle_radius"]), frames, f"{fmt(n[0])}, {fmt(n[1])}",
                     fmt(b.get("steps_per_frame")), fmt(b.get("flow_ms")), fmt(b.get("run_ms")),
                     f"{100 * b['share']:.2f} %" if b else "-",
                     ", ".join(f"{100 * s:.2f} %" for s in c["shares"]) or "-", fmt(b.get("ns")),
                     fmt(c["fixed_ns"]),
                     f"{100 * c['side_by_side']:+.1f} %" if c["side_by_side"] is not None else "-",
                     "-" if c["met"] is None else ("met" if c["met"] else "not met")])
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
    stages = sorted({k for c in summary(records) if c["best"] for k in c["best"]["stages"]})
    if stages:
        lines += ["The flow's stages, CPU ms per frame (fastest repeat): "
                  + "; ".join(f"{c['solver']} r = {fmt(c['particle_radius'])}: "
                              + ", ".join(f"`{k}` {fmt(c['best']['stages'].get(k))}" for k in stages)
                              for c in summary(records) if c["best"]) + ".", ""]
    failed = [r for r in records if r.get("status") != "ok"]
    for r in failed:
        lines += [f"- `{r.get('label', '?')}`: {r.get('status')}: {str(r.get('error', '')).splitlines()[0][:300]}"]
    if failed:
        lines += [""]
    met = [c["met"] for c in summary(records) if c["met"] is not None]
    if met:
        lines += [f"Goal (at most +{100 * GOAL:.0f} % per particle-step, in the run): "
                  f"{'met' if all(met) else 'not met'} for {sum(met)} of {len(met)} cases.", ""]
    return lines
