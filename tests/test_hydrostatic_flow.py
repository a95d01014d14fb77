"""benchmarks/hydrostatic_flow.py (issue #31, the tank at rest's flow as a field): its measures against fields whose
answer is exact, and the tool on the coarse fcc case for a few frames."""
import numpy as np

from benchmarks.hydrostatic_flow import flow, lag_correlations, radial_velocity


def test_a_steady_field_correlates_one_and_noise_about_zero():
    rng = np.random.default_rng(5)
    field = rng.normal(size=(200, 3))
    steady = np.repeat(field[None], 10, axis=0)
    assert all(abs(c - 1.0) < 1e-12 for c in lag_correlations(steady, (1, 3, 9)).values())
    noise = rng.normal(size=(10, 200, 3))
    assert all(abs(c) < 0.2 for c in lag_correlations(noise, (1, 3)).values())
    flipping = steady * np.where(np.arange(10) % 2 == 0, 1.0, -1.0)[:, None, None]  # v, -v, v, ...
    got = lag_correlations(flipping, (1, 2, 10))
    assert abs(got[1] + 1.0) < 1e-12 and abs(got[2] - 1.0) < 1e-12 and 10 not in got


def test_radial_velocity_of_a_source_and_a_vortex():
    """v = u (x - a) / |x - a| horizontally (a source about the axis a) reads u; a vortex about a reads 0; vertical
    velocity does not count."""
    rng = np.random.default_rng(6)
    a = np.array([0.3, 0.2])
    x = np.column_stack([rng.uniform(0, 0.6, 50), rng.uniform(0, 0.6, 50), rng.uniform(0, 0.5, 50)])
    r = x[:, :2] - a
    e = r / np.linalg.norm(r, axis=1)[:, None]
    source = np.column_stack([2e-3 * e, np.full(50, 5e-3)])
    vortex = np.column_stack([-e[:, 1], e[:, 0], np.zeros(50)]) * 3e-3
    np.testing.assert_allclose(radial_velocity(x, source, a), 2e-3, rtol=1e-12)
    np.testing.assert_allclose(radial_velocity(x, vortex, a), 0.0, atol=1e-15)


def test_the_tool_on_the_fcc_case():
    """Six frames of DFSPH on the coarse fcc tank: 13 start planes, the statistics over the last three, the planes'
    pressure at the end below 2 g (h - z) at depth and zero-ish at the top."""
    out = flow("dfsph", 0.025, 0.25, [], window=0.13)
    assert len(out["frames"]) == 6 and out["field"]["frames"] == 3
    assert len(out["planes"]) == 13
    deep = out["planes"][2]
    assert 0.3 * deep["g_depth"] < deep["p_over_rho0"] < 2.0 * deep["g_depth"]
    assert out["planes"][-1]["p_over_rho0"] < 0.5 * out["planes"][-1]["g_depth"] + 0.1
