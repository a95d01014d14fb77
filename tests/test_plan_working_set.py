"""The run's arrays against the CPU's last-level cache (``warp_sph.run.working_set``) and the plan's note where the step's
cost is carried past that cache with no calibration point there (docs/plan-model.md, item 12)."""
from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from warp_sph.plan import cost_notes
from warp_sph.plan.advisor import fit_models
from warp_sph.run.working_set import array_bytes, last_level_cache_bytes

from test_plan_models import tiny  # noqa: F401  (the fixture)
from test_plan_spike import TARGET, _cal, _points

MIB = 2**20


def test_the_last_level_cache_is_the_largest_level_listed(tmp_path):
    for name, level, size in (("index0", 1, "48K"), ("index2", 2, "1024K"), ("index3", 3, "32768K")):
        (tmp_path / name).mkdir()
        (tmp_path / name / "level").write_text(f"{level}\n")
        (tmp_path / name / "size").write_text(f"{size}\n")
    assert last_level_cache_bytes(tmp_path) == 32 * MIB
    assert last_level_cache_bytes(tmp_path / "none") == 0  # not listed (another OS, a container without sysfs)


def test_array_bytes_counts_each_array_once():
    """NumPy oracle: the arrays' nbytes, an array held twice counted once, through dicts, lists and Warp structs."""
    a = wp.zeros(100, dtype=wp.vec3, device="cpu")
    b = wp.zeros((10, 64), dtype=wp.int32, device="cpu")
    c = wp.zeros(7, dtype=float, device="cpu")
    holder = {"x": a, "lists": [b, a], "nested": {"c": c, "again": (b,)}}
    expected = sum(np.asarray(x.numpy()).nbytes for x in (a, b, c))
    assert array_bytes(holder) == expected == 100 * 12 + 640 * 4 + 7 * 4


def _sized(bytes_per_fluid: float, bytes_per_wall: float):
    """The spike test's points (CPU, above the thread split) with their arrays' bytes linear in the counts."""
    pts = _points()
    for p in pts:
        p.array_bytes = int(bytes_per_fluid * p.fluid + bytes_per_wall * p.boundary)
    return pts


def _chosen():
    return type("C", (), {"fluid_particles": TARGET[0], "boundary_particles": TARGET[1], "particle_radius": 0.0075})()


def test_a_plan_past_the_cache_without_a_point_there_says_so(tiny):  # noqa: F811
    """2,000 B per fluid and 100 B per wall particle: the largest point (2,352 + 2,178) takes 4.9 MB, the target
    (11,767 + 5,200) 24.0 MB. A 16 MiB cache lies between: the note gives both figures. A cache above the target, or
    one a calibration point already passed, or none (a GPU): no note. The prediction itself is unchanged."""
    pts = _sized(2000.0, 100.0)
    cal = _cal(pts)
    cal.cache_bytes = 16 * MIB
    m = fit_models(cal, "wcsph", tiny)
    need = 2000.0 * TARGET[0] + 100.0 * TARGET[1]
    assert m.array_bytes(*TARGET) == pytest.approx(need, rel=1e-6)
    assert m.array_bytes_calibrated == max(p.array_bytes for p in pts) < m.cache_bytes
    assert m.past_cache(*TARGET) == pytest.approx(need, rel=1e-6)
    (note,) = [n for n in cost_notes(m, _chosen()) if "last-level cache" in n]
    assert "(16 MiB)" in note and f"about {need / MIB:.3g} MiB" in note and \
        f"more than {m.array_bytes_calibrated / MIB:.3g} MiB" in note
    plain = fit_models(_cal(pts), "wcsph", tiny)  # no cache listed
    assert plain.past_cache(*TARGET) is None and plain.step_cost(*TARGET) == m.step_cost(*TARGET)
    for cache in (64 * MIB, 4 * MIB):  # beyond the target; below the largest calibration point's arrays
        cal.cache_bytes = cache
        assert fit_models(cal, "wcsph", tiny).past_cache(*TARGET) is None
    assert not any("last-level cache" in n for n in cost_notes(fit_models(_cal(_points()), "wcsph", tiny), _chosen()))


def test_the_bench_detail_keeps_the_arrays_against_the_cache(tiny):  # noqa: F811
    """``warp-sph bench plan``'s detail: the plan's fitted bytes at the chosen counts (the linear law's, NumPy oracle),
    the run's own (run.json ``array_bytes``), the most any calibration run took and the cache."""
    from types import SimpleNamespace

    from warp_sph.benchmarks.plan import run_detail
    from warp_sph.plan.advisor import point_summary, predict

    pts = _sized(2000.0, 100.0)
    cal = _cal(pts)
    cal.cache_bytes = 16 * MIB
    m = fit_models(cal, "wcsph", tiny)
    c = predict(tiny, m, 0.008)
    p = SimpleNamespace(chosen=c, models={"wcsph": m}, points=[point_summary(q) for q in pts])
    frames = [{"frame": 1, "density_error_mean": 0.0}] + [{"frame": k, "density_error_mean": 1e-3, "steps": 9}
                                                          for k in (2, 3, 4)]
    info = {"frames": frames, "sim_time_per_step_ms": 5.0, "fluid_particles": c.fluid_particles,
            "array_bytes": 123456789}
    got = run_detail(p, info)["array_bytes"]
    assert got["predicted"] == pytest.approx(2000.0 * c.fluid_particles + 100.0 * c.boundary_particles, rel=1e-6)
    assert got["actual"] == 123456789 and got["cache"] == 16 * MIB
    assert got["largest_calibrated"] == max(q.array_bytes for q in pts)


def test_read_bytes_counts_the_rows_used_entries():
    """NumPy oracle: a neighbour list's rows count at min(count, capacity) entries, a 1-D row array (DFSPH's pair rows)
    likewise, arrays of one entry per particle whole; array_bytes counts the allocation."""
    from warp_sph.kernels.neighbors import NeighborList
    from warp_sph.run.working_set import read_bytes

    counts = np.array([3, 0, 70, 5], dtype=np.int32)  # 70 > the capacity 64: 64 stored
    nl = NeighborList()
    nl.count = wp.array(counts, device="cpu")
    nl.index = wp.zeros((4, 64), dtype=wp.int32, device="cpu")
    nl.order = wp.zeros(4, dtype=wp.int32, device="cpu")
    from warp_sph.kernels.dfsph_search import DfsphPairs

    pairs = DfsphPairs()  # 1-D rows of n x capacity entries
    pairs.count = wp.array(np.minimum(counts, 64), device="cpu")
    pairs.offset = wp.zeros(4, dtype=wp.int32, device="cpu")
    pairs.index = wp.zeros(4 * 64, dtype=wp.int32, device="cpu")
    pairs.gradient = wp.zeros(4 * 64, dtype=wp.vec3, device="cpu")
    used = int(np.minimum(counts, 64).sum())
    holder = {"lists": nl, "pairs": pairs, "x": wp.zeros(4, dtype=wp.vec3, device="cpu")}
    per_row = 4 + 4 + 12  # list index, pair index, pair gradient
    small = 4 * 4 + 4 * 4 + 4 * 4 + 4 * 4 + 4 * 12  # the counts, order, offset and x
    assert array_bytes(holder) == 4 * 64 * per_row + small
    assert read_bytes(holder) == used * per_row + small
    assert read_bytes({"x": holder["x"]}) == array_bytes({"x": holder["x"]})  # no rows: the same
