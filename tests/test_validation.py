"""The validation bench's error figures, computed by the bench's own code (warp_sph/validation/errors.py and
validation.evaluate) from the shipped experimental data: the experiment itself scores 0, a known shift, scale
or offset is found again."""
import math

import numpy as np
import pytest

from warp_sph.benchmarks import validation as V
from warp_sph.validation import errors as E

SHIPPED = ("martin_moyce_1952_front", "martin_moyce_1952_residual", "koshizuka_oka_1996_front",
           "lobovsky_2014_sensor1", "lobovsky_2014_sensor3", "lobovsky_2014_sensor4")


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_series_have_citation_and_data(name):
    t, v, cite = E.load_series(name)
    assert len(t) >= 9 and np.all(np.isfinite(v)) and np.all(np.diff(t) >= 0)
    assert any("doi:" in line for line in cite), cite  # the paper is named with its DOI


def test_front_rms_of_the_experiment_is_zero_and_finds_a_shift():
    T, Z, _ = E.load_series("martin_moyce_1952_front")
    T0, Z0 = np.concatenate([[0.0], T]), np.concatenate([[1.0], Z])  # released at T = 0 from Z = 1
    same = E.front_rms(T0, Z0, T, Z)
    assert same["rms"] < 1e-9 and abs(same["shift"]) <= 1e-3 and same["points"] >= 10
    early = E.front_rms(T0 - 0.1, Z0, T, Z)  # a simulation 0.1 T ahead of the experiment
    assert early["shift"] == pytest.approx(0.1, abs=2e-3) and early["rms"] < 2e-3
    assert early["rms_unshifted"] > 0.02
    far = E.front_rms(T0 - 0.5, Z0, T, Z)  # more than the allowed 0.2 T: the shift stops at the bound
    assert far["shift"] == pytest.approx(0.2, abs=1e-3) and far["rms"] > 0.02
    scaled = E.front_rms(T0, 1.05 * Z0, T, Z)  # 5 % ahead everywhere: about 5 %
    assert 0.01 < scaled["rms"] <= 0.05 + 1e-9


def test_peak_and_gauge_figures():
    t, p, _ = E.load_series("lobovsky_2014_sensor1")
    same = E.peak(t, p, t, p)
    assert same["peak_error"] == 0.0 and same["time_error"] == 0.0 and same["exp_peak"] == pytest.approx(2.843)
    off = E.peak(1.05 * t, 1.1 * p, t, p)
    assert off["peak_error"] == pytest.approx(0.1) and off["time_error"] == pytest.approx(0.05)
    short = t <= 2.0  # a run that ends before the impact compares with the experiment's peak before it
    assert E.peak(t[short], p[short], t, p)["exp_time"] <= 2.0
    tau, h, _ = E.load_series("martin_moyce_1952_residual")
    assert E.gauge_rms(tau, h, tau, h)["rms"] == 0.0
    assert E.gauge_rms(tau, h + 0.05, tau, h)["rms"] == pytest.approx(0.05)


def test_lobovsky_peak_table():
    """Table 2 of Lobovsky et al. 2014 (per-run peak statistics) ships with its citation; a simulated peak equal to
    the median scores 0 and lies in the band, one at the 97.5 % percentile's double lies outside."""
    table, cite = E.load_table("lobovsky_2014_peaks")
    assert any("doi:" in line for line in cite) and list(table["z_mm"]) == [3, 15, 30, 80]
    assert np.all(table["p2_5_mbar"] < table["median_mbar"]) and np.all(table["median_mbar"] < table["p97_5_mbar"])
    med, lo, hi = table["median_mbar"][0], table["p2_5_mbar"][0], table["p97_5_mbar"][0]
    assert E.peak_statistics(med, med, lo, hi) == {"median": med, "band": [lo, hi], "median_error": 0.0, "in_band": True}
    out = E.peak_statistics(2 * hi, med, lo, hi)
    assert not out["in_band"] and out["median_error"] == pytest.approx(2 * hi / med - 1)


def test_moving_average():
    t = np.arange(0.0, 0.05, 0.001)
    assert np.allclose(E.moving_average(t, np.full_like(t, 3.0), 0.004), 3.0)
    ramp = E.moving_average(t, 2.0 * t, 0.004)
    assert np.allclose(ramp[2:-2], 2.0 * t[2:-2])
    spike = np.zeros_like(t)
    spike[20] = 1.0
    assert E.moving_average(t, spike, 0.004).max() == pytest.approx(0.2)  # 5 samples in +-2 ms
    assert np.array_equal(E.moving_average(t, spike, 0.0), spike)


