"""Rigid bodies in real runs: the run folder (USD body prims with a time-sampled transform that pass
check_usd --strict, run.json per-frame poses, velocities and fluid forces), a resume that continues
bit for bit (Newton's state in the checkpoints), the watchdog's retry restoring the bodies, no
tunnelling at 5 m/s, previews that draw the bodies, and bad [[bodies]] input refused in one line."""
import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from warp_sph.core.errors import SceneError
from warp_sph.core.step_graph import Stage
from warp_sph.io import check_usd
from warp_sph.io import run_folder as rf
from warp_sph.rigid.spec import quat_to_matrix
from warp_sph.run import runner
from warp_sph.run.simulation import Simulation
from warp_sph.scene import scene_from_dict

pytest.importorskip("newton")

FRAMES = 5


def scene_dict(**extra) -> dict:
    """A 0.6 m pool 0.24 m deep (r = 0.03 m, ~1,000 fluid particles) with a crate and a ball dropped in."""
    d = {
        "name": "bodies_run", "particle_radius": 0.03, "fps": 20.0,
        "container": {"min": [0, 0, 0], "max": [0.6, 0.6, 0.6]},
        "fluid": [{"min": [0, 0, 0], "max": [0.6, 0.6, 0.24]}],
        "bodies": [{"name": "crate", "shape": "box", "size": [0.2, 0.16, 0.14], "position": [0.2, 0.3, 0.4],
                    "density": 500.0, "rotation": [0.0, 10.0, 30.0]},
                   {"name": "ball", "shape": "sphere", "radius": 0.08, "position": [0.45, 0.3, 0.45],
                    "density": 800.0, "velocity": [-0.5, 0.0, 0.0]}],
        "output": {"checkpoint_every": 2},
    }
    for k, v in extra.items():
        d[k] = {**d.get(k, {}), **v} if isinstance(v, dict) else v
    return d


def quiet(*args, **kwargs):
    pass


def run_scene(out: Path, frames: int = FRAMES, **kw) -> dict:
    return runner.run(scene_from_dict(scene_dict()), out=out, device="cpu", frames=frames, progress=False, log=quiet,
                      **kw)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bodies") / "run"
    run_scene(out)
    return out


def test_run_json_records_each_body_per_frame(reference):
    info = rf.read_run_json(reference)
    assert info["model"]["bodies"]["names"] == ["crate", "ball"]
    assert [s["stage"] for s in info["step_graph"]][-1] == "bodies"
    assert "body_forces" in [s["stage"] for s in info["step_graph"]]
    frames = info["frames"]
    assert len(frames) == FRAMES
    first, last = frames[0]["bodies"], frames[-1]["bodies"]
    np.testing.assert_allclose(first["crate"]["position"], [0.2, 0.3, 0.4], atol=1e-6)
    np.testing.assert_allclose(first["ball"]["velocity"], [-0.5, 0.0, 0.0], atol=1e-6)
    for name in ("crate", "ball"):
        for key in ("position", "orientation", "velocity", "angular_velocity", "fluid_force", "fluid_torque"):
            assert len(last[name][key]) == (4 if key == "orientation" else 3)
        assert last[name]["position"][2] < first[name]["position"][2]  # they fell
    assert any(f["bodies"]["ball"]["fluid_force"][2] > 0 for f in frames[1:])  # and hit the water


def test_usd_bodies_pass_check_usd_and_follow_the_poses(reference):
    (path,) = sorted(reference.glob("*.usdc"))
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert check_usd.main([str(path), "--strict"]) == 0, out.getvalue()
    stage = Usd.Stage.Open(str(path))
    frames = rf.read_run_json(reference)["frames"]
    for name in ("crate", "ball"):
        prim = stage.GetPrimAtPath(f"/sph/bodies/{name}")
        assert prim.IsA(UsdGeom.Mesh)
        local = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(), dtype=np.float64)
        for f in frames:
            t = Usd.TimeCode(f["frame"])
            m = np.asarray(UsdGeom.XformCache(t).GetLocalToWorldTransform(prim), dtype=np.float64)
            world = local @ m[:3, :3] + m[3, :3]
            pose = f["bodies"][name]
            expect = local @ quat_to_matrix(pose["orientation"]).T + np.asarray(pose["position"])
            np.testing.assert_allclose(world, expect, atol=2e-6)


def test_resume_continues_bit_for_bit(reference, tmp_path):
    out = tmp_path / "resumed"
    run_scene(out, frames=4, threaded_export=False)  # checkpoints 1, 3 and the final one, 4
    rf.checkpoint_path(out, 4).unlink()  # resume from frame 3
    cp = np.load(rf.checkpoint_path(out, 3))
    assert "rigid_body_q" in cp.files and "rigid_body_qd" in cp.files
    info = runner.run(None, frames=FRAMES, resume=out, progress=False, device="cpu", log=quiet)
    assert info["status"] == "completed"
    a, b = rf.read_run_json(reference), rf.read_run_json(out)
    assert a["frames"] == b["frames"] and a["steps"] == b["steps"]  # body poses, velocities, forces included
    for k in range(1, FRAMES + 1):
        fa, fb = np.load(rf.frame_path(reference, k)), np.load(rf.frame_path(out, k))
        for key in fa.files:
            assert np.array_equal(fa[key], fb[key]), (k, key)


