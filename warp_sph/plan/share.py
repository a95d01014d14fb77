"""The calibration's decisions of ``warp-sph plan`` (``plan.plan``): the solvers' order, what a calibration run or a
whole run is predicted to cost and which fit in the calibration's share of the budget, and the line that says when the
count extrapolation rather than the budget stopped a plan."""
from __future__ import annotations

from .calibrate import PlanError


def budget_cap(candidates, chosen, budget_s: float, limit, source: str) -> str | None:
    """The line that says the count extrapolation, not the budget, stopped the plan: the finest setting of the
    chosen solver at its tolerance predicted within the budget's BUDGET_SAFETY with no limit on the extrapolation,
    when it is finer than ``chosen`` (None otherwise; at another tolerance the line named a tighter one, extrapolated
    11x from the count its effect was measured at, where the chosen tolerance's was 4x)."""
    from .advisor import BUDGET_SAFETY, CALIBRATION_SHARE, MAX_COUNT_EXTRAPOLATION, choose

    try:
        free = choose([c for c in candidates if c.solver == chosen.solver and c.tolerance == chosen.tolerance],
                      budget_s, None, limit, source, max_extrapolation=None)
    except PlanError:
        return None
    if free.particle_radius >= chosen.particle_radius * (1.0 - 1e-6):
        return None
    return (f"the budget would allow r = {free.particle_radius:.4g} m ({free.fluid_particles:,} fluid particles, "
            f"predicted {free.wall_time:.3g} s, {100 * free.wall_time / budget_s:.0f} % of the budget), but that is "
            f"{free.count_extrapolation:.2f}x the largest calibrated count and a plan extrapolates at most "
            f"{MAX_COUNT_EXTRAPOLATION:g}x: no finer calibration point fitted in its {100 * CALIBRATION_SHARE:.0f} % "
            f"share; the plan uses {100 * chosen.wall_time / budget_s:.0f} % (up to {100 * BUDGET_SAFETY:.0f} % aimed)")


def least_run_time(scene, names, radius: float, cache, device) -> tuple[float, str] | None:
    """(seconds, the bound in words): the least wall time a run of ``scene`` can take on this machine with any solver of
    ``names``, before anything is calibrated: the coarsest setting a plan considers (``radius`` [m], the coarsest
    calibration radius), its particles estimated from the geometry, its fewest steps (every frame at time.dt_max, or
    time.fixed_dt), each at least the least step and the least cost per particle-step measured on this machine, plus a
    fresh process's least start-up (``calibrate.machine_floor``); None where this machine has nothing cached."""
    import math

    from ..run.memory import estimate_particle_counts
    from .calibrate import machine_floor, variant
    from .fit import step_floor

    from ..core.errors import WarpSphError

    floor = machine_floor(cache, device)
    if floor is None:
        return None
    counts = []
    for s in names:
        try:
            counts.append(sum(estimate_particle_counts(variant(scene, s, radius))))
        except WarpSphError:  # the scene refuses this radius with this solver: its calibration run says why
            continue
    if not counts:
        return None
    n = min(counts)
    t = scene.time
    steps = max(math.ceil(step_floor(scene.fps, t.dt_max, t.fixed_dt) * scene.duration - 1e-9), 1)
    step = max(floor["step"], n * floor["particle_step"])
    seconds = floor["start"] + steps * step
    return seconds, (f"the coarsest setting, r = {radius:.4g} m with {n:,} particles, takes at least {steps:,} steps of "
                     f"{1e3 * step:.3g} ms after a {floor['start']:.3g} s start: the least measured on this machine "
                     f"over {floor['points']} cached calibration runs")


def rank_solvers(scene, cal, names, metric, budget_s, target_error, limit, previous_lead: str | None = None,
                 margin: float = 0.0) -> list:
    """``names`` in the order the plan would prefer them from the calibration so far (each solver's own best
    setting, ranked as ``advisor.choose`` ranks settings); solvers without a setting last. ``previous_lead``: the
    solver that led the previous plan of the request (``decisions.py``): its best setting is taken within the budget
    times (1 + ``margin``) and its wall time over (1 + ``margin``), so a timing change within the margin does not
    move it down the ranking."""
    from .advisor import candidates_for, choose, fit_models

    best, slack = {}, {}
    for s in names:
        m = fit_models(cal, s, scene, metric)
        if m is None:
            continue
        grace = 1.0 + margin if s == previous_lead else 1.0
        try:
            best[s] = choose(candidates_for(scene, {s: m}), budget_s * grace if budget_s is not None else None,
                             target_error, limit, scene.source)
        except PlanError:
            continue
        slack[s] = grace
    key = (lambda c: (c.wall_time / slack[c.solver], c.error)) if target_error is not None else (
        lambda c: (c.particle_radius, c.error, c.wall_time / slack[c.solver]))
    return sorted(best, key=lambda s: key(best[s])) + [s for s in names if s not in best]


def profile_solvers(order, costs: dict, spent: float, share: float) -> list:
    """The solvers of ``order`` (those with a cost in ``costs`` [s]) whose whole-run error profile fits, taken in
    order while ``spent`` [s] plus their costs stays within ``share`` [s]; one that does not fit is skipped and the
    next, cheaper one may still fit."""
    out = []
    for s in order:
        if s in costs and spent + costs[s] <= share:
            out.append(s)
            spent += costs[s]
    return out


