"""USD writer (layout of notes/usd_blender.md section 2), resume, crash safety; mesh sequences."""
import contextlib
import io
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
import types
from pathlib import Path

import meshio
import numpy as np
import pytest
from pxr import Usd, UsdGeom

from warp_sph.core.errors import OutputError
from warp_sph.io import check_usd
from warp_sph.io.export_mesh import MeshSequenceWriter
from warp_sph.io.export_usd import UsdWriter, container_box_mesh

FPS = 24.0
RADIUS = 0.02
N_PARTICLES = 64


def frame_data(frame: int, n: int = N_PARTICLES):
    """Deterministic per-frame particles and a surface whose topology changes with the frame."""
    rng = np.random.default_rng(frame)
    x = rng.uniform(-1.0, 1.0, size=(n, 3)).astype(np.float32)
    v = rng.normal(size=(n, 3)).astype(np.float32)
    density = rng.uniform(900.0, 1100.0, size=n).astype(np.float32)
    if frame % 2:
        surface = container_box_mesh((0.0, 0.0, 0.0), (1.0, 1.0, 0.5 + 0.1 * frame), open_top=False)
    else:  # a tetrahedron: different vertex and face counts
        verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, frame]], np.float32)
        surface = (verts, np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]], np.int32))
    return x, v, density, surface


def write_file(path, n_frames=4, empty_frame=3, static=True, **kw):
    static_meshes = [("container", *container_box_mesh((-1, -1, -1), (1, 1, 1)))] if static else []
    with UsdWriter(path, FPS, RADIUS, static_meshes=static_meshes, **kw) as writer:
        for f in range(1, n_frames + 1):
            x, v, density, surface = frame_data(f)
            writer.write_frame(f, x, v, {"density": density}, None if f == empty_frame else surface)
    return path


def samples(attr):
    return [float(t) for t in attr.GetTimeSamples()]


def test_layout_and_roundtrip(tmp_path):
    n = 4
    path = write_file(tmp_path / "run.usdc", n_frames=n, empty_frame=3)
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == FPS and stage.GetFramesPerSecond() == FPS
    assert stage.GetStartTimeCode() == 1 and stage.GetEndTimeCode() == n
    assert stage.GetDefaultPrim().GetPath() == "/sph"
    assert stage.GetRootLayer().GetFileFormat().formatId == "usdc"

    points = UsdGeom.Points(stage.GetPrimAtPath("/sph/particles"))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/sph/surface"))
    assert points and mesh
    density = UsdGeom.PrimvarsAPI(points).GetPrimvar("density")
    assert density.GetInterpolation() == UsdGeom.Tokens.vertex
    assert np.allclose(np.asarray(points.GetWidthsAttr().Get()), [2.0 * RADIUS])
    assert points.GetWidthsInterpolation() == UsdGeom.Tokens.constant
    assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    frames = [float(f) for f in range(1, n + 1)]
    for attr in (points.GetPointsAttr(), points.GetVelocitiesAttr(), points.GetExtentAttr(), density.GetAttr(),
                 mesh.GetPointsAttr(), mesh.GetFaceVertexCountsAttr(), mesh.GetFaceVertexIndicesAttr(),
                 mesh.GetExtentAttr()):
        assert samples(attr) == frames, attr.GetPath()

    for f in range(1, n + 1):
        x, v, rho, (sv, st) = frame_data(f)
        if f == 3:
            sv, st = np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
        px = np.asarray(points.GetPointsAttr().Get(f))
        assert np.array_equal(px, x)
        assert np.array_equal(np.asarray(points.GetVelocitiesAttr().Get(f)), v)
        assert np.array_equal(np.asarray(density.Get(f)), rho)
        lo, hi = np.asarray(points.GetExtentAttr().Get(f))
        assert np.all(lo <= x.min(0) - RADIUS + 1e-6) and np.all(hi >= x.max(0) + RADIUS - 1e-6)
        mv = np.asarray(mesh.GetPointsAttr().Get(f)).reshape(-1, 3)
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(f))
        idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(f))
        assert np.array_equal(mv, sv)
        assert len(counts) == len(st) and np.all(counts == 3)
        assert np.array_equal(idx, st.reshape(-1))
        if len(idx):
            assert idx.min() >= 0 and idx.max() < len(mv)
            lo, hi = np.asarray(mesh.GetExtentAttr().Get(f))
            assert np.all(lo <= mv.min(0)) and np.all(hi >= mv.max(0))

    # static meshes: default values plus an equal time sample per frame (check_usd.py --strict)
    container = UsdGeom.Mesh(stage.GetPrimAtPath("/sph/container"))
    assert container and samples(container.GetPointsAttr()) == frames == samples(container.GetExtentAttr())
    for f in frames:
        assert np.array_equal(np.asarray(container.GetPointsAttr().Get(f)), np.asarray(container.GetPointsAttr().Get()))
    assert len(container.GetFaceVertexCountsAttr().Get()) == 10


