"""Penalty boundary force (Becker & Teschner 2007, report eq. 12); device terms in ``kernels/penalty.py``.

Boundary particles push fluid particles within the support radius away with
B_R = ``penalty.strength`` c_s^2. They add nothing to the density or pressure, so every solver sees
the wall as an explicit force only: WCSPH in its force stage, PBF after its position update.
"""
from __future__ import annotations

import math

from ...kernels import penalty as _dev
from ...scene.parameters import Param
from ..boundary import BoundaryMethod
from ..registry import register_boundary
from ..solver import TimeStepBound


@register_boundary
class Penalty(BoundaryMethod):
    name = "penalty"
    title = "penalty force of boundary particles (Becker & Teschner 2007, eq. 12)"
    #: its force is a stiff spring: a resting tank at r = 0.05 m gains 2 % of its energy from it in the first
    #: frames, then sinks into it and stores 14-16 % there (measured for every solver; docs/extremes.md)
    stores_energy = True
    section_doc = "penalty boundary settings"
    parameters = (
        Param("penalty.strength", "float", "-", 0.02, "B_R / c_s^2: the force's strength relative to the "
              "squared speed of sound (Becker & Teschner 2007 use 0.02)", gt=0.0, le=10.0),
    )

    @property
    def strength(self) -> float:
        """B_R [m^2/s^2]."""
        return float(self.config.strength) * self.model.speed_of_sound ** 2

    def terms(self):
        return _dev.PENALTY

    def params(self):
        p = _dev.PenaltyParams()
        p.half_support = 0.5 * self.model.support_radius
        p.strength = self.strength
        return p

    def time_step_bounds(self, speed: float) -> list[TimeStepBound]:
        """An explicit spring of stiffness ~ B_R / h_b^2 per particle: dt <= cfl h_b / (sqrt(B_R) + v)."""
        m = self.model
        cfl = self.sim.scene.time.cfl
        h_b = 0.5 * m.support_radius
        wave = math.sqrt(self.strength)
        return [TimeStepBound("penalty wall", cfl * h_b / (wave + speed),
                              f"cfl h_b / (sqrt(B_R) + v) with cfl = {cfl:g}, h_b = H_s/2 = {h_b:.4g} m, "
                              f"sqrt(B_R) = {wave:.4g} m/s, v = {speed:.3g} m/s", ("penalty.strength", "time.cfl"))]

    def summary(self) -> dict:
        return {"penalty_strength": self.strength}
