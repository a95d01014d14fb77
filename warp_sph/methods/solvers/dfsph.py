"""Divergence-free SPH (Bender & Koschier 2015, 2017) as SPlisHSPlasH >= 2.12 computes it; kernels
in ``kernels/dfsph.py``, ``kernels/dfsph_solve.py`` and ``kernels/dfsph_search.py``, equations
there and in the research note ``dfsph.md``.

Step (one dt per substep):
  the fluid sorted into cells (the shared "neighbors" stage) -> one search at x ("density"): the
  neighbour lists the shared stages read, the density, the factor f_i = 1/D_i, the pair cache
  G_ij = V grad W_ij in compressed rows and the divergence source -> [stabilise: only when the fluid
  at x is over-dense far beyond the target, e.g. a compressed start, project the excess out of x
  without velocity] -> divergence solve: Jacobi
  sweeps on P^v until the mean positive compression rate is below target_divergence_error / dt,
  v += dt a(P^v) -> [the scene's forces (slot "before_pressure") and the boundary method's force] -> density source for
  v* = v + dt g (the over-density already at x enters with the share s = ``dfsph.error_share`` times
  ``error_share(dt)``: 1 at the adaptive step, 2 dt / bound for a smaller fixed step, so that it becomes a velocity e d / tau, not
  e d / dt) -> density solve: Jacobi sweeps on P with Chebyshev weights (``dfsph.chebyshev``, for fluid
  that starts at least ``dfsph.chebyshev_min_layers`` layers deep, ``fluid_layers``; else plain Jacobi; weights
  on the device, ``kernels/dfsph_solve.py`` solve_control) until the mean predicted over-density is below
  target_density_error, ending on the target's crossing between the last two sweeps
  (``dfsph.continuous_stop``) -> integrate: v = v* + dt a(P), x += dt v.

Both solves start from the last step's values (warm start, carried fields and checkpointed, so a
resume is bitwise equal): P (a pressure over density, the same at any dt for a resting load) and
P^v dt (a velocity-level correction), times ``dfsph.warm_start``, only where the particle is being
compressed. The time step is the velocity CFL bound (no acoustic bound).

Host reads: one read of a three-value control array per check (after the first min_iterations
sweeps, then every ``check_every`` sweeps: 1 on the CPU, where the read costs nothing; a device can
run blocks of sweeps between reads because the kernels stop by themselves once the control kernel
has set its done flag); one read of the mean over-density per step for the stabilisation test.

Host code in three modules: this one (the plug-in: parameters, workspace, stages, time-step bounds,
statistics, checkpoints, hints), ``dfsph_search.py`` (the step's one search: neighbour lists, density,
factor and pair cache; ``neighbor_threshold``, re-exported here) and ``dfsph_solve.py`` (the Jacobi /
Chebyshev solves and the stabilisation of an over-dense start).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ...core.launch import LIGHT_MIN_RANGE, MIN_RANGE, Replays, launch
from ...core.step_graph import Stage
from ...kernels import dfsph as _dfsph
from ...kernels import dfsph_solve as _dfsph_solve
from ...kernels import reduction as _reduce
from ...scene.parameters import Param
from ...neighbors.cell_lists import list_capacity, simulation_neighbor_lists
from ..density import neighbors_stage
from ..registry import register_solver
from ..solver import Solver, TimeStepBound
from ..force import ForceSlot
from .dfsph_search import FACTOR_FLOOR, NEIGHBOR_THRESHOLD_CUBIC, DfsphSearch, neighbor_threshold
from .dfsph_solve import STABILIZE_FACTOR, STABILIZE_FLOOR, DfsphSolve, fluid_layers

@register_solver
class DfsphSolver(DfsphSearch, DfsphSolve, Solver):
    """Divergence-free SPH: a divergence solve and a density solve per step, both Jacobi on the
    factor computed once per step (see the module docstring). Time step: velocity CFL for the
    speed at each substep's start, dt (v_max + |g| dt) <= cfl d (with moving bodies once per frame,
    dt <= cfl d / (v_max + |g| frame_dt)); the forces add their own bounds.

    check_every: sweeps between host reads of the stop test (default: 1 on the CPU, 4 elsewhere).
    """

    name = "dfsph"
    title = "divergence-free SPH (Bender & Koschier 2015, 2017)"
    #: each substep sized for the speed at its start, as SPlisHSPlasH's CFL step (the solves make any
    #: step stable; the CFL keeps the neighbourhoods and the warm start valid)
    time_step_per_substep = True
    section_doc = "divergence-free SPH settings"
    iterative = True
    #: moving bodies: after the density solve the step's wall pressure is final (term_i = (P^v_i + P_i) /
    #: rho0) and x, rho are still those of the search the solves used (integrate moves x after it)
    body_coupling_after = "pressure"
    parameters = (
        Param("dfsph.target_density_error", "float", "-", 5e-4, "the density solve stops when the mean predicted "
              "over-density max(rho*/rho0 - 1, 0) is below this (fraction of rho0; SPlisHSPlasH 'maxError' / 100)",
              gt=0.0, lt=1.0),
        Param("dfsph.target_divergence_error", "float", "-", 1e-3, "the divergence solve stops when the mean "
              "positive compression rate times dt, max(D(rho/rho0)/Dt, 0) dt, is below this (fraction of rho0 per "
              "step; SPlisHSPlasH 'maxErrorV' / 100)", gt=0.0, lt=1.0),
        Param("dfsph.min_iterations", "int", "-", 2, "fewest density-solve iterations per step", ge=1, le=10000),
        Param("dfsph.max_iterations", "int", "-", 100, "most density-solve iterations per step", ge=1, le=10000),
        Param("dfsph.divergence_min_iterations", "int", "-", 1, "fewest divergence-solve iterations per step",
              ge=1, le=10000),
        Param("dfsph.divergence_max_iterations", "int", "-", 100, "most divergence-solve iterations per step",
              ge=1, le=10000),
        Param("dfsph.divergence_solve", "bool", "-", True, "solve for a divergence-free velocity at the start of "
              "each step (off: only the density solve, as in IISPH)"),
        Param("dfsph.warm_start", "float", "-", 0.5, "fraction of the last step's pressures the solves start from "
              "(where a particle is being compressed; 0: start from zero)", ge=0.0, le=1.0),
        Param("dfsph.chebyshev", "float", "-", 0.8, "spectral-radius estimate of the density solve's Jacobi sweep "
              "for its Chebyshev acceleration (Wang 2015; 0: plain Jacobi), used when the fluid is at least "
              "dfsph.chebyshev_min_layers deep; with dfsph.continuous_stop off a solve ending on an accelerated sweep "
              "keeps the P its stop test checked. 0.8: a third fewer sweeps on the dam break at 59k particles, the "
              "same mean density error and hydrostatic load as plain Jacobi; higher values leave fluid at rest "
              "jittering", ge=0.0, lt=1.0),
        Param("dfsph.chebyshev_min_layers", "int", "-", 10, "the Chebyshev weights (dfsph.chebyshev) apply only when "
              "the fluid at the start is at least this many particle layers deep along gravity (its height / d + 1); "
              "shallower fluid's sweep converges faster than the estimate says, so the weights would slow it: a "
              "5-layer tank packed by time.settle stays at 3e-3 m/s instead of coming to rest (0: always)",
              ge=0, le=100000),
        Param("dfsph.continuous_stop", "bool", "-", True, "the density solve ends where its mean error crosses the "
              "target between its last two sweeps (P_(k-1) + theta (P_k - P_(k-1))), not on a whole sweep: the "
              "pressure is then a continuous function of the fluid's state. Off, a resting tank's sweep count flips "
              "between k and k + 1 (its error sits at the target) and each flip moves the walls' load by several %: "
              "it bounces"),
        Param("dfsph.search_skin", "float", "-", 0.0, "skin of the neighbour search in particle spacings d: lists "
              "of the pairs within H_s + skin, rebuilt only when a particle moved more than skin / 2 since the last "
              "build, the pair values recomputed every step (0: one search every step; > 0: equal to float "
              "rounding, the sums run in the lists' order)", ge=0.0, le=2.0),
        Param("dfsph.relaxation", "float", "-", 0.5, "Jacobi relaxation omega of both solves (SPlisHSPlasH: 0.5; "
              "1 overshoots on coupled pairs)", gt=0.0, le=1.0),
        Param("dfsph.error_share", "float", "-", 1.0, "share of the over-density present at a step's start that the "
              "density solve corrects within one adaptive step (Baumgarte stabilisation; the source's s = error_share "
              "min(1, 2 dt / adaptive step)): 1 corrects it at once, as SPlisHSPlasH; 0.1 spreads it over about 10 "
              "steps, so a leftover the solve cannot remove feeds a tenth of the velocity. Not a fix: with 0.1 the coarse fcc "
              "tank comes to rest (8.4e-4 m/s at 2 s) but the fine one compresses (0.1 m/s, mid-depth -28 %; "
              "docs/validation-notes.md)", gt=0.0, le=1.0),
    )

    @classmethod
    def validate(cls, scene, fail) -> None:
        p = scene.section(cls.name)
        if p.min_iterations > p.max_iterations:
            fail("dfsph.min_iterations", f"expected <= dfsph.max_iterations ({p.max_iterations}), got {p.min_iterations}")
        if p.divergence_min_iterations > p.divergence_max_iterations:
            fail("dfsph.divergence_min_iterations", f"expected <= dfsph.divergence_max_iterations "
                 f"({p.divergence_max_iterations}), got {p.divergence_min_iterations}")

    def __init__(self, sim, check_every: int | None = None):
        super().__init__(sim)
        m = self.model
        self.check_every = int(check_every) if check_every else (1 if m.device.is_cpu else 4)
        if self.check_every < 1:
            raise ValueError(f"check_every must be >= 1, got {check_every}")
        self.neighbor_threshold = neighbor_threshold(m.smoothing.name, m.smoothing_length, m.spacing)
        self.factor_floor = FACTOR_FLOOR / (m.spacing * m.spacing)
        self.skin = float(self.config.search_skin) * m.spacing  # [m]
        target = float(self.config.target_density_error)
        self.stabilize_threshold = max(STABILIZE_FACTOR * target, STABILIZE_FLOOR)
        self.max_shift = 0.5 * m.particle_radius
        #: the fluid's depth at the start in layers, and the Chebyshev estimate the density solve uses:
        #: dfsph.chebyshev when the fluid is at least dfsph.chebyshev_min_layers deep, else 0 (plain Jacobi)
        self.fluid_layers = fluid_layers(sim.get_field("particle_x")[: m.fluid_count], m.gravity, m.spacing)
        deep = self.fluid_layers >= int(self.config.chebyshev_min_layers)
        self.chebyshev = float(self.config.chebyshev) if deep else 0.0
        self._kept_force = None  # finish_frame's copy of the walls' force (allocated on the first frame)
        # figures of the last step (host values, read by step_statistics and tests)
        self.last_iterations = 0
        self.last_density_error = 0.0        # mean predicted over-density of the last sweep [-]
        self.last_divergence_iterations = 0
        self.last_divergence_error = 0.0     # mean positive compression rate of the last sweep times dt [-]
        self.last_start_error = 0.0          # mean over-density at x at the start of the step [-]
        self.last_stabilization = 0          # stabilisation rounds of the last step
        self.solves = 0                      # solves run (tests count them)
        self.sweep_loop = True               # CPU: run each solve's sweeps in one core.launch.run_loop

    # --- workspace -------------------------------------------------------------------------
    def _allocate(self) -> None:
        sim, m = self.sim, self.model
        n, dev = m.capacity, m.device  # the particle capacity (emitters: the active count changes)
        for name, dtype in (("particle_density", float), ("dfsph_factor", float), ("dfsph_divergence_source", float),
                            ("dfsph_divergence_pressure", float), ("dfsph_divergence_warm", float),
                            ("dfsph_density_source", float), ("dfsph_pressure", float), ("dfsph_error", float),
                            ("dfsph_acceleration", wp.vec3), ("boundary_force", wp.vec3),
                            ("particle_acceleration", wp.vec3), ("particle_pressure", float)):
            sim.allocate(name, dtype)
        chunks = max(1, -(-n // _reduce.REDUCE_CHUNK))
        self._partial = wp.zeros(chunks, dtype=float, device=dev)
        self._control = wp.zeros(_dfsph_solve.CONTROL_COUNT, dtype=wp.float64, device=dev)
        self._previous = wp.zeros(max(n, 1), dtype=float, device=dev)
        self._zero_control = wp.zeros(_dfsph_solve.CONTROL_COUNT, dtype=wp.float64, device=dev)
        # CPU: the sweeps' launches recorded once per solve site, the control read through a view
        self._replays = Replays() if dev.is_cpu else None
        self._control_view = self._control.numpy() if dev.is_cpu else None
        self._gravity = wp.vec3(*m.gravity)  # [m/s^2], one value (a replayed launch compares it by value)
        self._allocate_search()
        if self.with_bodies:
            # term_i of the walls' pressure (``body_pressure_term``) and the velocities the boundary
            # force term (apply_forces stage) read, for the body force gather
            sim.allocate("boundary_pressure_term", float)
            sim.allocate("boundary_force_velocity", wp.vec3)

    def replayed(self, kernel, dim: int, inputs, outputs, min_range: int = MIN_RANGE) -> None:
        """A launch of the step: on the CPU replayed from its recording (``core.launch.Replays``: arguments
        packed again only where they changed; the ranges on the persistent threads), else ``launch``; the
        same ranges, so bitwise the same."""
        if self._replays is not None and self.sweep_loop and dim > 0:
            self._replays.get(kernel, dim, inputs, outputs, device=self.model.device, min_range=min_range).launch()
        else:
            launch(kernel, dim, inputs, outputs, device=self.model.device, min_range=min_range)

    # --- stages ----------------------------------------------------------------------------
    def run_search(self, sim, dt) -> None:
        self.search(dt)

    def run_divergence(self, sim, dt) -> None:
        m, f, p = self.model, sim.fields, self.config
        finish = (_dfsph.finish_divergence, m.fluid_count,
                  [m.particle_mass, float(dt), self.nl.fluid, f["dfsph_pairs"], f["dfsph_divergence_pressure"]],
                  [f["particle_v"], f["boundary_force"], f["dfsph_divergence_warm"]])
        it, err = self.solve("dfsph_divergence_pressure", "dfsph_divergence_source", dt,
                             float(p.target_divergence_error) / dt, int(p.divergence_min_iterations),
                             int(p.divergence_max_iterations), True, finish=finish)
        self.last_divergence_iterations = it
        self.last_divergence_error = err * dt

    def run_source(self, sim, dt) -> None:
        m, f = self.model, sim.fields
        self.replayed(_dfsph.density_source, m.fluid_count,
                      [m.rest_density, self._gravity, float(dt), float(self.config.warm_start),
                       float(self.config.error_share) * self.error_share(dt),
                       self.nl.fluid, f["dfsph_pairs"], f["particle_density"], f["particle_v"]],
                      [f["dfsph_pressure"], f["dfsph_density_source"]])

    def run_pressure(self, sim, dt) -> None:
        p = self.config
        it, err = self.solve("dfsph_pressure", "dfsph_density_source", dt * dt, float(p.target_density_error),
                             int(p.min_iterations), int(p.max_iterations), False, chebyshev=True,
                             continuous=bool(p.continuous_stop))
        self.last_iterations = it
        self.last_density_error = err
        if self.with_bodies:
            m, f = self.model, sim.fields
            launch(_dfsph.body_pressure_term, m.fluid_count,
                   [m.rest_density, int(bool(p.divergence_solve)), self.nl.fluid, f["dfsph_divergence_pressure"],
                    f["dfsph_pressure"]], [f["boundary_pressure_term"]], device=m.device, min_range=LIGHT_MIN_RANGE)

    def run_force_velocity(self, sim, dt) -> None:
        wp.copy(sim.fields["boundary_force_velocity"], sim.fields["particle_v"])

    def run_integrate(self, sim, dt) -> None:
        m, f = self.model, sim.fields
        self.replayed(_dfsph.integrate, m.fluid_count,
                      [m.particle_mass, m.rest_density, self._gravity, float(dt), self.nl.fluid, f["dfsph_pairs"],
                       f["dfsph_pressure"], f["particle_density"]],
                      [f["particle_v"], f["particle_x"], f["boundary_force"], f["particle_pressure"],
                       f["particle_acceleration"]])

    def stages(self) -> list[Stage]:
        sim, m, p = self.sim, self.model, self.config
        # fluid list rows (and the pair cache's allocation) sized from the rest neighbour count, as PBF's
        # (``cell_lists.list_capacity``: 1.3 (4/3) pi R^3 / V, 44 slots at R = H_s, not 64); overflow grows and redoes
        simulation_neighbor_lists(sim, self.skin, fluid_capacity=list_capacity(m.support_radius + self.skin,
                                                                               m.particle_mass / m.rest_density))
        self._neighbors = neighbors_stage(sim, True, self.skin)
        self._allocate()
        self._pairs()
        terms = sim.boundary_terms
        with_boundary = terms is not None and terms.gradient is not None
        boundary_reads = ("boundary_x", "boundary_volume") if with_boundary else ()
        bodies = self.with_bodies
        if bodies:  # the moving particles' grid, and their velocities in the divergence source
            boundary_reads += ("moving_boundary_grid",) + (("boundary_v",) if with_boundary else ())
        search_out = ("neighbor_lists", "particle_density", "dfsph_pairs", "dfsph_factor", "dfsph_divergence_source",
                      "dfsph_divergence_pressure", "dfsph_acceleration", "dfsph_error", "boundary_force")
        search_reads = ("neighbor_cells", "particle_x", "particle_v", "dfsph_divergence_warm")
        wall = f" + {terms.name} boundary" if with_boundary else ""
        stages = [
            self._neighbors,
            Stage("density", self.run_search, reads=search_reads + boundary_reads, writes=search_out,
                  doc=(f"one search within H_s (list capacities {self.nl.capacities}): neighbour lists" if not self.skin
                       else f"lists within H_s + {p.search_skin:g} d rebuilt once a particle moved "
                       f"{p.search_skin / 2:g} d "
                       f"(capacities {self.nl.capacities}), their pairs within H_s") + f", density (eq. 7"
                      f"{wall}), pair cache V grad W_ij in compressed rows, f_i = 1/(|s_i|^2 + sum_j |V grad W_ij|^2), "
                      f"divergence source -delta(v), warm start {p.warm_start:g} P~v/dt"),
            Stage("stabilize", self.run_stabilize, reads=("particle_v", "dfsph_divergence_warm") + boundary_reads,
                  updates=("particle_x", "neighbor_cells") + search_out,
                  doc=f"when the mean over-density at x exceeds {self.stabilize_threshold:g}: density solves at rest "
                      "and capped shifts of x (no velocity)"),
        ]
        if p.divergence_solve:
            stages.append(Stage(
                "divergence", self.run_divergence,
                reads=("neighbor_lists", "dfsph_pairs", "dfsph_factor", "dfsph_divergence_source"),
                updates=("dfsph_divergence_pressure", "dfsph_acceleration", "dfsph_error", "particle_v",
                         "boundary_force", "dfsph_divergence_warm"),
                doc=f"Jacobi sweeps (omega {p.relaxation:g}) until mean max(D rho/Dt, 0) dt < "
                    f"{p.target_divergence_error:g} ({p.divergence_min_iterations}-{p.divergence_max_iterations}); "
                    "v += dt a(P^v)"))
        # the non-pressure forces (``warp_sph.methods.force``) act on the divergence-free v at x; the density
        # solve then projects what they did; gravity is added later (source, integrate)
        slot = ForceSlot("before_pressure", "list", "particle_x", gravity_in_velocity=False)
        forces = sim.forces
        explicit = forces.explicit_stages(slot)
        apply = forces.apply_stage(slot)
        #: the workspace field of the velocities the boundary force term was evaluated with (body gather)
        self.body_coupling_velocity = "particle_v"
        if bodies and apply is not None:
            # the density solve changes v after the apply stage: keep what its boundary force read
            self.body_coupling_velocity = "boundary_force_velocity"
            stages.append(Stage("force_velocity", self.run_force_velocity, reads=("particle_v",),
                                writes=("boundary_force_velocity",),
                                doc="v kept for the bodies' share of the boundary force (read by body_forces)"))
        stages += explicit + ([apply] if apply is not None else []) + forces.implicit_stages(slot) + forces.filter_stages(slot)
        stages += [
            Stage("source", self.run_source,
                  reads=("neighbor_lists", "dfsph_pairs", "particle_density", "particle_v"),
                  writes=("dfsph_density_source",), updates=("dfsph_pressure",),
                  doc=f"b = s min(1 - rho/rho0, 0) + max(1 - rho/rho0, 0) - dt delta(v + dt g), s = {p.error_share:g} "
                      f"min(1, 2 dt / adaptive step); warm start {p.warm_start:g} P where compressing"),
            Stage("pressure", self.run_pressure,
                  reads=("neighbor_lists", "dfsph_pairs", "dfsph_factor", "dfsph_density_source")
                  + (("dfsph_divergence_pressure",) if bodies and p.divergence_solve else ()),
                  updates=("dfsph_pressure", "dfsph_acceleration", "dfsph_error"),
                  writes=("boundary_pressure_term",) if bodies else (),
                  doc=f"Jacobi sweeps (omega {p.relaxation:g}, Chebyshev rho {self.chebyshev:g}: {self.fluid_layers} layers "
                      f"deep, weights from {p.chebyshev_min_layers}) until the mean predicted "
                      f"over-density < "
                      f"{p.target_density_error:g} ({p.min_iterations}-{p.max_iterations})"
                      + ("; bodies: term_i = (P^v_i + P_i) / rho0, the walls' pressure of the step" if bodies else "")),
            Stage("integrate", self.run_integrate,
                  reads=("neighbor_lists", "dfsph_pairs", "dfsph_pressure", "particle_density"),
                  writes=("particle_pressure", "particle_acceleration"),
                  updates=("particle_v", "particle_x", "boundary_force"),
                  doc="v += dt (g + a(P)); x += dt v; p = P rho^2 / rho0"),
        ]
        return stages

    def carried_fields(self) -> tuple[str, ...]:
        """The warm-start values: P of the density solve and P^v dt of the divergence solve."""
        return ("dfsph_pressure", "dfsph_divergence_warm")

    # --- interface -------------------------------------------------------------------------
    def time_step_bounds(self, speed: float) -> list[TimeStepBound]:
        """Velocity CFL for the fastest speed the step can reach: per substep (``sim.per_substep_step``)
        dt (v + |g| dt) = cfl d, i.e. dt = 2 cfl d / (v + sqrt(v^2 + 4 |g| cfl d)); once per frame
        dt = cfl d / (v + |g| frame_dt)."""
        m = self.model
        cfl = self.sim.scene.time.cfl
        g = float(np.linalg.norm(m.gravity))
        if self.sim.per_substep_step:
            reach = cfl * m.spacing
            dt = 2.0 * reach / max(speed + float(np.sqrt(speed * speed + 4.0 * g * reach)), 1e-12)
            bound = TimeStepBound("velocity CFL", dt, f"dt (v + |g| dt) = cfl d with cfl = {cfl:g}, d = {m.spacing:.4g} m, "
                                  f"v = {speed:.3g} m/s (the fastest particle at the substep's start), "
                                  f"|g| dt = {g * dt:.3g} m/s", ("time.cfl",))
        else:
            frame_dt = self.sim.frame_dt
            v = max(speed + g * frame_dt, 1e-12)
            bound = TimeStepBound("velocity CFL", cfl * m.spacing / v,
                                  f"cfl d / (v + |g| frame_dt) with cfl = {cfl:g}, d = {m.spacing:.4g} m, v = {speed:.3g} m/s, "
                                  f"|g| frame_dt = {g * frame_dt:.3g} m/s", ("time.cfl",))
        return [bound]

    def step_statistics(self) -> dict[str, float]:
        return {"iterations": float(self.last_iterations), "density_error": self.last_density_error,
                "divergence_iterations": float(self.last_divergence_iterations),
                "divergence_error": self.last_divergence_error,
                "stabilization_rounds": float(self.last_stabilization)}

    def finish_frame(self) -> None:
        """The density at the frame's positions (for the statistics and the watchdog). The walls' force of
        the frame's last substep is kept: the density pass starts a substep's sum of it (zeroes it), and
        wall probes and scripts read it after the frame."""
        force = self.sim.fields["boundary_force"]
        n = force.shape[0]  # the active particles (emitters: a prefix of the capacity)
        if self._kept_force is None or self._kept_force.shape[0] < n:
            self._kept_force = wp.empty(max(n, self.model.capacity), dtype=wp.vec3, device=force.device)
        if n:  # (count = 0 would copy the whole kept array: a sink emptied the fluid)
            wp.copy(self._kept_force, force, count=n)
        self.refresh_density()
        if n:
            wp.copy(force, self._kept_force, count=n)

    def refresh_density(self) -> None:
        """The search at the current positions (``Solver.refresh_density``); when a row overflowed (a start sampled
        denser than rest: the rows hold 1.3x the rest count), the lists grow and the search runs again, so the start's
        density counts every pair (``NeighborLists.grow_to_fit``)."""
        super().refresh_density()
        if self.nl.grow_to_fit():
            super().refresh_density()

    def checkpoint_arrays(self) -> dict:
        f = self.sim.fields
        return {"dfsph_pressure": f["dfsph_pressure"], "dfsph_divergence_warm": f["dfsph_divergence_warm"]}

    def restore_arrays(self, arrays) -> None:
        f = self.sim.fields
        for name in ("dfsph_pressure", "dfsph_divergence_warm"):
            if name in arrays:
                a = arrays[name]
                f[name].assign(a if isinstance(a, wp.array) else wp.array(np.asarray(a), dtype=float, device=self.model.device))
            else:
                f[name].zero_()

    def instability_hint(self, rule: str, stage: str | None) -> str | None:
        p = self.config
        if rule in ("outside", "dense", "fast") and self.last_iterations >= int(p.max_iterations):
            return (f"the density solve stopped at dfsph.max_iterations = {p.max_iterations} with the predicted density "
                    f"error {100 * self.last_density_error:.3g} % above the target: raise dfsph.max_iterations or lower "
                    "time.cfl")
        return None

    def summary(self) -> dict:
        return {"neighbor_threshold": self.neighbor_threshold, "stabilize_threshold": self.stabilize_threshold,
                "check_every": self.check_every, "fluid_layers": self.fluid_layers, "chebyshev": self.chebyshev}
