"""The shared "apply_forces" stage of the force family (``warp_sph.methods.force``): v += dt a_forces plus
the boundary method's non-pressure term, for solvers that correct velocities after it (DFSPH, PBF).
Kernel: ``kernels/force_apply.py``."""
from __future__ import annotations

import warp as wp

from ..core.launch import launch
from ..core.step_graph import Stage
from ..kernels import force_apply as _apply
from ..kernels import neighbors as _neighbors_dev
from .density import neighbor_args

#: the per-particle acceleration [m/s^2] explicit forces add into (read from the same v) before one v += dt a
FORCE_ACCELERATION = "force_acceleration"


def apply_stage(sim, slot, with_forces: bool, name: str = "apply_forces") -> Stage | None:
    """v += dt ``force_acceleration`` (when an explicit force wrote it) + dt a_boundary (the boundary
    method's force term, when it has one); None when neither. m a_boundary [N] goes to ``boundary_force``."""
    m = sim.model
    terms, params = sim.boundary_terms, sim.boundary_params
    with_force = terms is not None and terms.force is not None
    if not (with_forces or with_force):
        return None
    kernel = _apply.apply_kernel(m.smoothing.name, terms if with_force else None, with_forces, slot.neighbors)
    if not with_force:
        params = _neighbors_dev.NoBoundaryParams()  # the kernel is specialised without the boundary
    sim.allocate("boundary_force", wp.vec3)
    if with_forces:
        sim.allocate(FORCE_ACCELERATION, wp.vec3)
    positions = slot.positions

    def run(sim, dt):
        f = sim.fields
        bn, fn = neighbor_args(sim, slot.lists)
        launch(kernel, m.fluid_count,
               [m.particle_mass, m.smoothing_length, m.support_radius, float(dt), params, bn, m.boundary_x,
                m.boundary_v, m.boundary_volume, fn, f[positions], f["particle_density"],
                f[FORCE_ACCELERATION] if with_forces else f["particle_v"]],
               [f["particle_v"], f["boundary_force"]], device=m.device)

    moving = getattr(sim, "bodies", None) is not None  # boundary_v is a field: bodies move their particles
    boundary_reads = (("boundary_x", "boundary_volume") + (("boundary_v",) if moving else ())) if with_force else ()
    what = (["v += dt a_forces"] if with_forces else []) + ([f"{terms.name} boundary force"] if with_force else [])
    return Stage(name, run, reads=(slot.neighbor_field, positions, "particle_density") + boundary_reads
                 + ((FORCE_ACCELERATION,) if with_forces else ()), updates=("particle_v", "boundary_force"),
                 doc=" + ".join(what))
