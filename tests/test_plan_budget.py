"""warp-sph plan spending its budget (issue 37): the error's order from the finest calibrated radii, the step's cost
above the CPU launches' thread split from the points there, the budget a plan uses and the line that says when the
count extrapolation, not the budget, stopped it. Synthetic calibration points with known laws, NumPy oracles."""
from __future__ import annotations

import numpy as np
import pytest

from warp_sph.plan import budget_cap
from warp_sph.plan.advisor import Candidate, Plan, fit_models
from warp_sph.plan.calibrate import Calibration, Point, split_particles
from warp_sph.plan.report import model_line, table_lines

from test_plan_models import _point, tiny  # noqa: F401  (the fixture)


def _cal(*points, split=0):
    return Calibration(key="k", machine="m", points=list(points), step_floor=24.0, split_particles=split)


def test_the_error_order_comes_from_the_finest_radii(tiny):  # noqa: F811
    """An error that grows steeply between the coarse radii (d^-2.5, pre-asymptotic) and slowly between the fine ones
    (d^-0.5), as the dam break's PBF did (order -2.5 between r = 0.075 and 0.05 m, -0.77 over the finest three):
    the law is the finest three radii's, so a finer setting is predicted at d^-0.5 (before: all five points, the
    order measured -1.40 and clamped to -1: 1.23x the oracle at r = 0.008 m)."""
    radii = [0.06, 0.045, 0.03, 0.02, 0.013]
    b = 1e-4   # fine: e = b d^-0.5; coarse: continuous at d = 0.06 (r = 0.03)
    a = b * 0.06 ** -0.5 / 0.06 ** -2.5

    def law(d):
        return b * d ** -0.5 if d <= 0.06 + 1e-12 else a * d ** -2.5

    pts = [_point("wcsph", r, None, density_error_mean=law(2 * r), density_error_last=law(2 * r)) for r in radii]
    m = fit_models(_cal(*pts), "wcsph", tiny)
    assert m.error.exponent == pytest.approx(-0.5) and not m.error.clipped
    d = 2 * 0.008
    assert m.error(d) == pytest.approx(b * d ** -0.5)
    assert m.error_last(d) == pytest.approx(b * d ** -0.5)


def test_the_step_cost_above_the_thread_split_is_fitted_there(tiny):  # noqa: F811
    """Below 2,048 particles a step costs 1 ms + 10 us per fluid particle, above it 2 ms + 3 us (the launches split over
    the threads; measured, hydrostatic DFSPH: 10.4 us per fluid particle-step at 1,684 particles, 3.4-4.9 at 9,516):
    a target above the split takes the cost of the points above it (NumPy least squares), one below the line
    through all; with one count above, every point (nothing to fit a line to there)."""
    def t(n):
        return 1e-3 + 10e-6 * n if n < 2048 else 2e-3 + 3e-6 * n

    counts = [300, 1000, 1800, 4000, 9000]
    pts = [_point("wcsph", 0.03 * (400 / n) ** (1 / 3), None, fluid=n, boundary=0, step_time=t(n)) for n in counts]
    m = fit_models(_cal(*pts, split=2048), "wcsph", tiny)
    above = np.array([n for n in counts if n >= 2048], dtype=float)
    coef, *_ = np.linalg.lstsq(np.stack([np.ones_like(above), above], axis=1), [t(n) for n in above], rcond=None)
    assert m.split_particles == 2048
    assert m.step_cost(6000, 0) == pytest.approx(coef[0] + coef[1] * 6000) == pytest.approx(t(6000))
    # beyond the largest count (9,000) the line's falling cost per particle is not extrapolated: at least the largest
    # count's own, in proportion (``fit.fit_count_law``; tests/test_plan_cost.py)
    assert m.step_cost(30000, 0) == pytest.approx(t(9000) * 30000 / 9000)
    assert m.step_cost(1200, 0) == pytest.approx(m.step_time(1200, 0))  # below: the line through every point
    # the line through every point misses a target above the split (what the plan did before: +9 % here)
    assert abs(m.step_time(6000, 0) / t(6000) - 1.0) > 0.05
    assert "where the CPU launches split over the threads" in model_line(m)
    # one count above the split: no line there, every point's
    m1 = fit_models(_cal(*pts[:4], split=2048), "wcsph", tiny)
    assert m1.step_time_split is None and m1.step_cost(30000, 0) == m1.step_time(30000, 0)
    # on a GPU (split 0) the same points give one line
    assert fit_models(_cal(*pts), "wcsph", tiny).step_time_split is None


def test_split_count_of_the_devices():
    from warp_sph.core.device import resolve_device

    assert split_particles(resolve_device("cpu")) == 2048


def _candidate(r, ext, wall):
    return Candidate("pbf", r, 0.005, int(400 * (0.03 / r) ** 3), 0, 100, wall, 10**6, 1e-3, ext, 1.0)