def _write_probe(folder, name, t, v):
    rows = "".join(f"{float(a)!r},{float(b)!r},1\n" for a, b in zip(t, v))
    (folder / f"probe_{name}.csv").write_text(f"# test\ntime [s],value [-],fill [-]\n{rows}")


def test_bench_evaluation_of_the_experiment_itself_scores_zero(tmp_path):
    """validation.evaluate, as the bench calls it on a run folder, fed probe files that hold the experiments
    (converted to seconds and metres): front and residual RMS 0, peak and time errors 0, every goal met."""
    a, h0, g = 0.2, 0.4, 9.81
    T, Z, _ = E.load_series("martin_moyce_1952_front")
    tau, Hr, _ = E.load_series("martin_moyce_1952_residual")
    mm = tmp_path / "mm"
    mm.mkdir()
    _write_probe(mm, "front", np.concatenate([[0.0], T]) / math.sqrt(2 * g / a), a * np.concatenate([[1.0], Z]))
    _write_probe(mm, "residual", np.concatenate([[0.0], tau]) / math.sqrt(g / a), h0 * np.concatenate([[1.0], Hr]))
    fig, met, series = V.evaluate("martin_moyce", mm, {"probes": {"front": {}, "residual": {}}})
    assert fig["a"] == pytest.approx(a) and fig["initial_height"] == pytest.approx(h0)
    assert fig["front_rms"] < 1e-6 and fig["residual_rms"] < 1e-9 and met["front_rms"]
    lob = tmp_path / "lob"
    lob.mkdir()
    for s in V.LOBOVSKY_SENSORS:
        t, p, _ = E.load_series(f"lobovsky_2014_{s}")
        _write_probe(lob, s, t / math.sqrt(g / 0.3), p * 1000.0 * g * 0.3)
    fig, met, _ = V.evaluate("lobovsky", lob, {"probes": {s: {} for s in V.LOBOVSKY_SENSORS}}, pressure_window=0.0)
    table, _ = E.load_table("lobovsky_2014_peaks")
    for s in V.LOBOVSKY_SENSORS:
        assert abs(fig[s]["peak_error"]) < 1e-9 and abs(fig[s]["time_error"]) < 1e-9 and met[s] == {"peak": True,
                                                                                                    "time": True}
        # the digitised curve's peak against the per-run peaks of Table 2 (mbar -> p / (rho g H))
        median = table["median_mbar"][list(table["z_mm"]).index(V.LOBOVSKY_HEIGHTS_MM[s])] * 100.0 / (1000.0 * g * 0.3)
        assert fig[s]["table2"]["median"] == pytest.approx(median)
        assert fig[s]["table2"]["median_error"] == pytest.approx(fig[s]["sim_peak"] / median - 1)
        assert abs(fig[s]["rise_time_error"]) < 1e-9  # the load's arrival: the experiment's own


def test_lobovsky_sensor4_maximum_is_a_plateau():
    """The shipped curves within the simulated 0.8 s (T <= 0.8 sqrt(g/H)): sensor 1's maximum is one point (a sharp
    impact), sensor 4's a plateau: the curve stays within the 10 % peak goal of its maximum (0.577 at T = 3.549)
    from T = 3.383 to 4.464, -5 % to +26 % of that time, so its maximum has no time to 5 %; a simulated load
    that arrives with the experiment's (the curve up to its maximum) and then rises slowly to the same level by
    the end of the run has its maximum 29 % late while its arrival is exact (``errors.peak_shape``); a load
    arriving 10 % late reads a +10 % arrival."""
    g, H = 9.81, 0.3
    end = 0.8 * math.sqrt(g / H)
    t = np.arange(0.0, end + 1e-9, 0.001 * math.sqrt(g / H))
    te, pe, _ = E.load_series("lobovsky_2014_sensor1")
    assert E.peak_shape(t, np.interp(t, te, pe), te, pe, V.GOALS["peak_error"])["peak_span"] == [2.45, 2.45]
    te, pe, _ = E.load_series("lobovsky_2014_sensor4")
    shape = E.peak_shape(t, np.interp(t, te, pe), te, pe, V.GOALS["peak_error"])
    assert shape["peak_span"] == [3.383, 4.464] and abs(shape["rise_time_error"]) < 1e-3
    assert abs(shape["span_mean_error"]) < 0.01  # the curve, sampled at 1 ms, has the curve's level there
    top, t_top = 0.577, 3.549
    assert 4.464 / t_top - 1.0 > V.GOALS["time_error"]
    # arrives with the curve, then a plateau at 80 % of its level rising to the curve's maximum at the run's end
    slow = np.where(t < 3.0, np.interp(t, te, pe), 0.8 * top + 0.2 * top * (t - 3.0) / (end - 3.0))
    pk, sh = E.peak(t, slow, te, pe), E.peak_shape(t, slow, te, pe, V.GOALS["peak_error"])
    assert pk["peak_error"] == pytest.approx(0.0, abs=1e-9) and pk["time_error"] == pytest.approx(end / t_top - 1)
    assert pk["time_error"] > 0.28 and abs(sh["rise_time_error"]) < 1e-3 and sh["span_mean_error"] < -0.05
    late = E.peak_shape(t, np.interp(t / 1.1, te, pe), te, pe, V.GOALS["peak_error"])
    assert late["rise_time_error"] == pytest.approx(0.10, abs=2e-3)


