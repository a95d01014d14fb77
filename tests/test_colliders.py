"""Animated colliders (docs/colliders.md): paths from TOML keyframes or a USD file (``scene/paths.py``),
obstacles that move along them (``rigid/colliders.py``), their USD prims, checkpoints and bad input."""
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from warp_sph.core.errors import SceneError
from warp_sph.io import run_folder as rf
from warp_sph.run import runner
from warp_sph.run.simulation import Simulation
from warp_sph.scene import load_scene, scene_from_dict
from warp_sph.scene.paths import Path as PosePath, euler_matrix, usd_path

FPS = 24.0


def quiet(*args, **kwargs):
    pass


def rot(axis: str, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


# --- interpolation against analytic values --------------------------------------------------------
def test_linear_keys_interpolate_straight_and_hold_the_end_poses():
    p = PosePath([1.0, 3.0], [[0, 0, 0, 0, 0, 0], [2, -4, 6, 0, 0, 90]], "linear")
    R, T = p.pose(2.0)
    np.testing.assert_allclose(T, [1, -2, 3])
    np.testing.assert_allclose(R, rot("z", 45.0), atol=1e-12)
    v, w = p.velocity(2.0)
    np.testing.assert_allclose(v, [1, -2, 3])
    np.testing.assert_allclose(w, [0, 0, math.radians(45.0)])
    for t, key in ((0.0, 0), (5.0, 1)):  # held before the first and after the last key, at rest
        R, T = p.pose(t)
        np.testing.assert_allclose(T, p.channels[key, :3])
        v, w = p.velocity(t)
        assert not np.any(v) and not np.any(w)


def test_smooth_keys_are_catmull_rom_with_rest_at_the_ends():
    """Keys x = 0, 1, 4 at t = 0, 1, 2: tangents 0, (4 - 0) / 2 = 2, 0; at s = 1/2 of the first span the
    Hermite value is (0 + 1) / 2 + (0 - 2) / 8 = 0.25 and its rate 1.5 (1 - 0) - 0 / 4 - 2 / 4 = 1.0."""
    p = PosePath([0.0, 1.0, 2.0], [[0, 0, 0, 0, 0, 0], [1, 0, 0, 0, 0, 0], [4, 0, 0, 0, 0, 0]], "smooth")
    c, r = p.channels_at(np.array([0.0, 0.5, 1.0, 2.0]))
    np.testing.assert_allclose(c[:, 0], [0.0, 0.25, 1.0, 4.0])
    np.testing.assert_allclose(r[:, 0], [0.0, 1.0, 2.0, 0.0], atol=1e-12)


def test_rotation_channels_make_a_full_turn_and_compose_xyz():
    p = PosePath([0.0, 1.0], [[0] * 6, [0, 0, 0, 0, 0, 360]], "linear")
    np.testing.assert_allclose(p.pose(0.5)[0], rot("z", 180.0), atol=1e-12)
    np.testing.assert_allclose(p.pose(0.25)[0], rot("z", 90.0), atol=1e-12)
    R = euler_matrix([30.0, -20.0, 75.0])  # Blender's XYZ mode: X first, then Y, then Z
    np.testing.assert_allclose(R, rot("z", 75.0) @ rot("y", -20.0) @ rot("x", 30.0), atol=1e-12)


@pytest.mark.parametrize("interpolation", ["linear", "smooth"])
def test_particle_velocity_is_the_derivative_of_the_path(interpolation):
    """v = dT/dt + omega x (x - T) against central differences of x(t) = R(t) x_local + T(t)."""
    p = PosePath([0.0, 0.4, 1.0, 1.3], [[0, 0, 0, 0, 0, 0], [0.3, -0.1, 0.2, 40, -25, 90],
                                          [0.1, 0.5, 0.0, -30, 60, 200], [0.0, 0.0, 0.1, 10, 0, 90]], interpolation)
    local = np.array([[0.1, -0.2, 0.3], [-0.05, 0.07, 0.0], [0.2, 0.2, -0.1]])
    h = 1e-6
    for t in (0.13, 0.55, 0.97, 1.21):
        R, T = p.pose(t)
        v, w = p.velocity(t)
        x = local @ R.T + T
        (Ra, Ta), (Rb, Tb) = p.pose(t + h), p.pose(t - h)
        fd = ((local @ Ra.T + Ta) - (local @ Rb.T + Tb)) / (2 * h)
        np.testing.assert_allclose(v + np.cross(w, x - T), fd, atol=1e-6)


# --- scenes ------------------------------------------------------------------------------------
def tank(**obstacle) -> dict:
    """A 0.4 x 0.16 x 0.3 m tank (r = 0.02 m, ~100 fluid particles) with one animated box obstacle."""
    ob = {"name": "pusher", "shape": "box", "min": [-0.04, -0.08, -0.15], "max": [0.04, 0.08, 0.15]}
    ob.update(obstacle)
    return {"name": "tank", "particle_radius": 0.02, "fps": FPS, "duration": 0.5,
            "container": {"min": [0, 0, 0], "max": [0.4, 0.16, 0.3]},
            "fluid": [{"min": [0.12, 0, 0], "max": [0.4, 0.16, 0.08]}], "obstacles": [ob],
            "output": {"checkpoint_every": 2, "surface": False}}


PUSH = [{"time": 0.0, "translate": [0.05, 0.08, 0.15]}, {"time": 0.2, "translate": [0.3, 0.08, 0.15]}]
STIR = [{"time": 0.0, "translate": [0.05, 0.08, 0.15]}, {"time": 0.15, "translate": [0.12, 0.08, 0.15],
                                                        "rotation": [0.0, 0.0, 0.0]},
        {"time": 0.3, "translate": [0.05, 0.08, 0.15]}]


@pytest.mark.parametrize("boundary", ["akinci2012", "penalty"])
def test_pusher_at_the_step_speed_limit_lets_no_particle_through(boundary, device):
    """A wall across the whole tank, at rest for the first frame, then pushed at 4 m/s (linear: full speed
    at once) into the resting fluid: the step bound counts its speed before the fluid has any (it moves at
    most cfl d per substep; sized from the fluid's speed alone the step would stay at dt_max, 0.4 d per
    substep = 0.5 d at this speed) and at every substep every fluid particle stays ahead of its front face,
    with either boundary method."""
    keys = [{"time": 0.0, "translate": [0.05, 0.08, 0.15]}, {"time": 1 / FPS, "translate": [0.05, 0.08, 0.15]},
            {"time": 1 / FPS + 0.05, "translate": [0.25, 0.08, 0.15]}]
    sim = Simulation(scene_from_dict({**tank(keyframes=keys, interpolation="linear"), "boundary": boundary}), device=device)
    from warp_sph.core.step_graph import Stage

    seen = []

    def track(sim, dt):
        x = sim.get_field("particle_x")[:, 0]
        start, face = (sim.colliders.poses(t)[1][0, 0] + 0.04 for t in (sim.state.time, sim.state.time + dt))
        seen.append((x.min() - face, face - start, (face - start) / dt))

    sim.graph.insert(Stage("track", track, reads=("particle_x",)), after="colliders")
    for _ in range(4):
        sim.advance_frame()
    gap, move, speed = np.array(seen).T
    assert speed.max() == pytest.approx(4.0)  # it went at full speed
    # its top speed is the scene's reference speed (WCSPH's c_s = 10 v_ref, the pre-flight step estimate)
    assert sim.model.reference_speed == pytest.approx(4.0)
    assert sim.model.reference_speed_source == "the animated obstacles' top speed"
    assert move.max() <= sim.scene.time.cfl * sim.model.spacing * (1 + 1e-6)  # the step bound saw the wall
    assert gap.min() > 0.0, gap.min()
    assert sim.colliders.work_done() > 0.0  # it pushed


def test_work_of_the_paddle_keeps_the_energy_rule_sound(device):
    """The paddle scene's first 0.5 s: the fluid's energy rises above E(0) by more than the 1 % limit (the
    paddle drives it), E - W (W the work the paddle did, the rule's measure) does not."""
    scene = load_scene("paddle", {"output.usd": False, "particle_radius": 0.025})
    sim = Simulation(scene, device=device)
    rise, growth = [], []
    for _ in range(12):
        st = sim.advance_frame()
        e = sim.watchdog.energy
        rise.append((e.last.total - e.reference_total) / e.scale)
        growth.append(st.energy_growth)
    assert max(rise) > 0.01 and sim.colliders.work_done() > 0.0
    assert max(growth) <= 0.01


def test_checkpoint_and_resume_mid_animation_are_bitwise(tmp_path):
    scene = scene_from_dict(tank(keyframes=STIR, interpolation="smooth"))
    ref, out = tmp_path / "ref", tmp_path / "resumed"
    runner.run(scene, out=ref, device="cpu", frames=6, progress=False, log=quiet, threaded_export=False)
    runner.run(scene, out=out, device="cpu", frames=4, progress=False, log=quiet, threaded_export=False)
    rf.checkpoint_path(out, 4).unlink()  # resume from frame 3, the paddle half way
    info = runner.run(None, frames=6, resume=out, progress=False, device="cpu", log=quiet)
    assert info["status"] == "completed"
    a, b = rf.read_run_json(ref), rf.read_run_json(out)
    assert a["frames"] == b["frames"]  # collider poses, forces, energy (with the work) included
    for k in range(1, 7):
        fa, fb = np.load(rf.frame_path(ref, k)), np.load(rf.frame_path(out, k))
        for key in fa.files:
            assert np.array_equal(fa[key], fb[key]), (k, key)
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(next(ref.glob("*.usdc"))))
    xf = UsdGeom.Xformable(stage.GetPrimAtPath("/sph/bodies/pusher"))
    for frame in (1, 4, 6):  # the prim's transform is the path's pose at the frame's time
        M = np.array(xf.ComputeLocalToWorldTransform(Usd.TimeCode(frame)))
        R, T = scene.obstacles[0].path.pose((frame - 1) / FPS)
        np.testing.assert_allclose(M[3, :3], T, atol=1e-6)
        np.testing.assert_allclose(M[:3, :3].T, R, atol=1e-6)


