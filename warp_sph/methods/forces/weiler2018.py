"""Implicit viscosity (Weiler, Koschier, Brand & Bender 2018), kernels in ``kernels/weiler2018.py`` and its CG
iteration in ``kernels/weiler2018_cg.py`` (equations there and in the research note ``forces.md`` section 3.2).

Backward Euler on the velocities: A v_new = v* + c with A = I + dt (viscous Laplacian), solved for
dv = v_new - v* by conjugate gradients with a 3x3 block-Jacobi preconditioner, warm-started from
the last step's dv (a carried per-particle field, ``weiler2018_dv``: sorted with the particles and
checkpointed). No time-step bound: any nu runs at the solver's own step (at large dt nu / h^2 it
over-damps, as backward Euler does). The force runs last in its slot, on v* = v + dt (a_explicit + g)
(with DFSPH, whose gravity comes after the slot, v* includes this step's dt g for the walls' term and
the change excludes it), so it damps the other kicks as well.

Scene::

    [[forces]]
    method = "weiler2018"
    viscosity = 1.0             # nu [m^2/s]
    boundary_viscosity = 1.0    # nu_b [m^2/s] against walls (0: free slip)

Host reads: one read of the control array per check (every ``check_every`` iterations: 1 on the
CPU, where the read costs nothing; a device runs blocks of iterations, the kernels stop by
themselves once the control kernel set its done flag).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ...core.launch import launch
from ...core.step_graph import Stage
from ...kernels import reduction as _reduce
from ...kernels import weiler2018 as _weiler
from ...kernels import weiler2018_cg as _cg
from ...scene.parameters import Param
from ..force import Force, ForceSlot
from ..registry import register_force

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
        self.control = wp.zeros(_cg.CONTROL_COUNT, dtype=wp.float64, device=dev)
        # figures of the last solve (host values)
        self.last_iterations = 0
        self.last_residual = 0.0   # |r| / |r0| at the end [-]
        self.solves = 0

    def _pairs_for(self, capacity: int) -> wp.array:
        if self.pairs is None or self.pairs.shape[1] != capacity:
            self.pairs = wp.zeros((max(self.n, 1), capacity), dtype=wp.vec3, device=self.device)
        return self.pairs

    def _dots(self, a: wp.array, b: wp.array, c: wp.array, d: wp.array, first: int = 0) -> tuple:
        """Chunk sums of a . b and c . d into partial arrays ``first`` and ``first + 1``."""
        p, q = self._partials[first], self._partials[first + 1]
        launch(_cg.dot_chunks, p.shape[0], [_reduce.REDUCE_CHUNK, a, b, c, d, self.control], [p, q],
               device=self.device)
        return p, q

    def solve(self, dt: float, model, viscosity: float, boundary_viscosity: float, fluid_neighbors,
              boundary_neighbors, boundary_x, boundary_v, boundary_volume, particle_x, particle_density,
              particle_v, warm, boundary_force, velocity_shift=(0.0, 0.0, 0.0)) -> tuple[int, float]:
        """v <- v + dv for the step dt [s], with v* = v + velocity_shift (e.g. the step's dt g when the
        solver adds it after the solve); ``warm`` [m/s] holds the last dv on entry and this step's on
        return. ``model`` gives particle_mass, rest_density, smoothing_length and support_radius;
        neighbours are ``NeighborList`` structs at ``particle_x``; ``boundary_force`` [N] (None without
        the boundary term) gets the walls' viscous force. Returns (iterations, |r| / |r0| at the end)."""
        n, dev = self.n, self.device
        if n == 0:
            return 0, 0.0
        fn = fluid_neighbors
        shift = wp.vec3(*velocity_shift)
        if boundary_force is None:
            boundary_force = self.boundary_rhs  # not written: the kernel is specialised without the boundary
        pairs = self._pairs_for(fn.index.shape[1])
        control = self.control
        launch(self._setup, n,
               [float(model.particle_mass), float(model.rest_density), float(model.smoothing_length),
                float(model.support_radius), float(viscosity), float(boundary_viscosity), float(dt),
                boundary_neighbors, boundary_x, boundary_v, boundary_volume, fn, particle_x, particle_density],
               [pairs, self.block_inverse, self.boundary_block, self.boundary_rhs], device=dev)
        launch(_cg.reset_control, 1, [], [control], device=dev)
        launch(self._start, n, [fn, pairs, self.block_inverse, self.boundary_block, self.boundary_rhs, particle_v, shift,
                                 warm],
               [warm, self.start_residual, self.residual, self.preconditioned, self.direction], device=dev)
        rz, rr = self._dots(self.residual, self.preconditioned, self.residual, self.residual)
        start, speed = self._dots(self.start_residual, self.start_residual, particle_v, particle_v, 2)
        launch(_cg.start_control, 1, [rz, rr, start, speed, self.tolerance, self.max_iterations], [control],
               device=dev)
        self.solves += 1
        c = control.numpy()
        launched = 0
        while c[_cg.CONTROL_DONE] == 0.0 and launched < self.max_iterations:
            block = min(self.check_every, self.max_iterations - launched)
            for _ in range(block):
                launch(self._matvec, n, [fn, pairs, self.boundary_block, self.direction, control], [self.product],
                       device=dev)
                launch(_cg.alpha_control, 1, [self._dots(self.direction, self.product, self.direction,
                                                             self.product)[0]], [control], device=dev)
                launch(_cg.update, n, [fn, self.block_inverse, self.direction, self.product, control],
                       [warm, self.residual, self.preconditioned], device=dev)
                rz, rr = self._dots(self.residual, self.preconditioned, self.residual, self.residual)
                launch(_cg.beta_control, 1, [rz, rr, self.max_iterations], [control], device=dev)
                launch(_cg.new_direction, n, [fn, self.preconditioned, control], [self.direction], device=dev)
            launched += block
            c = control.numpy()  # the one read per check
        launch(self._finish, n, [float(model.particle_mass), float(dt), shift, fn, self.boundary_block, self.boundary_rhs, warm],
               [particle_v, boundary_force, warm], device=dev)
        start = float(c[_cg.CONTROL_START])
        rr = max(float(c[_cg.CONTROL_RR]), 0.0)
        self.last_iterations = int(c[_cg.CONTROL_ITERATIONS])
        self.last_residual = rr ** 0.5 / start if start > 0.0 else 0.0
        return self.last_iterations, self.last_residual


