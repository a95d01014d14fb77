"""Triangle meshes for obstacles and fluid blocks: loading (OBJ, STL, PLY via meshio; USD via usd-core),
surface sampling at a particle spacing (of a mesh, or of a box: ``box_surface``), and an inside test.
What a closed mesh encloses (closedness, volume, the inside of a lattice) is in ``mesh_volume.py``.

Everything here is host-side NumPy in float64; positions are in metres, Z up.
"""
from __future__ import annotations

import contextlib
import io
import math
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..core.errors import SceneError

MESHIO_SUFFIXES = (".obj", ".stl", ".ply")
USD_SUFFIXES = (".usd", ".usda", ".usdc")
MESH_SUFFIXES = MESHIO_SUFFIXES + USD_SUFFIXES


@dataclass(frozen=True)
class TriangleMesh:
    """A triangle soup with shared vertices.

    vertices: positions [m], shape (vertex_count, 3), float64.
    triangles: vertex indices, shape (triangle_count, 3), int64.
    """

    vertices: np.ndarray
    triangles: np.ndarray

    def transformed(self, scale: float = 1.0, translate=(0.0, 0.0, 0.0)) -> "TriangleMesh":
        """The mesh with x -> scale * x + translate (scale [-], translate [m])."""
        v = self.vertices * float(scale) + np.asarray(translate, dtype=np.float64)
        return TriangleMesh(v, self.triangles)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) corners of the axis-aligned bounding box [m]."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def triangle_corners(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Corner positions a, b, c of every triangle [m], each of shape (triangle_count, 3)."""
        t = self.triangles
        return self.vertices[t[:, 0]], self.vertices[t[:, 1]], self.vertices[t[:, 2]]


def _fan(polygons) -> list[tuple[int, int, int]]:
    """Triangulate convex-ish polygons (index lists) as fans around their first vertex."""
    tris = []
    for poly in polygons:
        for k in range(1, len(poly) - 1):
            tris.append((int(poly[0]), int(poly[k]), int(poly[k + 1])))
    return tris


def _load_meshio(path: Path) -> TriangleMesh:
    import meshio

    # meshio prints warnings on odd files; keep them out of the user's terminal.
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        mesh = meshio.read(str(path))
    points = np.asarray(mesh.points, dtype=np.float64)
    tris: list[np.ndarray] = []
    for block in mesh.cells:
        data = block.data
        if block.type == "triangle":
            tris.append(np.asarray(data, dtype=np.int64).reshape(-1, 3))
        elif block.type in ("quad", "polygon") or block.type.startswith("polygon"):
            tris.append(np.asarray(_fan(np.asarray(data)), dtype=np.int64).reshape(-1, 3))
    if points.ndim != 2 or points.shape[0] == 0 or points.shape[1] not in (2, 3):
        raise ValueError("no vertices")
    if points.shape[1] == 2:
        points = np.concatenate([points, np.zeros((len(points), 1))], axis=1)
    triangles = np.concatenate(tris) if tris else np.zeros((0, 3), dtype=np.int64)
    return TriangleMesh(points, triangles)


def _load_usd(path: Path) -> TriangleMesh:
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise ValueError("usd-core cannot open it")
    # Only authored stage metadata counts: USD's fallbacks (centimetres, Y up) would silently
    # shrink or tip over a hand-written file meant in this project's metres and Z up.
    meters = UsdGeom.GetStageMetersPerUnit(stage) if stage.HasAuthoredMetadata("metersPerUnit") else 1.0
    y_up = stage.HasAuthoredMetadata("upAxis") and UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    cache = UsdGeom.XformCache()
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        points = mesh.GetPointsAttr().Get()
        counts = mesh.GetFaceVertexCountsAttr().Get()
        indices = mesh.GetFaceVertexIndicesAttr().Get()
        if points is None or counts is None or indices is None:
            continue
        xf = cache.GetLocalToWorldTransform(prim)
        pts = np.array([xf.Transform(Gf.Vec3d(*p)) for p in points], dtype=np.float64) * meters
        if y_up:  # the project is Z-up: (x, y, z)_Y-up -> (x, -z, y)_Z-up
            pts = np.stack([pts[:, 0], -pts[:, 2], pts[:, 1]], axis=1)
        polys, start = [], 0
        idx = list(indices)
        for c in counts:
            polys.append(idx[start:start + c])
            start += c
        return TriangleMesh(pts, np.asarray(_fan(polys), dtype=np.int64).reshape(-1, 3))
    raise ValueError("it holds no UsdGeom.Mesh")


