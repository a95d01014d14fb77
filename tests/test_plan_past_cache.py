"""The rule "never extrapolate the step's cost across the CPU's last-level cache without a measurement"
(``warp_sph.plan.past_cache``, docs/plan-model.md item 12), on the fake clock of test_plan_share: synthetic runs whose
arrays take 2,000 B per fluid particle and whose step costs 1.5x more once they pass the L3, the L3's size read from a
fake sysfs folder (``working_set.CPU_CACHE_DIR``)."""
from __future__ import annotations

import importlib

import pytest

from warp_sph.plan import plan
from warp_sph.plan.advisor import CALIBRATION_SHARE
from warp_sph.plan.past_cache import CACHE_MARGIN, TIMING_FRAMES
from warp_sph.run import working_set

from test_plan_share import FakeClock, tiny  # noqa: F401  (the fixture)

calibrate_module = importlib.import_module("warp_sph.plan.calibrate")
BYTES_PER_FLUID = 2000
RISE = 1.5


class CacheClock(FakeClock):
    """FakeClock on a CPU (its thread split) with the run's arrays (``array_bytes``) and a step 1.5x dearer past the L3
    (the sysfs one); ``calls``: (solvers, radii, frames) of each calibrate call."""

    def __init__(self):
        super().__init__(power=1.0, c=1e-6)
        self.calls = []

    def point(self, solver, r, t, frames):
        p = super().point(solver, r, t, frames)
        p.array_bytes = BYTES_PER_FLUID * p.fluid
        if p.array_bytes > working_set.last_level_cache_bytes():
            p.step_time *= RISE
            p.first_step_time = p.step_time
            p.seconds, p.wall_time = 0.3 + p.steps * p.step_time, 0.25 + p.steps * p.step_time
        return p

    def __call__(self, scene, solvers, **kw):
        self.calls.append((tuple(solvers), tuple(kw["radii"]), kw["frames"]))
        cal = super().__call__(scene, solvers, **kw)
        cal.cache_bytes = working_set.last_level_cache_bytes()
        cal.split_particles = 2048  # a CPU's (``calibrate.split_particles``): the count law beyond the largest count
        return cal


def _sysfs(tmp_path, monkeypatch, mib_l3: float):
    for name, level, size in (("index0", 1, "48K"), ("index3", 3, f"{int(mib_l3 * 1024)}K")):
        (tmp_path / name).mkdir()
        (tmp_path / name / "level").write_text(f"{level}\n")
        (tmp_path / name / "size").write_text(f"{size}\n")
    monkeypatch.setattr(working_set, "CPU_CACHE_DIR", tmp_path)
    return working_set.last_level_cache_bytes()


def test_a_choice_past_the_cache_gets_a_timing_point_there_first(tiny, monkeypatch, tmp_path):  # noqa: F811
    """A 33.4 MiB L3 and a 60 s budget: the finer points stop at 15,645 fluid particles (29.8 MiB), the budget reaches
    past the L3. The plan times one frame of WCSPH at the coarsest ladder radius whose arrays pass the L3 by 1.25x;
    that point enters the step's cost (its 1.5x rise measured: the prediction at the chosen count carries it), not the
    error models, and the calibration keeps to its share. Before: no such point, the chosen count's step predicted at
    1.0 us per fluid particle where the run costs 1.5 us."""
    cache = _sysfs(tmp_path, monkeypatch, 35e6 / 2**20)
    clock = CacheClock()
    monkeypatch.setattr(calibrate_module, "calibrate", clock)
    p = plan(tiny, budget_s=60.0, solvers=["wcsph", "pbf"])
    timing = [c for c in clock.calls if c[2] == TIMING_FRAMES]
    assert len(timing) == 1 and timing[0][0] == ("wcsph",)
    r_t = timing[0][1][0]
    m = p.models["wcsph"]
    assert m.timing_radii == [r_t] and r_t not in m.calibrated_radii  # not in the error models
    assert m.array_bytes_calibrated >= CACHE_MARGIN * cache  # past the L3 by the margin
    # the coarsest such radius: the next coarser ladder radius's arrays do not pass it by the margin
    coarser = [c for c in p.candidates if c.solver == "wcsph" and c.particle_radius > r_t and c.tolerance == m.tolerance]
    assert all(m.array_bytes(c.fluid_particles, c.boundary_particles) < CACHE_MARGIN * cache for c in coarser)
    c = p.chosen
    assert c.solver == "wcsph" and BYTES_PER_FLUID * c.fluid_particles > cache
    assert m.step_cost(c.fluid_particles, c.boundary_particles) >= 0.95 * RISE * 1e-6 * c.fluid_particles
    assert not any("capped" in n or "unmeasured" in n for n in p.notes)
    assert p.calibration_seconds <= CALIBRATION_SHARE * 60.0
    assert any(q.get("timing_only") for q in p.points)
    # made again from the same clock: the same decisions, nothing run
    runs = clock.runs
    q = plan(tiny, budget_s=60.0, solvers=["wcsph", "pbf"])
    assert clock.runs == runs and q.chosen == p.chosen


