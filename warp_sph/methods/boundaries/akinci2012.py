"""Akinci et al. 2012 boundary particles (report eq. 13-16, 22-24); device terms in ``kernels/akinci2012.py``.

One layer of boundary particles on walls and obstacles, each with the volume V_b = 1 / sum_k W_bk of
its own layer (eq. 15, computed once in ``warp_sph.core.model``). The fluid sees them in its density
(rho0 sum_b V_b W_ib, eq. 13), in the pressure force (eq. 16, or mirrored) and, with
``material.boundary_friction`` sigma > 0, in the friction force (eq. 22-24); a moving body's own
``fluid_friction`` gives its particles their own sigma (a per-particle friction term).
"""
from __future__ import annotations

import warp as wp

from ...kernels import akinci2012 as _dev
from ..boundary import BoundaryMethod
from ..registry import register_boundary
from ..solver import TimeStepBound


@register_boundary
class Akinci2012(BoundaryMethod):
    name = "akinci2012"
    title = "Akinci et al. 2012 boundary particles (density, pressure and friction)"
    contributes_density = True

    @classmethod
    def sample(cls, scene):
        """The scene's particles (``BoundaryMethod.sample``); for a solver that asks for it
        (``Solver.relaxed_start``: WCSPH), with the fluid next to the static walls relaxed to rest density
        (``akinci2012_start.relax_start``: where walls meet, the flat-wall gap leaves the first layer up to
        0.8 % over-dense; blocks sampled with spacing_scale < 1, compressed on purpose, are left as they
        are). Adds
        ``sampled.start_rounds`` (projection rounds run) and ``sampled.start_error`` (the largest
        over-density before them) [-]."""
        import numpy as np

        from ..registry import solver
        from .akinci2012_start import relax_start

        sampled = super().sample(scene)
        sampled.start_rounds, sampled.start_error = 0, 0.0
        if not solver(scene.solver).relaxed_start:
            return sampled
        # a block sampled denser than the rest spacing (spacing_scale < 1) is a compressed start on purpose
        scales = np.array([float(b.spacing_scale) for b in scene.fluid] or [1.0])
        movable = scales[np.asarray(sampled.fluid_block, dtype=np.int64)] >= 1.0 - 1e-9
        sampled.fluid_x, sampled.start_rounds, sampled.start_error = relax_start(scene, sampled.fluid_x,
                                                                                 sampled.boundary_x, movable)
        return sampled

    def terms(self):
        m = self.model
        if m.boundary_particle_friction is not None:  # a moving body with its own fluid_friction
            return _dev.AKINCI2012_PARTICLE_FRICTION
        return _dev.AKINCI2012_FRICTION if m.boundary_friction > 0.0 else _dev.AKINCI2012

    def params(self):
        m = self.model
        p = _dev.AkinciParams()
        p.rest_density = m.rest_density
        p.friction = m.boundary_friction
        p.smoothing_length = m.smoothing_length
        p.speed_of_sound = m.speed_of_sound
        p.eps_h2 = 0.01 * m.smoothing_length * m.smoothing_length
        if m.boundary_particle_friction is not None:
            p.particle_friction = m.boundary_particle_friction
        else:
            if getattr(self, "_no_friction", None) is None:
                self._no_friction = wp.zeros(1, dtype=float, device=m.device)
            p.particle_friction = self._no_friction
        return p

    def time_step_bounds(self, speed: float) -> list[TimeStepBound]:
        """Explicit friction acts like a viscosity nu = sigma h c_s / 20 (10 nu m / rho of the viscosity
        form against Psi_b nu_b = m sigma h c_s / (2 rho) of eq. 24), so it needs the viscous bound
        0.0625 (H_s/2)^2 / nu."""
        m = self.model
        sigma = m.max_boundary_friction
        if sigma <= 0.0:
            return []
        nu = sigma * m.smoothing_length * m.speed_of_sound / 20.0
        length = 0.5 * m.support_radius
        keys = ("material.boundary_friction",) + (("bodies[].fluid_friction",) if sigma > m.boundary_friction else ())
        return [TimeStepBound("boundary friction", 0.0625 * length * length / nu,
                              f"0.0625 (H_s/2)^2 / nu_f with nu_f = sigma h c_s / 20 = {nu:.3g} m^2/s "
                              f"(sigma = {sigma:g}, h = {m.smoothing_length:.4g} m, "
                              f"c_s = {m.speed_of_sound:.4g} m/s)", keys)]
