"""warp-sph plan: the fits against synthetic data with known exponents, the parsing of --budget and
--target-error, a calibration of a tiny scene (a few frames at two radii), its cache, --apply (the file loads
as a scene and a run from it records the prediction beside what happened) and the bad inputs (one line, exit 2)."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

import warp_sph as ws
from warp_sph.cli import main
from warp_sph.plan import PlanError, plan
from warp_sph.plan.calibrate import calibration_frames, calibration_radii, radius_for_count
from warp_sph.plan.fit import extrapolation, fit_lattice_count, fit_line, fit_power_law, fit_step_rate
from warp_sph.plan.report import apply_scene, parse_budget, parse_error, set_flags, table_lines, toml_text
from warp_sph.scene import load_scene

TINY = """name = "tiny"
particle_radius = 0.05
duration = 0.25
fps = 24.0
[container]
min = [0.0, 0.0, 0.0]
max = [0.5, 0.3, 0.5]
[[fluid]]
min = [0.0, 0.0, 0.0]
max = [0.25, 0.3, 0.25]
[output]
usd = false
surface = false
"""
RADII = (0.03, 0.02)  # 150 and 420 fluid particles
FRAMES = 3            # two advanced frames
SOLVERS = ["wcsph", "pbf"]
BUDGET = 8.0          # [s]: the chosen setting stays within 4x the calibrated counts, its 2-frame run is cheap


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    path = tmp_path_factory.mktemp("plan") / "tiny.toml"
    path.write_text(TINY)
    return path


def _kw(cache):
    return dict(solvers=SOLVERS, cache=cache, calibration_radii=RADII, calibration_frames=FRAMES)


@pytest.fixture(scope="module")
def calibrated(tiny):
    cache = tiny.parent / "cache"
    return plan(str(tiny), budget_s=BUDGET, **_kw(cache)), cache


# --- fits: synthetic data with known exponents as oracles ------------------------------------------

@pytest.mark.parametrize("exponent", [-1.0, 0.0, 1.5, 2.0])
def test_power_law_recovers_a_known_exponent(exponent):
    x = np.array([0.01, 0.02, 0.04, 0.08])
    f = fit_power_law(x, 3.0 * x**exponent)
    assert f.exponent == pytest.approx(exponent, abs=1e-9)
    assert f.coefficient == pytest.approx(3.0, rel=1e-9)
    assert f(0.005) == pytest.approx(3.0 * 0.005**exponent, rel=1e-9)


def test_power_law_with_noise_clipping_and_one_point():
    rng = np.random.default_rng(1)
    x = np.geomspace(0.01, 0.1, 6)
    f = fit_power_law(x, 2.0 * x**1.2 * np.exp(rng.normal(0, 0.02, x.size)))
    assert f.exponent == pytest.approx(1.2, abs=0.1)
    assert fit_power_law(x, x**5, exponent_range=(-1, 4)).exponent == 4.0  # clipped, coefficient refitted
    one = fit_power_law([0.1], [7.0])
    assert one.exponent == 0.0 and one(0.01) == pytest.approx(7.0)
    with pytest.raises(ValueError):
        fit_power_law([0.1, 0.2], [0.0, -1.0])


def test_line_is_non_negative_and_exact_on_a_line():
    n = np.array([1e3, 4e3, 1.6e4])
    f = fit_line(n, 2e-3 + 5e-8 * n)
    assert f.intercept == pytest.approx(2e-3, rel=1e-6) and f.slope == pytest.approx(5e-8, rel=1e-6)
    g = fit_line(n, 1.0 - 1e-5 * n)  # a falling cost: no negative slope
    assert g.slope >= 0 and g.intercept >= 0
    h = fit_line(n, -1.0 + 1e-3 * n)  # a negative intercept: through the origin
    assert h.intercept == 0.0 and h.slope > 0
    assert extrapolation(8e3, 1e2, 1e3) == 8.0 and extrapolation(50, 100, 1e3) == 2.0
    assert extrapolation(5e2, 1e2, 1e3) == 1.0


def test_lattice_count_recovers_the_wall_gap():
    d = np.array([0.1, 0.07, 0.05])
    n = ((1.0 - 1.1 * d) / d) ** 3  # a 1 m block that loses 1.1 spacings to the walls' gap
    f = fit_lattice_count(d, n, 3)
    assert f.a == pytest.approx(1.0) and f.b == pytest.approx(-1.1)
    assert f(0.01) == round(((1.0 - 0.011) / 0.01) ** 3)
    assert fit_lattice_count([0.1], [1000], 2)(0.05) == 4000


def test_lattice_count_gives_the_measured_count_at_a_calibrated_spacing():
    """Small lattices are whole numbers of particles (27 = 3^3 at one radius, where a line through the other
    points gives 26): at a calibrated spacing the fit returns what was sampled there, between them the fit (the
    plan of a tiny scene predicted 26 particles at its 27-particle radius when timing changed the radii calibrated)."""
    d, n = [0.06, 0.04, 0.03], [27, 64, 216]
    f = fit_lattice_count(d, n, 3)
    assert [f(x) for x in d] == n
    a, b = np.polyfit(d, np.asarray(d) * np.asarray(n, dtype=float) ** (1 / 3), 1)[::-1]
    assert f(0.05) == round(((a + b * 0.05) / 0.05) ** 3)  # between calibrated spacings: the fitted lattice line


def test_step_rate_floor_and_cfl_order():
    d = np.array([0.08, 0.06, 0.04])
    wcsph = fit_step_rate(d, 40.0 / d, floor=200.0)  # dt ~ d above the floor
    assert wcsph.law.exponent == pytest.approx(-1.0) and wcsph(0.01) == pytest.approx(4000.0)
    viscous = fit_step_rate(d, 4.0 / d**2, floor=200.0)  # a viscous bound: dt ~ d^2
    assert viscous.law.exponent == pytest.approx(-2.0)
    clamped = fit_step_rate(d, np.full(3, 200.0), floor=200.0)  # every point at dt_max: d^-1 through the finest
    assert clamped(0.08) == 200.0 and clamped(0.04) == 200.0 and clamped(0.02) == pytest.approx(400.0)
    assert fit_step_rate(d, 40.0 / d**0.5, floor=1.0).law.exponent == -1.0  # never slower than d^-1


# --- parsing ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("text,seconds", [("90", 90), ("90s", 90), ("10m", 600), ("1.5h", 5400), ("1h30m", 5400),
                                          ("2 min", 120)])
def test_budget_units(text, seconds):
    assert parse_budget(text) == pytest.approx(seconds)


@pytest.mark.parametrize("text", ["", "ten", "10x", "-5m", "0s", "m", "5m5m", "1e400"])
def test_malformed_budget(text):
    with pytest.raises(PlanError, match="--budget"):
        parse_budget(text)


def test_target_error_forms():
    assert parse_error("0.5%") == pytest.approx(0.005) and parse_error("0.005") == pytest.approx(0.005)
    for bad in ("2", "abc", "0%", "150%"):
        with pytest.raises(PlanError, match="--target-error"):
            parse_error(bad)


def test_calibration_radii_follow_the_geometry(tiny):
    scene = load_scene(str(tiny))
    r = radius_for_count(scene, 1000)
    assert (0.25 * 0.3 * 0.25) / (2 * r) ** 3 == pytest.approx(1000, rel=1e-9)
    radii = calibration_radii(scene)
    assert radii == sorted(radii, reverse=True) and max(radii) <= 0.25 / 6 + 1e-12  # 3 layers in the thinnest block
    assert calibration_frames(scene) == 4  # 0.1 s at 24 fps: 3 frames advanced


# --- a calibration of the tiny scene -------------------------------------------------------------

def test_plan_of_a_tiny_scene(calibrated):
    p, cache = calibrated
    assert set(p.models) == set(SOLVERS)
    c = p.chosen
    assert c.wall_time <= 0.8 * BUDGET and c.steps >= 6  # at least one step per frame (0.25 s at 24 fps)
    # within the budget the finest radius is chosen: nothing finer fits, within 4x the largest calibrated count
    assert c.count_extrapolation <= 4.0
    assert not any(d.particle_radius < c.particle_radius and d.wall_time <= 0.8 * BUDGET and d.count_extrapolation <= 4
                   for d in p.candidates)
    assert any(d.pareto for d in p.candidates)
    assert max(d.particle_radius for d in p.candidates) == pytest.approx(0.03, rel=1e-3)  # the coarsest calibrated
    assert c.count_extrapolation >= 1 and c.spacing_extrapolation >= 1
    assert ("x the largest calibrated count" in c.extrapolated()) == (c.count_extrapolation > 1.05)
    # at a calibrated radius the prediction is what the calibration measured: the sampled count, and the steps
    # scaled from the calibration's simulated time to the scene's 0.25 s
    files = [json.loads(f.read_text())["points"] for f in cache.glob("calibration-*.json")]
    points = next(f for f in files if any(q["particle_radius"] == 0.02 for q in f))  # the short runs' file
    for solver in SOLVERS:
        point = next(q for q in points if q["solver"] == solver and q["particle_radius"] == 0.03)
        pred = next(d for d in p.candidates if d.solver == solver and d.particle_radius == pytest.approx(0.03))
        assert pred.fluid_particles == pytest.approx(point["fluid"], rel=0.02)
        assert pred.steps == pytest.approx(point["steps"] * 0.25 / point["simulated_time"], rel=0.35)


def test_calibration_is_cached(calibrated, tiny):
    p, cache = calibrated
    q = plan(str(tiny), budget_s=BUDGET, **_kw(cache))
    assert q.calibration_cached and not p.calibration_cached
    assert q.calibration_seconds == p.calibration_seconds  # nothing ran again
    assert q.chosen == p.chosen
    # one file of the short runs, one of the whole-duration runs of the error profile; no run folder left
    assert len(list(cache.glob("calibration-*.json"))) == 2 and not list(cache.glob("calibration-*/"))


def test_public_api_and_table(calibrated):
    p, _ = calibrated
    assert "plan" in ws.__all__ and ws.plan.__doc__
    lines = table_lines(p)
    assert lines[1].split()[:3] == ["solver", "radius", "tolerance"] and lines[2].startswith("*")
    assert f"solver={p.chosen.solver}" in set_flags(p)
    from warp_sph.scene.load import apply_overrides

    d = apply_overrides(load_scene("hydrostatic").to_dict(), set_flags(p))  # the flags load as scene values
    assert ws.scene_from_dict(d).plan.wall_time == pytest.approx(p.chosen.wall_time, rel=1e-5)


def test_apply_writes_a_scene_that_runs_and_records_the_plan(calibrated, tiny, tmp_path):
    p, _ = calibrated
    out = apply_scene(load_scene(str(tiny)), p, tmp_path / "planned.toml")
    s = load_scene(str(out))
    assert s.solver == p.chosen.solver and s.particle_radius == pytest.approx(p.chosen.particle_radius)
    assert s.plan.wall_time == pytest.approx(p.chosen.wall_time) and s.plan.budget == BUDGET
    with pytest.raises(PlanError, match="exists"):
        apply_scene(load_scene(str(tiny)), p, out)
    info = ws.run(s, out=tmp_path / "run", frames=2, progress=False, log=lambda *a: None)
    rec = json.loads((tmp_path / "run" / "run.json").read_text())["plan"]
    assert rec["predicted"]["wall_time"] == pytest.approx(p.chosen.wall_time)
    assert rec["actual"]["wall_time"] == pytest.approx(info["wall_time"])
    assert rec["actual"]["frames"] == 2 and rec["whole_scene"] is False
    assert rec["ratio"]["wall_time"] == pytest.approx(info["wall_time"] / p.chosen.wall_time)


def test_toml_text_round_trips_a_scene():
    import tomllib

    d = load_scene("dam_break").to_dict()
    assert tomllib.loads(toml_text(d)) == json.loads(json.dumps(d))


# --- bad input: one line, exit status 2 ------------------------------------------------------------

def _cli(capsys, *args):
    rc = main(list(args))
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.mark.parametrize("args,match", [
    (["--budget", "ten minutes"], "--budget 'ten minutes': expected a wall time"),
    (["--target-error", "2"], "--target-error '2'"),
    ([], "give --budget"),
    (["--budget", "1m", "--device", "cuda:7"], "--device cuda:7"),
    (["--budget", "1m", "--solvers", "nope"], "unknown nope"),
])
def test_cli_bad_input(tiny, tmp_path, capsys, args, match):
    rc, out, err = _cli(capsys, "plan", str(tiny), "--cache", str(tmp_path), "--no-progress", *args)
    assert rc == 2 and match in err and len(err.strip().splitlines()) == 1, err
    assert not list(tmp_path.glob("calibration-*.json"))


def test_budget_too_small_and_target_out_of_reach(calibrated, tiny):
    p, cache = calibrated
    cheapest = min(c.wall_time for c in p.candidates)
    with pytest.raises(PlanError, match=r"too small: the cheapest stable setting .* is predicted to take") as e:
        plan(str(tiny), budget_s=0.5 * cheapest, **_kw(cache))
    assert "\n" not in str(e.value)
    with pytest.raises(PlanError, match=r"below what the finest affordable setting within --budget 8 s reaches") as e:
        plan(str(tiny), budget_s=BUDGET, target_error=1e-7, **_kw(cache))
    assert "\n" not in str(e.value)
    # without a budget: every candidate within 4x the calibrated counts is affordable
    loose = plan(str(tiny), target_error=0.99, **_kw(cache))
    best = min(c.density_error for c in loose.candidates if c.count_extrapolation <= 4)
    # the closest setting is named with its own error, which misses the target (which setting it is depends on the
    # calibration, which ranks solvers for this target and so may run other points than the loose plan did)
    with pytest.raises(PlanError, match=rf"--target-error {100 * 0.5 * best:.3g}% is below what the finest affordable "
                       r"setting that fits in memory reaches: (\w+), particle_radius [0-9.e-]+ m.*, [0-9,]+ fluid "
                       r"particles gives ([0-9.e+-]+) % in ") as e:
        plan(str(tiny), target_error=0.5 * best, **_kw(cache))
    named = re.search(r"reaches: (\w+), .* gives ([0-9.e+-]+) % in ", str(e.value))
    assert named.group(1) in SOLVERS and float(named.group(2)) > 100 * 0.5 * best
    assert "\n" not in str(e.value)
    q = plan(str(tiny), target_error=2.0 * best, **_kw(cache))  # reachable: the cheapest that reaches it
    assert q.chosen.density_error <= 2.0 * best
    assert all(c.wall_time >= q.chosen.wall_time for c in q.candidates if c.density_error <= 2.0 * best
               and c.count_extrapolation <= 4)


def test_a_scene_that_cannot_be_calibrated(tiny, tmp_path, capsys):
    # every calibration run is refused before its first step: more substeps than time.max_steps
    rc, out, err = _cli(capsys, "plan", str(tiny), "--budget", "1m", "--solvers", "wcsph", "--cache", str(tmp_path),
                        "--no-progress", "--set", "time.max_steps=1")
    assert rc == 2 and "cannot be calibrated" in err and "time.max_steps" in err
    assert len(err.strip().splitlines()) == 1, err


def test_cli_plan_table_plot_line_and_apply(tiny, tmp_path, capsys):
    out = tmp_path / "planned.toml"
    rc, text, err = _cli(capsys, "plan", str(tiny), "--budget", "8s", "--solvers", "wcsph", "--cache",
                         str(tiny.parent / "cache"), "--no-progress", "--apply", str(out), "--plot",
                         str(tmp_path / "pareto.png"))
    assert rc == 0, err
    lines = text.splitlines()
    row = next(line for line in lines if line.startswith("*"))
    assert row.split()[1] == "wcsph" and load_scene(str(out)).solver == "wcsph"
    try:
        import matplotlib  # noqa: F401
        assert (tmp_path / "pareto.png").stat().st_size > 0 and f"Pareto front: {tmp_path / 'pareto.png'}" in text
    except ImportError:  # one line says why there is no plot; the table is printed all the same
        assert sum("matplotlib is not installed" in line for line in lines) == 1
    rc, text, err = _cli(capsys, "plan", str(tiny), "--budget", "8s", "--solvers", "wcsph", "--cache",
                         str(tiny.parent / "cache"), "--no-progress", "--apply", str(out))
    assert rc == 2 and "exists; pass --force" in err and text == ""  # refused before any calibration


def test_cli_target_out_of_reach_names_the_closest_plan(tiny, capsys):
    rc, out, err = _cli(capsys, "plan", str(tiny), "--target-error", "0.00001%", "--solvers", "wcsph", "--cache",
                        str(tiny.parent / "cache"), "--no-progress")
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert "--target-error 1e-05% is below what the finest affordable setting that fits in memory reaches: wcsph, " \
           "particle_radius" in err and " gives " in err


def test_next_calibration_point_steps_at_most_4x():
    from warp_sph.plan.advisor import Candidate, next_point
    from warp_sph.plan.calibrate import Calibration, Point

    cal = Calibration(key="k", machine="m", points=[
        Point("wcsph", 0.04, fluid=300, boundary=200, seconds=1.0),
        Point("wcsph", 0.02, fluid=800, boundary=200, seconds=2.0, steps=100, step_time=0.015)])
    far = Candidate("wcsph", 0.002, None, 10**6, 0, 1000, 10.0, 0, 0.01, 1000.0, 10.0)
    r, cost, largest = next_point(cal, far)  # the fit's choice is 1000x beyond: step 4x only
    assert largest == 0.02 and r == pytest.approx(0.02 * 0.25 ** (1 / 3), rel=1e-3)
    # 0.5 s outside the steps as it was, the steps' 1.5 s times 4x the particles and 0.02 / r the steps
    assert cost == pytest.approx(0.5 + 1.5 * 4.0 * 0.02 / r, rel=1e-3)
    near = Candidate("wcsph", 0.01, None, 6000, 0, 100, 1.0, 0, 0.01, 6.0, 2.0)
    r, cost, _ = next_point(cal, near)  # a quarter of its count: 1500 particles
    assert r == pytest.approx(0.02 * (1000 / 1500) ** (1 / 3), rel=1e-3)


def test_plot_and_cache_paths_refused_before_any_calibration(tiny, tmp_path, capsys):
    """``plan --cache FILE`` ended in a FileExistsError traceback after loading the scene, and ``--plot`` replaced
    whatever file it named (a user's picture) without a word. Both are checked first: one line, exit 2, nothing
    calibrated or written; --force lets --plot replace a file, as --apply."""
    mine = tmp_path / "mine.png"
    mine.write_bytes(b"my own picture")
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    for args, line in (
            (["--cache", str(notes)], f"--cache {notes}: is a file; expected a folder for the calibration cache"),
            (["--cache", str(notes / "sub")], f"--cache {notes / 'sub'}: lies under the file {notes}; expected a "
                                              "folder for the calibration cache"),
            (["--plot", str(mine), "--cache", str(tmp_path / "c")], f"--plot {mine}: the file exists; pass --force "
                                                                    "to replace it"),
            (["--plot", str(notes), "--cache", str(tmp_path / "c")], f"--plot {notes}: expected a .png file path")):
        rc, out, err = _cli(capsys, "plan", str(tiny), "--budget", "8s", "--no-progress", *args)
        assert rc == 2 and out == "" and err.strip() == f"warp-sph: error: {line}", err
    assert mine.read_bytes() == b"my own picture" and notes.read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.png", "notes.txt"]
