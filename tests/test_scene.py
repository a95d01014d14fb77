"""Scene files: loading, defaults, overrides, validation errors, round trip, parameter table."""
import json
import math

import pytest

from warp_sph.core.errors import SceneError
from warp_sph.scene import (
    all_parameters,
    Scene,
    list_scenes,
    load_scene,
    parameter_table_markdown,
    scene_from_dict,
)

BUILTIN = ["dam_break", "hydrostatic", "radial_expansion", "drop_into_pool", "obstacle", "floating_bodies",
           "droplet_zero_g", "crown_splash", "honey", "bunny_splash", "paddle", "faucet", "river"]

MINIMAL = """
[[fluid]]
min = [0.0, 0.0, 0.0]
max = [0.5, 0.5, 0.5]
"""


def write(tmp_path, text, name="scene.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_builtin_scene_names():
    names = [n for n, _ in list_scenes()]
    assert sorted(names) == sorted(BUILTIN)
    assert all(desc for _, desc in list_scenes())


@pytest.mark.parametrize("name", BUILTIN)
def test_builtin_scene_loads(name):
    scene = load_scene(name)
    assert isinstance(scene, Scene)
    assert scene.name == name
    assert scene.fluid


def test_dam_break_values():
    s = load_scene("dam_break")
    assert s.particle_radius == 0.025 and s.spacing == 0.05
    assert s.duration == 2.0 and s.fps == 24.0
    assert s.container.min == (0.0, 0.0, 0.0) and s.container.max == (4.0, 1.5, 3.0)
    assert s.fluid[0].min == (0.0, 0.0, 0.0) and s.fluid[0].max == (1.0, 1.0, 1.0)


def test_radial_expansion_has_no_container_or_gravity():
    s = load_scene("radial_expansion")
    assert s.container is None
    assert s.gravity == (0.0, 0.0, 0.0)
    assert s.fluid[0].spacing_scale == 0.9


def test_defaults_resolved(tmp_path):
    s = load_scene(str(write(tmp_path, MINIMAL)))
    assert s.name == "scene"
    assert s.particle_radius == 0.025
    assert s.smoothing_kernel == "cubic" and s.h_per_spacing is None
    assert s.solver == "dfsph" and s.boundary == "akinci2012"
    assert s.boundary_gap is None and 1.05 * s.spacing < s.wall_gap < 1.15 * s.spacing
    assert s.gravity == (0.0, 0.0, -9.81)
    assert s.material.rest_density == 1000.0 and s.material.viscosity == 0.0
    assert s.wcsph.equation_of_state == "linear" and s.wcsph.speed_of_sound_factor == 10.0
    assert s.pbf.max_iterations == 50 and s.pbf.min_iterations == 2 and s.pbf.tensile_correction is False
    assert s.dfsph.target_density_error == 5e-4 and s.dfsph.warm_start == 0.5 and s.dfsph.divergence_solve is True
    assert s.time.cfl == 0.4 and s.time.dt_max == 5e-3 and s.time.fixed_dt == 0.0
    assert s.container.max == (4.0, 1.5, 3.0)
    assert s.output.usd is True and s.output.particle_primvars == ["density"]
    assert s.output.surface_cell_per_radius == 2.0 and s.output.surface_iso == 0.6
    assert s.output.surface_spray_neighbors == 5 and s.output.surface_decimation_error == 0.0
    assert s.fluid[0].shape == "box" and s.fluid[0].velocity == (0.0, 0.0, 0.0)
    assert s.fluid[0].spacing_scale == 1.0
    assert s.obstacles == [] and s.whitewater is None and "whitewater" not in s.to_dict()
    # every table parameter has a value in to_dict
    d = s.to_dict()
    optional = {p.path for p in all_parameters() if p.kind == "table" and p.default is None}  # [plan]: absent
    for p in all_parameters():
        if (p.kind in ("table", "tables", "table_or_false") or "[]" in p.path or p.path.startswith("forces[")
                or p.default is None or p.section in optional or p.path.startswith("whitewater.")):
            continue
        section, _, key = p.path.rpartition(".")
        assert key in (d[section] if section else d), p.path


def test_smoothing_length_follows_kernel(tmp_path):
    s = load_scene(str(write(tmp_path, MINIMAL)), ["smoothing_kernel=quintic"])
    assert math.isclose(s.smoothing_length, 2.0 / 3.0 * s.spacing)
    assert math.isclose(s.support_radius, 2.0 * s.spacing)
    s = load_scene(str(write(tmp_path, MINIMAL)), ["h_per_spacing=1.2"])
    assert math.isclose(s.smoothing_length, 1.2 * s.spacing)


def test_overrides_by_key_path():
    s = load_scene("dam_break", [
        "particle_radius=0.02",
        "material.rest_density=998",
        "fluid[0].max=[1, 1, 0.5]",
        "output.usd=false",
        "smoothing_kernel=quintic",
        "output.mesh_sequence=",
        "pbf.max_iterations=7",
    ])
    assert s.particle_radius == 0.02
    assert s.material.rest_density == 998.0
    assert s.fluid[0].max == (1.0, 1.0, 0.5)
    assert s.output.usd is False
    assert s.smoothing_kernel == "quintic"
    assert s.output.mesh_sequence == ""
    assert s.pbf.max_iterations == 7


def test_overrides_as_dict_and_container_false():
    s = load_scene("dam_break", {"container": False, "gravity": [0, 0, 0], "fluid[0].velocity": [1, 0, 0]})
    assert s.container is None
    assert s.gravity == (0.0, 0.0, 0.0)
    assert s.fluid[0].velocity == (1.0, 0.0, 0.0)


def test_override_errors_name_the_key():
    with pytest.raises(SceneError, match=r"dam_break\.toml.*material\.nope"):
        load_scene("dam_break", ["material.nope=1"])
    with pytest.raises(SceneError, match=r"fluid\[3\].*out of range"):
        load_scene("dam_break", ["fluid[3].min=[0,0,0]"])
    with pytest.raises(SceneError, match=r"KEY=VALUE"):
        load_scene("dam_break", ["particle_radius"])
    with pytest.raises(SceneError, match=r"dam_break\.toml: particle_radius: expected a finite number > 0"):
        load_scene("dam_break", ["particle_radius=-1"])


BAD = [
    # (toml text, key path in the message, a word of what was expected)
    ("colour = 1\n" + MINIMAL, "colour", "unknown key"),
    ("[material]\ndensity = 1000\n" + MINIMAL, "material.density", "unknown key"),
    (MINIMAL + "spacing_scale = 1.0\nfoo = 2\n", "fluid[0].foo", "unknown key"),
    ("particle_radius = 'big'\n" + MINIMAL, "particle_radius", "number"),
    ("particle_radius = -0.01\n" + MINIMAL, "particle_radius", "> 0"),
    ("particle_radius = 0\n" + MINIMAL, "particle_radius", "> 0"),
    ("particle_radius = nan\n" + MINIMAL, "particle_radius", "finite"),
    ("duration = inf\n" + MINIMAL, "duration", "finite"),
    ("gravity = [0, 0]\n" + MINIMAL, "gravity", "3"),
    ("gravity = [0, nan, 0]\n" + MINIMAL, "gravity", "finite"),
    ("[pbf]\nmax_iterations = 2.5\n" + MINIMAL, "pbf.max_iterations", "integer"),
    ("[output]\nusd = 1\n" + MINIMAL, "output.usd", "true or false"),
    ("[output]\nparticle_primvars = ['velocity']\n" + MINIMAL, "output.particle_primvars", "density"),
    ("solver = 'sph'\n" + MINIMAL, "solver", "wcsph"),
    ("smoothing_kernel = 'gaussian'\n" + MINIMAL, "smoothing_kernel", "cubic"),
    ("[wcsph]\nequation_of_state = 'cole'\n" + MINIMAL, "wcsph.equation_of_state", "tait"),
    ("fps = 24\n", "fluid", "at least one"),
    ("[[fluid]]\nmin = [0, 0, 0]\n", "fluid[0].max", "missing"),
    ("[[fluid]]\nmin = [0, 0, 0]\nmax = [5, 1, 1]\n", "fluid[0]", "container"),
    ("[[fluid]]\nshape = 'sphere'\ncenter = [3.9, 1, 1]\nradius = 0.2\n", "fluid[0]", "container"),
    ("[[fluid]]\nmin = [1, 0, 0]\nmax = [0.5, 1, 1]\n", "fluid[0].max", "fluid[0].min"),
    ("[[fluid]]\nshape = 'sphere'\nmin = [0, 0, 0]\nradius = 0.2\n", "fluid[0].min", "shape"),
    ("[[fluid]]\nshape = 'cone'\nmin = [0, 0, 0]\n", "fluid[0].shape", "box"),
    ("[container]\nmin = [0, 0, 0]\nmax = [1, -1, 1]\n" + MINIMAL, "container.max", "container.min"),
    ("[pbf]\nmin_iterations = 9\nmax_iterations = 3\n" + MINIMAL, "pbf.min_iterations", "max_iterations"),
    (MINIMAL + "spacing_scale = 0.1\n", "fluid[0].spacing_scale", ">= 0.5"),
    ("[[obstacles]]\nshape = 'mesh'\nfile = 'nothere.obj'\n" + MINIMAL, "obstacles[0].file", "not found"),
]


@pytest.mark.parametrize("text,key,expected", BAD)
def test_bad_input_names_file_and_key(tmp_path, text, key, expected):
    path = write(tmp_path, text)
    with pytest.raises(SceneError) as info:
        load_scene(str(path))
    msg = str(info.value)
    assert "\n" not in msg
    assert str(path) in msg
    assert f": {key}:" in msg
    assert expected in msg


@pytest.mark.parametrize("suffix", [".obj", ".stl", ".ply"])
def test_text_file_that_is_not_a_mesh(tmp_path, suffix):
    (tmp_path / f"notes{suffix}").write_text("these are my notes, not a mesh\n")
    path = write(tmp_path, f"[[obstacles]]\nshape = 'mesh'\nfile = 'notes{suffix}'\n" + MINIMAL)
    with pytest.raises(SceneError) as info:
        load_scene(str(path))
    msg = str(info.value)
    assert str(path) in msg and "obstacles[0].file" in msg and f"notes{suffix}" in msg


def test_mesh_path_resolves_against_scene_folder(tmp_path, monkeypatch):
    sub = tmp_path / "sub"
    (sub / "m").mkdir(parents=True)
    (sub / "m" / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    path = write(sub, "[[obstacles]]\nshape = 'mesh'\nfile = 'm/tri.obj'\n" + MINIMAL)
    monkeypatch.chdir(tmp_path)
    s = load_scene(str(path))
    assert s.obstacles[0].file == str((sub / "m" / "tri.obj").resolve())
    assert s.obstacles[0].scale == 1.0 and s.obstacles[0].translate == (0.0, 0.0, 0.0)
    assert s.obstacles[0].min is None


def test_malformed_toml(tmp_path):
    path = write(tmp_path, "particle_radius = 0.025\n[material\nrest_density = 1000\n")
    with pytest.raises(SceneError) as info:
        load_scene(str(path))
    msg = str(info.value)
    assert str(path) in msg and "line 2" in msg


def test_unknown_scene_name():
    with pytest.raises(SceneError, match="dam_break"):
        load_scene("no_such_scene")
    with pytest.raises(SceneError, match="not found"):
        load_scene("missing/file.toml")


def test_scene_from_dict_validates():
    s = scene_from_dict({"fluid": [{"shape": "sphere", "center": [1, 1, 1], "radius": 0.3}]}, source="script")
    assert s.fluid[0].radius == 0.3 and s.fluid[0].min is None
    with pytest.raises(SceneError, match=r"^script: fluid\[0\]\.radius: "):
        scene_from_dict({"fluid": [{"shape": "sphere", "center": [1, 1, 1], "radius": -1}]}, source="script")


@pytest.mark.parametrize("name", BUILTIN)
def test_to_dict_round_trip(name):
    s = load_scene(name, ["h_per_spacing=1.1"] if name == "hydrostatic" else None)
    d = s.to_dict()
    json.dumps(d)  # JSON-serialisable
    assert "source" not in d
    assert scene_from_dict(d) == s
    assert scene_from_dict(json.loads(json.dumps(d))) == s


def test_parameter_table_lists_every_parameter():
    table = parameter_table_markdown()
    rows = {line.split("|")[1].strip().strip("`"): line for line in table.splitlines()[2:]}
    assert len(rows) == len(all_parameters())
    assert all(line.count("|") == 7 for line in table.splitlines())  # six cells, no stray pipes
    for p in all_parameters():
        row = rows[p.path]
        cells = [c.strip() for c in row.split("|")[1:-1]]
        assert cells[2] == p.unit, p.path
        assert cells[5], p.path  # description
    assert rows["particle_radius"].split("|")[4].strip() == "0.025"
    assert rows["material.rest_density"].split("|")[3].strip() == "kg/m^3"
    assert rows["gravity"].split("|")[4].strip() == "[0, 0, -9.81]"
    assert rows["fluid[].min"].split("|")[4].strip() == "required"
    from warp_sph.methods import registry

    assert ", ".join(f'"{n}"' for n in registry.solver_names()) in rows["solver"]
    assert set(registry.solver_names()) >= {"wcsph", "pbf"}
