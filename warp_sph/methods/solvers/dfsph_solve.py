"""DFSPH's Jacobi solves (Bender & Koschier 2017, Algorithms 2 and 3) with Chebyshev weights (Wang 2015), and the
stabilisation of an over-dense start: the host side of ``kernels/dfsph_solve.py``'s sweeps. A mixin of
``DfsphSolver`` (``dfsph.py``), as ``dfsph_search.py`` is for the step's search: it reads the solver's model,
fields, configuration, neighbour lists and the control/partial arrays ``DfsphSolver._allocate`` makes.
"""
from __future__ import annotations

import numpy as np

from ...core.launch import launch, run_loop
from ...kernels import dfsph_solve as _dfsph_solve
from ...kernels import reduction as _reduce

#: stabilise when the mean over-density at x exceeds this many times the density target (and 0.1 %)
STABILIZE_FACTOR = 10.0
STABILIZE_FLOOR = 1e-3
#: most stabilisation rounds (each: a density solve at rest, a capped shift, new neighbours)
STABILIZE_ROUNDS = 50
#: Jacobi sweeps of each round's solve: a local projection, as PBF's. A converged solve of a deep
#: over-dense block (the radial expansion at r = 0.0125 m: 22 layers at 1.37 rho0) has interior
#: pressures whose shifts, each capped at max_shift, cross the neighbours' and clump the block
#: (max density 1.4 -> 13 rho0 in 20 rounds); a few sweeps per round move each particle by its local
#: over-density only.
STABILIZE_ITERATIONS = 5


CHEBYSHEV_DELAY = _dfsph_solve.CHEBYSHEV_DELAY


def chebyshev_weight(sweep: int, rho: float, last: float) -> float:
    """Host copy of ``kernels/dfsph_solve.py``'s chebyshev_weight (tests): the weight w of sweep ``sweep``
    (0-based), P <- max(0, P_prev + w (P_jacobi - P_prev)); 1 (plain
    Jacobi) for the first CHEBYSHEV_DELAY sweeps or rho = 0; then 2 / (2 - rho^2), then
    4 / (4 - rho^2 w_last)."""
    if rho <= 0.0 or sweep < CHEBYSHEV_DELAY:
        return 1.0
    if sweep == CHEBYSHEV_DELAY:
        return 2.0 / (2.0 - rho * rho)
    return 4.0 / (4.0 - rho * rho * last)


def fluid_layers(x: np.ndarray, gravity, spacing: float) -> int:
    """Particle layers of the fluid at ``x`` [m] (N, 3) along gravity: round(height / spacing) + 1, the height
    the extent of the positions along -g (without gravity: their largest extent along an axis); 0 without
    fluid."""
    x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
    if len(x) == 0:
        return 0
    g = np.asarray(gravity, dtype=np.float64)
    gn = float(np.linalg.norm(g))
    height = float(np.ptp(x @ (-g / gn))) if gn > 0.0 else float(np.ptp(x, axis=0).max())
    return int(round(height / spacing)) + 1


