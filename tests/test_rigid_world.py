"""The Newton wrapper (warp_sph/rigid/world.py): analytic motion under gravity and a wrench, contacts with
the container and obstacles, bitwise checkpoint/restore, and the one-line error without Newton.

Newton is in the ``test`` extra; its kernels compile once per machine (~1 min on 2 cores, then cached).
"""
import sys

import numpy as np
import pytest
import warp as wp

from warp_sph.core.errors import SceneError
from warp_sph.rigid import Body, RigidWorld, StaticCollider
from warp_sph.rigid.spec import box_mesh, quat_to_matrix

G = 9.81


def wrench(world, rows):
    return wp.array(np.asarray(rows, dtype=np.float32).reshape(-1, 6), dtype=wp.spatial_vector, device="cpu")


def test_missing_newton_is_one_line_scene_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "newton", None)  # makes `import newton` raise ImportError
    with pytest.raises(SceneError) as err:
        RigidWorld([Body(shape="box", size=(0.1, 0.1, 0.1), position=(0, 0, 0), density=500.0)])
    msg = str(err.value)
    assert msg.startswith("bodies:") and "pip install 'warp-sph[rigid]'" in msg and "\n" not in msg


def test_free_fall_and_substeps_match_symplectic_euler():
    """No contacts: z_M = z0 - g h^2 M (M + 1) / 2 and v_M = -g M h after M Newton steps of h
    (semi-implicit Euler); a call longer than max_substep runs ceil(dt / max_substep) steps."""
    body = Body(shape="box", size=(0.4, 0.2, 0.1), position=(0.5, -0.25, 2.0), density=500.0)
    world = RigidWorld([body], contact_frequency=300.0)
    assert world.max_substep == pytest.approx(1.0 / (4 * 300.0))
    dt = 2.5 * world.max_substep
    n = world.substeps_for(dt)
    assert n == 3
    calls = 40
    for _ in range(calls):
        world.step(dt)
    h, M = dt / n, calls * n
    pose = world.poses()
    assert world.substeps == M and world.steps == calls
    np.testing.assert_allclose(pose["position"][0], [0.5, -0.25, 2.0 - G * h * h * M * (M + 1) / 2], atol=2e-6)
    np.testing.assert_allclose(pose["velocity"][0], [0.0, 0.0, -G * M * h], rtol=1e-5)
    np.testing.assert_allclose(pose["orientation"][0], [0, 0, 0, 1], atol=1e-7)


def test_wrench_world_frame_about_com():
    """A box turned 90 degrees about z, no gravity: F gives v = F t / m; a torque about world x spins it
    about world x with omega = tau t / I_xx^world = tau t / I_yy^body (a principal axis: no precession)."""
    body = Body(shape="box", size=(0.4, 0.2, 0.1), position=(0, 0, 0), rotation=(0, 0, 90), density=500.0)
    world = RigidWorld([body], gravity=(0.0, 0.0, 0.0))
    m = 4.0
    inertia_yy = m * (0.4**2 + 0.1**2) / 12.0
    np.testing.assert_allclose(world.model.body_mass.numpy(), [m], rtol=1e-6)
    F, tau = np.array([2.0, -1.0, 0.5]), 0.05
    f = wrench(world, [[*F, tau, 0.0, 0.0]])
    dt, calls = 1e-3, 200
    for _ in range(calls):
        world.step(dt, f)
    t = dt * calls
    pose = world.poses()
    np.testing.assert_allclose(pose["velocity"][0], F * t / m, rtol=1e-5)
    np.testing.assert_allclose(pose["angular_velocity"][0], [tau * t / inertia_yy, 0, 0], rtol=1e-4, atol=1e-7)


