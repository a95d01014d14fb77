"""``benchmarks/plan_replay.py``: a recorded ``bench plan`` case's step cost fitted again from its calibration points
gives the prediction the plan made (the same code), so a change of the step cost's rule is judged on the recorded runs.
"""
from __future__ import annotations

from dataclasses import replace

import pytest

from warp_sph.benchmarks.plan_replay import replay
from warp_sph.plan.advisor import fit_models, point_summary, predict

from test_plan_models import tiny  # noqa: F401  (the fixture)
from test_plan_spike import _cal, _points
from test_plan_sweeps import _dfsph_points


def _record(scene, cal, solver: str, radius: float, actual: float) -> tuple:
    """A bench plan record of ``solver`` at ``radius`` [m] as ``benchmarks/plan.py`` writes it, and the prediction."""
    m = fit_models(cal, solver, scene)
    c = predict(scene, m, radius)
    frames = int(round(scene.duration * scene.fps)) + 1
    plan = {"points": [point_summary(p) for p in cal.points], "models": {solver: m.to_dict()}, "chosen": c.to_dict(),
            "frames": frames}
    return {"kind": "plan", "status": "completed", "label": "tiny-60s", "date": "2026-11-26T00:00:00", "solver": solver,
            "plan": plan, "actual": {"wall_time": actual}, "wall_ratio": actual / c.wall_time}, c, m


@pytest.mark.parametrize("slow", [1.0, 3.0])
def test_the_replay_reproduces_the_plans_prediction(tiny, slow):  # noqa: F811
    """Points above the CPU's thread split (the count law, a slowed point left out) and below it (the sweeps' factor),
    with an export wait per frame: the replayed wall time is the plan's to rounding, actual / replayed its ratio."""
    cal = _cal([replace(p, export_wait=0.03 * p.frames) for p in _points(slow)])
    record, c, m = _record(tiny, cal, "wcsph", 0.008, 12.0)
    assert m.frame_overhead(1000) > 0 and (m.slowed != []) == (slow > 1.0)
    got = replay(record)
    assert got["replayed"] == pytest.approx(c.wall_time, rel=1e-9) and got["ratio"] == pytest.approx(12.0 / c.wall_time)
    record, c, m = _record(tiny, _cal(_dfsph_points(tiny), split=0), "dfsph", 0.012, 5.0)
    assert m.sweep_factor(c.fluid_particles, 0.024) != 1.0
    assert replay(record)["replayed"] == pytest.approx(c.wall_time, rel=1e-9)


def test_the_replay_takes_the_course_from_the_whole_runs_frames(tiny):  # noqa: F811
    """A record whose whole run kept its frames' steps and CPU time: the replay measures C from them as the plan did
    (``points.course_ratio``), even where the record's model says 1 (made before the rule): the plan's prediction."""
    import numpy as np

    from test_plan_models import _point

    window = [_point("wcsph", 0.03, None, step_time=0.02), _point("wcsph", 0.02, None, step_time=0.05)]
    steps = np.array([9] * 3 + [12] * 9)
    cpu = steps * np.array([0.9, 0.05, 0.05] + [0.065] * 9)               # the later frames 1.3x the window's per step
    whole = _point("wcsph", 0.03, None, frames=12, steps=int(steps.sum()), step_time=0.06,
                   density_errors=[1e-3] * 12, frame_steps=steps.tolist(), frame_cpu=cpu.tolist())
    cal = _cal(window, split=0)
    m = fit_models(cal, "wcsph", tiny, profile=_cal([whole], split=0))
    oracle = (cpu[1:].sum() / steps[1:].sum()) / (cpu[1:3].sum() / steps[1:3].sum())   # 1.3 x 99 + 18 over 117 steps
    assert oracle > 1.1 and m.cost_ratio == pytest.approx(oracle)
    c = predict(tiny, m, 0.012)
    frames = int(round(tiny.duration * tiny.fps)) + 1
    plan = {"points": [point_summary(p) for p in window] + [point_summary(whole, whole=True)],
            "models": {"wcsph": {**m.to_dict(), "cost_ratio": 1.0}}, "chosen": c.to_dict(), "frames": frames}
    record = {"kind": "plan", "status": "completed", "label": "tiny-60s", "date": "2026-11-27T00:00:00",
              "solver": "wcsph", "plan": plan, "actual": {"wall_time": 9.0}, "wall_ratio": 9.0 / c.wall_time}
    assert plan["points"][-1]["frame_cpu"] == cpu.tolist()
    assert replay(record)["replayed"] == pytest.approx(c.wall_time, rel=1e-9)
    plan["points"][-1].pop("frame_cpu")                                        # an older record: its own C (1 here)
    assert replay(record)["replayed"] < c.wall_time