@pytest.mark.parametrize("case", list(V.CASES))
@pytest.mark.parametrize("solver", ["dfsph", "pbf"])
def test_validation_scenes_run_and_probe(case, solver):
    """Each case's scene, as the bench loads it (PBF without the pressure probes inside the fluid: those on
    a wall read the wall load, which PBF has), runs a short frame and its probes sample."""
    from warp_sph.run.simulation import Simulation

    c = V.CASES[case]
    scene = V.load_case_scene(c, solver, c.radii[0], extra=["fps=40"])
    assert scene is not None
    sim = Simulation(scene)
    sim.probes.sample_now(0.0)
    sim.advance_frame()
    got = sim.probes.collect()
    assert set(got) == {p.name for p in scene.probes} and all(len(rows) >= 2 for rows in got.values())
    if solver == "pbf":
        names = {p.name for p in scene.probes if p.kind == "pressure"}
        lobovsky = set(V.LOBOVSKY_SENSORS) | {f"{s}_kernel" for s in V.LOBOVSKY_SENSORS}  # transducers, kernel loads
        assert names == {"lobovsky": lobovsky, "hydrostatic": {"floor"}}.get(V.case_kind(case), set())


def test_hydrostatic_evaluation_figures(tmp_path):
    """validation.evaluate on the hydrostatic case's probe files: p / (rho0 g (h - z)) - 1 over the second half
    with h the height probe and z the water's floor (gap - r above the floor's particles: the scene's z = 0, the case
    moving its walls out), and the depth the water's volume gives over the floor it covers to gap - r from every
    wall (12 x 12 columns of 10 layers at r = 0.025 m fill the 0.6 x 0.6 x 0.5 m tank: 10 d) with how far below
    that level the surface lies [d]."""
    scene = V.load_case_scene(V.CASES["hydrostatic"], "dfsph", 0.025)
    d, rho0, g = 0.05, 1000.0, 9.81
    floor = 0.0
    assert scene.container.min[2] == pytest.approx(-(scene.wall_gap - 0.025))
    t = np.linspace(0.0, 2.0, 97)
    depth = 12 * 12 * 10 * d ** 3 / 0.6 ** 2
    h = floor + depth - 0.1 * d + 0.001 * np.sin(7 * t)     # a surface 0.1 d below the volume's level
    _write_probe(tmp_path, "surface", t, h)
    _write_probe(tmp_path, "floor", t, 1.004 * rho0 * g * (h - floor))
    _write_probe(tmp_path, "middle", t, rho0 * g * (h - 0.25))
    info = {"probes": {"floor": {}, "middle": {}, "surface": {}}, "scene": scene.to_dict(), "fluid_particles": 12 * 12 * 10,
            "model": {"particle_mass": rho0 * d ** 3, "rest_density": rho0}}
    fig, met, _ = V.evaluate("hydrostatic", tmp_path, info)
    assert fig["floor_error"] == pytest.approx(0.004, abs=1e-6) and abs(fig["middle_error"]) < 1e-6
    assert fig["floor_surface"] == pytest.approx(floor)
    assert fig["depth_by_volume"] == pytest.approx(depth, rel=1e-9) and depth == pytest.approx(10 * d, rel=1e-9)
    assert fig["surface_drop_d"] == pytest.approx((floor + depth - h[t >= 1.0].mean()) / d, rel=1e-9)
    assert fig["surface_drop_d"] == pytest.approx(0.1, abs=3e-3)
    assert met == {"floor_error": True, "middle_error": True}
    # with the run's last state (the case's last_state checkpoint) the mean |v| at the end, the figure
    from warp_sph.io import atomic
    from warp_sph.io import run_folder as rf

    v = np.zeros((12 * 12 * 10, 3))
    v[:, 0], v[::2, 2] = 3e-4, 4e-4                  # |v| = 3e-4 and 5e-4 m/s, about half each: mean 4e-4
    n = len(v)
    (tmp_path / "checkpoints").mkdir()
    atomic.atomic_save_npz(rf.checkpoint_path(tmp_path, 1), particle_x_local=np.zeros((n, 3)), particle_v=10 * v, step=0,
                           frame=1, state_frame=1, time=0.0, last_max_speed=0.0)
    fig, met, _ = V.evaluate("hydrostatic", tmp_path, info)
    assert fig["mean_speed_final"] == pytest.approx(4e-3, rel=1e-3) and met["settled"] is False
    atomic.atomic_save_npz(rf.checkpoint_path(tmp_path, 49), particle_x_local=np.zeros((n, 3)), particle_v=v, step=9,
                           frame=49, state_frame=49, time=2.0, last_max_speed=0.0)
    fig, met, _ = V.evaluate("hydrostatic", tmp_path, info)
    assert fig["mean_speed_final"] == pytest.approx(4e-4, rel=1e-3) and met["settled"] is True


