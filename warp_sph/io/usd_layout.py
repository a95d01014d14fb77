"""The layout of a run's USD file: creating the stage with its prims, and reopening it to resume.

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
    /sph/bodies/<name>     moving rigid bodies (``add_body``): Mesh whose points are in the body frame
                           (origin at the centre of mass), written like a static mesh, and whose
                           xformOp:translate (centre of mass [m]) and xformOp:orient (quatf) are
                           time-sampled every frame: Blender plays them with a Transform Cache.
    /sph/whitewater/<set>  spray, foam, bubbles: Points with widths, velocities, primvars:age
                           (``usd_whitewater``), only when the scene has [whitewater]

``export_usd.UsdWriter`` writes the frames into this layout; ``check_resumable`` and a resumed
writer open an existing file with ``open_for_resume``, which checks it before anything changes.
"""
from __future__ import annotations

import os

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from ..core.errors import OutputError

#: prim names under /sph that are not static meshes
RESERVED = ("particles", "surface", "spray", "bodies", "whitewater")
#: the parent prim of the moving rigid bodies
BODIES = "/sph/bodies"


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


def vec3f(a: np.ndarray) -> Vt.Vec3fArray:
    """(N, 3) points as a float32 Vt.Vec3fArray (through FromNumpy: a list round trip is ~9x slower)."""
    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32).reshape(-1, 3))


def extent(points: np.ndarray, pad: float) -> Vt.Vec3fArray:
    """The USD extent (lower, upper) [m] of ``points`` grown by ``pad`` [m] (zeros for no points)."""
    if len(points) == 0:
        return vec3f(np.zeros((2, 3)))
    return vec3f(np.stack([points.min(axis=0) - pad, points.max(axis=0) + pad]))


def first_line(exc: BaseException) -> str:
    """The first informative line of an exception (pxr's Tf errors span several lines)."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return lines[0] if lines else type(exc).__name__



def define_points(stage, path: str, with_velocities: bool, width: float | None = None):
    """A Points prim at ``path``: points, extent and widths (constant: ``width`` [m], or set per frame when None)
    and velocities (``with_velocities``) created without samples; returns it."""
    points = UsdGeom.Points.Define(stage, path)
    points.CreatePointsAttr()
    points.CreateExtentAttr()
    if width is None:
        points.CreateWidthsAttr()
    else:
        points.CreateWidthsAttr(Vt.FloatArray([width]))
    points.SetWidthsInterpolation(UsdGeom.Tokens.constant)
    if with_velocities:
        points.CreateVelocitiesAttr()
    return points


def define_triangle_mesh(stage, path: str, verts: np.ndarray, tris: np.ndarray):
    """A Mesh prim of triangles at ``path`` (no subdivision): points ``verts`` [m] (the file's coordinates),
    faces ``tris`` (T, 3) and their extent; returns it."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreatePointsAttr(vec3f(verts))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(tris), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(tris.reshape(-1))))
    mesh.CreateExtentAttr(extent(verts, 0.0))
    return mesh


def create_stage(path: str, fps: float, particle_radius: float, first_frame: int, origin, primvars: tuple[str, ...],
                 with_surface: bool, with_velocities: bool, with_normals: bool, with_spray: bool, static_meshes,
                 overwrite: bool, local) -> Usd.Stage:
    """A new stage at ``path`` with the layout above (not saved yet): /sph (translated by ``origin``
    [m] unless None), /sph/particles, /sph/surface, /sph/spray as chosen, and the static meshes
    (name, vertices [m] in world coordinates, triangles), whose points ``local`` turns into the file's
    float32 points. OutputError when the folder is missing or the file exists without ``overwrite``."""
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise OutputError(f"USD output folder {folder} does not exist")
    if os.path.exists(path):
        if not overwrite:
            raise OutputError(f"USD file {path} already exists; remove it, choose another path, "
                              "or resume it")
        os.remove(path)
    try:
        layer = Sdf.Layer.Find(path)
        if layer is not None:  # still open in this process (a stage someone holds): reuse it, emptied
            layer.Clear()
            stage = Usd.Stage.Open(layer)
        else:
            stage = Usd.Stage.CreateNew(path)
    except Exception as exc:  # pxr raises Tf.ErrorException
        raise OutputError(f"cannot create USD file {path}: {first_line(exc)}") from None
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(first_frame)
    stage.SetEndTimeCode(first_frame)
    root = UsdGeom.Xform.Define(stage, "/sph")
    stage.SetDefaultPrim(root.GetPrim())
    if origin is not None:
        root.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*origin.tolist()))

    points = define_points(stage, "/sph/particles", with_velocities, width=2.0 * particle_radius)
    api = UsdGeom.PrimvarsAPI(points)
    for name in primvars:
        api.CreatePrimvar(name, Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)

    if with_surface:
        mesh = UsdGeom.Mesh.Define(stage, "/sph/surface")
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreatePointsAttr()
        mesh.CreateFaceVertexCountsAttr()
        mesh.CreateFaceVertexIndicesAttr()
        mesh.CreateExtentAttr()
        if with_normals:
            UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("normals", Sdf.ValueTypeNames.Normal3fArray,
                                                    UsdGeom.Tokens.vertex)

    if with_spray:
        define_points(stage, "/sph/spray", with_velocities)

    for name, verts, tris in static_meshes:
        if not Sdf.Path.IsValidIdentifier(name) or name in RESERVED:
            raise ValueError(f"static mesh name {name!r} must be a USD identifier other than {RESERVED}")
        verts = local(verts)
        tris = np.asarray(tris, dtype=np.int32).reshape(-1, 3)
        if len(tris) and (tris.min() < 0 or tris.max() >= len(verts)):
            raise ValueError(f"static mesh {name!r}: triangle indices out of range")
        define_triangle_mesh(stage, f"/sph/{name}", verts, tris)
    return stage


