"""Bad input through the command line and through load_scene: one clear line on stderr, a non-zero
exit status, no traceback, and no file that existed before is changed or lost."""
import hashlib
import json
import re
import warnings
from pathlib import Path

import pytest

from warp_sph.cli import main
from warp_sph.core.errors import SceneError
from warp_sph.scene import load_scene

GOOD = """
name = "tiny"
particle_radius = 0.05
duration = 0.05
fps = 20.0
[container]
min = [0.0, 0.0, 0.0]
max = [0.8, 0.6, 0.8]
[[fluid]]
min = [0.0, 0.0, 0.0]
max = [0.4, 0.6, 0.4]
[output]
usd = false
surface = false
"""


def snapshot(folder: Path) -> dict:
    """{relative path: sha256} of every file under folder."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def run_cli(args, capsys):
    code = main(args)
    err = capsys.readouterr().err
    return code, err


def error_line(err: str) -> str:
    """The one 'warp-sph: error:' line (Warp may print its own CUDA banner lines before it)."""
    lines = [ln for ln in err.splitlines() if ln.startswith("warp-sph: error:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """A folder with a user's files in it (that must survive every failed run) as the cwd."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("my notes\n")
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "measurements.csv").write_text("t,x\n0,1\n")
    return tmp_path


def write(folder: Path, name: str, text: str) -> Path:
    p = folder / name
    p.write_text(text)
    return p