def test_retry_restores_the_bodies():
    """The watchdog's frame start holds the bodies' Newton state: a restored frame replays bit for bit
    (on_instability = "retry": the frame start also holds the solver's warm start, DFSPH's P and P^v)."""
    sim = Simulation(scene_from_dict(scene_dict(output={"usd": False}, time={"on_instability": "retry"})))
    for _ in range(2):
        sim.advance_frame()  # the ball is in the water
    last = sim.last_frame
    q0 = sim.fields["body_q"].numpy().copy()
    x0 = sim.model.boundary_x.numpy().copy()
    sim.advance_frame()  # saves the frame start, then steps
    after = (sim.fields["body_q"].numpy().copy(), sim.get_field("particle_x"), sim.last_frame.bodies)
    assert not np.array_equal(after[0], q0)
    sim.watchdog.restore()
    assert np.array_equal(sim.fields["body_q"].numpy(), q0)
    assert np.array_equal(sim.model.boundary_x.numpy(), x0)  # the particles went back with the bodies
    sim.last_frame = last
    sim.advance_frame()
    assert np.array_equal(sim.fields["body_q"].numpy(), after[0])
    assert np.array_equal(sim.get_field("particle_x"), after[1])
    assert sim.last_frame.bodies == after[2]


@pytest.mark.parametrize("target", ["wall", "obstacle"])
def test_fast_body_never_passes_a_wall_or_obstacle(target):
    """A 0.1 m cube thrown at 5 m/s through shallow water at a container wall or a box obstacle: at
    every substep its centre stays more than half its size (less 1 cm of contact) inside the free side."""
    d = scene_dict(output={"usd": False}, fluid=[{"min": [0, 0, 0], "max": [0.6, 0.6, 0.1]}])
    d["bodies"] = [{"shape": "box", "size": [0.1, 0.1, 0.1], "position": [0.2, 0.3, 0.2], "density": 800.0,
                    "velocity": [5.0, 0.0, -1.0]}]
    limit = 0.6
    if target == "obstacle":
        d["obstacles"] = [{"shape": "box", "min": [0.4, 0.0, 0.0], "max": [0.5, 0.6, 0.6]}]
        limit = 0.4
    sim = Simulation(scene_from_dict(d))
    x = []
    sim.graph.insert(Stage("track", lambda sim, dt: x.append(sim.fields["body_q"].numpy()[0, 0] + sim.model.origin[0]),
                           reads=("body_q",)), after="bodies")
    for _ in range(4):
        sim.advance_frame()
    x = np.asarray(x)
    assert x.max() > limit - 0.05 - 0.02  # it reached the wall
    assert x.max() < limit - 0.05 + 0.01, x.max()


def test_preview_draws_the_bodies(reference, tmp_path):
    pytest.importorskip("PIL")
    from warp_sph.preview.render_run import BODY_COLOR, Camera, body_meshes, preview_run

    meta = json.loads((reference / "run.json").read_text())
    solids = body_meshes(meta)[FRAMES]
    assert len(solids) == 2
    verts = solids[0][0]
    pose = meta["frames"][-1]["bodies"]["crate"]
    np.testing.assert_allclose(verts.mean(axis=0), pose["position"], atol=1e-6)  # a box: vertex mean = centre
    camera = Camera(position=(0.3, -0.9, 0.9), target=(0.3, 0.3, 0.3))
    (png,) = preview_run(reference, frames=[FRAMES], camera=camera, size=(160, 90), out=tmp_path)
    from PIL import Image

    image = np.asarray(Image.open(png)).astype(float)
    colour = np.asarray(BODY_COLOR) * 255
    assert (np.linalg.norm(image - colour, axis=2) < 80).sum() > 20  # body-coloured pixels


