"""What a real run leaves in its folder: a Blender-ready USD (checked here and by the shipped
``warp_sph.io.check_usd --strict``), checkpoints a resumed run continues bit for bit, a USD that
survives SIGKILL, and re-exports from the recorded frames (``warp-sph export``).

All runs are a small dam break (particle_radius 0.05 m: 729 fluid particles) on the CPU.
"""
import contextlib
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import meshio
import numpy as np
import pytest
from pxr import Usd, UsdGeom

from warp_sph.run import runner
from warp_sph.io import check_usd
from warp_sph.io import run_folder as rf
from warp_sph.cli import main as cli_main
from warp_sph.core.errors import OutputError, WarpSphError
from warp_sph.io.reexport import export_run, parse_frame_range
from warp_sph.scene import list_scenes, load_scene

SMALL = ["particle_radius=0.05", "output.checkpoint_every=3"]
FRAMES = 7


def run_checker_strict(path: Path) -> None:
    """warp_sph.io.check_usd --strict (the checker shipped with the package) passes."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = check_usd.main([str(path), "--strict"])
    assert code == 0, out.getvalue()


def quiet(*args, **kwargs):
    pass


def run_small(out: Path, frames: int, extra=(), scene="dam_break", **kw) -> dict:
    return runner.run(load_scene(scene, overrides=SMALL + list(extra)), out=out, device="cpu", frames=frames,
                      progress=False, log=quiet, **kw)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted 7-frame run (checkpoints at frames 1, 4, 7)."""
    out = tmp_path_factory.mktemp("reference") / "run"
    run_small(out, FRAMES)
    return out


def usd_path(out: Path) -> Path:
    (path,) = sorted(Path(out).glob("*.usdc"))
    return path


def usd_samples(path: Path) -> dict:
    """Every time sample of every attribute: {(attribute path, time): numpy value}."""
    stage = Usd.Stage.Open(str(path))
    out = {}
    for prim in stage.Traverse():
        for attr in prim.GetAttributes():
            for t in attr.GetTimeSamples():
                out[(str(attr.GetPath()), t)] = np.asarray(attr.Get(t))
    return out


def assert_blender_ready(path: Path, frames: int, first: int = 1, radius: float = 0.05) -> None:
    """What Blender's importer needs (notes/usd_blender.md), checked on every prim and sample."""
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == stage.GetFramesPerSecond() > 0
    assert stage.GetStartTimeCode() == first and stage.GetEndTimeCode() == first + frames - 1
    assert stage.GetDefaultPrim().GetPath() == "/sph"
    times = [float(t) for t in range(first, first + frames)]
    gprims = [p for p in stage.Traverse() if p.IsA(UsdGeom.Points) or p.IsA(UsdGeom.Mesh)]
    assert {"particles", "surface", "spray", "container"} <= {p.GetName() for p in gprims}
    for prim in gprims:
        g = UsdGeom.PointBased(prim)
        assert [float(t) for t in g.GetPointsAttr().GetTimeSamples()] == times, prim.GetPath()
        assert [float(t) for t in g.GetExtentAttr().GetTimeSamples()] == times, prim.GetPath()
        for t in times:
            pts = np.asarray(g.GetPointsAttr().Get(t), dtype=np.float64).reshape(-1, 3)
            assert np.all(np.isfinite(pts)), (prim.GetPath(), t)
            lo, hi = np.asarray(g.GetExtentAttr().Get(t), dtype=np.float64)
            pad = 0.0
            if prim.IsA(UsdGeom.Points):
                widths = np.asarray(UsdGeom.Points(prim).GetWidthsAttr().Get(t))
                # spray: 2 r, or one 1e-4 r placeholder point on a frame without spray (export_usd.py)
                allowed = [2 * radius, 1e-4 * radius] if prim.GetName() == "spray" else [2 * radius]
                assert len(widths) == 1 and min(abs(widths[0] - w) for w in allowed) < 1e-6 * radius
                pad = 0.5 * float(widths[0])
                v = np.asarray(UsdGeom.Points(prim).GetVelocitiesAttr().Get(t))
                assert v.shape == pts.shape and np.all(np.isfinite(v))
            if len(pts):
                assert np.all(lo <= pts.min(0) - pad + 1e-5) and np.all(hi >= pts.max(0) + pad - 1e-5)
            if prim.GetName() == "surface":  # vertex normals: unit, one per point
                n = np.asarray(UsdGeom.PrimvarsAPI(prim).GetPrimvar("normals").Get(t), dtype=np.float64).reshape(-1, 3)
                assert n.shape == pts.shape and np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-4)
            if prim.IsA(UsdGeom.Mesh):
                mesh = UsdGeom.Mesh(prim)
                assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
                counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(t))
                idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(t))
                assert np.all(counts == 3) and counts.sum() == len(idx)
                if len(idx):
                    assert idx.min() >= 0 and idx.max() < len(pts)
                    tris = idx.reshape(-1, 3)
                    assert not np.any((tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2]))
                    if prim.GetName() == "surface":  # closed, wound outward: positive volume
                        a, b, c = pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]]
                        assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() > 0, t


