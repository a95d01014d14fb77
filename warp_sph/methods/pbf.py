"""Position-based fluids (Macklin & Mueller 2013; seed report section 4.5, eq. 17-20).

Step: predict (v += dt g, x* = x + dt v) -> neighbours on x* -> density and lambda at x* ->
solve (iterations of a density pass and a Jacobi correction dx, eq. 18, as in SPlisHSPlasH:
until the average density error mean(max(rho/rho0 - 1, 0)) of the iteration's density pass is below
``pbf.target_density_error``, between ``min_iterations`` and ``max_iterations`` iterations) -> update (v = (x* - x)/dt, x = x*) -> [viscosity and boundary friction] -> [XSPH]
-> [vorticity confinement].

Why the report's solver exploded (physics notes 4.4): dx ~ C grad C / |grad C|^2, so a
denominator sum_k |grad_k C_i|^2 that is too small gives a correction that is too large. Here
grad C uses V = m/rho0 (report eq. 20 with consistent units), and the relaxation epsilon is
dimensionless: eps = relaxation * D0, with D0 the denominator of an interior particle of a
rest lattice, computed once on the host from the same kernel (``rest_denominator``).

Neighbours (``PbfSolver`` lists/neighbor_mode): lists built once per step on x* with the search
radius H_s + margin (``warp_sph.neighbors.NeighborLists``), read by every solver iteration and by
viscosity, XSPH and vorticity, rebuilt only when a particle drifted farther than margin / 2 (the
default); or the reference hash-grid variant, rebuilt before every density pass or queried with
H_s + margin. Sums and maxima over the particles are reduced in a fixed order (bitwise
reproducible on any thread count).
"""
from __future__ import annotations


import numpy as np
import warp as wp

from .wcsph import VISCOUS_FACTOR
from ..kernels import integrate as _integrate
from ..kernels import pbf as _pbf
from ..core.launch import LIGHT_MIN_RANGE, launch
from ..core.smoothing import evaluate, lattice_offsets
from .common import neighbor_lists, xsph_stage
from ..core.step_graph import Stage


#: default search margin of the neighbour lists [spacings d]: lists hold pairs within H_s + margin
#: and are rebuilt once a particle moved more than margin / 2 during the solve
LIST_MARGIN = 0.2


def rest_denominator(smoothing: str, h: float, spacing: float, particle_mass: float, rest_density: float) -> float:
    """D0 = |grad_i C_i|^2 + sum_j |grad_j C_i|^2 [1/m^2] for an interior particle of a perfect
    cubic lattice at spacing d, with grad_j C_i = -(m/rho0) grad W_ij (physics notes 4.4; cubic
    h = d, m = rho0 d^3: d^2 D0 = 0.425)."""
    from ..core.smoothing import get_smoothing_kernel

    kernel = get_smoothing_kernel(smoothing)
    offsets = lattice_offsets(spacing, kernel.support_radius(h))
    _, g = evaluate(smoothing, offsets, h)
    g = g.astype(np.float64) * (particle_mass / rest_density)
    return float(np.dot(g.sum(0), g.sum(0)) + np.sum(g * g))


