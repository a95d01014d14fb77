"""USD export for Blender: a run's frames as time samples in one ``.usdc`` file (``UsdWriter``).

The file's prims and their attributes (particles, surface, spray, static meshes, moving bodies) are
described and created in ``usd_layout.py`` (notes/usd_blender.md section 2); this module writes the
frames into them.

Frame f is written at time code f (1 = the initial state; ``first_frame`` for a re-export of a
frame range). The stage is saved after every frame: crate saves append, so memory stays flat and a crash (even SIGKILL) leaves every frame written
so far readable (tests/test_export_usd.py). Arrays go through ``Vt.*Array.FromNumpy`` (a list
round trip is ~9x slower).

A full disk: a crate Save overwrites the file's structural sections and table of contents (the
last ~1 kB) with the new samples and a new table, and a Save that fails part-way leaves a file
that no longer opens (and the next Save crashed the process). So before each Save the writer
checks the free space against the bytes the Save will write (the new samples, the rewritten
time-sample tables and sections) and refuses with one line when they do not fit; and it keeps a
copy of the header and those last bytes, which it writes back when a Save fails anyway (a race
with another writer): the file then holds every frame of the last good Save (``crate_guard``;
tests/test_disk_full.py). Cost: a ~1 kB read and a statvfs per frame, 25-95 us against 11-32 ms
for the frame's write_frame at 6,859 particles and a 25k-vertex surface (2-core VM).

A scene far from the origin (``origin``): float32 world coordinates would lose up to
|x| 2^-24 (4.9e-4 m at 1e4 m), so points are written relative to ``origin`` and /sph carries a
double-precision ``xformOp:translate`` = origin (Blender: the "sph" empty sits at the origin).
"""
from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from ..core.errors import OutputError
from . import atomic
from . import usd_whitewater
from .crate_guard import crate_tail, restore_crate_tail
from .usd_bodies import BodyMeshes
from .usd_layout import (RESERVED, clear_after, container_box_mesh, create_stage, extent, file_origin,
                         first_line, open_for_resume, vec3f)

__all__ = ["UsdWriter", "container_box_mesh"]


