"""Surface tension and adhesion of Akinci, Akinci & Teschner 2013 (kernels in ``kernels/akinci2013.py``).

a_i = -sum_j K_ij [gamma m C(r_ij) x^_ij + gamma_k (n_i - n_j)] - beta rho0 sum_b V_b A(r_ib) x^_ib [m/s^2]
(cohesion + curvature between fluid particles, adhesion to the boundary particles), with normals
n_i = H sum_j (m/rho_j) grad W_ij and K_ij = 2 rho0/(rho_i + rho_j); research note forces.md 2.1.

Units. Akinci's gamma is not a surface tension: it multiplies a mass in the cohesion term and
nothing in the curvature term, so one number cannot be sigma for both. Here the user sets the
surface tension sigma [N/m] and the code uses
  gamma   = sigma / (SIGMA_PER_GAMMA rho0^2 H^2)                [m^4/(kg s^2)]  (cohesion)
  gamma_k = curvature CURVATURE_WEIGHT gamma rho0               [m/s^2]         (curvature)
  beta    = adhesion / (SIGMA_PER_GAMMA rho0^2 H^2)             [m^4/(kg s^2)]  (adhesion)
The accelerations then scale as gamma rho0 times a function of the geometry in units of H, so the
effective surface tension is sigma_eff = c gamma rho0^2 H^2 with c depending on the smoothing kernel,
H/d and (measured) the drop's size in particles. Cohesion alone has the surface energy
c = 4 int_0^1 C(q H) H^9 (32/pi)^-1 q^4 dq = 21/7040 = 0.00298 (a uniform half-space bonded by the
pair force, Kirkwood-Buff; research note forces.md 2.1); the curvature term is not derived from an energy
and, at the default weight, more than doubles it. SIGMA_PER_GAMMA is therefore measured: the undamped
l = 2 frequency of zero-gravity droplets (omega^2 = 8 sigma / (rho R^3), Rayleigh 1879;
``python -m warp_sph.benchmarks.surface_tension``, docs/surface_tension.md).
CURVATURE_WEIGHT = 1e-3 keeps SPlisHSPlasH's balance of the two terms at water's density (there
gamma_k = gamma in SI numbers at rho0 = 1000 kg/m^3); the scene key ``curvature`` scales it (0: cohesion
only, no normals pass; the calibration holds for 1).

Adhesion is set in the same units: ``adhesion`` = sigma gives beta = gamma (SPlisHSPlasH's defaults,
beta = 0.01 with gamma = 0.05, are adhesion = 0.2 sigma). It is a wall-attraction coefficient scaled
like sigma, not a measured work of adhesion.

Explicit, so the capillary waves of the shortest resolved wavelength need
dt <= sqrt(rho0 d^3 / (2 pi sigma)) (Brackbill, Kothe & Zemach 1992).

Scene: ``[[forces]] method = "akinci2013"``, ``surface_tension = 0.0728``, ``adhesion = 0.0``.
"""
from __future__ import annotations

import math

import warp as wp

from ...core.launch import launch
from ...core.step_graph import Stage
from ...kernels import akinci2013 as _dev
from ...scene.parameters import Param
from ..force import Force, ForceSlot
from ..registry import register_force
from ..solver import TimeStepBound

#: sigma_eff / (gamma rho0^2 H^2) [-] for support H = 2d (the default of every kernel) and curvature = 1: measured
#: on zero-g droplets of R = 6 and 7 d (DFSPH, cubic, sigma = 10 N/m, dt = 0.3 x the capillary bound; the odd
#: part of two oppositely kicked runs, damping removed): with 0.0107 they oscillated at 0.884 and 0.954 of
#: Rayleigh's frequency; 0.0107 x 0.919^2 (sigma_eff ~ omega^2 taken linear in gamma; the table in
#: docs/surface_tension.md, measured with this value, checks it). The droplet's size in particles still matters.
SIGMA_PER_GAMMA = 0.0090
#: gamma_k = CURVATURE_WEIGHT gamma rho0 (module docstring)
CURVATURE_WEIGHT = 1.0e-3


def akinci_coefficients(sigma: float, adhesion: float, rest_density: float, support_radius: float,
                        curvature: float = 1.0):
    """(gamma [m^4/(kg s^2)], gamma_k [m/s^2], beta [m^4/(kg s^2)]) for surface tension sigma [N/m],
    adhesion [N/m] and the curvature term's weight [-] (module docstring)."""
    scale = SIGMA_PER_GAMMA * rest_density ** 2 * support_radius ** 2
    gamma = sigma / scale
    return gamma, curvature * CURVATURE_WEIGHT * gamma * rest_density, adhesion / scale


def capillary_step(rest_density: float, spacing: float, sigma: float) -> float:
    """sqrt(rho0 d^3 / (2 pi sigma)) [s] (inf for sigma = 0)."""
    if sigma <= 0.0:
        return math.inf
    return math.sqrt(rest_density * spacing ** 3 / (2.0 * math.pi * sigma))


