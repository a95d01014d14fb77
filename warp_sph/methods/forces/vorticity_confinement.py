"""Vorticity confinement (Fedkiw, Stam & Jensen 2001; Macklin & Mueller 2013 eq. 15-16); kernels in
``kernels/vorticity_confinement.py``.

omega_i = sum_j (m/rho_j) grad_i W_ij x (v_j - v_i); eta_i = sum_j (m/rho_j) (|omega_j| - |omega_i|) grad_i W_ij;
a_i = eps v_ref (N_i x omega_i) [m/s^2] with N = eta/|eta| and v_ref the scene's reference speed, so the
strength eps is dimensionless. It puts back rotation that numerical diffusion removes: it adds energy and
conserves no momentum, an art knob, not physics. Works with every solver (an explicit force).

Scene: ``[[forces]] method = "vorticity_confinement"``, ``strength = 0.01``; or the older ``pbf.vorticity``
(with solver = "pbf"), which sets this force.
"""
from __future__ import annotations

import warp as wp

from ...core.launch import launch
from ...core.step_graph import Stage
from ...kernels import vorticity_confinement as _dev
from ...scene.parameters import Param
from ..force import Force, ForceSlot
from ..registry import register_force


@register_force
class VorticityConfinement(Force):
    """Vorticity confinement (module docstring)."""

    name = "vorticity_confinement"
    title = "vorticity confinement (Fedkiw et al. 2001, Macklin & Mueller 2013)"
    kind = "vorticity"
    mode = "explicit"
    stores_energy = True  # puts rotational energy in by design: the energy watchdog's rule is off
    legacy_keys = {"pbf.vorticity": "strength"}
    parameters = (
        Param("vorticity_confinement.strength", "float", "-", 0.01, "confinement strength eps: a = eps v_ref (N x omega) "
              "with v_ref the scene's reference speed (adds energy; 0.01-0.1 typical)", ge=0.0, le=100.0),
    )

    @classmethod
    def is_active(cls, config) -> bool:
        return config.strength > 0.0

    def stages(self, slot: ForceSlot) -> list[Stage]:
        m = self.model
        vort = _dev.vorticity_kernel(m.smoothing.name, slot.neighbors)
        conf = _dev.confinement_kernel(m.smoothing.name, slot.neighbors)
        self.sim.allocate("particle_vorticity", wp.vec3)
        eps = float(self.config.strength)
        positions, field = slot.positions, slot.acceleration

        def run(sim, dt):
            f = sim.fields
            nb = slot.neighbor_arg(sim)
            launch(vort, m.fluid_count, [m.particle_mass, m.smoothing_length, m.support_radius, nb, f[positions],
                                         f["particle_v"], f["particle_density"]], [f["particle_vorticity"]], device=m.device)
            launch(conf, m.fluid_count, [m.particle_mass, m.smoothing_length, m.support_radius, eps, m.reference_speed,
                                         nb, f[positions], f["particle_density"], f["particle_vorticity"]],
                   [f[field]], device=m.device)

        return [Stage("vorticity", run, reads=(slot.neighbor_field, positions, "particle_v", "particle_density"),
                      writes=("particle_vorticity",), updates=(field,),
                      doc=f"vorticity confinement, eps = {eps:g} (v_ref = {m.reference_speed:.3g} m/s)")]

    def instability_hint(self, rule: str, stage: str | None) -> str | None:
        if rule in ("fast", "non_finite"):
            return (f"vorticity confinement ({self.keypath}, strength {self.config.strength:g}) adds energy: lower "
                    "its strength")
        return None

    def summary(self) -> dict:
        return {"strength": float(self.config.strength)}
