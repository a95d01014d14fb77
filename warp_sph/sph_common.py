"""Stages shared by every solver: neighbour grid, density summation, XSPH."""
from __future__ import annotations

import warp as wp

from .kernels import density as _density
from .kernels import integrate as _integrate
from .launch import launch
from .step_graph import Stage


def neighbors_stage(sim) -> Stage:
    """Rebuild the fluid hash grid (cell = search radius = support radius H_s)."""

    def run(sim, dt):
        sim.fluid_grid.build(sim.fields["particle_x"])

    return Stage("neighbors", run, reads=("particle_x",), writes=("fluid_grid",),
                 doc=f"wp.HashGrid rebuild, radius H_s = {sim.model.support_radius:.4g} m")


def density_stage(sim, positions: str = "particle_x") -> Stage:
    """rho_i = m sum_j W_ij (+ sum_b Psi_b W_ib with Akinci boundaries), report eq. 7/13."""
    m = sim.model
    with_boundary = m.boundary_method == "akinci2012"
    kernel = _density.density_kernel(m.smoothing.name, with_boundary)
    sim.allocate("particle_density", float)

    def run(sim, dt):
        f = sim.fields
        launch(kernel, m.fluid_count,
               [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density,
                m.boundary_grid_id, m.boundary_x, m.boundary_volume, sim.fluid_grid.id, f[positions]],
               [f["particle_density"]], device=m.device)

    reads = ("fluid_grid", positions) + (("boundary_x", "boundary_volume", "boundary_grid") if with_boundary else ())
    return Stage("density", run, reads=reads, writes=("particle_density",),
                 doc="eq. 7" + (" + Akinci boundary eq. 13-15" if with_boundary else ""))


def xsph_stage(sim, positions: str = "particle_x") -> Stage:
    """XSPH velocity filter (report eq. 21) with factor eps = material.xsph [-]."""
    m = sim.model
    kernel = _integrate.xsph_kernel(m.smoothing.name)
    sim.allocate("velocity_correction", wp.vec3)

    def run(sim, dt):
        f = sim.fields
        launch(kernel, m.fluid_count,
               [m.particle_mass, m.smoothing_length, m.support_radius, m.xsph,
                sim.fluid_grid.id, f[positions], f["particle_v"], f["particle_density"]],
               [f["velocity_correction"]], device=m.device)
        launch(_integrate.add_velocity_correction, m.fluid_count, [f["velocity_correction"]],
               [f["particle_v"]], device=m.device)

    return Stage("xsph", run, reads=("fluid_grid", positions, "particle_density"),
                 writes=("velocity_correction",), updates=("particle_v",), doc=f"XSPH eq. 21, eps = {m.xsph}")