def run_checker(path, *args):
    """warp_sph.io.check_usd on ``path`` (in this process): returncode, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = check_usd.main([str(path), *args])
    return types.SimpleNamespace(returncode=code, stdout=out.getvalue(), stderr=err.getvalue())


def test_check_usd_strict(tmp_path):
    path = write_file(tmp_path / "clean.usdc", n_frames=4, empty_frame=None, static=False)
    result = run_checker(path, "--strict")
    assert result.returncode == 0, result.stdout + result.stderr


def test_check_usd_full_file(tmp_path):
    """With a static container and an empty-surface frame the checker (which warns on empty frames)
    reports that warning and nothing else."""
    path = write_file(tmp_path / "full.usdc", n_frames=4, empty_frame=3, static=True)
    result = run_checker(path, "--json")
    report = json.loads(result.stdout)
    unexpected_warnings = [w for w in report["warnings"] if "is empty at" not in w]
    assert not report["errors"] and not unexpected_warnings, report


def test_resume_truncates_later_samples(tmp_path):
    path = write_file(tmp_path / "run.usdc", n_frames=5, empty_frame=None)
    with UsdWriter(path, FPS, RADIUS, resume_after_frame=3) as writer:
        stage = Usd.Stage.Open(str(path))
        assert stage.GetEndTimeCode() == 3
        for prim in stage.Traverse():
            for attr in prim.GetAttributes():
                assert all(t <= 3 for t in attr.GetTimeSamples()), attr.GetPath()
        assert samples(stage.GetAttributeAtPath("/sph/particles.points")) == [1.0, 2.0, 3.0]
        with pytest.raises(ValueError):
            writer.write_frame(5, *frame_data(5)[:2])
        for f in (4, 5, 6):
            x, v, rho, surface = frame_data(f + 100)
            writer.write_frame(f, x, v, {"density": rho}, surface)
    stage = Usd.Stage.Open(str(path))
    assert stage.GetEndTimeCode() == 6
    points = stage.GetAttributeAtPath("/sph/particles.points")
    assert samples(points) == [float(f) for f in range(1, 7)]
    assert np.array_equal(np.asarray(points.Get(2)), frame_data(2)[0])
    assert np.array_equal(np.asarray(points.Get(5)), frame_data(105)[0])
    assert samples(stage.GetAttributeAtPath("/sph/surface.faceVertexIndices")) == [float(f) for f in range(1, 7)]


def test_errors(tmp_path):
    path = write_file(tmp_path / "run.usdc", n_frames=2)
    with pytest.raises(OutputError, match="exists"):
        UsdWriter(path, FPS, RADIUS)
    with pytest.raises(OutputError, match="does not exist"):
        UsdWriter(tmp_path / "missing.usdc", FPS, RADIUS, resume_after_frame=1)
    with pytest.raises(OutputError, match="fps"):
        UsdWriter(path, 2 * FPS, RADIUS, resume_after_frame=1)
    writer = UsdWriter(path, FPS, RADIUS, overwrite=True)
    x, v, rho, surface = frame_data(1)
    with pytest.raises(ValueError, match="expected frame 1"):
        writer.write_frame(2, x, v, {"density": rho}, surface)
    with pytest.raises(ValueError, match="primvars"):
        writer.write_frame(1, x, v, {}, surface)
    writer.write_frame(1, x, v, {"density": rho}, surface)
    writer.close()
    assert Usd.Stage.Open(str(path)).GetEndTimeCode() == 1


WRITER_SCRIPT = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    sys.path.insert(0, {tests!r})
    from test_export_usd import frame_data, FPS, RADIUS
    from warp_sph.io.export_usd import UsdWriter
    writer = UsdWriter({path!r}, FPS, RADIUS)
    for f in range(1, 10000):
        x, v, rho, surface = frame_data(f, n=5000)
        writer.write_frame(f, x, v, {{"density": rho}}, surface)
        print(f, flush=True)
        time.sleep(0.02)
    """
)


