"""Position-based fluids (Macklin & Mueller 2013; seed report section 4.5, eq. 17-20).

Step: predict (v += dt g, x* = x + dt v) -> neighbours on x* -> density and lambda at x* ->
solve (Jacobi corrections dx, eq. 18, until the average density error mean(max(rho/rho0 - 1, 0))
is below ``pbf.target_density_error``, between ``min_iterations`` and ``max_iterations``
corrections) -> update (v = (x* - x)/dt, x = x*) -> [viscosity and boundary friction] -> [XSPH]
-> [vorticity confinement].

Why the report's solver exploded (physics notes 4.4): dx ~ C grad C / |grad C|^2, so a
denominator sum_k |grad_k C_i|^2 that is too small gives a correction that is too large. Here
grad C uses V = m/rho0 (report eq. 20 with consistent units), and the relaxation epsilon is
dimensionless: eps = relaxation * D0, with D0 the denominator of an interior particle of a
rest lattice, computed once on the host from the same kernel (``rest_denominator``).

Neighbours: the fluid grid is rebuilt on x* before every density pass (``neighbor_mode =
"rebuild"``, the default), or built once per step and queried with the radius enlarged by a
margin (``"margin"``), rebuilt only when a particle drifted farther than the margin.
"""
from __future__ import annotations

import math

import numpy as np
import warp as wp

from .wcsph import VISCOUS_FACTOR
from .kernels import integrate as _integrate
from .kernels import pbf as _pbf
from .launch import launch
from .smoothing import evaluate, lattice_offsets
from .sph_common import xsph_stage
from .step_graph import Stage


def rest_denominator(smoothing: str, h: float, spacing: float, particle_mass: float, rest_density: float) -> float:
    """D0 = |grad_i C_i|^2 + sum_j |grad_j C_i|^2 [1/m^2] for an interior particle of a perfect
    cubic lattice at spacing d, with grad_j C_i = -(m/rho0) grad W_ij (physics notes 4.4; cubic
    h = d, m = rho0 d^3: d^2 D0 = 0.425)."""
    from .smoothing import get_smoothing_kernel

    kernel = get_smoothing_kernel(smoothing)
    offsets = lattice_offsets(spacing, kernel.support_radius(h))
    _, g = evaluate(smoothing, offsets, h)
    g = g.astype(np.float64) * (particle_mass / rest_density)
    return float(np.dot(g.sum(0), g.sum(0)) + np.sum(g * g))


