"""The packing pass before t = 0 (``time.settle``): the fluid relaxed toward the solver's discrete equilibrium
under gravity, then the run starts from there at rest.

A fluid sampled on a lattice is not in the discrete equilibrium of the kernel, the walls and the solver: a
resting tank started from the lattice falls for one step (DFSPH: its interior is at rest density, so no
pressure at first; WCSPH: uncompressed), kicks a layer-alternating velocity the solvers cannot see (the
cubic spline's grad W(2 d) = 0) and keeps creeping toward the packing it wants (docs/validation-notes.md,
"Hydrostatic depth and the tank at rest"). The pass steps the scene's own step graph and damps the velocity after every step,
v <- KEEP v (damped dynamics: the packing keeps some momentum, which converges faster than steps that each
start from rest), until the time-mean of the fluid's mean |v| over one frame of packing time (1/fps) is
below ``time.settle`` [m/s] (a mean over a frame: DFSPH at rest ends in a cycle of a few steps whose speeds
differ by 2x, its solve stopping at 4 or 5 sweeps) or ``time.settle_steps`` steps were taken (then the run
goes on and run.json's ``settle.converged`` is false). The step is the run's own step at rest
(``time_step(0)``: every bound, clamped to [dt_min, dt_max], or ``time.fixed_dt``); measured: with the
pressure's bound alone (5 ms) the explicit viscosity of the hydrostatic scene at r = 0.0125 m (bound
0.78 ms) blew the pass up to a mean |v| of 2 m/s.

Afterwards v = 0, the clock and the step count are 0 again, the density is refreshed and the probes
sample from t = 0: the run is the scene started from the packed state. Only fluid moves (the scene
validation refuses the pass with moving bodies, animated obstacles or emitters, and without gravity).
"""
from __future__ import annotations

import math
import time

import numpy as np
import warp as wp

from ..core.launch import launch
from ..kernels import reduction as _reduce
from ..kernels import settle as _dev

#: velocity kept after each packing step, v <- KEEP v (measured on the hydrostatic tank, DFSPH: at r = 0.0125 m,
#: 0.78 ms steps, the mean |v| after 1000 steps is 2.2e-3 m/s with 0.9 and 2.6e-3 with 0.975; at r = 0.025 m, 1000
#: steps of 5 ms: 1.3e-3 with 0.7, 1.6e-3 with 0.9, 2.7e-3 with 0.97; 3000 steps of 5 ms: 7.5e-4 with 0.9,
#: 1.2e-3 for steps that each start from rest, 0)
KEEP = 0.9


def settle(sim, log=None) -> dict | None:
    """Run the packing pass of ``sim``'s scene (``time.settle`` > 0; None otherwise) from its current state;
    returns the record run.json keeps: steps, the step [s], packing time [s], the last packing frame's time-mean of the mean |v| [m/s]
    (``mean_speed``), the criterion (``tolerance``), ``converged``, CPU seconds and the mean particle
    displacement [m]."""
    t = sim.scene.time
    tol = float(t.settle)
    if not tol > 0.0:
        return None
    n = int(sim.model.fluid_count)
    velocity = sim.fields["particle_v"]
    chunks = max(1, -(-n // _reduce.REDUCE_CHUNK))
    partial = wp.zeros(chunks, dtype=float, device=sim.device)
    x0 = sim.get_field("particle_x")
    c0 = time.process_time()
    velocity.zero_()
    steps, elapsed, window, speed, dt = 0, 0.0, [0.0, 0.0], math.inf, 0.0
    converged = False
    with sim.in_cell_order():
        while steps < int(t.settle_steps):
            dt = sim.time_step(0.0)  # the run's own step at rest (every bound: an explicit viscosity's too)
            sim.step(dt)
            steps += 1
            elapsed += dt
            launch(_dev.speed_sum_and_damp, chunks, [_reduce.REDUCE_CHUNK, KEEP], [velocity, partial],
                   device=sim.device)
            step_speed = float(partial.numpy().sum()) / max(n, 1)
            if not math.isfinite(step_speed):
                break  # the run's watchdog names the broken state at its first frame
            window[0] += step_speed * dt
            window[1] += dt
            if window[1] >= sim.frame_dt * (1.0 - 1e-9):  # one frame of packing: its time-mean |v|
                speed = window[0] / window[1]
                window = [0.0, 0.0]
                if speed < tol:
                    converged = True
                    break
    moved = float(np.mean(np.linalg.norm(sim.get_field("particle_x") - x0, axis=1)))
    _restart_at_rest(sim)
    rec = {"steps": steps, "step": dt, "packing_time": elapsed, "mean_speed": speed, "tolerance": tol,
           "converged": converged, "cpu_time": time.process_time() - c0, "mean_displacement": moved}
    if log is not None:
        log(f"settle: {steps} packing steps of {1e3 * dt:.3g} ms, mean |v| {speed:.3g} m/s "
            f"({'below' if converged else 'NOT below'} time.settle = {tol:g} m/s for a frame), mean displacement "
            f"{moved / sim.scene.spacing:.3g} d")
    return rec


def _restart_at_rest(sim) -> None:
    """The packed state as the run's start: v = 0 (already), t = 0, step 0, density and statistics refreshed,
    the energy check's reference taken anew and the probes sampling from t = 0."""
    sim.fields["particle_v"].zero_()
    sim.state.time = 0.0
    sim.state.step = 0
    sim.state.frame = 0
    sim.refresh_density()
    sim.last_frame = None
    sim.watchdog.energy.stale = True
    if sim.probes is not None:
        sim.probes.restart(0.0)
