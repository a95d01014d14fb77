"""A frame of a Simulation: its substeps, sized once per frame or for the speed at each substep's start, in
cell order; the neighbour lists grown and the frame redone when they overflowed; the watchdog's check of the
end state and its retry with half the step (``warp_sph.run.watchdog``). ``Simulation.advance_frame`` calls
``advance_frame`` here.
"""
from __future__ import annotations

import math

import numpy as np

from .diagnostics import FrameStatistics
from .watchdog import MAX_RETRIES, frame_substeps


def advance_frame(sim) -> FrameStatistics:
    """``Simulation.advance_frame``: advance ``sim`` to the next frame time in substeps no larger than the
    time-step bound: equal ones sized once for the frame (the last frame's speed), or, when the solver asks
    for it (``per_substep_step``), each sized for the speed at its start.

    During the substeps the per-particle fields are in cell order (``cell_order``, see
    ``warp_sph.neighbors.particle_order``); before and after, every particle is at its stable index.
    The watchdog checks the frame's end state (non-finite values, escaped, too fast or too
    compressed particles). On a violation the frame is retried from its start with half the
    step (``time.on_instability = "retry"``) or a SimulationError names the stage, step, time,
    particle and likely cause (the state is left at the failure).
    """
    wd = sim.watchdog
    if sim.flow is not None:  # sinks and emitters, outside the cell order (every solver's first stage
        sim.flow.begin_frame()  # computes the density of the new count: no refresh needed here)
    last = sim.last_frame if sim.last_frame else sim.statistics()
    max_speed = max(last.max_speed, last.body_speed)  # the CFL includes the bodies' particles
    if sim.colliders is not None:  # and the animated obstacles' top speed over the coming frame
        max_speed = max(max_speed, sim.colliders.max_speed(sim.state.time, sim.state.time + sim.frame_dt))
    if sim.flow is not None:  # the particles just emitted enter at the nozzle's speed
        max_speed = max(max_speed, sim.flow.last_speed)
    wd.save()
    retries = 0
    while True:
        solver_stats = []
        with sim.in_cell_order():
            if sim.per_substep_step:
                n, dt_min, dt_max = _substeps_for_speed(sim, solver_stats)
            else:
                bound = sim.time_step(max_speed)
                n = frame_substeps(sim.frame_dt, bound)
                dt_min = dt_max = sim.frame_dt / n
                if sim.bodies is not None:
                    sim.bodies.plan_frame(dt_max, max_speed)
                for _ in range(n):
                    sim.step(dt_max)
                    solver_stats.append({**sim.solver.step_statistics(), **sim.forces.step_statistics()})
            sim.solver.finish_frame()  # e.g. PBF: the density at the frame's positions, for the statistics
        if _grow_neighbor_lists(sim):
            wd.restore()  # neighbours were dropped: redo the frame with the larger lists
            continue
        sim.state.frame += 1
        sim.state.time = sim.state.frame * sim.frame_dt
        if sim.colliders is not None:  # at the exact frame time (a resume starts there)
            sim.colliders.place(sim.state.time)
        stats = sim.statistics(steps=n, dt_min=dt_min, dt_max=dt_max)
        stats.retries = retries
        if wd.broken(stats.watch) is None:
            break
        if wd.mode == "retry" and retries < MAX_RETRIES:
            wd.restore()
            wd.dt_scale *= 0.5
            retries += 1
            continue
        raise wd.error(stats, n, dt_max, retries, max_speed)
    if retries == 0:
        wd.dt_scale = min(1.0, 2.0 * wd.dt_scale)
    if solver_stats and solver_stats[0]:
        keys = solver_stats[0].keys()
        stats.solver = {k: {"mean": float(np.mean([s[k] for s in solver_stats])),
                            "max": float(np.max([s[k] for s in solver_stats]))} for k in keys}
    sim.last_frame = stats
    return stats


def _substeps_for_speed(sim, solver_stats: list) -> tuple[int, float, float]:
    """One frame in substeps each sized for the flow's speed at its start: what is left of the frame
    split into equal substeps no larger than ``time_step(current_speed())``, the first of them taken.
    A steady bound gives equal substeps (a resting tank steps as with one size per frame; steps that
    change size every substep stir the solves' warm start), a growing speed shorter ones. Appends
    each substep's solver statistics; returns (substeps, smallest dt, largest dt) [-, s, s]."""
    elapsed, n, dt_min, dt_max = 0.0, 0, math.inf, 0.0
    while sim.frame_dt - elapsed > 1e-9 * sim.frame_dt:
        remaining = sim.frame_dt - elapsed
        dt = remaining / frame_substeps(remaining, sim.time_step(sim.current_speed()))
        sim.step(dt)
        solver_stats.append({**sim.solver.step_statistics(), **sim.forces.step_statistics()})
        elapsed += dt
        n += 1
        dt_min, dt_max = min(dt_min, dt), max(dt_max, dt)
    return n, dt_min, dt_max


def _grow_neighbor_lists(sim) -> bool:
    """Once per frame (one host read): True, after growing them, if a particle had more neighbours
    than the neighbour lists hold."""
    lists = sim.fields.get("neighbor_lists")
    if lists is None:
        return False
    worst = lists.overflow()
    if worst:
        import warnings

        warnings.warn(f"frame {sim.state.frame + 1}: a particle had {worst} neighbours, more than the list "
                      f"capacities {lists.capacities}; the lists grow and the frame is redone",
                      RuntimeWarning, stacklevel=4)
        lists.grow(worst)
    return bool(worst)