# --- USD-driven paths -------------------------------------------------------------------------
def write_blender_like_usd(path: Path, pose, frames: int, fps: float = FPS, up: str = "Z", mpu: float = 1.0) -> None:
    """A USD file as Blender's exporter writes an animated object: /root/paddle Xform with translate and
    rotateXYZ ops sampled at every frame (time code = frame, from 1), timeCodesPerSecond = fps; ``pose(t)``
    gives (T [m], Euler XYZ [deg]) in Z-up metres, written in the file's up axis and units."""
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if up == "Z" else UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(frames)
    UsdGeom.Xform.Define(stage, "/root")
    xf = UsdGeom.Xform.Define(stage, "/root/paddle")
    t_op, r_op = xf.AddTranslateOp(), xf.AddRotateXYZOp()
    y_to_z = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    from warp_sph.scene.paths import matrix_euler

    for f in range(1, frames + 1):
        T, e = pose((f - 1) / fps)
        if up == "Y":  # the same world motion seen from a Y-up file: R_y = C^T R, T_y = C^T T
            e = matrix_euler(y_to_z.T @ euler_matrix(e))
            T = y_to_z.T @ T
        t_op.Set(Gf.Vec3d(*(np.asarray(T) / mpu)), Usd.TimeCode(f))
        r_op.Set(Gf.Vec3f(*map(float, e)), Usd.TimeCode(f))
    stage.GetRootLayer().Save()


