"""``warp-sph bench whitewater``: what whitewater (``[whitewater]``, docs/whitewater.md) costs per step.

The same splash scene twice, with whitewater at its defaults (``--set whitewater.enabled=true`` creates
the table) and without; each variant runs ``repeats`` times, alternating, each in a fresh process. The
measure is the process CPU time per substep of the frames (all threads; load-independent work), the
fastest run of each variant; the whitewater stage's share of the stage wall times is reported beside
it. The goal (issue #30): whitewater costs at most 15 % of the step.
"""
from __future__ import annotations

#: the issue's goal: with whitewater on, a step costs at most this much more
GOAL = 0.15


def specs(scene_name: str, frames: int, repeats: int, device=None, overrides=()) -> list:
    """RunSpecs: (on, off) x repeats, alternating."""
    from .cases import RunSpec

    out = []
    for k in range(max(1, int(repeats))):
        # "off" says so: a --set whitewater.<key> alone would create the table and turn whitewater on
        for variant, extra in (("on", ["whitewater.enabled=true"]), ("off", ["whitewater.enabled=false"])):
            out.append(RunSpec(scene=scene_name, overrides=["output.usd=false", *overrides, *extra], frames=frames,
                               device=device, kind="whitewater", name="whitewater",
                               params={"scene": scene_name, "variant": variant, "repeat": k + 1}))
    return out


def cpu_ms_per_step(record: dict) -> float | None:
    m = record.get("metrics") or {}
    if not m.get("steps") or m.get("cpu_seconds") is None:
        return None
    return 1e3 * m["cpu_seconds"] / m["steps"]


def stage_share(record: dict) -> float | None:
    """The whitewater stage's share of the summed stage wall times, first calls excluded."""
    rows = record.get("stage_times") or []
    steady = {r["stage"]: r["seconds"] - r["first_call_seconds"] for r in rows}
    total = sum(steady.values())
    return steady.get("whitewater", 0.0) / total if total > 0 else None


def summary(records: list[dict]) -> dict | None:
    """Fastest CPU ms per step of each variant, the extra cost of whitewater (None without both)."""
    best, share = {}, None
    for r in records:
        ms = cpu_ms_per_step(r)
        v = (r.get("params") or {}).get("variant")
        if r.get("status") == "ok" and ms and v:
            if ms < best.get(v, float("inf")):
                best[v] = ms
                if v == "on":
                    share = stage_share(r)
    if "on" not in best or "off" not in best:
        return None
    extra = best["on"] / best["off"] - 1.0
    return {"on_ms": best["on"], "off_ms": best["off"], "extra": extra, "stage_share": share, "goal": GOAL,
            "met": extra <= GOAL}


def section(records: list[dict], fmt, head) -> list[str]:
    """Markdown of the latest ``bench whitewater`` run."""
    if not records:
        return []
    lines = ["## Whitewater", ""] + head(records)
    scene = (records[0].get("params") or {}).get("scene", "?")
    lines += [f"Scene `{scene}` with `[whitewater]` at its defaults and without, each run in turn in a fresh process. "
              "*CPU ms/step*: process CPU time of the frames per substep (all threads); *stage share*: the whitewater "
              "stage's part of the stage wall times. The goal compares the fastest *CPU ms/step* of each variant.", ""]
    header = ["variant", "repeat", "status", "fluid N", "steps", "CPU ms/step", "stage share", "load (1 min)"]
    rows = []
    for r in records:
        p, m = r.get("params") or {}, r.get("metrics") or {}
        share = stage_share(r) if p.get("variant") == "on" else None
        rows.append([p.get("variant", "?"), fmt(p.get("repeat")), r.get("status", "?"), fmt(r.get("fluid_particles")),
                     fmt(m.get("steps")), fmt(cpu_ms_per_step(r)), f"{100 * share:.1f} %" if share else "-",
                     fmt(((r.get("host") or {}).get("load_average") or [None])[0])])
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
    s = summary(records)
    if s:
        lines += [f"Fastest: {fmt(s['on_ms'])} CPU ms per step with whitewater, {fmt(s['off_ms'])} without: "
                  f"{100 * s['extra']:+.1f} % (goal: at most +{100 * GOAL:.0f} %; {'met' if s['met'] else 'not met'}).",
                  ""]
    return lines
