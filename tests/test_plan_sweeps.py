"""warp-sph plan's step cost beyond the calibrated counts as a per-step part plus a per-sweep part times the solver's
sweeps per step (issue 37): the sweeps' law against the spacing, its bounds from the scene, the sweeps' stages' share
of a step read from run.json's stage times, and the prediction's step cost (a + b s). Synthetic calibration points
with known laws and NumPy oracles; nothing runs a simulation."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from warp_sph.plan import cost_notes
from warp_sph.plan.advisor import fit_models, predict
from warp_sph.plan.calibrate import Calibration, scene_tolerance
from warp_sph.plan.fit import SWEEPS_EXPONENT_RANGE, fit_sweeps
from warp_sph.plan.points import SOLVE_STAGES, solve_share, sweep_bounds
from warp_sph.scene import load_scene

from test_plan_models import _point, tiny  # noqa: F401  (the fixture)


def _cal(*points):
    return Calibration(key="k", machine="m", points=list(points), step_floor=24.0)


def test_solve_share_is_the_sweeps_stages_share_of_the_steady_step():
    """Each stage's steady time is its seconds less its first call's (the kernel loads); the share is the sweeps'
    stages' over all of them (the figures of a 4-frame hydrostatic DFSPH run, rounded)."""
    stages = [{"stage": "neighbors", "seconds": 0.016, "first_call_seconds": 0.001},
              {"stage": "density", "seconds": 0.060, "first_call_seconds": 0.010},
              {"stage": "divergence", "seconds": 0.030, "first_call_seconds": 0.005},
              {"stage": "pressure", "seconds": 0.031, "first_call_seconds": 0.001},
              {"stage": "integrate", "seconds": 0.006, "first_call_seconds": 0.0}]
    steady = {"neighbors": 0.015, "density": 0.05, "divergence": 0.025, "pressure": 0.03, "integrate": 0.006}
    assert solve_share(stages) == pytest.approx((0.025 + 0.03) / sum(steady.values()))
    assert "pressure" in SOLVE_STAGES and "neighbors" not in SOLVE_STAGES
    assert solve_share([]) == 0.0 and solve_share([{"stage": "pressure", "seconds": 0.0}]) == 0.0


@pytest.mark.parametrize("solver", ["dfsph", "pbf"])
def test_a_calibration_run_records_its_sweeps_stages_share(tiny, tmp_path, monkeypatch, solver):  # noqa: F811
    """A real calibration run of each iterating solver (2 frames of the tiny tank): SOLVE_STAGES names stages it has
    (a renamed stage would silently drop the sweeps' part), its share lies strictly between 0 and 1, and its sweeps are
    at least the scene's fewest."""
    import json

    from warp_sph.core.device import resolve_device
    from warp_sph.plan.points import run_point
    from warp_sph.run import runner

    seen = {}
    real = runner.run

    def spy(*a, **k):
        info = real(*a, **k)
        seen.update({s["stage"]: s for s in info["stage_times"]})
        return info

    monkeypatch.setattr(runner, "run", spy)
    p = run_point(tiny, solver, 0.03, 3, resolve_device("cpu"), tmp_path / "run")
    assert p.status == "completed", p.error
    assert set(SOLVE_STAGES) & set(seen), json.dumps(list(seen))
    assert 0.0 < p.solve_share < 1.0
    assert p.solve_share == pytest.approx(solve_share(list(seen.values())))
    assert p.sweeps >= sweep_bounds(tiny, solver)[0] - 1e-9


def test_the_sweeps_bounds_come_from_the_scene():
    """The fewest sweeps: the density solve's min_iterations plus, with the divergence solve on, its own (DFSPH's
    defaults 2 + 1, the hydrostatic runs' 3.0-3.05 at the finest radii); a solver without iterations has none."""
    s = load_scene("hydrostatic")
    assert sweep_bounds(s, "dfsph") == (3.0, 200.0)
    assert sweep_bounds(s, "pbf") == (2.0, 50.0)
    assert sweep_bounds(s, "wcsph") == (0.0, 0.0)      # no cap: 0 (a plan's record is JSON without inf)
    off = load_scene("hydrostatic", overrides=["dfsph.divergence_solve=false", "dfsph.min_iterations=4"])
    assert sweep_bounds(off, "dfsph") == (4.0, 100.0)