# -- the USD of a run ---------------------------------------------------------------------------
def test_run_usd_passes_check_usd_strict(reference):
    run_checker_strict(usd_path(reference))


def test_run_usd_is_blender_ready(reference):
    path = usd_path(reference)
    assert_blender_ready(path, FRAMES)
    info = rf.read_run_json(reference)
    assert info["status"] == "completed" and len(info["frames"]) == FRAMES
    stage = Usd.Stage.Open(str(path))
    n = info["fluid_particles"]
    for f in range(1, FRAMES + 1):
        rec = np.load(rf.frame_path(reference, f))
        assert np.array_equal(np.asarray(stage.GetAttributeAtPath("/sph/particles.points").Get(f)), rec["x"])
        assert len(rec["x"]) == n and float(rec["time"]) == pytest.approx((f - 1) / 24.0)
    assert sorted(p.name for p in (reference / "checkpoints").iterdir()) == \
        ["checkpoint_000001.npz", "checkpoint_000004.npz", "checkpoint_000007.npz"]


def test_obstacle_meshes_in_usd(tmp_path):
    out = tmp_path / "obstacle"
    run_small(out, 2, scene="obstacle", extra=["output.checkpoint_every=0"])
    path = usd_path(out)
    assert_blender_ready(path, 2)
    run_checker_strict(path)
    stage = Usd.Stage.Open(str(path))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/sph/obstacle_0"))
    assert mesh, [str(p.GetPath()) for p in stage.Traverse()]
    pts = np.asarray(mesh.GetPointsAttr().Get(2))
    # scenes/obstacle.toml: cylinder of radius 0.15 m, height 0.6 m standing at (1.6, 0.505, 0)
    assert pts[:, 2].min() == pytest.approx(0.0, abs=1e-6) and pts[:, 2].max() == pytest.approx(0.6, abs=1e-5)
    assert np.hypot(pts[:, 0] - 1.6, pts[:, 1] - 0.505).max() == pytest.approx(0.15, rel=1e-3)
    assert not (out / "checkpoints").exists()


# -- checkpoints and resume -----------------------------------------------------------------------
def assert_same_run(a: Path, b: Path) -> None:
    """Recorded frames, USD samples and per-frame statistics of two runs are bitwise equal."""
    fa, fb = sorted((a / "frames").iterdir()), sorted((b / "frames").iterdir())
    assert [p.name for p in fa] == [p.name for p in fb]
    for pa, pb in zip(fa, fb):
        da, db = np.load(pa), np.load(pb)
        assert sorted(da.files) == sorted(db.files)
        for k in da.files:
            assert np.array_equal(da[k], db[k]), (pa.name, k)
    sa, sb = usd_samples(usd_path(a)), usd_samples(usd_path(b))
    assert sorted(sa) == sorted(sb)
    for key in sa:
        assert np.array_equal(sa[key], sb[key]), key
    ia, ib = rf.read_run_json(a), rf.read_run_json(b)
    assert ia["frames"] == ib["frames"] and ia["steps"] == ib["steps"]