def test_mass_properties_from_shapes_and_mesh(tmp_path):
    """Newton's mass and inertia of a box, a sphere, and a box given as a mesh file (convex hull)."""
    verts, tris = box_mesh([0.15, 0.1, 0.05])
    path = tmp_path / "box.obj"
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in verts + 3.0)
                    + "".join(f"f {a} {b} {c}\n" for a, b, c in tris + 1))
    bodies = [Body(shape="box", size=(0.3, 0.2, 0.1), position=(0, 0, 0), density=800.0),
              Body(shape="sphere", radius=0.1, position=(1, 0, 0), mass=3.0),
              Body(shape="mesh", file=str(path), position=(2, 0, 0), density=800.0)]
    world = RigidWorld(bodies, gravity=(0, 0, 0))
    mass = world.model.body_mass.numpy()
    inertia = world.model.body_inertia.numpy()
    m_box = 800.0 * 0.006
    box_I = m_box / 12.0 * np.array([0.2**2 + 0.1**2, 0.3**2 + 0.1**2, 0.3**2 + 0.2**2])
    np.testing.assert_allclose(mass, [m_box, 3.0, m_box], rtol=1e-5)
    np.testing.assert_allclose(np.diag(inertia[0]), box_I, rtol=1e-5)
    np.testing.assert_allclose(np.diag(inertia[1]), [0.4 * 3.0 * 0.01] * 3, rtol=1e-5)
    np.testing.assert_allclose(inertia[2], np.diag(box_I), rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(world.body_com.numpy(), 0.0, atol=1e-6)
    np.testing.assert_allclose(world.poses()["position"], [[0, 0, 0], [1, 0, 0], [2, 0, 0]], atol=1e-6)


def container_world(bodies, **kw):
    return RigidWorld(bodies, container=((-0.5, -0.5, 0.0), (0.5, 0.5, 1.0)), **kw)


def test_bodies_come_to_rest_on_the_floor():
    """A box, a tilted box and a sphere dropped into the container rest on the floor: the centre
    height is the half height (sphere: radius) within the resting penetration g / w^2 and a little."""
    bodies = [Body(shape="box", size=(0.2, 0.16, 0.1), position=(-0.25, 0, 0.5), density=2000.0),
              Body(shape="box", size=(0.2, 0.16, 0.1), position=(0.2, 0.2, 0.7), rotation=(20, 10, 0), density=700.0),
              Body(shape="sphere", radius=0.06, position=(0.2, -0.2, 0.3), density=1200.0, velocity=(1, 0, 0))]
    world = container_world(bodies, contact_frequency=300.0)
    for _ in range(1500):  # 1.5 s
        world.step(1e-3)
    pose = world.poses()
    depth = G / 300.0**2
    z = pose["position"][:, 2]
    np.testing.assert_allclose(z, [0.05, 0.05, 0.06], atol=2 * depth + 1e-3)
    assert np.abs(pose["velocity"]).max() < 0.05 and np.abs(pose["angular_velocity"][:2]).max() < 0.5
    # the tilted box came down flat: its local z axis points up (or down)
    up = quat_to_matrix(pose["orientation"][1])[:, 2]
    assert abs(up[2]) > 0.999


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_fast_body_does_not_tunnel(axis):
    """5 m/s into a wall of the container (both directions) and into a box obstacle: never through."""
    half = 0.05
    for sign in (1.0, -1.0):
        v = np.zeros(3)
        v[axis] = 5.0 * sign
        start = np.array([0.0, 0.0, 0.5])
        body = Body(shape="box", size=(2 * half,) * 3, position=tuple(start), density=1000.0, velocity=tuple(v))
        world = container_world([body], gravity=(0, 0, 0))
        lo, hi = np.array([-0.5, -0.5, 0.0]), np.array([0.5, 0.5, 1.0])
        worst = np.inf
        for _ in range(400):
            world.step(5e-4)
            x = world.poses()["position"][0]
            worst = min(worst, float(np.min(np.concatenate([x - lo, hi - x]))))
        # never further into a wall than half its own size (the centre stays inside by > half/2)
        assert worst > 0.5 * half, (axis, sign, worst)
        v_end = world.poses()["velocity"][0]
        assert v_end[axis] * sign < 0.5  # it bounced or stopped, not flew on
    # a box obstacle in the middle of the floor, hit from above at 5 m/s
    body = Body(shape="sphere", radius=0.05, position=(0.0, 0.0, 0.8), density=1000.0, velocity=(0, 0, -5.0))
    world = container_world([body], obstacles=[StaticCollider("box", (-0.2, -0.2, 0.0), (0.2, 0.2, 0.3))])
    lowest = np.inf
    for _ in range(600):
        world.step(5e-4)
        lowest = min(lowest, float(world.poses()["position"][0, 2]))
    assert lowest > 0.3 + 0.025  # the sphere never sank more than half its radius into the top face


def test_checkpoint_restore_continues_bitwise():
    bodies = [Body(shape="box", size=(0.2, 0.16, 0.1), position=(-0.2, 0, 0.4), rotation=(10, 5, 0), density=900.0,
                   velocity=(3, 0, -1), angular_velocity=(0, 2, 0)),
              Body(shape="sphere", radius=0.07, position=(0.2, 0.1, 0.3), density=400.0)]
    world = container_world(bodies)
    f = wrench(world, [[0.5, 0, 2, 0, 0.01, 0], [0, -0.2, 1.0, 0, 0, 0]])
    for _ in range(150):
        world.step(7e-4, f)
    saved = world.state_arrays()
    for _ in range(150):
        world.step(7e-4, f)
    first = world.state_arrays()
    world.load_state_arrays(saved)
    for _ in range(150):
        world.step(7e-4, f)
    second = world.state_arrays()
    assert set(first) == set(second) and "body_q" in first and "body_qd" in first
    for name in first:
        assert np.array_equal(first[name], second[name]), name
    # a fresh world restored from the checkpoint continues the same way
    other = container_world(bodies)
    other.load_state_arrays(saved)
    for _ in range(150):
        other.step(7e-4, f)
    assert np.array_equal(other.state_arrays()["body_q"], first["body_q"])
    with pytest.raises(ValueError, match="body_q"):
        other.load_state_arrays({k: v for k, v in saved.items() if k != "body_q"})


def test_stack_of_unequal_masses_is_stable_at_the_largest_substep():
    """A 4000 kg/m^3 box resting on a 200 kg/m^3 box on the floor (mass ratio 20), stepped at exactly
    max_substep: per-contact stiffness from the reduced mass keeps it stable; heights within the
    contact penetration m_top g / (4 mu w^2) of the stacked heights."""
    bodies = [Body(shape="box", size=(0.2, 0.2, 0.1), position=(0, 0, 0.06), density=200.0),
              Body(shape="box", size=(0.2, 0.2, 0.1), position=(0, 0, 0.17), density=4000.0)]
    world = container_world(bodies, contact_frequency=300.0)
    assert world.max_substep == pytest.approx(1.0 / (4 * 300.0))
    dt = world.max_substep
    assert world.substeps_for(dt) == 1
    for _ in range(int(1.5 / dt)):
        world.step(dt)
    pose = world.poses()
    depth = 21 * G / (4 * 300.0**2)  # both loads over the light body's reduced mass
    np.testing.assert_allclose(pose["position"][:, 2], [0.05, 0.15], atol=2 * depth + 1e-4)
    np.testing.assert_allclose(pose["position"][:, :2], 0.0, atol=1e-4)
    assert np.abs(pose["velocity"]).max() < 1e-3
