"""Weakly compressible SPH solver (Becker & Teschner 2007): its stages and its time-step bound.

Step: neighbours -> density (eq. 7/13) -> [XSPH, eq. 21] -> pressure (eq. 9 or Tait) ->
forces (eq. 10, 12 or 16, viscosity, friction eq. 22-24, gravity) -> semi-implicit Euler (eq. 11).
"""
from __future__ import annotations


import warp as wp

from ..kernels import integrate as _integrate
from ..kernels import wcsph as _wcsph
from ..core.launch import LIGHT_MIN_RANGE, launch
from .common import _neighbor_args, density_stage, neighbors_stage, xsph_stage
from ..core.step_graph import Stage


#: dt <= VISCOUS_FACTOR (H_s/2)^2 / nu for the explicit viscosity
VISCOUS_FACTOR = 0.0625


class WcsphSolver:
    """Explicit WCSPH. Time step: acoustic CFL dt <= cfl (H_s/2) / (c_s + v_max) and, with
    viscosity, dt <= 0.0625 (H_s/2)^2 / nu: Morris 1997's 0.125 h^2/nu halved, because the
    10-nu explicit form was measured unstable at 1.0x and stable at 0.8x of the Morris bound
    (tests/test_extremes.py, nu = 1 m^2/s column).

    Neighbours: lists built once per step and read by density, XSPH and forces (``lists = True``),
    or hash-grid queries in every pass (``lists = False``, the reference variant)."""

    name = "wcsph"

    def __init__(self, lists: bool = True):
        self.lists = lists

    def stages(self, sim) -> list[Stage]:
        m = sim.model
        n = m.fluid_count
        sim.allocate("particle_pressure", float)
        sim.allocate("particle_acceleration", wp.vec3)
        sim.allocate("boundary_force", wp.vec3)
        with_boundary = m.boundary_method != "none"
        with_viscosity = m.viscosity > 0.0
        with_friction = m.boundary_method == "akinci2012" and m.boundary_friction > 0.0
        pressure_kernel = _wcsph.pressure_kernel(m.equation_of_state)
        mirrored = sim.scene.wcsph.boundary_pressure == "mirrored"
        force_kernel = _wcsph.acceleration_kernel(m.smoothing.name, m.boundary_method, with_viscosity, with_friction,
                                                  mirrored, "list" if self.lists else "grid")

        gravity = wp.vec3(*m.gravity)
        neighbors = "neighbor_lists" if self.lists else "fluid_grid"

        def run_pressure(sim, dt):
            launch(pressure_kernel, n, [m.rest_density, m.stiffness, sim.fields["particle_density"]],
                   [sim.fields["particle_pressure"]], device=m.device, min_range=LIGHT_MIN_RANGE)

        def run_forces(sim, dt):
            f = sim.fields
            boundary_neighbors, fluid_neighbors = _neighbor_args(sim, self.lists)
            launch(force_kernel, n,
                   [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density,
                    gravity, m.viscosity, m.boundary_friction, m.speed_of_sound,
                    boundary_neighbors, m.boundary_x, m.boundary_volume,
                    fluid_neighbors, f["particle_x"], f["particle_v"], f["particle_density"], f["particle_pressure"]],
                   [f["particle_acceleration"], f["boundary_force"]], device=m.device)

        def run_integrate(sim, dt):
            f = sim.fields
            launch(_integrate.integrate_symplectic_euler, n, [f["particle_acceleration"], float(dt)],
                   [f["particle_v"], f["particle_x"]], device=m.device, min_range=LIGHT_MIN_RANGE)

        boundary_reads = ("boundary_x", "boundary_volume", "boundary_grid") if with_boundary else ()
        terms = ["pressure (eq. 10)"]
        if m.boundary_method == "akinci2012":
            terms.append("Akinci boundary pressure (" + ("mirrored" if mirrored else "eq. 16") + ")")
        if m.boundary_method == "penalty":
            terms.append("penalty boundary (eq. 12)")
        if with_viscosity:
            terms.append("viscosity")
        if with_friction:
            terms.append("boundary friction (eq. 22-24)")
        terms.append("gravity")
        stages = [neighbors_stage(sim, lists=self.lists), density_stage(sim, lists=self.lists)]
        if m.xsph > 0.0:
            stages.append(xsph_stage(sim, lists=self.lists))
        stages += [
            Stage("pressure", run_pressure, reads=("particle_density",), writes=("particle_pressure",),
                  doc=f"{m.equation_of_state} equation of state, K = {m.stiffness:.4g} Pa"),
            Stage("forces", run_forces,
                  reads=(neighbors, "particle_x", "particle_v", "particle_density", "particle_pressure") + boundary_reads,
                  writes=("particle_acceleration", "boundary_force"), doc=" + ".join(terms)),
            Stage("integrate", run_integrate, reads=("particle_acceleration",), updates=("particle_v", "particle_x"),
                  doc="semi-implicit Euler (eq. 11)"),
        ]
        return stages

    def time_step_bound(self, sim, max_speed: float, frame_dt: float) -> float:
        m = sim.model
        length = 0.5 * m.support_radius
        dt = sim.scene.time.cfl * length / (m.speed_of_sound + max_speed)
        if m.viscosity > 0:
            dt = min(dt, VISCOUS_FACTOR * length * length / m.viscosity)
        return dt

    def step_statistics(self, sim) -> dict:
        return {}