def _nbytes(value) -> int:
    try:
        return int(np.asarray(value).nbytes)
    except Exception:
        return 64


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
        with_whitewater: write /sph/whitewater/{spray,foam,bubbles} (``usd_whitewater``), points
            ``whitewater_width`` [m] wide.
        resume_after_frame: k to reopen the existing file, delete every time sample after frame k
            and continue with frame k + 1; None to create a new file.
        overwrite: replace an existing file when creating a new one (otherwise OutputError).
        first_frame: time code of the first frame of a new file (startTimeCode; default 1). A
            re-export of frames A..B keeps the run's frame numbers: first_frame = A.
        origin: None (points in world coordinates) or a point [m] (float64): points are written
            relative to it and /sph gets the double-precision translate ``origin``, for scenes
            far from (0, 0, 0). Positions given to the writer are always world coordinates. A
            resumed file keeps its own origin.
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
        with_whitewater: bool = False,
        whitewater_width: float = 0.0,
        overwrite: bool = False,
        first_frame: int = 1,
        origin=None,
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
        self.with_whitewater = bool(with_whitewater)
        self.whitewater_width = float(whitewater_width) or self.particle_radius
        #: file size growth [bytes] of each frame written by this writer, and seconds per write
        self.frame_bytes: list[int] = []
        self.write_seconds: list[float] = []
        for name in self.primvar_names:
            if not Sdf.Path.IsValidIdentifier(name):
                raise ValueError(f"primvar name {name!r} is not a valid USD identifier")
        self.origin = None if origin is None or not np.any(np.asarray(origin, dtype=np.float64)) \
            else np.asarray(origin, dtype=np.float64).reshape(3)
        self._failed = False  # a Save was refused or failed: the stage is never saved again
        self.stage = None
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
        self.stage = create_stage(self.path, self.fps, self.particle_radius, self.first_frame, self.origin,
                                  self.primvar_names, self.with_surface, self.with_velocities, self.with_normals,
                                  self.with_spray, static_meshes, overwrite, self._local)
        if self.with_whitewater:
            usd_whitewater.define(self.stage, self.with_velocities)
        self._save(0)
        return self.stage

    def _resume(self, k: int) -> Usd.Stage:
        # every check first: a refused resume changes nothing
        stage, self.first_frame = open_for_resume(self.path, k, self.fps, self.with_surface, self.with_spray,
                                                  self.with_normals)
        usd_whitewater.check(stage, self.path, self.with_whitewater)
        self.origin = file_origin(stage)
        clear_after(stage, k)
        stage.SetEndTimeCode(max(k, self.first_frame))
        self.stage = stage
        self._save(0)
        return stage

    @staticmethod
    def check_resumable(path, k: int, fps: float, with_surface: bool) -> None:
        """Raise OutputError if ``path`` cannot be resumed after frame ``k``; changes nothing."""
        open_for_resume(os.fspath(path), int(k), float(fps), bool(with_surface))

    def _local(self, points) -> np.ndarray:
        """World positions [m] -> float32 points of the file (relative to ``origin`` if it has one)."""
        if self.origin is None:
            return np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 3)
        return np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.origin,
                                    dtype=np.float32)

    def _save(self, new_bytes: int) -> None:
        """stage.Save(), refused before it starts when the disk lacks room for it, and undone when it
        fails part-way, so the file always holds every frame of the last good Save.

        new_bytes: size of the values set since the last Save [bytes] (the Save writes these, the
        time-sample tables and the structural sections again).
        """
        saved = crate_tail(self.path)
        if saved is None:  # a new file, or a text layer (.usda, rewritten whole)
            old = os.path.getsize(self.path) if os.path.isfile(self.path) else 0
            needed = new_bytes + old + (1 << 16)
        else:
            samples = 8 * (max(self.last_frame - self.first_frame, 0) + 2) if hasattr(self, "last_frame") else 16
            needed = new_bytes + 2 * len(saved[2]) + samples * 32 + (1 << 16)
        free = atomic.free_bytes(Path(self.path))
        if free is not None and free < needed:
            self._failed = True
            raise OutputError(f"no space left on device for {self.path}: its next save needs about "
                              f"{atomic.format_bytes(needed)}, {atomic.format_bytes(free)} free; the file keeps frames "
                              f"up to {self._last_saved()}; free some space, then continue with --resume")
        try:
            self.stage.Save()
        except Exception as exc:  # pxr's Tf.ErrorException (e.g. "No space left on device")
            self._failed = True
            restored = saved is not None and restore_crate_tail(self.path, saved)
            free = atomic.free_bytes(Path(self.path))
            raise OutputError(f"cannot save {self.path} ({atomic.format_bytes(free)} free): {first_line(exc)}; "
                              + (f"the file keeps frames up to {self._last_saved()}" if restored else
                                 "the file may be damaged") + "; free some space, then continue with --resume") from None

    def _last_saved(self) -> str:
        last = getattr(self, "last_frame", None)
        first = getattr(self, "first_frame", 1)
        return "none" if last is None or last < first else str(last)

    def _bind(self) -> None:
        stage = self.stage
        points = UsdGeom.Points(stage.GetPrimAtPath("/sph/particles"))
        self._points = points.GetPointsAttr()
        self._points_extent = points.GetExtentAttr()
        self._velocities = points.GetVelocitiesAttr() if self.with_velocities else None
        self._points_prim = points
        self._ids = self._id_primvar = None  # made by the first frame with ids (emitters: a changing count)
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
        self._whitewater = usd_whitewater.WhitewaterPoints(stage, self.with_velocities) if self.with_whitewater else None
        # static meshes: their default points and extent, repeated as a time sample every frame
        self._statics = []
        for prim in stage.GetPrimAtPath("/sph").GetChildren():
            if prim.GetName() in RESERVED or not prim.IsA(UsdGeom.Mesh):
                continue
            mesh = UsdGeom.Mesh(prim)
            for attr in (mesh.GetPointsAttr(), mesh.GetExtentAttr()):
                value = attr.Get(Usd.TimeCode.Default())
                if value is None:
                    raise OutputError(f"{self.path}: static mesh {prim.GetPath()} has no default {attr.GetName()}")
                self._statics.append((attr, value))
        self._bodies = BodyMeshes(stage, self.path)

    # -- moving rigid bodies ---------------------------------------------------------------------
    def add_body(self, name: str, vertices: np.ndarray, triangles: np.ndarray) -> None:
        """Declare a moving rigid body /sph/bodies/<name>: its closed surface in the body frame
        (vertices (V, 3) [m] about the centre of mass, triangles (T, 3) wound CCW seen from outside).
        Every later ``write_frame`` needs its pose. Call before the first frame; on a resumed file the
        body must already be there (same vertex count) and this only checks it."""
        if self.stage is None:
            raise OutputError(f"{self.path}: add_body after close")
        self._bodies.add(self.stage, name, vertices, triangles, frames_written=self.last_frame >= self.first_frame)

    # -- frames --------------------------------------------------------------------------------
    def write_frame(
        self,
        frame: int,
        particle_x: np.ndarray,
        particle_v: np.ndarray | None = None,
        primvars: Mapping[str, np.ndarray] | None = None,
        surface: tuple | None = None,
        bodies: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
        spray: tuple[np.ndarray, np.ndarray | None] | None = None,
        whitewater: Mapping[str, tuple] | None = None,
        ids: np.ndarray | None = None,
    ) -> None:
        """Write frame ``frame`` (time code; 1 = initial state) and save the stage.

        Args:
            frame: the next frame: last written + 1 (first_frame for a new file, k + 1 after a resume).
            particle_x: positions [m], (N, 3), in stable particle order.
            particle_v: velocities [m/s], (N, 3); required unless with_velocities=False.
            primvars: one (N,) float array per declared primvar name (e.g. density [kg/m^3]).
            surface: (vertices (V, 3) [m], triangles (T, 3)[, normals (V, 3) unit]); None or empty
                arrays write an empty surface for this frame (required sample, so every frame has one).
            bodies: {name: (centre of mass [m] (3,), world coordinates, orientation quaternion
                (x, y, z, w))} for exactly the bodies declared with ``add_body``.
            spray: (positions (S, 3) [m], velocities (S, 3) [m/s] or None) of the spray particles;
                None or none at all writes the placeholder point (module docstring).
            whitewater: {"spray" | "foam" | "bubbles": (positions (K, 3) [m], velocities (K, 3) [m/s],
                ages (K,) [s])} (a missing set is empty: its placeholder point) with with_whitewater.
            ids: (N,) persistent particle ids (emitters and sinks change N from frame to frame): written as
                the Points' ``ids`` and as the int primvar ``id`` (vertex), which Blender imports as the
                point attribute "id"; None writes neither.
        """
        if self.stage is None or self._failed:
            raise OutputError(f"{self.path}: write_frame after close" if self.stage is None else
                              f"{self.path}: write_frame after a failed save")
        t_start = time.perf_counter()
        size_before = os.path.getsize(self.path) if os.path.exists(self.path) else 0
        frame = int(frame)
        if frame != self.last_frame + 1:
            raise ValueError(f"frames must be written in order: expected frame {self.last_frame + 1}, got {frame}")
        x = self._local(particle_x)
        n = len(x)
        primvars = dict(primvars or {})
        if set(primvars) != set(self.primvar_names):
            raise ValueError(f"write_frame needs exactly the primvars {sorted(self.primvar_names)}; got {sorted(primvars)}")
        bodies = self._bodies.poses(bodies, self.origin)
        t = Usd.TimeCode(frame)
        self._points.Set(vec3f(x), t)
        self._points_extent.Set(extent(x, self.particle_radius), t)
        if self._velocities is not None:
            if particle_v is None:
                raise ValueError("write_frame needs particle_v (the writer was made with_velocities=True)")
            v = np.ascontiguousarray(particle_v, dtype=np.float32).reshape(-1, 3)
            if len(v) != n:
                raise ValueError(f"{len(v)} velocities for {n} particles")
            self._velocities.Set(vec3f(v), t)
        if ids is not None:
            ids = np.ascontiguousarray(ids, dtype=np.int64).reshape(-1)
            if len(ids) != n:
                raise ValueError(f"{len(ids)} ids for {n} particles")
            if self._ids is None:
                self._ids = self._points_prim.CreateIdsAttr()
                self._id_primvar = UsdGeom.PrimvarsAPI(self._points_prim).CreatePrimvar(
                    "id", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.vertex).GetAttr()
            self._ids.Set(Vt.Int64Array.FromNumpy(ids), t)
            self._id_primvar.Set(Vt.IntArray.FromNumpy(ids.astype(np.int32)), t)
        for name, attr in self._primvars.items():
            values = np.ascontiguousarray(primvars[name], dtype=np.float32).reshape(-1)
            if len(values) != n:
                raise ValueError(f"primvar {name!r}: {len(values)} values for {n} particles")
            attr.Set(Vt.FloatArray.FromNumpy(values), t)
        if self.with_surface:
            if surface is None:
                verts, tris = np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
            else:
                verts = self._local(surface[0])
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
                self._mesh_normals.Set(vec3f(normals), t)
            self._mesh_points.Set(vec3f(verts), t)
            self._mesh_counts.Set(Vt.IntArray.FromNumpy(np.full(len(tris), 3, np.int32)), t)
            self._mesh_indices.Set(Vt.IntArray.FromNumpy(tris.reshape(-1)), t)
            self._mesh_extent.Set(extent(verts, 0.0), t)
        spray_bytes = 0
        if self.with_spray:
            sx = np.zeros((0, 3), np.float32) if spray is None else self._local(spray[0])
            sv = np.zeros((len(sx), 3), np.float32) if spray is None or spray[1] is None else \
                np.ascontiguousarray(spray[1], dtype=np.float32).reshape(-1, 3)
            if len(sv) != len(sx):
                raise ValueError(f"{len(sv)} spray velocities for {len(sx)} spray particles")
            width = 2.0 * self.particle_radius
            if len(sx) == 0:  # placeholder (module docstring): the lowest particle, 1e-4 r wide, at rest
                sx = x[np.argmin(x[:, 2])][None, :] if n else np.zeros((1, 3), np.float32)
                sv = np.zeros((1, 3), np.float32)
                width = 1e-4 * self.particle_radius
            self._spray_points.Set(vec3f(sx), t)
            self._spray_widths.Set(Vt.FloatArray([width]), t)
            self._spray_extent.Set(extent(sx, 0.5 * width), t)
            if self._spray_velocities is not None:
                self._spray_velocities.Set(vec3f(sv), t)
            spray_bytes = 2 * sx.nbytes + 64
        if self._whitewater is not None:
            low = x[np.argmin(x[:, 2])] if n else np.zeros(3, np.float32)
            spray_bytes += self._whitewater.write(t, dict(whitewater or {}), self.whitewater_width, low,
                                                  1e-4 * self.particle_radius, self._local)
        for attr, value in self._statics:
            attr.Set(value, t)
        self._bodies.write(bodies, t)
        self.stage.SetEndTimeCode(frame)
        new_bytes = x.nbytes + 64 + (0 if self._velocities is None else x.nbytes) + 4 * n * len(self._primvars) \
            + (2 * verts.nbytes + 2 * tris.nbytes if self.with_surface else 0) + spray_bytes \
            + sum(_nbytes(value) for _, value in self._statics)
        self._save(new_bytes)
        self.last_frame = frame
        self.frame_bytes.append(os.path.getsize(self.path) - size_before)
        self.write_seconds.append(time.perf_counter() - t_start)

    def close(self) -> None:
        """Save and release the stage (idempotent). After a refused or failed save the stage is
        released unsaved: the file keeps its last good save."""
        if self.stage is not None:
            try:
                if not self._failed and self.stage.GetRootLayer().dirty:
                    self._save(0)
            finally:
                self.stage = None

    def __enter__(self) -> UsdWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
