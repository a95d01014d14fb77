"""``warp-sph plan``: the settings that fit a wall-time budget or reach a target error, predicted from
short calibration runs of the scene itself (docs/plan.md).

    calibrate.py  calibration runs at coarse radii for each solver; cached per scene and machine
    points.py     one calibration run and the figures read from its run.json (Point)
    fit.py        the fitted models: power laws and non-negative lines
    metrics.py    the errors a target may name: density, or a validation scene's error against its experiment
    models.py     a solver's models fitted to its calibration points (SolverModel)
    advisor.py    models -> candidates (solver x tolerance x radius) -> the recommendation (Plan)
    share.py      the calibration's decisions: the solvers' order, the runs' predicted costs, what fits the share
    past_cache.py the step's cost past the CPU's last-level cache: a timing-only point there, or the choice capped
    decisions.py  the previous plan's decisions, kept where fresh timings move them within a margin
    report.py     the table, the Pareto plot, the scene file or --set flags of --apply
"""
from __future__ import annotations

import math
from dataclasses import replace

from .advisor import Candidate, Plan, SolverModel
from .calibrate import PlanError
from .past_cache import TIMING_FRAMES, cap_note, timing_cost, timing_target, within_cache
from .decisions import DECISION_MARGIN, decisions_path, keep_previous, read_previous, request_key, write_decision
from .share import budget_cap, cost_notes, least_run_time, point_cost, profile_solvers, rank_solvers, whole_run_cost

#: calibration rounds of a plan at most: the default radii, then finer points towards the setting chosen
MAX_ROUNDS = 4