@pytest.mark.parametrize("k, expected", [(0.65, 0.65), (-0.3, 0.0), (2.0, SWEEPS_EXPONENT_RANGE[1])])
def test_the_sweeps_law_is_fitted_to_the_finest_radii(k, expected):
    d = np.array([0.027, 0.031, 0.036])
    s = 3.58 * (d / d[0]) ** k
    # a coarse point off the law (the coarsest radius's few particles): left out, only the finest three count
    law = fit_sweeps([0.085, *d], [9.0, *s], points=3)
    assert law.measured == pytest.approx(k) and law.exponent == pytest.approx(expected)
    if expected == k:
        assert law(0.019) == pytest.approx(3.58 * (0.019 / 0.027) ** k)  # NumPy oracle
    assert fit_sweeps([0.03, 0.02], [0.0, 0.0]) is None                   # WCSPH: no sweeps


def _dfsph_points(tiny, share=0.4):  # noqa: F811
    """DFSPH points whose sweeps fall with refinement as s = 3.58 (d / d_ref)^0.65 (the hydrostatic tank's: 4.31,
    3.97, 3.58 at r = 0.018, 0.0155, 0.0136 m), each step 1 us per fluid particle."""
    t0 = scene_tolerance(tiny, "dfsph")
    radii = [0.03, 0.024, 0.02]
    d_ref = 2 * radii[-1]
    return [_point("dfsph", r, t0, sweeps=3.58 * (2 * r / d_ref) ** 0.65, solve_share=share) for r in radii]


def test_the_step_cost_beyond_the_largest_count_carries_the_predicted_sweeps(tiny):  # noqa: F811
    """Beyond the largest calibrated count the step costs (1 - f) T + f T s(d) / s_ref over what the count's fit
    gives (T): f the largest point's sweeps' stages' share, s the sweeps' law within the scene's bounds (DFSPH: at
    least 2 + 1); inside the calibrated counts the fit alone (it carries the points' own sweeps)."""
    pts = _dfsph_points(tiny)
    m = fit_models(_cal(*pts), "dfsph", tiny)
    ref = pts[-1]
    assert m.sweeps_fluid == ref.fluid and m.sweeps_reference == pytest.approx(3.58) and m.solve_share == 0.4
    assert m.sweeps.exponent == pytest.approx(0.65)
    d = 2 * 0.016                                  # finer: fewer sweeps, above the floor of 3
    s = 3.58 * (d / (2 * ref.particle_radius)) ** 0.65
    assert s > 3.0 and m.sweeps_at(d) == pytest.approx(s)
    n = int(ref.fluid * 2)
    plain = replace(m, sweeps=None)
    assert m.step_cost(n, 0, d) == pytest.approx(plain.step_cost(n, 0) * (0.6 + 0.4 * s / 3.58))
    assert m.step_cost(n, 0) == pytest.approx(plain.step_cost(n, 0))              # no spacing: no factor
    assert m.sweep_factor(ref.fluid, d) == 1.0                                     # inside the calibrated counts
    # much finer: the law would go below the scene's fewest sweeps, the floor holds
    assert m.sweeps_at(2 * 0.004) == 3.0
    assert m.sweep_factor(10 * ref.fluid, 2 * 0.004) == pytest.approx(0.6 + 0.4 * 3.0 / 3.58)
    # the prediction's wall time: its steps at that cost (NumPy oracle of a + b s)
    r = 0.012
    c, c0 = predict(tiny, m, r), predict(tiny, plain, r)
    assert c.steps == c0.steps and c.fluid_particles > ref.fluid
    factor = 0.6 + 0.4 * max(3.58 * (2 * r / (2 * ref.particle_radius)) ** 0.65, 3.0) / 3.58
    assert c.wall_time - c0.wall_time == pytest.approx(c.steps * plain.step_cost(c.fluid_particles, 0) * (factor - 1))
    note = [n for n in cost_notes(m, c) if "for its sweeps" in n]
    assert len(note) == 1 and "against 3.58 at that count" in note[0] and "took 40 % of its step" in note[0]


