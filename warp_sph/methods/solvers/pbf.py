"""Position-based fluids (Macklin & Mueller 2013; seed report section 4.5, eq. 17-20); kernels in
``kernels/pbf.py`` (per particle), ``kernels/pbf_pairs.py`` (over neighbour lists) and ``kernels/pbf_hash_grid.py``
(the reference variant).

Step: [stabilize x] -> predict (v += dt g, x* = x + dt v) -> neighbours on x* -> density and lambda at
x* -> solve (iterations of a density pass and a Jacobi correction dx, eq. 18, as in SPlisHSPlasH: until
the average density error mean(max(rho/rho0 - 1, 0)) of the iteration's density pass is below
``pbf.target_density_error``, between ``min_iterations`` and ``max_iterations``) -> update
(v = (x* - x)/dt, x = x*) -> [the scene's forces (slot "after_update") and the boundary method's force].

Iterations per step: each step gravity moves the fluid by |g| dt^2 and the Jacobi solve carries that
load down a column kappa d^2 dC/dz per iteration, so a column of depth H needs about
|g| H dt^2 / (2 kappa d^2 eta) iterations to hold the mean error at eta (measured law, ``solve_bound``):
at a fixed step they grow with the depth in particles squared over the spacing (2 at 6.9k, 15 at 493k
particles at 5 ms in the dam break). The "pressure solve" time-step bound keeps them near
``pbf.target_iterations``; it costs steps where it binds, which the iterations it saves pay for
(cost per step ~ overhead + iterations, steps ~ 1/sqrt(iterations)).

Why the report's solver exploded (physics notes 4.4): dx ~ C grad C / |grad C|^2, so a denominator
sum_k |grad_k C_i|^2 that is too small gives a correction that is too large. Here grad C uses
V = m/rho0 (report eq. 20 with consistent units), and an explicit relaxation is dimensionless:
eps = relaxation * D0, with D0 the denominator of an interior particle of the start's rest lattice,
computed once on the host from the same kernel (``rest_denominator``). By default eps = 3/4 A_max - D0
(``auto_epsilon``): one Jacobi iteration multiplies a density wave by 1 - A(q) / (D0 + eps), A the symbol
of J J^T; A_max / D0 = 2.8 (cubic) / 3.3 (fcc), so eps ~ 0 amplifies the short waves (issue #31).

Neighbours: lists built once per step on x* with the search radius H_s + margin
(``warp_sph.neighbors.NeighborLists``), read by every solver iteration and by the forces, rebuilt only when a particle drifted farther than margin / 2; or the reference hash-grid
variant, rebuilt before every density pass or queried with H_s + margin. Sums and maxima over the
particles are reduced in a fixed order (bitwise reproducible on any thread count).

Host code in three modules: this one (the plug-in: parameters, stages and the solve loop, time-step
bounds, statistics, hints), ``pbf_passes.py`` (the density and correction passes it runs) and
``pbf_lattice.py`` (rest-lattice calibration: D0, kappa, the fluid depth).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ...core.launch import LIGHT_MIN_RANGE
from ...core.model import fluid_lattice
from ...core.smoothing import evaluate
from ...core.step_graph import Stage
from ...kernels import pbf as _pbf
from ...scene.parameters import Param
from ..registry import register_solver
from ..solver import Solver, TimeStepBound
from ..force import ForceSlot
from .pbf_lattice import auto_epsilon, fluid_depth, lattice_transport, rest_denominator
from .pbf_passes import PbfPasses

__all__ = ["LIST_MARGIN", "PbfSolver", "fluid_depth", "lattice_transport", "rest_denominator"]

#: search margin of the lists [spacings d]: pairs within H_s + margin, rebuilt once a particle moved margin / 2.
#: 0.1 d listed 12 % fewer pairs (0.90x CPU per step on the fixed-step dam break) but changes the pairs' order, and
#: the resting tank's floor probe (tests/test_probes.py, PBF, coarse) then read +1.14 % against its 1 % goal
#: (+0.13 % at 0.2 d): kept at 0.2 d (docs/performance.md, "PBF's step")
LIST_MARGIN = 0.2


@register_solver
class PbfSolver(PbfPasses, Solver):
    """Iterative position-based pressure solver. Time step: velocity CFL
    dt <= cfl d / (v_max + |g| frame_dt), the pressure-solve bound dt <= d sqrt(2 kappa K eta / (|g| H))
    (``solve_bound``: the step whose weight the solve carries in about K = ``pbf.target_iterations``
    iterations, so the iterations per step do not grow with the fluid's depth in particles); the forces
    add their own bounds.

    lists: neighbour lists built on x* once per step with the search radius H_s + margin and read by
    every pass of the step; rebuilt when a particle of x* drifted more than margin / 2 from where they
    were built (then no pair closer than H_s can be missing). ``lists=False``: hash-grid queries in
    every pass (the reference variant), grid rebuilt before every density pass ("rebuild") or
    queried with H_s + margin and rebuilt once a particle drifted more than the margin ("margin").
    neighbor_mode "rebuild" with lists: rebuilt before every density pass, no margin.
    margin [spacings d]; max_step [particle radii] caps |dx_i| per iteration (0: off).
    """

    name = "pbf"
    title = "position-based fluids (Macklin & Mueller 2013)"
    #: the walls' correction summed over the step's iterations is its boundary_pressure_term; particle_x
    #: and particle_v after "update" are what the apply_forces stage's boundary force reads
    body_coupling_after = "update"
    section_doc = "position-based fluids settings"
    iterative = True
    parameters = (
        Param("pbf.target_density_error", "float", "-", 0.005, "stop iterating when the average density error "
              "(fraction of rho0) is below this", gt=0.0, lt=1.0),
        Param("pbf.max_iterations", "int", "-", 50, "most constraint iterations per substep", ge=1, le=10000),
        Param("pbf.min_iterations", "int", "-", 2, "fewest constraint iterations per substep", ge=0, le=10000),
        Param("pbf.relaxation", "float", "-", None, "constraint-force mixing epsilon, relative to the "
              "denominator D0 = sum_k (grad_k C)^2 of the start's rest lattice (cubic or fcc); absent (auto): "
              "eps = 3/4 A_max - D0, A_max the largest symbol of J J^T on that lattice (1.12 D0 cubic, 1.50 D0 fcc "
              "with the cubic kernel), the Jacobi solve's best damping of short density waves; below "
              "1/2 A_max / D0 - 1 (0.41 cubic, 0.67 fcc) the solve amplifies them", ge=0.0, le=1e6,
              default_text="auto"),
        Param("pbf.tensile_correction", "bool", "-", False, "artificial pressure s_corr against clustering"),
        Param("pbf.tensile_k", "float", "-", 0.1, "s_corr strength k", ge=0.0, le=10.0),
        Param("pbf.tensile_n", "int", "-", 4, "s_corr exponent n", ge=1, le=16),
        Param("pbf.tensile_dq", "float", "-", 0.2, "s_corr reference distance dq in smoothing lengths h",
              gt=0.0, lt=2.0),
        Param("pbf.vorticity", "float", "-", 0.0, "vorticity confinement strength epsilon: sets [[forces]] method = "
              "\"vorticity_confinement\" strength (which works with every solver)", ge=0.0, le=100.0),
        Param("pbf.target_iterations", "float", "-", 4.0, "iterations per step the time step is sized for "
              "(solve bound dt <= d sqrt(2 kappa K eta / (g H)), H the fluid depth, eta the target density error, "
              "kappa = 2.4 for the cubic kernel: at a fixed step the iterations grow as g H dt^2 / d^2); 0: no such bound", ge=0.0, le=1000.0),
    )

    @classmethod
    def validate(cls, scene, fail) -> None:
        p = scene.section(cls.name)
        if p.min_iterations > p.max_iterations:
            fail("pbf.min_iterations", f"expected <= pbf.max_iterations ({p.max_iterations}), got {p.min_iterations}")

    def __init__(self, sim, neighbor_mode: str | None = None, margin: float | None = None, max_step: float = 0.5,
                 lists: bool = True):
        super().__init__(sim)
        if neighbor_mode is None:
            neighbor_mode = "margin" if lists else "rebuild"
        if neighbor_mode not in ("rebuild", "margin"):
            raise ValueError(f"neighbor_mode must be 'rebuild' or 'margin', got {neighbor_mode!r}")
        m, p = self.model, self.config
        self.lists = bool(lists)
        self.neighbor_mode = neighbor_mode
        self.margin_per_spacing = float(LIST_MARGIN if margin is None and lists else 0.25 if margin is None else margin)
        self.max_step_per_radius = max_step  # trust region: |dx_i| per iteration <= this * r (0: off)
        self.max_step = max_step * m.particle_radius if max_step > 0 else 1e30
        self.stabilize_factor = 2.0  # pre-stabilise when the error at x exceeds this times the target
        self.trace = False  # record (density error, largest |dx|) per iteration in last_trace
        # figures of the last step, read by step_statistics and tests (host values, no device read)
        self.last_iterations = 0
        self.last_density_error = 0.0
        self.last_max_correction = 0.0
        self.last_error_sum = 0.0             # sum of C_i of the last density pass [-]
        self.last_error_count = 0             # the particles that pass summed (emitters, sinks: it changes)
        self.last_iteration_correction = 0.0  # largest |dx_i| of the last correction [m]
        self.last_drift = 0.0                 # largest distance of x* from where neighbours were searched [m]
        self.last_stabilization = 0
        self.last_trace = None
        self.grid_builds = 0
        rest = (m.smoothing.name, m.smoothing_length, m.spacing, m.particle_mass, m.rest_density, fluid_lattice(sim.scene))
        self.rest_denominator = rest_denominator(*rest)  # on the start's own lattice (cubic or fcc)
        self.epsilon = auto_epsilon(*rest) if p.relaxation is None else float(p.relaxation) * self.rest_denominator
        self.kappa = lattice_transport(*rest[:5], self.epsilon, rest[5])
        self.fluid_depth = fluid_depth(sim.sampled, m.gravity)
        w_dq, _ = evaluate(m.smoothing.name, np.array([[p.tensile_dq * m.smoothing_length, 0.0, 0.0]]),
                           m.smoothing_length)
        self.tensile_inv_w = 1.0 / float(w_dq[0])
        self.tensile_scale = 1.0 / self.rest_denominator
        self.margin = self.margin_per_spacing * m.spacing if neighbor_mode == "margin" else 0.0
        if self.lists:
            self.query_radius = m.support_radius  # pairs are filtered by H_s; the lists hold H_s + margin
            self.allowed_drift = 0.5 * self.margin  # two particles may each move margin / 2 towards each other
        else:
            self.query_radius = m.support_radius + self.margin
            self.allowed_drift = self.margin  # the query point is current, only the grid's points are old
        self._density_is_current = True
        self._offset_set = False  # pbf_constraint_offset holds zeros

    # --- stages ----------------------------------------------------------------------------
    def run_stabilize(self, sim, dt) -> None:
        """Pre-stabilisation (Macklin et al. 2014, section 4.4): an error already present at x (an
        over-dense start, or a step that hit max_iterations) is projected out of x itself, without
        turning into velocity; ``last_error_sum`` is the last density pass, at x. Then, for a step
        shorter than half the adaptive step (share s = ``error_share(dt)`` < 1), the constraint offset
        o_i = (1 - s) C_i(x): the solve corrects only the share s of the error left at x, so that it
        becomes a velocity of about C d / tau, not C d / dt (issue #36)."""
        f = sim.fields
        share = self.error_share(dt)
        if self._offset_set:  # the stabilisation and the test at x read the full error
            f["pbf_constraint_offset"].zero_()
            self._offset_set = False
        self.last_stabilization = 0
        self.last_max_correction = 0.0
        at_x = False
        # the last pass's own mean: a frame's emitters and sinks changed the count since (not sum / new count)
        if self.mean_error() > self.stabilize_factor * float(self.config.target_density_error):
            self._stabilize()
            at_x = True
        if share < 1.0:
            if not at_x:
                wp.copy(f["predicted_x"], f["particle_x"])
                self.reuse_neighbors()
                self.constraint_pass()  # C at x, all the offset needs
            self._run(_pbf.constraint_offset, self.model.fluid_count, [1.0 - share, f["pbf_constraint"]],
                      [f["pbf_constraint_offset"]], min_range=LIGHT_MIN_RANGE)
            self._offset_set = True

    def mean_error(self) -> float:
        """The mean C of the last density pass [-]: its sum over the particles it summed (0 without any)."""
        return self.last_error_sum / self.last_error_count if self.last_error_count else 0.0

    def _stabilize(self) -> None:
        """The projection of ``run_stabilize``: corrections at dt = 0 until the mean error at x is below the
        target (at most max_iterations); leaves the last density pass at x."""
        f = self.sim.fields
        target, max_it = float(self.config.target_density_error), int(self.config.max_iterations)
        # re-evaluate at x (the last pass may belong to another state, e.g. a watchdog retry)
        wp.copy(f["predicted_x"], f["particle_x"])
        self.build_neighbors()
        self.density_pass()
        err = self.mean_error()
        it = 0
        while err > target and it < max_it:
            self.correction(0.0)
            it += 1
            self.refresh_neighbors()
            self.density_pass()
            err = self.mean_error()
            self.last_max_correction = max(self.last_max_correction, self.last_iteration_correction)
        wp.copy(f["particle_x"], f["predicted_x"])
        self.last_stabilization = it

    def run_predict(self, sim, dt) -> None:
        m, f = self.model, sim.fields
        self._run(_pbf.predict_positions, m.fluid_count, [wp.vec3(*m.gravity), float(dt), f["particle_x"]],
                  [f["particle_v"], f["predicted_x"], f["boundary_force"]], min_range=LIGHT_MIN_RANGE)
        if self.with_bodies:
            self._run(_pbf.clear_float, m.fluid_count, [], [self._term], min_range=LIGHT_MIN_RANGE)

    def run_neighbors(self, sim, dt) -> None:
        if self.lists:
            self.sort_neighbors()  # the fluid lists come with the density pass ("density")
        else:
            self.build_neighbors()

    def run_density(self, sim, dt) -> None:
        if self.lists:
            self.search_density_pass()
        else:
            self.density_pass()

    def run_solve(self, sim, dt) -> None:
        """Iterations as in SPlisHSPlasH: each one is a density pass (the "density" stage for the first)
        and a correction; the stop test reads the error of the iteration's density pass, so it costs no
        extra pass after the last correction (``finish_frame`` measures x)."""
        target = float(self.config.target_density_error)
        min_it, max_it = int(self.config.min_iterations), int(self.config.max_iterations)
        it = 0
        err = self.mean_error()  # from the "density" stage
        largest = 0.0
        trace = [] if self.trace else None
        while it < max_it and (it < min_it or err > target):
            if it > 0:
                self.refresh_neighbors()
                self.density_pass()
                err = self.mean_error()
            self.correction(dt)
            it += 1
            largest = max(largest, self.last_iteration_correction)
            if trace is not None:
                trace.append((err, self.last_iteration_correction))
        self.last_iterations = it
        self.last_density_error = err
        self.last_max_correction = max(largest, self.last_max_correction)
        self.last_trace = trace
        self._density_is_current = it == 0
        if self._needs_exact_grid and self.last_drift > 0:
            self.build_neighbors()  # later stages query the grid with the plain support radius

    def run_update(self, sim, dt) -> None:
        m, f = self.model, sim.fields
        self._run(_pbf.update_velocity, m.fluid_count, [wp.vec3(*m.gravity), float(dt), 1.0 / dt, f["predicted_x"]],
                  [f["particle_v"], f["particle_x"], f["particle_acceleration"]], min_range=LIGHT_MIN_RANGE)

    def stages(self) -> list[Stage]:
        sim, m, p = self.sim, self.model, self.config
        self._allocate()
        nb = "neighbor_lists" if self.lists else "fluid_grid"
        with_boundary = self._with_boundary_gradient
        boundary_reads = (("boundary_x", "boundary_volume") + (() if self.lists else ("boundary_grid",))
                          if with_boundary else ())
        passes = ("particle_density", "particle_lambda", "pbf_constraint") + (("pbf_pairs",) if self.lists else ())
        term = ("boundary_pressure_term",) if self.with_bodies else ()
        correction = ("predicted_x", "position_correction", "pbf_correction_size", "boundary_force") + term
        if self.lists:
            nl = self.nl
            neighbor_doc = (f"neighbour lists on x* within H_s + {self.margin / m.spacing:.3g} d = {nl.search_radius:.4g} m "
                            f"(capacities {nl.capacities}), rebuilt "
                            + ("before every density pass" if self.neighbor_mode == "rebuild"
                               else f"when x* drifts > {self.allowed_drift / m.spacing:.3g} d"))
        else:
            neighbor_doc = f"wp.HashGrid on x*, radius H_s = {m.support_radius:.4g} m ({self.neighbor_mode})"
        target = float(p.target_density_error)
        # the lists of moving boundary particles are rebuilt with the fluid's (neighbors, solve, stabilize)
        moving = ("moving_boundary_grid",) if self.with_bodies else ()
        stages = [
            Stage("stabilize", self.run_stabilize, reads=("particle_x",) + boundary_reads + moving,
                  updates=("particle_x", nb, "pbf_neighbor_x", "pbf_neighbor_slot", "pbf_constraint_offset") + passes + correction,
                  doc=f"when the last density pass read a mean error > {self.stabilize_factor:g}x the target: "
                      "project it out of x with density passes and corrections at dt = 0 (no velocity); for a "
                      "step under half the adaptive step, leave the share 1 - 2 dt / bound of the error at x "
                      "to later steps (constraint offset)"),
            Stage("predict", self.run_predict, reads=("particle_x",), updates=("particle_v", "predicted_x",
                                                                              "boundary_force") + term,
                  doc="v += dt g; x* = x + dt v; the step's boundary force starts at 0"),
            Stage("neighbors", self.run_neighbors, reads=("predicted_x",) + moving,
                  updates=(nb, "pbf_neighbor_x", "pbf_neighbor_slot"),
                  doc=neighbor_doc),
            Stage("density", self.run_density, reads=(nb, "predicted_x", "pbf_constraint_offset") + boundary_reads,
                  updates=passes + ((nb, "pbf_neighbor_slot") if self.lists else ()),
                  doc="density at x* (eq. 7" + (f" + {sim.boundary_terms.name} boundary" if with_boundary else "")
                      + "), C (eq. 17), lambda (eq. 19)"),
            Stage("solve", self.run_solve, reads=("particle_lambda", "pbf_constraint_offset") + boundary_reads + moving,
                  updates=(nb, "pbf_neighbor_x", "pbf_neighbor_slot") + passes + correction,
                  doc=f"iterations of [density pass +] Jacobi correction (eq. 18) until the pass reads mean C < "
                      f"{target:g} ({p.min_iterations}-{p.max_iterations} iterations), eps = {self.epsilon / self.rest_denominator:.3g} D0"
                      + (", s_corr" if p.tensile_correction else "")),
            Stage("update", self.run_update, reads=("predicted_x",), updates=("particle_v", "particle_x",
                                                                              "particle_acceleration"),
                  doc="v = (x* - x)/dt; x = x*"),
        ]
        # the non-pressure forces (``warp_sph.methods.force``) act on the new velocity after the projection
        # (Macklin & Mueller 2013, SPlisHSPlasH), with the neighbours found on x* (= x now)
        slot = ForceSlot("after_update", "list" if self.lists else "grid", "particle_x", gravity_in_velocity=True)
        after = sim.forces.stages(slot)
        # the grid variant queries H_s + margin during the solve; stages after it query H_s on a current grid
        self._needs_exact_grid = not self.lists and self.neighbor_mode == "margin" and bool(after)
        return stages + after

    def carried_fields(self) -> tuple[str, ...]:
        """Workspace fields that outlive a step (read by the next step's stabilisation check and stages)."""
        nb = "neighbor_lists" if self.lists else "fluid_grid"
        return ("predicted_x", nb, "pbf_neighbor_x", "pbf_neighbor_slot", "particle_density", "particle_lambda", "pbf_constraint",
                "pbf_constraint_offset",
                "position_correction", "pbf_correction_size", "boundary_force", "particle_acceleration") + (
            ("pbf_pairs",) if self.lists else ()) + (("boundary_pressure_term",) if self.with_bodies else ())

    # --- interface -------------------------------------------------------------------------
    def time_step_bounds(self, speed: float) -> list[TimeStepBound]:
        m = self.model
        cfl = self.sim.scene.time.cfl
        g = float(np.linalg.norm(m.gravity))
        frame_dt = self.sim.frame_dt
        v = max(speed + g * frame_dt, 1e-12)
        bounds = [TimeStepBound("velocity CFL", cfl * m.spacing / v,
                                f"cfl d / (v + |g| frame_dt) with cfl = {cfl:g}, d = {m.spacing:.4g} m, v = {speed:.3g} m/s, "
                                f"|g| frame_dt = {g * frame_dt:.3g} m/s", ("time.cfl",))]
        solve = self.solve_bound()
        if solve is not None:
            bounds.append(solve)
        return bounds

    def step_floor(self) -> TimeStepBound | None:
        """|g| dt^2 >= ulp(X) / 2, X the largest local coordinate (half the container, or the fluid's extent):
        PBF moves particles by positions, and a step whose gravity displacement |g| dt^2 is below the float32
        spacing of the positions loses the load to rounding: corrections come in whole ulps and the fluid
        gains energy (measured in a 0.6 m box: E rises at dt = 2e-5 s, |g| dt^2 = 0.13 ulp; steady at 3.9e-5 s,
        0.5 ulp). None without gravity."""
        m = self.model
        g = float(np.linalg.norm(m.gravity))
        if g <= 0.0:
            return None
        if m.container_lo is not None:
            extent = float(max(np.abs(m.container_lo).max(), np.abs(m.container_hi).max()))
        else:
            x = self.sim.fields["particle_x"].numpy()
            extent = 2.0 * float(np.abs(x).max()) if len(x) else 0.0
        if extent <= 0.0:
            return None
        ulp = float(np.spacing(np.float32(extent)))
        return TimeStepBound("float32 position resolution", float(np.sqrt(0.5 * ulp / g)),
                             f"|g| dt^2 >= ulp / 2 with ulp = {ulp:.3g} m, the float32 spacing of positions "
                             f"{extent:.3g} m from the local origin", ("time.fixed_dt",))

    def solve_bound(self) -> TimeStepBound | None:
        """dt <= d sqrt(2 kappa K eta / (|g| H)): the step whose hydrostatic load the solve carries in about
        K = ``pbf.target_iterations`` iterations. Each step gravity moves the fluid by |g| dt^2; with K
        Jacobi corrections of kappa d^2 dC/dz each (``lattice_transport``) the column settles into a
        linear density error of mean |g| H dt^2 / (2 kappa K d^2), which the stop test holds at eta
        (measured: 2.1, 3.6, 7.1, 15.2 iterations for columns of 10, 20, 40, 80 layers at dt = 4.6 ms,
        d = 0.05 m; 15.2 -> 4.4 -> 2.1 at dt / 2, dt / 4). None without gravity or with K = 0."""
        p, m = self.config, self.model
        k = float(p.target_iterations)
        g = float(np.linalg.norm(m.gravity))
        if k <= 0.0 or g <= 0.0 or self.fluid_depth <= 0.0 or self.kappa <= 0.0:
            return None
        eta = float(p.target_density_error)
        seconds = m.spacing * float(np.sqrt(2.0 * self.kappa * k * eta / (g * self.fluid_depth)))
        return TimeStepBound("pressure solve", seconds,
                             f"d sqrt(2 kappa K eta / (|g| H)) with d = {m.spacing:.4g} m, kappa = {self.kappa:.3g}, "
                             f"K = {k:g}, eta = {eta:g}, H = {self.fluid_depth:.3g} m",
                             ("pbf.target_iterations", "pbf.target_density_error"))

    def step_statistics(self) -> dict[str, float]:
        # density_error: the average error of the last iteration's density pass, before its correction
        return {"iterations": float(self.last_iterations), "density_error": self.last_density_error,
                "max_correction": self.last_max_correction, "stabilization_iterations": float(self.last_stabilization)}

    def finish_frame(self) -> None:
        """Density, lambda and error at the frame's positions x (= x*) for the statistics and the next
        step's stabilisation test: one pass per frame, not per step."""
        if not self._density_is_current:
            self.refresh_neighbors()
            self.density_pass()
            self._density_is_current = True

    def restore_arrays(self, arrays) -> None:
        """x* = x after the state was restored (the density refresh reads x*)."""
        wp.copy(self.sim.fields["predicted_x"], self.sim.fields["particle_x"])

    def refresh_density(self) -> None:
        """Density, lambda and C at the current positions (x* = x), e.g. after a resume or at the start; when a row
        overflowed (a start sampled denser than rest: the rows hold 1.3x the rest count), the lists grow and the pass
        runs again, so the start's density counts every pair (``NeighborLists.grow_to_fit``, as DFSPH's)."""
        self._density_at_x()
        if self.lists and self.nl.grow_to_fit():
            self._density_at_x()
        self._density_is_current = True

    def _density_at_x(self) -> None:
        wp.copy(self.sim.fields["predicted_x"], self.sim.fields["particle_x"])
        self.build_neighbors()
        self.density_pass()

    def instability_hint(self, rule: str, stage: str | None) -> str | None:
        p = self.config
        if rule in ("outside", "dense") and self.last_iterations >= int(p.max_iterations):
            return (f"the solve stopped at pbf.max_iterations = {p.max_iterations} with the density error "
                    f"{100 * self.last_density_error:.3g} % above the target: raise pbf.max_iterations, or lower "
                    f"pbf.target_iterations (now {p.target_iterations:g}) or time.cfl for smaller steps")
        if p.tensile_correction and rule in ("non_finite", "fast"):
            return (f"the tensile correction (pbf.tensile_k = {p.tensile_k:g}, pbf.tensile_n = {p.tensile_n}) may "
                    "dominate the pressure: lower pbf.tensile_k or set pbf.tensile_correction = false")
        return None

    def summary(self) -> dict:
        return {"rest_denominator": self.rest_denominator, "epsilon": self.epsilon, "kappa": self.kappa,
                "fluid_depth": self.fluid_depth,
                "search_radius": self.nl.search_radius if self.nl is not None else self.query_radius}