@register_force
class Akinci2013(Force):
    """Akinci 2013 surface tension with adhesion (module docstring)."""

    name = "akinci2013"
    title = "surface tension and adhesion (Akinci, Akinci & Teschner 2013)"
    kind = "surface_tension"
    mode = "explicit"
    stores_energy = True  # surface energy, which the energy watchdog does not count
    parameters = (
        Param("akinci2013.surface_tension", "float", "N/m", 0.0728, "surface tension sigma (water 0.0728 at 20 C); "
              "converted to Akinci's gamma with the calibration measured on a zero-g droplet; explicit: needs "
              "dt <= sqrt(rho0 d^3 / (2 pi sigma))", ge=0.0, le=1.0e6),
        Param("akinci2013.adhesion", "float", "N/m", 0.0, "attraction of the fluid to walls and bodies, scaled like "
              "surface_tension (adhesion = surface_tension gives Akinci's beta = gamma; 0: none, no wall pass)",
              ge=0.0, le=1.0e6),
        Param("akinci2013.curvature", "float", "-", 1.0, "weight of Akinci's curvature term (n_i - n_j): 1 = "
              "SPlisHSPlasH's balance with cohesion, 0 = cohesion only (no normals pass); the calibration of "
              "surface_tension holds for 1 (docs/surface_tension.md)", ge=0.0, le=100.0),
    )

    @classmethod
    def is_active(cls, config) -> bool:
        return config.surface_tension > 0.0 or config.adhesion > 0.0

    @property
    def coefficients(self) -> tuple[float, float, float]:
        m = self.model
        return akinci_coefficients(float(self.config.surface_tension), float(self.config.adhesion), m.rest_density,
                                   m.support_radius, float(self.config.curvature))

    def stages(self, slot: ForceSlot) -> list[Stage]:
        m = self.model
        gamma, gamma_k, beta = self.coefficients
        with_adhesion = beta > 0.0 and m.boundary_count > 0
        # the boundary force is produced before the slot in DFSPH (search) and PBF (prediction); WCSPH's force
        # stage writes it after its slot, so there the walls' share of adhesion is not added
        with_reaction = with_adhesion and (slot.name == "after_update" or not slot.gravity_in_velocity)
        with_curvature = gamma_k > 0.0
        normals = _dev.normals_kernel(m.smoothing.name, slot.neighbors) if with_curvature else None
        force = _dev.force_kernel(with_adhesion, with_reaction, slot.neighbors, with_curvature)
        self.sim.allocate("particle_normal", wp.vec3)
        positions, field = slot.positions, slot.acceleration
        no_force = wp.zeros(1, dtype=wp.vec3, device=m.device)

        def run(sim, dt):
            f = sim.fields
            nb = slot.neighbor_arg(sim)
            bn = slot.boundary_neighbor_arg(sim)
            if with_curvature:
                launch(normals, m.fluid_count, [m.particle_mass, m.smoothing_length, m.support_radius, nb,
                                                f[positions], f["particle_density"]], [f["particle_normal"]],
                       device=m.device)
            launch(force, m.fluid_count,
                   [m.particle_mass, m.rest_density, m.support_radius, gamma, gamma_k, beta, bn, m.boundary_x,
                    m.boundary_volume, nb, f[positions], f["particle_density"], f["particle_normal"]],
                   [f[field], f["boundary_force"] if with_reaction else no_force], device=m.device)

        boundary = ("boundary_x", "boundary_volume") if with_adhesion else ()
        if with_adhesion and not slot.lists:
            boundary += ("boundary_grid",)
        what = f"sigma = {self.config.surface_tension:g} N/m (gamma = {gamma:.4g})"
        if with_curvature:
            what += f", curvature weight {self.config.curvature:g} (gamma_k = {gamma_k:.4g})"
        if with_adhesion:
            what += f", adhesion = {self.config.adhesion:g} N/m (beta = {beta:.4g})"
        return [Stage("surface_tension", run, reads=(slot.neighbor_field, positions, "particle_density") + boundary,
                      writes=("particle_normal",) if with_curvature else (), updates=(field,) + (("boundary_force",) if with_reaction else ()),
                      doc=f"Akinci 2013 {'normals, cohesion + curvature' if with_curvature else 'cohesion'}"
                          f"{' + adhesion' if with_adhesion else ''}: {what}")]

    def time_step_bounds(self, speed: float) -> list[TimeStepBound]:
        sigma = float(self.config.surface_tension)
        if sigma <= 0.0:
            return []
        m = self.model
        return [TimeStepBound("capillary", capillary_step(m.rest_density, m.spacing, sigma),
                              f"sqrt(rho0 d^3/(2 pi sigma)) with rho0 = {m.rest_density:g} kg/m^3, d = {m.spacing:.4g} m, "
                              f"sigma = {sigma:g} N/m", (self.key_path(self.keypath, "surface_tension"),))]

    def instability_hint(self, rule: str, stage: str | None) -> str | None:
        if stage == "surface_tension" and rule in ("non_finite", "fast"):
            return (f"surface tension {self.config.surface_tension:g} N/m ({self.keypath}): a coarse resolution "
                    "clusters at the surface when sigma is large; lower it or refine the particles")
        return None

    def summary(self) -> dict:
        gamma, gamma_k, beta = self.coefficients
        m = self.model
        return {"surface_tension": float(self.config.surface_tension), "adhesion": float(self.config.adhesion),
                "curvature": float(self.config.curvature), "gamma": gamma, "curvature_gamma": gamma_k, "beta": beta,
                "time_step_bound": capillary_step(m.rest_density, m.spacing, float(self.config.surface_tension))}
