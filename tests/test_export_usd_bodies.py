"""Moving rigid bodies in the USD export (UsdWriter.add_body, write_frame(bodies=...)): a Mesh per body
with body-frame points and time-sampled translate/orient, valid for check_usd.py --strict, resumable."""
import subprocess
import sys

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom

from warp_sph.io.export_usd import UsdWriter
from warp_sph.rigid.spec import box_mesh, quat_to_matrix, rotation_quaternion, sphere_mesh

FPS, RADIUS = 24.0, 0.02
BODIES = {"crate": box_mesh([0.2, 0.1, 0.05]), "ball": sphere_mesh(0.1, 2)}


def check_usd_strict(path) -> subprocess.CompletedProcess:
    """The checker shipped with warp-sph (``python -m warp_sph.io.check_usd FILE --strict``)."""
    return subprocess.run([sys.executable, "-m", "warp_sph.io.check_usd", str(path), "--strict"],
                          capture_output=True, text=True, timeout=120)


def pose(name: str, frame: int):
    """A centre of mass [m] and quaternion (x, y, z, w) that change with the frame."""
    k = 0 if name == "crate" else 1
    p = np.array([0.1 * frame, -0.05 * frame * k, 1.0 - 0.02 * frame * frame])
    q = rotation_quaternion((10.0 * frame, 25.0 * k, -7.0 * frame))
    return p, q


def write(path, frames, resume_after=None, origin=None):
    rng = np.random.default_rng(0)
    with UsdWriter(path, FPS, RADIUS, primvars=(), with_surface=False, resume_after_frame=resume_after,
                   origin=origin) as w:
        for name, (v, t) in BODIES.items():
            w.add_body(name, v, t)
        for f in frames:
            x = rng.uniform(-1, 1, size=(20, 3)).astype(np.float32)
            shift = np.zeros(3) if origin is None else np.asarray(origin)
            w.write_frame(f, x + shift, np.zeros_like(x), bodies={n: (pose(n, f)[0] + shift, pose(n, f)[1])
                                                                  for n in BODIES})


@pytest.mark.parametrize("origin", [None, (1.0e4, -2.0e4, 5.0e3)])
def test_body_prims_and_world_points(tmp_path, origin):
    """World points through /sph's translate (the origin of a far scene) and the body's xform."""
    path = tmp_path / "bodies.usdc"
    write(path, range(1, 5), origin=origin)
    shift = np.zeros(3) if origin is None else np.asarray(origin)
    stage = Usd.Stage.Open(str(path))
    cache = UsdGeom.XformCache()
    for name, (verts, tris) in BODIES.items():
        prim = stage.GetPrimAtPath(f"/sph/bodies/{name}")
        assert prim.IsA(UsdGeom.Mesh)
        mesh = UsdGeom.Mesh(prim)
        assert [op.GetOpName() for op in mesh.GetOrderedXformOps()] == ["xformOp:translate", "xformOp:orient"]
        assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
        assert mesh.GetPointsAttr().GetTimeSamples() == [1.0, 2.0, 3.0, 4.0]
        for f in range(1, 5):
            local = np.asarray(mesh.GetPointsAttr().Get(f), dtype=np.float64)
            assert np.allclose(local, verts, atol=1e-7)  # body frame, unchanged
            cache.SetTime(Usd.TimeCode(f))
            m = np.array(cache.GetLocalToWorldTransform(prim))  # row-vector convention: x' = x M
            world = np.c_[local, np.ones(len(local))] @ m
            p, q = pose(name, f)
            np.testing.assert_allclose(world[:, :3], local @ quat_to_matrix(q).T + p + shift, atol=1e-6, rtol=0)
    result = check_usd_strict(path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "/sph/bodies/crate" in result.stdout and "winding outward" in result.stdout


def test_resume_keeps_bodies(tmp_path):
    path = tmp_path / "bodies.usdc"
    write(path, range(1, 6))
    write(path, range(3, 5), resume_after=2)  # frames 3, 4 rewritten, 5 dropped
    stage = Usd.Stage.Open(str(path))
    op = UsdGeom.Mesh(stage.GetPrimAtPath("/sph/bodies/ball")).GetOrderedXformOps()[1]
    assert op.GetTimeSamples() == [1.0, 2.0, 3.0, 4.0]
    q = pose("ball", 4)[1]
    assert op.Get(4) == Gf.Quatf(*map(float, (q[3], q[0], q[1], q[2])))
    result = check_usd_strict(path)
    assert result.returncode == 0, result.stdout + result.stderr


def test_body_errors(tmp_path):
    verts, tris = BODIES["crate"]
    with UsdWriter(tmp_path / "e.usdc", FPS, RADIUS, primvars=(), with_surface=False) as w:
        with pytest.raises(ValueError, match="identifier"):
            w.add_body("no good", verts, tris)
        with pytest.raises(ValueError, match="out of range"):
            w.add_body("crate", verts, tris + 100)
        w.add_body("crate", verts, tris)
        x = np.zeros((3, 3), np.float32)
        with pytest.raises(ValueError, match="poses of bodies"):
            w.write_frame(1, x, x)
        with pytest.raises(ValueError, match="not finite"):
            w.write_frame(1, x, x, bodies={"crate": ((0, np.nan, 0), (0, 0, 0, 1))})
        assert w.last_frame == 0  # nothing of the refused frame was written
        w.write_frame(1, x, x, bodies={"crate": ((0, 0, 0), (0, 0, 0, 1))})
        with pytest.raises(ValueError, match="before the first frame"):
            w.add_body("late", verts, tris)
