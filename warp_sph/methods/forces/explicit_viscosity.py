"""Explicit viscosity (SPlisHSPlasH's 'standard' form; kernels in ``kernels/explicit_viscosity.py``).

a_i = 10 nu sum_j (2 m / (rho_i + rho_j)) (v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij [m/s^2],
nu kinematic [m^2/s]. Explicit, so it needs dt <= VISCOUS_FACTOR (H_s/2)^2 / nu: Morris et al. 1997's
0.125 h^2/nu halved, because the 10-nu form was measured unstable at 1.0x and stable at 0.8x of the
Morris bound (tests/test_extremes.py, nu = 1 m^2/s column). A viscosity whose bound would need more
than MAX_SUBSTEPS_PER_FRAME substeps per frame (or a fixed step above the bound) is refused when the
scene is loaded, naming the implicit method (Weiler et al. 2018), whose step does not shrink with nu.

Scene: ``[[forces]] method = "explicit_viscosity"``, ``viscosity = 0.01``; or the older
``material.viscosity``, which sets this force.
"""
from __future__ import annotations

import math

from ...core.launch import launch
from ...core.step_graph import Stage
from ...kernels import explicit_viscosity as _dev
from ...scene.parameters import Param
from ..force import Force, ForceSlot
from ..registry import register_force
from ..solver import TimeStepBound

#: dt <= VISCOUS_FACTOR (H_s/2)^2 / nu
VISCOUS_FACTOR = 0.0625
#: refuse a viscosity whose explicit bound needs more substeps per output frame than this
MAX_SUBSTEPS_PER_FRAME = 1000
#: the implicit viscosity a refusal names (``[[forces]] method = ...``)
IMPLICIT_METHOD = "weiler2018"


def viscous_step(support_radius: float, viscosity: float) -> float:
    """The explicit bound VISCOUS_FACTOR (H_s/2)^2 / nu [s] (inf for nu = 0)."""
    if viscosity <= 0.0:
        return math.inf
    length = 0.5 * support_radius
    return VISCOUS_FACTOR * length * length / viscosity


@register_force
class ExplicitViscosity(Force):
    """Explicit Laplacian viscosity (module docstring)."""

    name = "explicit_viscosity"
    title = "explicit viscosity (SPlisHSPlasH 'standard', Morris et al. 1997); low viscosity"
    kind = "viscosity"
    mode = "explicit"
    legacy_keys = {"material.viscosity": "viscosity"}
    parameters = (
        Param("explicit_viscosity.viscosity", "float", "m^2/s", 0.01, "kinematic viscosity nu (water 1e-6; a scene "
              "scaled s times up from a real one looks right with nu s^1.5); explicit: needs dt <= 0.0625 (H_s/2)^2 / nu, "
              f"refused above {MAX_SUBSTEPS_PER_FRAME} substeps per frame (use method = \"{IMPLICIT_METHOD}\")", ge=0.0),
    )

    @classmethod
    def is_active(cls, config) -> bool:
        return config.viscosity > 0.0

    @classmethod
    def validate_config(cls, scene, config, keypath: str, fail) -> None:
        """Refuse a viscosity whose step bound the run cannot afford: a fixed step above it, or more than
        MAX_SUBSTEPS_PER_FRAME substeps per frame; the message names the implicit method."""
        nu = float(config.viscosity)
        if nu <= 0.0:
            return
        bound = viscous_step(scene.support_radius, nu)
        key = cls.key_path(keypath, "viscosity")
        formula = f"0.0625 (H_s/2)^2/nu with H_s/2 = {0.5 * scene.support_radius:.4g} m, nu = {nu:g} m^2/s"
        implicit = f'[[forces]] method = "{IMPLICIT_METHOD}" (implicit viscosity, its step does not shrink with nu)'
        fixed = float(scene.time.fixed_dt)
        if fixed > bound * (1.0 + 1e-6):
            fail(key, f"the explicit viscous time-step bound {bound:.4g} s ({formula}) is below time.fixed_dt = "
                 f"{fixed:.4g} s; lower time.fixed_dt, lower the viscosity or use {implicit}")
        per_frame = (1.0 / float(scene.fps)) / max(bound, 1e-300)
        if fixed <= 0.0 and per_frame > MAX_SUBSTEPS_PER_FRAME:
            fail(key, f"{nu:g} m^2/s needs the explicit viscous time-step bound {bound:.3g} s ({formula}): "
                 f"{per_frame:.3g} substeps per frame, more than {MAX_SUBSTEPS_PER_FRAME}; use {implicit}, or at most "
                 f"{nu * MAX_SUBSTEPS_PER_FRAME / per_frame:.3g} m^2/s for the explicit method")

    def stages(self, slot: ForceSlot) -> list[Stage]:
        m = self.model
        kernel = _dev.viscosity_kernel(m.smoothing.name, slot.neighbors)
        nu = float(self.config.viscosity)
        positions = slot.positions
        field = slot.acceleration

        def run(sim, dt):
            f = sim.fields
            launch(kernel, m.fluid_count, [m.particle_mass, m.smoothing_length, m.support_radius, nu,
                                           slot.neighbor_arg(sim), f[positions], f["particle_v"], f["particle_density"]],
                   [f[field]], device=m.device)

        return [Stage("viscosity", run, reads=(slot.neighbor_field, positions, "particle_v", "particle_density"),
                      updates=(field,), doc=f"explicit viscosity, nu = {nu:g} m^2/s")]

    def time_step_bounds(self, speed: float) -> list[TimeStepBound]:
        nu = float(self.config.viscosity)
        length = 0.5 * self.model.support_radius
        return [TimeStepBound("viscous", viscous_step(self.model.support_radius, nu),
                              f"0.0625 (H_s/2)^2/nu with H_s/2 = {length:.4g} m, nu = {nu:g} m^2/s",
                              (self.key_path(self.keypath, "viscosity"),))]

    def instability_hint(self, rule: str, stage: str | None) -> str | None:
        if stage == "viscosity" and rule in ("non_finite", "fast"):
            return (f"explicit viscosity {self.config.viscosity:g} m^2/s ({self.keypath}) at its step bound: lower it or "
                    f'use [[forces]] method = "{IMPLICIT_METHOD}"')
        return None

    def summary(self) -> dict:
        return {"viscosity": float(self.config.viscosity),
                "time_step_bound": viscous_step(self.model.support_radius, float(self.config.viscosity))}
