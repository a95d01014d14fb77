"""warp-sph plan's models without running a simulation: the solver tolerance as a candidate (exponents measured
from a pair of calibration points, against synthetic figures with known exponents), the run's density error with
the last calibrated frame held, the errors against a validation case's experiment (synthetic probe files against
NumPy oracles) and their bad input (one line, exit status 2)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from warp_sph.cli import main
from warp_sph.plan import PlanError
from warp_sph.plan.advisor import Candidate, candidates_for, choose, fit_models, predict, run_density_error
from warp_sph.plan.calibrate import Calibration, Point, scene_tolerance, tolerance_key
from warp_sph.plan.metrics import check_metric, evaluate_reference, metric_names
from warp_sph.plan.report import parse_target, set_flags
from warp_sph.scene import load_scene

from test_plan import TINY as PLAN_TINY

# the plan tests' tiny tank, run for 0.5 s instead of 0.25 s
TINY = PLAN_TINY.replace("duration = 0.25", "duration = 0.5")
assert TINY != PLAN_TINY
T0 = 0.005   # pbf.target_density_error's default
K = {"step_time": -0.5, "steps_per_second": -0.25, "error": 1.0, "error_last": 0.8, "metric": 0.5}


def _validation(name):
    from warp_sph.validation.cases import _scene_dir

    return load_scene(str(_scene_dir() / f"{name}.toml"))


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    path = tmp_path_factory.mktemp("plan_models") / "tiny.toml"
    path.write_text(TINY)
    return load_scene(str(path))


def _point(solver, r, t, **over):
    """A synthetic calibration point: N ~ r^-3, 30 steps at r = 0.03 (steps ~ 1/r), step time 1e-6 s per particle,
    density errors 0.01 d and 0.02 d (mean, last), a front error 2 d^0.5; each times (t / T0)^k (K)."""
    f = (lambda k: 1.0) if t is None else (lambda k: (t / T0) ** K[k])
    n = int(round(400 * (0.03 / r) ** 3))
    d = 2 * r
    p = Point(solver, r, tolerance=t, fluid=n, boundary=0, frames=3, simulated_time=0.125, wall_time=1.0,
              steps=int(round(30 * (0.03 / r) * f("steps_per_second"))), step_time=1e-6 * n * f("step_time"),
              density_error_mean=0.01 * d * f("error"), density_error_last=0.02 * d * f("error_last"),
              reference={"front": 2.0 * d**0.5 * f("metric")})
    for k, v in over.items():
        setattr(p, k, v)
    return p


def _cal(*points):
    return Calibration(key="k", machine="m", points=list(points), step_floor=24.0)


# --- the tolerance -------------------------------------------------------------------------------

def test_tolerance_keys_come_from_the_parameter_registry(tiny):
    assert tolerance_key("pbf") == "pbf.target_density_error"
    assert tolerance_key("dfsph") == "dfsph.target_density_error"
    assert tolerance_key("wcsph") is None  # no density tolerance: its compressibility is the speed of sound
    assert scene_tolerance(tiny, "pbf") == T0 and scene_tolerance(tiny, "dfsph") == 5e-4
    assert scene_tolerance(tiny, "wcsph") is None


def test_tolerance_exponents_and_candidates(tiny):
    cal = _cal(_point("pbf", 0.03, T0), _point("pbf", 0.02, T0), _point("pbf", 0.02, T0 / 4))
    m = fit_models(cal, "pbf", tiny)
    # the exponents of the synthetic laws, measured from the pair at r = 0.02 (steps are rounded to integers)
    assert m.tolerance_exponents["step_time"] == pytest.approx(K["step_time"], abs=1e-9)
    assert m.tolerance_exponents["error"] == pytest.approx(K["error"], abs=1e-9)
    assert m.tolerance_exponents["error_last"] == pytest.approx(K["error_last"], abs=1e-9)
    assert m.tolerance_exponents["steps_per_second"] == pytest.approx(K["steps_per_second"], abs=0.03)
    assert m.tolerances == [T0, T0 / 4]
    assert m.candidate_tolerances() == [T0, T0 / 2, T0 / 4]  # only between the calibrated ones
    # the models at the scene's tolerance come from its points only: the error law 0.01 d exactly
    assert m.error.exponent == pytest.approx(1.0) and m.error(0.1) == pytest.approx(1e-3)
    # a prediction at t0/2 by hand: steps, step time and errors scaled by (1/2)^k
    c = predict(tiny, m, 0.02, T0 / 2)
    n = c.fluid_particles
    frames = round(0.5 * 24)
    rate = m.steps_per_second(0.04) * 0.5 ** m.tolerance_exponents["steps_per_second"]
    steps = max(math.ceil(rate * 0.5), frames)
    step = m.step_time(n) * 0.5 ** K["step_time"]
    wall = m.load_time + m.setup_time(n) + steps * step + frames * m.frame_overhead(n)
    assert c.steps == steps and c.wall_time == pytest.approx(wall, rel=1e-9) and c.tolerance == T0 / 2
    first, last = 0.01 * 0.04 * 0.5 ** K["error"], 0.02 * 0.04 * 0.5 ** K["error_last"]
    assert c.density_error == pytest.approx((3 * first + (frames - 3) * last) / frames, rel=1e-9)
    # the tolerance's effect was measured at the pair's count (r = 0.02: 1350 particles): t != t0 extrapolates from it
    pair = _point("pbf", 0.02, T0).particles
    assert m.tolerance_particles == pair
    fine = predict(tiny, m, 0.01, T0 / 4)
    assert fine.tolerance_extrapolation == pytest.approx(fine.particles / pair)
    assert fine.count_extrapolation == pytest.approx(fine.particles / pair)  # beyond 4x: not chosen
    assert predict(tiny, m, 0.01, T0).tolerance_extrapolation == 1.0
    assert "the tolerance's effect" in fine.extrapolated()
    # every candidate of the solver at each of the three tolerances; WCSPH has one (None)
    cands = candidates_for(tiny, {"pbf": m})
    assert {c.tolerance for c in cands} == {T0, T0 / 2, T0 / 4}
    w = fit_models(_cal(_point("wcsph", 0.03, None), _point("wcsph", 0.02, None)), "wcsph", tiny)
    assert w.tolerance is None and w.candidate_tolerances() == [None] and w.tolerance_exponents == {}


def test_one_tolerance_without_a_pair(tiny):
    m = fit_models(_cal(_point("dfsph", 0.03, 5e-4), _point("dfsph", 0.02, 5e-4)), "dfsph", tiny)
    assert m.tolerances == [5e-4] and m.candidate_tolerances() == [5e-4] and m.tolerance_factor("error", 1e-4) == 1.0


def test_budget_buys_the_tighter_tolerance_at_the_finest_radius(tiny):
    cal = _cal(_point("pbf", 0.03, T0), _point("pbf", 0.02, T0), _point("pbf", 0.02, T0 / 4))
    m = fit_models(cal, "pbf", tiny)
    cands = candidates_for(tiny, {"pbf": m})
    r1 = sorted({c.particle_radius for c in cands}, reverse=True)[3]
    budget = 1.25 * max(c.wall_time for c in cands if c.particle_radius == r1)
    c = choose(cands, budget, None, None, "tiny")
    # the finest radius that fits, then the smallest error there: the tightest tolerance (error ~ t^1)
    assert c.particle_radius == min(d.particle_radius for d in cands if d.wall_time <= 0.8 * budget
                                    and d.count_extrapolation <= 4)
    same = [d for d in cands if d.particle_radius == c.particle_radius and d.wall_time <= 0.8 * budget]
    assert c.density_error == min(d.density_error for d in same) and c.particle_radius <= r1
    assert c.tolerance == T0 / 4 if c.particle_radius == r1 else True  # at r1 every tolerance fits: the tightest


def test_the_calibration_goes_first_to_the_solver_the_plan_would_choose(tiny):
    from warp_sph.plan import rank_solvers

    # one radius each: pbf 10x cheaper per particle-step, so a budget buys it a finer radius
    cal = _cal(_point("wcsph", 0.03, None, step_time=4e-3), _point("pbf", 0.03, T0, step_time=4e-4))
    assert rank_solvers(tiny, cal, ["wcsph", "pbf"], "density", 5.0, None, None) == ["pbf", "wcsph"]
    # a target error: the cheapest that reaches it first (both reach 1: pbf is cheaper)
    assert rank_solvers(tiny, cal, ["wcsph", "pbf"], "density", None, 0.99, None) == ["pbf", "wcsph"]
    # a solver without a point comes last
    assert rank_solvers(tiny, cal, ["dfsph", "wcsph"], "density", 5.0, None, None) == ["wcsph", "dfsph"]


def test_set_flags_and_apply_carry_the_tolerance(tiny, tmp_path):
    from warp_sph.plan.advisor import Plan
    from warp_sph.plan.report import apply_scene

    c = Candidate("pbf", 0.02, 0.00125, 400, 0, 40, 3.0, 10**6, 0.001, 1.0, 1.0)
    p = Plan(scene="tiny", source=tiny.source, chosen=c, budget_s=10.0, machine="m")
    assert "pbf.target_density_error=0.00125" in set_flags(p)
    s = load_scene(str(apply_scene(tiny, p, tmp_path / "planned.toml")))
    assert s.solver == "pbf" and s.section("pbf").target_density_error == 0.00125
    w = Candidate("wcsph", 0.02, None, 400, 0, 40, 3.0, 10**6, 0.001, 1.0, 1.0)
    assert not any("target_density_error" in f for f in set_flags(Plan(scene="t", source="t", chosen=w)))


def test_run_density_error_holds_the_last_frame(tiny):
    m = fit_models(_cal(_point("wcsph", 0.03, None), _point("wcsph", 0.02, None)), "wcsph", tiny)
    d = 0.05
    assert run_density_error(m, d, 3) == pytest.approx(0.01 * d)          # the calibration's own span
    assert run_density_error(m, d, 12) == pytest.approx((3 * 0.01 * d + 9 * 0.02 * d) / 12)
    assert run_density_error(m, d, 2) == pytest.approx(0.01 * d)          # a shorter run: the calibrated mean


def test_the_error_profile_scales_the_later_frames(tiny):
    # a whole run at the coarsest radius: 1e-3 in the 3 calibrated frames, then 2e-3, 3e-3, 3e-3, ... (12 frames)
    prof = [1e-3, 1e-3, 1e-3] + [2e-3, 3e-3] + [3e-3] * 7
    whole = _point("wcsph", 0.03, None, density_errors=prof)
    m = fit_models(_cal(_point("wcsph", 0.03, None), _point("wcsph", 0.02, None)), "wcsph", tiny, profile=_cal(whole))
    assert m.profile == prof
    r = (2e-3 + 3e-3 * 8) / 9 / 1e-3      # its mean after frame 3 over its mean in frames 1-3
    assert m.later_ratio(12) == pytest.approx(r)
    d = 0.05
    # the later frames at the calibrated mean (0.01 d) times R; the last calibrated frame's law (0.02 d) is not used
    assert run_density_error(m, d, 12) == pytest.approx((3 * 0.01 * d + 9 * 0.01 * d * r) / 12)
    assert m.later_ratio(20) == 1.0 and m.later_ratio(3) == 1.0  # a profile too short, or nothing after it
    assert "later frames x 2.89 that (the error's course over a whole run)" in __import__(
        "warp_sph.plan.report", fromlist=["model_line"]).model_line(m)


def test_an_oscillating_error_is_predicted_from_the_calibrated_mean_not_its_last_frame(tiny):
    """A WCSPH-like error that oscillates about a level that does not fall with the spacing: each calibration's last
    frame is a sample of the oscillation (here low at the finer radius), so its law fell steeply (hydrostatic 180 s:
    order +2.4, the run's error 3.1x the prediction); the calibrated frames' mean and the profile hold the level."""
    level = 3e-3
    osc = [0.4, 1.4, 0.9, 1.5, 0.7, 1.3, 0.8, 1.2, 0.9, 1.1, 1.0, 1.0]   # a damped oscillation about 1
    prof = [level * x for x in osc]
    pts = [_point("wcsph", r, None, density_error_mean=level * float(np.mean(osc[:3])), density_error_last=last,
                  density_errors=[])
           for r, last in ((0.03, level * 0.9), (0.02, level * 0.2))]          # the finer run's frame 3 in a trough
    whole = _point("wcsph", 0.03, None, density_errors=prof)
    m = fit_models(_cal(*pts), "wcsph", tiny, profile=_cal(whole))
    assert m.error_last.exponent > 1.0  # the last frames' law: a steep fall that is not there
    d = 2 * 0.01
    oracle = (3 * float(np.mean(prof[:3])) + 9 * float(np.mean(prof[:3])) * (np.mean(prof[3:]) / np.mean(prof[:3]))) / 12
    assert run_density_error(m, d, 12) == pytest.approx(oracle)           # = the profile's own mean over 12 frames
    assert run_density_error(m, d, 12) == pytest.approx(float(np.mean(prof)))


def test_a_fresh_process_pays_the_first_runs_kernel_loads(tiny):
    from warp_sph.plan.advisor import process_overhead

    def pt(r, n, wall, first=False):  # no steps: the set-up is the run's wall time
        return Point("wcsph", r, fluid=n, wall_time=wall, first_in_process=first)

    # set-up 0.2 s + 1e-4 s per particle; the process's first run 1.5 s more
    pts = [pt(0.04, 1000, 1.7 + 0.1, True), pt(0.03, 2000, 0.2 + 0.2), pt(0.02, 6000, 0.2 + 0.6)]
    cal = _cal(*pts)
    assert process_overhead(cal, tiny) == pytest.approx(1.5)
    m = fit_models(cal, "wcsph", tiny)
    assert m.load_time == pytest.approx(1.5) and m.setup_time(1000) == pytest.approx(0.3)  # the first run left out
    assert process_overhead(_cal(*pts[1:]), tiny) == 0.0  # no first run among the points: nothing measured


def test_a_clamped_order_says_so(tiny):
    from warp_sph.plan.fit import fit_power_law
    from warp_sph.plan.report import model_line

    law = fit_power_law([0.04, 0.06], [4e-3, 1e-3], (-2.0, 4.0))   # e ~ d^-3.4: clamped to -2 (ORDER_RANGE)
    assert law.clipped and law.exponent == -2.0 and law.measured == pytest.approx(math.log(4) / math.log(2 / 3))
    assert not fit_power_law([0.04, 0.06], [1e-3, 2e-3], (-2.0, 4.0)).clipped
    pts = [_point("wcsph", 0.03, None, density_error_mean=1e-3), _point("wcsph", 0.02, None, density_error_mean=4e-3)]
    line = model_line(fit_models(_cal(*pts), "wcsph", tiny))
    assert "(measured -3.42, clamped)" in line and "no tolerance" in line


# --- errors against an experiment ----------------------------------------------------------------

def test_metric_names_of_the_validation_scenes(tiny):
    assert metric_names(tiny) == ["density"]
    assert metric_names(_validation("martin_moyce")) == ["density", "front", "residual"]
    assert metric_names(_validation("lobovsky")) == ["density", "sensor1", "sensor3", "sensor4"]
    assert metric_names(_validation("hydrostatic_probes")) == ["density", "floor", "middle"]
    assert metric_names(load_scene("hydrostatic")) == ["density"]  # the tank without probes: no reference


@pytest.mark.parametrize("text,metric,value", [("0.5%", "density", 0.005), ("front:4%", "front", 0.04),
                                               ("sensor1:0.1", "sensor1", 0.1), (" density:1% ", "density", 0.01)])
def test_parse_target(text, metric, value):
    assert parse_target(text) == (metric, pytest.approx(value))


@pytest.mark.parametrize("text", ["front:", "front:x", ":4%", "fr ont:4%", "front:150%"])
def test_parse_target_rejects(text):
    with pytest.raises(PlanError, match="--target-error") as e:
        parse_target(text)
    assert f"--target-error {text!r}:" in str(e.value)  # the whole value as given, not only its error part


def test_unknown_or_absent_metric_lists_the_scenes_metrics(tiny):
    with pytest.raises(PlanError, match=r"front:\.\.\.: an error against an experiment for scene 'tiny': it is not a "
                       r"validation case .*; its metrics: density$"):
        check_metric(tiny, "front")
    with pytest.raises(PlanError, match=r"an unknown metric for scene 'martin_moyce'.*its metrics: density, front, "
                       r"residual$"):
        check_metric(_validation("martin_moyce"), "peak")
    assert check_metric(_validation("martin_moyce"), "front") == "front"


def _write_probe(folder, name, t, v):
    rows = "".join(f"{float(a)!r},{float(b)!r},1\n" for a, b in zip(t, v))
    (folder / f"probe_{name}.csv").write_text(f"# warp-sph probe {name}\ntime [s],value,fill [-]\n{rows}")


def test_reference_errors_of_a_column_collapse_against_numpy_oracles(tmp_path):
    from warp_sph.validation.errors import load_series

    scene = _validation("martin_moyce")
    g, a, h0 = 9.81, 0.2, 0.4
    te, ze, _ = load_series("martin_moyce_1952_front")
    tr, hr, _ = load_series("martin_moyce_1952_residual")
    # the front 10 % ahead of the experiment, the residual column 0.05 H0 above it, at the experiment's times
    tf = np.concatenate([[0.0], te / math.sqrt(2 * g / a), [te[-1] / math.sqrt(2 * g / a) + 0.1]])
    zf = np.concatenate([[1.0], 1.1 * ze, [1.1 * ze[-1]]])
    th = np.concatenate([[0.0], tr / math.sqrt(g / a)])
    hh = np.concatenate([[1.0], hr + 0.05])
    _write_probe(tmp_path, "front", tf, a * zf)
    _write_probe(tmp_path, "residual", th, h0 * hh)
    out = evaluate_reference(scene, tmp_path, {"probes": {"front": {}, "residual": {}}})
    assert out["residual"] == pytest.approx(0.05, abs=1e-12)
    # front: brute-force relative RMS over shifts |s| <= 0.2 (points every shift can evaluate), its minimum
    T = tf * math.sqrt(2 * g / a)
    use = (te - 0.2 >= T[0]) & (te + 0.2 <= T[-1])
    rms = [np.sqrt(np.mean(((np.interp(te[use] - s, T, zf) - ze[use]) / ze[use]) ** 2))
           for s in np.linspace(-0.2, 0.2, 40001)]
    assert out["front"] == pytest.approx(min(rms), abs=1e-5) and out["front"] < 0.1 + 1e-12
    assert evaluate_reference(load_scene("hydrostatic"), tmp_path, {"probes": {"x": {}}}) == {}
    # a completed run made from a plan on "residual" records its error beside the prediction (run.json "plan")
    from warp_sph.plan.compare import compare_with_plan, summary_line

    info = {"scene": scene.to_dict(), "status": "completed", "wall_time": 2.0, "frames": [], "steps": 10}
    rec = compare_with_plan({"wall_time": 1.0, "density_error": 0.01, "metric": "residual", "metric_error": 0.04}, info,
                            tmp_path)
    assert rec["actual"]["metric_error"] == pytest.approx(0.05) and rec["ratio"]["metric_error"] == pytest.approx(1.25)
    assert "residual error 5 % (predicted 4 %)" in summary_line(rec)
    assert "metric_error" not in compare_with_plan({"metric": "residual"}, dict(info, status="running"), tmp_path)["actual"]


def test_plan_on_an_error_against_the_experiment(tmp_path):
    scene = _validation("martin_moyce")
    pts = [_point("dfsph", r, 5e-4, density_error_mean=1e-3, density_error_last=1e-3,
                  reference={"front": 2.0 * (2 * r) ** 0.5}) for r in (0.015, 0.01)]
    pts.append(_point("dfsph", 0.01, 1.25e-4, density_error_mean=1e-3, density_error_last=1e-3,
                      reference={"front": 2.0 * 0.02**0.5 * 0.25**0.5}))
    m = fit_models(_cal(*pts), "dfsph", scene, "front")
    assert m.metric == "front" and m.metric_error.exponent == pytest.approx(0.5)
    assert m.tolerance_exponents["metric"] == pytest.approx(0.5)
    cands = candidates_for(scene, {"dfsph": m})
    for c in cands:  # the hand-computed law: 2 d^0.5 (t / t0)^0.5
        assert c.metric == "front"
        assert c.error == pytest.approx(2.0 * (2 * c.particle_radius) ** 0.5 * (c.tolerance / 5e-4) ** 0.5, rel=1e-9)
    target = 0.2
    c = choose(cands, None, target, None, "mm")
    assert c.error <= target and all(d.wall_time >= c.wall_time for d in cands if d.error <= target
                                     and d.count_extrapolation <= 4)
    best = min((d for d in cands if d.count_extrapolation <= 4), key=lambda d: (d.error, d.wall_time))
    with pytest.raises(PlanError, match=rf"--target-error front:1% is below what the finest affordable setting that "
                       rf"fits in memory reaches: dfsph, particle_radius {best.particle_radius:.4g} m, tolerance "
                       rf"{best.tolerance:.3g}, .* gives {100 * best.error:.3g} %"):
        choose(cands, None, 0.01, None, "mm")
    # a scene whose calibration measured no point of the metric: no model for it
    assert fit_models(_cal(*[_point("dfsph", 0.01, 5e-4, reference={})]), "dfsph", scene, "front") is None


def _cli(capsys, *args):
    rc = main(list(args))
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.mark.parametrize("scene,target,match", [
    ("tiny", "front:4%", "an error against an experiment for scene 'tiny': it is not a validation case"),
    ("martin_moyce", "peak:4%", "an unknown metric for scene 'martin_moyce'"),
    ("tiny", "fr-ont:4%", "expected METRIC:ERROR"),
])
def test_cli_metric_errors(tiny, tmp_path, capsys, scene, target, match):
    from warp_sph.validation.cases import _scene_dir

    path = tiny.source if scene == "tiny" else str(_scene_dir() / f"{scene}.toml")
    rc, out, err = _cli(capsys, "plan", path, "--target-error", target, "--cache", str(tmp_path), "--no-progress")
    assert rc == 2 and match in err and len(err.strip().splitlines()) == 1, err
    assert "its metrics: density" in err or "METRIC:ERROR" in err
    assert not list(tmp_path.glob("calibration-*.json"))  # refused before any calibration run
