"""Kinematic bodies ([[bodies]] kinematic = true): animated colliders given as bodies (docs/colliders.md)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from warp_sph.core.errors import SceneError
from warp_sph.run.simulation import Simulation
from warp_sph.scene import load_scene, scene_from_dict

FPS = 24.0
# a wall across the 0.4 x 0.16 x 0.3 m tank, centre pushed from x = 0.05 to 0.2 m in 0.2 s (linear keys)
PUSH = [{"time": 0.0, "translate": [0.05, 0.08, 0.15]}, {"time": 0.2, "translate": [0.2, 0.08, 0.15],
                                                        "rotation": [0.0, 0.0, 0.0]}]


def tank(kinematic: bool = True, **body) -> dict:
    """The test_colliders tank (r = 0.02 m, ~100 fluid particles) with the pusher as a kinematic body
    (``kinematic``) or as the equivalent animated box obstacle."""
    base = {"name": "tank", "particle_radius": 0.02, "fps": FPS, "duration": 0.5,
            "container": {"min": [0, 0, 0], "max": [0.4, 0.16, 0.3]},
            "fluid": [{"min": [0.12, 0, 0], "max": [0.4, 0.16, 0.08]}],
            "output": {"checkpoint_every": 2, "surface": False}}
    if kinematic:
        b = {"name": "pusher", "kinematic": True, "size": [0.08, 0.16, 0.3], "keyframes": PUSH,
             "interpolation": "linear"}
        b.update(body)
        return {**base, "bodies": [b]}
    return {**base, "obstacles": [{"name": "pusher", "shape": "box", "min": [-0.04, -0.08, -0.15],
                                   "max": [0.04, 0.08, 0.15], "keyframes": PUSH, "interpolation": "linear"}]}


def test_kinematic_box_follows_its_keys_and_pushes_the_fluid(device):
    """Not a Newton body (no mass given, no rigid world); its particles sit at the keys' poses at the keys'
    times (x = R x_local + T, x_local the box centred at the origin) and it sweeps the fluid ahead of it."""
    scene = scene_from_dict(tank())
    assert scene.bodies == [] and [ob.name for ob in scene.obstacles] == ["pusher"]
    sim = Simulation(scene, device=device)
    assert sim.bodies is None and sim.colliders is not None and sim.colliders.names == ["pusher"]
    start = sim.colliders.start
    local = sim.colliders.colliders[0].samples.local_x
    assert np.abs(local).max(axis=0) == pytest.approx([0.04, 0.08, 0.15])  # the box of size, centred
    x0 = sim.get_field("boundary_x")[start:start + len(local)]
    np.testing.assert_allclose(x0, local + PUSH[0]["translate"], atol=1e-6)
    fluid0 = sim.get_field("particle_x")
    while sim.state.time < 0.2 - 1e-9:
        sim.advance_frame()
    x = sim.get_field("boundary_x")[start:start + len(local)]
    at = local + PUSH[1]["translate"]
    assert sim.state.time == pytest.approx(5 / FPS)  # frame 5 ends at 0.208 s, past the last key: held
    np.testing.assert_allclose(x, at, atol=1e-5)
    fluid = sim.get_field("particle_x")
    face = PUSH[1]["translate"][0] + 0.04
    assert fluid0[:, 0].min() < face  # fluid stood where the wall's front face ends up ...
    assert fluid[:, 0].min() > face - 0.25 * sim.model.spacing  # ... and was pushed ahead of it
    assert sim.colliders.work_done() > 0.0


def test_kinematic_body_equals_the_animated_obstacle(device):
    """Same sampling, same boundary positions and velocities, same fluid, bit for bit, after 2 frames."""
    sims = [Simulation(scene_from_dict(tank(kinematic=k)), device=device) for k in (True, False)]
    for sim in sims:
        for _ in range(2):
            sim.advance_frame()
    for name in ("boundary_x", "boundary_v", "particle_x", "particle_v"):
        a, b = (s.get_field(name) for s in sims)
        assert a.shape == b.shape and np.array_equal(a, b), name


def _sphere_tank(kinematic: bool) -> dict:
    """The tank with a sphere of radius 0.05 m pushed through the fluid (centre z = 0.06 m), as a kinematic body
    or as the equivalent animated sphere obstacle (center = the local origin)."""
    keys = [{"time": 0.0, "translate": [0.06, 0.08, 0.06]}, {"time": 0.2, "translate": [0.25, 0.08, 0.06]}]
    d = tank()
    if kinematic:
        d["bodies"] = [{"name": "ball", "kinematic": True, "shape": "sphere", "radius": 0.05, "keyframes": keys}]
    else:
        d["bodies"] = []
        d["obstacles"] = [{"name": "ball", "shape": "sphere", "center": [0, 0, 0], "radius": 0.05, "keyframes": keys}]
    return d


def test_kinematic_sphere_follows_its_keys_and_equals_the_animated_sphere(device):
    """A kinematic sphere is a sphere obstacle centred at the local origin: its particles on |x_local| = R sit at
    x_local + T at the keys, and the run equals the animated sphere obstacle's bit for bit after 2 frames."""
    scene = scene_from_dict(_sphere_tank(True))
    ob = scene.obstacles[0]
    assert scene.bodies == [] and (ob.shape, tuple(ob.center), ob.radius) == ("sphere", (0.0, 0.0, 0.0), 0.05)
    sims = [Simulation(scene, device=device), Simulation(scene_from_dict(_sphere_tank(False)), device=device)]
    start, local = sims[0].colliders.start, sims[0].colliders.colliders[0].samples.local_x
    np.testing.assert_allclose(np.linalg.norm(local, axis=1), 0.05, atol=1e-12)
    np.testing.assert_allclose(sims[0].get_field("boundary_x")[start:start + len(local)], local + [0.06, 0.08, 0.06],
                               atol=1e-6)
    for sim in sims:
        for _ in range(2):
            sim.advance_frame()
    for name in ("boundary_x", "boundary_v", "particle_x", "particle_v"):
        a, b = (s.get_field(name) for s in sims)
        assert a.shape == b.shape and np.array_equal(a, b), name
    sim = sims[0]
    while sim.state.time < 0.2 - 1e-9:
        sim.advance_frame()
    np.testing.assert_allclose(sim.get_field("boundary_x")[start:start + len(local)], local + [0.25, 0.08, 0.06],
                               atol=1e-5)


