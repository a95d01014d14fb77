"""What a preview reads from a run folder: run.json, the recorded frames, the surface and obstacle
meshes of the run's USD file, and the rigid bodies' poses.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..io.run_folder import read_frame, read_run_json
from .render import PreviewError

BODY_COLOR = (0.78, 0.45, 0.18)  # orange-brown wood for moving rigid bodies
SURFACE_PRIM = "/sph/surface"
SPRAY_PRIM = "/sph/spray"


def read_run(run_dir: Path) -> tuple[dict, list[int]]:
    """(run.json as a dict, the recorded frame numbers in order); OutputError (one line, as ``export`` and
    ``plot``: ``run_folder.read_run_json``) when it is no run folder or its run.json is damaged."""
    meta = read_run_json(run_dir)
    if "frames" in meta:
        try:
            recorded = sorted(int(f["frame"]) for f in meta["frames"])
        except (TypeError, KeyError, ValueError):
            raise PreviewError(f"{run_dir / 'run.json'}: 'frames' is not a list of frame records; expected "
                               "[{\"frame\": N, ...}, ...] as warp-sph run writes it") from None
    else:
        recorded = sorted(int(p.stem.split("_")[-1]) for p in (run_dir / "frames").glob("frame_*.npz"))
    return meta, recorded


def frame_path(run_dir: Path, frame: int) -> Path:
    """The recorded frame file ``frames/frame_{frame:06d}.npz`` of the run."""
    return run_dir / "frames" / f"frame_{frame:06d}.npz"


def load_frame(run_dir: Path, frame: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Positions x [m] (float32, (N, 3)) and velocities v [m/s] (None when not recorded) of a recorded frame."""
    path = frame_path(run_dir, frame)
    if not path.is_file():
        raise PreviewError(f"frame {frame} is listed but its file {path} is missing")
    data = read_frame(path, ("x", "v?"))  # one line naming the file when it is damaged (as ``export``)
    return np.asarray(data["x"], dtype=np.float32), data.get("v")


