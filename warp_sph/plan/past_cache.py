"""The rule "never extrapolate the step's cost across the CPU's last-level cache without a measurement" of ``warp-sph
plan`` (docs/plan-model.md, item 12).

Where the setting a plan would choose reads arrays past the L3 (``SolverModel.past_cache``; the bytes a step reads,
run.json ``read_bytes``) and no calibration point of its solver is past it, the plan runs a TIMING-ONLY point of that
solver: the coarsest ladder radius whose fitted bytes pass the L3 by CACHE_MARGIN (never finer than the setting
itself), TIMING_FRAMES frames (its steady step from the frames after the first step), its step time then entering the
step's cost like any point (``models.fit_models``' ``timing``; the error models ignore it). It is decided under the
calibration's share like the finer points: its cost (``timing_cost``) times the runs' over-run. Where it does not fit,
the choice is capped at the settings whose step cost is not carried past the L3 unmeasured (``within_cache``) and a
note says so (``cap_note``).
Measured (dam break 60 s, DFSPH): every point inside the 32 MiB L3, the run's arrays 90.7 MiB at 50,653 fluid
particles: 1.98x the predicted wall time; a point past the L3 (21,952 fluid, 40.6 MiB) replayed into that plan: 1.31x.
"""
from __future__ import annotations

#: the timing point's arrays pass the L3 by at least this factor (a point just past it may still run mostly cached)
CACHE_MARGIN = 1.25
#: frames of a timing point, the initial one included: one advanced frame, its steps' time per step without the first
#: step (which loads the kernels: ``points.steady_step_time``). Measured (dam break DFSPH, 21,952 fluid, 9 steps a frame,
#: three runs at load 4.1-4.8): CPU time 1.06-1.11 s in the first advanced frame, 1.08-1.17 s in the second, whose step
#: the calibration points' median of three frames takes; 1.47-1.50 s in the third
TIMING_FRAMES = 2


def timing_target(candidates, model, chosen):
    """The candidate of ``chosen``'s solver and tolerance at which to time the step past the L3: the coarsest whose
    fitted arrays take CACHE_MARGIN x the cache or more, or ``chosen`` itself where none coarser does; None where
    ``chosen``'s step cost is not carried past the cache unmeasured (``past_cache``)."""
    if model.past_cache(chosen.fluid_particles, chosen.boundary_particles) is None:
        return None
    same = sorted((c for c in candidates if c.solver == chosen.solver and c.tolerance == chosen.tolerance
                   and c.particle_radius >= chosen.particle_radius), key=lambda c: -c.particle_radius)
    need = CACHE_MARGIN * model.cache_bytes
    return next((c for c in same if model.array_bytes(c.fluid_particles, c.boundary_particles) >= need), chosen)


def timing_cost(cal, model, target, frames: int = TIMING_FRAMES) -> float:
    """[s] predicted cost of a timing point at ``target`` (a Candidate) over ``frames`` frames: the largest calibrated
    point's time outside its steps (``advisor.fixed_time``) plus its steps per frame times (r / r_target) (steps ~ 1/d)
    over the timing point's advanced frames, each at the fitted step cost at the target's counts (``step_cost``)."""
    from .advisor import fixed_time

    largest = max(cal.for_solver(model.solver), key=lambda q: q.particles)
    steps = largest.steps / max(largest.frames, 1) * (largest.particle_radius / target.particle_radius) * (frames - 1)
    d = 2.0 * target.particle_radius
    return fixed_time(largest, cal.points) + steps * model.step_cost(target.fluid_particles, target.boundary_particles, d)


def within_cache(candidates, models) -> list:
    """The candidates whose step cost is not carried past the L3 unmeasured: their arrays fit in it, or their solver has
    a calibration point past it, or nothing is known of either (a GPU, points without ``array_bytes``)."""
    return [c for c in candidates if models[c.solver].past_cache(c.fluid_particles, c.boundary_particles) is None]


def cap_note(model, free, capped, target, cost: float, share_pct: float) -> str:
    """The line that says the plan stopped at ``capped`` because ``free`` (the choice without the cap) has its arrays
    past the L3 and the timing point at ``target`` (predicted ``cost`` [s]) did not fit in the calibration's share."""
    mib = 2.0**20
    need = model.past_cache(free.fluid_particles, free.boundary_particles) or 0.0
    return (f"capped at {capped.solver}, r = {capped.particle_radius:.4g} m ({capped.fluid_particles:,} fluid "
            f"particles): the budget would allow r = {free.particle_radius:.4g} m ({free.fluid_particles:,}), whose "
            f"steps read about {need / mib:.3g} MiB of arrays, past this CPU's {model.cache_bytes / mib:.3g} MiB "
            f"last-level cache where no calibration run's did ({model.array_bytes_calibrated / mib:.3g} MiB at most), "
            f"and a timing point past it (r = {target.particle_radius:.4g} m, {target.fluid_particles:,} fluid, "
            f"predicted {cost:.3g} s) "
            f"did not fit in {share_pct:.0f} % of the budget: the step's cost is not extrapolated across the cache")