def test_kinematic_mesh_body_is_centred_at_its_centroid(tmp_path):
    """A mesh body's frame has its origin at the centroid of its volume, as a dynamic body's."""
    from warp_sph.rigid.spec import box_mesh

    v, t = box_mesh(np.array([0.04, 0.08, 0.15]))
    v = v + [1.0, 2.0, 3.0]  # the file's box is far from the origin
    (tmp_path / "box.obj").write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v)
                                      + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in t))
    scene = scene_from_dict(_mesh_tank(tmp_path))
    ob = scene.obstacles[0]
    np.testing.assert_allclose(ob.translate, [-1.0, -2.0, -3.0], atol=1e-9)
    from warp_sph.scene.meshes import load_triangle_mesh

    lo, hi = load_triangle_mesh(ob.file).transformed(ob.scale, ob.translate).bounds
    np.testing.assert_allclose(lo, [-0.04, -0.08, -0.15], atol=1e-9)
    np.testing.assert_allclose(hi, [0.04, 0.08, 0.15], atol=1e-9)


def _mesh_tank(tmp_path) -> dict:
    d = tank()
    b = d["bodies"][0]
    del b["size"]
    b.update(shape="mesh", file=str(tmp_path / "box.obj"))
    return d


@pytest.mark.parametrize("change,message", [
    ({"keyframes": None}, "bodies[0].kinematic: a kinematic body needs a path"),
    ({"density": 500.0}, "bodies[0].density: not used by a kinematic body"),
    ({"mass": 1.0}, "bodies[0].mass: not used by a kinematic body"),
    ({"velocity": [1.0, 0.0, 0.0]}, "bodies[0].velocity: not used by a kinematic body"),
    ({"position": [0.2, 0.08, 0.15]}, "bodies[0].position: not used by a kinematic body"),
    ({"kinematic": False, "density": 500.0, "position": [0.2, 0.08, 0.15]},
     "bodies[0].keyframes: only a kinematic body follows a path"),
    ({"shape": "sphere", "radius": 0.0, "size": None}, "bodies[0].radius: expected a finite number > 0"),
    ({"keyframes": [PUSH[0], {"time": 0.3, "translate": [0.5, 0.08, 0.15]}]}, "bodies[0]: its path leaves the container"),
])
def test_bad_kinematic_bodies_are_one_line_errors(change, message):
    d = tank()
    b = d["bodies"][0]
    for k, v in change.items():
        if v is None:
            b.pop(k, None)
        else:
            b[k] = v
    with pytest.raises(SceneError) as info:
        scene_from_dict(d)
    text = str(info.value)
    assert "\n" not in text and message in text, text


