"""Shared stage: vorticity confinement (Macklin & Mueller 2013 eq. 15-16), strength ``pbf.vorticity``."""
from __future__ import annotations

import warp as wp

from ..core.launch import LIGHT_MIN_RANGE, launch
from ..core.step_graph import Stage
from ..kernels import integrate as _integrate
from ..kernels import vorticity as _vorticity


def vorticity_stage(sim, strength: float, lists: bool = True) -> Stage:
    """omega_i = sum_j (m/rho_j) grad W_ij x v_ji; dv_i = dt strength v_ref (N x omega_i), N = grad|omega| / |grad|omega||."""
    m = sim.model
    kind = "list" if lists else "grid"
    vort = _vorticity.vorticity_kernel(m.smoothing.name, kind)
    conf = _vorticity.confinement_kernel(m.smoothing.name, kind)
    sim.allocate("particle_vorticity", wp.vec3)
    sim.allocate("vorticity_dv", wp.vec3)

    def run(sim, dt):
        f = sim.fields
        nb = f["neighbor_lists"].fluid if lists else sim.fluid_grid.id
        launch(vort, m.fluid_count, [m.particle_mass, m.smoothing_length, m.support_radius, nb,
                                     f["particle_x"], f["particle_v"], f["particle_density"]],
               [f["particle_vorticity"]], device=m.device)
        launch(conf, m.fluid_count, [m.particle_mass, m.smoothing_length, m.support_radius, float(strength),
                                     m.reference_speed, float(dt), nb, f["particle_x"], f["particle_density"],
                                     f["particle_vorticity"]],
               [f["vorticity_dv"]], device=m.device)
        launch(_integrate.add_velocity_correction, m.fluid_count, [f["vorticity_dv"]], [f["particle_v"]],
               device=m.device, min_range=LIGHT_MIN_RANGE)

    return Stage("vorticity", run, reads=("neighbor_lists" if lists else "fluid_grid", "particle_x", "particle_density"),
                 writes=("particle_vorticity", "vorticity_dv"), updates=("particle_v",),
                 doc=f"vorticity confinement, eps = {strength:g}")
