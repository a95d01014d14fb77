"""The XSPH velocity filter (Monaghan 1989; report eq. 21); kernels in ``kernels/xsph.py``.

v_i += eps sum_j (m/rho_j) (v_j - v_i) W_ij: each particle's velocity moves towards its neighbours' mean.
Not a viscosity and not physical (its factor has no unit; it damps particle-scale jitter and, less,
every relative motion). A filter: it runs after the other forces of the slot.

The filter acts once per step, so with a fixed factor its smoothing per second grows as 1 / dt: a solver
whose steps are 4.7x longer (DFSPH against WCSPH in the fcc tank at rest, docs/validation-notes.md) is damped
4.7x less. ``xsph.reference_step`` = tau > 0 makes eps the smoothing per tau: a step of dt runs
n = ceil(dt / tau) passes, each with eps_n = 1 - (1 - eps)^(dt / (n tau)), so that any steps spanning the
same time apply (1 - eps) per tau to a velocity difference the filter removes whole (exactly: a step of
n tau is n passes of eps, the same as n steps of tau).

Scene: ``[[forces]] method = "xsph"``, ``factor = 0.05``; or the older ``material.xsph``, which sets
this force.
"""
from __future__ import annotations

import math

import warp as wp

from ...core.launch import LIGHT_MIN_RANGE, launch
from ...core.step_graph import Stage
from ...kernels import integrate as _integrate
from ...kernels import xsph as _dev
from ...scene.parameters import Param
from ..force import Force, ForceSlot
from ..registry import register_force


def filter_passes(factor: float, reference_step: float, dt: float) -> tuple[int, float]:
    """(passes, factor of each pass) of the filter in a step of dt [s]: (1, factor) without a reference step
    (reference_step <= 0), else n = ceil(dt / reference_step) passes of 1 - (1 - factor)^(dt / (n
    reference_step)), which compound to (1 - factor)^(dt / reference_step)."""
    if reference_step <= 0.0 or dt <= 0.0:
        return 1, factor
    n = max(1, math.ceil(dt / reference_step - 1e-9))
    return n, 1.0 - (1.0 - factor) ** (dt / (n * reference_step))


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
        Param("xsph.reference_step", "float", "s", 0.0, "the step the factor is given for: a step dt runs "
              "ceil(dt / reference_step) passes whose factors compound to (1 - factor) per reference_step, so the "
              "smoothing per second does not depend on the solver's step (0: one pass of the factor per step, "
              "Monaghan's filter, whose smoothing per second grows as 1 / dt)", ge=0.0, le=1.0),
    )

    @classmethod
    def is_active(cls, config) -> bool:
        return config.factor > 0.0

    def stages(self, slot: ForceSlot) -> list[Stage]:
        m = self.model
        kernel = _dev.xsph_kernel(m.smoothing.name, slot.neighbors)
        self.sim.allocate("velocity_correction", wp.vec3)
        eps = float(self.config.factor)
        reference = float(self.config.reference_step)
        positions = slot.positions

        def run(sim, dt):
            f = sim.fields
            passes, factor = filter_passes(eps, reference, dt)
            for _ in range(passes):
                launch(kernel, m.fluid_count, [m.particle_mass, m.smoothing_length, m.support_radius, factor,
                                               slot.neighbor_arg(sim), f[positions], f["particle_v"],
                                               f["particle_density"]], [f["velocity_correction"]], device=m.device)
                launch(_integrate.add_velocity_correction, m.fluid_count, [f["velocity_correction"]], [f["particle_v"]],
                       device=m.device, min_range=LIGHT_MIN_RANGE)

        per = f" per {reference:g} s (ceil(dt / {reference:g} s) passes)" if reference > 0.0 else ""
        return [Stage("xsph", run, reads=(slot.neighbor_field, positions, "particle_density"),
                      writes=("velocity_correction",), updates=("particle_v",), doc=f"XSPH eq. 21, eps = {eps:g}{per}")]

    def summary(self) -> dict:
        return {"factor": float(self.config.factor), "reference_step": float(self.config.reference_step)}
