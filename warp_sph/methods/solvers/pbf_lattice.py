"""PBF's host-side calibration on the scene's rest lattice (cubic or fcc, ``fluid[].lattice``; no kernel
launches): the rest denominator D0 that scales an explicit relaxation, the default relaxation epsilon from
the Jacobi solve's symbol (``auto_epsilon``), the Jacobi transport factor kappa and the fluid depth H that
size the pressure-solve time-step bound (``PbfSolver.solve_bound``); see ``pbf.py`` for the physics.

A helper of the solver ``pbf.py`` (it registers nothing; the registry imports it harmlessly).
"""
from __future__ import annotations

import numpy as np

from ...core.smoothing import LATTICE_LAYER, evaluate, get_smoothing_kernel, lattice_offsets


def _scaled_gradients(smoothing: str, h: float, spacing: float, particle_mass: float, rest_density: float,
                      lattice: str) -> tuple[np.ndarray, np.ndarray]:
    """(x_j - x_i [m], V grad_i W_ij [1/m]) over the neighbours of an interior particle of the lattice, V = m / rho0."""
    kernel = get_smoothing_kernel(smoothing)
    offsets = lattice_offsets(spacing, kernel.support_radius(h), lattice)
    offsets = offsets[np.linalg.norm(offsets, axis=1) > 0.0]
    _, g = evaluate(smoothing, -offsets, h)
    return offsets.astype(np.float64), g.astype(np.float64) * (particle_mass / rest_density)


def rest_denominator(smoothing: str, h: float, spacing: float, particle_mass: float, rest_density: float,
                     lattice: str = "cubic") -> float:
    """D0 = |grad_i C_i|^2 + sum_j |grad_j C_i|^2 [1/m^2] for an interior particle of a perfect
    lattice ("cubic" or "fcc", nearest spacing d), with grad_j C_i = -(m/rho0) grad W_ij (physics notes
    4.4; cubic h = d, m = rho0 d^3: d^2 D0 = 0.425; the fcc lattice's is 1.72 times the cubic one's
    at the same mass)."""
    _, g = _scaled_gradients(smoothing, h, spacing, particle_mass, rest_density, lattice)
    return float(np.dot(g.sum(0), g.sum(0)) + np.sum(g * g))


def jacobi_symbol_max(smoothing: str, h: float, spacing: float, particle_mass: float, rest_density: float,
                      lattice: str = "cubic", grid: int = 12, rounds: int = 12) -> float:
    """A_max [1/m^2]: the largest A(q) = |sum_j V grad W_ij sin(q . x_ij)|^2 over the wave vectors q of the
    lattice's Brillouin zone, A the symbol of J J^T of the linearised density constraint (one PBF Jacobi
    iteration multiplies a constraint wave by 1 - A(q) / (D0 + eps)). A grid of ``grid``^3 waves, then
    ``rounds`` local searches around the best, each on a 5^3 grid half as wide (issue #31)."""
    x, g = _scaled_gradients(smoothing, h, spacing, particle_mass, rest_density, lattice)
    c = LATTICE_LAYER[lattice]
    s = 0.0 if lattice == "cubic" else 0.5
    a = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [s, s, c]]) * spacing   # primitive vectors (rows)
    b = 2.0 * np.pi * np.linalg.inv(a).T                                   # reciprocal: a_i . b_k = 2 pi delta_ik

    def symbol(frac: np.ndarray) -> np.ndarray:
        return np.sum((np.sin((frac @ b) @ x.T) @ g) ** 2, axis=1)

    f = np.arange(grid) / grid
    frac = np.stack(np.meshgrid(f, f, f, indexing="ij"), axis=-1).reshape(-1, 3)
    values = symbol(frac)
    best, top = frac[int(np.argmax(values))], float(values.max())
    step = 1.0 / grid
    local = np.stack(np.meshgrid(*[np.linspace(-1.0, 1.0, 5)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    for _ in range(rounds):
        frac = best + step * local
        values = symbol(frac)
        k = int(np.argmax(values))
        if values[k] > top:
            best, top = frac[k], float(values[k])
        step *= 0.5
    return top


def auto_epsilon(smoothing: str, h: float, spacing: float, particle_mass: float, rest_density: float,
                 lattice: str = "cubic") -> float:
    """The default relaxation eps = max(3/4 A_max - D0, 0) [1/m^2] (``pbf.relaxation`` absent): the Jacobi
    smoother's optimum for the short waves (A in [A_max / 2, A_max] multiplied by factors within +-1/3 per
    iteration, no wave by a factor below -1/2). With eps ~ 0 the worst wave (A_max / D0 = 2.8 cubic, 3.3 fcc,
    cubic kernel) is multiplied by -1.8 / -2.3 per iteration: the solve amplifies it (issue #31)."""
    d0 = rest_denominator(smoothing, h, spacing, particle_mass, rest_density, lattice)
    a_max = jacobi_symbol_max(smoothing, h, spacing, particle_mass, rest_density, lattice)
    return max(0.75 * a_max - d0, 0.0)


def lattice_transport(smoothing: str, h: float, spacing: float, particle_mass: float, rest_density: float,
                      epsilon: float, lattice: str = "cubic") -> float:
    """kappa [-]: one Jacobi correction (eq. 18) of an interior rest-lattice particle under a constraint
    that grows linearly with height, C = c' z, moves it by dx_z = -kappa d^2 c' (lambda = -C/(D0 + eps),
    dx_i = sum_j V (lambda_i + lambda_j) grad W_ij). It sets how fast the solve carries the weight of
    a column down: cubic h = d, eps = 0: kappa = 2.40."""
    offsets, g = _scaled_gradients(smoothing, h, spacing, particle_mass, rest_density, lattice)
    d0 = rest_denominator(smoothing, h, spacing, particle_mass, rest_density, lattice)
    return float(np.sum(offsets[:, 2] * g[:, 2]) / ((d0 + epsilon) * spacing ** 2))


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
