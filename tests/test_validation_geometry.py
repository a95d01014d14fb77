"""The Lobovsky case's geometry against the experiment's (scenes/validation/lobovsky.toml's ``container.inner``,
warp_sph/scene/container.py): the water fills the paper's column and tank at every resolution, the sensors sit at
Table 2's heights above the water's floor, and a transducer 3 mm above the floor of a tank at rest reads the hydrostatic pressure there."""
import numpy as np
import pytest

from warp_sph.scene import scene_from_dict
from warp_sph.scene.sampling import sample_scene
from warp_sph.validation import errors as E
from warp_sph.validation.cases import CASES, LOBOVSKY_HEIGHTS_MM, LOBOVSKY_SENSORS, load_case_scene, water_offset

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
    frame of the water's floor: z = 0 with ``container.inner``, g d - r above the floor's particles without)."""
    from warp_sph.run.simulation import Simulation

    scene = load_case_scene(CASES["hydrostatic"], "dfsph", 0.025)
    data = scene.to_dict()
    floor = 0.0 if walls else water_offset(scene)
    data["probes"] = [{"name": "low", "kind": "pressure", "position": [0.0, 0.305, 0.003], "rate": 48.0,
                       "sensor_diameter": 0.0042},
                      {"name": "surface", "kind": "height", "position": [0.305, 0.305, 0.0], "rate": 48.0}]
    data["container"]["inner"] = walls
    scene = scene_from_dict(data, source="tank")
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


def test_bench_validation_bad_set_is_one_error_before_any_case(tmp_path, monkeypatch):
    """``bench validation --set bogus=1`` (or a bad value) stops with the scene loader's one-line error before the
    first case runs (it failed every case one by one, exit 1), and no run folder or record is written."""
    from warp_sph.benchmarks import runner, validation as V
    from warp_sph.core.errors import WarpSphError

    monkeypatch.setattr(V, "run_one", lambda *a, **kw: pytest.fail("a case ran"))
    for bad, match in (("bogus=1", "bogus: unknown key"), ("dfsph.target_density_error=abc", "target_density_error")):
        with pytest.raises(WarpSphError, match=match):
            runner.main(["validation", "--cases", "hydrostatic,lobovsky", "--solvers", "dfsph", "--set", bad,
                         "--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "out")])
    assert not (tmp_path / "runs").exists() and not (tmp_path / "out" / "validation.jsonl").exists()


def test_scene_file_is_the_bench_case(tmp_path):
    """``warp-sph run scenes/validation/lobovsky.toml`` builds what the bench runs (one source of truth: the scene
    file's ``container.inner``): at r = 10 mm with DFSPH the same fluid and wall particles, container and probes as
    ``load_case_scene``; and a run.json scene, loaded again, keeps those walls (``inner`` is resolved once)."""
    from warp_sph.scene import load_scene
    from warp_sph.scene.sampling import sample_scene

    from warp_sph.validation.cases import _scene_dir

    user = load_scene(str(_scene_dir() / CASES["lobovsky"].scene))
    bench = load_case_scene(CASES["lobovsky"], "dfsph", user.particle_radius)
    assert user.solver == bench.solver == "dfsph"
    a, b = sample_scene(user), sample_scene(bench)
    np.testing.assert_array_equal(a.fluid_x, b.fluid_x)
    np.testing.assert_array_equal(a.boundary_x, b.boundary_x)
    assert (user.container.min, user.container.max) == (bench.container.min, bench.container.max)
    assert user.container.min[2] == pytest.approx(-water_offset(user)) and not user.container.inner
    assert [(p.name, p.position, p.sensor_diameter) for p in user.probes] == \
        [(p.name, p.position, p.sensor_diameter) for p in bench.probes]
    again = scene_from_dict(user.to_dict(), source="run.json")
    assert (again.container.min, again.container.max) == (user.container.min, user.container.max)
    assert [p.position for p in again.probes] == [p.position for p in user.probes]


def test_plot_draws_the_experiment_beside_each_sensor(tmp_path, monkeypatch):
    """``warp-sph plot RUN`` of a run of scenes/validation/lobovsky.toml (2 frames at 20 fps here) draws, beside
    each sensor naming ``experiment``, the shipped curve in SI units (t = T sqrt(H/g) [s], p = P rho g H [Pa]) over
    the run's time span, and nothing beside the kernel loads (matplotlib replaced by a recorder: no extra needed)."""
    from unittest import mock

    from warp_sph.preview import plot_probes
    from warp_sph.run import runner
    from warp_sph.scene import load_scene
    from warp_sph.validation.cases import _scene_dir

    scene = load_scene(str(_scene_dir() / CASES["lobovsky"].scene), overrides=["output.usd=false", "fps=20"])
    assert {p.name: p.experiment for p in scene.probes if p.experiment} == \
        {s: f"lobovsky_2014_{s}" for s in LOBOVSKY_SENSORS}
    runner.run(scene, out=tmp_path / "run", frames=2, progress=False, log=lambda *a: None)
    made, saved = [], []

    def subplots(*args, **kwargs):
        made.append(mock.MagicMock())
        return mock.MagicMock(), made[-1]

    monkeypatch.setattr(plot_probes, "pyplot", lambda: mock.MagicMock(subplots=subplots))
    monkeypatch.setattr(plot_probes, "save_figure", lambda fig, path: saved.append(path.stem) or path)
    plot_probes.plot_run(tmp_path / "run")
    assert len(saved) == len(made) == 6
    t_end = 0.05  # 2 frames at 20 fps: t = 0 .. 0.05 s
    for name, ax in zip(saved, made):
        lines = ax.plot.call_args_list
        s = name.removeprefix("probe_")
        if s not in LOBOVSKY_SENSORS:
            assert len(lines) == 1, name
            continue
        assert len(lines) == 2 and "Lobovsky et al. 2014" in lines[1].kwargs["label"], name
        te, pe = lines[1].args[0], lines[1].args[1]
        T, P, _ = E.load_series(f"lobovsky_2014_{s}")
        keep = T * np.sqrt(0.3 / G) <= t_end + 1e-9
        assert keep.sum() >= 2
        np.testing.assert_allclose(te, T[keep] * np.sqrt(0.3 / G))
        np.testing.assert_allclose(pe, P[keep] * 1000.0 * G * 0.3)


def test_inner_box_is_written_back_and_placed_for_each_radius():
    """``to_dict`` of a scene with ``container.inner`` gives the box and probes as written (inner = true), so the
    scene changed to another radius and loaded again (``warp-sph plan``'s variants, run.json) puts its walls the
    water offset of that radius outside the box: at r = 5 mm the same file's walls and sensors are those the
    loader gives at 5 mm, not those of 10 mm."""
    from warp_sph.scene import load_scene
    from warp_sph.validation.cases import _scene_dir

    path = str(_scene_dir() / CASES["lobovsky"].scene)
    coarse = load_scene(path)
    d = coarse.to_dict()
    assert d["container"]["inner"] is True and d["container"]["max"] == [1.61, 0.15, 0.6]
    assert [p["position"] for p in d["probes"]][:3] == [[1.61, 0.075, 0.003], [1.61, 0.075, 0.03], [1.61, 0.075, 0.08]]
    assert scene_from_dict(d) == coarse
    d["particle_radius"] = 0.005
    fine, direct = scene_from_dict(d), load_scene(path, overrides=["particle_radius=0.005"])
    assert fine == direct and fine.container.max[0] == pytest.approx(1.61 + water_offset(fine))
    assert water_offset(fine) < 0.7 * water_offset(coarse)