def test_without_room_for_the_timing_point_the_choice_stays_inside_the_cache(tiny, monkeypatch, tmp_path):  # noqa: F811
    """A 42.9 MiB L3, the same 60 s budget: the timing point past it (31,298 fluid) does not fit in the share left. The
    plan caps its choice at the finest setting whose arrays fit in the L3 and a note names the L3, the arrays the budget's
    choice would need and the count it stopped at. Before: 44,257 fluid particles (84 MiB), its cost extrapolated."""
    cache = _sysfs(tmp_path, monkeypatch, 45e6 / 2**20)
    clock = CacheClock()
    monkeypatch.setattr(calibrate_module, "calibrate", clock)
    p = plan(tiny, budget_s=60.0, solvers=["wcsph", "pbf"])
    assert not [c for c in clock.calls if c[2] == TIMING_FRAMES]
    c = p.chosen
    assert BYTES_PER_FLUID * c.fluid_particles <= cache
    # the finest within the cache: the next finer candidate of its solver passes it
    finer = [q for q in p.candidates if q.solver == c.solver and q.tolerance == c.tolerance
             and q.particle_radius < c.particle_radius]
    assert BYTES_PER_FLUID * max(finer, key=lambda q: q.particle_radius).fluid_particles > cache
    note = next(n for n in p.notes if n.startswith("capped"))
    assert f"{cache / 2**20:.3g} MiB last-level cache" in note and f"({c.fluid_particles:,} fluid" in note
    assert p.calibration_seconds <= CALIBRATION_SHARE * 60.0
    assert not any("unmeasured" in n for n in p.notes)  # the capped choice carries nothing past the cache


def test_the_replay_fits_a_recorded_timing_point_into_the_step_cost(tiny, monkeypatch, tmp_path):  # noqa: F811
    """``benchmarks/plan_replay.py`` on the record of the timing point's plan (as ``bench plan`` writes it): the
    replayed wall time is the plan's; without the timing point it falls (the L3's rise unmeasured again)."""
    from warp_sph.benchmarks.plan_replay import replay

    _sysfs(tmp_path, monkeypatch, 35e6 / 2**20)
    monkeypatch.setattr(calibrate_module, "calibrate", CacheClock())
    p = plan(tiny, budget_s=60.0, solvers=["wcsph", "pbf"])
    rec = p.to_dict()
    record = {"kind": "plan", "status": "completed", "label": "tiny-60s", "date": "2026-11-26T00:00:00",
              "solver": p.chosen.solver, "plan": rec, "actual": {"wall_time": 30.0}, "wall_ratio": 1.0}
    assert replay(record)["replayed"] == pytest.approx(p.chosen.wall_time, rel=1e-9)
    rec["points"] = [q for q in rec["points"] if not q.get("timing_only")]
    assert replay(record)["replayed"] < 0.9 * p.chosen.wall_time