class SurfaceReader:
    """The surface mesh (prim /sph/surface) of a run's USD file, one time sample per frame."""

    def __init__(self, run_dir: Path):
        from pxr import Usd, UsdGeom

        files = sorted(p for ext in ("usdc", "usd", "usda") for p in run_dir.glob(f"*.{ext}"))
        if not files:
            raise PreviewError(f"surface preview needs the run's USD file, none found in {run_dir}")
        try:  # the run's own file (named after its scene) before any other USD in the folder
            from ..io.run_folder import safe_name

            own = run_dir / f"{safe_name(json.loads((run_dir / 'run.json').read_text())['scene']['name'])}.usdc"
        except (OSError, ValueError, KeyError, TypeError):
            own = None
        self.path = own if own is not None and own.is_file() else files[0]
        self._usd = Usd
        try:
            self.stage = Usd.Stage.Open(str(self.path))
        except Exception as exc:  # pxr's Tf.ErrorException: a damaged file
            lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
            raise PreviewError(f"{self.path} does not open: {lines[0] if lines else exc}") from None
        prim = self.stage.GetPrimAtPath(SURFACE_PRIM)
        if not prim or not prim.IsValid():
            raise PreviewError(
                f"{self.path} has no surface mesh at {SURFACE_PRIM} (was the run made without surface export?)"
            )
        self.mesh = UsdGeom.Mesh(prim)
        self._geom = UsdGeom
        parent = self.stage.GetPrimAtPath(SURFACE_PRIM).GetParent()
        #: obstacle meshes beside the surface (the container is drawn as the box outline)
        self.solid_prims = [p for p in parent.GetChildren() if p.IsA(UsdGeom.Mesh)
                            and p.GetName() not in ("surface", "container")]

    def _world(self, prim, points: np.ndarray, time) -> np.ndarray:
        """Points of ``prim`` in world coordinates [m] (a run far from the origin writes them
        relative to /sph's translate), in float64 until the renderer takes them."""
        m = np.asarray(self._geom.XformCache(time).GetLocalToWorldTransform(prim), dtype=np.float64)
        if np.array_equal(m, np.eye(4)):
            return points
        return points.astype(np.float64) @ m[:3, :3] + m[3, :3]

    def frame(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Surface mesh of ``frame`` [m], with the spray points (/sph/spray) added as small spheres of
        their width, so the preview shows what a render with a foam material would."""
        points_attr = self.mesh.GetPointsAttr()
        if frame not in {int(round(t)) for t in points_attr.GetTimeSamples()} and points_attr.GetNumTimeSamples():
            raise PreviewError(f"{self.path}: {SURFACE_PRIM} has no surface for frame {frame}")
        time = self._usd.TimeCode(frame)
        points = np.asarray(points_attr.Get(time) or [], dtype=np.float32).reshape(-1, 3)
        counts = np.asarray(self.mesh.GetFaceVertexCountsAttr().Get(time) or [], dtype=np.int64)
        indices = np.asarray(self.mesh.GetFaceVertexIndicesAttr().Get(time) or [], dtype=np.int64)
        points = self._world(self.mesh.GetPrim(), points, time)
        triangles = _triangulate(counts, indices)
        spray = self.stage.GetPrimAtPath(SPRAY_PRIM)
        if spray and spray.IsValid():
            sp = self._geom.Points(spray)
            centers = np.asarray(sp.GetPointsAttr().Get(time) or [], dtype=np.float32).reshape(-1, 3)
            widths = np.asarray(sp.GetWidthsAttr().Get(time) or [0.0], dtype=np.float32)
            if len(centers):
                sv, st = _sphere_mesh(self._world(spray, centers, time),
                                      0.5 * (widths if len(widths) == len(centers) else widths[:1]))
                triangles = np.concatenate([triangles, st + len(points)])
                points = np.concatenate([points, sv.astype(points.dtype)])
        return points, triangles

    def first_time(self) -> float:
        """The first time code of the surface (1.0 when it has none)."""
        times = self.mesh.GetPointsAttr().GetTimeSamples()
        return float(times[0]) if times else 1.0

    def solids(self, frame: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Obstacle meshes (world vertices [m], triangles) at ``frame``."""
        out = []
        time = self._usd.TimeCode(frame)
        for prim in self.solid_prims:
            mesh = self._geom.Mesh(prim)
            points = np.asarray(mesh.GetPointsAttr().Get(time) or [], dtype=np.float32).reshape(-1, 3)
            counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(time) or [], dtype=np.int64)
            indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(time) or [], dtype=np.int64)
            if len(points) and len(counts):
                out.append((self._world(prim, points, time), _triangulate(counts, indices)))
        return out


def obstacle_meshes(run_dir: Path, scene: dict, surface) -> list[tuple[np.ndarray, np.ndarray]]:
    """The run's obstacle meshes in world coordinates [m]: from its USD (where they were written)
    when there is one, else from the scene in run.json (mesh files loaded again)."""
    if surface is None:
        try:
            surface = SurfaceReader(run_dir)
        except PreviewError:
            surface = None
    if surface is not None:
        return surface.solids(surface.first_time())
    from ..io.reexport import scene_static_meshes

    return [(v, t) for name, v, t in scene_static_meshes(scene) if name != "container"]


