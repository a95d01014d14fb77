"""benchmarks/fixed_step_profile.py (issue #32): the per-stage CPU profile of a fixed WCSPH / PBF step adds up, and its
counts (list searches, PBF iterations and density passes) agree with the solvers' own counters."""
import pytest

from warp_sph.benchmarks import fixed_step_profile as P


def _check_stages(r):
    stages = r["stages"]
    total = sum(v["cpu_ms_per_step"] for v in stages.values())  # "outside the steps" closes the sum
    assert total == pytest.approx(r["cpu_ms_per_step"], rel=1e-9, abs=1e-9)
    assert all(v["cpu_ms_per_step"] >= 0.0 for name, v in stages.items() if name != "outside the steps")
    assert r["kernels"]["steps"] > 0 and r["kernels"]["kernel_runs_per_step"] > 0


def test_wcsph_profile_splits_search_and_kept_list_steps():
    r = P.profile_solver("wcsph", 0.1, 0.0, 1, P.GOAL_SET)
    assert r["steps"] == round((1.0 / 24) / r["dt"])  # the bench's fixed step, a whole number per frame
    st = r["stages"]
    for name in ("pressure", "forces", "integrate"):
        assert st[name]["calls_per_step"] == 1.0
    searched = st.get("density (search)", {}).get("calls_per_step", 0.0)
    kept = st.get("density (kept lists)", {}).get("calls_per_step", 0.0)
    assert searched + kept == pytest.approx(1.0)
    assert searched > 0.0  # the first step after the start searches
    assert r["searches_per_step"] == pytest.approx(searched)  # KeptLists.builds agrees with the stage split
    assert r["lists"]["fluid_per_particle"] > 0
    _check_stages(r)


def test_pbf_profile_counts_iterations_and_density_passes():
    r = P.profile_solver("pbf", 0.1, 0.0, 1, ("pbf.min_iterations=3",))
    its = r["iterations"]
    assert sum(its.values()) == r["steps"]
    assert min(its) >= 3  # the override reached the solver
    # each iteration after the first reads a density pass (the first is the "density" stage's fused search)
    solve_passes = sum((k - 1) * n for k, n in its.items()) / r["steps"]
    assert r["density_passes_per_step"] >= solve_passes
    assert r["stages"]["solve"]["calls_per_step"] == 1.0
    _check_stages(r)