def fail(keypath, message):
    raise SceneError(f"{keypath}: {message}")


@pytest.mark.parametrize("up,mpu", [("Z", 1.0), ("Y", 0.01)])
def test_usd_path_matches_the_keyframed_path(tmp_path, up, mpu):
    scene = load_scene("paddle")
    keyed = scene.obstacles[0].path
    frames = int(keyed.times[-1] * FPS) + 3
    file = tmp_path / "paddle.usda"
    write_blender_like_usd(file, lambda t: (keyed.pose(t)[1], keyed.channels_at(t)[0][3:]), frames, up=up, mpu=mpu)
    usd = usd_path(file, "/root/paddle", "smooth", fail, "obstacles[0]")
    np.testing.assert_allclose(usd.times, np.arange(frames) / FPS)
    t = np.linspace(0.0, keyed.times[-1] + 0.1, 97)
    (R1, T1), (R2, T2) = keyed.pose(t), usd.pose(t)
    np.testing.assert_allclose(T2, T1, atol=2e-4)  # a cubic through per-frame samples of a cubic
    np.testing.assert_allclose(R2, R1, atol=2e-3)
    k = np.arange(frames) / FPS  # at the samples themselves: the file's poses
    np.testing.assert_allclose(usd.pose(k)[1], keyed.pose(k)[1], atol=1e-6)