CASES = {
    # name: (scene text or None for GOOD, extra CLI args, pattern the error line must match)
    "malformed_toml": ("particle_radius = = 0.05\n", [], r"malformed TOML"),
    "unterminated_table": ("[container\nmin = [0, 0, 0]\n", [], r"malformed TOML"),
    "unknown_solver": (GOOD.replace('name = "tiny"', 'name = "tiny"\nsolver = "sph9000"'), [],
                       r"solver: expected one of .*'pbf'.*'wcsph'.*, got 'sph9000'"),
    "unknown_kernel": (GOOD.replace('name = "tiny"', 'name = "tiny"\nsmoothing_kernel = "gauss"'), [],
                       r"smoothing_kernel: expected one of .*'cubic'.*got 'gauss'"),
    "nan_radius": (GOOD.replace("particle_radius = 0.05", "particle_radius = nan"), [],
                   r"particle_radius: expected a finite number > 0 and <= 1000, got nan"),
    "inf_gravity": (GOOD.replace('name = "tiny"', 'name = "tiny"\ngravity = [0.0, 0.0, -inf]'), [],
                    r"gravity: expected a list of 3 finite numbers"),
    "negative_radius": (GOOD.replace("particle_radius = 0.05", "particle_radius = -0.05"), [],
                        r"particle_radius: expected a finite number > 0 and <= 1000, got -0.05"),
    "negative_viscosity_set": (None, ["--set", "material.viscosity=-1"],
                               r"material.viscosity: expected a finite number >= 0, got -1"),
    "nan_set": (None, ["--set", "material.rest_density=nan"], r"material.rest_density: expected a finite number"),
    "negative_fps": (None, ["--set", "fps=-24"], r"fps: expected a finite number > 0"),
    "no_fluid": ("\n".join(ln for ln in GOOD.splitlines() if "fluid" not in ln and not ln.startswith(("min", "max")))
                 + "\n", [], r"fluid: expected at least one \[\[fluid\]\] block"),
    "fluid_smaller_than_d": (GOOD.replace("max = [0.4, 0.6, 0.4]", "max = [0.01, 0.01, 0.01]"), [],
                             r"no fluid particle left after sampling"),
    "fluid_outside_container": (GOOD.replace("max = [0.4, 0.6, 0.4]", "max = [0.4, 0.6, 4.0]"), [],
                                r"fluid\[0\]: box .* is not inside the container"),
    "inverted_box": (GOOD.replace("max = [0.4, 0.6, 0.4]", "max = [-0.4, 0.6, 0.4]"), [],
                     r"fluid\[0\]\.max: expected every component >"),
    "unknown_key": (GOOD.replace('name = "tiny"', 'name = "tiny"\nparticle_radios = 0.05'), [],
                    r"particle_radios: unknown key"),
    "fixed_dt_above_bound": (None, ["--set", "solver=wcsph", "--set", "time.fixed_dt=0.004"],
                             r"time\.fixed_dt: 0\.004 s is .*x the acoustic CFL time-step bound"),
    "fixed_dt_above_velocity_bound": (None, ["--set", "time.fixed_dt=0.02"],
                                      r"time\.fixed_dt: 0\.02 s is .*x the velocity CFL time-step bound"),
    # issue 36, the rest of the trial: a traceback, a hang, silent or wrong causes before the fix
    "huge_radius": (GOOD.replace("particle_radius = 0.05", "particle_radius = 1e30"), [],
                    r"particle_radius: expected a finite number > 0 and <= 1000, got 1e\+30"),  # ZeroDivisionError
    "endless_smoothing": (None, ["--set", "output.surface=true", "--set", "output.surface_smoothing_iterations=1000000000"],
                          r"output\.surface_smoothing_iterations: expected an integer >= 0 and <= 1000"),  # ran forever
    "endless_normal_smoothing": (None, ["--set", "output.surface_normal_smoothing_iterations=1000000000"],
                                 r"output\.surface_normal_smoothing_iterations: expected an integer >= 0 and <= 1000"),
    "all_spray": (None, ["--set", "output.surface_spray_neighbors=1000000000"],
                  r"output\.surface_spray_neighbors: expected <= 17, .*flat free surface"),
    "surface_spray": (None, ["--set", "output.surface_spray_neighbors=18"], r"output\.surface_spray_neighbors: expected <= 17"),
    "huge_gravity": (None, ["--set", "gravity=[0,0,-1e30]"],
                     r"gravity: expected a list of 3 finite numbers of length <= 1000, got \[0, 0, -1e\+30\]"),
    "container_true": (GOOD.replace("[container]\nmin = [0.0, 0.0, 0.0]\nmax = [0.8, 0.6, 0.8]", "container = true"), [],
                       r"container: expected a table \(\[container\] with min and max\) or false, got true"),
    "single_fluid_table": (GOOD.replace("[[fluid]]", "[fluid]"), [],
                           r"fluid: expected an array of tables: write \[\[fluid\]\] .*got a single table \[fluid\]"),
    "single_bodies_table": (GOOD + "[bodies]\nshape = \"box\"\nsize = [0.1, 0.1, 0.1]\nposition = [0.6, 0.3, 0.6]\n"
                            "density = 500.0\n", [],
                            r"bodies: expected an array of tables: write \[\[bodies\]\] .*got a single table \[bodies\]"),
    "single_obstacles_table": (GOOD + "[obstacles]\nmin = [0.6, 0.2, 0.0]\nmax = [0.7, 0.4, 0.2]\n", [],
                               r"obstacles: expected an array of tables: write \[\[obstacles\]\]"),
    "endless_frames": (None, ["--frames", "1000000000"],  # the max-steps preflight that duration = 1e30 gets
                       r"the run needs about .* substeps .*--frames 1,000,000,000 at 20 fps\), more than time\.max_steps"),
    "unknown_scene": ("__builtin__:no_such_scene", [], r"no such scene file or built-in scene"),
    "missing_file": ("__path__:missing.toml", [], r"missing.toml: scene file not found"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_cli_bad_scene(case, workdir, capsys):
    text, extra, pattern = CASES[case]
    if text is not None and text.startswith("__builtin__:"):
        scene_arg = text.split(":", 1)[1]
    elif text is not None and text.startswith("__path__:"):
        scene_arg = str(workdir / text.split(":", 1)[1])
    else:
        scene_arg = str(write(workdir, "scene.toml", GOOD if text is None else text))
    before = snapshot(workdir)
    code, err = run_cli(["run", scene_arg, "--out", str(workdir / "out"), "--no-progress"] + extra, capsys)
    assert code != 0
    line = error_line(err)
    assert re.search(pattern, line), line
    after = snapshot(workdir)
    for path, digest in before.items():
        assert after.get(path) == digest, f"{path} changed or vanished"


def test_mesh_file_that_is_not_a_mesh(workdir, capsys):
    (workdir / "cylinder.obj").write_text("this is not a mesh\n\x00\x01 binary junk\n")
    (workdir / "picture.stl").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(200))
    for name in ("cylinder.obj", "picture.stl", "nowhere.ply", "notes.txt"):
        scene = GOOD + f'[[obstacles]]\nshape = "mesh"\nfile = "{name}"\n'
        path = write(workdir, "scene.toml", scene)
        before = snapshot(workdir)
        code, err = run_cli(["run", str(path), "--out", str(workdir / "out"), "--no-progress"], capsys)
        assert code != 0
        line = error_line(err)
        assert "obstacles[0].file" in line and name in line, line
        assert snapshot(workdir) == before
        with pytest.raises(SceneError, match=r"obstacles\[0\]\.file"):
            load_scene(str(path))


def test_mesh_file_that_is_a_folder(workdir, capsys):
    """A folder given as a mesh file was reported "not found"."""
    path = write(workdir, "scene.toml", GOOD + '[[obstacles]]\nshape = "mesh"\nfile = "data"\n')
    before = snapshot(workdir)
    code, err = run_cli(["run", str(path), "--out", str(workdir / "out"), "--no-progress"], capsys)
    assert code == 2 and "obstacles[0].file: mesh file" in error_line(err)
    assert error_line(err).endswith("data' is a folder; expected a mesh file")
    assert snapshot(workdir) == before


def test_non_empty_output_folder_is_refused(workdir, capsys):
    scene = write(workdir, "scene.toml", GOOD)
    out = workdir / "data"  # holds the user's measurements, not a run
    before = snapshot(workdir)
    code, err = run_cli(["run", str(scene), "--out", str(out), "--no-progress"], capsys)
    assert code != 0
    assert re.search(r"output folder .*data is not empty and holds no warp-sph run", error_line(err))
    code, err = run_cli(["run", str(scene), "--out", str(out), "--no-progress", "--overwrite"], capsys)
    assert code != 0
    error_line(err)
    assert snapshot(workdir) == before


def test_output_path_is_a_file(workdir, capsys):
    scene = write(workdir, "scene.toml", GOOD)
    before = snapshot(workdir)
    code, err = run_cli(["run", str(scene), "--out", str(workdir / "notes.txt"), "--no-progress"], capsys)
    assert code != 0
    assert "exists and is not a folder" in error_line(err)
    assert snapshot(workdir) == before


def test_unwritable_output_folder(workdir, capsys):
    import os

    scene = write(workdir, "scene.toml", GOOD)
    locked = workdir / "locked"
    locked.mkdir()
    (locked / "keep.txt").write_text("keep me\n")
    locked.chmod(0o555)
    try:
        if os.access(locked, os.W_OK):
            pytest.skip("running as a user who can write anywhere (root)")
        before = snapshot(workdir)
        for out in (locked / "run", locked):
            code, err = run_cli(["run", str(scene), "--out", str(out), "--no-progress"], capsys)
            assert code != 0
            error_line(err)
        assert snapshot(workdir) == before
    finally:
        locked.chmod(0o755)


def test_unwritable_output_folder_as_root(workdir, capsys, monkeypatch):
    """Where permissions cannot be tested (root), a write that fails still gives one line."""
    from warp_sph.io import run_folder

    def refuse(self, *a, **k):
        raise PermissionError(13, "Permission denied")

    scene = write(workdir, "scene.toml", GOOD)
    monkeypatch.setattr(run_folder.Path, "write_bytes", refuse)
    before = snapshot(workdir)
    code, err = run_cli(["run", str(scene), "--out", str(workdir / "new_out"), "--no-progress"], capsys)
    assert code != 0
    assert re.search(r"cannot write to output folder .*new_out: Permission denied", error_line(err))
    assert snapshot(workdir) == before


def test_previous_run_is_kept_without_overwrite(workdir, capsys):
    scene = write(workdir, "scene.toml", GOOD)
    out = workdir / "run1"
    code, _ = run_cli(["run", str(scene), "--out", str(out), "--no-progress", "--frames", "2"], capsys)
    assert code == 0
    before = snapshot(workdir)
    code, err = run_cli(["run", str(scene), "--out", str(out), "--no-progress", "--frames", "2"], capsys)
    assert code != 0
    assert "holds a previous run; pass --overwrite" in error_line(err)
    assert snapshot(workdir) == before


def test_check_command_reports_bad_scene(workdir, capsys):
    path = write(workdir, "scene.toml", GOOD.replace("particle_radius = 0.05", "particle_radius = 0"))
    code, err = run_cli(["check", str(path)], capsys)
    assert code == 2
    assert "particle_radius: expected a finite number > 0 and <= 1000, got 0" in error_line(err)


@pytest.mark.parametrize("text,pattern", [
    ("particle_radius = = 1", r"malformed TOML"),
    ('solver = "iisph"\n[[fluid]]\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n', r"solver: expected one of"),
    ("particle_radius = nan\n[[fluid]]\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n", r"particle_radius"),
    ("[material]\nviscosity = -0.1\n[[fluid]]\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n", r"material\.viscosity"),
    ("fluid = []\n", r"expected at least one \[\[fluid\]\] block"),
])
def test_load_scene_errors(text, pattern, tmp_path):
    path = write(tmp_path, "bad.toml", text)
    with pytest.raises(SceneError, match=pattern) as err:
        load_scene(str(path))
    assert str(path) in str(err.value) and "\n" not in str(err.value)


# -- first-hour findings (issue 15) ------------------------------------------------------------------
WITH_USD = GOOD.replace("usd = false\nsurface = false\n", "usd = true\nsurface = true\ncheckpoint_every = 3\n") \
    .replace("duration = 0.05", "duration = 0.35")  # 8 frames at 20 fps


def test_binary_or_latin1_scene_file(workdir, capsys):
    """A scene file that is not UTF-8 text (binary junk, a Latin-1 byte) is a one-line SceneError."""
    cases = {"latin1.toml": GOOD.replace('name = "tiny"', 'name = "caf\xe9"').encode("latin-1"),
             "binary.toml": bytes(range(256)) * 4,
             "utf16.toml": GOOD.encode("utf-16")}
    for name, data in cases.items():
        (workdir / name).write_bytes(data)
        before = snapshot(workdir)
        code, err = run_cli(["run", str(workdir / name), "--out", str(workdir / "out"), "--no-progress"], capsys)
        assert code == 2, err
        line = error_line(err)
        assert name in line and ("UTF-8" in line or "malformed TOML" in line), line
        assert snapshot(workdir) == before
        code, err = run_cli(["check", str(workdir / name)], capsys)
        assert code == 2 and name in error_line(err)


@pytest.mark.parametrize("device", ["gpu7", "cuda:0", "cuda", "CPU", ""])
def test_bad_device_is_one_line_and_creates_nothing(device, workdir, capsys):
    import warp as wp

    if device.startswith("cuda") and wp.get_cuda_device_count() > 0:
        device = "cuda:99"  # a device this machine does not have either
    scene = write(workdir, "scene.toml", GOOD)
    before = snapshot(workdir)
    code, err = run_cli(["run", str(scene), "--device", device, "--no-progress"], capsys)
    assert code == 2
    line = error_line(err)
    assert f"--device {device}" in line and "available: cpu" in line, line
    assert not (workdir / "runs").exists() and snapshot(workdir) == before


def test_failed_start_removes_what_it_created(workdir, capsys, monkeypatch):
    """A start that fails once the folder exists (here: the USD cannot be created) removes the run
    folder it made (runs/ included); in a folder that existed it removes only its own files."""
    from warp_sph.io import export_usd

    def refuse(*args, **kwargs):
        raise export_usd.OutputError("cannot create USD file (simulated)")

    monkeypatch.setattr(export_usd, "create_stage", refuse)
    scene = write(workdir, "scene.toml", WITH_USD)
    before = snapshot(workdir)
    code, err = run_cli(["run", str(scene), "--no-progress"], capsys)
    assert code == 2 and "simulated" in error_line(err)
    assert not (workdir / "runs").exists() and snapshot(workdir) == before
    kept = workdir / "kept"
    kept.mkdir()
    code, err = run_cli(["run", str(scene), "--out", str(kept), "--no-progress"], capsys)
    assert code == 2 and kept.is_dir() and list(kept.iterdir()) == []


@pytest.mark.parametrize("name", ["../precious", "../../x", "/tmp/abs", "a/b\\c", "..", ".hidden", "tank v2"])
def test_scene_name_never_places_files_outside_the_run(name, workdir, capsys):
    """The scene name becomes file names only after sanitising: nothing is written beside or
    above the run folder, whatever the name says."""
    out = workdir / "out"
    out.mkdir()
    (out / "precious.usdc").write_bytes(b"the user's own USD")
    (workdir / "x").mkdir()
    text = WITH_USD.replace('name = "tiny"', f"name = {name!r}".replace("'", '"').replace("\\", "\\\\"))
    scene = write(workdir, "scene.toml", text)
    before = snapshot(workdir)
    code, err = run_cli(["run", str(scene), "--out", str(out / "run"), "--no-progress", "--frames", "2"], capsys)
    assert code == 0, err
    code, err = run_cli(["run", str(scene), "--no-progress", "--frames", "2"], capsys)  # default folder
    assert code == 0, err
    after = snapshot(workdir)
    for path, digest in before.items():
        assert after.get(path) == digest, f"{path} changed"
    new = sorted(set(after) - set(before))
    assert new and all(p.startswith(("out/run/", "runs/")) for p in new), new
    (usd,) = [p for p in new if p.startswith("out/run/") and p.endswith(".usdc")]
    assert "/" not in usd[len("out/run/"):]
    (default_run,) = {p.split("/")[1] for p in new if p.startswith("runs/")}
    assert not default_run.startswith(".") and default_run not in ("", "..")


def run_with_usd(workdir: Path, capsys, out_name="run", frames=8, text=None) -> Path:
    scene = write(workdir, "scene.toml", text or WITH_USD)
    out = workdir / out_name
    code, err = run_cli(["run", str(scene), "--out", str(out), "--no-progress", "--frames", str(frames)], capsys)
    assert code == 0, err
    return out


def test_overwrite_removes_only_run_files(workdir, capsys):
    out = run_with_usd(workdir, capsys, frames=3)
    (out / "frames" / "my_extra.json").write_text("{}")
    (out / "checkpoints" / "notes.txt").write_text("mine")
    (out / "other.usdc").write_bytes(b"another USD of mine")
    (out / "frames" / "frame_12.npz").write_bytes(b"not one of ours (6 digits)")
    mine = {p: (out / p).read_bytes() for p in ("frames/my_extra.json", "checkpoints/notes.txt", "other.usdc",
                                                "frames/frame_12.npz")}
    scene = workdir / "scene.toml"
    code, err = run_cli(["run", str(scene), "--out", str(out), "--no-progress", "--frames", "2", "--overwrite"],
                        capsys)
    assert code == 0, err
    for p, data in mine.items():
        assert (out / p).read_bytes() == data, p
    assert sorted(p.name for p in (out / "frames").glob("frame_??????.npz")) == ["frame_000001.npz", "frame_000002.npz"]


def test_refused_resume_changes_nothing(workdir, capsys):
    """With the USD gone, a resume is refused, and every frame after the checkpoint is still there;
    a resume that proceeds removes only the frames after its checkpoint, and says so."""
    out = run_with_usd(workdir, capsys)
    (out / "checkpoints" / "checkpoint_000008.npz").unlink()  # latest is now 7; frame 8 comes after it
    usd = out / "tiny.usdc"
    moved = workdir / "tiny.usdc.bak"
    usd.rename(moved)
    before = snapshot(workdir)
    code, err = run_cli(["run", "--resume", str(out), "--frames", "10", "--no-progress"], capsys)
    assert code == 2 and "does not exist" in error_line(err)
    assert snapshot(workdir) == before and (out / "frames" / "frame_000008.npz").is_file()
    moved.rename(usd)
    code = main(["run", "--resume", str(out), "--frames", "10", "--no-progress"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "from frame 7" in captured.out and "removed 1 files of frames 8..8" in captured.out, captured.out
    assert (out / "frames" / "frame_000008.npz").is_file()  # written again


def test_checkpoint_of_another_scene_is_refused(workdir, capsys):
    """A checkpoint with another particle count, or a run.json whose scene was edited, is refused
    before anything changes."""
    import json
    import shutil

    out = run_with_usd(workdir, capsys)
    small = run_with_usd(workdir, capsys, out_name="small", frames=2,
                         text=WITH_USD.replace("max = [0.4, 0.6, 0.4]", "max = [0.2, 0.6, 0.2]"))
    shutil.copy(small / "checkpoints" / "checkpoint_000002.npz", out / "checkpoints" / "checkpoint_000009.npz")
    before = snapshot(workdir)
    code, err = run_cli(["run", "--resume", str(out), "--frames", "12", "--no-progress"], capsys)
    assert code == 2
    assert re.search(r"checkpoint_000009\.npz: holds \d+ fluid particles, the scene of run.json has \d+",
                     error_line(err))
    assert snapshot(workdir) == before
    (out / "checkpoints" / "checkpoint_000009.npz").unlink()
    info = json.loads((out / "run.json").read_text())
    info["scene"]["material"]["viscosity"] = 0.01  # same particles, another scene
    (out / "run.json").write_text(json.dumps(info))
    before = snapshot(workdir)
    code, err = run_cli(["run", "--resume", str(out), "--frames", "12", "--no-progress"], capsys)
    assert code == 2 and "written for another scene than the one in run.json" in error_line(err)
    assert snapshot(workdir) == before


def test_checkpoint_of_another_version_is_refused(workdir, capsys):
    """A checkpoint written by another warp-sph or Warp version is refused (a resume is bitwise only with
    the versions that started the run), naming the version to install; nothing changes."""
    import numpy as np

    out = run_with_usd(workdir, capsys)
    path = out / "checkpoints" / "checkpoint_000008.npz"
    with np.load(path) as f:
        data = dict(f)
    data["warp_version"] = np.array("0.0.1")
    np.savez(path, **data)
    before = snapshot(workdir)
    code, err = run_cli(["run", "--resume", str(out), "--frames", "12", "--no-progress"], capsys)
    assert code == 2
    assert re.search(r"checkpoint_000008\.npz: written with warp 0\.0\.1, this is .*install warp==0\.0\.1", error_line(err))
    assert snapshot(workdir) == before


@pytest.mark.parametrize("damage", ["truncated", "random_bytes", "empty_run_json", "run_json_list", "nan"])
def test_damaged_resume_input_is_one_line(damage, workdir, capsys):
    import numpy as np

    out = run_with_usd(workdir, capsys, frames=5)
    cp = out / "checkpoints" / "checkpoint_000005.npz"
    if damage == "truncated":
        cp.write_bytes(cp.read_bytes()[: cp.stat().st_size // 2])
    elif damage == "random_bytes":
        cp.write_bytes(np.random.default_rng(0).bytes(4096))
    elif damage == "empty_run_json":
        (out / "run.json").write_text("{}")
    elif damage == "run_json_list":
        (out / "run.json").write_text("[1, 2]")
    else:
        data = dict(np.load(cp))
        data["particle_v"][0, 0] = np.nan
        np.savez(cp, **data)
    before = snapshot(workdir)
    code, err = run_cli(["run", "--resume", str(out), "--frames", "9", "--no-progress"], capsys)
    assert code == 2
    line = error_line(err)
    assert ("checkpoint_000005.npz" in line) if damage in ("truncated", "random_bytes", "nan") else ("run.json" in line)
    assert snapshot(workdir) == before


def test_huge_gravity_is_one_line_without_numpy_warnings(workdir, capsys):
    """gravity = [0, 0, -1e30] printed a NumPy overflow warning and a message with NaN naming time.cfl."""
    scene = write(workdir, "scene.toml", GOOD.replace('name = "tiny"', 'name = "tiny"\ngravity = [0.0, 0.0, -1e30]'))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a NumPy RuntimeWarning on the way fails here
        code, err = run_cli(["run", str(scene), "--out", str(workdir / "out"), "--no-progress"], capsys)
    assert code == 2
    assert err.strip().splitlines() == [error_line(err)]
    assert "nan" not in err.lower() and "time.cfl" not in err


def test_resume_without_checkpoint_restarts_from_the_start(workdir, capsys):
    """A run killed before its first checkpoint left run.json (and maybe its USD) but no checkpoint:
    --resume refused ("no checkpoint") and a plain run refused the folder. Now --resume runs it again
    from frame 1 in its folder, says so in one line, and keeps the user's files there."""
    from warp_sph.io import atomic
    from warp_sph.io import run_folder as rf
    from warp_sph.scene import load_scene

    scene = load_scene(str(write(workdir, "scene.toml", GOOD.replace("usd = false", "usd = true"))))
    out = workdir / "out"
    out.mkdir()
    (out / "mine.txt").write_text("keep me\n")
    # what a run killed in its first second leaves: run.json written first, a USD, no frame, no checkpoint
    atomic.atomic_write_json(out / "run.json", {"scene": scene.to_dict(), "frames_requested": 2, "frames": [],
                                            "status": "starting", "out": str(out)})
    (out / "tiny.usdc").write_bytes(b"PXR-USDC partial")
    code = main(["run", "--resume", str(out), "--no-progress"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    said = [ln for ln in captured.out.splitlines() if "no checkpoint" in ln]
    assert said == [f"{out}: no checkpoint to resume from (it stopped before its first one): running it again "
                    "from frame 1 with the scene of its run.json, replacing its run files"]
    assert (out / "mine.txt").read_text() == "keep me\n"
    info = json.loads((out / "run.json").read_text())
    assert info["status"] == "completed" and [f["frame"] for f in info["frames"]] == [1, 2]
    assert rf.latest_checkpoint(out) is not None and (out / "tiny.usdc").stat().st_size > 100


def test_a_run_writes_run_json_before_its_usd(workdir, monkeypatch, capsys):
    """So that a run killed at its very start leaves a folder that --resume takes (before the fix
    the USD came first, and a folder holding only it was refused by both --resume and a plain run)."""
    from warp_sph.run import runner

    seen = []

    class Probe(runner.Exporter):
        def __init__(self, sim, out, **kw):
            seen.append(sorted(p.name for p in out.iterdir()))
            raise KeyboardInterrupt  # killed right here

    monkeypatch.setattr(runner, "Exporter", Probe)
    scene = write(workdir, "scene.toml", GOOD.replace("usd = false", "usd = true"))
    assert main(["run", str(scene), "--out", str(workdir / "out"), "--no-progress"]) == 130
    assert seen == [["run.json"]]


@pytest.mark.parametrize("args,pattern", [
    (["--size", "axb"], r"--size 'axb': expected WxH"),
    (["--size", "0x10"], r"--size '0x10'"),
    (["--size", "640"], r"--size '640'"),
    (["--frames", "a:b"], r"--frames 'a:b': expected A:B"),
    (["--frames", "5:2"], r"--frames '5:2'"),
    (["--camera", "1,2,3"], r"--camera '1,2,3': expected px,py,pz,tx,ty,tz"),
    (["--camera", "1,2,3,4,5,x"], r"--camera"),
    (["--camera", "1,2,3,1,2,3"], r"--camera '1,2,3,1,2,3': the position and the target are the same point"),
])
def test_preview_bad_arguments(args, pattern, workdir, capsys):
    code, err = run_cli(["preview", str(workdir)] + args, capsys)
    assert code == 2
    assert re.search(pattern, error_line(err)), err


@pytest.mark.parametrize("flag,value,pattern", [
    ("--surface-cell", "1e-9", r"--surface-cell 1e-09: expected a finite number >= 0\.1 and <= 4, as the scene key "
                               r"output\.surface_cell_per_radius"),
    ("--surface-cell", "0", r"--surface-cell 0: expected a finite number >= 0\.1"),
    ("--surface-iso", "2", r"--surface-iso 2: expected a finite number > 0 and < 1, as the scene key output\.surface_iso"),
])
def test_export_flags_take_the_scene_keys_range(flag, value, pattern, workdir, capsys):
    """``export RUN --surface-cell 1e-9`` wrote a USD whose surface was empty in every frame; the scene key
    refuses below 0.1, and now the flag does too, before anything is written."""
    import numpy as np

    run = workdir / "run"
    (run / "frames").mkdir(parents=True)
    model = {"smoothing_kernel": "cubic", "smoothing_length": 0.1, "particle_radius": 0.05}
    (run / "run.json").write_text(json.dumps({"scene": {"name": "tiny", "particle_radius": 0.05}, "model": model}))
    np.savez(run / "frames" / "frame_000001.npz", x=np.zeros((8, 3), np.float32), v=np.zeros((8, 3), np.float32),
             density=np.full(8, 1000.0, np.float32))
    before = snapshot(workdir)
    code, err = run_cli(["export", str(run), flag, value], capsys)
    assert code == 2
    assert re.search(pattern, error_line(err)), err
    assert snapshot(workdir) == before and not (run / "export").exists()


def test_python_api_bad_input_says_what_was_expected():
    """Scripts (docs/scripting.md): ``load_scene(name, "particle_radius=0.05")`` read the string character by
    character ("--set 'p': expected KEY=VALUE"); ``sim.step(-1.0)`` stepped backwards without a word; an
    unknown field was a bare KeyError 'name'."""
    from warp_sph.run.simulation import Simulation

    scene = load_scene("dam_break", "particle_radius=0.1")
    assert scene.particle_radius == 0.1
    sim = Simulation(load_scene("dam_break", ["particle_radius=0.1", "output.usd=false"]))
    for dt in (-1.0, 0.0, float("nan"), "1e-3"):
        with pytest.raises(ValueError, match=r"Simulation.step: dt must be a finite number of seconds > 0"):
            sim.step(dt)
    assert sim.state.step == 0 and sim.state.time == 0.0
    with pytest.raises(KeyError, match=r"field 'nope' is not an array of this simulation; its arrays: .*particle_x"):
        sim.get_field("nope")


@pytest.mark.parametrize("argv,words", [
    (["plan", "tank", "--budget", "-5s"], "plan: argument --budget: expected one argument (a value that starts "
                                          "with '-' is written --budget=VALUE)"),
    (["run", "--frames", "x"], "run: argument --frames: invalid int value: 'x'"),
    (["export"], "export: the following arguments are required: run"),
    (["preview", "r", "--frame", "1", "--frames", "1:2"], "preview: argument --frames: not allowed with"),
    (["runn"], "invalid choice: 'runn'"),
    (["scenes", "extra"], "scenes: unrecognized arguments: extra; see warp-sph scenes --help"),
    (["bench", "splishsplash", "--repeats", "x"], "bench splishsplash: argument --repeats: expected an integer > 0"),
    (["bench", "--bogus"], "bench: unrecognized arguments: --bogus; see warp-sph bench --help"),
])
def test_argparse_errors_are_one_line(argv, words, workdir, capsys):
    """argparse's refusals print one line (not its usage block), exit status 2, nothing written."""
    before = snapshot(workdir)
    code, err = run_cli(argv, capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "usage:" not in err, err
    assert words in error_line(err)
    assert snapshot(workdir) == before


def test_a_sweep_file_given_to_run_points_to_sweep(workdir, capsys):
    """``warp-sph run SWEEP.toml`` listed every scene key as expected instead of naming the command."""
    path = write(workdir, "sw.toml", '[sweep]\nscene = "dam_break"\nparam = { solver = ["wcsph", "pbf"] }\n')
    before = snapshot(workdir)
    for command in ("run", "check"):
        code, err = run_cli([command, str(path)], capsys)
        assert code == 2 and error_line(err).endswith(f"sw.toml: sweep: a sweep file ([sweep] / [[case]]), not a "
                                                      f"scene; run it with: warp-sph sweep {path}"), err
    assert snapshot(workdir) == before
