"""Mesh and particle-set helpers for the surface tests (quality as numbers, notes/surface.md section 7)."""
from __future__ import annotations

import math

import numpy as np

RADIUS = 0.02
SPACING = 2.0 * RADIUS


def lattice_sphere(radius_in_r: float = 15.0, jitter: float = 0.0, seed: int = 1, center=(0.0, 0.0, 0.0)):
    """Lattice points (spacing 2 r) inside a sphere of radius_in_r r, jittered by up to jitter r."""
    n = int(math.ceil(radius_in_r / 2.0)) + 1
    k = np.arange(-n, n + 1)
    p = np.stack(np.meshgrid(k, k, k, indexing="ij"), -1).reshape(-1, 3) * SPACING
    p = p[np.linalg.norm(p, axis=1) < radius_in_r * RADIUS]
    rng = np.random.default_rng(seed)
    p = p + rng.uniform(-jitter, jitter, p.shape) * RADIUS
    return p + np.asarray(center)


def lattice_box(nx: int, ny: int, nz: int, jitter: float = 0.0, seed: int = 2):
    k = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"), -1).reshape(-1, 3)
    p = k * SPACING
    rng = np.random.default_rng(seed)
    return p + rng.uniform(-jitter, jitter, p.shape) * RADIUS


def edges(tris: np.ndarray) -> np.ndarray:
    return np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])


def is_closed_manifold(tris: np.ndarray) -> bool:
    """Every undirected edge in exactly two triangles, every directed edge once (consistent winding)."""
    e = edges(tris)
    _, counts = np.unique(np.sort(e, axis=1), axis=0, return_counts=True)
    return bool(np.all(counts == 2)) and len(np.unique(e, axis=0)) == len(e)


def euler_characteristic(verts: np.ndarray, tris: np.ndarray) -> int:
    n_edges = len(np.unique(np.sort(edges(tris), axis=1), axis=0))
    return len(np.unique(tris)) - n_edges + len(tris)


def components(tris: np.ndarray, n_vertices: int) -> np.ndarray:
    """Connected component label per triangle (label propagation with pointer jumping)."""
    label = np.arange(n_vertices)
    e = edges(tris)
    while True:
        new = label.copy()
        np.minimum.at(new, e[:, 0], label[e[:, 1]])
        np.minimum.at(new, e[:, 1], label[e[:, 0]])
        new = new[new]
        if np.array_equal(new, label):
            return label[tris[:, 0]]
        label = new


def volume(verts: np.ndarray, tris: np.ndarray, origin=None) -> float:
    v = verts.astype(np.float64) - (verts.astype(np.float64).mean(axis=0) if origin is None else origin)
    return float(np.einsum("ij,ij->i", v[tris[:, 0]], np.cross(v[tris[:, 1]], v[tris[:, 2]])).sum() / 6.0)


def mean_curvature_radius(verts: np.ndarray, tris: np.ndarray) -> float:
    """1 / (area-weighted mean of |H|), H from the cotangent Laplacian (Meyer et al. 2003):
    H n = (1 / 4 A) sum_j (cot a + cot b) (x_i - x_j), A the barycentric area."""
    v = verts.astype(np.float64)
    lap = np.zeros_like(v)
    area = np.zeros(len(v))
    for k in range(3):
        i, j, o = tris[:, k], tris[:, (k + 1) % 3], tris[:, (k + 2) % 3]
        a, b = v[i] - v[o], v[j] - v[o]
        cot = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(np.cross(a, b), axis=1), 1e-30)
        d = (v[i] - v[j]) * cot[:, None]
        np.add.at(lap, i, d)
        np.add.at(lap, j, -d)
    t_area = 0.5 * np.linalg.norm(np.cross(v[tris[:, 1]] - v[tris[:, 0]], v[tris[:, 2]] - v[tris[:, 0]]), axis=1)
    for k in range(3):
        np.add.at(area, tris[:, k], t_area / 3.0)
    h = np.linalg.norm(lap, axis=1) / (4.0 * np.maximum(area, 1e-30))
    return float(1.0 / (np.sum(h * area) / np.sum(area)))


def plane_fit_rms(points: np.ndarray) -> tuple[float, float]:
    """(rms, max) distance of points from their least-squares plane z = a x + b y + c."""
    a = np.c_[points[:, 0], points[:, 1], np.ones(len(points))]
    coef, *_ = np.linalg.lstsq(a, points[:, 2], rcond=None)
    res = (points[:, 2] - a @ coef) / math.sqrt(1.0 + coef[0] ** 2 + coef[1] ** 2)
    return float(np.sqrt(np.mean(res**2))), float(np.abs(res).max())


def _point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Distance from points p to triangles (a, b, c), row by row (Ericson, Real-Time Collision
    Detection 5.1.5: closest point by Voronoi region)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    denom = va + vb + vc
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        q = a + ab * v[:, None] + ac * w[:, None]  # interior
        # edges and vertices
        t_ab = np.clip(d1 / np.where(d1 - d3 != 0, d1 - d3, 1), 0, 1)
        t_ac = np.clip(d2 / np.where(d2 - d6 != 0, d2 - d6, 1), 0, 1)
        t_bc = np.clip((d4 - d3) / np.where((d4 - d3) + (d5 - d6) != 0, (d4 - d3) + (d5 - d6), 1), 0, 1)
    cand = [q, a + ab * t_ab[:, None], a + ac * t_ac[:, None], b + (c - b) * t_bc[:, None], a, b, c]
    inside = (va >= 0) & (vb >= 0) & (vc >= 0)
    dist = np.min(np.stack([np.linalg.norm(p - x, axis=1) for x in cand[1:]]), axis=0)
    return np.where(inside, np.minimum(np.linalg.norm(p - q, axis=1), dist), dist)


def distance_to_mesh(points: np.ndarray, verts: np.ndarray, tris: np.ndarray, reach: float) -> np.ndarray:
    """Distance from each point to the mesh (verts, tris), exact for distances below ``reach`` [m]
    (triangles are looked up in a grid of cells of size reach; farther points get >= reach)."""
    points = np.asarray(points, np.float64)
    v = np.asarray(verts, np.float64)
    lo = np.minimum(points.min(0), v.min(0)) - reach
    cell = lambda x: np.floor((x - lo) / reach).astype(np.int64)  # noqa: E731
    t_cells = cell(v[tris].min(axis=1)), cell(v[tris].max(axis=1))
    buckets: dict = {}
    for t in range(len(tris)):
        c0, c1 = t_cells[0][t], t_cells[1][t]
        for i in range(c0[0], c1[0] + 1):
            for j in range(c0[1], c1[1] + 1):
                for k in range(c0[2], c1[2] + 1):
                    buckets.setdefault((i, j, k), []).append(t)
    out = np.full(len(points), np.inf)
    pc = cell(points)
    rows, cols = [], []
    for n, c in enumerate(pc):
        near = set()
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                for dk in (-1, 0, 1):
                    near.update(buckets.get((c[0] + di, c[1] + dj, c[2] + dk), ()))
        rows += [n] * len(near)
        cols += list(near)
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    if len(rows):
        d = _point_triangle_distance(points[rows], v[tris[cols, 0]], v[tris[cols, 1]], v[tris[cols, 2]])
        np.minimum.at(out, rows, d)
    return np.minimum(out, reach)
