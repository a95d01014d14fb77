"""Transducer probes (probes[].sensor_diameter, warp_sph/run/probe_sensors.py): the face's share of each wall
cell, the device sum against a brute-force NumPy oracle of the same force split, and a column at rest whose
floor and side-wall transducers read rho0 g depth."""
import numpy as np
import pytest

from warp_sph.run.probe_sensors import face_weights
from warp_sph.run.simulation import Simulation

from small_scenes import small_tank
from sph_oracle import grad_W

G = 9.81


def test_face_weights_share_the_disc_among_wall_cells():
    """A sensor smaller than a wall cell, centred on a lattice point, is that one cell (w = 1, A = s^2); centred
    on a cell's edge in two halves, on its corner in four quarters; 3 mm over the floor the bottom cell is a half cell."""
    lo, hi = np.zeros(3), np.array([0.8, 0.6, 0.8])
    (cell,) = face_weights(np.array([0.3, 0.2, 0.0]), 0.0042, lo, hi, 2, 0.1)
    assert cell[0] == (3, 2) and cell[1] == pytest.approx(1.0) and cell[2] == pytest.approx(0.01)
    two = face_weights(np.array([0.35, 0.2, 0.0]), 0.05, lo, hi, 2, 0.1)
    assert len(two) == 2 and all(w == pytest.approx(0.5, abs=5e-3) for _, w, _ in two)
    corner = face_weights(np.array([0.35, 0.25, 0.0]), 0.05, lo, hi, 2, 0.1)
    assert len(corner) == 4 and all(w == pytest.approx(0.25, abs=5e-3) for _, w, _ in corner)
    (edge,) = face_weights(np.array([0.0, 0.3, 0.003]), 0.0042, lo, hi, 0, 0.1)
    assert edge[0] == (3, 0) and edge[2] == pytest.approx(0.1 * 0.05)


def test_transducer_matches_numpy_oracle():
    """Two substeps with different wall forces F_i: the reading is (dt1 p1 + dt2 p2) / (dt1 + dt2), p the face
    particle's sum_i s_i V_b grad_i W_ib . n / A_b with s_i = F_i . G_i / |G_i|^2 (brute force in float64)."""
    probes = [{"name": "floor", "kind": "pressure", "position": [0.3, 0.2, 0.0], "rate": 24.0, "sensor_diameter": 0.0042},
              {"name": "side", "kind": "pressure", "position": [0.0, 0.3, 0.2], "rate": 24.0, "sensor_diameter": 0.0042}]
    sim = Simulation(small_tank("sensor_tank", probes=probes))
    m, probes_ = sim.model, sim.probes
    x = sim.get_field("particle_x").astype(np.float64)
    xb = m.to_world(m.boundary_x.numpy())
    vb = m.boundary_volume.numpy().astype(np.float64)
    h, H = m.smoothing_length, m.support_radius
    rng = np.random.default_rng(3)
    group = probes_.groups[0]
    expect = np.zeros(2)
    for dt in (0.002, 0.003):
        F = rng.normal(0.0, 20.0, x.shape) + np.array([0.0, 0.0, 30.0])
        sim.set_field("boundary_force", F.astype(np.float32))
        probes_.grid.build(sim.fields["particle_x"])
        group.sensors.accumulate(sim, probes_.grid.id, m.boundary_grid_id, dt)
        for k, (point, axis) in enumerate((((0.3, 0.2, 0.0), 2), ((0.0, 0.3, 0.2), 0))):
            b = int(np.argmin(np.linalg.norm(xb - np.asarray(point), axis=1)))
            n = np.zeros(3)
            n[axis] = 1.0
            load = 0.0
            for i in np.flatnonzero(np.linalg.norm(x - xb[b], axis=1) < H):
                near = np.linalg.norm(x[i] - xb, axis=1) < H
                g = (vb[near, None] * grad_W(m.smoothing.name, x[i] - xb[near], h)).sum(axis=0)
                load += F[i] @ g / (g @ g) * vb[b] * grad_W(m.smoothing.name, (x[i] - xb[b])[None], h)[0] @ n
            expect[k] += dt * load / 0.1 ** 2  # one 0.1 m wall cell: w = 1
    group.sensors.read(group.values, 0)
    got = group.values.numpy()[0]
    assert np.all(np.abs(expect) > 1.0)
    np.testing.assert_allclose(got, expect / 0.005, rtol=1e-4)
    assert group.sensors.elapsed == 0.0 and not group.sensors.impulse.numpy().any()


def test_transducers_in_a_column_at_rest_read_rho0_g_depth():
    """The hydrostatic tank (scenes/validation, r = 0.025 m, DFSPH) after 0.5-1 s: a 4.2 mm transducer in the
    middle of the floor reads rho0 g D within 2.5 % (D: the water's volume over the floor it covers, from
    the water's floor gap - r), one on a side wall about 0.1 m up (on the wall particle nearest to that point) rho0 g (h - z) within 3 %, h
    the height probe's surface (measured: -2.1 % with the 0.61 m walls, where 0.1 m was a wall particle's height)."""
    from warp_sph.scene import scene_from_dict
    from warp_sph.validation.cases import CASES, load_case_scene

    scene = load_case_scene(CASES["hydrostatic"], "dfsph", 0.025)
    data = scene.to_dict()
    lo = scene.container.min  # the wall particles' planes, gap - r outside the water's 0.6 m tank
    from warp_sph.scene.sampling import sample_scene

    b = sample_scene(scene).boundary_x.astype(np.float64)  # the side transducer on a wall particle, as at 0.61 m
    b = b[np.abs(b[:, 0] - lo[0]) < 1e-6]
    side = b[np.argmin(np.hypot(b[:, 1] - 0.3, b[:, 2] - 0.1))]
    data["probes"] = [{"name": "floor", "kind": "pressure", "position": [0.3, 0.3, lo[2]], "rate": 48.0,
                       "sensor_diameter": 0.0042},
                      {"name": "wall", "kind": "pressure", "position": [lo[0], float(side[1]), float(side[2])], "rate": 48.0,
                       "sensor_diameter": 0.0042},
                      {"name": "surface", "kind": "height", "position": [0.3, 0.3, lo[2]], "rate": 48.0}]
    sim = Simulation(scene_from_dict(data, source="column"))
    got = {"floor": [], "wall": [], "surface": []}
    while sim.state.time < 1.0 - 1e-9:
        sim.advance_frame()
        for k, v in sim.probes.collect().items():
            got[k] += [p for t, p, _ in v if t >= 0.5]
    m = sim.model
    depth = m.fluid_count * m.particle_mass / m.rest_density / 0.6 ** 2  # the water fills the 0.6 m tank
    assert np.mean(got["floor"]) == pytest.approx(1000.0 * G * depth, rel=2.5e-2)
    assert np.mean(got["wall"]) == pytest.approx(1000.0 * G * (np.mean(got["surface"]) - side[2]), rel=3e-2)


def test_sensor_diameter_only_on_a_wall_pressure_probe():
    """One-line SceneErrors before any step: on a height probe (not its kind's key), inside the fluid."""
    from warp_sph.core.errors import SceneError

    with pytest.raises(SceneError, match=r"probes\[0\]\.sensor_diameter: not used by kind 'height'"):
        small_tank("x", probes=[{"kind": "height", "position": [0.3, 0.3, 0.0], "sensor_diameter": 0.004}])
    with pytest.raises(SceneError, match=r"probes\[0\]\.sensor_diameter: a transducer lies on a container wall"):
        Simulation(small_tank("x", probes=[{"kind": "pressure", "position": [0.3, 0.3, 0.3], "sensor_diameter": 0.004}]))