def open_for_resume(path: str, k: int, fps: float, with_surface: bool, with_spray: bool | None = None,
                    with_normals: bool = False) -> tuple[Usd.Stage, int]:
    """Open the file and check it can continue after frame ``k``: (stage, its first frame). OutputError
    naming what does not match (fps, frame range, surface / spray prims (None: not checked), normals)."""
    if k < 0:
        raise ValueError(f"resume_after_frame must be >= 0; got {k}")
    if not os.path.isfile(path):
        raise OutputError(f"cannot resume: USD file {path} does not exist")
    try:
        stage = Usd.Stage.Open(path)
    except Exception as exc:
        raise OutputError(f"cannot resume: USD file {path} does not open: {first_line(exc)}") from None
    if not stage or not stage.GetPrimAtPath("/sph/particles").IsA(UsdGeom.Points):
        raise OutputError(f"cannot resume: {path} has no /sph/particles Points prim (not a warp-sph file?)")
    if stage.GetTimeCodesPerSecond() != fps:
        raise OutputError(f"cannot resume: {path} was written at {stage.GetTimeCodesPerSecond():g} fps, "
                          f"this run exports at {fps:g} fps")
    first_frame = int(stage.GetStartTimeCode())
    if k < first_frame - 1:
        raise OutputError(f"cannot resume after frame {k}: {path} starts at frame {first_frame}")
    end = stage.GetEndTimeCode()
    if end < k:
        raise OutputError(f"cannot resume after frame {k}: {path} ends at frame {end:g}")
    for name, wanted in (("surface", with_surface), ("spray", with_spray)):
        if wanted is not None and wanted != stage.GetPrimAtPath(f"/sph/{name}").IsValid():
            raise OutputError(f"cannot resume: {path} {'lacks' if wanted else 'has'} /sph/{name}")
    if with_normals and \
            not UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/sph/surface")).HasPrimvar("normals"):
        raise OutputError(f"cannot resume: {path} has no surface normals (primvars:normals)")
    return stage, first_frame


def file_origin(stage) -> np.ndarray | None:
    """The translate of /sph (the origin points are relative to) [m], None if it has none."""
    ops = UsdGeom.Xformable(stage.GetPrimAtPath("/sph")).GetOrderedXformOps()
    for op in ops:
        if op.GetOpType() == UsdGeom.XformOp.TypeTranslate:
            value = np.asarray(op.Get(), dtype=np.float64).reshape(3)
            return value if np.any(value) else None
    return None


def clear_after(stage, k: int) -> None:
    """Delete every time sample after frame ``k`` (a resume continues with frame k + 1)."""
    for prim in stage.Traverse():
        for attr in prim.GetAttributes():
            for t in attr.GetTimeSamples():
                if t > k:
                    attr.ClearAtTime(t)