class PbfSolver:
    """Iterative position-based pressure solver. Time step: velocity CFL
    dt <= cfl d / (v_max + |g| frame_dt) and, with viscosity, dt <= 0.0625 (H_s/2)^2 / nu.

    lists: neighbour lists (``warp_sph.neighbors.NeighborLists``) built on x* once per step with the
    search radius H_s + margin and read by every pass of the step (solver iterations, viscosity,
    XSPH, vorticity); rebuilt when a particle of x* drifted more than margin / 2 from where they
    were built (then no pair closer than H_s can be missing). ``lists=False``: hash-grid queries in
    every pass (the reference variant), grid rebuilt before every density pass ("rebuild") or
    queried with H_s + margin and rebuilt once a particle drifted more than the margin ("margin").
    neighbor_mode "rebuild" with lists: rebuilt before every density pass, no margin.
    margin [spacings d]; max_step [particle radii] caps |dx_i| per iteration (0: off).
    """

    name = "pbf"

    def __init__(self, neighbor_mode: str | None = None, margin: float | None = None, max_step: float = 0.5,
                 lists: bool = True):
        if neighbor_mode is None:
            neighbor_mode = "margin" if lists else "rebuild"
        if neighbor_mode not in ("rebuild", "margin"):
            raise ValueError(f"neighbor_mode must be 'rebuild' or 'margin', got {neighbor_mode!r}")
        self.lists = bool(lists)
        self.neighbor_mode = neighbor_mode
        if margin is None:
            margin = LIST_MARGIN if lists else 0.25
        self.margin_per_spacing = float(margin)  # search margin in spacings d ("margin" mode)
        self.max_step_per_radius = max_step  # trust region: |dx_i| per iteration <= this * r (0: off)
        self.last_iterations = 0
        self.last_density_error = 0.0
        self.last_max_correction = 0.0
        self.last_error_sum = 0.0             # sum of C_i of the last density pass [-]
        self.last_iteration_correction = 0.0  # largest |dx_i| of the last correction [m]
        self.last_drift = 0.0                 # largest distance of x* from where neighbours were searched [m]
        self.grid_builds = 0
        self.stabilize_factor = 2.0  # pre-stabilise when the error at x exceeds this times the target
        self.last_stabilization = 0
        self.trace = False          # record (density error, largest |dx|) per iteration in last_trace
        self.last_trace = None

    # --- stages ----------------------------------------------------------------------------
    def stages(self, sim) -> list[Stage]:
        m = sim.model
        p = sim.scene.pbf
        n = m.fluid_count
        dev = m.device
        with_boundary = m.boundary_method == "akinci2012"
        with_viscosity = m.viscosity > 0.0
        with_friction = with_boundary and m.boundary_friction > 0.0
        tensile = bool(p.tensile_correction)
        with_vorticity = p.vorticity > 0.0
        lists = self.lists
        kind = "list" if lists else "grid"
        neighbors_field = "neighbor_lists" if lists else "fluid_grid"

        sim.fields["predicted_x"] = wp.clone(sim.fields["particle_x"])  # x* = x until the first step
        sim.allocate("particle_density", float)
        sim.allocate("particle_lambda", float)
        sim.allocate("position_correction", wp.vec3)
        sim.allocate("boundary_force", wp.vec3)
        sim.allocate("particle_acceleration", wp.vec3)
        self._neighbor_x = wp.zeros(n, dtype=wp.vec3, device=dev)   # x* the neighbours were searched at
        self._constraint = wp.zeros(n, dtype=float, device=dev)      # C_i of the last density pass
        self._correction_size = wp.zeros(n, dtype=float, device=dev)  # |dx_i| of the last correction
        chunks = max(1, -(-n // _pbf.REDUCE_CHUNK))
        self._error_partial = wp.zeros(chunks, dtype=float, device=dev)
        self._correction_partial = wp.zeros((chunks, 2), dtype=float, device=dev)

        self.rest_denominator = rest_denominator(m.smoothing.name, m.smoothing_length, m.spacing,
                                                 m.particle_mass, m.rest_density)
        self.epsilon = float(p.relaxation) * self.rest_denominator
        w_dq, _ = evaluate(m.smoothing.name, np.array([[p.tensile_dq * m.smoothing_length, 0.0, 0.0]]),
                           m.smoothing_length)
        tensile_inv_w = 1.0 / float(w_dq[0])
        tensile_scale = 1.0 / self.rest_denominator
        margin = self.margin_per_spacing * m.spacing if self.neighbor_mode == "margin" else 0.0
        if lists:
            nl = neighbor_lists(sim, margin)
            self.query_radius = m.support_radius  # pairs are filtered by H_s; the lists hold H_s + margin
            allowed_drift = 0.5 * margin  # two particles may each move margin / 2 towards each other
        else:
            nl = None
            self.query_radius = m.support_radius + margin
            allowed_drift = margin  # the query point is current, only the grid's points are old
        self.max_step = self.max_step_per_radius * m.particle_radius if self.max_step_per_radius > 0 else 1e30

        if lists:
            # the density pass keeps its pairs (V grad W, neighbour, [W]) for the correction at the same x*
            density_lambda = _pbf.density_lambda_pairs_kernel(m.smoothing.name, with_boundary, tensile)
            correction = _pbf.correction_pairs_kernel(with_boundary, tensile)
            self._pairs = _pbf.PairCache()
            self._pairs.count = wp.zeros(n, dtype=wp.int32, device=dev)
            self._pairs.boundary_gradient = wp.zeros(n, dtype=wp.vec3, device=dev)
            self._pairs_capacity = 0
        else:
            density_lambda = _pbf.density_lambda_kernel(m.smoothing.name, with_boundary)
            correction = _pbf.correction_kernel(m.smoothing.name, with_boundary, tensile)
        target = float(p.target_density_error)
        min_it, max_it = int(p.min_iterations), int(p.max_iterations)

        def neighbor_args(sim):
            """(boundary_neighbors, fluid_neighbors) kernel arguments."""
            if lists:
                return nl.boundary, nl.fluid
            return m.boundary_grid_id, sim.fluid_grid.id

        def build_neighbors(sim):
            x = sim.fields["predicted_x"]
            if lists:
                nl.build(x)
            else:
                sim.fluid_grid.build(x)
            self.grid_builds += 1
            wp.copy(self._neighbor_x, x)
            self.last_drift = 0.0

        def refresh_neighbors(sim):
            """After a correction: rebuild where the neighbours may be incomplete."""
            if self.neighbor_mode == "rebuild" or self.last_drift > allowed_drift:
                build_neighbors(sim)

        def run_predict(sim, dt):
            f = sim.fields
            # pre-stabilisation (Macklin et al. 2014, section 4.4): an error already present at x
            # (an over-dense start, or a step that hit max_iterations) is projected out of x
            # itself, without turning into velocity; last_error_sum is the last density pass, at x
            err = self.last_error_sum / n
            self.last_stabilization = 0
            self.last_max_correction = 0.0
            if err > self.stabilize_factor * target:
                # re-evaluate at x (the last pass may belong to another state, e.g. a watchdog retry)
                wp.copy(f["predicted_x"], f["particle_x"])
                build_neighbors(sim)
                run_density(sim, 0.0)
                err = self.last_error_sum / n
                it = 0
                while err > target and it < max_it:
                    run_correction(sim, 0.0)
                    it += 1
                    refresh_neighbors(sim)
                    run_density(sim, 0.0)
                    err = self.last_error_sum / n
                    self.last_max_correction = max(self.last_max_correction, self.last_iteration_correction)
                wp.copy(f["particle_x"], f["predicted_x"])
                self.last_stabilization = it
            launch(_pbf.predict_positions, n, [wp.vec3(*m.gravity), float(dt), f["particle_x"]],
                   [f["particle_v"], f["predicted_x"], f["boundary_force"]], device=dev, min_range=LIGHT_MIN_RANGE)

        def run_neighbors(sim, dt):
            build_neighbors(sim)

        def pair_cache():
            """The PairCache, with rows as long as the fluid lists (which grow on overflow)."""
            capacity = nl.capacities[0]
            if capacity != self._pairs_capacity:
                self._pairs.index = wp.zeros((max(n, 1), capacity), dtype=wp.int32, device=dev)
                self._pairs.gradient = wp.zeros((max(n, 1), capacity), dtype=wp.vec3, device=dev)
                self._pairs.value = wp.zeros((max(n, 1), capacity) if tensile else (1, 1), dtype=float, device=dev)
                self._pairs_capacity = capacity
            return self._pairs

        def run_density(sim, dt):
            f = sim.fields
            boundary_neighbors, fluid_neighbors = neighbor_args(sim)
            if lists:
                launch(density_lambda, n,
                       [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, self.epsilon,
                        boundary_neighbors, m.boundary_x, m.boundary_volume, fluid_neighbors, f["predicted_x"]],
                       [f["particle_density"], f["particle_lambda"], self._constraint, pair_cache()], device=dev)
            else:
                launch(density_lambda, n,
                       [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, self.epsilon,
                        self.query_radius, boundary_neighbors, m.boundary_x, m.boundary_volume,
                        fluid_neighbors, f["predicted_x"]],
                       [f["particle_density"], f["particle_lambda"], self._constraint], device=dev)
            # sum of C_i in a fixed order: chunk sums on the device, their sum on the host (one read)
            launch(_pbf.sum_chunks, self._error_partial.shape[0], [_pbf.REDUCE_CHUNK, self._constraint],
                   [self._error_partial], device=dev)
            self.last_error_sum = float(self._error_partial.numpy().sum(dtype=np.float64))

        def run_correction(sim, dt):
            f = sim.fields
            boundary_neighbors, fluid_neighbors = neighbor_args(sim)
            inv_dt2 = 1.0 / (dt * dt) if dt > 0 else 0.0
            if lists:
                launch(correction, n,
                       [m.particle_mass, float(p.tensile_k), int(p.tensile_n), tensile_inv_w, tensile_scale,
                        inv_dt2, self.max_step, fluid_neighbors, self._pairs, f["particle_lambda"]],
                       [f["position_correction"], f["boundary_force"], self._correction_size], device=dev)
            else:
                launch(correction, n,
                       [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, self.query_radius,
                        float(p.tensile_k), int(p.tensile_n), tensile_inv_w, tensile_scale, inv_dt2, self.max_step,
                        boundary_neighbors, m.boundary_x, m.boundary_volume,
                        fluid_neighbors, f["predicted_x"], f["particle_lambda"]],
                       [f["position_correction"], f["boundary_force"], self._correction_size], device=dev)
            launch(_pbf.apply_correction, n, [f["position_correction"]], [f["predicted_x"]], device=dev, min_range=LIGHT_MIN_RANGE)
            launch(_pbf.max_correction_drift_chunks, self._correction_partial.shape[0],
                   [_pbf.REDUCE_CHUNK, self._correction_size, f["predicted_x"], self._neighbor_x],
                   [self._correction_partial], device=dev)
            s = self._correction_partial.numpy().max(axis=0)  # one read
            self.last_iteration_correction = float(s[0])
            self.last_drift = float(s[1])

        self.run_correction = run_correction  # one Jacobi correction of x* (stage tests)

        def run_solve(sim, dt):
            """Iterations as in SPlisHSPlasH: each one is a density pass (the "density" stage for the
            first) and a correction; the stop test reads the error of the iteration's density pass,
            so it costs no extra pass after the last correction (``finish_frame`` measures x)."""
            it = 0
            err = self.last_error_sum / n  # from the "density" stage
            largest = 0.0
            trace = [] if self.trace else None
            while it < max_it and (it < min_it or err > target):
                if it > 0:
                    refresh_neighbors(sim)
                    run_density(sim, dt)
                    err = self.last_error_sum / n
                run_correction(sim, dt)
                it += 1
                largest = max(largest, self.last_iteration_correction)
                if trace is not None:
                    trace.append((err, self.last_iteration_correction))
            self.last_iterations = it
            self.last_density_error = err
            self.last_max_correction = max(largest, self.last_max_correction)
            self.last_trace = trace
            self._density_is_current = it == 0
            if not lists and self.neighbor_mode == "margin" and self._needs_exact_grid and self.last_drift > 0:
                build_neighbors(sim)  # later stages query the grid with the plain support radius

        def finish_frame(sim):
            """Density, lambda and error at the frame's positions x (= x*) for the statistics and the
            next step's pre-stabilisation test: one pass per frame, not per step."""
            if not self._density_is_current:
                refresh_neighbors(sim)
                run_density(sim, 0.0)
                self._density_is_current = True

        self.finish_frame = finish_frame
        self._density_is_current = True

        def run_update(sim, dt):
            f = sim.fields
            launch(_pbf.update_velocity, n, [wp.vec3(*m.gravity), 1.0 / dt, f["predicted_x"]],
                   [f["particle_v"], f["particle_x"], f["particle_acceleration"]], device=dev, min_range=LIGHT_MIN_RANGE)

        boundary_reads = ("boundary_x", "boundary_volume", "boundary_grid") if with_boundary else ()
        if lists:
            neighbor_doc = (f"neighbour lists on x* within H_s + {margin / m.spacing:.3g} d = {nl.search_radius:.4g} m "
                            f"(capacities {nl.capacities}), rebuilt "
                            + ("before every density pass" if self.neighbor_mode == "rebuild"
                               else f"when x* drifts > {allowed_drift / m.spacing:.3g} d"))
        else:
            neighbor_doc = f"wp.HashGrid on x*, radius H_s = {m.support_radius:.4g} m ({self.neighbor_mode})"
        stages = [
            Stage("predict", run_predict, reads=("particle_x",), updates=("particle_v", "particle_x"),
                  writes=("predicted_x", "boundary_force"),
                  doc="[pre-stabilise x when its error > 2x target, with the previous step's neighbours, "
                      "density and lambda]; v += dt g; x* = x + dt v"),
            Stage("neighbors", run_neighbors, reads=("predicted_x",), writes=(neighbors_field,), doc=neighbor_doc),
            Stage("density", run_density, reads=(neighbors_field, "predicted_x") + boundary_reads,
                  writes=("particle_density", "particle_lambda"),
                  doc="density at x* (eq. 7" + (" + Akinci eq. 13" if with_boundary else "")
                      + "), C (eq. 17), lambda (eq. 19)"),
            Stage("solve", run_solve, reads=("particle_density", "particle_lambda") + boundary_reads,
                  writes=("position_correction",),
                  updates=("predicted_x", neighbors_field, "particle_density", "particle_lambda", "boundary_force"),
                  doc=f"iterations of [density pass +] Jacobi correction (eq. 18) until the pass reads mean C < {target:g} "
                      f"({min_it}-{max_it} iterations), "
                      f"eps = {p.relaxation:g} D0" + (", s_corr" if tensile else "")),
            Stage("update", run_update, reads=("predicted_x",), updates=("particle_v", "particle_x"),
                  writes=("particle_acceleration",), doc="v = (x* - x)/dt; x = x*"),
        ]
        if with_viscosity or with_friction:
            viscous = _pbf.viscous_kernel(m.smoothing.name, with_viscosity, with_friction, kind)
            sim.allocate("viscous_dv", wp.vec3)

            def run_viscous(sim, dt):
                f = sim.fields
                boundary_neighbors, fluid_neighbors = neighbor_args(sim)
                launch(viscous, n,
                       [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, m.viscosity,
                        m.boundary_friction, m.speed_of_sound, float(dt),
                        boundary_neighbors, m.boundary_x, m.boundary_volume,
                        fluid_neighbors, f["particle_x"], f["particle_v"], f["particle_density"]],
                       [f["viscous_dv"], f["boundary_force"]], device=dev)
                launch(_integrate.add_velocity_correction, n, [f["viscous_dv"]], [f["particle_v"]], device=dev, min_range=LIGHT_MIN_RANGE)

            terms = (["viscosity"] if with_viscosity else []) + (["boundary friction (eq. 22-24)"] if with_friction else [])
            stages.append(Stage("viscosity", run_viscous,
                                reads=(neighbors_field, "particle_x", "particle_density") + boundary_reads,
                                writes=("viscous_dv",), updates=("particle_v", "boundary_force"),
                                doc=" + ".join(terms)))
        if m.xsph > 0.0:
            stages.append(xsph_stage(sim, lists=lists))
        if with_vorticity:
            vort = _pbf.vorticity_kernel(m.smoothing.name, kind)
            conf = _pbf.confinement_kernel(m.smoothing.name, kind)
            sim.allocate("particle_vorticity", wp.vec3)
            sim.allocate("vorticity_dv", wp.vec3)

            def run_vorticity(sim, dt):
                f = sim.fields
                _, fluid_neighbors = neighbor_args(sim)
                launch(vort, n, [m.particle_mass, m.smoothing_length, m.support_radius, fluid_neighbors,
                                 f["particle_x"], f["particle_v"], f["particle_density"]],
                       [f["particle_vorticity"]], device=dev)
                launch(conf, n, [m.particle_mass, m.smoothing_length, m.support_radius, float(p.vorticity),
                                 m.reference_speed, float(dt), fluid_neighbors, f["particle_x"],
                                 f["particle_density"], f["particle_vorticity"]],
                       [f["vorticity_dv"]], device=dev)
                launch(_integrate.add_velocity_correction, n, [f["vorticity_dv"]], [f["particle_v"]], device=dev, min_range=LIGHT_MIN_RANGE)

            stages.append(Stage("vorticity", run_vorticity, reads=(neighbors_field, "particle_x", "particle_density"),
                                writes=("particle_vorticity", "vorticity_dv"), updates=("particle_v",),
                                doc=f"vorticity confinement, eps = {p.vorticity:g}"))
        self._needs_exact_grid = len(stages) > 5
        return stages

    # --- solver interface ------------------------------------------------------------------
    def time_step_bound(self, sim, max_speed: float, frame_dt: float) -> float:
        m = sim.model
        g = float(np.linalg.norm(m.gravity))
        dt = sim.scene.time.cfl * m.spacing / max(max_speed + g * frame_dt, 1e-12)
        if m.viscosity > 0:
            length = 0.5 * m.support_radius
            dt = min(dt, VISCOUS_FACTOR * length * length / m.viscosity)
        return dt

    def step_statistics(self, sim) -> dict:
        # density_error: the average error of the last iteration's density pass, before its correction
        return {"iterations": float(self.last_iterations), "density_error": self.last_density_error,
                "max_correction": self.last_max_correction, "stabilization_iterations": float(self.last_stabilization)}

    def checkpoint_arrays(self, sim) -> dict:
        return {}

    def restore_arrays(self, sim, npz) -> None:
        """x* = x after the runner restored the state (the density refresh reads x*)."""
        wp.copy(sim.fields["predicted_x"], sim.fields["particle_x"])
