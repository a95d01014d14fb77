"""Sphere obstacles ([[obstacles]] shape = "sphere", center, radius): static and animated (docs/colliders.md)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from warp_sph.core.errors import SceneError
from warp_sph.run.simulation import Simulation
from warp_sph.scene import scene_from_dict
from warp_sph.scene.sampling import PointGrid, sample_scene

C, R = np.array([0.2, 0.1, 0.06]), 0.05


def dam(**sphere) -> dict:
    """A 0.4 x 0.2 x 0.3 m tank (r = 0.02 m), a column of water at the left, a sphere on its way."""
    ob = {"shape": "sphere", "center": C.tolist(), "radius": R}
    ob.update(sphere)
    return {"name": "dam", "particle_radius": 0.02, "fps": 24.0, "duration": 0.5,
            "container": {"min": [0, 0, 0], "max": [0.4, 0.2, 0.3]},
            "fluid": [{"min": [0, 0, 0], "max": [0.4, 0.2, 0.16]}],
            "obstacles": [ob], "output": {"checkpoint_every": 2, "surface": False}}


def test_static_sphere_is_sampled_on_its_surface_and_holds_no_fluid():
    """Its particles lie on |x - c| = R (Fibonacci lattice, round(4 pi R^2 / d^2) points less those within d/2 of
    a wall particle), normals outward (x - c) / R; no fluid centre within the wall gap of them or inside; the
    fluid comes up to it (the nearest fluid centre is within the gap + one spacing)."""
    scene = scene_from_dict(dam())
    s = sample_scene(scene)
    d, gap = scene.spacing, scene.wall_gap
    mine = s.boundary_object == 0
    x, n = s.boundary_x[mine], s.boundary_normals[mine]
    full = int(round(4.0 * np.pi * R * R / d**2))
    assert 0.9 * full <= len(x) <= full  # the floor (z = 0) clips the points within d/2 of it
    np.testing.assert_allclose(np.linalg.norm(x - C, axis=1), R, rtol=0, atol=1e-12)
    np.testing.assert_allclose(n, (x - C) / R, atol=1e-6)
    walls = s.boundary_x[s.boundary_object == -1]
    assert PointGrid(walls, d).nearest_distance(x, d).min() >= 0.5 * d * (1 - 1e-9)
    dist = np.linalg.norm(s.fluid_x - C, axis=1)
    assert np.all(dist > R)
    near = PointGrid(x, 2.0 * gap).nearest_distance(s.fluid_x, 2.0 * gap)
    assert near.min() >= gap * (1 - 1e-6) and near.min() <= gap + d


def test_dam_break_around_a_sphere_runs_and_stays_outside(device):
    """A 0.12 m column collapses onto a sphere 0.09 m downstream: after 4 frames the front has reached it (within
    the wall gap + one spacing of its surface) and no fluid centre got inside (the impact at this coarse r = 0.02 m
    brings the nearest to about 0.9 r from the surface, measured: 0.018 m)."""
    d = dam(center=[0.27, 0.1, 0.06], radius=0.06)
    d["fluid"] = [{"min": [0, 0, 0], "max": [0.12, 0.2, 0.16]}]
    sim = Simulation(scene_from_dict(d), device=device)
    for _ in range(4):
        sim.advance_frame()
    x = sim.get_field("particle_x")
    assert np.all(np.isfinite(x))
    gap = np.linalg.norm(x - [0.27, 0.1, 0.06], axis=1).min() - 0.06
    assert 0.0 < gap < sim.scene.wall_gap + sim.model.spacing, gap


def test_animated_sphere_follows_its_keys(device):
    """Local samples on |x| = R about the local origin (center = 0), placed at x_local + T(t) at the keys."""
    keys = [{"time": 0.0, "translate": [0.1, 0.1, 0.22]}, {"time": 0.1, "translate": [0.3, 0.1, 0.22]}]
    sim = Simulation(scene_from_dict(dam(center=[0, 0, 0], keyframes=keys, interpolation="linear")),
                     device=device)
    c = sim.colliders.colliders[0]
    local = c.samples.local_x
    np.testing.assert_allclose(np.linalg.norm(local, axis=1), R, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(c.vertices, axis=1), R, atol=1e-12)  # the USD icosphere
    start = sim.colliders.start
    np.testing.assert_allclose(sim.get_field("boundary_x")[start:start + len(local)], local + keys[0]["translate"],
                               atol=1e-6)
    assert c.inside(np.array([keys[0]["translate"], [0.1, 0.1, 0.22 + 1.01 * R]])).tolist() == [True, False]
    for _ in range(3):  # frame 3 ends at 0.125 s, past the last key: held
        sim.advance_frame()
    np.testing.assert_allclose(sim.get_field("boundary_x")[start:start + len(local)], local + keys[1]["translate"],
                               atol=1e-5)


@pytest.mark.parametrize("change,message", [
    ({"radius": 0.0}, "obstacles[0].radius"),
    ({"radius": -0.1}, "obstacles[0].radius"),
    ({"radius": None}, "obstacles[0].radius"),
    ({"center": None}, "obstacles[0].center"),
    ({"min": [0, 0, 0]}, "obstacles[0].min"),
])
def test_bad_sphere_obstacles_are_one_line_errors(change, message):
    d = dam()
    for k, v in change.items():
        if v is None:
            d["obstacles"][0].pop(k)
        else:
            d["obstacles"][0][k] = v
    with pytest.raises(SceneError) as info:
        scene_from_dict(d)
    text = str(info.value)
    assert "\n" not in text and message in text, text


def test_emitter_inside_a_sphere_is_refused():
    d = dam()
    d["emitters"] = [{"shape": "circle", "position": C.tolist(), "direction": [1.0, 0.0, 0.0], "radius": 0.02,
                      "speed": 1.0, "end": 0.2}]
    with pytest.raises(SceneError, match=r"emitters\[0\]: the nozzle lies inside obstacles\[0\]"):
        scene_from_dict(d)


def test_sphere_radius_zero_on_the_command_line_exits_2(tmp_path):
    (tmp_path / "bad.toml").write_text("""particle_radius = 0.02
[container]
min = [0, 0, 0]
max = [0.4, 0.2, 0.3]
[[fluid]]
min = [0, 0, 0]
max = [0.4, 0.2, 0.16]
[[obstacles]]
shape = "sphere"
center = [0.2, 0.1, 0.06]
radius = 0.0
""")
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "warp_sph.cli", "run", str(tmp_path / "bad.toml"), "--out", str(out),
                        "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"{tmp_path / 'bad.toml'}: obstacles[0].radius" in lines[0], r.stderr
    assert not out.exists()