def test_sigkill_leaves_readable_frames(tmp_path):
    path = tmp_path / "killed.usdc"
    script = WRITER_SCRIPT.format(tests=str(Path(__file__).resolve().parent), path=str(path))
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        written = 0
        deadline = time.monotonic() + 120
        while written < 4 and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            written = int(line)
        assert written >= 4, proc.stderr.read()
        time.sleep(0.013)  # land somewhere inside a later frame
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    stage = Usd.Stage.Open(str(path))
    end = int(stage.GetEndTimeCode())
    assert end >= written
    frames = [float(f) for f in range(1, end + 1)]
    for attr_path in ("/sph/particles.points", "/sph/particles.velocities", "/sph/particles.extent",
                      "/sph/particles.primvars:density", "/sph/surface.points", "/sph/surface.faceVertexIndices",
                      "/sph/surface.faceVertexCounts", "/sph/surface.extent"):
        assert samples(stage.GetAttributeAtPath(attr_path)) == frames, attr_path
    for f in range(1, end + 1):
        x, _, _, (sv, st) = frame_data(f, n=5000)
        assert np.array_equal(np.asarray(stage.GetAttributeAtPath("/sph/particles.points").Get(f)), x)
        assert len(stage.GetAttributeAtPath("/sph/surface.faceVertexCounts").Get(f)) == len(st)


def test_container_box_mesh_outward():
    lo, hi = np.array([-0.5, 0.0, 0.1]), np.array([1.0, 2.0, 3.0])
    verts, tris = container_box_mesh(lo, hi, open_top=False)
    assert verts.dtype == np.float32 and tris.dtype == np.int32 and tris.shape == (12, 3)
    v = verts.astype(np.float64)
    volume = np.einsum("ij,ij->i", v[tris[:, 0]], np.cross(v[tris[:, 1]], v[tris[:, 2]])).sum() / 6.0
    assert volume == pytest.approx(np.prod(hi - lo))
    center = (lo + hi) / 2
    normals = np.cross(v[tris[:, 1]] - v[tris[:, 0]], v[tris[:, 2]] - v[tris[:, 0]])
    assert np.all(np.einsum("ij,ij->i", normals, v[tris].mean(1) - center) > 0)
    verts, tris = container_box_mesh(lo, hi)
    assert len(tris) == 10
    assert not np.any(np.all(verts[tris][:, :, 2] == np.float32(hi[2]), axis=1))  # no top face


@pytest.mark.parametrize("fmt", ["obj", "ply", "vtk"])
def test_mesh_sequence(tmp_path, fmt):
    writer = MeshSequenceWriter(tmp_path / "meshes", fmt)
    verts, tris = container_box_mesh((0, 0, 0), (1, 2, 3), open_top=False)
    path = writer.write_frame(7, verts, tris)
    assert Path(path).name == f"surface_000007.{fmt}"
    mesh = meshio.read(path)
    assert np.allclose(mesh.points, verts)
    assert np.array_equal(mesh.cells_dict["triangle"], tris)
    empty = writer.write_frame(8, np.zeros((0, 3)), np.zeros((0, 3), np.int32))  # empty surface: still a file
    if fmt == "vtk":  # meshio 5.3 cannot read a VTK file without cells back; check the header
        assert b"POINTS 0" in Path(empty).read_bytes()
    else:
        assert len(meshio.read(empty).points) == 0
    assert sorted(os.listdir(tmp_path / "meshes")) == [f"surface_000007.{fmt}", f"surface_000008.{fmt}"]
    with pytest.raises(ValueError):
        MeshSequenceWriter(tmp_path, "stl")


