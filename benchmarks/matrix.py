"""``warp-sph bench matrix``: every built-in scene x every solver x resolution, run to the end or stopped.

Each case simulates the scene's first second (at most 24 frames) from rest and reports whether it
finished or was stopped (with the watchdog's one-line reason), its wall time per simulated second
(stepping only), mean and max density error and the solver's iterations per step. Default
resolutions: particle radius 0.025 and 0.0125 m for every scene, and the dam break also at
0.008 m (227k fluid particles); on a GPU (``--device cuda:0``) every scene also at 0.00625 and
0.004 m. The cases are benchmark runs (``cases.RunSpec``) on a sweep executor, so the matrix runs
serially or on a Dask LocalCluster or cluster (``--workers``, ``--scheduler``).
"""
from __future__ import annotations

import math

from .records import label, solver_names, scene_names
from .tables import invocation_heads

RADII = (0.025, 0.0125)
#: the default dam break only, besides RADII (226,981 fluid particles)
DAM_BREAK_RADII = (0.008,)
#: added for every scene on a GPU
GPU_RADII = (0.00625, 0.004)
MAX_FRAMES = 24

#: the words the report uses for a record's status
STATUS_WORDS = {"ok": "finished", "unstable": "stopped", "time_limit": "time limit", "failed": "failed"}


def matrix_frames(scene) -> int:
    """Frames after the initial state covering the scene's first second (or its duration, if
    shorter), at most ``MAX_FRAMES``."""
    return max(1, min(MAX_FRAMES, int(math.ceil(scene.fps * min(1.0, scene.duration) - 1e-9))))


def default_radii(scene: str, device: str | None) -> tuple[float, ...]:
    radii = RADII + (DAM_BREAK_RADII if scene == "dam_break" else ())
    if device and str(device).startswith("cuda"):
        radii += GPU_RADII
    return tuple(sorted(radii, reverse=True))


def matrix_specs(scenes=None, solvers=None, radii=None, frames: int | None = None, device: str | None = None,
                 time_limit: float | None = None, overrides=(), warm_up: bool = True) -> list:
    """RunSpecs of the matrix, coarsest resolution first (so the cheap cases report first).

    radii: None for the defaults (``default_radii``), else these for every scene; frames: None
    for ``matrix_frames`` of each scene; overrides: ``--set`` values applied to every case."""
    from warp_sph.scene import load_scene

    from .cases import RunSpec

    specs = []
    scenes = list(scenes or scene_names())
    solvers = list(solvers or solver_names())
    for scene in scenes:
        base = load_scene(scene, overrides=list(overrides))
        n = frames or matrix_frames(base)
        for r in (radii or default_radii(scene, device)):
            for solver in solvers:
                params = {"scene": scene, "solver": solver, "particle_radius": r}
                specs.append(RunSpec(scene=scene, overrides=[*overrides, f"particle_radius={r}", f"solver={solver}"],
                                     frames=n, device=device, kind="matrix", name="matrix", params=params,
                                     time_limit=time_limit, warm_up=warm_up))
    specs.sort(key=lambda s: (-s.params["particle_radius"], scenes.index(s.params["scene"]),
                              solvers.index(s.params["solver"])))
    return specs


def status_word(record: dict) -> str:
    return STATUS_WORDS.get(record.get("status"), str(record.get("status")))


def reason(record: dict) -> str:
    """The one-line reason a case did not finish ('' when it did)."""
    if record.get("status") == "ok":
        return ""
    text = str(record.get("error") or "").strip().splitlines()
    return text[0] if text else ""


def case_key(record: dict) -> tuple:
    p = record.get("params") or {}
    return (p.get("scene"), p.get("solver"), p.get("particle_radius"), record.get("device") or "cpu")


def latest_per_case(records: list[dict]) -> list[dict]:
    """The latest record of each case (scene, solver, radius, device), in the order of first appearance:
    a matrix may be run in parts (``--scenes``, ``--solvers``, ``--radii``) and a part re-run."""
    best: dict[tuple, dict] = {}
    for r in records:
        k = case_key(r)
        if k not in best or r.get("invocation", r.get("date", "")) >= best[k].get("invocation", best[k].get("date", "")):
            best[k] = r
    return list(best.values())


def section(records: list[dict], fmt, head) -> list[str]:
    """Markdown of the matrix from the latest record of each case (``latest_per_case``): one table per
    particle radius (scene x solver), then the reasons of the cases that did not finish. fmt/head: the
    report's number formatter and section header (command, machine, versions) of one invocation."""
    records = latest_per_case(records)
    if not records:
        return []
    lines = ["## Matrix: every scene x every solver", ""]
    lines += invocation_heads(records, head)
    finished = sum(1 for r in records if r.get("status") == "ok")
    lines += [f"{finished} of {len(records)} cases finished. Each case: the scene's first second (at most "
              f"{MAX_FRAMES} frames) from rest; *wall s / sim s* is stepping wall time per simulated second; "
              "*iterations* the solver's iterations per step (mean over frames of the per-frame mean, and the "
              "largest in any step).", ""]
    radii = sorted({(r.get("params") or {}).get("particle_radius") for r in records}, reverse=True)
    for radius in radii:
        rows = []
        for r in (x for x in records if (x.get("params") or {}).get("particle_radius") == radius):
            m = r.get("metrics") or {}
            p = r.get("params") or {}
            why = reason(r)
            rows.append([p.get("scene", "?"), p.get("solver", "?"), status_word(r), fmt(r.get("fluid_particles")),
                         fmt(m.get("frames")), fmt(m.get("simulated_seconds")), fmt(m.get("wall_per_simulated_second")),
                         fmt(m.get("density_error_mean_avg"), 100), fmt(m.get("density_error_max"), 100),
                         fmt(m.get("solver_iterations_mean")), fmt(m.get("solver_iterations_max")),
                         (why[:160] + ("…" if len(why) > 160 else "")).replace("|", "\\|")])
        header = ["scene", "solver", "status", "fluid N", "frames", "sim s", "wall s / sim s", "mean ρ err %",
                  "max ρ err %", "iterations (mean)", "iterations (max)", "reason"]
        lines += [f"### r = {radius:g} m", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
    stopped = [r for r in records if r.get("status") != "ok"]
    if stopped:
        lines += ["Cases that did not finish, with the full reason:", ""]
        lines += [f"- `{label(r.get('params') or {})}`: {status_word(r)}: {reason(r)}" for r in stopped] + [""]
    return lines