def test_kinematic_and_obstacle_names_clash():
    d = tank()
    d["obstacles"] = tank(kinematic=False)["obstacles"]
    with pytest.raises(SceneError, match=r"bodies\[0\]\.name: 'pusher' is also the name of obstacles\[0\]"):
        scene_from_dict(d)


def test_bad_kinematic_body_on_the_command_line_exits_2(tmp_path):
    (tmp_path / "bad.toml").write_text("""particle_radius = 0.02
[container]
min = [0, 0, 0]
max = [0.4, 0.16, 0.3]
[[fluid]]
min = [0.12, 0, 0]
max = [0.4, 0.16, 0.08]
[[bodies]]
kinematic = true
size = [0.08, 0.16, 0.3]
density = 500.0
keyframes = [{time = 0.0, translate = [0.05, 0.08, 0.15]}]
""")
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "warp_sph.cli", "run", str(tmp_path / "bad.toml"), "--out", str(out),
                        "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "bodies[0].density: not used by a kinematic body" in lines[0], r.stderr
    assert f"{tmp_path / 'bad.toml'}: bodies[0].density" in lines[0], lines[0]
    assert not out.exists()


def test_dynamic_bodies_keep_their_names_and_round_trip():
    """A dynamic body after a kinematic one keeps body<index as written>; the validated scene (run.json's
    scene, what a resume reads) round-trips, the kinematic body as an animated obstacle."""
    d = tank()
    d["bodies"][0].pop("name")
    d["bodies"].append({"size": [0.05, 0.05, 0.05], "position": [0.3, 0.08, 0.2], "density": 500.0})
    scene = scene_from_dict(d)
    assert [b.name for b in scene.bodies] == ["body1"] and [o.name for o in scene.obstacles] == ["body0"]
    assert scene_from_dict(scene.to_dict()) == scene


def test_kinematic_body_from_usd_animation_is_written_under_sph_bodies(tmp_path):
    """A path from a USD file (Blender-like, test_colliders' writer): the run's USD holds the body as
    /sph/bodies/<name> at the path's pose every frame, run.json records it."""
    from pxr import Usd, UsdGeom
    from test_colliders import quiet, write_blender_like_usd

    from warp_sph.io import run_folder as rf
    from warp_sph.run import runner

    write_blender_like_usd(tmp_path / "anim.usda", lambda t: ((0.05 + 0.5 * t, 0.08, 0.15), (0.0, 0.0, 0.0)), 6)
    d = tank()
    b = d["bodies"][0]
    del b["keyframes"]
    b["animation"] = {"file": str(tmp_path / "anim.usda"), "prim": "/root/paddle"}
    scene = scene_from_dict(d)
    out = tmp_path / "run"
    runner.run(scene, out=out, device="cpu", frames=3, progress=False, log=quiet, threaded_export=False)
    stage = Usd.Stage.Open(str(next(out.glob("*.usdc"))))
    xf = UsdGeom.Xformable(stage.GetPrimAtPath("/sph/bodies/pusher"))
    for frame in (1, 3):
        M = np.array(xf.ComputeLocalToWorldTransform(Usd.TimeCode(frame)))
        np.testing.assert_allclose(M[3, :3], [0.05 + 0.5 * (frame - 1) / FPS, 0.08, 0.15], atol=1e-6)
    frames = rf.read_run_json(out)["frames"]
    assert "pusher" in frames[-1]["bodies"]
