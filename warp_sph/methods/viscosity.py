"""Shared: the explicit-viscosity time-step bound, and the non-pressure forces stage of implicit solvers.

Explicit viscosity (``material.viscosity`` nu [m^2/s], SPlisHSPlasH's 'standard' form) needs
dt <= VISCOUS_FACTOR (H_s/2)^2 / nu: Morris et al. 1997's 0.125 h^2/nu halved, because the 10-nu
form was measured unstable at 1.0x and stable at 0.8x of the Morris bound (tests/test_extremes.py,
nu = 1 m^2/s column).
"""
from __future__ import annotations

import warp as wp

from ..core.launch import LIGHT_MIN_RANGE, launch
from ..core.step_graph import Stage
from ..kernels import integrate as _integrate
from ..kernels import neighbors as _neighbors_dev
from ..kernels import viscosity as _viscosity
from .solver import TimeStepBound

#: dt <= VISCOUS_FACTOR (H_s/2)^2 / nu for the explicit viscosity
VISCOUS_FACTOR = 0.0625


def viscous_bounds(model) -> list[TimeStepBound]:
    """[the viscous bound] when the scene has viscosity, else []."""
    if model.viscosity <= 0.0:
        return []
    length = 0.5 * model.support_radius
    return [TimeStepBound("viscous", VISCOUS_FACTOR * length * length / model.viscosity,
                          f"0.0625 (H_s/2)^2/nu with H_s/2 = {length:.4g} m, nu = {model.viscosity:g} m^2/s",
                          ("material.viscosity",))]


def viscous_stage(sim, positions_field: str = "particle_x", lists: bool = True, name: str = "viscosity") -> Stage | None:
    """dv = dt (viscosity + the boundary method's non-pressure force) added to v (None when the scene has
    neither). The boundary force (m a_boundary [N]) is added to ``boundary_force``."""
    m = sim.model
    terms, params = sim.boundary_terms, sim.boundary_params
    with_viscosity = m.viscosity > 0.0
    with_force = terms is not None and terms.force is not None
    if not (with_viscosity or with_force):
        return None
    kernel = _viscosity.viscous_kernel(m.smoothing.name, terms if with_force else None, with_viscosity,
                                       "list" if lists else "grid")
    if not with_force:
        params = _neighbors_dev.NoBoundaryParams()  # the kernel is specialised without the boundary
    sim.allocate("viscous_dv", wp.vec3)
    sim.allocate("boundary_force", wp.vec3)

    def run(sim, dt):
        f = sim.fields
        if lists:
            nl = f["neighbor_lists"]
            bn, fn = nl.boundary, nl.fluid
        else:
            bn, fn = m.boundary_grid_id, sim.fluid_grid.id
        launch(kernel, m.fluid_count,
               [m.particle_mass, m.smoothing_length, m.support_radius, m.viscosity, float(dt), params,
                bn, m.boundary_x, m.boundary_v, m.boundary_volume, fn, f[positions_field], f["particle_v"],
                f["particle_density"]],
               [f["viscous_dv"], f["boundary_force"]], device=m.device)
        launch(_integrate.add_velocity_correction, m.fluid_count, [f["viscous_dv"]], [f["particle_v"]],
               device=m.device, min_range=LIGHT_MIN_RANGE)

    terms_doc = (["viscosity"] if with_viscosity else []) + ([f"{terms.name} boundary force"] if with_force else [])
    moving = getattr(sim, "bodies", None) is not None  # boundary_v is a field: bodies move their particles
    boundary_reads = ("boundary_x", "boundary_volume") + (("boundary_v",) if moving else ()) if with_force else ()
    return Stage(name, run, reads=("neighbor_lists" if lists else "fluid_grid", positions_field, "particle_density")
                 + boundary_reads, writes=("viscous_dv",), updates=("particle_v", "boundary_force"),
                 doc=" + ".join(terms_doc))
