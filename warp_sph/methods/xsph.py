"""Shared stage: the XSPH velocity filter (report eq. 21), factor ``material.xsph``."""
from __future__ import annotations

import warp as wp

from ..core.launch import LIGHT_MIN_RANGE, launch
from ..core.step_graph import Stage
from ..kernels import integrate as _integrate
from ..kernels import xsph as _xsph


def xsph_stage(sim, lists: bool = True, neighbors: str | None = None) -> Stage:
    """v_i += eps sum_j (m/rho_j) (v_j - v_i) W_ij with eps = material.xsph [-]. neighbors: the workspace
    field that holds the neighbours (default: ``neighbor_lists`` or ``fluid_grid``)."""
    m = sim.model
    kernel = _xsph.xsph_kernel(m.smoothing.name, "list" if lists else "grid")
    sim.allocate("velocity_correction", wp.vec3)
    field = neighbors or ("neighbor_lists" if lists else "fluid_grid")

    def run(sim, dt):
        f = sim.fields
        nb = f["neighbor_lists"].fluid if lists else sim.fluid_grid.id
        launch(kernel, m.fluid_count,
               [m.particle_mass, m.smoothing_length, m.support_radius, m.xsph, nb, f["particle_x"], f["particle_v"],
                f["particle_density"]],
               [f["velocity_correction"]], device=m.device)
        launch(_integrate.add_velocity_correction, m.fluid_count, [f["velocity_correction"]], [f["particle_v"]],
               device=m.device, min_range=LIGHT_MIN_RANGE)

    return Stage("xsph", run, reads=(field, "particle_x", "particle_density"), writes=("velocity_correction",),
                 updates=("particle_v",), doc=f"XSPH eq. 21, eps = {m.xsph}")
