"""USD export for Blender: time-sampled particles (UsdGeomPoints) and fluid surface (UsdGeomMesh).

Layout (notes/usd_blender.md section 2), one ``.usdc`` file for the whole run:

    defaultPrim = "sph", upAxis = "Z", metersPerUnit = 1, timeCodesPerSecond = framesPerSecond = fps,
    startTimeCode = 1, endTimeCode = last frame written (updated before every Save)
    /sph                   Xform
    /sph/particles         Points: points, velocities, extent (+/- r), primvars:<name> (vertex)
                           time-sampled every frame, in stable particle order; widths = 2 r (constant)
    /sph/surface           Mesh (subdivisionScheme none): points, faceVertexCounts,
                           faceVertexIndices (CCW seen from outside), extent, and primvars:normals
                           (vertex interpolation: smooth shading in Blender without modifiers), every frame
    /sph/spray             Points: the spray particles (few neighbours, not in the surface mesh): points,
                           velocities, extent (+/- width / 2), widths (constant interpolation, one value
                           per frame: 2 r); the count changes per frame. A frame without spray holds one
                           point 1e-4 r wide at the lowest particle (under the water, below a pixel in
                           any render), because an empty Points sample is flagged by USD checkers
                           (check_usd.py --strict) and some importers
    /sph/<name>            static meshes (container walls, obstacles): topology as default values;
                           points and extent as default values *and* one (equal) time sample per
                           frame, so every Points/Mesh prim spans the frame range (check_usd.py
                           --strict; Blender adds a Mesh Sequence Cache that reads the same mesh).
                           Crate shares equal values only within one Save, so each frame costs
                           12 B per static vertex (the 8-vertex container: ~0.1 kB per frame).

Frame f is written at time code f (1 = the initial state; ``first_frame`` for a re-export of a
frame range). The stage is saved after every frame: crate saves append, so memory stays flat and a crash (even SIGKILL) leaves every frame written
so far readable (tests/test_export_usd.py). Arrays go through ``Vt.*Array.FromNumpy`` (a list
round trip is ~9x slower).
"""
from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from ..core.errors import OutputError

_RESERVED = ("particles", "surface", "spray")