class DfsphSolve:
    """The solves and the stabilisation of ``DfsphSolver`` (see the module docstring)."""

    # --- passes ----------------------------------------------------------------------------
    def mean_error(self) -> float:
        """Mean of the per-particle ``dfsph_error`` [-], summed in a fixed order (one read)."""
        n = self.model.fluid_count
        self.replayed(_dfsph_solve.error_chunks, self._partial.shape[0], [_reduce.REDUCE_CHUNK, self.sim.fields["dfsph_error"],
                                                                    self._zero_control], [self._partial])
        return float(self._partial.numpy().sum(dtype=np.float64)) / max(n, 1)

    def solve(self, pressure: str, source: str, scale: float, target: float, min_iterations: int,
              max_iterations: int, active_only: bool, chebyshev: bool = False,
              continuous: bool = False, finish=None) -> tuple[int, float]:
        """Jacobi sweeps on the workspace field ``pressure`` for the field ``source`` (see
        ``kernels/dfsph_solve.py``) until the mean error is at most ``target`` after at least
        ``min_iterations`` sweeps, or ``max_iterations`` ran. ``continuous``: the solve ends on the linear
        crossing of the target between its last two sweeps (``kernels/dfsph_solve.py`` solve_control), not on the
        whole last sweep. ``finish``: (kernel, dim, inputs, outputs) of a particle-parallel launch after the
        sweeps (the CPU runs it in the sweeps' hand-off). Returns (iterations, mean error of the last sweep)."""
        m, f = self.model, self.sim.fields
        n, dev = m.fluid_count, m.device
        fn, pairs = self.nl.fluid, f["dfsph_pairs"]
        control, partial = self._control, self._partial
        acc, err, p, b, fac = f["dfsph_acceleration"], f["dfsph_error"], f[pressure], f[source], f["dfsph_factor"]
        omega = float(self.config.relaxation)
        launched = 0
        block = max(1, min_iterations)
        self.solves += 1
        rho = self.chebyshev if chebyshev else 0.0
        keep = rho > 0.0 or continuous
        if self._replays is not None and self.sweep_loop and n > 0:
            # CPU: every sweep of the solve in one run_loop (one hand-off per solve, a barrier between the
            # passes; the same launches in the same order, so bitwise the launch-per-pass path below)
            r, tag = self._replays, (pressure, bool(active_only))
            before = [[r.get(_dfsph_solve.reset_control, 1, [], [control], device=dev, tag=tag)]]
            after = [[r.get(_dfsph_solve.finish_sweeps, n, [fn, control, self._previous], [p], device=dev, tag=tag)]] if keep else []
            if finish is not None:
                after.append([r.get(*finish, device=dev, tag=tag)])
            passes = [[r.get(_dfsph_solve.pressure_acceleration, n, [fn, pairs, p, control], [acc], device=dev, tag=tag)],
                      [r.get(_dfsph_solve.jacobi_update, n, [fn, pairs, fac, b, acc, float(scale), omega, int(active_only),
                                                      control, int(keep)], [p, self._previous, err], device=dev,
                             tag=tag)],
                      [r.get(_dfsph_solve.error_chunks, partial.shape[0], [_reduce.REDUCE_CHUNK, err, control], [partial],
                             device=dev, tag=tag),
                       r.get(_dfsph_solve.solve_control, 1, [partial, n, float(target), int(min_iterations),
                                                       int(max_iterations), rho, int(continuous)], [control],
                             device=dev, tag=tag)]]
            c = self._control_view
            first, every = block, self.check_every

            def stop(sweep: int) -> bool:  # the same checks as the loop below: after `first`, every `every`
                return sweep >= first and (sweep - first) % every == 0 and c[_dfsph_solve.CONTROL_DONE] != 0.0

            run_loop(passes, max_iterations, stop, before=before, after=after)
            return int(c[_dfsph_solve.CONTROL_ITERATIONS]), float(c[_dfsph_solve.CONTROL_ERROR])
        launch(_dfsph_solve.reset_control, 1, [], [control], device=dev)
        while True:
            block = min(block, max_iterations - launched)
            for _ in range(block):
                launch(_dfsph_solve.pressure_acceleration, n, [fn, pairs, p, control], [acc], device=dev)
                launch(_dfsph_solve.jacobi_update, n, [fn, pairs, fac, b, acc, float(scale), omega, int(active_only), control,
                                                 int(keep)], [p, self._previous, err], device=dev)
                launch(_dfsph_solve.error_chunks, partial.shape[0], [_reduce.REDUCE_CHUNK, err, control], [partial], device=dev)
                launch(_dfsph_solve.solve_control, 1, [partial, n, float(target), int(min_iterations), int(max_iterations),
                                                 rho, int(continuous)], [control], device=dev)
            launched += block
            c = control.numpy()  # the one read per check
            if c[_dfsph_solve.CONTROL_DONE] != 0.0 or launched >= max_iterations:
                if keep:
                    launch(_dfsph_solve.finish_sweeps, n, [fn, control, self._previous], [p], device=dev)
                if finish is not None:
                    launch(*finish, device=dev)
                return int(c[_dfsph_solve.CONTROL_ITERATIONS]), float(c[_dfsph_solve.CONTROL_ERROR])
            block = self.check_every

    def run_stabilize(self, sim, dt) -> None:
        """When the mean over-density at x exceeds ``stabilize_threshold`` (a compressed start, a step
        that hit max_iterations): rounds of a density solve at rest (b = 1 - rho_hat, scale 1) and a
        position shift x += a(P) capped at half a particle radius, with new neighbours, density and
        factor after each, until the over-density is below the density target; no velocity results."""
        f = sim.fields
        m = self.model
        err = self.mean_error()
        self.last_start_error = err
        self.last_stabilization = 0
        if err <= self.stabilize_threshold:
            return
        p = self.config
        target = float(p.target_density_error)
        rounds = 0
        while err > target and rounds < STABILIZE_ROUNDS:
            fn, pairs = self.nl.fluid, f["dfsph_pairs"]
            launch(_dfsph_solve.stabilize_source, m.fluid_count, [m.rest_density, fn, f["particle_density"]],
                   [f["dfsph_divergence_source"], f["dfsph_divergence_pressure"]], device=m.device)
            sweeps = min(STABILIZE_ITERATIONS, int(p.max_iterations))
            self.solve("dfsph_divergence_pressure", "dfsph_divergence_source", 1.0, target, min(int(p.min_iterations), sweeps),
                       sweeps, False)
            launch(_dfsph_solve.shift_positions, m.fluid_count, [fn, pairs, f["dfsph_divergence_pressure"], self.max_shift],
                   [f["particle_x"]], device=m.device)
            self._neighbors.run(sim, dt)
            self.search(dt)
            err = self.mean_error()
            rounds += 1
        self.last_stabilization = rounds