def whole_run_cost(points, scale: float, others=()) -> float:
    """Predicted seconds of a whole-duration run from ``points`` (one solver's calibration runs at the radius):
    each one's steps and export waits times ``scale`` (the whole run's frames over a calibration run's) plus its
    time outside them, less the kernel loads: its first step's excess, and where it was the process's first run,
    the shared kernels' too (its fixed time then the least of ``others``' completed runs that were not a process's
    first; measured, dam break: DFSPH's first 3-frame run at r = 0.0747 m took 1.09 s, its 12-frame run 0.74 s)."""
    def fixed(p):
        return max(p.seconds - p.steps * p.step_time - p.export_wait - p.load_time, 0.0)

    rest = [fixed(q) for q in others if not q.first_in_process and q.status == "completed"]
    return sum((min([fixed(p), *rest]) if p.first_in_process else fixed(p))
               + (p.steps * p.step_time + p.export_wait) * scale for p in points)


def point_cost(cal, solver: str, radius: float) -> float:
    """Predicted seconds of a calibration run of ``solver`` at ``radius`` [m], scaled from its finest point run:
    its time outside the steps (``advisor.fixed_time``: without the kernel loads), its steps' time times
    (r / radius)^4 (particles ~ r^-3, steps ~ r^-1);
    0 when the point is cached or the solver has none."""
    pts = cal.for_solver(solver)
    if not pts or any(abs(p.particle_radius / radius - 1.0) <= 1e-6 for p in pts):
        return 0.0
    from .advisor import fixed_time

    p = min(pts, key=lambda q: q.particle_radius)
    steps = p.steps * p.step_time
    return fixed_time(p, cal.points) + steps * (p.particle_radius / radius) ** 4


def cost_notes(model, chosen) -> list:
    """The lines that say how the chosen setting's step cost was carried beyond the calibration: the whole-run cost
    ratio C (applied or not, and its measured value), the calibration points left out as slowed by the load, a fitted
    cost too flat beyond the largest count (held per particle instead), the count law beyond the largest calibrated
    count and the sweeps' factor (``models.SolverModel.sweep_factor``)."""
    from .models import COST_RATIO_MIN_WINDOW, COST_RATIO_NOISE, MIN_COUNT_EXPONENT

    out = []
    if model.cost_ratio_measured is not None:
        how = (f"applied: x {model.cost_ratio:.3g}" if model.cost_ratio != 1.0 else
               "not applied: within the timing noise of 1" if abs(model.cost_ratio_measured - 1.0) <= COST_RATIO_NOISE
               else f"not applied: the calibration window's steps took {model.cost_ratio_window:.2g} s, under "
                    f"{COST_RATIO_MIN_WINDOW:g} s" if model.cost_ratio_window < COST_RATIO_MIN_WINDOW
               else "not applied")
        out.append(f"{model.solver}'s step cost over the whole run: {model.cost_ratio_measured:.3g}x the calibration "
                   f"window's at the same radius ({how})")
    for r, nf, t, r2, nf2, t2 in model.slowed:
        out.append(f"{model.solver}'s calibration point at r = {r:.4g} m ({nf:,} fluid particles, {1e3 * t:.3g} ms "
                   f"per step) took longer per step than the larger count at r = {r2:.4g} m ({nf2:,}, {1e3 * t2:.3g} "
                   f"ms): slowed by the machine's load, left out of the step's cost")
    k = model.flat_growth(chosen.fluid_particles, chosen.boundary_particles)
    if k is not None:
        nf = model.count_anchor[0]
        out.append(f"{model.solver}'s fitted step cost grows as Nf^{k:.2f} beyond {nf:,} fluid particles (the largest "
                   f"calibrated), under Nf^{MIN_COUNT_EXPONENT:g}: that count's measured cost per fluid particle-step "
                   f"held instead")
    if model.count_law is not None and chosen.fluid_particles > model.count_fluid:
        law = model.count_law
        out.append(f"{model.solver}'s step cost beyond {model.count_fluid:,} fluid particles (the largest calibrated) "
                   f"at least ~ Nf^{law.exponent:.2f} from that count's (exponent measured over the largest counts: "
                   f"{law.measured:.2f})")
    d = 2.0 * chosen.particle_radius
    factor = model.sweep_factor(chosen.fluid_particles, d)
    if abs(factor - 1.0) >= 5e-4:  # shown as x 1 otherwise
        out.append(f"{model.solver}'s step cost beyond {model.sweeps_fluid:,} fluid particles x {factor:.3g} for its sweeps: "
                   f"{model.sweeps_at(d):.3g} per step predicted at r = {chosen.particle_radius:.4g} m (~ d^"
                   f"{model.sweeps.exponent:.2f} over the finest calibrated radii) against {model.sweeps_reference:.3g} "
                   f"at that count, whose sweeps' stages took {100 * model.solve_share:.0f} % of its step")
    elif model.sweeps_grow() and chosen.fluid_particles > model.sweeps_fluid:
        out.append(f"{model.solver}'s sweeps per step grew with refinement over the finest calibrated radii (~ d^"
                   f"{model.sweeps.measured:.2f}): beyond {model.sweeps_fluid:,} fluid particles its "
                   f"{model.sweeps_reference:.3g} per step are held (the whole run's sweeps fall after its first frames)")
    need = model.past_cache(chosen.fluid_particles, chosen.boundary_particles)
    if need is not None:
        mib = 2.0**20
        out.append(f"{model.solver}'s step cost is carried past this CPU's last-level cache "
                   f"({model.cache_bytes / mib:.3g} MiB) unmeasured: the run's steps read about {need / mib:.3g} MiB of "
                   f"arrays at the chosen count, no calibration run's more than "
                   f"{model.array_bytes_calibrated / mib:.3g} MiB "
                   f"(the dam break's DFSPH then cost more per particle-step than calibrated, its PBF and the "
                   f"hydrostatic tank's DFSPH did not: docs/plan-model.md, item 12)")
    return out
