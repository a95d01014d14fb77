"""``warp-sph bench bodies``: what moving rigid bodies cost per simulation step.

The same scene twice: with its ``[[bodies]]`` (two-way coupled, stepped by Newton), and with every
body replaced by a static obstacle of the same shape at its initial pose (a closed mesh written to
``<results>/bodies_as_obstacles/``). Each variant runs the scene's first frames ``repeats`` times,
alternating, each in a fresh process; per variant the fastest run's wall time per step counts (this
machine's speed drifts by +-20 % with the load). The goal (issue #19): bodies cost at most 15 % more
per step than the same bodies as static obstacles.
"""
from __future__ import annotations

from pathlib import Path

#: the issue's goal: a scene with bodies costs at most this much more per step than with obstacles
GOAL = 0.15


def obstacle_overrides(scene, folder: Path) -> list[str]:
    """Scene overrides that turn every body of ``scene`` into a static mesh obstacle of the same shape
    at its initial pose (OBJ files written to ``folder``), after the scene's own obstacles."""
    import meshio
    import numpy as np

    from warp_sph.rigid.spec import posed
    from warp_sph.rigid.spec import body_geometry, body_name
    from warp_sph.sweep.cases import toml_value

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tables = []
    for ob in scene.to_dict().get("obstacles", []):
        tables.append("{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in ob.items()) + "}")
    for i, body in enumerate(scene.bodies):
        geo = body_geometry(body)
        R, c = posed(geo, body)
        path = (folder / f"{scene.name}_{body_name(body, i)}.obj").resolve()
        meshio.write_points_cells(str(path), geo.vertices @ R.T + c, [("triangle", np.asarray(geo.triangles))])
        tables.append("{" + f'shape = "mesh", file = {toml_value(str(path))}' + "}")
    return ["bodies=[]", "obstacles=[" + ", ".join(tables) + "]"]


def specs(scene_name: str, frames: int, repeats: int, folder: Path, device=None, overrides=()) -> list:
    """RunSpecs: (bodies, obstacles) x repeats, alternating."""
    from warp_sph.scene import load_scene

    from .cases import RunSpec

    scene = load_scene(scene_name, overrides=list(overrides))
    if not scene.bodies:
        from warp_sph.core.errors import WarpSphError

        raise WarpSphError(f"bench bodies: --scene: scene {scene_name!r} has no [[bodies]]; expected a scene with "
                           "moving bodies, e.g. floating_bodies")
    static = obstacle_overrides(scene, folder)
    out = []
    for k in range(max(1, int(repeats))):
        for variant, extra in (("bodies", []), ("obstacles", static)):
            out.append(RunSpec(scene=scene_name, overrides=list(overrides) + extra, frames=frames, device=device,
                               kind="bodies", name="bodies",
                               params={"scene": scene.name, "variant": variant, "repeat": k + 1}))
    return out


def steady_ms_per_step(record: dict) -> float | None:
    """Stage time per step [ms] without each stage's first call (which loads the kernels, and Newton's
    modules for a new world): the sum over stages of (seconds - first call) / (calls - 1), as run.json's
    ``sim_time_per_step_ms``."""
    rows = record.get("stage_times") or []
    calls = max((r.get("calls", 0) for r in rows), default=0)
    if calls < 2:
        return None
    return 1e3 * sum(r["seconds"] - r["first_call_seconds"] for r in rows) / (calls - 1)


def summary(records: list[dict]) -> dict | None:
    """The fastest steady ms per step of each variant and the extra cost of the bodies (None without both)."""
    best = {}
    for r in records:
        ms = steady_ms_per_step(r)
        v = (r.get("params") or {}).get("variant")
        if r.get("status") == "ok" and ms and v:
            best[v] = min(best.get(v, ms), ms)
    if "bodies" not in best or "obstacles" not in best:
        return None
    extra = best["bodies"] / best["obstacles"] - 1.0
    return {"bodies_ms": best["bodies"], "obstacles_ms": best["obstacles"], "extra": extra, "goal": GOAL,
            "met": extra <= GOAL}


def section(records: list[dict], fmt, head) -> list[str]:
    """Markdown of the latest ``bench bodies`` run: every repeat, the fastest of each variant, the goal."""
    if not records:
        return []
    lines = ["## Moving bodies against static obstacles", ""] + head(records)
    scene = (records[0].get("params") or {}).get("scene", "?")
    lines += [f"Scene `{scene}` with its rigid bodies (two-way coupled, Newton) and with the same shapes as static "
              "obstacles at their initial poses; the scene's first frames, each variant run in turn in a fresh "
              "process. *ms/step*: stage time per substep without each stage's first call (which loads the kernels and "
              "Newton's modules); *wall ms/step*: the frames' wall time per substep, first calls and per-frame "
              "statistics included. The goal compares the fastest *ms/step* of each variant.", ""]
    rows = []
    for r in records:
        p, m = r.get("params") or {}, r.get("metrics") or {}
        bodies = {s["stage"]: s for s in r.get("stage_times") or []}
        coupling = sum(bodies[s]["ms_per_call"] for s in ("body_forces", "bodies") if s in bodies)
        rows.append([p.get("variant", "?"), fmt(p.get("repeat")), r.get("status", "?"), fmt(r.get("fluid_particles")),
                     fmt(r.get("boundary_particles")), fmt(m.get("steps")), fmt(steady_ms_per_step(r)),
                     fmt(m.get("ms_per_step")), fmt(coupling) if coupling else "-",
                     fmt(((r.get("host") or {}).get("load_average") or [None])[0])])
    header = ["variant", "repeat", "status", "fluid N", "boundary N", "steps", "ms/step", "wall ms/step",
              "body stages ms/step", "load (1 min)"]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
    s = summary(records)
    if s:
        lines += [f"Fastest: {fmt(s['bodies_ms'])} ms per step with bodies, {fmt(s['obstacles_ms'])} with static "
                  f"obstacles: bodies cost {100 * s['extra']:+.1f} % per step (goal: at most "
                  f"+{100 * GOAL:.0f} %; {'met' if s['met'] else 'not met'}).", ""]
    return lines