@register_force
class Weiler2018(Force):
    """Implicit viscosity (module docstring): nu from water to honey and beyond at the solver's own step."""

    name = "weiler2018"
    title = "implicit viscosity (Weiler et al. 2018): high viscosity at the solver's own step"
    kind = "viscosity"
    mode = "implicit"
    parameters = (
        Param("weiler2018.viscosity", "float", "m^2/s", 0.01, "kinematic viscosity nu (water 1e-6, honey 2e-3..7e-3; "
              "a scene scaled s times up from a real one looks right with nu s^1.5); implicit: no step bound",
              ge=0.0, le=1e5),
        Param("weiler2018.boundary_viscosity", "float", "m^2/s", 0.0, "viscosity nu_b against the boundary particles "
              "(0: the fluid slips along walls; about nu: it sticks, e.g. honey on a plate)", ge=0.0, le=1e5),
        Param("weiler2018.tolerance", "float", "-", 0.01, "the conjugate-gradient solve stops when the residual's "
              "norm is this fraction of its value at dv = 0", gt=0.0, lt=1.0),
        Param("weiler2018.max_iterations", "int", "-", 100, "most conjugate-gradient iterations per step", ge=1,
              le=10000),
    )

    @classmethod
    def is_active(cls, config) -> bool:
        return config.viscosity > 0.0 or config.boundary_viscosity > 0.0

    @classmethod
    def validate_config(cls, scene, config, keypath: str, fail) -> None:
        if scene.bodies and config.boundary_viscosity > 0.0:
            fail(cls.key_path(keypath, "boundary_viscosity"), "moving [[bodies]] do not receive the implicit "
                 "viscosity's wall force: set 0 (free slip) or remove the bodies")

    def __init__(self, sim, config, keypath: str):
        super().__init__(sim, config, keypath)
        m = self.model
        self.with_boundary = m.boundary_count > 0 and float(config.boundary_viscosity) > 0.0
        self.solver = Weiler2018Solve(m.fluid_count, m.smoothing.name, self.with_boundary, float(config.tolerance),
                                      int(config.max_iterations), m.device)
        sim.allocate(WARM_FIELD, wp.vec3)
        if self.with_boundary:
            sim.allocate("boundary_force", wp.vec3)

    def stages(self, slot: ForceSlot) -> list[Stage]:
        if not slot.lists:
            raise ValueError(f"force {self.name!r} ({self.keypath}) reads the step's neighbour lists; the solver runs "
                             "with hash-grid queries (lists=False)")
        m, sim, c = self.model, self.sim, self.config
        nu, nu_b = float(c.viscosity), float(c.boundary_viscosity)
        positions = slot.positions
        gravity = None if slot.gravity_in_velocity else np.asarray(m.gravity, dtype=np.float64)
        moving = getattr(sim, "bodies", None) is not None

        def run(sim, dt):
            f = sim.fields
            nl = f["neighbor_lists"]
            shift = (0.0, 0.0, 0.0) if gravity is None else tuple(float(g) * dt for g in gravity)
            self.solver.solve(dt, m, nu, nu_b, nl.fluid, nl.boundary, m.boundary_x,
                              f["boundary_v"] if moving else m.boundary_v, m.boundary_volume, f[positions],
                              f["particle_density"], f["particle_v"], f[WARM_FIELD],
                              f["boundary_force"] if self.with_boundary else None, shift)

        boundary_reads = (("boundary_x", "boundary_volume") + (("boundary_v",) if moving else ())
                          if self.with_boundary else ())
        doc = (f"backward-Euler viscosity nu = {nu:g} m^2/s" + (f", walls nu_b = {nu_b:g} m^2/s" if self.with_boundary
                                                                  else "")
               + f": block-Jacobi CG to |r| <= {c.tolerance:g} |r0| (at most {c.max_iterations}), warm-started from "
               f"the last dv" + ("" if gravity is None else "; v* includes this step's dt g"))
        return [Stage("implicit_viscosity", run, reads=(slot.neighbor_field, positions, "particle_density")
                      + boundary_reads, updates=("particle_v", WARM_FIELD)
                      + (("boundary_force",) if self.with_boundary else ()), doc=doc)]

    def carried_fields(self) -> tuple[str, ...]:
        """The warm start: the last step's dv [m/s]."""
        return (WARM_FIELD,)

    def step_statistics(self) -> dict[str, float]:
        return {"viscosity_iterations": float(self.solver.last_iterations),
                "viscosity_residual": self.solver.last_residual}

    def instability_hint(self, rule: str, stage: str | None) -> str | None:
        c = self.config
        if stage == "implicit_viscosity" and self.solver.last_iterations >= int(c.max_iterations):
            return (f"the implicit viscosity stopped at max_iterations = {c.max_iterations} with |r| / |r0| = "
                    f"{self.solver.last_residual:.3g} above tolerance {c.tolerance:g}: raise "
                    f"{self.key_path(self.keypath, 'max_iterations')}")
        return None

    def summary(self) -> dict:
        c = self.config
        return {"viscosity": float(c.viscosity), "boundary_viscosity": float(c.boundary_viscosity),
                "with_boundary": self.with_boundary, "tolerance": float(c.tolerance),
                "max_iterations": int(c.max_iterations), "check_every": self.solver.check_every}