def load_triangle_mesh(path: str | os.PathLike) -> TriangleMesh:
    """Load a triangle mesh [m] from .obj/.stl/.ply (meshio) or .usd/.usda/.usdc (first UsdGeom.Mesh).

    Polygons are triangulated as fans. USD meshes get their world transform applied, and the
    stage's metersPerUnit and a Y-up to Z-up rotation where the stage authors them (unauthored:
    metres, Z up, this project's convention). Raises SceneError naming the file when it is missing, has an
    unknown suffix, cannot be parsed, or holds no triangle.
    """
    path = Path(path)
    if not path.is_file():
        what = "is a folder; expected a mesh file" if path.is_dir() else "not found"
        raise SceneError(f"mesh file {str(path)!r} {what}")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise SceneError(f"mesh file {str(path)!r}: unknown suffix {suffix!r}; expected one of {', '.join(MESH_SUFFIXES)}")
    try:
        mesh = _load_usd(path) if suffix in USD_SUFFIXES else _load_meshio(path)
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - any parser failure means "not a mesh";
        # meshio calls sys.exit(1) when no reader accepts a file.
        msg = "no reader accepts it" if isinstance(exc, SystemExit) else (" ".join(str(exc).split()) or type(exc).__name__)
        raise SceneError(f"mesh file {str(path)!r} is not a readable triangle mesh ({msg[:120]})") from None
    tris = mesh.triangles
    if len(tris) == 0:
        raise SceneError(f"mesh file {str(path)!r} holds no triangles or polygons")
    if tris.min() < 0 or tris.max() >= len(mesh.vertices) or not np.all(np.isfinite(mesh.vertices)):
        raise SceneError(f"mesh file {str(path)!r} has out-of-range vertex indices or non-finite vertices")
    return mesh


#: Surface samples closer than this many spacings to an earlier sample are dropped. 0.8 keeps a
#: square lattice at spacing d intact and gives about the lattice's count (area / d^2, within 2 %
#: on the shipped cylinder) with holes of radius <= 0.83 d (square lattice: 0.71 d); 0.5 left the
#: thin side triangles of a cylinder twice as dense as the lattice.
SURFACE_MIN_DISTANCE = 0.8