def test_sweeps_that_grow_with_refinement_hold_the_largest_counts(tiny):  # noqa: F811
    """The dam break's DFSPH: the calibration window's sweeps grow with refinement (5.4, 10.3, 18.5 per step at r =
    0.0315, 0.0198, 0.0132 m; the law's exponent clipped to 0 makes it a constant, the points' geometric mean, below
    the largest count's own). Beyond that count the step takes the largest count's sweeps (factor 1), not the mean
    (the whole runs' steps cost 0.90-1.14x their first frames': the growth is not the run's, nor is a fall)."""
    t0 = scene_tolerance(tiny, "dfsph")
    radii = [0.0315, 0.0198, 0.0132]
    sweeps = [5.44, 10.33, 18.45]
    pts = [_point("dfsph", r, t0, sweeps=s, solve_share=0.64) for r, s in zip(radii, sweeps)]
    m = fit_models(_cal(*pts), "dfsph", tiny)
    assert m.sweeps.measured < 0 and m.sweeps.exponent == 0.0 and m.sweeps_grow()
    mean = float(np.exp(np.mean(np.log(sweeps))))                    # what the clipped law alone gives
    assert m.sweeps(0.01) == pytest.approx(mean) and mean < 0.7 * 18.45
    ref = pts[-1]
    d = 2 * 0.0083
    assert m.sweeps_reference == pytest.approx(18.45) and m.sweeps_at(d) == pytest.approx(18.45)
    assert m.sweep_factor(4 * ref.fluid, d) == pytest.approx(1.0)    # the old rule: 0.36 + 0.64 x mean / 18.45
    plain = replace(m, sweeps=None)
    assert m.step_cost(4 * ref.fluid, 0, d) == pytest.approx(plain.step_cost(4 * ref.fluid, 0))
    c = predict(tiny, m, 0.0083)
    assert c.fluid_particles > ref.fluid
    note = [n for n in cost_notes(m, c) if "grew with refinement" in n]
    assert len(note) == 1 and "18.4 per step are held" in note[0] and "for its sweeps" not in " ".join(cost_notes(m, c))
    # sweeps that fall with refinement (the tank's) still carry the law's fall
    falling = fit_models(_cal(*_dfsph_points(tiny)), "dfsph", tiny)
    assert not falling.sweeps_grow() and falling.sweep_factor(10 ** 6, 2 * 0.012) < 1.0
    # sweeps at the solver's fewest at every radius (PBF's 2: a fit's rounding, not a growth): no note
    flat = fit_models(_cal(*[replace(p, sweeps=2.0) for p in pts]), "dfsph", tiny)
    flat = replace(flat, sweeps=replace(flat.sweeps, measured=-1e-16))
    assert not flat.sweeps_grow() and not any("grew with refinement" in n for n in cost_notes(flat, c))


def test_no_sweeps_part_without_a_measured_share_or_sweeps(tiny):  # noqa: F811
    """A cached point of an older schema, or a solver without sweeps (WCSPH), leaves the step cost as fitted."""
    m = fit_models(_cal(*_dfsph_points(tiny, share=0.0)), "dfsph", tiny)
    assert m.sweep_factor(10**6, 0.01) == 1.0
    w = fit_models(_cal(_point("wcsph", 0.03, None), _point("wcsph", 0.02, None)), "wcsph", tiny)
    assert w.sweeps is None and w.sweeps_at(0.01) == 0.0 and w.sweep_factor(10**6, 0.01) == 1.0


def test_the_models_stay_json(tiny):  # noqa: F811
    """A plan's record (``warp-sph bench plan``) writes the models with allow_nan=False: no inf in the sweeps' bounds
    (the bench of 14:07 failed there on WCSPH's, after its four cases had run)."""
    import json

    for m in (fit_models(_cal(*_dfsph_points(tiny)), "dfsph", tiny),
              fit_models(_cal(_point("wcsph", 0.03, None), _point("wcsph", 0.02, None)), "wcsph", tiny)):
        json.dumps(m.to_dict(), allow_nan=False)
