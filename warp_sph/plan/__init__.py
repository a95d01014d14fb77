"""``warp-sph plan``: the settings that fit a wall-time budget or reach a target error, predicted from
short calibration runs of the scene itself (docs/plan.md).

    calibrate.py  calibration runs at coarse radii for each solver; cached per scene and machine
    fit.py        the fitted models: power laws and non-negative lines
    advisor.py    models -> candidates (solver x radius) -> the recommendation (Plan)
    report.py     the table, the Pareto plot, the scene file or --set flags of --apply
"""
from __future__ import annotations

from .advisor import Candidate, Plan, SolverModel
from .calibrate import PlanError

#: calibration rounds of a plan at most: the default radii, then finer points towards the setting chosen
MAX_ROUNDS = 4


def plan(scene, budget_s: float | None = None, target_error: float | None = None, device: str | None = None,
         solvers=None, cache=None, refresh: bool = False, progress: bool = False, log=None,
         calibration_radii=None, calibration_frames: int | None = None) -> Plan:
    """Recommend the solver and particle radius for ``scene`` within ``budget_s`` seconds of wall time on this
    machine, or the cheapest setting whose mean density error is at most ``target_error`` (a fraction: 0.005
    for 0.5 %), or both.

    scene: a Scene, a built-in scene name or a .toml path. The scene is calibrated first: a fraction of a
    second of simulated time at two or three coarse radii for each solver of ``solvers`` (default: every
    registered solver), each an ordinary run with the scene's own outputs; the figures are cached per scene
    content and machine in ``cache`` (default ``~/.cache/warp-sph/plan``, ``$WARP_SPH_CACHE_DIR``),
    ``refresh=True`` runs them again; ``calibration_radii`` [m] and ``calibration_frames`` (including the
    initial one) replace the defaults (``calibrate.calibration_radii``, ``calibrate.calibration_frames``).
    Models fitted to them (steps per simulated second and error against the spacing, wall time against the
    particle count) predict every candidate over the scene's duration. No setting beyond 4x the largest
    calibrated particle count is chosen; when the fit would choose one, a finer calibration point of its
    solver is run first (at a quarter of its count, at most 4x the largest calibrated count), while the
    calibration stays within 10 % of the budget.

    Returns a ``Plan``: ``chosen`` (a ``Candidate``: solver, particle_radius, tolerance, fluid_particles,
    steps, wall_time [s], memory [bytes], density_error [-] and how far each is extrapolated),
    ``alternatives`` (the best setting of each other solver), every candidate with its Pareto flag, the
    models and the calibration's cost. Raises PlanError (one line, with the closest feasible setting) for a
    budget too small for the coarsest stable setting, a target error below what the finest affordable
    setting reaches, or a scene that cannot be calibrated.
    """
    from ..methods.registry import solver_names
    from ..run.memory import available_device_memory, available_host_memory
    from ..core.device import resolve_device
    from ..scene import Scene, load_scene
    from .advisor import CALIBRATION_SHARE, MAX_COUNT_EXTRAPOLATION, candidates_for, choose, fit_models, next_point
    from .calibrate import calibrate, calibration_frames as cal_frames, calibration_radii as default_radii

    if budget_s is None and target_error is None:
        raise PlanError("plan: give a wall-time budget (--budget 10m) or a target error (--target-error 0.5%)")
    if budget_s is not None and not budget_s > 0:
        raise PlanError(f"--budget {budget_s!r}: expected a wall time > 0")
    if target_error is not None and not target_error > 0:
        raise PlanError(f"--target-error {target_error!r}: expected an error > 0")
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    dev = resolve_device(device)
    names = tuple(solvers) if solvers else solver_names()
    unknown = [s for s in names if s not in solver_names()]
    if unknown:
        raise PlanError(f"--solvers: unknown {', '.join(unknown)}; expected some of {', '.join(solver_names())}")
    radii = list(calibration_radii) if calibration_radii else default_radii(scene)
    frames = calibration_frames or cal_frames(scene)
    limit = available_device_memory(dev) if dev.is_cuda else available_host_memory()
    spent, cached, todo = 0.0, True, (names, radii)
    for _ in range(MAX_ROUNDS):
        cal = calibrate(scene, todo[0], device=dev, radii=todo[1], frames=frames, cache=cache, refresh=refresh,
                        progress=progress, log=log or (lambda *a, **k: None))
        # the calibration's whole cost: every point of these solvers, run now or loaded from the cache
        spent, cached = sum(p.seconds for p in cal.points if p.solver in names), cached and cal.cached
        models = {s: m for s in names if (m := fit_models(cal, s)) is not None}
        candidates = candidates_for(scene, models)
        free = choose(candidates, budget_s, target_error, limit, scene.source, max_extrapolation=None)
        if free.count_extrapolation <= MAX_COUNT_EXTRAPOLATION:
            break
        # the setting the fit would choose lies far beyond the calibration: one more point of its solver, when
        # that fits in the calibration's share of the budget
        r_new, cost, largest = next_point(cal, free)
        if r_new >= largest or (budget_s is not None and spent + cost > CALIBRATION_SHARE * budget_s):
            break
        todo = ([free.solver], [r_new])
        refresh = False
    chosen = choose(candidates, budget_s, target_error, limit, scene.source)
    failed = {p.solver: p.error for p in cal.failures() if p.solver in names and p.solver not in models}
    alternatives = []
    for s in models:
        if s == chosen.solver:
            continue
        try:
            alternatives.append(choose([c for c in candidates if c.solver == s], budget_s, target_error, limit,
                                       scene.source))
        except PlanError:
            pass
    return Plan(scene=scene.name, source=scene.source, chosen=chosen, alternatives=alternatives,
                candidates=candidates, models=models, budget_s=budget_s, target_error=target_error,
                duration=scene.duration, frames=int(round(scene.duration * scene.fps)) + 1,
                calibration_seconds=spent, calibration_cached=cached, cache_path=cal.path,
                machine=cal.machine, failed_solvers=failed)


__all__ = ["Candidate", "Plan", "PlanError", "SolverModel", "plan"]
