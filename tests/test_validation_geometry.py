"""The Lobovsky case's geometry against the experiment's (warp_sph/validation/cases.py, ``experiment_walls``): the
water fills the paper's column and tank at every resolution, the sensors sit at Table 2's heights above the
water's floor, and a transducer 3 mm above the floor of a tank at rest reads the hydrostatic pressure there."""
import numpy as np
import pytest

from warp_sph.scene import scene_from_dict
from warp_sph.scene.sampling import sample_scene
from warp_sph.validation import errors as E
from warp_sph.validation.cases import (CASES, LOBOVSKY_HEIGHTS_MM, LOBOVSKY_SENSORS, experiment_walls,
                                       load_case_scene, water_offset)

G = 9.81


@pytest.mark.parametrize("radius", [0.01, 0.005])
def test_lobovsky_water_and_sensors_are_the_experiments(radius):
    """At the bench's two radii the sampled water spans the paper's column, 0.6 m long and H = 0.3 m high from the
    tank's floor and end wall (each particle filling r around its centre; before, the column lost the water offset
    g d - r at each wall: H = 0.28 m at r = 10 mm), and the transducers sit on the downstream wall's particle
    plane, on the tank's centreline, at the heights above the floor of the shipped Table 2 (3, 30, 80 mm)."""
    scene = load_case_scene(CASES["lobovsky"], "dfsph", radius)
    x = sample_scene(scene).fluid_x
    r, d = radius, 2.0 * radius
    lo, hi = x.min(axis=0) - r, x.max(axis=0) + r
    np.testing.assert_allclose(lo, 0.0, atol=1e-9)
    assert hi[0] == pytest.approx(0.6, abs=1e-9) and hi[2] == pytest.approx(0.3, abs=1e-9)
    assert 0.15 - d < hi[1] <= 0.15 + 1e-9  # whole columns across the 0.15 m width
    c = scene.container
    off = water_offset(scene)
    assert 0.5 * d < off < 0.7 * d  # g d - r with g about 1.1
    assert c.max[0] == pytest.approx(1.61 + off) and c.min[2] == pytest.approx(-off)
    table, _ = E.load_table("lobovsky_2014_peaks")
    probes = {p.name: p for p in scene.probes}
    for s in LOBOVSKY_SENSORS:
        p = probes[s]
        assert p.sensor_diameter == pytest.approx(0.0042)
        assert p.position[0] == pytest.approx(c.max[0]) and p.position[1] == pytest.approx(0.5 * (c.min[1] + c.max[1]))
        assert 1000.0 * p.position[2] == pytest.approx(LOBOVSKY_HEIGHTS_MM[s]) and LOBOVSKY_HEIGHTS_MM[s] in table["z_mm"]


def _tank_reading(walls: bool, duration: float = 0.8) -> tuple[float, float]:
    """The hydrostatic tank (r = 0.025 m, DFSPH) with a 4.2 mm transducer on a side wall 3 mm above the floor:
    (its mean reading over the second half, rho0 g (h - z_sensor) with h the height probe's surface, in the
    frame of the water's floor: z = 0 with ``experiment_walls``, g d - r above the floor's particles without)."""
    from warp_sph.run.simulation import Simulation

    from dataclasses import replace

    # the hydrostatic case's tank as its scene gives it (the case itself moves the walls out since issue #31)
    scene = load_case_scene(replace(CASES["hydrostatic"], experiment_walls=False), "dfsph", 0.025)
    data = scene.to_dict()
    floor = 0.0 if walls else water_offset(scene)
    data["probes"] = [{"name": "low", "kind": "pressure", "position": [0.0, 0.305, 0.003], "rate": 48.0,
                       "sensor_diameter": 0.0042},
                      {"name": "surface", "kind": "height", "position": [0.305, 0.305, 0.0], "rate": 48.0}]
    scene = scene_from_dict(data, source="tank")
    if walls:
        scene = experiment_walls(scene)
    sim = Simulation(scene)
    got = {"low": [], "surface": []}
    while sim.state.time < duration - 1e-9:
        sim.advance_frame()
        for k, v in sim.probes.collect().items():
            got[k] += [p for t, p, _ in v if t >= 0.5 * duration]
    return float(np.mean(got["low"])), 1000.0 * G * (float(np.mean(got["surface"])) - 0.003 - floor)


def test_transducer_3mm_above_the_floor_reads_the_hydrostatic_pressure():
    """Sensor 1's place (3 mm up a wall) in a tank at rest: with the experiment's walls (the wall particles g d - r
    behind the water's boundary) the transducer reads rho0 g (h - 3 mm) within 5 % (measured -2.5 %); at the
    lattice height 3 mm of the old geometry it read the floor-corner particle's half cell, which lies below the
    water's floor and carries a third of that (measured 0.34): sensor 1 read low with DFSPH and PBF for this."""
    got, expect = _tank_reading(walls=True)
    assert got == pytest.approx(expect, rel=0.05)
    old, expect_old = _tank_reading(walls=False)
    assert old < 0.5 * expect_old


def test_bench_radius_option(tmp_path, monkeypatch):
    """``bench validation --radius R``: one run per case and solver at R, labelled r=R; R <= 0 is a one-line error
    before any run."""
    from warp_sph.benchmarks import runner, validation as V
    from warp_sph.core.errors import WarpSphError

    calls = []
    monkeypatch.setattr(V, "run_one", lambda case, solver, res, out, **kw: calls.append((case.name, solver, res,
                                                                                           kw["radius"])) or {})
    V.run_validation(["lobovsky"], ["dfsph"], ["coarse", "fine"], tmp_path, radius=0.0025)
    assert calls == [("lobovsky", "dfsph", "r=0.0025", 0.0025)]
    with pytest.raises(WarpSphError, match="--radius"):
        runner.main(["validation", "--cases", "lobovsky", "--radius", "0", "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out" / "validation.jsonl").exists()
