"""DFSPH's density solve with Chebyshev weights (``dfsph.chebyshev``, Wang 2015): the weight sequence
against its closed-form limit, sweeps against a NumPy oracle, fewer sweeps than plain Jacobi to the
same target on a deep column, and the depth rule (``dfsph.chebyshev_min_layers``) that keeps shallow fluid on
plain Jacobi."""
import math

import numpy as np
import pytest

from small_scenes import small_tank, stage
from test_dfsph import prepared
from warp_sph.methods.solvers.dfsph_solve import CHEBYSHEV_DELAY, chebyshev_weight, fluid_layers
from warp_sph.run.simulation import Simulation


def test_weights_start_plain_and_tend_to_the_optimal_over_relaxation():
    """w = 1 for the first CHEBYSHEV_DELAY sweeps (and always for rho = 0), then 2 / (2 - rho^2), and the
    recurrence w <- 4 / (4 - rho^2 w) tends to its fixed point 2 / (1 + sqrt(1 - rho^2))."""
    for rho in (0.5, 0.9, 0.99):
        w, seq = 1.0, []
        for k in range(400):
            w = chebyshev_weight(k, rho, w)
            seq.append(w)
        assert seq[:CHEBYSHEV_DELAY] == [1.0] * CHEBYSHEV_DELAY
        assert seq[CHEBYSHEV_DELAY] == pytest.approx(2.0 / (2.0 - rho * rho))
        assert np.all(np.diff(seq[CHEBYSHEV_DELAY:]) <= 0)  # non-increasing towards the limit
        assert seq[-1] == pytest.approx(2.0 / (1.0 + math.sqrt(1.0 - rho * rho)), rel=1e-9)
        assert 1.0 < seq[-1] < 2.0
    assert all(chebyshev_weight(k, 0.0, 1.0) == 1.0 for k in range(10))


def test_chebyshev_sweeps_against_numpy(device):
    """Four sweeps of the density solve with rho = 0.9: P^J = max(0, P - omega f r / dt^2) from the
    oracle's operator, then P <- max(0, Q + w (P^J - Q)) with Q the P of the sweep before; the last
    sweep applied w != 1, so the solve returns the P its stop test checked (Q), not the extrapolation."""
    rho = 0.9
    sim, o = prepared(seed=1, device=device, dfsph={"chebyshev": rho, "chebyshev_min_layers": 0})
    m, s = sim.model, sim.solver
    dt = 2e-3
    stage(sim, "density").run(sim, dt)
    rng = np.random.default_rng(7)
    P = rng.uniform(0.0, 5.0, m.fluid_count)
    b = rng.normal(0.0, 0.01, m.fluid_count)
    sim.set_field("dfsph_pressure", P)
    sim.set_field("dfsph_density_source", b)
    sweeps = CHEBYSHEV_DELAY + 2
    it, _ = s.solve("dfsph_pressure", "dfsph_density_source", dt * dt, 0.0, sweeps, sweeps, False, chebyshev=True)
    assert it == sweeps
    omega = sim.scene.dfsph.relaxation
    q, p, w = P.copy(), P.copy(), 1.0
    for k in range(sweeps):
        r = b - dt * dt * o.delta(o.accel(p), boundary=False)
        pj = np.maximum(p - omega * o.f * r / (dt * dt), 0.0)
        w = chebyshev_weight(k, rho, w)
        new = np.maximum(q + w * (pj - q), 0.0) if w != 1.0 else pj
        q, p = p, new
    assert w > 1.0  # the weights were exercised, the last sweep's too
    got = sim.get_field("dfsph_pressure")
    np.testing.assert_allclose(got, q, rtol=2e-3, atol=2e-3 * np.abs(q).max())
    assert np.abs(p - q).max() > 0.1 * np.abs(q).max()  # the extrapolated P differs: the revert is seen
    assert (q == 0).any() and (q > 0).any()  # the clamp is exercised


def _column_sweeps(device, rho: float) -> tuple[float, float]:
    """Density sweeps per step and the last mean predicted over-density of a 24-layer column settling
    under gravity (0.3 s at a fixed 4 ms step)."""
    sc = small_tank("dfsph_column", particle_radius=0.025, container={"min": [0.0, 0.0, 0.0], "max": [0.3, 0.3, 1.4]},
                    fluid=[{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.25, 0.25, 1.2]}],
                    time={"fixed_dt": 0.004}, dfsph={"chebyshev": rho})
    sim = Simulation(sc, device=device)
    its, errs = [], []
    for _ in range(7):
        st = sim.advance_frame()
        assert st.outside == 0 and st.non_finite == 0
        its.append(st.solver["iterations"]["mean"])
        errs.append(st.solver["density_error"]["max"])
    assert max(errs) <= sc.dfsph.target_density_error  # every step met the target
    return float(np.mean(its)), float(np.mean(errs))