def test_the_plan_says_when_the_count_extrapolation_stops_it():
    """Budget 60 s (48 s aimed): the finest candidate within 4x of the calibrated count takes 10 s; the budget would
    buy r = 0.015 m (5x the count, 30 s): the line names it. With 20 s the budget itself stops the plan: no line."""
    cands = [_candidate(0.02, 2.0, 10.0), _candidate(0.015, 5.0, 30.0), _candidate(0.01, 15.0, 100.0)]
    chosen = cands[0]
    line = budget_cap(cands, chosen, 60.0, None, "s.toml")
    assert line.startswith("the budget would allow r = 0.015 m") and "5.00x the largest calibrated count" in line
    assert "predicted 30 s, 50 % of the budget" in line and "the plan uses 17 %" in line
    assert budget_cap(cands, chosen, 20.0, None, "s.toml") is None
    # a tighter tolerance at a finer radius is not what the line compares with: the chosen tolerance's setting
    tight = Candidate("pbf", 0.012, 0.00125, 15000, 0, 100, 40.0, 10**6, 1e-4, 11.0, 1.0)
    assert budget_cap(cands + [tight], chosen, 60.0, None, "s.toml") == line
    p = Plan(scene="s", source="s.toml", chosen=chosen, budget_s=60.0)
    assert p.budget_used == pytest.approx(10.0 / 60.0) and p.to_dict()["budget_used"] == pytest.approx(1 / 6)
    assert "budget used: 17 % predicted (10 s of 60 s)" in table_lines(p)
    assert Plan(scene="s", source="s.toml", chosen=chosen).budget_used is None



def test_the_next_point_fits_what_is_left_of_the_share():
    """The largest point: 1,000 particles, 100 steps of 15 ms, 0.5 s outside them. The fit's choice 1000x beyond: the
    4x point (predicted 0.5 + 1.5 x 4^(4/3) = 10 s) when it fits; with 4 s left, the count whose cost fits
    (1000 x (3.5 / 1.5)^(3/4) = 1,888 particles); with 1 s left not even 1.5x fits (the caller runs nothing).
    A choice only just beyond 4x (a quarter of it ~ the largest count) still steps up 1.5x (before: the same radius,
    and the finer points stopped with the share a third used)."""
    from warp_sph.plan.advisor import LEAST_STEP_UP, STEP_UP, next_point

    cal = Calibration(key="k", machine="m", points=[
        Point("wcsph", 0.04, fluid=300, boundary=200, seconds=1.0),
        Point("wcsph", 0.02, fluid=800, boundary=200, seconds=2.0, steps=100, step_time=0.015)])
    far = Candidate("wcsph", 0.002, None, 10**6, 0, 1000, 10.0, 0, 0.01, 1000.0, 10.0)

    def count(r):
        return 1000 * (0.02 / r) ** 3

    r, cost, _ = next_point(cal, far, room=20.0)
    assert count(r) == pytest.approx(STEP_UP * 1000, rel=1e-3)
    r, cost, _ = next_point(cal, far, room=4.0)
    assert count(r) == pytest.approx(1000 * (3.5 / 1.5) ** 0.75, rel=1e-3) and cost == pytest.approx(4.0, rel=1e-2)
    r, cost, _ = next_point(cal, far, room=1.0)  # not even 1.5x fits: the 4x point, whose cost the caller refuses
    assert count(r) == pytest.approx(STEP_UP * 1000, rel=1e-3) and cost > 1.0
    just = Candidate("wcsph", 0.0126, None, 4002, 0, 100, 1.0, 0, 0.01, 4.002, 1.6)
    r, _, largest = next_point(cal, just)
    assert r < largest and count(r) == pytest.approx(LEAST_STEP_UP * 1000, rel=1e-3)


def test_a_finer_point_is_priced_without_the_kernel_loads():
    """The process's first calibration run (DFSPH, hydrostatic 60 s at load 5: 1.67 s, its second radius 0.44 s) paid
    the kernel loads: a later run of the process does not, so its cost is scaled from the least fixed time of the
    others' runs, and a run's first-step excess (its own kernels) is left out too."""
    from warp_sph.plan import point_cost
    from warp_sph.plan.advisor import fixed_time

    first = Point("dfsph", 0.04, fluid=100, boundary=400, seconds=1.67, steps=27, step_time=0.003,
                  first_step_time=0.5, first_in_process=True)
    other = Point("pbf", 0.04, fluid=100, boundary=400, seconds=0.35, steps=27, step_time=0.003,
                  first_step_time=0.05)
    own_other = 0.35 - 27 * 0.003 - (0.05 - 0.003)
    assert fixed_time(other) == pytest.approx(own_other)
    assert fixed_time(first, [first, other]) == pytest.approx(own_other)
    assert fixed_time(first) == pytest.approx(1.67 - 27 * 0.003 - (0.5 - 0.003))  # no other run to compare with
    cal = _cal(first, other)
    # (r / r_new)^4 = 16 at r_new = r / 2
    assert point_cost(cal, "dfsph", 0.02) == pytest.approx(own_other + 27 * 0.003 * 16)
