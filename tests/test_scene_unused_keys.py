"""Keys of a solver's or boundary's section that the scene's method does not read: one warning line naming
the key, the section and the method in use (``--set solver=pbf`` would make them count); a key no section knows
stays an error."""
import warnings

import numpy as np
import pytest

from warp_sph.core.errors import SceneError
from warp_sph.scene import load_scene, scene_from_dict
from warp_sph.scene.unused import UnusedKeyWarning

SCENE = """
particle_radius = 0.1
{solver}
[pbf]
max_iterations = 3
target_density_error = 0.005

[container]
min = [0.0, 0.0, 0.0]
max = [1.0, 1.0, 1.0]

[[fluid]]
min = [0.0, 0.0, 0.0]
max = [0.4, 0.4, 0.4]
"""


def _load(*args):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(*args)
    return scene, [str(w.message) for w in caught if issubclass(w.category, UnusedKeyWarning)]


def test_another_solvers_keys_warn_once_naming_key_section_and_solver(tmp_path):
    f = tmp_path / "mine.toml"
    f.write_text(SCENE.format(solver=""))
    scene, lines = _load(str(f))
    # target_density_error = 0.005 is pbf's default: it changes nothing whichever solver runs, so it is not named
    assert lines == [f"{f}: pbf.max_iterations: no effect with solver 'dfsph' (the [pbf] keys apply with "
                     "solver = 'pbf', e.g. --set solver=pbf)"]
    assert scene.solver == "dfsph" and scene.pbf.max_iterations == 3  # kept: --set solver=pbf uses it
    scene, lines = _load(str(f), ["solver=pbf"])
    assert lines == [] and scene.pbf.max_iterations == 3
    f.write_text(SCENE.format(solver='solver = "pbf"'))
    assert _load(str(f))[1] == []
    # --set of another solver's key, and of the unused boundary's
    _, lines = _load(str(f), ["dfsph.max_iterations=50", "penalty.strength=2"])
    assert len(lines) == 2 and "dfsph.max_iterations: no effect with solver 'pbf'" in lines[0]
    assert "penalty.strength: no effect with boundary 'akinci2012'" in lines[1] and "--set boundary=penalty" in lines[1]


def test_a_misspelt_key_of_an_unused_section_is_still_an_error(tmp_path):
    f = tmp_path / "mine.toml"
    f.write_text(SCENE.format(solver="").replace("max_iterations = 3", "iterations = 3"))
    with pytest.raises(SceneError, match=r"mine\.toml: pbf\.iterations: unknown key; expected one of "):
        load_scene(str(f))


def test_builtin_scenes_carry_every_solvers_tuning_without_a_warning_but_set_keys_warn():
    """hydrostatic sets [pbf] relaxation = 1 for a --set solver=pbf run: not the user's doing, not named."""
    scene, lines = _load("hydrostatic")
    assert lines == [] and scene.solver == "dfsph" and scene.pbf.relaxation == 1.0
    _, lines = _load("hydrostatic", ["pbf.max_iterations=7"])
    assert len(lines) == 1 and lines[0].endswith("hydrostatic.toml: pbf.max_iterations: no effect with solver "
                                                 "'dfsph' (the [pbf] keys apply with solver = 'pbf', e.g. --set "
                                                 "solver=pbf)")
    assert _load("hydrostatic", {"pbf.max_iterations": 7})[1] == lines


def test_wcsph_speed_of_sound_is_read_by_every_solver_so_it_does_not_warn():
    """c_s (wcsph.speed_of_sound / stiffness / factor) scales the Akinci friction and the penalty force of any
    solver: with dfsph it is not 'no effect'."""
    from warp_sph.core.model import _speed_of_sound

    scene, lines = _load("dam_break", ["wcsph.speed_of_sound=37", "wcsph.density_diffusion=0.1"])
    assert len(lines) == 1 and "wcsph.density_diffusion:" in lines[0] and "speed_of_sound" not in lines[0]
    x = np.array([[0.1, 0.1, 0.1]])
    assert _speed_of_sound(scene, x, np.zeros((1, 3)), np.zeros(3))[1] == 37.0


def test_a_scene_written_out_whole_loads_without_warnings(tmp_path):
    """Scene.to_dict holds every method's section at its values (plan --apply writes it as TOML): only keys
    that differ from their defaults are named."""
    from warp_sph.plan.report import toml_text

    scene = load_scene("dam_break", ["particle_radius=0.1"])
    f = tmp_path / "whole.toml"
    f.write_text(toml_text(scene.to_dict()))
    back, lines = _load(str(f))
    assert lines == [] and back == scene_from_dict(scene.to_dict())


def test_the_cli_prints_the_warning_as_one_line(tmp_path, capsys):
    from warp_sph.cli import main

    f = tmp_path / "mine.toml"
    f.write_text(SCENE.format(solver=""))
    assert main(["check", str(f)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"warp-sph: warning: {f}: pbf.max_iterations: no effect with solver 'dfsph' (the [pbf] keys "
                   "apply with solver = 'pbf', e.g. --set solver=pbf)"], err


def test_akinci_friction_keys_warn_with_the_penalty_boundary(tmp_path):
    """material.boundary_friction and bodies[].fluid_friction are the Akinci boundary's friction term (sigma);
    the penalty wall has none."""
    f = tmp_path / "mine.toml"
    f.write_text(SCENE.format(solver='solver = "pbf"\nboundary = "penalty"\n[material]\nboundary_friction = 0.2\n'))
    scene, lines = _load(str(f))
    assert scene.material.boundary_friction == 0.2
    assert lines == [f"{f}: material.boundary_friction: no effect with boundary 'penalty' (the friction of the "
                     "akinci2012 boundary: boundary = 'akinci2012', e.g. --set boundary=akinci2012)"]
    assert _load(str(f), ["boundary=akinci2012"])[1] == []
    assert _load(str(f), ["material.boundary_friction=0"])[1] == []  # 0: no friction either way
    # a built-in scene: the keys given with --set only
    _, lines = _load("floating_bodies", ["boundary=penalty", "bodies[1].fluid_friction=0.5"])
    assert len(lines) == 1 and ": bodies[1].fluid_friction: no effect with boundary 'penalty'" in lines[0]