def container_box_mesh(lower, upper, open_top: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh of the box [lower, upper] [m] (Z up), wound CCW seen from outside.

    Returns vertices (8, 3) float32 [m] and triangles (10 or 12, 3) int32; with ``open_top`` the
    face at z = upper.z is left out (an open tank).
    """
    lo = np.asarray(lower, dtype=np.float64).reshape(3)
    hi = np.asarray(upper, dtype=np.float64).reshape(3)
    if not np.all(hi > lo):
        raise ValueError(f"container box needs upper > lower on every axis; got {lo.tolist()} .. {hi.tolist()}")
    # vertex v = bit0 * x + bit1 * y + bit2 * z
    verts = np.array([[(hi if (v >> a) & 1 else lo)[a] for a in range(3)] for v in range(8)], dtype=np.float32)
    quads = [
        (0, 2, 3, 1),  # z = lo (bottom, normal -z)
        (0, 1, 5, 4),  # y = lo (normal -y)
        (2, 6, 7, 3),  # y = hi (normal +y)
        (0, 4, 6, 2),  # x = lo (normal -x)
        (1, 3, 7, 5),  # x = hi (normal +x)
    ]
    if not open_top:
        quads.append((4, 5, 7, 6))  # z = hi (top, normal +z)
    tris = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int32)
    return verts, tris


def _vec3f(a: np.ndarray) -> Vt.Vec3fArray:
    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32).reshape(-1, 3))


def _extent(points: np.ndarray, pad: float) -> Vt.Vec3fArray:
    if len(points) == 0:
        return _vec3f(np.zeros((2, 3)))
    return _vec3f(np.stack([points.min(axis=0) - pad, points.max(axis=0) + pad]))


class UsdWriter:
    """Writes a run as one Blender-ready ``.usdc`` stage, one time sample per frame.

    Args:
        path: output file (``.usdc`` recommended; ``.usd`` is written as crate too).
        fps: frames per second of the export (timeCodesPerSecond = framesPerSecond = fps).
        particle_radius: particle radius r [m]; widths = 2 r, extents padded by r.
        static_meshes: (name, vertices (V, 3) [m], triangles (T, 3)) written once under /sph/name.
        primvars: names of per-particle float primvars written every frame (e.g. "density").
        with_surface: write /sph/surface.
        with_velocities: write particle velocities [m/s] (Blender 'velocity', motion blur).
        with_normals: write the surface's vertex normals (primvars:normals) when a frame gives them.
        with_spray: write /sph/spray (spray particles as their own point set).
        resume_after_frame: k to reopen the existing file, delete every time sample after frame k
            and continue with frame k + 1; None to create a new file.
        overwrite: replace an existing file when creating a new one (otherwise OutputError).
        first_frame: time code of the first frame of a new file (startTimeCode; default 1). A
            re-export of frames A..B keeps the run's frame numbers: first_frame = A.
    """

    def __init__(
        self,
        path,
        fps: float,
        particle_radius: float,
        static_meshes: Sequence[tuple[str, np.ndarray, np.ndarray]] = (),
        primvars: tuple[str, ...] = ("density",),
        with_surface: bool = True,
        resume_after_frame: int | None = None,
        *,
        with_velocities: bool = True,
        with_normals: bool = False,
        with_spray: bool = False,
        overwrite: bool = False,
        first_frame: int = 1,
    ):
        if not fps > 0.0:
            raise ValueError(f"fps must be > 0; got {fps}")
        if not particle_radius > 0.0:
            raise ValueError(f"particle_radius must be > 0 [m]; got {particle_radius}")
        self.path = os.fspath(path)
        self.fps = float(fps)
        self.particle_radius = float(particle_radius)
        self.primvar_names = tuple(primvars)
        self.with_surface = bool(with_surface)
        self.with_velocities = bool(with_velocities)
        self.with_normals = bool(with_normals) and self.with_surface
        self.with_spray = bool(with_spray)
        #: file size growth [bytes] of each frame written by this writer, and seconds per write
        self.frame_bytes: list[int] = []
        self.write_seconds: list[float] = []
        for name in self.primvar_names:
            if not Sdf.Path.IsValidIdentifier(name):
                raise ValueError(f"primvar name {name!r} is not a valid USD identifier")
        if resume_after_frame is None:
            self.first_frame = int(first_frame)
            self.stage = self._create(static_meshes, overwrite)
            self.last_frame = self.first_frame - 1
        else:
            self.stage = self._resume(int(resume_after_frame))
            self.last_frame = int(resume_after_frame)
        self._bind()

    # -- creation ------------------------------------------------------------------------------
    def _create(self, static_meshes, overwrite: bool) -> Usd.Stage:
        folder = os.path.dirname(os.path.abspath(self.path))
        if not os.path.isdir(folder):
            raise OutputError(f"USD output folder {folder} does not exist")
        if os.path.exists(self.path):
            if not overwrite:
                raise OutputError(f"USD file {self.path} already exists; remove it, choose another path, "
                                  "or resume it")
            os.remove(self.path)
        try:
            layer = Sdf.Layer.Find(self.path)
            if layer is not None:  # still open in this process (a stage someone holds): reuse it, emptied
                layer.Clear()
                stage = Usd.Stage.Open(layer)
            else:
                stage = Usd.Stage.CreateNew(self.path)
        except Exception as exc:  # pxr raises Tf.ErrorException
            raise OutputError(f"cannot create USD file {self.path}: {exc}") from exc
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        stage.SetTimeCodesPerSecond(self.fps)
        stage.SetFramesPerSecond(self.fps)
        stage.SetStartTimeCode(self.first_frame)
        stage.SetEndTimeCode(self.first_frame)
        root = UsdGeom.Xform.Define(stage, "/sph")
        stage.SetDefaultPrim(root.GetPrim())

        points = UsdGeom.Points.Define(stage, "/sph/particles")
        points.CreatePointsAttr()
        points.CreateExtentAttr()
        points.CreateWidthsAttr(Vt.FloatArray([2.0 * self.particle_radius]))
        points.SetWidthsInterpolation(UsdGeom.Tokens.constant)
        if self.with_velocities:
            points.CreateVelocitiesAttr()
        api = UsdGeom.PrimvarsAPI(points)
        for name in self.primvar_names:
            api.CreatePrimvar(name, Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)

        if self.with_surface:
            mesh = UsdGeom.Mesh.Define(stage, "/sph/surface")
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            mesh.CreatePointsAttr()
            mesh.CreateFaceVertexCountsAttr()
            mesh.CreateFaceVertexIndicesAttr()
            mesh.CreateExtentAttr()
            if self.with_normals:
                UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("normals", Sdf.ValueTypeNames.Normal3fArray,
                                                        UsdGeom.Tokens.vertex)

        if self.with_spray:
            spray = UsdGeom.Points.Define(stage, "/sph/spray")
            spray.CreatePointsAttr()
            spray.CreateExtentAttr()
            spray.CreateWidthsAttr()
            spray.SetWidthsInterpolation(UsdGeom.Tokens.constant)
            if self.with_velocities:
                spray.CreateVelocitiesAttr()

        for name, verts, tris in static_meshes:
            if not Sdf.Path.IsValidIdentifier(name) or name in _RESERVED:
                raise ValueError(f"static mesh name {name!r} must be a USD identifier other than {_RESERVED}")
            verts = np.asarray(verts, dtype=np.float32).reshape(-1, 3)
            tris = np.asarray(tris, dtype=np.int32).reshape(-1, 3)
            if len(tris) and (tris.min() < 0 or tris.max() >= len(verts)):
                raise ValueError(f"static mesh {name!r}: triangle indices out of range")
            mesh = UsdGeom.Mesh.Define(stage, f"/sph/{name}")
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            mesh.CreatePointsAttr(_vec3f(verts))
            mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(tris), 3, np.int32)))
            mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(tris.reshape(-1))))
            mesh.CreateExtentAttr(_extent(verts, 0.0))
        stage.Save()
        return stage

    def _resume(self, k: int) -> Usd.Stage:
        if k < 0:
            raise ValueError(f"resume_after_frame must be >= 0; got {k}")
        if not os.path.isfile(self.path):
            raise OutputError(f"cannot resume: USD file {self.path} does not exist")
        try:
            stage = Usd.Stage.Open(self.path)
        except Exception as exc:
            raise OutputError(f"cannot resume: USD file {self.path} does not open: {exc}") from exc
        if not stage or not stage.GetPrimAtPath("/sph/particles").IsA(UsdGeom.Points):
            raise OutputError(f"cannot resume: {self.path} has no /sph/particles Points prim (not a warp-sph file?)")
        if stage.GetTimeCodesPerSecond() != self.fps:
            raise OutputError(f"cannot resume: {self.path} was written at {stage.GetTimeCodesPerSecond():g} fps, "
                              f"this run exports at {self.fps:g} fps")
        self.first_frame = int(stage.GetStartTimeCode())
        if k < self.first_frame - 1:
            raise OutputError(f"cannot resume after frame {k}: {self.path} starts at frame {self.first_frame}")
        end = stage.GetEndTimeCode()
        if end < k:
            raise OutputError(f"cannot resume after frame {k}: {self.path} ends at frame {end:g}")
        for name, wanted in (("surface", self.with_surface), ("spray", self.with_spray)):
            if wanted != stage.GetPrimAtPath(f"/sph/{name}").IsValid():
                raise OutputError(f"cannot resume: {self.path} {'lacks' if wanted else 'has'} /sph/{name}")
        if self.with_normals and not UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/sph/surface")).HasPrimvar("normals"):
            raise OutputError(f"cannot resume: {self.path} has no surface normals (primvars:normals)")
        for prim in stage.Traverse():
            for attr in prim.GetAttributes():
                for t in attr.GetTimeSamples():
                    if t > k:
                        attr.ClearAtTime(t)
        stage.SetEndTimeCode(max(k, self.first_frame))
        stage.Save()
        return stage

    def _bind(self) -> None:
        stage = self.stage
        points = UsdGeom.Points(stage.GetPrimAtPath("/sph/particles"))
        self._points = points.GetPointsAttr()
        self._points_extent = points.GetExtentAttr()
        self._velocities = points.GetVelocitiesAttr() if self.with_velocities else None
        api = UsdGeom.PrimvarsAPI(points)
        self._primvars = {}
        for name in self.primvar_names:
            pv = api.GetPrimvar(name)
            if not pv:
                raise OutputError(f"{self.path}: /sph/particles has no primvar {name!r}")
            self._primvars[name] = pv.GetAttr()
        if self.with_surface:
            mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/sph/surface"))
            self._mesh_points = mesh.GetPointsAttr()
            self._mesh_counts = mesh.GetFaceVertexCountsAttr()
            self._mesh_indices = mesh.GetFaceVertexIndicesAttr()
            self._mesh_extent = mesh.GetExtentAttr()
            self._mesh_normals = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("normals").GetAttr() if self.with_normals else None
        if self.with_spray:
            spray = UsdGeom.Points(stage.GetPrimAtPath("/sph/spray"))
            self._spray_points = spray.GetPointsAttr()
            self._spray_extent = spray.GetExtentAttr()
            self._spray_widths = spray.GetWidthsAttr()
            self._spray_velocities = spray.GetVelocitiesAttr() if self.with_velocities else None
        # static meshes: their default points and extent, repeated as a time sample every frame
        self._statics = []
        for prim in stage.GetPrimAtPath("/sph").GetChildren():
            if prim.GetName() in _RESERVED or not prim.IsA(UsdGeom.Mesh):
                continue
            mesh = UsdGeom.Mesh(prim)
            for attr in (mesh.GetPointsAttr(), mesh.GetExtentAttr()):
                value = attr.Get(Usd.TimeCode.Default())
                if value is None:
                    raise OutputError(f"{self.path}: static mesh {prim.GetPath()} has no default {attr.GetName()}")
                self._statics.append((attr, value))

    # -- frames --------------------------------------------------------------------------------
    def write_frame(
        self,
        frame: int,
        particle_x: np.ndarray,
        particle_v: np.ndarray | None = None,
        primvars: Mapping[str, np.ndarray] | None = None,
        surface: tuple | None = None,
        spray: tuple[np.ndarray, np.ndarray | None] | None = None,
    ) -> None:
        """Write frame ``frame`` (time code; 1 = initial state) and save the stage.

        Args:
            frame: the next frame: last written + 1 (first_frame for a new file, k + 1 after a resume).
            particle_x: positions [m], (N, 3), in stable particle order.
            particle_v: velocities [m/s], (N, 3); required unless with_velocities=False.
            primvars: one (N,) float array per declared primvar name (e.g. density [kg/m^3]).
            surface: (vertices (V, 3) [m], triangles (T, 3)[, normals (V, 3) unit]); None or empty
                arrays write an empty surface for this frame (required sample, so every frame has one).
            spray: (positions (S, 3) [m], velocities (S, 3) [m/s] or None) of the spray particles;
                None writes no spray this frame (an empty sample).
        """
        if self.stage is None:
            raise OutputError(f"{self.path}: write_frame after close")
        t_start = time.perf_counter()
        size_before = os.path.getsize(self.path) if os.path.exists(self.path) else 0
        frame = int(frame)
        if frame != self.last_frame + 1:
            raise ValueError(f"frames must be written in order: expected frame {self.last_frame + 1}, got {frame}")
        x = np.ascontiguousarray(particle_x, dtype=np.float32).reshape(-1, 3)
        n = len(x)
        primvars = dict(primvars or {})
        if set(primvars) != set(self.primvar_names):
            raise ValueError(f"write_frame needs exactly the primvars {sorted(self.primvar_names)}; got {sorted(primvars)}")
        t = Usd.TimeCode(frame)
        self._points.Set(_vec3f(x), t)
        self._points_extent.Set(_extent(x, self.particle_radius), t)
        if self._velocities is not None:
            if particle_v is None:
                raise ValueError("write_frame needs particle_v (the writer was made with_velocities=True)")
            v = np.ascontiguousarray(particle_v, dtype=np.float32).reshape(-1, 3)
            if len(v) != n:
                raise ValueError(f"{len(v)} velocities for {n} particles")
            self._velocities.Set(_vec3f(v), t)
        for name, attr in self._primvars.items():
            values = np.ascontiguousarray(primvars[name], dtype=np.float32).reshape(-1)
            if len(values) != n:
                raise ValueError(f"primvar {name!r}: {len(values)} values for {n} particles")
            attr.Set(Vt.FloatArray.FromNumpy(values), t)
        if self.with_surface:
            if surface is None:
                verts, tris = np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
            else:
                verts = np.ascontiguousarray(surface[0], dtype=np.float32).reshape(-1, 3)
                tris = np.ascontiguousarray(surface[1], dtype=np.int32).reshape(-1, 3)
            if len(tris) and (tris.min() < 0 or tris.max() >= len(verts)):
                raise ValueError(f"surface triangle indices out of range 0..{len(verts) - 1}")
            if self._mesh_normals is not None:
                normals = surface[2] if surface is not None and len(surface) > 2 and surface[2] is not None else None
                if normals is None:
                    if len(verts):
                        raise ValueError("write_frame needs surface normals (the writer was made with_normals=True)")
                    normals = np.zeros((0, 3), np.float32)
                normals = np.ascontiguousarray(normals, dtype=np.float32).reshape(-1, 3)
                if len(normals) != len(verts):
                    raise ValueError(f"{len(normals)} surface normals for {len(verts)} vertices")
                self._mesh_normals.Set(_vec3f(normals), t)
            self._mesh_points.Set(_vec3f(verts), t)
            self._mesh_counts.Set(Vt.IntArray.FromNumpy(np.full(len(tris), 3, np.int32)), t)
            self._mesh_indices.Set(Vt.IntArray.FromNumpy(tris.reshape(-1)), t)
            self._mesh_extent.Set(_extent(verts, 0.0), t)
        if self.with_spray:
            sx = np.zeros((0, 3), np.float32) if spray is None else \
                np.ascontiguousarray(spray[0], dtype=np.float32).reshape(-1, 3)
            sv = np.zeros((len(sx), 3), np.float32) if spray is None or spray[1] is None else \
                np.ascontiguousarray(spray[1], dtype=np.float32).reshape(-1, 3)
            if len(sv) != len(sx):
                raise ValueError(f"{len(sv)} spray velocities for {len(sx)} spray particles")
            width = 2.0 * self.particle_radius
            if len(sx) == 0:  # placeholder (module docstring): the lowest particle, 1e-4 r wide, at rest
                sx = x[np.argmin(x[:, 2])][None, :] if n else np.zeros((1, 3), np.float32)
                sv = np.zeros((1, 3), np.float32)
                width = 1e-4 * self.particle_radius
            self._spray_points.Set(_vec3f(sx), t)
            self._spray_widths.Set(Vt.FloatArray([width]), t)
            self._spray_extent.Set(_extent(sx, 0.5 * width), t)
            if self._spray_velocities is not None:
                self._spray_velocities.Set(_vec3f(sv), t)
        for attr, value in self._statics:
            attr.Set(value, t)
        self.stage.SetEndTimeCode(frame)
        self.stage.Save()
        self.last_frame = frame
        self.frame_bytes.append(os.path.getsize(self.path) - size_before)
        self.write_seconds.append(time.perf_counter() - t_start)

    def close(self) -> None:
        """Save and release the stage (idempotent)."""
        if self.stage is not None:
            self.stage.Save()
            self.stage = None

    def __enter__(self) -> UsdWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
