"""Rigid-body coupling stages (kernels/rigid.py, warp_sph/rigid/coupling.py, sampling.py, spec.py)
against NumPy oracles. No Newton needed: poses are written by hand in Newton's layout."""
import math

import numpy as np
import pytest
import warp as wp

from sph_oracle import W
from warp_sph.core.smoothing import get_smoothing_kernel
from warp_sph.rigid.coupling import BodyParticles
from warp_sph.rigid.sampling import BodySamples, fibonacci_sphere, sample_body
from warp_sph.rigid.spec import Body, body_geometry, box_mesh, quat_to_matrix, rotation_quaternion, sphere_mesh
from warp_sph.scene.mesh_volume import closed_surface_problem, volume_and_centroid as _signed_volume
from warp_sph.scene.meshes import TriangleMesh


def _closed(verts, tris) -> bool:
    return closed_surface_problem(TriangleMesh(verts, tris)) is None


def random_quaternions(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def make_bodies(rng, counts, start):
    """BodyParticles for bodies with ``counts`` random local samples, and random poses/twists/COMs."""
    samples = [BodySamples(local_x=rng.uniform(-0.3, 0.3, size=(c, 3)), normals=np.zeros((c, 3), np.float32),
                           volume=np.full(c, 1e-6, np.float32)) for c in counts]
    bp = BodyParticles(samples, start=start, device="cpu", chunk=64)
    nb = len(counts)
    pose = np.concatenate([rng.uniform(-1, 1, size=(nb, 3)), random_quaternions(rng, nb)], axis=1).astype(np.float32)
    twist = rng.uniform(-2, 2, size=(nb, 6)).astype(np.float32)
    com = rng.uniform(-0.05, 0.05, size=(nb, 3)).astype(np.float32)
    arrays = (wp.array(pose, dtype=wp.transform, device="cpu"), wp.array(twist, dtype=wp.spatial_vector, device="cpu"),
              wp.array(com, dtype=wp.vec3, device="cpu"))
    return samples, bp, pose.astype(np.float64), twist.astype(np.float64), com.astype(np.float64), arrays


def test_place_body_particles_matches_numpy():
    rng = np.random.default_rng(3)
    counts, start = [300, 1, 517], 40
    samples, bp, pose, twist, com, (body_q, body_qd, body_com) = make_bodies(rng, counts, start)
    n = start + bp.count
    bx = wp.array(np.full((n, 3), 7.0, np.float32), dtype=wp.vec3, device="cpu")
    bv = wp.zeros(n, dtype=wp.vec3, device="cpu")
    bp.place(body_q, body_qd, body_com, bx, bv)
    x, v = bx.numpy(), bv.numpy()
    assert np.all(x[:start] == 7.0) and np.all(v[:start] == 0.0)  # static particles untouched
    for k, s in enumerate(samples):
        R = quat_to_matrix(pose[k, 3:])
        xk = s.local_x @ R.T + pose[k, :3]
        x_com = R @ com[k] + pose[k, :3]
        vk = twist[k, :3] + np.cross(twist[k, 3:], xk - x_com)
        sl = slice(start + bp.offsets[k], start + bp.offsets[k + 1])
        np.testing.assert_allclose(x[sl], xk, atol=2e-6)
        np.testing.assert_allclose(v[sl], vk, atol=2e-5)


def test_placed_velocity_is_the_rate_of_the_placed_positions():
    """v from the kernel = d/dt of x from the kernel for a pose advanced by the twist (rigid motion)."""
    rng = np.random.default_rng(4)
    samples, bp, pose, twist, com, (body_q, body_qd, body_com) = make_bodies(rng, [200], 0)
    dt = 1e-4
    # advance the pose: centre of mass moves with v, orientation turns with omega about the COM
    R0 = quat_to_matrix(pose[0, 3:])
    x_com0 = R0 @ com[0] + pose[0, :3]
    w = twist[0, 3:]
    angle = np.linalg.norm(w) * dt
    axis = w / np.linalg.norm(w)
    dq = np.concatenate([axis * math.sin(angle / 2), [math.cos(angle / 2)]])
    from warp_sph.rigid.spec import quat_multiply
    q1 = quat_multiply(dq, pose[0, 3:])
    R1 = quat_to_matrix(q1)
    p1 = x_com0 + twist[0, :3] * dt - R1 @ com[0]
    x1 = samples[0].local_x @ R1.T + p1
    x0 = samples[0].local_x @ R0.T + pose[0, :3]
    bx = wp.zeros(bp.count, dtype=wp.vec3, device="cpu")
    bv = wp.zeros(bp.count, dtype=wp.vec3, device="cpu")
    bp.place(body_q, body_qd, body_com, bx, bv)
    v_mid_fd = (x1 - x0) / dt
    np.testing.assert_allclose(bv.numpy(), v_mid_fd, atol=2e-3 * np.abs(v_mid_fd).max())


def test_wrench_matches_numpy_and_is_bitwise_ordered(monkeypatch):
    rng = np.random.default_rng(5)
    counts, start = [1000, 3, 129], 17
    samples, bp, pose, twist, com, (body_q, body_qd, body_com) = make_bodies(rng, counts, start)
    n = start + bp.count
    bx = wp.zeros(n, dtype=wp.vec3, device="cpu")
    bv = wp.zeros(n, dtype=wp.vec3, device="cpu")
    bp.place(body_q, body_qd, body_com, bx, bv)
    # forces spanning orders of magnitude, so the summation order shows in float32
    f = np.zeros((n, 3), np.float32)  # f[start + i]: the force on moving particle i (the kernel reads f[start:])
    f[start:] = (rng.normal(size=(bp.count, 3)) * 10.0 ** rng.uniform(-3, 3, size=(bp.count, 1))).astype(np.float32)
    forces = wp.array(f[start:], dtype=wp.vec3, device="cpu")
    out = wp.zeros(len(counts), dtype=wp.spatial_vector, device="cpu")
    bp.wrench(body_q, body_com, bx, forces, out)
    got = out.numpy().astype(np.float64)
    x = bx.numpy().astype(np.float64)
    for k in range(len(counts)):
        sl = slice(start + bp.offsets[k], start + bp.offsets[k + 1])
        x_com = quat_to_matrix(pose[k, 3:]) @ com[k] + pose[k, :3]
        F = f[sl].astype(np.float64).sum(axis=0)
        tau = np.cross(x[sl] - x_com, f[sl].astype(np.float64)).sum(axis=0)
        scale_f = np.abs(f[sl]).sum()
        scale_t = (np.linalg.norm(x[sl] - x_com, axis=1) * np.linalg.norm(f[sl], axis=1)).sum()
        np.testing.assert_allclose(got[k, :3], F, atol=1e-5 * scale_f)
        np.testing.assert_allclose(got[k, 3:], tau, atol=1e-5 * scale_t)
        # the force part is plain float32 addition: chunk sums in index order, then chunks in order
        expect = np.zeros(3, np.float32)
        for a in range(bp.offsets[k], bp.offsets[k + 1], 64):
            s = np.zeros(3, np.float32)
            for i in range(a, min(a + 64, bp.offsets[k + 1])):
                s = (s + f[start + i]).astype(np.float32)
            expect = (expect + s).astype(np.float32)
        assert np.array_equal(out.numpy()[k, :3], expect)
    # the same on any number of CPU threads (no float atomics)
    for threads in ("1", "2", "7"):
        monkeypatch.setenv("WARP_SPH_CPU_THREADS", threads)
        again = wp.zeros(len(counts), dtype=wp.spatial_vector, device="cpu")
        bp.wrench(body_q, body_com, bx, forces, again)
        assert np.array_equal(again.numpy(), out.numpy())


def test_closed_meshes_are_outward():
    for verts, tris in (box_mesh([0.2, 0.1, 0.05]), sphere_mesh(0.3, 2)):
        volume, centroid = _signed_volume(verts, tris)
        assert volume > 0 and _closed(verts, tris)
        np.testing.assert_allclose(centroid, 0.0, atol=1e-12)
    assert _signed_volume(*box_mesh([0.2, 0.1, 0.05]))[0] == pytest.approx(0.4 * 0.2 * 0.1)


def test_body_geometry_mass_and_mesh_centre(tmp_path):
    box = body_geometry(Body(shape="box", size=(0.4, 0.2, 0.1), position=(0, 0, 0), density=500.0))
    assert box.mass == pytest.approx(4.0) and box.volume == pytest.approx(0.008)
    sphere = body_geometry(Body(shape="sphere", radius=0.1, position=(0, 0, 0), mass=2.0))
    assert sphere.mass == 2.0 and sphere.density == pytest.approx(2.0 / (4 / 3 * math.pi * 1e-3))
    # a box mesh file offset from its origin and wound inward: recentred on its centroid, flipped outward
    verts, tris = box_mesh([0.1, 0.2, 0.3])
    path = tmp_path / "b.obj"
    with open(path, "w") as fh:
        for v in verts + [1.0, 2.0, 3.0]:
            fh.write(f"v {v[0]} {v[1]} {v[2]}\n")
        for t in tris[:, ::-1] + 1:
            fh.write(f"f {t[0]} {t[1]} {t[2]}\n")
    mesh = body_geometry(Body(shape="mesh", file=str(path), scale=2.0, position=(0, 0, 0), density=100.0))
    assert mesh.volume == pytest.approx(8 * 0.2 * 0.4 * 0.6) and mesh.mass == pytest.approx(100.0 * mesh.volume)
    np.testing.assert_allclose(mesh.vertices.mean(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(mesh.extra["file_centroid"], [2.0, 4.0, 6.0])
    assert _signed_volume(mesh.vertices, mesh.triangles)[0] > 0


def test_rotation_quaternion_is_blender_xyz():
    """Euler XYZ (Blender): R = Rz Ry Rx."""
    a, b, c = 30.0, -50.0, 120.0
    ca, sa = math.cos(math.radians(a)), math.sin(math.radians(a))
    cb, sb = math.cos(math.radians(b)), math.sin(math.radians(b))
    cc, sc = math.cos(math.radians(c)), math.sin(math.radians(c))
    Rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    Rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    np.testing.assert_allclose(quat_to_matrix(rotation_quaternion((a, b, c))), Rz @ Ry @ Rx, atol=1e-12)


@pytest.mark.parametrize("smoothing", ["cubic", "quintic"])
def test_body_samples_and_akinci_volumes(smoothing):
    d = 0.02
    kernel = get_smoothing_kernel(smoothing)
    h = kernel.default_smoothing_length(d)
    for body in (Body(shape="box", size=(0.2, 0.12, 0.08), position=(0, 0, 0), density=500.0),
                 Body(shape="sphere", radius=0.1, position=(0, 0, 0), density=500.0)):
        geo = body_geometry(body)
        s = sample_body(geo, d, smoothing, h, device="cpu")
        x = s.local_x
        # on the surface, about d apart
        if body.shape == "box":
            assert s.count == 11 * 7 * 5 - 9 * 5 * 3  # lattice points on the faces of a 10 x 6 x 4 cell box
            assert np.all(np.isclose(np.abs(x), geo.half_extents).any(axis=1))
        else:
            np.testing.assert_allclose(np.linalg.norm(x, axis=1), 0.1, rtol=1e-12)
            assert s.count == round(4 * math.pi * 0.1**2 / d**2)
        dist = np.linalg.norm(x[:, None] - x[None], axis=2) + np.eye(len(x)) * 1e9
        nearest = dist.min(axis=1)
        assert nearest.min() > 0.6 * d and np.median(nearest) < 1.2 * d
        # outward normals
        assert np.all(np.einsum("ij,ij->i", s.normals, x) > 0)
        # Akinci volumes against the brute-force sum over the body's own samples
        oracle = 1.0 / W(smoothing, np.linalg.norm(x[:, None] - x[None], axis=2), h).sum(axis=1)
        np.testing.assert_allclose(s.volume, oracle, rtol=2e-5)


def test_fibonacci_sphere_count_and_spread():
    x, n = fibonacci_sphere(1.0, 0.1)
    assert len(x) == round(4 * math.pi / 0.01)
    np.testing.assert_allclose(x.mean(axis=0), 0.0, atol=2e-3)  # evenly spread


def test_inset_samples_lie_on_the_inset_surface(tmp_path):
    """Samples on the surface moved inward by the inset (box, sphere, and a box given as a mesh file)."""
    d, inset = 0.02, 0.015
    h = np.array([0.1, 0.06, 0.04])
    box = body_geometry(Body(shape="box", size=tuple(2 * h), position=(0, 0, 0), density=500.0))
    sphere = body_geometry(Body(shape="sphere", radius=0.1, position=(0, 0, 0), density=500.0))
    verts, tris = box_mesh(h)
    path = tmp_path / "box.obj"
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in verts) + "".join(f"f {a} {b} {c}\n" for a, b, c in tris + 1))
    mesh = body_geometry(Body(shape="mesh", file=str(path), position=(0, 0, 0), density=500.0))
    for geo in (box, mesh):
        s = sample_body(geo, d, "cubic", d, inset=inset, device="cpu")
        ratio = np.abs(s.local_x) / (h - inset)
        np.testing.assert_allclose(ratio.max(axis=1), 1.0, atol=1e-9)  # every sample on a face of the inset box
        assert s.count > 100
    s = sample_body(sphere, d, "cubic", d, inset=inset, device="cpu")
    np.testing.assert_allclose(np.linalg.norm(s.local_x, axis=1), 0.1 - inset, rtol=1e-12)
    from warp_sph.core.errors import SceneError
    with pytest.raises(SceneError, match="too thin"):
        sample_body(box, d, "cubic", d, inset=0.04, device="cpu")
