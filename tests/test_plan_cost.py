"""warp-sph plan's wall-time model beyond the calibration (issue 37): the step's cost against the fluid count beyond
the largest calibrated count (a power law with a measured, clipped exponent through the largest count's cost) and the
whole run's step cost over the calibration window's (the ratio C of the whole-run profile). Synthetic calibration
points with known laws, NumPy oracles; nothing runs a simulation."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from warp_sph.plan import cost_notes
from warp_sph.plan.advisor import fit_models, predict
from warp_sph.plan.calibrate import Calibration
from warp_sph.plan.fit import fit_count_law
from warp_sph.plan.models import COUNT_EXPONENT_RANGE, applied_cost_ratio

from test_plan_models import _point, tiny  # noqa: F401  (the fixture)


def _cal(*points, split=0):
    return Calibration(key="k", machine="m", points=list(points), step_floor=24.0, split_particles=split)


def _radius(n):  # the synthetic points' radius for n fluid particles (``_point``: n = 400 (0.03 / r)^3)
    return 0.03 * (400 / n) ** (1 / 3)


@pytest.mark.parametrize("b, expected", [(1.05, 1.05), (0.8, 1.0), (1.6, 1.1)])
def test_count_law_measures_its_exponent_clips_it_and_passes_through_the_largest_count(b, expected):
    counts = np.array([4000.0, 8000.0, 16000.0])
    t = 3e-6 * counts**b
    # a coarser point off the law: left out of the fit (only the three largest counts), else the slope would change
    law = fit_count_law([1000.0, *counts], [1.0, *t], COUNT_EXPONENT_RANGE, points=3)
    assert law.measured == pytest.approx(b)
    assert law.exponent == pytest.approx(expected) and law.clipped == (expected != b)
    assert law(16000) == pytest.approx(t[-1])                      # through the largest count's measured cost
    assert law(64000) == pytest.approx(t[-1] * 4.0**expected)       # NumPy oracle of the clipped law


def test_count_law_needs_two_counts():
    assert fit_count_law([5000, 5000], [1e-2, 1.1e-2]) is None
    assert fit_count_law([], []) is None
    # a repeated largest count: the law passes through the geometric mean of its times
    law = fit_count_law([2000, 4000, 4000], [4e-3, 8e-3, 8e-3 * 1.21])
    assert law(4000) == pytest.approx(8e-3 * 1.1)


def test_the_cost_per_particle_stops_falling_beyond_the_largest_count(tiny):  # noqa: F811
    """Above the thread split a step costs 5 ms + 2 us per fluid particle in the calibration (the launches' overhead
    spread over more particles: 3.7 us per particle at 3,000, 2.4 at 12,000); beyond the largest count the plan takes
    at least that count's cost per particle (measured: the line predicted 1.3-1.7 us per particle-step where the whole
    runs took 2.1-2.6 us at 3-5x the largest count): inside the calibrated range the line through the points holds."""
    def t(n):
        return 1e-3 + 10e-6 * n if n < 2048 else 5e-3 + 2e-6 * n

    counts = [300, 1000, 3000, 6000, 12000]
    pts = [_point("wcsph", _radius(n), None, fluid=n, boundary=0, step_time=t(n)) for n in counts]
    m = fit_models(_cal(*pts, split=2048), "wcsph", tiny)
    assert m.count_fluid == 12000 and m.count_law.exponent == 1.0 and m.count_law.measured < 1.0
    assert m.step_cost(8000, 0) == pytest.approx(t(8000))            # inside: the line above the split
    assert m.step_cost(48000, 0) == pytest.approx(t(12000) * 4.0)    # beyond: the largest count's, in proportion
    assert m.step_time_split(48000, 0) == pytest.approx(t(48000))    # what the line said: 0.87x that
    assert t(48000) < 0.9 * m.step_cost(48000, 0)
    line = __import__("warp_sph.plan.report", fromlist=["model_line"]).model_line(m)
    assert "beyond 12,000 fluid particles at least ~ Nf^1.00" in line
    # on a GPU (no thread split) the cost per particle falls with the count as the device fills: no such bound
    g = fit_models(_cal(*pts), "wcsph", tiny)
    assert g.count_law is None and g.step_cost(48000, 0) == pytest.approx(g.step_time(48000, 0))


@pytest.mark.parametrize("measured, applied", [(1.3, 1.3), (1.05, 1.0), (0.93, 1.0), (2.0, 1.5), (0.5, 0.8)])
def test_the_whole_runs_step_cost_ratio(tiny, measured, applied):  # noqa: F811
    """The whole-run profile (the scene's duration at the coarsest radius) takes ``measured`` x the calibration
    point's steady step time at that radius: the wall prediction's steps cost that much more (within 10 % of 1 it is
    timing noise and taken as 1; clipped to 0.8-1.5; not applied against a point whose steps took under 0.5 s), the
    plan's notes say so."""
    window = [_point("wcsph", 0.03, None, step_time=0.02), _point("wcsph", 0.02, None, step_time=0.05)]  # 0.6 s, 2.25 s
    whole = _point("wcsph", 0.03, None, frames=12, steps=120, step_time=window[0].step_time * measured,
                   density_errors=[1e-3] * 12)
    m = fit_models(_cal(*window), "wcsph", tiny, profile=_cal(whole))
    assert m.cost_ratio_measured == pytest.approx(measured) and m.cost_ratio == pytest.approx(applied)
    assert applied_cost_ratio(measured) == pytest.approx(applied) and applied_cost_ratio(None) == 1.0
    base = replace(m, cost_ratio=1.0)
    assert m.step_cost(5000, 100) == pytest.approx(applied * base.step_cost(5000, 100))
    r = 0.012
    c, c1 = predict(tiny, m, r), predict(tiny, base, r)
    assert c.steps == c1.steps
    assert c.wall_time - c1.wall_time == pytest.approx(c.steps * base.step_cost(c.fluid_particles, c.boundary_particles)
                                                       * (applied - 1.0), abs=1e-12)
    notes = cost_notes(m, c)
    assert len(notes) == 1 and f"{measured:.3g}x the calibration window's" in notes[0]
    assert ("applied: x" in notes[0]) == (applied != 1.0)
    # against a calibration point whose steps took under 0.5 s: measured and noted, not applied (a sample of the load)
    short = replace(window[0], step_time=0.01)                                               # 30 steps: 0.3 s
    ms = fit_models(_cal(short, window[1]), "wcsph", tiny, profile=_cal(replace(whole, step_time=0.01 * measured)))
    assert ms.cost_ratio_measured == pytest.approx(measured) and ms.cost_ratio == 1.0
    assert abs(measured - 1.0) <= 0.1 or "not applied: the calibration window's steps took 0.3 s, under 0.5 s" in \
        cost_notes(ms, c)[0]
    # against the process's first calibration run (its steady steps are not a reference): no ratio
    first = replace(window[0], first_in_process=True)
    assert fit_models(_cal(first, window[1]), "wcsph", tiny, profile=_cal(whole)).cost_ratio_measured is None
    # without a whole run there is nothing to say and nothing applied
    m0 = fit_models(_cal(*window), "wcsph", tiny)
    assert m0.cost_ratio == 1.0 and m0.cost_ratio_measured is None and cost_notes(m0, c) == []


@pytest.mark.parametrize("later", [1.3, 0.7])
def test_the_course_of_the_step_cost_is_measured_within_the_whole_run(tiny, later):  # noqa: F811
    """Where the whole run recorded its frames' CPU time, C is that run's CPU per step over its advanced frames 2..F over
    its frames 2..F_c (F_c: the calibration's frames; the first frame, which loads the kernels, left out), whatever
    the calibration point at that radius measured (another process's steps); NumPy oracle on synthetic frame_times."""
    from warp_sph.plan.points import course_ratio

    window = [_point("wcsph", 0.03, None, step_time=0.02, first_in_process=True),
              _point("wcsph", 0.02, None, step_time=0.05)]
    steps = np.array([9, 9, 9, 12, 14, 14, 13, 12, 12, 11, 11, 10])
    per_step = np.array([0.9] + [0.05] * 2 + [0.05 * later] * 9)     # [s] CPU per step; frame 1 loads the kernels
    cpu = steps * per_step
    whole = _point("wcsph", 0.03, None, frames=12, steps=int(steps.sum()), step_time=0.07,
                   density_errors=[1e-3] * 12, frame_steps=steps.tolist(), frame_cpu=cpu.tolist())
    oracle = (cpu[1:].sum() / steps[1:].sum()) / (cpu[1:3].sum() / steps[1:3].sum())
    assert course_ratio(whole, 3) == (pytest.approx(oracle), pytest.approx(cpu[1:3].sum()))
    m = fit_models(_cal(*window), "wcsph", tiny, profile=_cal(whole))   # the old rule: none (a first-in-process point)
    assert m.cost_ratio_measured == pytest.approx(oracle) and m.cost_ratio_window == pytest.approx(0.9)
    assert m.cost_ratio == pytest.approx(applied_cost_ratio(oracle, 0.9)) and m.cost_ratio != 1.0
    # the same course over a window of ms steps (the coarsest radius's): measured, not applied (its timing noise)
    short = replace(whole, frame_cpu=(cpu * 0.01).tolist())
    ms = fit_models(_cal(*window), "wcsph", tiny, profile=_cal(short))
    assert ms.cost_ratio_measured == pytest.approx(oracle) and ms.cost_ratio == 1.0
    # a run without frame_cpu (cached before it) or no frame beyond the window: the cross-run rule, or nothing
    assert course_ratio(replace(whole, frame_cpu=[]), 3) == (None, 0.0)
    assert course_ratio(replace(whole, frame_cpu=cpu[:3].tolist(), frame_steps=steps[:3].tolist()), 3) == (None, 0.0)


def test_the_count_law_takes_the_points_whose_fluid_splits(tiny):  # noqa: F811
    """A dam break's coarse points pass the thread split on their walls (216 fluid with 2,022 wall particles): their
    cost per fluid particle is mostly the walls' and the steps' overhead, so the count law takes only the points
    whose fluid count reaches the split; with one such count there is no law."""
    walls = [_point("wcsph", _radius(n), None, fluid=n, boundary=3000, step_time=3e-3 + 1e-6 * n) for n in (216, 512)]
    fine = [_point("wcsph", _radius(n), None, fluid=n, boundary=6000, step_time=2e-6 * n) for n in (4000, 8000)]
    m = fit_models(_cal(*walls, *fine, split=2048), "wcsph", tiny)
    assert m.count_fluid == 8000 and m.count_law.measured == pytest.approx(1.0)
    assert m.count_law(32000) == pytest.approx(2e-6 * 32000)
    assert fit_models(_cal(*walls, fine[0], split=2048), "wcsph", tiny).count_law is None


def test_the_bench_detail_compares_the_steps_cpu_time(tiny):  # noqa: F811
    """``warp-sph bench plan``'s detail: the prediction in process CPU time (the predicted wall step times the largest
    calibrated count's CPU per wall second of its steps, ``cpu_per_wall``, a one-frame timing point's too) against the
    run's CPU per step over its frames 2.. (NumPy oracle)."""
    from types import SimpleNamespace

    from warp_sph.benchmarks.plan import run_detail
    from warp_sph.plan.advisor import point_summary
    from warp_sph.plan.points import cpu_per_wall

    steps = np.array([9, 9, 9])
    pts = [_point("wcsph", r, None, frame_steps=steps.tolist(), first_step_time=0.0) for r in (0.03, 0.02)]
    for p in pts:
        p.steps = int(steps.sum())
        p.frame_cpu = (steps * 1.5 * p.step_time).tolist()              # 1.5 s of CPU per second of step
    assert cpu_per_wall(pts[0]) == pytest.approx(1.5) and cpu_per_wall(replace(pts[0], frame_cpu=[])) is None
    one = replace(pts[0], steps=9, frame_steps=[9], frame_cpu=[0.7 + 9 * pts[0].step_time], first_step_time=0.5 +
                  pts[0].step_time)                                     # a timing point: its one frame loads kernels
    assert cpu_per_wall(one) == pytest.approx((0.7 + 9 * one.step_time) / (9 * one.step_time + 0.5))
    m = fit_models(_cal(*pts), "wcsph", tiny)
    c = predict(tiny, m, 0.012)
    p = SimpleNamespace(chosen=c, models={"wcsph": m}, points=[{**point_summary(q), "whole_run": False} for q in pts])
    run_steps = np.array([9, 12, 14, 14])
    run_cpu = np.array([5.0, 0.2, 0.25, 0.26])
    frames = [{"frame": 1, "density_error_mean": 0.0}] + [{"frame": k + 2, "density_error_mean": 1e-3, "steps": int(n)}
                                                          for k, n in enumerate(run_steps)]
    info = {"frames": frames, "sim_time_per_step_ms": 5.0, "fluid_particles": c.fluid_particles,
            "frame_times": [{"steps": int(n), "cpu_time": float(t)} for n, t in zip(run_steps, run_cpu)]}
    got = run_detail(p, info)["cpu"]
    step = m.step_cost(c.fluid_particles, c.boundary_particles, 2 * 0.012)
    assert got["largest_calibrated_per_wall"] == pytest.approx(1.5)
    assert got["predicted"] == pytest.approx(1.5 * step)
    assert got["run"] == pytest.approx(run_cpu[1:].sum() / run_steps[1:].sum())
    assert got["ratio"] == pytest.approx(got["run"] / (1.5 * step))
    # points or a run from before the frames' CPU time was kept: nothing to compare
    old = SimpleNamespace(chosen=c, models={"wcsph": m},
                          points=[{**point_summary(q), "whole_run": False, "cpu_per_wall": None} for q in pts])
    assert run_detail(old, {**info, "frame_times": []})["cpu"]["ratio"] is None
