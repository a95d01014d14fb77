"""Penalty boundary force (Becker & Teschner 2007, report eq. 12): the terms of ``kernels/boundary.py``.

Boundary particles push fluid particles within the support radius away along x_ib with
B_R = strength [m^2/s^2]; they add nothing to the density, so a solver sees the wall only as a force.
"""
import warp as wp

from .boundary import BoundaryTerms


@wp.struct
class PenaltyParams:
    """half_support h_b = H_s / 2 [m] (the force acts over q = r / h_b in [0, 2]); strength B_R [m^2/s^2]."""

    half_support: float
    strength: float


@wp.func
def penalty_weight(q: float) -> float:
    """Shape of the Becker & Teschner 2007 boundary force (report eq. 12, q = r/h_b in [0, 2])."""
    if q < 2.0 / 3.0:
        return 2.0 / 3.0
    if q < 1.0:
        return 2.0 * q - 1.5 * q * q
    if q < 2.0:
        t = 2.0 - q
        return 0.5 * t * t
    return 0.0


@wp.func
def penalty_force(params: PenaltyParams, b: int, x_ib: wp.vec3, v_ib: wp.vec3, grad_ib: wp.vec3, volume_b: float,
                  rho_i: float) -> wp.vec3:
    """a_i = (B_R / 2) weight(r / h_b) x_ib / r^2 [m/s^2] (eq. 12 with equal masses: m_b / (m_i + m_b) = 1/2)."""
    r = wp.length(x_ib)
    h_b = params.half_support
    if r > 1.0e-6 * h_b:
        return (0.5 * params.strength / r * penalty_weight(r / h_b) / r) * x_ib
    return wp.vec3(0.0)


PENALTY = BoundaryTerms("penalty", PenaltyParams, force=penalty_force, dissipative=False)
