"""Implicit viscosity (Weiler, Koschier, Brand & Bender 2018), kernels in ``kernels/weiler2018.py``
(equations there and in the research note ``forces.md`` section 3.2).

Backward Euler on the velocities: A v_new = v* + c with A = I + dt (viscous Laplacian), solved for
dv = v_new - v* by conjugate gradients with a 3x3 block-Jacobi preconditioner, warm-started from
the last step's dv (a carried per-particle field, ``weiler2018_dv``: sorted with the particles and
checkpointed). No time-step bound: any nu runs at the solver's own step (at large dt nu / H_s^2 it
over-damps, as backward Euler does).

Host reads: one read of the control array per check (every ``check_every`` iterations: 1 on the
CPU, where the read costs nothing; a device runs blocks of iterations, the kernels stop by
themselves once the control kernel set its done flag).
"""
from __future__ import annotations

import warp as wp

from ...core.launch import launch
from ...kernels import reduction as _reduce
from ...kernels import weiler2018 as _weiler

#: the carried per-particle field: the last step's dv = v_new - v* [m/s] (the warm start)
WARM_FIELD = "weiler2018_dv"


class Weiler2018Solve:
    """The solve's arrays and launches for ``fluid_count`` particles (see the module docstring).

    smoothing: the smoothing kernel's name; with_boundary: include the boundary term (nu_b > 0 and
    boundary particles exist); tolerance: stop when |r| <= tolerance |r0| (r0: the residual at
    dv = 0); max_iterations: most CG iterations per solve.
    """

    def __init__(self, fluid_count: int, smoothing: str, with_boundary: bool, tolerance: float,
                 max_iterations: int, device, check_every: int | None = None):
        self.n = int(fluid_count)
        self.device = wp.get_device(device)
        self.with_boundary = bool(with_boundary)
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self.check_every = int(check_every) if check_every else (1 if self.device.is_cpu else 4)
        n, dev = max(self.n, 1), self.device
        self._setup = _weiler.setup_kernel(smoothing, self.with_boundary)
        self._start = _weiler.start_kernel(self.with_boundary)
        self._matvec = _weiler.matvec_kernel(self.with_boundary)
        self._finish = _weiler.finish_kernel(self.with_boundary)
        nb = n if self.with_boundary else 1
        self.block_inverse = wp.zeros(n, dtype=wp.mat33, device=dev)
        self.boundary_block = wp.zeros(nb, dtype=wp.mat33, device=dev)
        self.boundary_rhs = wp.zeros(nb, dtype=wp.vec3, device=dev)
        (self.start_residual, self.residual, self.preconditioned, self.direction,
         self.product) = (wp.zeros(n, dtype=wp.vec3, device=dev) for _ in range(5))
        self.pairs: wp.array | None = None
        chunks = max(1, -(-self.n // _reduce.REDUCE_CHUNK))
        self._partials = [wp.zeros(chunks, dtype=wp.float64, device=dev) for _ in range(4)]
        self.control = wp.zeros(_weiler.CONTROL_COUNT, dtype=wp.float64, device=dev)
        # figures of the last solve (host values)
        self.last_iterations = 0
        self.last_residual = 0.0   # |r| / |r0| at the end [-]
        self.solves = 0

    def _pairs_for(self, capacity: int) -> wp.array:
        if self.pairs is None or self.pairs.shape[1] != capacity:
            self.pairs = wp.zeros((max(self.n, 1), capacity), dtype=wp.vec3, device=self.device)
        return self.pairs

    def _dot(self, k: int, a: wp.array, b: wp.array) -> wp.array:
        partial = self._partials[k]
        launch(_weiler.dot_chunks, partial.shape[0], [_reduce.REDUCE_CHUNK, a, b, self.control], [partial],
               device=self.device)
        return partial

    def solve(self, dt: float, model, viscosity: float, boundary_viscosity: float, fluid_neighbors,
              boundary_neighbors, boundary_x, boundary_v, boundary_volume, particle_x, particle_density,
              particle_v, warm, boundary_force) -> tuple[int, float]:
        """v <- v_new for the step dt [s] (v holds v* on entry); ``warm`` [m/s] holds the last dv on entry
        and this step's on return. ``model`` gives particle_mass, rest_density, smoothing_length and
        support_radius; neighbours are ``NeighborList`` structs at ``particle_x``. Returns
        (iterations, |r| / |r0| at the end)."""
        n, dev = self.n, self.device
        if n == 0:
            return 0, 0.0
        fn = fluid_neighbors
        pairs = self._pairs_for(fn.index.shape[1])
        control = self.control
        launch(self._setup, n,
               [float(model.particle_mass), float(model.rest_density), float(model.smoothing_length),
                float(model.support_radius), float(viscosity), float(boundary_viscosity), float(dt),
                boundary_neighbors, boundary_x, boundary_v, boundary_volume, fn, particle_x, particle_density],
               [pairs, self.block_inverse, self.boundary_block, self.boundary_rhs], device=dev)
        launch(_weiler.reset_control, 1, [], [control], device=dev)
        launch(self._start, n, [fn, pairs, self.block_inverse, self.boundary_block, self.boundary_rhs, particle_v, warm],
               [warm, self.start_residual, self.residual, self.preconditioned, self.direction], device=dev)
        launch(_weiler.start_control, 1,
               [self._dot(0, self.residual, self.preconditioned), self._dot(1, self.residual, self.residual),
                self._dot(2, self.start_residual, self.start_residual), self._dot(3, particle_v, particle_v),
                self.tolerance, self.max_iterations], [control], device=dev)
        self.solves += 1
        c = control.numpy()
        launched = 0
        while c[_weiler.CONTROL_DONE] == 0.0 and launched < self.max_iterations:
            block = min(self.check_every, self.max_iterations - launched)
            for _ in range(block):
                launch(self._matvec, n, [fn, pairs, self.boundary_block, self.direction, control], [self.product],
                       device=dev)
                launch(_weiler.alpha_control, 1, [self._dot(0, self.direction, self.product)], [control], device=dev)
                launch(_weiler.update, n, [fn, self.block_inverse, self.direction, self.product, control],
                       [warm, self.residual, self.preconditioned], device=dev)
                launch(_weiler.beta_control, 1,
                       [self._dot(0, self.residual, self.preconditioned), self._dot(1, self.residual, self.residual),
                        self.max_iterations], [control], device=dev)
                launch(_weiler.new_direction, n, [fn, self.preconditioned, control], [self.direction], device=dev)
            launched += block
            c = control.numpy()  # the one read per check
        launch(self._finish, n, [float(model.particle_mass), float(dt), fn, self.boundary_block, self.boundary_rhs, warm],
               [particle_v, boundary_force, warm], device=dev)
        start = float(c[_weiler.CONTROL_START])
        rr = max(float(c[_weiler.CONTROL_RR]), 0.0)
        self.last_iterations = int(c[_weiler.CONTROL_ITERATIONS])
        self.last_residual = rr ** 0.5 / start if start > 0.0 else 0.0
        return self.last_iterations, self.last_residual
