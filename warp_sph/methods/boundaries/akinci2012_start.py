"""A start at rest density next to Akinci walls (issue #36): the sampled fluid relaxed, before the first
step, until no particle is over-dense.

The wall gap (``core.smoothing.wall_gap``) puts the first fluid layer at rest density over one flat wall
layer, but where walls meet the first layer sees two or three walls: a block in a box corner starts 0.79 %
over rest density at the corner and 0.26 % along the edges (r = 0.025 m, cubic kernel). Every solver turns
that into motion: DFSPH and PBF correct it as a velocity, a stiff WCSPH releases the elastic energy it
stores, about c_s^2 delta^2 / 2 per kg (7.44 J at c_s = 1000 m/s for a 0.3 m corner block, a third of its
energy). ``relax_start`` removes it with position-based density projections (PBF's correction, Macklin &
Mueller 2013 eq. 18, at rest: no velocity) over the fluid within 2 H_s of the static boundary particles,
in NumPy on the host, with the same kernel, calibrated mass and Akinci volumes V_b = 1 / sum_k W_bk as
the run:

    rho_i / rho0 = V sum_j W_ij + sum_b V_b W_ib,   C_i = max(rho_i / rho0 - 1, 0)
    lambda_i = -C_i / (|grad_i C_i|^2 + sum_j |V grad W_ij|^2)
    dx_i = sum_j V (lambda_i + lambda_j) grad W_ij + lambda_i sum_b V_b grad W_ib

A helper of the boundary method ``akinci2012.py`` (it registers nothing).
"""
from __future__ import annotations

import numpy as np

from ...core.smoothing import calibrated_mass, evaluate
from ...scene.sampling import PointGrid

#: largest over-density left at t = 0 [-] (DFSPH's default density target)
START_TOLERANCE = 5e-4
#: most projection rounds: the corner block (0.3 m) needs 5; in a 1 m block the excess spreads to the free
#: surface slowly (Jacobi), 0.79 % -> 0.25 % in one round, 0.08 % after 30
START_ROUNDS = 30


def point_pairs(query: np.ndarray, points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """All index pairs (i, j) with |query_i - points_j| < radius (cell hashing, vectorised)."""
    grid = PointGrid(points, radius)
    qc = np.floor(np.asarray(query, dtype=np.float64) / radius).astype(np.int64)
    rows, cols = [], []
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                keys = grid._keys(qc + np.array([dx, dy, dz]))
                lo = np.searchsorted(grid.sorted_keys, keys, side="left")
                count = np.searchsorted(grid.sorted_keys, keys, side="right") - lo
                total = int(count.sum())
                if total == 0:
                    continue
                first = np.cumsum(count) - count
                at = np.arange(total) - np.repeat(first, count) + np.repeat(lo, count)
                rows.append(np.repeat(np.arange(len(query)), count))
                cols.append(grid.order[at])
    if not rows:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    i, j = np.concatenate(rows), np.concatenate(cols)
    keep = np.linalg.norm(query[i] - points[j], axis=1) < radius
    return i[keep], j[keep]


def _sum(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Per-row sums of ``values`` (scalars or 3-vectors) grouped by ``index`` [n rows]."""
    if values.ndim == 1:
        return np.bincount(index, weights=values, minlength=n)
    return np.stack([np.bincount(index, weights=values[:, k], minlength=n) for k in range(values.shape[1])], axis=1)


def relax_start(scene, fluid_x: np.ndarray, boundary_x: np.ndarray,
                movable: np.ndarray | None = None) -> tuple[np.ndarray, int, float]:
    """Fluid positions [m] moved until no particle within reach of the walls reads more than START_TOLERANCE
    over rest density (at most START_ROUNDS rounds of the projection in the module docstring); returns
    (positions, rounds, largest over-density before) [m, -, -]. Positions farther than 2 H_s from every
    boundary particle, or where ``movable`` (bool per particle) is False, are not moved."""
    fluid_x = np.array(fluid_x, dtype=np.float64).reshape(-1, 3)
    boundary_x = np.asarray(boundary_x, dtype=np.float64).reshape(-1, 3)
    if not len(fluid_x) or not len(boundary_x):
        return fluid_x, 0, 0.0
    name, h, support = scene.smoothing_kernel, scene.smoothing_length, scene.support_radius
    from ...core.model import fluid_lattice

    volume = calibrated_mass(name, h, scene.spacing, 1.0, fluid_lattice(scene))  # m / rho0 [m^3]
    reach = PointGrid(boundary_x, 2.0 * support).nearest_distance(fluid_x, 2.0 * support) < 2.0 * support
    near = np.nonzero(reach if movable is None else reach & np.asarray(movable, dtype=bool))[0]
    if not len(near):
        return fluid_x, 0, 0.0
    bi, bk = point_pairs(boundary_x, boundary_x, support)
    w, _ = evaluate(name, boundary_x[bi] - boundary_x[bk], h)
    psi = 1.0 / np.bincount(bi, weights=w.astype(np.float64), minlength=len(boundary_x))  # Akinci V_b [m^3]
    w_self = float(evaluate(name, np.zeros((1, 3)), h)[0][0])
    n, first_error = len(near), 0.0
    lam_all = np.zeros(len(fluid_x))
    # pairs once: the rounds move particles by < 1 % of d, and W and grad W vanish at H_s
    fi, fj = point_pairs(fluid_x[near], fluid_x, support)
    other = near[fi] != fj
    fi, fj = fi[other], fj[other]
    ei, eb = point_pairs(fluid_x[near], boundary_x, support)
    for rounds in range(START_ROUNDS + 1):
        x = fluid_x[near]
        wf, gf = evaluate(name, x[fi] - fluid_x[fj], h)
        wb, gb = evaluate(name, x[ei] - boundary_x[eb], h)
        gf = volume * gf.astype(np.float64)
        gb = psi[eb, None] * gb.astype(np.float64)
        ratio = volume * (w_self + _sum(fi, wf.astype(np.float64), n)) + _sum(ei, psi[eb] * wb, n)
        c = np.maximum(ratio - 1.0, 0.0)
        if rounds == 0:
            first_error = float(c.max())
        if c.max() <= START_TOLERANCE or rounds == START_ROUNDS:
            return fluid_x, rounds, first_error
        grad_b = _sum(ei, gb, n)
        grad = _sum(fi, gf, n) + grad_b
        lam = -c / ((grad * grad).sum(axis=1) + _sum(fi, (gf * gf).sum(axis=1), n))
        lam_all[near] = lam
        dx = _sum(fi, (lam_all[near[fi]] + lam_all[fj])[:, None] * gf, n) + lam[:, None] * grad_b
        fluid_x[near] += dx
    return fluid_x, START_ROUNDS, first_error