def test_resume_reproduces_uninterrupted_run(reference, tmp_path):
    out = tmp_path / "resumed"
    run_small(out, 5, threaded_export=False)  # checkpoints 1, 4 and the final one, 5
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == \
        ["checkpoint_000001.npz", "checkpoint_000004.npz", "checkpoint_000005.npz"]
    rf.checkpoint_path(out, 5).unlink()  # as if stopped before it: frame 5 is recomputed after the resume
    before = rf.read_run_json(out)["frame_times"]
    info = runner.run(None, frames=FRAMES, resume=out, progress=False, device="cpu", log=quiet)
    assert info["status"] == "completed"
    assert_same_run(reference, out)
    # each advanced frame's own timing: the frames up to the checkpoint as the first session measured them, the
    # others from the resumed session, one entry per frame with the frame's substeps
    times = rf.read_run_json(out)["frame_times"]
    assert [t["frame"] for t in times] == list(range(2, FRAMES + 1))
    assert times[:3] == before[:3] and [t["frame"] for t in before] == [2, 3, 4, 5]
    assert [t["steps"] for t in times] == [f["steps"] for f in info["frames"][1:]]
    assert all(t["wall_time"] >= t["step_seconds"] > 0 and t["cpu_time"] > 0 for t in times)
    assert [t["first_step"] for t in times] == [True, False, False, True, False, False]  # each session's first step
    assert info["array_bytes"] > 0  # the arrays the steps read (``run.working_set``)
    assert_blender_ready(usd_path(out), FRAMES)