def _normals(verts):
    n = np.asarray(verts, np.float64) - np.asarray(verts, np.float64).mean(0)
    return (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32)


def test_spray_normals_and_bytes_per_frame(tmp_path):
    """/sph/spray holds the spray points (a 1e-4 r placeholder on a frame without spray), the surface
    carries vertex normals, and the writer reports each frame's bytes."""
    path = tmp_path / "spray.usdc"
    spray_counts = {1: 3, 2: 0, 3: 5}
    with UsdWriter(path, FPS, RADIUS, with_normals=True, with_spray=True) as writer:
        for f, k in spray_counts.items():
            x, v, rho, (verts, tris) = frame_data(f)
            writer.write_frame(f, x, v, {"density": rho}, (verts, tris, _normals(verts)), spray=(x[:k], v[:k]))
        assert len(writer.frame_bytes) == 3 and all(b > 0 for b in writer.frame_bytes)
        assert abs(sum(writer.frame_bytes) - os.path.getsize(path)) < 2048  # the header of frame 1's file
    stage = Usd.Stage.Open(str(path))
    spray = UsdGeom.Points(stage.GetPrimAtPath("/sph/spray"))
    surface = UsdGeom.Mesh(stage.GetPrimAtPath("/sph/surface"))
    for f, k in spray_counts.items():
        x, v, _, (verts, _) = frame_data(f)
        pts = np.asarray(spray.GetPointsAttr().Get(f))
        width = float(spray.GetWidthsAttr().Get(f)[0])
        if k:
            assert np.array_equal(pts, x[:k]) and width == pytest.approx(2 * RADIUS)
            assert np.array_equal(np.asarray(spray.GetVelocitiesAttr().Get(f)), v[:k])
        else:  # one invisible point at the lowest particle, at rest
            assert np.array_equal(pts, x[np.argmin(x[:, 2])][None]) and width == pytest.approx(1e-4 * RADIUS)
            assert np.all(np.asarray(spray.GetVelocitiesAttr().Get(f)) == 0.0)
        lo, hi = np.asarray(spray.GetExtentAttr().Get(f))
        assert np.all(lo <= pts.min(0) - width / 2 + 1e-7) and np.all(hi >= pts.max(0) + width / 2 - 1e-7)
        normals = UsdGeom.PrimvarsAPI(surface).GetPrimvar("normals")
        assert normals.GetInterpolation() == UsdGeom.Tokens.vertex
        assert np.array_equal(np.asarray(normals.Get(f)), _normals(verts))
    with pytest.raises(ValueError, match="normals"):
        with UsdWriter(tmp_path / "bad.usdc", FPS, RADIUS, with_normals=True) as writer:
            x, v, rho, surface = frame_data(1)
            writer.write_frame(1, x, v, {"density": rho}, surface)
    result = run_checker(path, "--strict")
    assert result.returncode == 0, result.stdout + result.stderr
    # resuming keeps the layout; a writer without spray cannot resume a file with it
    with UsdWriter(path, FPS, RADIUS, with_normals=True, with_spray=True, resume_after_frame=2) as writer:
        x, v, rho, (verts, tris) = frame_data(7)
        writer.write_frame(3, x, v, {"density": rho}, (verts, tris, _normals(verts)), spray=None)
    with pytest.raises(OutputError, match="spray"):
        UsdWriter(path, FPS, RADIUS, with_normals=True, resume_after_frame=2)