def test_hydrostatic_misses_name_the_unsettled_tank():
    """The report's 'Misses' line names a hydrostatic run that is not at rest (rms speed >= 1e-3 m/s) with its
    speed, and a figure outside 1 % with its value; a run within both goals is not named."""
    from benchmarks.validation_report import misses

    base = {"case": "hydrostatic", "resolution": "coarse", "pressure_probe": "wall load"}
    moving = {**base, "solver": "dfsph", "rms_speed_final": 7.1e-3,
              "figures": {"floor_error": 0.012}, "goals_met": {"floor_error": False, "settled": False}}
    still = {**base, "solver": "pbf", "rms_speed_final": 5e-4,
             "figures": {"floor_error": 0.004}, "goals_met": {"floor_error": True, "settled": True}}
    line = " ".join(misses("hydrostatic", [moving, still]))
    assert "dfsph coarse floor: +1.20 %" in line and "dfsph coarse: rms speed 7.1e-03 m/s" in line
    # with the last state's mean |v| (the figure) the line names it beside the rms speed
    moving["figures"]["mean_speed_final"] = 5.3e-3
    line = " ".join(misses("hydrostatic", [moving, still]))
    assert "dfsph coarse: mean |v| 5.3e-03 m/s (rms 7.1e-03) at the end" in line
    assert "pbf" not in line.split(". Why:")[0]
    assert misses("hydrostatic", [still]) == []


def test_lobovsky_misses_say_when_the_load_arrived():
    """A Lobovsky run whose sensor-4 maximum comes late on the plateau (the slow load of
    ``test_lobovsky_sensor4_maximum_is_a_plateau``, through ``evaluate``): the report's 'Misses' line gives the time
    error with the load's arrival (+0.0 %), the curve's span within 10 % of its maximum (T = 3.38 to 4.46, -5 to
    +26 % of its time) and the simulated mean load there."""
    from benchmarks.validation_report import misses

    g, H = 9.81, 0.3
    end = 0.8 * math.sqrt(g / H)
    t = np.arange(0.0, end + 1e-9, 0.001 * math.sqrt(g / H))
    te, pe, _ = E.load_series("lobovsky_2014_sensor4")
    slow = np.where(t < 3.0, np.interp(t, te, pe), 0.8 * 0.577 + 0.2 * 0.577 * (t - 3.0) / (end - 3.0))
    fig = E.peak(t, slow, te, pe)
    fig.update(E.peak_shape(t, slow, te, pe, V.GOALS["peak_error"]))
    rec = {"case": "lobovsky", "solver": "dfsph", "resolution": "fine", "pressure_probe": "transducer",
           "figures": {"sensor4": fig}, "goals_met": {"sensor4": {"peak": True, "time": False}}}
    line = misses("lobovsky", [rec])[0].split(". Why:")[0]
    assert "dfsph fine sensor4: time +28.9 % (arrival +0.0 %; the curve within 10 % of its maximum from T = 3.38 " \
           "to 4.46, -5 to +26 % of its time, the mean load there -" in line
    rec["goals_met"]["sensor4"]["time"] = True
    assert misses("lobovsky", [rec]) == []