def test_finished_run_is_complete_or_extended(reference, tmp_path):
    """--resume of a finished run simulates nothing ("already complete"); with --frames beyond its
    end it continues from the final checkpoint, and equals the longer uninterrupted run."""
    out = tmp_path / "finished"
    run_small(out, 5)
    before = {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    said = []
    info = runner.run(None, resume=out, progress=False, device="cpu", log=said.append)
    assert any("already complete" in line for line in said), said
    assert info["status"] == "completed" and len(info["frames"]) == 5
    assert {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()} == before
    said.clear()
    runner.run(None, frames=FRAMES, resume=out, progress=False, device="cpu", log=said.append)
    assert any("resuming" in line and "from frame 5" in line for line in said), said
    assert_same_run(reference, out)


def test_resume_errors(tmp_path):
    with pytest.raises(OutputError, match="run.json"):
        runner.run(None, resume=tmp_path, progress=False, log=quiet)
    out = tmp_path / "nocp"
    run_small(out, 2, extra=["output.checkpoint_every=0"])
    with pytest.raises(OutputError, match="no checkpoint"):  # complete with 2 frames; a third needs one
        runner.run(None, resume=out, frames=3, progress=False, log=quiet)


def test_sigkill_then_resume(reference, tmp_path):
    """A run killed with SIGKILL keeps a USD holding every frame saved before the kill, each sample
    readable, with endTimeCode = the number of frames; resuming it reproduces the uninterrupted run."""
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "warp_sph.cli", "run", "--out", str(out), "--frames", "400", "--device", "cpu",
           "--no-progress"] + [a for s in SMALL for a in ("--set", s)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not rf.frame_path(out, 4).exists():
            assert proc.poll() is None, proc.stderr.read()
            assert time.monotonic() < deadline, "no frame 4 within 60 s"
            time.sleep(0.01)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    stage = Usd.Stage.Open(str(usd_path(out)))
    end = int(stage.GetEndTimeCode())
    assert 3 <= end < 400
    for prim in ("/sph/particles", "/sph/surface", "/sph/container"):
        attr = stage.GetAttributeAtPath(f"{prim}.points")
        assert [float(t) for t in attr.GetTimeSamples()] == [float(f) for f in range(1, end + 1)], prim
        for f in range(1, end + 1):
            assert np.all(np.isfinite(np.asarray(attr.Get(f))))
    recorded = sorted(int(p.stem.split("_")[1]) for p in (out / "frames").glob("frame_*.npz"))
    assert recorded[:end] == list(range(1, end + 1))
    # a checkpoint on disk implies its frame's outputs are: resume from it continues the file
    k = int(np.load(rf.latest_checkpoint(out))["frame"])
    assert k <= end and k <= recorded[-1]
    frames = max(end, k) + 2
    runner.run(None, frames=frames, resume=out, progress=False, device="cpu", log=quiet)
    ref = reference
    if frames != FRAMES:
        ref = tmp_path / "uninterrupted"
        run_small(ref, frames)
    assert_same_run(ref, out)
    assert_blender_ready(usd_path(out), frames)
    run_checker_strict(usd_path(out))


# -- re-export ------------------------------------------------------------------------------------
def test_export_usd_finer_surface(reference, tmp_path):
    out = tmp_path / "fine.usdc"
    path = export_run(reference, fmt="usd", out=out, cell_per_radius=0.5, frames="2:4")
    assert path == out
    assert_blender_ready(out, 3, first=2)
    run_checker_strict(out)
    run_stage, fine = Usd.Stage.Open(str(usd_path(reference))), Usd.Stage.Open(str(out))
    for f in (2, 3, 4):
        for attr in ("/sph/particles.points", "/sph/particles.velocities", "/sph/particles.primvars:density"):
            assert np.array_equal(np.asarray(fine.GetAttributeAtPath(attr).Get(f)),
                                  np.asarray(run_stage.GetAttributeAtPath(attr).Get(f))), (attr, f)
        # the run's surface cell is 1.0 r: a 0.5 r grid gives about 4x the raw triangles, and decimation
        # (same error bound) keeps more of the finer mesh's detail
        n_run = len(run_stage.GetAttributeAtPath("/sph/surface.faceVertexIndices").Get(f))
        n_fine = len(fine.GetAttributeAtPath("/sph/surface.faceVertexIndices").Get(f))
        assert n_fine / n_run > 2.0
    with pytest.raises(OutputError, match="overwrite"):
        export_run(reference, fmt="usd", out=out, frames="2:4")
    export_run(reference, fmt="usd", out=out, frames="3:3", overwrite=True)
    assert Usd.Stage.Open(str(out)).GetStartTimeCode() == Usd.Stage.Open(str(out)).GetEndTimeCode() == 3


def test_export_same_settings_reproduces_run_surface(reference, tmp_path):
    path = export_run(reference, fmt="usd", out=tmp_path, frames="1:2")
    assert path == tmp_path / "dam_break.usdc"
    a, b = Usd.Stage.Open(str(usd_path(reference))), Usd.Stage.Open(str(path))
    for f in (1, 2):
        va = np.asarray(a.GetAttributeAtPath("/sph/surface.points").Get(f))
        vb = np.asarray(b.GetAttributeAtPath("/sph/surface.points").Get(f))
        # the run meshes the recorded float32 world positions re-localised as the export does: same input,
        # same (deterministic) pipeline, so the same surface, spray and normals
        assert len(va) == len(vb), (len(va), len(vb))
        assert np.array_equal(va, vb)
        for attr in ("/sph/surface.faceVertexIndices", "/sph/surface.primvars:normals", "/sph/spray.points"):
            assert np.array_equal(np.asarray(a.GetAttributeAtPath(attr).Get(f)),
                                  np.asarray(b.GetAttributeAtPath(attr).Get(f))), (attr, f)


@pytest.mark.parametrize("fmt", ["obj", "ply", "vtk"])
def test_export_mesh_sequence(reference, tmp_path, fmt):
    out = tmp_path / fmt
    assert cli_main(["export", str(reference), "--format", fmt, "--out", str(out), "--frames", "6:7",
                     "--surface-cell", "1.0"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [f"surface_000006.{fmt}", f"surface_000007.{fmt}"]
    mesh = meshio.read(out / f"surface_000007.{fmt}")
    assert len(mesh.cells_dict["triangle"]) > 100 and np.all(np.isfinite(mesh.points))
    assert cli_main(["export", str(reference), "--format", fmt, "--out", str(out), "--frames", "5"]) == 2
    assert cli_main(["export", str(reference), "--format", fmt, "--out", str(out), "--frames", "5",
                     "--overwrite"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [f"surface_000005.{fmt}"]


def _copy_run(reference: Path, dest: Path, frames=(1, 2, 3, 4)) -> Path:
    """run.json and the recorded frames ``frames`` of the reference run, in a folder of their own."""
    (dest / "frames").mkdir(parents=True)
    shutil.copy(reference / "run.json", dest / "run.json")
    for f in frames:
        shutil.copy(rf.frame_path(reference, f), rf.frame_path(dest, f))
    return dest


def _crc_damaged(path: Path) -> None:
    """Flip bytes inside the stored x array: the archive's directory still reads, its data fails the CRC."""
    data = bytearray(path.read_bytes())
    start = data.index(b"x.npy") + 200
    data[start:start + 16] = bytes(16)
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("damage", ["truncated", "crc"])
def test_export_of_a_damaged_frame_keeps_the_last_good_export(reference, tmp_path, capsys, damage):
    """``export --overwrite`` removed the good USD first and then stopped at a damaged frame, leaving a partial
    one (and a mesh sequence lost its old files first). Now the export goes to a hidden file beside it and
    replaces it only when every frame is in: one line naming the frame file, exit 2, the old files as they
    were, nothing left behind."""
    run = _copy_run(reference, tmp_path / "run")
    out = tmp_path / "out.usdc"
    assert cli_main(["export", str(run), "--out", str(out), "--frames", "1:4"]) == 0
    meshes = tmp_path / "obj"
    assert cli_main(["export", str(run), "--format", "obj", "--out", str(meshes), "--frames", "1:4"]) == 0
    good, good_obj = out.read_bytes(), {p.name: p.read_bytes() for p in meshes.iterdir()}
    capsys.readouterr()
    frame = rf.frame_path(run, 3)
    if damage == "truncated":
        frame.write_bytes(frame.read_bytes()[:1000])
    else:
        _crc_damaged(frame)
    errors = []
    assert cli_main(["export", str(run), "--out", str(out), "--frames", "1:4", "--overwrite"]) == 2
    assert out.read_bytes() == good
    errors.append(capsys.readouterr().err)
    assert cli_main(["export", str(run), "--format", "obj", "--out", str(meshes), "--frames", "1:4", "--overwrite"]) == 2
    assert {p.name: p.read_bytes() for p in meshes.iterdir()} == good_obj
    errors.append(capsys.readouterr().err)
    for err in errors:
        err = err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"warp-sph: error: {frame}: unreadable recorded frame ("), err
        assert err[0].endswith("; --frames 1:2 exports the frames before it"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["obj", "out.usdc", "run"]  # no temporary file left
    # a new export is not created at all
    assert cli_main(["export", str(run), "--frames", "1:4"]) == 2
    assert not [p for p in run.rglob("*") if p.is_file() and p.parent.name != "frames" and p.name != "run.json"]


def test_export_to_a_file_that_is_not_usd_is_refused(reference, tmp_path, capsys):
    """``export RUN --out notes.txt --overwrite`` removed the user's notes.txt, then failed in USD's own
    traceback-like message (no file format for .txt). Now: one line before anything, the file kept."""
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    assert cli_main(["export", str(reference), "--out", str(notes), "--frames", "1:1", "--overwrite"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0] == (f"warp-sph: error: --out {notes}: a USD export is written to a .usdc file "
                                        "(or .usd, .usda); name it so, or give a folder"), err
    assert notes.read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_export_default_location_and_errors(reference, tmp_path, capsys):
    assert cli_main(["export", str(reference), "--format", "obj", "--frames", "7:"]) == 0
    assert (reference / "export" / "obj" / "surface_000007.obj").is_file()
    assert cli_main(["export", str(reference), "--frames", "3:99"]) == 2
    assert "not recorded" in capsys.readouterr().err
    assert cli_main(["export", str(tmp_path)]) == 2
    with pytest.raises(WarpSphError):
        parse_frame_range("a:b", [1, 2])
    with pytest.raises(WarpSphError):
        parse_frame_range("3:2", [1, 2, 3])
    assert parse_frame_range(None, [1, 2, 3]) == [1, 2, 3]
    assert parse_frame_range(":2", [1, 2, 3]) == [1, 2]
    info = json.loads((reference / "run.json").read_text())
    assert info["status"] == "completed"  # exports leave the run itself alone


# -- every built-in scene, default outputs ----------------------------------------------------------
@pytest.mark.parametrize("name", [n for n, _ in list_scenes()])
def test_builtin_scene_with_default_outputs(name, tmp_path, monkeypatch):
    """Each built-in scene as shipped (USD, surface, recorded frames, checkpoints on) writes a USD
    that passes check_usd --strict, with its container and obstacles, and re-exports."""
    monkeypatch.chdir(tmp_path)
    scene = load_scene(name)
    info = runner.run(scene, device="cpu", frames=2, progress=False, log=quiet)
    out = Path(info["out"])
    assert out == Path("runs") / name and info["status"] == "completed"
    path = usd_path(out)
    run_checker_strict(path)
    stage = Usd.Stage.Open(str(path))
    names = {p.GetName() for p in stage.GetPrimAtPath("/sph").GetChildren()}
    assert ("container" in names) == (scene.container is not None), names
    obstacles = list(enumerate(scene.obstacles or []))
    assert {f"obstacle_{i}" for i, ob in obstacles if not ob.animated} <= names
    moving = {p.GetName() for p in stage.GetPrimAtPath("/sph/bodies").GetChildren()} if "bodies" in names else set()
    assert {ob.name or f"obstacle{i}" for i, ob in obstacles if ob.animated} <= moving  # animated: /sph/bodies/<name>
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["checkpoint_000001.npz", "checkpoint_000002.npz"]
    exported = export_run(out, fmt="usd", frames="2:2")
    run_checker_strict(exported)


# -- file modes ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("umask", [0o022, 0o027, 0o002])
def test_files_follow_the_umask(umask, tmp_path):
    """run.json, frames, checkpoints, the USD, mesh files and exports get 0666 & ~umask, as any
    file the user's programs create (mkstemp alone gives 0600)."""
    old = os.umask(umask)
    try:
        out = tmp_path / "run"
        run_small(out, 2, extra=['output.mesh_sequence="obj"'])
        export_run(out, fmt="obj", frames="2:2")
        export_run(out, fmt="usd", frames="1:2")
        files = [p for p in out.rglob("*") if p.is_file()]
        assert {p.suffix for p in files} >= {".json", ".npz", ".usdc", ".obj"}
        for p in files:
            assert (p.stat().st_mode & 0o777) == 0o666 & ~umask, (p, oct(p.stat().st_mode & 0o777))
    finally:
        os.umask(old)


# -- a scene far from the origin -----------------------------------------------------------------------
FAR = np.array([1.0e4, -2.0e4, 1.0e4])


def _shifted(offset) -> list[str]:
    lo, hi = np.array([0.0, 0.0, 0.0]) + offset, np.array([1.2, 0.6, 1.0]) + offset
    flo, fhi = lo, np.array([0.5, 0.6, 0.5]) + offset
    vec = lambda a: "[" + ",".join(repr(float(v)) for v in a) + "]"  # noqa: E731
    return [f"container.min={vec(lo)}", f"container.max={vec(hi)}", f"fluid[0].min={vec(flo)}",
            f"fluid[0].max={vec(fhi)}", "output.checkpoint_every=0"]


def test_far_from_origin_keeps_positions(tmp_path):
    """The same tank at 1e4 m: statistics equal, and recorded frames and USD points (through the
    /sph translate) give the world positions to 1e-6 m (float32 world coordinates: 4.9e-4 m)."""
    said = []
    near = runner.run(load_scene("dam_break", overrides=SMALL + _shifted(np.zeros(3))), out=tmp_path / "near",
                      device="cpu", frames=3, progress=False, log=quiet)
    far = runner.run(load_scene("dam_break", overrides=SMALL + _shifted(FAR)), out=tmp_path / "far",
                     device="cpu", frames=3, progress=False, log=said.append)
    assert any("float64" in line for line in said), said
    for a, b in zip(near["frames"], far["frames"]):
        assert a["steps"] == b["steps"]
        assert a["density_error_max"] == pytest.approx(b["density_error_max"], abs=1e-5)
    far_stage = Usd.Stage.Open(str(usd_path(tmp_path / "far")))
    near_stage = Usd.Stage.Open(str(usd_path(tmp_path / "near")))
    run_checker_strict(usd_path(tmp_path / "far"))
    cache = UsdGeom.XformCache(3)
    m = np.asarray(cache.GetLocalToWorldTransform(far_stage.GetPrimAtPath("/sph/particles")))
    assert np.allclose(m[:3, :3], np.eye(3)) and np.allclose(m[3, :3], FAR + [0.6, 0.3, 0.5])
    for f in (1, 3):
        xn = np.load(rf.frame_path(tmp_path / "near", f))["x"].astype(np.float64)
        xf = np.load(rf.frame_path(tmp_path / "far", f))["x"]
        assert xf.dtype == np.float64
        assert np.abs(xf - FAR - xn).max() < 1e-6
        pf = np.asarray(far_stage.GetAttributeAtPath("/sph/particles.points").Get(f), dtype=np.float64) + m[3, :3]
        pn = np.asarray(near_stage.GetAttributeAtPath("/sph/particles.points").Get(f), dtype=np.float64)
        assert np.abs(pf - FAR - pn).max() < 1e-6
    # a re-export keeps the origin, and so does the container mesh
    exported = export_run(tmp_path / "far", fmt="usd", out=tmp_path / "far.usdc")
    run_checker_strict(exported)
    stage = Usd.Stage.Open(str(exported))
    m2 = np.asarray(UsdGeom.XformCache(2).GetLocalToWorldTransform(stage.GetPrimAtPath("/sph/container")))
    box = np.asarray(stage.GetAttributeAtPath("/sph/container.points").Get(2), dtype=np.float64) + m2[3, :3]
    assert np.allclose(box.min(0), FAR, atol=1e-9) and np.allclose(box.max(0), FAR + [1.2, 0.6, 1.0], atol=1e-9)


# -- progress bar and summary agree ------------------------------------------------------------------
def test_progress_shows_the_summary_error(tmp_path, capsys):
    """The radial expansion is compressed at frame 1 only: the bar's figure is the largest error of
    any frame so far, as in the summary, not the last frame's (negative) one."""
    info = runner.run(load_scene("radial_expansion", overrides=["particle_radius=0.05"]), out=tmp_path / "r",
                      device="cpu", frames=4, progress=True, log=quiet)
    err = capsys.readouterr().err
    shown = [float(v) for v in re.findall(r"max density error\s+(-?[\d.]+) %", err)]
    assert shown, err
    worst = max(f["density_error_max"] for f in info["frames"])
    assert info["frames"][-1]["density_error_max"] < worst
    assert shown[-1] == pytest.approx(100 * worst, abs=0.006)
    cli_main_out = io.StringIO()
    from warp_sph.cli_commands import print_summary
    with contextlib.redirect_stdout(cli_main_out):
        print_summary(info)
    assert f"max {100 * worst:.3f} %" in cli_main_out.getvalue()