def sample_surface(mesh: TriangleMesh, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points on the surface of ``mesh`` about ``spacing`` [m] apart, with the face normals there.

    Each triangle, taken from the corner a opposite its longest edge, gets the lattice
    a + (i/n1)(b - a) + (j/n2)(c - a), i/n1 + j/n2 <= 1, n = ceil(edge length / spacing) per leg;
    then every edge is sampled at ceil(length / spacing) intervals. The union, at least as dense
    as the spacing, is thinned greedily in that order so that no two points are closer than
    SURFACE_MIN_DISTANCE * spacing (shared edges, thin triangles). A square split into two
    triangles along a diagonal thus keeps a square lattice at spacing L / ceil(L / spacing).
    Returns (points (K, 3), unit normals (K, 3)), float64.
    """
    a, b, c = mesh.triangle_corners()
    normal = np.cross(b - a, c - a)
    area2 = np.linalg.norm(normal, axis=1)
    unit = normal / np.where(area2 > 0.0, area2, 1.0)[:, None]
    corners = np.stack([a, b, c], axis=1)  # (T, 3 corners, 3)
    opposite = np.stack([np.linalg.norm(c - b, axis=1), np.linalg.norm(a - c, axis=1),
                         np.linalg.norm(b - a, axis=1)], axis=1)
    first = np.argmax(opposite, axis=1)  # the corner opposite the longest edge
    inner, inner_n, edge_pts, edge_n = [], [], [], []
    for t in np.nonzero(area2 > 1e-30)[0]:
        o = corners[t, first[t]]
        e1 = corners[t, (first[t] + 1) % 3] - o
        e2 = corners[t, (first[t] + 2) % 3] - o
        n1 = max(1, int(math.ceil(np.linalg.norm(e1) / spacing - 1e-9)))
        n2 = max(1, int(math.ceil(np.linalg.norm(e2) / spacing - 1e-9)))
        i, j = np.meshgrid(np.arange(n1 + 1), np.arange(n2 + 1), indexing="ij")
        m = i * n2 + j * n1 <= n1 * n2
        p = o + (i[m] / n1)[:, None] * e1 + (j[m] / n2)[:, None] * e2
        inner.append(p)
        inner_n.append(np.broadcast_to(unit[t], p.shape))
        for k in range(3):
            p0, p1 = corners[t, k], corners[t, (k + 1) % 3]
            ne = max(1, int(math.ceil(np.linalg.norm(p1 - p0) / spacing - 1e-9)))
            s = np.arange(ne + 1)[:, None] / ne
            edge_pts.append(p0 + s * (p1 - p0))
            edge_n.append(np.broadcast_to(unit[t], (ne + 1, 3)))
    if not inner:
        return np.zeros((0, 3)), np.zeros((0, 3))
    points = np.concatenate(inner + edge_pts)
    normals = np.concatenate(inner_n + edge_n)
    keep_idx = greedy_thin(points, SURFACE_MIN_DISTANCE * spacing)
    return points[keep_idx], normals[keep_idx]


def box_surface(lo, hi, spacing: float, inward: bool, open_faces=()) -> tuple[np.ndarray, np.ndarray]:
    """Points on the six faces of the box lo..hi [m] on a square lattice about ``spacing`` apart.

    Each edge of length L gets n = max(1, round(L / spacing)) intervals; edge and corner points
    appear once. Returns (points (K, 3), unit normals (K, 3)); normals point into the box when
    ``inward`` (container walls), out of it otherwise (obstacles); the normalised sum at edges.
    open_faces: faces left out, as (axis, side) with side 0 at lo, 1 at hi (the edges they share with
    the other faces stay; those faces alone give their normals).
    """
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    n = np.maximum(1, np.round((hi - lo) / spacing)).astype(np.int64)
    faces = []
    for axis in range(3):
        a, b = [x for x in range(3) if x != axis]
        ia, ib = np.meshgrid(np.arange(n[a] + 1), np.arange(n[b] + 1), indexing="ij")
        for k, side in enumerate((0, n[axis])):
            if (axis, k) in open_faces:
                continue
            idx = np.zeros((ia.size, 3), dtype=np.int64)
            idx[:, axis] = side
            idx[:, a] = ia.ravel()
            idx[:, b] = ib.ravel()
            faces.append(idx)
    idx = np.unique(np.concatenate(faces), axis=0)
    points = lo + idx * ((hi - lo) / n)
    closed_lo = np.array([(axis, 0) not in open_faces for axis in range(3)])
    closed_hi = np.array([(axis, 1) not in open_faces for axis in range(3)])
    normals = ((idx == 0) & closed_lo).astype(np.float64) - ((idx == n) & closed_hi).astype(np.float64)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return points, (normals if inward else -normals)


def greedy_thin(points: np.ndarray, min_distance: float) -> np.ndarray:
    """Indices of a subset of ``points`` (in order) in which no two are closer than ``min_distance``.

    Greedy in input order: a point is kept when no earlier kept point lies within min_distance.
    """
    cell = float(min_distance)
    keys = np.floor(points / cell).astype(np.int64)
    grid: dict[tuple[int, int, int], list[int]] = {}
    kept: list[int] = []
    r2 = min_distance * min_distance
    offsets = [(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)]
    for idx in range(len(points)):
        kx, ky, kz = (int(k) for k in keys[idx])
        p = points[idx]
        close = False
        for dx, dy, dz in offsets:
            for q in grid.get((kx + dx, ky + dy, kz + dz), ()):
                d = points[q] - p
                if d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < r2:
                    close = True
                    break
            if close:
                break
        if not close:
            grid.setdefault((kx, ky, kz), []).append(idx)
            kept.append(idx)
    return np.asarray(kept, dtype=np.int64)


def winding_number(mesh: TriangleMesh, points: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Generalised winding number of a closed mesh at ``points`` (shape (N, 3)) [-].

    Sum of the solid angles of the triangles seen from each point over 4 pi (Van Oosterom &
    Strackee 1983): +-1 inside a closed surface (sign from the orientation), 0 outside, robust
    where a ray-parity test would hit an edge.
    """
    a, b, c = mesh.triangle_corners()
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(points))
    step = max(1, chunk * 64 // max(1, len(a)))
    for s in range(0, len(points), step):
        p = points[s:s + step, None, :]
        ra, rb, rc = a[None] - p, b[None] - p, c[None] - p
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (ra, rb, rc))
        num = np.einsum("ptk,ptk->pt", ra, np.cross(rb, rc))
        den = (la * lb * lc + np.einsum("ptk,ptk->pt", ra, rb) * lc
               + np.einsum("ptk,ptk->pt", rb, rc) * la + np.einsum("ptk,ptk->pt", rc, ra) * lb)
        out[s:s + step] = 2.0 * np.arctan2(num, den).sum(axis=1) / (4.0 * math.pi)
    return out


