"""PBF's host-side calibration on a rest lattice (no kernel launches): the rest denominator D0 that
scales the relaxation epsilon, the Jacobi transport factor kappa and the fluid depth H that size the
pressure-solve time-step bound (``PbfSolver.solve_bound``); see ``pbf.py`` for the physics.

A helper of the solver ``pbf.py`` (it registers nothing; the registry imports it harmlessly).
"""
from __future__ import annotations

import numpy as np

from ...core.smoothing import evaluate, get_smoothing_kernel, lattice_offsets


def rest_denominator(smoothing: str, h: float, spacing: float, particle_mass: float, rest_density: float) -> float:
    """D0 = |grad_i C_i|^2 + sum_j |grad_j C_i|^2 [1/m^2] for an interior particle of a perfect
    cubic lattice at spacing d, with grad_j C_i = -(m/rho0) grad W_ij (physics notes 4.4; cubic
    h = d, m = rho0 d^3: d^2 D0 = 0.425)."""
    kernel = get_smoothing_kernel(smoothing)
    offsets = lattice_offsets(spacing, kernel.support_radius(h))
    _, g = evaluate(smoothing, offsets, h)
    g = g.astype(np.float64) * (particle_mass / rest_density)
    return float(np.dot(g.sum(0), g.sum(0)) + np.sum(g * g))


def lattice_transport(smoothing: str, h: float, spacing: float, particle_mass: float, rest_density: float,
                      epsilon: float) -> float:
    """kappa [-]: one Jacobi correction (eq. 18) of an interior rest-lattice particle under a constraint
    that grows linearly with height, C = c' z, moves it by dx_z = -kappa d^2 c' (lambda = -C/(D0 + eps),
    dx_i = sum_j V (lambda_i + lambda_j) grad W_ij). It sets how fast the solve carries the weight of
    a column down: cubic h = d, eps = 0: kappa = 2.40."""
    kernel = get_smoothing_kernel(smoothing)
    offsets = lattice_offsets(spacing, kernel.support_radius(h))  # x_j - x_i
    _, g = evaluate(smoothing, -offsets, h)                         # grad_i W_ij at x_ij = x_i - x_j
    volume = particle_mass / rest_density
    d0 = rest_denominator(smoothing, h, spacing, particle_mass, rest_density)
    return float(volume * np.sum(offsets[:, 2] * g[:, 2].astype(np.float64)) / ((d0 + epsilon) * spacing ** 2))


def fluid_depth(sampled, gravity) -> float:
    """The fluid's initial extent along gravity [m] (top particle to bottom particle, plus one spacing d);
    0 without gravity."""
    g = np.asarray(gravity, dtype=np.float64)
    gn = float(np.linalg.norm(g))
    x = np.asarray(sampled.fluid_x, dtype=np.float64).reshape(-1, 3)
    if gn == 0.0 or not len(x):
        return 0.0
    z = x @ (-g / gn)
    return float(z.max() - z.min()) + float(sampled.spacing)