def plan(scene, budget_s: float | None = None, target_error: float | None = None, device: str | None = None,
         solvers=None, cache=None, refresh: bool = False, progress: bool = False, log=None,
         calibration_radii=None, calibration_frames: int | None = None, metric: str = "density") -> Plan:
    """Recommend the solver, particle radius and solver tolerance for ``scene`` within ``budget_s`` seconds of
    wall time on this machine, or the cheapest setting whose error is at most ``target_error`` (a fraction:
    0.005 for 0.5 %), or both. ``metric``: the error ``target_error`` names, "density" (the mean density error,
    every scene) or, for a validation scene, an error against its experiment ("front", "sensor1", ...:
    ``metrics.metric_names``); another is a PlanError listing the scene's metrics.

    scene: a Scene, a built-in scene name or a .toml path. The scene is calibrated first: a fraction of a
    second of simulated time (the whole duration for an error against an experiment) at two or three coarse
    radii for each solver of ``solvers`` (default: every registered solver), each an ordinary run with the
    scene's own outputs; a solver with a density tolerance (PBF, DFSPH) also at a quarter of the scene's
    tolerance at the finest of those radii. The figures are cached per scene content and machine in ``cache``
    (default ``~/.cache/warp-sph/plan``, ``$WARP_SPH_CACHE_DIR``), ``refresh=True`` runs them again;
    ``calibration_radii`` [m] and ``calibration_frames`` (including the initial one) replace the defaults
    (``calibrate.calibration_radii``, ``calibrate.calibration_frames``; given radii are all run). With a budget
    the default calibration keeps within CALIBRATION_SHARE of it: the coarsest radius first, every solver; then the
    lead, the first solver in the ranking of their one-radius models whose whole run (the scene's duration at the
    coarsest radius: the course of its density error, ``advisor.SolverModel.later_ratio``) fits: that whole run at
    once, its further radii, its finer points and its second tolerance; then the others' further radii, second
    tolerances and whole runs, in rank order, each only while its cost, scaled from the points run
    (``point_cost``, ``whole_run_cost``) times the runs' measured over-run, fits (``Plan.notes`` says what was left
    out). Without a whole run to decide on (none needed or none fits) every solver leads.
    Models fitted to them (steps per simulated second and error against the spacing and the tolerance, wall
    time against the particle count) predict every candidate over the scene's duration. No setting beyond 4x
    the largest calibrated particle count is chosen; when the fit would choose one, a finer calibration point
    of its solver is run first (at a quarter of its count, at least 1.5x and at most 4x the largest calibrated
    count, smaller where only that fits), while the calibration stays within its share of the budget; where the 4x
    limit rather than the budget stops the plan, a note says so (``budget_cap``). A setting whose arrays pass the CPU's
    last-level cache is chosen only once a calibration point of its solver is past it: a timing-only point (one frame,
    ``past_cache.py``) under the same share, else the choice is capped inside the cache (a note says so).

    Returns a ``Plan``: ``chosen`` (a ``Candidate``: solver, particle_radius, tolerance, fluid_particles,
    steps, wall_time [s], memory [bytes], density_error [-], metric_error [-] and how far each is
    extrapolated), ``alternatives`` (the best setting of each other solver), every candidate with its Pareto
    flag, the models and the calibration's cost. Raises PlanError (one line, with the closest feasible setting)
    for a budget too small for the coarsest stable setting, a target error below what the finest affordable
    setting reaches, an unknown metric or a scene that cannot be calibrated.
    """
    from ..methods.registry import solver_names
    from ..run.memory import available_device_memory, available_host_memory
    from ..core.device import resolve_device
    from ..scene import Scene, load_scene
    from .advisor import (BUDGET_SAFETY, CALIBRATION_MARGIN, CALIBRATION_SHARE, MAX_COUNT_EXTRAPOLATION, candidates_for,
                          choose, fit_models, fixed_time, next_point, point_summary)
    from .calibrate import (CALIBRATION_TIME, TOLERANCE_STEP, _same_radius, _same_tolerance, calibrate,
                            calibration_frames as cal_frames, calibration_radii as default_radii, is_cached,
                            scene_tolerance, tolerance_key)
    from .metrics import DENSITY, calibration_time, check_metric

    if budget_s is None and target_error is None:
        raise PlanError("plan: give a wall-time budget (--budget 10m) or a target error (--target-error 0.5%)")
    if budget_s is not None and not budget_s > 0:
        raise PlanError(f"--budget {budget_s!r}: expected a wall time > 0")
    if target_error is not None and not target_error > 0:
        raise PlanError(f"--target-error {target_error!r}: expected an error > 0")
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    metric = check_metric(scene, metric or DENSITY)
    dev = resolve_device(device)
    names = tuple(solvers) if solvers else solver_names()
    unknown = [s for s in names if s not in solver_names()]
    if unknown:
        raise PlanError(f"--solvers: unknown {', '.join(unknown)}; expected some of {', '.join(solver_names())}")
    radii = list(calibration_radii) if calibration_radii else default_radii(scene)
    frames = calibration_frames or cal_frames(scene, calibration_time(scene, metric, CALIBRATION_TIME))
    # a budget whose BUDGET_SAFETY (the share a plan may use) not even the coarsest setting's least cost on this
    # machine fits is refused before calibrating (the calibration would refuse it after spending seconds; where the
    # scene's coarsest points are cached nothing runs, and the plan's own refusal names the cheapest setting)
    least = (least_run_time(scene, names, max(radii), cache, dev) if budget_s is not None
             and (refresh or not is_cached(scene, names, max(radii), frames, cache, dev)) else None)
    if least is not None and least[0] > BUDGET_SAFETY * budget_s:
        raise PlanError(f"{scene.source}: --budget {budget_s:g} s is too small: {least[1]}, {least[0]:.3g} s in all "
                        f"(plans keep {100 * BUDGET_SAFETY:.0f} % of the budget); give --budget "
                        f"{math.ceil(least[0] / BUDGET_SAFETY)}s or more")
    limit = available_device_memory(dev) if dev.is_cuda else available_host_memory()
    # the decisions keep within CALIBRATION_MARGIN of the share, every predicted cost times what the runs so far
    # took over their prediction (``overrun``): the last run's own error then has room below the share
    share = CALIBRATION_MARGIN * CALIBRATION_SHARE * budget_s if budget_s is not None else math.inf
    # radii the caller gives are all calibrated (with the tolerance points); the defaults keep within the share
    first = share if not calibration_radii else math.inf
    notes: list[str] = []
    quiet = log or (lambda *a, **k: None)

    fresh = [refresh]
    asked: list[tuple[str, float, float | None]] = []  # (solver, radius, tolerance) this plan has asked for

    def run(solvers_, radii_, factor=1.0):
        out = calibrate(scene, solvers_, device=dev, radii=radii_, frames=frames, cache=cache, refresh=fresh[0],
                        progress=progress, log=quiet, tolerance_factor=factor)
        fresh[0] = False  # --refresh: the first call starts the cache afresh, the later ones add to it
        for s in solvers_:
            t = scene_tolerance(scene, s)
            asked.extend((s, r, None if t is None else t * factor) for r in radii_)
        # the decisions below see only the points this plan has asked for so far, never the cache's others: a
        # plan made again from the cache then takes the same decisions at the same moments and runs nothing (with
        # every cached point visible at once, a later decision could differ and ask for a point never run)
        return replace(out, points=[p for p in out.points if any(
            p.solver == s and _same_radius(p.particle_radius, r) and _same_tolerance(p.tolerance, t)
            for s, r, t in asked)])

    profile_seconds = 0.0
    timing, timing_seconds, timed, untimed = None, 0.0, set(), {}  # timing-only points past the L3 (``past_cache.py``)
    forecast = [0.0, 0.0]  # [s] predicted and measured of the runs whose cost was predicted before they ran

    def spent_of(cal):  # the calibration's whole cost: every point of these solvers, run now or from the cache
        return sum(p.seconds for p in cal.points if p.solver in names) + profile_seconds + timing_seconds

    def fit_all(with_profile=True):  # every solver's models from the points so far (None where it has none)
        return {s: m for s in names
                if (m := fit_models(cal, s, scene, metric, profile if with_profile else None, timing)) is not None}

    def overrun():  # what the predicted runs took over their prediction so far (at least 1)
        return max(1.0, forecast[1] / forecast[0]) if forecast[0] > 0 else 1.0

    def run_forecast(cal, cost, solvers_, radii_, factor=1.0):  # a run whose cost was predicted: checked after it
        before = spent_of(cal)
        cal = run(solvers_, radii_, factor)
        forecast[0] += cost
        forecast[1] += spent_of(cal) - before
        return cal

    # the coarsest radius first, every solver; then the solvers that can be chosen are decided BEFORE the rest of the
    # share is spent: where the run outlasts the calibration, a solver is chosen only with its whole-run error profile
    # (below), so the first solver in the one-radius ranking whose profile fits leads: its whole run goes first, then
    # its further radii, its finer points and its second tolerance, the others what is left after them (measured,
    # dam break 60 s: the finer points went to DFSPH, whose profile then did not fit; the chosen PBF, calibrated to
    # 729 fluid particles, was held to 4x that count: 2.8 s predicted of 60 s, its error 2.34x the prediction)
    cal = run(names, radii[:1])
    cached = cal.cached
    # the previous plan of this request: its decisions stand within DECISION_MARGIN of fresh timings (``decisions.py``)
    request, memo = request_key(budget_s, target_error, metric, names), decisions_path(cache, cal.key)
    previous = read_previous(memo, request)
    order = rank_solvers(scene, cal, names, metric, budget_s, target_error, limit, previous.get("lead"), DECISION_MARGIN)
    whole, r0 = int(round(scene.duration * scene.fps)) + 1, 0.0
    profile_costs = {}
    if whole > frames and any(cal.for_solver(s) for s in names):
        r0 = max(p.particle_radius for s in names for p in cal.for_solver(s))
        scale = (whole - 1) / max(frames - 1, 1)
        profile_costs = {s: whole_run_cost([p for p in cal.for_solver(s, scene_tolerance(scene, s))
                                          if p.particle_radius == r0], scale, cal.points)
                         for s in order if cal.for_solver(s, scene_tolerance(scene, s))}
    profiled = profile_solvers(order, {s: c * overrun() for s, c in profile_costs.items()}, spent_of(cal), first)[:1]
    lead = profiled or list(order)  # without a profile to reserve (none needed, or none fits) every solver may be chosen
    reserved = 0.0  # [s] of whole runs decided but not yet run
    # the error's course over the whole run (the lead's before the finer points), one solver at a time: a
    # later one only while its predicted cost, times what the runs so far took over their prediction, still fits
    # (measured, dam break 60 s: two profiles predicted 0.68 s took 1.02 s, and the calibration 6.2 s of 6)
    profile, whole_runs = None, set()

    def take_profile(s, say=True) -> bool:  # the whole run of ``s`` at r0, when its cost times the overrun still fits
        nonlocal profile, profile_seconds, cached
        if profile is not None and spent_of(cal) + profile_costs[s] * overrun() > first:
            if say:
                notes.append(f"no error profile of {s} (its whole run at r = {r0:.4g} m, predicted "
                             f"{profile_costs[s] * overrun():.3g} s, does not fit in {100 * CALIBRATION_SHARE:.0f} % "
                             f"of the budget after the others'): its error after the calibrated "
                             f"{(frames - 1) / scene.fps:.3g} s is held at its last calibrated frame's")
            return False
        try:
            out = calibrate(scene, [s], device=dev, radii=[r0], frames=whole, cache=cache, refresh=refresh and profile is None,
                            progress=progress, log=quiet)
        except PlanError as exc:
            notes.append(f"no error profile of {s}: {exc}")
            return False
        whole_runs.add(s)
        # the whole runs this plan asked for only (the cache may hold others': a plan made again decides the same)
        profile = replace(out, points=[p for p in out.points if p.solver in whole_runs
                                       and abs(p.particle_radius / r0 - 1.0) <= 1e-6])
        secs = sum(p.seconds for p in out.points if p.solver == s and abs(p.particle_radius / r0 - 1.0) <= 1e-6)
        profile_seconds += secs
        forecast[0] += profile_costs[s]
        forecast[1] += secs
        cached = cached and out.cached
        return True

    def time_past_cache(choice, cands, models_) -> bool:
        """A timing-only point of ``choice``'s solver past the L3 where ``choice`` passes it and no point of that solver
        did, when its cost times the overrun fits in the share (``past_cache.py``); whether it ran."""
        nonlocal timing, timing_seconds, cached
        s = choice.solver
        target = timing_target(cands, models_[s], choice) if s not in timed else None
        if target is None:
            return False
        tf = min(TIMING_FRAMES, frames)
        cost = timing_cost(cal, models_[s], target, tf)
        if spent_of(cal) + reserved + cost * overrun() > share:
            untimed[s] = (target, cost * overrun())
            return False
        t = target.tolerance
        out = calibrate(scene, [s], device=dev, radii=[target.particle_radius], frames=tf, cache=cache,
                        refresh=refresh and timing is None and tf not in (frames, whole), progress=progress, log=quiet,
                        tolerance_factor=1.0 if t is None else t / scene_tolerance(scene, s))
        timed.add(s)
        keep = [p for p in out.points if p.solver == s and _same_radius(p.particle_radius, target.particle_radius)
                and _same_tolerance(p.tolerance, t)]
        timing = replace(out, points=(timing.points if timing is not None else []) + keep)
        secs = sum(p.seconds for p in keep)
        timing_seconds += secs
        forecast[0] += cost
        forecast[1] += secs
        cached = cached and out.cached
        untimed.pop(s, None)
        return True

    # the lead's whole run at once: what it really took counts before the finer points are decided (measured, dam
    # break 60 s at load 7: reserved at its predicted 0.77 s, it took 1.57 s at the end and the calibration 6.25 s of 6)
    for s in profiled:
        take_profile(s)

    def further(cal, solvers_):  # the further default radii of ``solvers_``
        nonlocal cached
        for r in radii[1:]:
            left = []
            for s in solvers_:
                cost = point_cost(cal, s, r)
                if spent_of(cal) + reserved + cost * overrun() > first:
                    left.append(s)
                    continue
                cal = run_forecast(cal, cost, [s], [r])
                cached = cached and cal.cached
            if left:
                notes.append(f"not calibrated at r = {r:.4g} m: {', '.join(left)} (predicted beyond "
                             f"{100 * CALIBRATION_SHARE:.0f} % of the budget)")
        return cal

    def second_tolerance(cal, solvers_):  # each solver's second tolerance at its finest default radius calibrated
        nonlocal cached
        for s in solvers_:
            if not tolerance_key(s) or not cal.for_solver(s):
                continue
            default = [p.particle_radius for p in cal.for_solver(s) if any(_same_radius(p.particle_radius, r)
                                                                           for r in radii)]
            r_tol = min(default or [p.particle_radius for p in cal.for_solver(s)])
            if len({p.tolerance for p in cal.for_solver(s) if p.particle_radius == r_tol}) > 1:
                continue  # cached
            # about the cost of the same run at the scene's tolerance, its kernels loaded
            cost = sum(fixed_time(p, cal.points) + p.steps * p.step_time
                       for p in cal.for_solver(s) if p.particle_radius == r_tol)
            if spent_of(cal) + reserved + cost * overrun() <= first:
                cal = run_forecast(cal, cost, [s], [r_tol], 1.0 / TOLERANCE_STEP)
                cached = cached and cal.cached
            else:
                notes.append(f"{s}'s tolerance not varied: its calibration at r = {r_tol:.4g} m was predicted to "
                             f"take {cost:.3g} s, beyond {100 * CALIBRATION_SHARE:.0f} % of the budget")
        return cal

    cal = further(cal, lead)
    for _ in range(MAX_ROUNDS):
        models = {s: m for s in names if (m := fit_models(cal, s, scene, metric, profile)) is not None}
        if not models:
            raise PlanError(f"{scene.source}: the scene cannot be calibrated for --target-error {metric}: no "
                            f"calibration run measured it")
        candidates = [c for c in candidates_for(scene, models) if c.solver in lead]
        if not candidates:
            break
        try:
            free = choose(candidates, budget_s, target_error, limit, scene.source, max_extrapolation=None)
        except PlanError:
            break  # no setting of the lead qualifies: the others' points below may (the final choice says if none)
        if free.count_extrapolation <= MAX_COUNT_EXTRAPOLATION:
            break
        # the setting the fit would choose lies far beyond the calibration: one more point of its solver, when
        # that fits in the calibration's share of the budget
        r_new, cost, largest = next_point(cal, free, (share - spent_of(cal) - reserved) / overrun())
        if r_new >= largest or spent_of(cal) + cost * overrun() + reserved > share:
            break
        cal = run_forecast(cal, cost, [free.solver], [r_new])
        cached = cached and cal.cached
    # the lead's choice past the L3 with no point of it there: a timing point first (before its second tolerance and
    # the others' points), when it fits in the share
    models = fit_all()
    lead_candidates = [c for c in candidates_for(scene, models) if c.solver in lead]
    try:
        time_past_cache(choose(lead_candidates, budget_s, target_error, limit, scene.source), lead_candidates, models)
    except PlanError:
        pass
    # then the lead's second tolerance, at its finest default radius: a budget plan chooses the finest radius first
    # and the tolerance only between settings at one radius, so the finer points have the first claim on the share
    cal = second_tolerance(cal, lead)
    # the others after the lead's finer points, in rank order while they fit: their further radii and tolerance, then
    # their whole runs (measured, dam break 60 s: the three profiles reserved first left no room for a finer point,
    # and the plan stayed at 3.5k fluid particles, 3.9 s predicted of a 60 s budget)
    others = [s for s in order if s not in lead]
    cal = second_tolerance(further(cal, others), others)
    models = fit_all(with_profile=False)
    if not models:
        raise PlanError(f"{scene.source}: the scene cannot be calibrated for --target-error {metric}: no "
                        f"calibration run measured it")
    candidates = candidates_for(scene, models)
    profiled += profile_solvers([s for s in order if s not in profiled],
                                {s: c * overrun() for s, c in profile_costs.items()}, spent_of(cal) + reserved, first)
    unprofiled = [s for s in order if s in profile_costs and s not in profiled]
    for s in profiled:
        if s not in whole_runs:
            take_profile(s)
    if profile is not None:
        models = fit_all()
        candidates = candidates_for(scene, models)
    chosen = choose(candidates, budget_s, target_error, limit, scene.source)
    # the chosen solver's error over the whole run is measured, or the choice is made again among the solvers whose
    # is (measured, hydrostatic 180 s: a solver ranked on an error held from the first 0.125 s is not comparable
    # with one whose later frames were measured)
    later = int(round(scene.duration * scene.fps))
    for _ in range(len(names)):
        if profile is None or models[chosen.solver].has_profile(later) or later <= frames - 1:
            break
        s = chosen.solver
        if s in profile_costs and s not in profiled and take_profile(s, say=False):
            profiled.append(s)
            models = fit_all()
            candidates = candidates_for(scene, models)
            chosen = choose(candidates, budget_s, target_error, limit, scene.source)
            continue
        measured = [c for c in candidates if models[c.solver].has_profile(later)]
        try:
            again = choose(measured, budget_s, target_error, limit, scene.source)
        except PlanError:
            break  # no solver with a profile has a setting that qualifies: the choice stands, its error held
        notes.append(f"{s} not chosen: no whole-run error profile of it fits in {100 * CALIBRATION_SHARE:.0f} % of the "
                     f"budget, and its error after the calibrated {(frames - 1) / scene.fps:.3g} s would be held")
        chosen = again
        break
    unprofiled = [s for s in unprofiled if s not in whole_runs and s in models]
    if unprofiled:
        notes.append(f"no error profile of {', '.join(unprofiled)} (a whole run at r = {r0:.4g} m, predicted "
                     f"{sum(profile_costs[s] for s in unprofiled):.3g} s, does not fit in {100 * CALIBRATION_SHARE:.0f} % "
                     f"of the budget): the error after the calibrated {(frames - 1) / scene.fps:.3g} s is held at its "
                     f"last calibrated frame's")
    # the step's cost is never carried past the L3 unmeasured: a timing point of the chosen solver there, or the choice
    # capped at the settings within it (``past_cache.py``; measured, dam break 60 s: 1.98x the predicted wall time)
    for _ in range(len(names)):
        if not time_past_cache(chosen, candidates, models):
            break
        models = fit_all()
        candidates = candidates_for(scene, models)
        chosen = choose(candidates, budget_s, target_error, limit, scene.source)
    pool = candidates
    if models[chosen.solver].past_cache(chosen.fluid_particles, chosen.boundary_particles) is not None:
        pool = within_cache(candidates, models)
        try:
            free, chosen = chosen, choose(pool, budget_s, target_error, limit, scene.source)
            target, cost = untimed.get(free.solver) or (timing_target(candidates, models[free.solver], free), 0.0)
            notes.append(cap_note(models[free.solver], free, chosen, target, cost, 100 * CALIBRATION_SHARE))
        except PlanError:
            pool = candidates  # nothing qualifies within the cache: the choice stands, the cost notes say it passes
    chosen = keep_previous(chosen, pool, previous, budget_s, target_error, limit)
    write_decision(memo, request, chosen, (profiled or order or [None])[0])
    notes += cost_notes(models[chosen.solver], chosen)
    if budget_s is not None and target_error is None:
        cap = budget_cap(pool, chosen, budget_s, limit, scene.source)
        if cap is not None:
            notes.append(cap)
    failed = {p.solver: p.error for p in cal.failures() if p.solver in names and p.solver not in models}
    alternatives = []
    for s in models:
        if s == chosen.solver:
            continue
        try:
            alternatives.append(choose([c for c in pool if c.solver == s], budget_s, target_error, limit,
                                       scene.source))
        except PlanError:
            pass
    return Plan(scene=scene.name, source=scene.source, chosen=chosen, alternatives=alternatives,
                candidates=candidates, models=models, budget_s=budget_s, target_error=target_error,
                duration=scene.duration, frames=int(round(scene.duration * scene.fps)) + 1,
                calibration_seconds=spent_of(cal), calibration_cached=cached, cache_path=cal.path,
                machine=cal.machine, failed_solvers=failed, metric=metric, notes=notes,
                points=[point_summary(p) for p in cal.points if p.solver in names]
                + [point_summary(p, whole=True) for p in (profile.points if profile is not None else [])]
                + [point_summary(p, timing=True) for p in (timing.points if timing is not None else [])])


__all__ = ["Candidate", "Plan", "PlanError", "SolverModel", "budget_cap", "cost_notes", "least_run_time", "plan", "point_cost",
           "profile_solvers",
           "rank_solvers", "whole_run_cost"]