def body_meshes(meta: dict) -> dict[int, list[tuple[np.ndarray, np.ndarray, tuple]]]:
    """{frame: [(world vertices [m], triangles, BODY_COLOR), ...]}: each rigid body of the run's scene
    (its shape in the body frame, ``rigid.spec.body_geometry``) at the pose run.json recorded for the frame."""
    entries = (meta.get("scene") or {}).get("bodies") or []
    animated = [(i, ob) for i, ob in enumerate((meta.get("scene") or {}).get("obstacles") or [])
                if ob.get("keyframes") or ob.get("animation")]
    if not entries and not animated:
        return {}
    from ..rigid.spec import Body, body_geometry, body_name, quat_to_matrix

    shapes = {}
    for i, ob in animated:  # animated obstacles: their surface in their own frame, at the recorded pose
        shapes[ob.get("name") or f"obstacle{i}"] = _local_obstacle_mesh(ob, i)
    for i, entry in enumerate(entries):
        try:
            geo = body_geometry(Body(**entry))
        except Exception as exc:  # a mesh file moved away since the run
            raise PreviewError(f"bodies[{i}] of run.json cannot be drawn: {' '.join(str(exc).split())[:160]}") from None
        shapes[body_name(Body(**entry), i)] = geo
    out = {}
    for record in meta.get("frames") or []:
        solids = []
        for name, pose in (record.get("bodies") or {}).items():
            geo = shapes.get(name)
            if geo is None:
                continue
            R = quat_to_matrix(pose["orientation"])
            solids.append((geo.vertices @ R.T + np.asarray(pose["position"]), geo.triangles, BODY_COLOR))
        out[int(record["frame"])] = solids
    return out


class _Mesh:
    def __init__(self, vertices, triangles):
        self.vertices, self.triangles = vertices, triangles


def _local_obstacle_mesh(ob: dict, i: int) -> _Mesh:
    """An animated obstacle's surface in its own frame (the geometry as written in the scene) [m]."""
    from ..rigid.spec import box_mesh
    from ..scene.meshes import load_triangle_mesh

    if ob.get("shape", "box") == "box":
        lo, hi = np.asarray(ob["min"], float), np.asarray(ob["max"], float)
        verts, tris = box_mesh(0.5 * (hi - lo))
        return _Mesh(verts + 0.5 * (lo + hi), tris)
    try:
        mesh = load_triangle_mesh(ob["file"]).transformed(ob.get("scale") or 1.0, ob.get("translate") or (0.0, 0.0, 0.0))
    except Exception as exc:  # a mesh file moved away since the run
        raise PreviewError(f"obstacles[{i}] of run.json cannot be drawn: {' '.join(str(exc).split())[:160]}") from None
    return _Mesh(mesh.vertices, mesh.triangles)


def _sphere_mesh(centers: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Icospheres (42 vertices, 80 faces each, wound outward) at ``centers`` [m] with ``radii`` [m]."""
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
                  [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
                  [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    edges = {}
    verts = list(v)
    faces = []
    for a, b, c in f:  # one subdivision: midpoints shared through ``edges``
        m = []
        for p, q in ((a, b), (b, c), (c, a)):
            key = (min(p, q), max(p, q))
            if key not in edges:
                edges[key] = len(verts)
                verts.append(0.5 * (v[p] + v[q]))
            m.append(edges[key])
        faces += [[a, m[0], m[2]], [b, m[1], m[0]], [c, m[2], m[1]], m]
    unit = np.asarray(verts)
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    faces = np.asarray(faces, dtype=np.int64)
    n = len(centers)
    pts = centers[:, None, :] + np.broadcast_to(np.asarray(radii, np.float64).reshape(-1, 1, 1), (n, 1, 1)) * unit[None]
    tris = faces[None] + (np.arange(n) * len(unit))[:, None, None]
    return pts.reshape(-1, 3), tris.reshape(-1, 3).astype(np.int32)


def _triangulate(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Fan-triangulate USD faces (faceVertexCounts, faceVertexIndices) into (T, 3)."""
    if len(counts) == 0:
        return np.zeros((0, 3), dtype=np.int32)
    if np.all(counts == 3):
        return indices.reshape(-1, 3).astype(np.int32)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tris = [
        (indices[s], indices[s + k], indices[s + k + 1]) for s, n in zip(starts, counts) for k in range(1, n - 1)
    ]
    return np.asarray(tris, dtype=np.int32).reshape(-1, 3)