class PbfSolver:
    """Iterative position-based pressure solver. Time step: velocity CFL
    dt <= cfl d / (v_max + |g| frame_dt) and, with viscosity, dt <= 0.0625 (H_s/2)^2 / nu."""

    name = "pbf"

    def __init__(self, neighbor_mode: str = "rebuild", margin: float = 0.25, max_step: float = 0.5):
        if neighbor_mode not in ("rebuild", "margin"):
            raise ValueError(f"neighbor_mode must be 'rebuild' or 'margin', got {neighbor_mode!r}")
        self.neighbor_mode = neighbor_mode
        self.margin_per_spacing = margin   # query margin in spacings d ("margin" mode)
        self.max_step_per_radius = max_step  # trust region: |dx_i| per iteration <= this * r (0: off)
        self.last_iterations = 0
        self.last_density_error = 0.0
        self.last_max_correction = 0.0
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

        sim.fields["predicted_x"] = wp.clone(sim.fields["particle_x"])  # x* = x until the first step
        sim.allocate("particle_density", float)
        sim.allocate("particle_lambda", float)
        sim.allocate("position_correction", wp.vec3)
        sim.allocate("boundary_force", wp.vec3)
        sim.allocate("particle_acceleration", wp.vec3)
        self._grid_x = wp.zeros(n, dtype=wp.vec3, device=dev)
        # per-iteration numbers read back in one copy: [sum of C_i, largest |dx_i| of the iteration]
        self._iteration_stats = wp.zeros(2, dtype=float, device=dev)
        self._error_sum = self._iteration_stats[0:1]
        self._max_correction = self._iteration_stats[1:2]
        self._max_drift = wp.zeros(1, dtype=float, device=dev)

        self.rest_denominator = rest_denominator(m.smoothing.name, m.smoothing_length, m.spacing,
                                                 m.particle_mass, m.rest_density)
        self.epsilon = float(p.relaxation) * self.rest_denominator
        w_dq, _ = evaluate(m.smoothing.name, np.array([[p.tensile_dq * m.smoothing_length, 0.0, 0.0]]),
                           m.smoothing_length)
        tensile_inv_w = 1.0 / float(w_dq[0])
        tensile_scale = 1.0 / self.rest_denominator
        margin = self.margin_per_spacing * m.spacing if self.neighbor_mode == "margin" else 0.0
        self.query_radius = m.support_radius + margin
        self.max_step = self.max_step_per_radius * m.particle_radius if self.max_step_per_radius > 0 else 1e30

        density_lambda = _pbf.density_lambda_kernel(m.smoothing.name, with_boundary)
        correction = _pbf.correction_kernel(m.smoothing.name, with_boundary, tensile)
        target = float(p.target_density_error)
        min_it, max_it = int(p.min_iterations), int(p.max_iterations)

        def build_grid(sim):
            f = sim.fields
            sim.fluid_grid.build(f["predicted_x"])
            self.grid_builds += 1
            if self.neighbor_mode == "margin":
                wp.copy(self._grid_x, f["predicted_x"])
                self._max_drift.zero_()

        def run_predict(sim, dt):
            f = sim.fields
            # pre-stabilisation (Macklin et al. 2014, section 4.4): an error already present at x
            # (an over-dense start, or a step that hit max_iterations) is projected out of x
            # itself, without turning into velocity; _error_sum holds the last density pass, at x
            err = float(self._error_sum.numpy()[0]) / n
            self.last_stabilization = 0
            self.last_max_correction = 0.0
            if err > self.stabilize_factor * target:
                # re-evaluate at x (the last pass may belong to another state, e.g. a watchdog retry)
                wp.copy(f["predicted_x"], f["particle_x"])
                build_grid(sim)
                run_density(sim, 0.0)
                err = float(self._error_sum.numpy()[0]) / n
                it = 0
                while err > target and it < max_it:
                    self._max_correction.zero_()
                    run_correction(sim, 0.0)
                    it += 1
                    build_grid(sim)
                    run_density(sim, 0.0)
                    s = self._iteration_stats.numpy()
                    err = float(s[0]) / n
                    self.last_max_correction = max(self.last_max_correction, float(s[1]))
                wp.copy(f["particle_x"], f["predicted_x"])
                self.last_stabilization = it
            launch(_pbf.predict_positions, n, [wp.vec3(*m.gravity), float(dt), f["particle_x"]],
                   [f["particle_v"], f["predicted_x"], f["boundary_force"]], device=dev)

        def run_neighbors(sim, dt):
            build_grid(sim)

        def run_density(sim, dt):
            f = sim.fields
            self._error_sum.zero_()
            launch(density_lambda, n,
                   [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, self.epsilon,
                    self.query_radius, m.boundary_grid_id, m.boundary_x, m.boundary_volume,
                    sim.fluid_grid.id, f["predicted_x"]],
                   [f["particle_density"], f["particle_lambda"], self._error_sum], device=dev)

        def run_correction(sim, dt):
            f = sim.fields
            launch(correction, n,
                   [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, self.query_radius,
                    float(p.tensile_k), int(p.tensile_n), tensile_inv_w, tensile_scale,
                    1.0 / (dt * dt) if dt > 0 else 0.0, self.max_step,
                    m.boundary_grid_id, m.boundary_x, m.boundary_volume,
                    sim.fluid_grid.id, f["predicted_x"], f["particle_lambda"]],
                   [f["position_correction"], f["boundary_force"], self._max_correction], device=dev)
            launch(_pbf.apply_correction, n, [f["position_correction"], self._grid_x],
                   [f["predicted_x"], self._max_drift], device=dev)

        self.run_correction = run_correction  # one Jacobi correction of x* (stage tests)

        def run_solve(sim, dt):
            it = 0
            err = float(self._error_sum.numpy()[0]) / n  # from the "density" stage
            largest = 0.0
            trace = [] if self.trace else None
            while True:
                if it >= max_it or (it >= min_it and err <= target):
                    break
                self._max_correction.zero_()
                run_correction(sim, dt)
                it += 1
                if self.neighbor_mode == "margin" and float(self._max_drift.numpy()[0]) > margin:
                    build_grid(sim)
                elif self.neighbor_mode == "rebuild":
                    build_grid(sim)
                run_density(sim, dt)
                s = self._iteration_stats.numpy()  # one host read per iteration
                err = float(s[0]) / n
                largest = max(largest, float(s[1]))
                if trace is not None:
                    trace.append((err, float(s[1])))
            self.last_iterations = it
            self.last_density_error = err
            self.last_max_correction = max(largest, self.last_max_correction)
            self.last_trace = trace
            if self.neighbor_mode == "margin" and self._needs_exact_grid and float(self._max_drift.numpy()[0]) > 0:
                build_grid(sim)  # later stages query with the plain support radius

        def run_update(sim, dt):
            f = sim.fields
            launch(_pbf.update_velocity, n, [wp.vec3(*m.gravity), 1.0 / dt, f["predicted_x"]],
                   [f["particle_v"], f["particle_x"], f["particle_acceleration"]], device=dev)

        boundary_reads = ("boundary_x", "boundary_volume", "boundary_grid") if with_boundary else ()
        stages = [
            Stage("predict", run_predict, reads=("particle_x",), updates=("particle_v", "particle_x"),
                  writes=("predicted_x", "boundary_force"),
                  doc="[pre-stabilise x when its error > 2x target, with the previous step's grid, "
                      "density and lambda]; v += dt g; x* = x + dt v"),
            Stage("neighbors", run_neighbors, reads=("predicted_x",), writes=("fluid_grid",),
                  doc=f"wp.HashGrid on x*, radius H_s = {m.support_radius:.4g} m ({self.neighbor_mode})"),
            Stage("density", run_density, reads=("fluid_grid", "predicted_x") + boundary_reads,
                  writes=("particle_density", "particle_lambda"),
                  doc="density at x* (eq. 7" + (" + Akinci eq. 13" if with_boundary else "")
                      + "), C (eq. 17), lambda (eq. 19)"),
            Stage("solve", run_solve, reads=("particle_density", "particle_lambda") + boundary_reads,
                  writes=("position_correction",),
                  updates=("predicted_x", "fluid_grid", "particle_density", "particle_lambda", "boundary_force"),
                  doc=f"Jacobi corrections (eq. 18) until mean C < {target:g} ({min_it}-{max_it} iterations), "
                      f"eps = {p.relaxation:g} D0" + (", s_corr" if tensile else "")),
            Stage("update", run_update, reads=("predicted_x",), updates=("particle_v", "particle_x"),
                  writes=("particle_acceleration",), doc="v = (x* - x)/dt; x = x*"),
        ]
        if with_viscosity or with_friction:
            viscous = _pbf.viscous_kernel(m.smoothing.name, with_viscosity, with_friction)
            sim.allocate("viscous_dv", wp.vec3)

            def run_viscous(sim, dt):
                f = sim.fields
                launch(viscous, n,
                       [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, m.viscosity,
                        m.boundary_friction, m.speed_of_sound, float(dt),
                        m.boundary_grid_id, m.boundary_x, m.boundary_volume,
                        sim.fluid_grid.id, f["particle_x"], f["particle_v"], f["particle_density"]],
                       [f["viscous_dv"], f["boundary_force"]], device=dev)
                launch(_integrate.add_velocity_correction, n, [f["viscous_dv"]], [f["particle_v"]], device=dev)

            terms = (["viscosity"] if with_viscosity else []) + (["boundary friction (eq. 22-24)"] if with_friction else [])
            stages.append(Stage("viscosity", run_viscous,
                                reads=("fluid_grid", "particle_x", "particle_density") + boundary_reads,
                                writes=("viscous_dv",), updates=("particle_v", "boundary_force"),
                                doc=" + ".join(terms)))
        if m.xsph > 0.0:
            stages.append(xsph_stage(sim))
        if with_vorticity:
            vort = _pbf.vorticity_kernel(m.smoothing.name)
            conf = _pbf.confinement_kernel(m.smoothing.name)
            sim.allocate("particle_vorticity", wp.vec3)
            sim.allocate("vorticity_dv", wp.vec3)

            def run_vorticity(sim, dt):
                f = sim.fields
                launch(vort, n, [m.particle_mass, m.smoothing_length, m.support_radius, sim.fluid_grid.id,
                                 f["particle_x"], f["particle_v"], f["particle_density"]],
                       [f["particle_vorticity"]], device=dev)
                launch(conf, n, [m.particle_mass, m.smoothing_length, m.support_radius, float(p.vorticity),
                                 m.reference_speed, float(dt), sim.fluid_grid.id, f["particle_x"],
                                 f["particle_density"], f["particle_vorticity"]],
                       [f["vorticity_dv"]], device=dev)
                launch(_integrate.add_velocity_correction, n, [f["vorticity_dv"]], [f["particle_v"]], device=dev)

            stages.append(Stage("vorticity", run_vorticity, reads=("fluid_grid", "particle_x", "particle_density"),
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
        return {"iterations": float(self.last_iterations), "density_error": self.last_density_error,
                "max_correction": self.last_max_correction, "stabilization_iterations": float(self.last_stabilization)}

    def checkpoint_arrays(self, sim) -> dict:
        return {}

    def restore_arrays(self, sim, npz) -> None:
        """x* = x after the runner restored the state (the density refresh reads x*)."""
        wp.copy(sim.fields["predicted_x"], sim.fields["particle_x"])