def points_inside(mesh: TriangleMesh, points: np.ndarray) -> np.ndarray:
    """Boolean mask of ``points`` inside the closed mesh (|winding number| > 0.5)."""
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    return np.abs(winding_number(mesh, points)) > 0.5


def merged_vertex_ids(mesh: TriangleMesh, tolerance: float = 1e-9) -> np.ndarray:
    """Triangle corners as merged vertex ids, shape (T, 3): vertices closer than ``tolerance`` times
    the mesh size are one vertex (files that repeat vertices per face)."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    size = float(np.ptp(v, axis=0).max()) if len(v) else 1.0
    keys = np.round(v / max(size * tolerance, 1e-300)).astype(np.int64)
    _, ids = np.unique(keys, axis=0, return_inverse=True)
    return ids.reshape(-1)[np.asarray(mesh.triangles, dtype=np.int64)]


def open_edge_count(mesh: TriangleMesh, tolerance: float = 1e-9) -> int:
    """Edges used by exactly one triangle (0 for a closed surface); vertices merged as in
    ``merged_vertex_ids``, so files that repeat vertices per face count as closed when their faces meet."""
    t = merged_vertex_ids(mesh, tolerance)
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    edges = edges[edges[:, 0] != edges[:, 1]]
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int(np.count_nonzero(counts == 1))


@lru_cache(maxsize=16)
def _load_cached(path: str, mtime_ns: int, size: int) -> TriangleMesh:
    return load_triangle_mesh(path)


def load_triangle_mesh_cached(path: str | os.PathLike) -> TriangleMesh:
    """``load_triangle_mesh`` remembered per (path, modification time, size): the bounds, volume and
    inside test of one scene's mesh blocks read the file once. Do not modify the returned arrays."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError:
        return load_triangle_mesh(p)
    return _load_cached(str(p), st.st_mtime_ns, st.st_size)