def test_paddle_scene_from_usd_runs_as_from_keyframes(tmp_path, device):
    """The paddle scene with its motion read from a Blender-like USD file: same particles at t = 0 and,
    two frames on, within 1 mm of the keyframed run."""
    keyed_scene = load_scene("paddle", {"output.usd": False})
    keyed = keyed_scene.obstacles[0].path
    write_blender_like_usd(tmp_path / "paddle.usda", lambda t: (keyed.pose(t)[1], keyed.channels_at(t)[0][3:]),
                           int(keyed.times[-1] * FPS) + 3)
    d = keyed_scene.to_dict()
    del d["obstacles"][0]["keyframes"]
    d["obstacles"][0]["animation"] = {"file": "paddle.usda", "prim": "/root/paddle"}
    usd_scene = scene_from_dict(d, source=str(tmp_path / "paddle.toml"), base_dir=tmp_path)
    a, b = Simulation(keyed_scene, device=device), Simulation(usd_scene, device=device)
    np.testing.assert_allclose(a.get_field("particle_x"), b.get_field("particle_x"), atol=1e-6)
    for _ in range(2):
        a.advance_frame(), b.advance_frame()
    np.testing.assert_allclose(a.get_field("boundary_x"), b.get_field("boundary_x"), atol=1e-3)
    np.testing.assert_allclose(a.get_field("particle_x"), b.get_field("particle_x"), atol=1e-3)


# --- bad input ---------------------------------------------------------------------------------
def _static_usd(path: Path) -> None:
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/still").AddTranslateOp().Set((0.2, 0.08, 0.15))
    stage.GetRootLayer().Save()


@pytest.mark.parametrize("change,message", [
    ({"keyframes": [{"time": 0.2}, {"time": 0.1}]}, "obstacles[0].keyframes[1].time: keyframe times must increase"),
    ({"keyframes": [{"time": 0.1}, {"time": 0.1}]}, "0.1 s is duplicated"),
    ({"keyframes": []}, "obstacles[0].keyframes: expected at least one keyframe"),
    ({"keyframes": PUSH, "interpolation": "cubic"}, "obstacles[0].interpolation: expected one of 'linear', 'smooth'"),
    ({"keyframes": [{"time": 0.0, "translate": [0.05, 0.08, 0.15]}, {"time": 0.3, "translate": [0.5, 0.08, 0.15]}]},
     "obstacles[0]: its path leaves the container"),
    ({"animation": {"file": "nowhere.usda", "prim": "/paddle"}}, "obstacles[0].animation.file: USD file"),
    ({"animation": {"file": "still.usda", "prim": "/paddle"}}, "prim '/paddle' does not exist"),
    ({"animation": {"file": "still.usda", "prim": "/still"}}, "is not animated: its transform has no time samples"),
    ({"animation": {"file": "still.usda", "prim": "/still"}, "keyframes": PUSH}, "give keyframes or animation, not both"),
    ({"keyframes": PUSH, "name": "2fast"}, "obstacles[0].name: expected letters, digits and '_'"),
])
def test_bad_paths_are_one_line_errors_before_any_kernel(tmp_path, change, message):
    _static_usd(tmp_path / "still.usda")
    (tmp_path / "bad.toml").write_text(_toml(tank(**change)))
    with pytest.raises(SceneError) as info:
        load_scene(str(tmp_path / "bad.toml"))
    text = str(info.value)
    assert "\n" not in text and message in text and text.startswith(str(tmp_path / "bad.toml")), text


