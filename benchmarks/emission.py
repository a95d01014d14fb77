"""``warp-sph bench emission``: what emitters and sinks cost per particle-step.

The same scene twice: with its ``[[emitters]]`` and ``[[sinks]]`` (the particle count changes at every
frame: removal by a stable device gather, emission into the capacity's free slots, a density refresh
after a change), and without them (``emitters=[]``, ``sinks=[]``: a fixed count, as every scene before
them). Each variant runs the scene's first frames ``repeats`` times, alternating, each in a fresh process.
The measure is the process CPU time of the frames over the particle-steps, sum over frames of substeps x
active particles, so that the two variants' different particle counts compare (CPU time rather than
wall time: this machine is shared, and its load moves wall times by +-20 %); per variant the fastest
run counts. The goal (issue #29): emission and removal add at most 5 % per particle-step.
"""
from __future__ import annotations

#: the issue's goal: emitters and sinks cost at most this much more per particle-step
GOAL = 0.05


def specs(scene_name: str, frames: int, repeats: int, device=None, overrides=()) -> list:
    """RunSpecs: (flow, fixed) x repeats, alternating."""
    from warp_sph.scene import load_scene

    from .cases import RunSpec

    scene = load_scene(scene_name, overrides=list(overrides))
    if not (scene.emitters or scene.sinks):
        raise SystemExit(f"warp-sph bench emission: scene {scene_name!r} has no [[emitters]] or [[sinks]]")
    out = []
    for k in range(max(1, int(repeats))):
        for variant, extra in (("flow", []), ("fixed", ["emitters=[]", "sinks=[]"])):
            out.append(RunSpec(scene=scene_name, overrides=list(overrides) + extra, frames=frames, device=device,
                               kind="emission", name="emission",
                               params={"scene": scene.name, "variant": variant, "repeat": k + 1}))
    return out


def particle_steps(record: dict) -> int:
    """Sum over the frames of substeps x active particles (the count is fixed during a frame)."""
    series = record.get("series") or {}
    steps, particles = series.get("steps") or [], series.get("particles") or []
    return int(sum(s * n for s, n in zip(steps, particles)))


def ns_per_particle_step(record: dict) -> float | None:
    """Process CPU time of the frames per particle-step [ns] (None without the figures)."""
    cpu = (record.get("metrics") or {}).get("cpu_seconds")
    ps = particle_steps(record)
    return 1e9 * cpu / ps if cpu and ps else None


def summary(records: list[dict]) -> dict | None:
    """The fastest ns per particle-step of each variant and the extra cost of the flow (None without both)."""
    best = {}
    for r in records:
        ns = ns_per_particle_step(r)
        v = (r.get("params") or {}).get("variant")
        if r.get("status") == "ok" and ns and v:
            best[v] = min(best.get(v, ns), ns)
    if "flow" not in best or "fixed" not in best:
        return None
    extra = best["flow"] / best["fixed"] - 1.0
    return {"flow_ns": best["flow"], "fixed_ns": best["fixed"], "extra": extra, "goal": GOAL, "met": extra <= GOAL}


def section(records: list[dict], fmt, head) -> list[str]:
    """Markdown of the latest ``bench emission`` run: every repeat, the fastest of each variant, the goal."""
    if not records:
        return []
    lines = ["## Emitters and sinks against a fixed particle count", ""] + head(records)
    scene = (records[0].get("params") or {}).get("scene", "?")
    lines += [f"Scene `{scene}` with its emitters and sinks, and without them; the scene's first frames, each variant "
              "run in turn in a fresh process. *ns/particle-step*: process CPU time of the frames over the sum of "
              "substeps x active particles. The goal compares the fastest of each variant.", ""]
    header = ["variant", "repeat", "status", "particles (first, last)", "steps", "particle-steps", "ns/particle-step",
              "load (1 min)"]
    rows = []
    for r in records:
        p, m = r.get("params") or {}, r.get("metrics") or {}
        n = (r.get("series") or {}).get("particles") or [None]
        rows.append([p.get("variant", "?"), fmt(p.get("repeat")), r.get("status", "?"), f"{fmt(n[0])}, {fmt(n[-1])}",
                     fmt(m.get("steps")), fmt(particle_steps(r)), fmt(ns_per_particle_step(r)),
                     fmt(((r.get("host") or {}).get("load_average") or [None])[0])])
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
    s = summary(records)
    if s:
        lines += [f"Fastest: {fmt(s['flow_ns'])} ns per particle-step with emitters and sinks, {fmt(s['fixed_ns'])} "
                  f"without: {100 * s['extra']:+.1f} % (goal: at most +{100 * GOAL:.0f} %; "
                  f"{'met' if s['met'] else 'not met'}).", ""]
    return lines
