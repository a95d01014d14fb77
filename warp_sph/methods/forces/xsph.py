"""The XSPH velocity filter (Monaghan 1989; report eq. 21); kernels in ``kernels/xsph.py``.

v_i += eps sum_j (m/rho_j) (v_j - v_i) W_ij: each particle's velocity moves towards its neighbours' mean.
Not a viscosity and not physical (its factor has no unit; it damps particle-scale jitter and, less,
every relative motion). A filter: it runs after the other forces of the slot.

Scene: ``[[forces]] method = "xsph"``, ``factor = 0.05``; or the older ``material.xsph``, which sets
this force.
"""
from __future__ import annotations

import warp as wp

from ...core.launch import LIGHT_MIN_RANGE, launch
from ...core.step_graph import Stage
from ...kernels import integrate as _integrate
from ...kernels import xsph as _dev
from ...scene.parameters import Param
from ..force import Force, ForceSlot
from ..registry import register_force


@register_force
class Xsph(Force):
    """XSPH (module docstring)."""

    name = "xsph"
    title = "XSPH velocity filter (Monaghan 1989)"
    kind = "filter"
    mode = "filter"
    legacy_keys = {"material.xsph": "factor"}
    parameters = (
        Param("xsph.factor", "float", "-", 0.05, "XSPH factor eps (report eq. 21): 0.01-0.1 damps particle jitter, "
              "more makes the fluid move as a block", ge=0.0, le=1.0),
    )

    @classmethod
    def is_active(cls, config) -> bool:
        return config.factor > 0.0

    def stages(self, slot: ForceSlot) -> list[Stage]:
        m = self.model
        kernel = _dev.xsph_kernel(m.smoothing.name, slot.neighbors)
        self.sim.allocate("velocity_correction", wp.vec3)
        eps = float(self.config.factor)
        positions = slot.positions

        def run(sim, dt):
            f = sim.fields
            launch(kernel, m.fluid_count, [m.particle_mass, m.smoothing_length, m.support_radius, eps,
                                           slot.neighbor_arg(sim), f[positions], f["particle_v"], f["particle_density"]],
                   [f["velocity_correction"]], device=m.device)
            launch(_integrate.add_velocity_correction, m.fluid_count, [f["velocity_correction"]], [f["particle_v"]],
                   device=m.device, min_range=LIGHT_MIN_RANGE)

        return [Stage("xsph", run, reads=(slot.neighbor_field, positions, "particle_density"),
                      writes=("velocity_correction",), updates=("particle_v",), doc=f"XSPH eq. 21, eps = {eps:g}")]

    def summary(self) -> dict:
        return {"factor": float(self.config.factor)}