def test_bad_path_on_the_command_line_exits_2_and_writes_nothing(tmp_path):
    (tmp_path / "bad.toml").write_text(_toml(tank(keyframes=[{"time": 0.2}, {"time": 0.1}])))
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "warp_sph.cli", "run", str(tmp_path / "bad.toml"), "--out", str(out),
                        "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "keyframes[1].time: keyframe times must increase" in lines[0], r.stderr
    assert not out.exists()


def _toml(d: dict) -> str:
    """A scene dict as TOML (tables, arrays of tables, inline tables for keyframes)."""
    def value(v):
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + "}"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return json.dumps(v)

    lines = [f"{k} = {value(v)}" for k, v in d.items() if not isinstance(v, (dict, list)) or k == "keyframes"]
    for k, v in d.items():
        if isinstance(v, dict):
            lines += [f"[{k}]"] + [f"{a} = {value(b)}" for a, b in v.items()]
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            for block in v:
                lines += [f"[[{k}]]"] + [f"{a} = {value(b)}" for a, b in block.items()]
    return "\n".join(lines) + "\n"


def test_two_animated_obstacles_need_distinct_names():
    d = tank(keyframes=PUSH[:1])
    d["obstacles"].append(dict(d["obstacles"][0]))
    with pytest.raises(SceneError, match=r"obstacles\[1\]\.name: 'pusher' is also the name of obstacles\[0\]"):
        scene_from_dict(d)


# --- overlaps along the path, in world coordinates -------------------------------------------------
def _with(obstacles=(), bodies=(), **keys):
    d = tank(keyframes=PUSH, **keys)
    d["obstacles"] += list(obstacles)
    if bodies:
        d["bodies"] = list(bodies)
    return d


CROSS = [{"time": 0.0, "translate": [0.35, 0.08, 0.15]}, {"time": 0.2, "translate": [0.1, 0.08, 0.15]}]


@pytest.mark.parametrize("extra, message", [
    # the pusher (x 0.01..0.09 at t = 0, pushed to x = 0.3 by t = 0.2 s) through a static box on its way
    ({"obstacles": [{"shape": "box", "min": [0.18, 0.0, 0.2], "max": [0.22, 0.16, 0.3]}]},
     r"obstacles\[0\]: its path runs into obstacles\[1\] \(static\) at t = 0\.0[5-9]\d* s"),
    # ... through a sphere, and through an animated obstacle coming the other way
    ({"obstacles": [{"shape": "sphere", "center": [0.2, 0.08, 0.25], "radius": 0.03}]},
     r"obstacles\[0\]: its path runs into obstacles\[1\] \(static\)"),
    ({"obstacles": [{"name": "other", "shape": "box", "min": [-0.02, -0.08, -0.05], "max": [0.02, 0.08, 0.05],
                     "keyframes": CROSS}]},
     r"obstacles\[0\]: its path runs into obstacles\[1\] \(animated\) at t = 0\.1\d* s"),
    # a dynamic body where the pusher's path puts it at t = 0 (its local box lies about the origin)
    ({"bodies": [{"shape": "box", "size": [0.06, 0.06, 0.06], "position": [0.05, 0.08, 0.25], "density": 800}]},
     r"bodies\[0\]: overlaps obstacles\[0\] at t = 0"),
])
def test_solids_on_an_obstacles_path_are_refused_in_world_coordinates(extra, message):
    """Obstacles were checked where their geometry is written (their own frame about the origin), not where
    their path moves them: a path through a static obstacle or another animated one passed, and so did a
    dynamic body inside the obstacle at t = 0, while a body where the unmoved box would be was refused."""
    with pytest.raises(SceneError) as info:
        scene_from_dict(_with(**extra))
    text = str(info.value)
    assert "\n" not in text and re.search(message, text), text