@pytest.mark.parametrize("change, message", [
    (lambda d: d["bodies"][0].update(mass=1.0), r"bodies\[0\]\.density: expected exactly one of density"),
    (lambda d: d["bodies"][0].update(size=[0.2, 0.0, 0.1]), r"bodies\[0\]\.size: expected 3 edge lengths > 0"),
    (lambda d: d["bodies"][0].update(size=[0.2, 0.05, 0.1]), r"bodies\[0\]\.size: expected every edge > 0\.0717"),
    (lambda d: d["bodies"][1].update(radius=0.03), r"bodies\[1\]\.radius: expected > 0\.0358"),
    (lambda d: d["bodies"][0].update(position=[0.05, 0.3, 0.4]), r"bodies\[0\]: spans .* not inside the container"),
    (lambda d: d["bodies"][1].update(position=[0.25, 0.3, 0.45]), r"bodies\[1\]: overlaps bodies\[0\] at t = 0"),
    (lambda d: d.update(obstacles=[{"shape": "box", "min": [0.1, 0.2, 0.0], "max": [0.3, 0.4, 0.35]}]),
     r"bodies\[0\]: overlaps obstacles\[0\]"),
    (lambda d: d["bodies"][0].update(name="1crate"), r"bodies\[0\]\.name: expected letters"),
    (lambda d: d["bodies"][1].update(name="crate"), r"bodies\[1\]\.name: 'crate' is also the name of bodies\[0\]"),
    (lambda d: d["bodies"][0].update(density=-5.0), r"bodies\[0\]\.density: expected a finite number > 0"),
    (lambda d: d["bodies"][0].update(radius=0.1), r"bodies\[0\]\.radius: not used by shape 'box'"),
    (lambda d: d["bodies"][0].update(spin=1.0), r"bodies\[0\]\.spin: unknown key"),
    (lambda d: d.update(rigid={"contact_friction": -1.0}), r"rigid\.contact_friction: expected a finite number >= 0"),
])
def test_bad_bodies_are_one_line_errors(change, message):
    d = scene_dict()
    change(d)
    with pytest.raises(SceneError, match=message) as err:
        scene_from_dict(d)
    assert "\n" not in str(err.value)


def test_mesh_body_must_be_closed(tmp_path):
    path = tmp_path / "open.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\n")  # one face missing
    d = scene_dict()
    d["bodies"][0] = {"shape": "mesh", "file": str(path), "scale": 0.2, "position": [0.2, 0.3, 0.4], "density": 500.0}
    with pytest.raises(SceneError, match=r"bodies\[0\]\.file: mesh .* is not closed"):
        scene_from_dict(d)


@pytest.mark.parametrize("solver", ["wcsph", "pbf"])
def test_hash_grid_variant_refuses_bodies(solver):
    """The solvers with a wp.HashGrid variant (DFSPH has none) refuse bodies there in one line."""
    with pytest.raises(SceneError, match=r"hash-grid variant \(lists=False\) cannot move bodies"):
        Simulation(scene_from_dict(scene_dict(solver=solver, output={"usd": False})), solver_options={"lists": False})


def test_scene_with_bodies_and_no_newton_names_the_install_command(monkeypatch, tmp_path, capsys):
    """Validation refuses a scene with bodies when Newton does not import: one line with the command,
    exit status 2 from the CLI, before anything is sampled or built."""
    import sys

    from warp_sph.cli import main

    monkeypatch.setitem(sys.modules, "newton", None)  # `import newton` raises ImportError
    with pytest.raises(SceneError, match=r"bodies: .*pip install 'warp-sph\[rigid\]'") as err:
        scene_from_dict(scene_dict())
    assert "\n" not in str(err.value)
    path = tmp_path / "scene.toml"
    path.write_text('particle_radius = 0.03\n[container]\nmin = [0, 0, 0]\nmax = [0.6, 0.6, 0.6]\n'
                    '[[fluid]]\nmin = [0, 0, 0]\nmax = [0.6, 0.6, 0.24]\n'
                    '[[bodies]]\nsize = [0.2, 0.2, 0.2]\nposition = [0.3, 0.3, 0.4]\ndensity = 500.0\n')
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err_text = capsys.readouterr().err
    assert "pip install 'warp-sph[rigid]'" in err_text and not (tmp_path / "out").exists()


def test_a_solver_without_the_coupling_term_refuses_bodies():
    """A registered solver that does not name body_coupling_after is refused at validation, in one line."""
    from warp_sph.methods import registry
    from warp_sph.methods.solver import Solver

    class NoCoupling(Solver):
        name = "nocoupling"
        title = "a solver without the boundary pressure term (a test solver)"

    registry.register_solver(NoCoupling)
    try:
        with pytest.raises(SceneError, match=r"bodies: solver 'nocoupling' with boundary 'akinci2012' cannot move "
                                             r"bodies: the nocoupling solver does not provide the wall pressure term"):
            scene_from_dict(scene_dict(solver="nocoupling"))
        scene_from_dict({k: v for k, v in scene_dict(solver="nocoupling").items() if k != "bodies"})  # fine without
    finally:
        registry.unregister("nocoupling")


def test_export_keeps_the_bodies(reference, tmp_path):
    """warp-sph export of a run with bodies writes them again, at the poses of the run (same samples)."""
    from warp_sph.io.reexport import export_run

    path = export_run(reference, fmt="usd", out=tmp_path / "again.usdc")
    (original,) = sorted(reference.glob("*.usdc"))
    a, b = Usd.Stage.Open(str(original)), Usd.Stage.Open(str(path))
    for name in ("crate", "ball"):
        for attr in ("xformOp:translate", "xformOp:orient", "points"):
            pa = a.GetAttributeAtPath(f"/sph/bodies/{name}.{attr}")
            pb = b.GetAttributeAtPath(f"/sph/bodies/{name}.{attr}")
            assert pa.GetTimeSamples() == pb.GetTimeSamples()
            for t in pa.GetTimeSamples():
                assert np.array_equal(np.asarray(pa.Get(t)), np.asarray(pb.Get(t))), (name, attr, t)
