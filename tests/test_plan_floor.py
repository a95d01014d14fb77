"""warp-sph plan refuses a budget that not even the coarsest setting's least cost on this machine fits, before it
calibrates anything (issue 37): the floor is read from this machine's cached calibration runs (any scene), never
typed in; without a cache it calibrates first, as before. ``calibrate`` is replaced by a tripwire: nothing runs."""
from __future__ import annotations

import importlib
import json
import math
from dataclasses import asdict

import pytest

from warp_sph.cli import main
from warp_sph.core.device import resolve_device
from warp_sph.plan import PlanError, plan
from warp_sph.plan.advisor import BUDGET_SAFETY
from warp_sph.plan.calibrate import Point, calibration_radii, machine_floor, machine_text, variant
from warp_sph.run.memory import estimate_particle_counts

from test_plan_models import tiny  # noqa: F401  (the fixture)

calibrate_module = importlib.import_module("warp_sph.plan.calibrate")


class Calibrated(Exception):
    pass


def _tripwire(*a, **k):
    raise Calibrated()


def _write_cache(folder, machine, points):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "calibration-00000000000000000000.json").write_text(
        json.dumps({"key": "k", "machine": machine, "points": [asdict(p) for p in points]}))


def _points():
    """Two runs of another scene on this machine: the process's first (1.2 s outside its 40 steady steps of 2 ms at
    1,000 particles) and a later one (30 steps of 6 ms at 12,000 particles: 0.5 us per particle-step)."""
    first = Point("wcsph", 0.02, fluid=800, boundary=200, frames=3, steps=40, step_time=2e-3, wall_time=1.2 + 40 * 2e-3,
                  first_step_time=0.1, first_in_process=True)
    later = Point("pbf", 0.01, tolerance=0.005, fluid=9000, boundary=3000, frames=3, steps=30, step_time=6e-3,
                  wall_time=0.9 + 30 * 6e-3)
    return [first, later]


def test_the_machine_floor_is_the_least_measured_on_this_machine(tmp_path):
    dev = resolve_device("cpu")
    assert machine_floor(tmp_path / "none", dev) is None
    _write_cache(tmp_path / "c", machine_text(dev), _points())
    f = machine_floor(tmp_path / "c", dev)
    assert f["start"] == pytest.approx(1.2) and f["step"] == pytest.approx(2e-3)
    assert f["particle_step"] == pytest.approx(6e-3 / 12000) and f["points"] == 2
    # another machine's runs are no floor of this one's
    _write_cache(tmp_path / "other", machine_text(dev) + " elsewhere", _points())
    assert machine_floor(tmp_path / "other", dev) is None


def test_a_budget_below_the_floor_is_refused_before_calibrating(tiny, tmp_path, monkeypatch):  # noqa: F811
    dev = resolve_device("cpu")
    _write_cache(tmp_path, machine_text(dev), _points())
    monkeypatch.setattr(calibrate_module, "calibrate", _tripwire)
    # the oracle: the coarsest calibration radius's estimated count, every frame at dt_max, the floor's costs
    r0 = max(calibration_radii(tiny))
    n = sum(estimate_particle_counts(variant(tiny, "wcsph", r0)))
    frames = round(tiny.duration * tiny.fps)
    steps = frames * math.ceil(1.0 / (tiny.fps * tiny.time.dt_max) - 1e-9)
    least = 1.2 + steps * max(2e-3, n * 6e-3 / 12000)
    with pytest.raises(PlanError) as e:
        plan(tiny, budget_s=0.99 * least / BUDGET_SAFETY, solvers=["wcsph"], cache=tmp_path)
    msg = str(e.value)
    assert "\n" not in msg and "too small" in msg and f"{least:.3g} s in all" in msg
    assert f"--budget {math.ceil(least / BUDGET_SAFETY)}s or more" in msg and f"{n:,} particles" in msg
    # a budget it fits: the plan calibrates (the tripwire)
    with pytest.raises(Calibrated):
        plan(tiny, budget_s=1.01 * least / BUDGET_SAFETY, solvers=["wcsph"], cache=tmp_path)
    # no cache of this machine: no honest floor, the plan calibrates first as before
    with pytest.raises(Calibrated):
        plan(tiny, budget_s=0.01, solvers=["wcsph"], cache=tmp_path / "empty")


def test_the_command_refuses_in_one_line_with_status_2(tiny, tmp_path, monkeypatch, capsys):  # noqa: F811
    _write_cache(tmp_path / "c", machine_text(resolve_device("cpu")), _points())
    monkeypatch.setattr(calibrate_module, "calibrate", _tripwire)
    assert main(["plan", str(tiny.source), "--budget", "1s", "--solvers", "wcsph", "--cache", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--budget 1 s is too small" in err[0]