def test_solids_clear_of_the_path_and_fluid_it_runs_through_are_fine(monkeypatch):
    """A static box past the path's end, an animated obstacle the pusher never reaches, a body where the pusher's
    local box would be (about the origin, not where its path puts it): accepted. The fluid on the path is what
    a paddle is for; at t = 0 the fluid inside the obstacle's world pose is removed, none elsewhere."""
    from warp_sph.rigid import world
    from warp_sph.scene.sampling import sample_scene

    monkeypatch.setattr(world, "require_newton", lambda: None)  # validation only: Newton's import takes seconds
    late = [{"time": 0.0, "translate": [0.38, 0.08, 0.2]}, {"time": 0.5, "translate": [0.38, 0.08, 0.25]}]
    scene_from_dict(_with(obstacles=[{"shape": "box", "min": [0.36, 0.0, 0.0], "max": [0.4, 0.16, 0.05]},
                                     {"shape": "box", "min": [-0.02, -0.08, -0.05], "max": [0.02, 0.08, 0.05],
                                      "name": "late", "keyframes": late}]))
    held = tank(keyframes=[{"time": 0.0, "translate": [0.3, 0.08, 0.15]}])  # x 0.26..0.34 all the time
    held["bodies"] = [{"shape": "box", "size": [0.06, 0.06, 0.06], "position": [0.05, 0.08, 0.05], "density": 800}]
    scene_from_dict(held)
    # written at x 0.04..0.12, moved by 0.14 m: in the world at x 0.18..0.26 from t = 0 on
    d = tank(keyframes=[{"time": 0.0, "translate": [0.14, 0.0, 0.0]}], min=[0.04, 0.0, 0.0], max=[0.12, 0.16, 0.3])
    d["fluid"] = [{"min": [0.0, 0.0, 0.0], "max": [0.4, 0.16, 0.08]}]
    x = sample_scene(scene_from_dict(d)).fluid_x
    assert not np.any((x[:, 0] > 0.18) & (x[:, 0] < 0.26))  # the world box: empty
    assert np.count_nonzero((x[:, 0] > 0.04) & (x[:, 0] < 0.12)) > 0  # where the box is written: fluid kept


def test_a_short_smooth_segment_counts_at_its_peak_speed(tmp_path, capsys):
    """A smooth path from rest to rest moves 0.5 m in 1 us: its speed peaks at 1.5 x 0.5 m / 1 us mid-segment,
    but the step bound sampled 64 times over the run and the keys, where a smooth path is at rest, and saw 0
    m/s: the obstacle jumped through the fluid in one 5 ms substep. Now the peak counts and the run is
    refused before any step (one line, exit 2, nothing written)."""
    from warp_sph.cli import main as cli_main

    jump = [{"time": 0.0, "translate": [0.05, 0.08, 0.15]}, {"time": 1e-6, "translate": [0.3, 0.08, 0.15]}]
    path = PosePath(np.array([0.0, 1e-6]), np.array([[0.05, 0.08, 0.15, 0, 0, 0], [0.3, 0.08, 0.15, 0, 0, 0]]),
                    "smooth")
    assert path.max_speed(0.0, 0.0, 0.5) == pytest.approx(1.5 * 0.25 / 1e-6, rel=1e-9)
    (tmp_path / "jump.toml").write_text(_toml(tank(keyframes=jump, interpolation="smooth")))
    out = tmp_path / "out"
    assert cli_main(["run", str(tmp_path / "jump.toml"), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "comes from the animated obstacles' top speed" in err[0], err
    assert not out.exists()
