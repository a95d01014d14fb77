"""What a closed triangle mesh encloses: whether it is closed and consistently oriented, its volume,
and which points of a lattice lie inside it (``[[fluid]] shape = "mesh"``).

Host-side NumPy in float64; positions in metres.
"""
from __future__ import annotations

import numpy as np

from .meshes import TriangleMesh, merged_vertex_ids, points_inside


def closed_surface_problem(mesh: TriangleMesh, tolerance: float = 1e-9) -> str | None:
    """Why ``mesh`` is not a closed, consistently oriented surface, or None when it is.

    Closed: every edge is shared by exactly two triangles that traverse it in opposite directions
    (a -> b in one, b -> a in the other); degenerate triangles (two corners merged) are ignored.
    Vertices are merged as in ``meshes.merged_vertex_ids``.
    """
    t = merged_vertex_ids(mesh, tolerance)
    t = t[(t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 2] != t[:, 0])]
    if len(t) == 0:
        return "it has no non-degenerate triangle"
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    undirected, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    single = int(np.count_nonzero(counts == 1))
    if single:
        return f"it is open: {single} edges belong to one triangle only"
    many = int(np.count_nonzero(counts > 2))
    if many:
        return f"it is not manifold: {many} edges are shared by more than two triangles"
    _, dcounts = np.unique(directed, axis=0, return_counts=True)
    flipped = int(np.count_nonzero(dcounts > 1))
    if flipped:
        return (f"its triangles are not consistently oriented: {flipped} edges run the same way in both "
                "of their triangles")
    return None


def signed_volume(mesh: TriangleMesh) -> float:
    """Volume [m^3] enclosed by a closed mesh: sum over triangles of a . (b x c) / 6 (divergence
    theorem); positive when the triangles are counter-clockwise seen from outside."""
    return volume_and_centroid(mesh.vertices, mesh.triangles)[0]


def volume_and_centroid(vertices: np.ndarray, triangles: np.ndarray) -> tuple[float, np.ndarray]:
    """(signed volume [m^3], centroid [m]) of a closed triangle surface (sum of tetrahedra to the origin;
    positive when wound counter-clockwise seen from outside)."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    v6 = np.einsum("ij,ij->i", a, np.cross(b, c))
    volume = float(v6.sum() / 6.0)
    if volume == 0.0:
        return 0.0, np.zeros(3)
    centroid = (v6[:, None] * (a + b + c)).sum(axis=0) / (4.0 * v6.sum())
    return volume, centroid


def lattice_inside(mesh: TriangleMesh, xs: np.ndarray, ys: np.ndarray, zs: np.ndarray,
                   eps: float = 1e-7) -> np.ndarray:
    """Inside mask of the lattice xs x ys x zs [m] (shape (len(xs), len(ys), len(zs))) for a closed mesh.

    Ray parity along +z, one ray per (x, y) column: each triangle whose xy-projection holds the
    column strictly (every barycentric coordinate > eps) crosses it at z = u z_a + v z_b + w z_c;
    a point is inside when an odd number of crossings lies above it. A column that passes within
    eps of a projected edge or vertex (where parity would count a crossing twice or not at all)
    falls back to the winding number (``points_inside``) for its points. Cost: columns x triangles
    plus the fallback's points x triangles, instead of points x triangles.
    """
    xs, ys, zs = (np.asarray(a, dtype=np.float64) for a in (xs, ys, zs))
    a, b, c = mesh.triangle_corners()
    ambiguous = np.zeros((len(xs), len(ys)), dtype=bool)
    starts = np.zeros((len(xs), len(ys), len(zs) + 1), dtype=np.int64)
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    lo = np.minimum(np.minimum(a, b), c)
    hi = np.maximum(np.maximum(a, b), c)
    i0, i1 = np.searchsorted(xs, lo[:, 0], "left"), np.searchsorted(xs, hi[:, 0], "right")
    j0, j1 = np.searchsorted(ys, lo[:, 1], "left"), np.searchsorted(ys, hi[:, 1], "right")
    for t in np.nonzero((i1 > i0) & (j1 > j0))[0]:
        px, py = np.meshgrid(xs[i0[t]:i1[t]], ys[j0[t]:j1[t]], indexing="ij")
        if area[t] == 0.0:  # vertical triangle: a column in its plane is ambiguous, others miss it
            cross = (b[t, 0] - a[t, 0]) * (py - a[t, 1]) - (b[t, 1] - a[t, 1]) * (px - a[t, 0])
            cross2 = (c[t, 0] - a[t, 0]) * (py - a[t, 1]) - (c[t, 1] - a[t, 1]) * (px - a[t, 0])
            size = float(np.ptp(np.stack([a[t], b[t], c[t]]), axis=0).max()) ** 2
            ambiguous[i0[t]:i1[t], j0[t]:j1[t]] |= (np.abs(cross) <= eps * size) & (np.abs(cross2) <= eps * size)
            continue
        u = ((b[t, 0] - px) * (c[t, 1] - py) - (b[t, 1] - py) * (c[t, 0] - px)) / area[t]
        v = ((c[t, 0] - px) * (a[t, 1] - py) - (c[t, 1] - py) * (a[t, 0] - px)) / area[t]
        w = 1.0 - u - v
        m = np.minimum(np.minimum(u, v), w)
        ambiguous[i0[t]:i1[t], j0[t]:j1[t]] |= np.abs(m) <= eps
        hit = m > eps
        if not hit.any():
            continue
        zc = u[hit] * a[t, 2] + v[hit] * b[t, 2] + w[hit] * c[t, 2]
        k = np.searchsorted(zs, zc, "left")  # points 0..k-1 lie below the crossing
        ii, jj = np.nonzero(hit)
        np.add.at(starts, (ii + i0[t], jj + j0[t], 0), 1)
        np.add.at(starts, (ii + i0[t], jj + j0[t], k), -1)
    inside = np.cumsum(starts, axis=2)[:, :, :len(zs)] % 2 == 1
    if ambiguous.any():
        ci, cj = np.nonzero(ambiguous)
        pts = np.stack([np.repeat(xs[ci], len(zs)), np.repeat(ys[cj], len(zs)), np.tile(zs, len(ci))], axis=1)
        inside[ci, cj, :] = points_inside(mesh, pts).reshape(len(ci), len(zs))
    return inside
