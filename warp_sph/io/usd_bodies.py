"""The moving rigid bodies of a run's USD file ([[bodies]], docs/scenes.md "Moving rigid bodies"):

    /sph/bodies                  Xform
    /sph/bodies/<name>           Mesh: the body's closed surface in its own frame (points about the centre of
                                 mass [m], CCW triangles), xformOp:translate [m] and xformOp:orient time-sampled
                                 every frame (the pose); points and extent repeated as a sample every frame

``BodyMeshes`` declares them (``add``), checks a frame's poses before anything of the frame is written
(``poses``) and writes them (``write``); ``UsdWriter`` (export_usd.py) calls it.
"""
from __future__ import annotations

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom

from ..core.errors import OutputError
from .usd_layout import BODIES, define_triangle_mesh, extent


class BodyMeshes:
    """The body meshes of ``stage`` (those already in a resumed file bound at once); ``path``: the file, for
    the messages. Holds the bodies' attributes, never the stage: the writer alone keeps the stage alive, and
    releases it unsaved after a failed save (a stage kept alive past that crashed the process)."""

    def __init__(self, stage, path):
        self.path = path
        self._bodies = {}
        bodies = stage.GetPrimAtPath(BODIES)
        for prim in bodies.GetChildren() if bodies.IsValid() else ():
            self._bind(prim)

    def add(self, stage, name: str, vertices: np.ndarray, triangles: np.ndarray, frames_written: bool) -> None:
        """Define /sph/bodies/<name> (see ``UsdWriter.add_body``); on a resumed file only check the vertex count."""
        if not Sdf.Path.IsValidIdentifier(name):
            raise ValueError(f"body name {name!r} is not a valid USD identifier")
        verts = np.asarray(vertices, dtype=np.float32).reshape(-1, 3)
        tris = np.asarray(triangles, dtype=np.int32).reshape(-1, 3)
        if len(tris) == 0 or tris.min() < 0 or tris.max() >= len(verts):
            raise ValueError(f"body {name!r}: no triangles, or triangle indices out of range")
        if name in self._bodies:
            if len(self._bodies[name]["points"][1]) != len(verts):
                raise OutputError(f"{self.path}: body {name!r} has another vertex count in the file")
            return
        if frames_written:
            raise ValueError(f"body {name!r}: add bodies before the first frame is written")
        UsdGeom.Xform.Define(stage, BODIES)
        mesh = define_triangle_mesh(stage, f"{BODIES}/{name}", verts, tris)
        mesh.AddTranslateOp()
        mesh.AddOrientOp()
        stage.Save()
        self._bind(mesh.GetPrim())

    def _bind(self, prim) -> None:
        mesh = UsdGeom.Mesh(prim)
        ops = {op.GetOpType(): op for op in mesh.GetOrderedXformOps()}
        if not prim.IsA(UsdGeom.Mesh) or set(ops) != {UsdGeom.XformOp.TypeTranslate, UsdGeom.XformOp.TypeOrient}:
            raise OutputError(f"{self.path}: {prim.GetPath()} is not a warp-sph body (a Mesh with translate and orient)")
        entry = {"translate": ops[UsdGeom.XformOp.TypeTranslate], "orient": ops[UsdGeom.XformOp.TypeOrient]}
        for key, attr in (("points", mesh.GetPointsAttr()), ("extent", mesh.GetExtentAttr())):
            entry[key] = (attr, attr.Get(Usd.TimeCode.Default()))
        self._bodies[prim.GetName()] = entry

    def poses(self, bodies, origin) -> dict:
        """{name: (Gf.Vec3d, Gf.Quatf)} checked before anything of the frame is written; ``bodies``: {name:
        (position [m], quaternion x, y, z, w)}; ``origin``: the file's origin (/sph's translate) or None."""
        bodies = dict(bodies or {})
        if set(bodies) != set(self._bodies):
            raise ValueError(f"write_frame needs exactly the poses of bodies {sorted(self._bodies)}; got {sorted(bodies)}")
        out = {}
        for name, (position, quaternion) in bodies.items():
            p = np.asarray(position, dtype=np.float64).reshape(3)
            q = np.asarray(quaternion, dtype=np.float64).reshape(4)
            if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q)) and np.linalg.norm(q) > 0.0):
                raise ValueError(f"body {name!r}: pose {p.tolist()}, {q.tolist()} is not finite")
            if origin is not None:  # /sph carries the origin: the body's translate is relative to it
                p = p - origin
            out[name] = (Gf.Vec3d(*p), Gf.Quatf(float(q[3]), float(q[0]), float(q[1]), float(q[2])).GetNormalized())
        return out

    def write(self, poses: dict, t: Usd.TimeCode) -> None:
        """The poses (from ``poses``) and the repeated points and extent as samples at ``t``."""
        for name, (translate, orient) in poses.items():
            entry = self._bodies[name]
            entry["translate"].Set(translate, t)
            entry["orient"].Set(orient, t)
            for attr, value in (entry["points"], entry["extent"]):
                attr.Set(value, t)