def test_deep_column_needs_fewer_sweeps_for_the_same_target(device):
    """The deeper the fluid, the slower plain Jacobi converges; Chebyshev weights (0.8, the value the
    documentation recommends) cut the sweeps a 24-layer column needs per step while every step still
    meets the density target."""
    plain, _ = _column_sweeps(device, 0.0)
    fast, _ = _column_sweeps(device, 0.8)
    assert plain > 6  # deep enough that plain Jacobi needs many sweeps
    assert fast < 0.75 * plain, (plain, fast)  # measured 7.7 -> 5.4


def test_accelerated_solve_is_bitwise_reproducible_over_thread_counts(monkeypatch, device):
    """The weights are computed by one thread from the fixed-order error sum (solve_control) and every
    sweep writes only its own particle: with dfsph.chebyshev = 0.8, 1, 2 or 3 CPU threads give bitwise the
    same state and sweep counts, and the solves ran past the plain sweeps (the weights were used)."""
    from test_dfsph import block_on_floor

    res = []
    for threads in ("1", "2", "3"):
        monkeypatch.setenv("WARP_SPH_CPU_THREADS", threads)
        sim = Simulation(block_on_floor(nx=16, ny=16, nz=12, material={"xsph": 0.05, "viscosity": 1e-3},
                                        dfsph={"chebyshev": 0.8}), device=device)
        assert sim.model.fluid_count >= 3 * 1024  # three ranges of the split launch
        figures = []
        for _ in range(3):
            sim.step(4e-3)
            s = sim.solver
            figures.append((s.last_iterations, s.last_density_error))
        res.append((sim.get_field("particle_x"), sim.get_field("particle_v"), figures))
    assert max(it for it, _ in res[0][2]) > CHEBYSHEV_DELAY
    for x, v, figures in res[1:]:
        assert np.array_equal(x, res[0][0]) and np.array_equal(v, res[0][1])
        assert figures == res[0][2]


def test_fluid_layers_counts_the_lattice_layers_along_gravity():
    """fluid_layers: a lattice of nz layers at spacing d reads nz along -g whatever the other extents, along
    the gravity's own axis when it is not z, and along the largest extent without gravity; no fluid: 0."""
    d = 0.05
    grid = np.stack(np.meshgrid(np.arange(8) * d, np.arange(3) * d, np.arange(5) * d, indexing="ij"), -1).reshape(-1, 3)
    grid = grid + np.random.default_rng(0).uniform(-0.01, 0.01, grid.shape) * d  # round-off of a settled lattice
    assert fluid_layers(grid, (0.0, 0.0, -9.81), d) == 5
    assert fluid_layers(grid, (-9.81, 0.0, 0.0), d) == 8
    assert fluid_layers(grid, (0.0, 0.0, 0.0), d) == 8
    assert fluid_layers(np.zeros((0, 3)), (0.0, 0.0, -9.81), d) == 0


def test_shallow_fluid_keeps_plain_jacobi_and_deep_fluid_gets_the_weights(device):
    """The default estimate (0.8) applies from dfsph.chebyshev_min_layers (10) layers: the 5-layer tank of
    tests/test_settle.py keeps plain Jacobi (at 0.8 its packing pass stays at 3.2e-3 m/s after 3000 steps
    instead of settling below 1.2e-3 m/s in 1372: test_settle fails), a 12-layer block gets the weights, and
    chebyshev_min_layers = 0 gives them to any depth."""
    from test_dfsph import block_on_floor
    from test_settle import tank

    shallow = Simulation(tank(1.2e-3), device=device).solver
    assert shallow.fluid_layers == 5 and shallow.chebyshev == 0.0
    assert shallow.config.chebyshev == 0.8 and shallow.config.chebyshev_min_layers == 10  # the defaults
    deep = Simulation(block_on_floor(nx=4, ny=4, nz=12), device=device).solver
    assert deep.fluid_layers == 12 and deep.chebyshev == 0.8
    forced = Simulation(tank(1.2e-3, dfsph={"chebyshev_min_layers": 0}), device=device).solver
    assert forced.chebyshev == 0.8
