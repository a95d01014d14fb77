"""Position-based fluids (report section 4.5): stage oracles, the rest-lattice denominator, and the
report's failure case (an over-dense block that exploded) plus whole-scene invariants."""
import math

import numpy as np
import pytest

from sph_oracle import SUPPORT, W, grad_W
from small_scenes import small_tank, stage
from warp_sph.methods.solvers.pbf import rest_denominator
from warp_sph.methods.solvers.pbf_lattice import auto_epsilon
from warp_sph.scene import load_scene
from warp_sph.run.simulation import Simulation
from warp_sph.core.smoothing import LATTICE_LAYER, get_smoothing_kernel, lattice_offsets


def pbf_scene(**kw):
    return small_tank("pbf_test", **{"solver": "pbf", **kw})



def oracle_denominator(kernel, h, d, volume):
    g = grad_W(kernel, lattice_offsets(d, SUPPORT[kernel] * h), h) * volume
    return float(g.sum(0) @ g.sum(0) + (g * g).sum())


# --- the lambda denominator (physics notes 4.4) ----------------------------------------------
@pytest.mark.parametrize("h_per_d, expected", [(1.0, 0.425), (1.3, 0.143), (2.0, 0.017)])
def test_rest_denominator_matches_unit_free_table(h_per_d, expected):
    d, rho0 = 0.02, 1000.0
    got = rest_denominator("cubic", h_per_d * d, d, rho0 * d**3, rho0) * d * d
    assert got == pytest.approx(expected, abs=1.5e-3)


@pytest.mark.parametrize("kernel", ["cubic", "quintic", "quadric"])
def test_rest_denominator_matches_numpy_oracle_and_solver(kernel, device):
    sim = Simulation(pbf_scene(smoothing_kernel=kernel), device=device)
    m = sim.model
    volume = m.particle_mass / m.rest_density
    ref = oracle_denominator(kernel, m.smoothing_length, m.spacing, volume)
    assert sim.solver.rest_denominator == pytest.approx(ref, rel=1e-4)
    # units: d^2 D0 is O(0.1-1) for support 2d in any unit system, never 1e-3 or 1e-6 (report 4.5)
    assert 0.2 < ref * m.spacing**2 < 0.6
    # pbf.relaxation absent: eps from the lattice's Jacobi symbol (test_default_relaxation_damps_every_wave...)
    assert sim.scene.pbf.relaxation is None
    assert sim.solver.epsilon == pytest.approx(auto_epsilon(kernel, m.smoothing_length, m.spacing, m.particle_mass,
                                                            m.rest_density), rel=1e-6)
    assert sim.solver.epsilon > 0.5 * ref


def test_fcc_start_uses_the_fcc_denominator_and_an_explicit_relaxation_keeps_its_meaning(device):
    """On an fcc start D0 is the fcc lattice's sum (1.72 times the cubic one's at the same mass, issue #31), and
    an explicit pbf.relaxation still means eps = relaxation * D0."""
    scene = pbf_scene(fluid=[{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.6, 0.5, 0.5], "lattice": "fcc"}],
                      pbf={"relaxation": 0.3})
    sim = Simulation(scene, device=device)
    m = sim.model
    volume = m.particle_mass / m.rest_density
    g = grad_W("cubic", lattice_offsets(m.spacing, SUPPORT["cubic"] * m.smoothing_length, "fcc"), m.smoothing_length)
    fcc = float(((g * volume) ** 2).sum())
    assert sim.solver.rest_denominator == pytest.approx(fcc, rel=1e-4)
    assert sim.solver.rest_denominator == pytest.approx(1.72 * oracle_denominator("cubic", m.smoothing_length,
                                                                                  m.spacing, volume), rel=5e-3)
    assert sim.solver.epsilon == pytest.approx(0.3 * fcc, rel=1e-4)


def periodic_jacobi_modes(kernel, lattice, d=0.05, rho0=1000.0, n=8):
    """Brute force (NumPy, no solver code): the eigenvalues of J J^T on a periodic n^3 lattice (cubic, or fcc as
    square layers d / sqrt 2 apart, shifted by (d/2, d/2)), J = dC/dx (C_i = V sum_j W_ij - 1) assembled pair by
    pair, and its diagonal D. One PBF Jacobi iteration (lambda = -C / (D + eps), dx = J^T lambda, eq. 18-19) is
    C <- (1 - J J^T / (D + eps)) C: a mode of eigenvalue A is multiplied by 1 - A / (D + eps). Also returns
    (h, m): the smoothing length and calibrated mass [kg]."""
    h = get_smoothing_kernel(kernel).default_h_per_spacing * d
    support = SUPPORT[kernel] * h
    c, s = LATTICE_LAYER[lattice], (0.0 if lattice == "cubic" else 0.5)
    k = int(np.ceil(support / (c * d))) + 1
    r = np.arange(-k, k + 1)
    ijl = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
    pos = np.stack([ijl[:, 0] + s * ijl[:, 2], ijl[:, 1] + s * ijl[:, 2], c * ijl[:, 2]], axis=1) * d
    near = np.linalg.norm(pos, axis=1) < support
    volume = 1.0 / float(W(kernel, np.linalg.norm(pos[near], axis=1), h).sum())  # calibrated: rho = rho0
    keep = near & (np.linalg.norm(pos, axis=1) > 0)
    steps, offsets = ijl[keep], pos[keep]
    assert n >= 2 * np.abs(steps).max() + 1                 # no two offsets land on one particle
    g = grad_W(kernel, -offsets, h) * volume                # V grad_i W_ij, x_i - x_j = -offset
    cells = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    index = lambda a: (a[:, 0] % n) * n * n + (a[:, 1] % n) * n + a[:, 2] % n
    J = np.zeros((n ** 3, n ** 3, 3))
    for o, gj in zip(steps, g):                             # dC_i = sum_j V grad_i W_ij . (dx_i - dx_j)
        i, j = index(cells), index(cells + o)
        J[i, i] += gj
        J[i, j] -= gj
    J = J.reshape(n ** 3, -1)
    JJ = J @ J.T
    D = float(JJ[0, 0])
    assert np.allclose(np.diag(JJ), D)
    return np.linalg.eigvalsh(JJ), D, h, volume * rho0


@pytest.mark.parametrize("kernel, lattice", [("cubic", "cubic"), ("cubic", "fcc"), ("quintic", "fcc")])
def test_default_relaxation_damps_every_wave_of_the_jacobi_solve(kernel, lattice):
    """Issue #31: with the default eps = 3/4 A_max - D0 (``auto_epsilon``) no mode of the linearised Jacobi
    iteration grows, nor flips beyond -1/3 (the smoother's bound, A <= A_max); the old default eps = 1e-4 D0
    multiplied the worst wave by about -1.8 (cubic) / -2.3 (fcc) per iteration with the cubic kernel."""
    modes, D, h, mass = periodic_jacobi_modes(kernel, lattice)
    assert D == pytest.approx(rest_denominator(kernel, h, 0.05, mass, 1000.0, lattice), rel=1e-6)  # the start's D0
    factors = 1.0 - modes / (D + auto_epsilon(kernel, h, 0.05, mass, 1000.0, lattice))
    assert factors.max() <= 1.0 + 1e-9 and factors.min() > -1.0
    assert factors.min() >= -1.0 / 3.0 - 1e-6
    if kernel == "cubic":  # the quintic kernel's worst wave (cubic lattice: -1.17) falls between a small box's waves
        assert (1.0 - modes / (D + 1e-4 * D)).min() < -1.0


# --- stages against NumPy --------------------------------------------------------------------
def oracle_density_lambda(sim, x):
    m = sim.model
    k, h = m.smoothing.name, m.smoothing_length
    V = m.particle_mass / m.rest_density
    xij = x[:, None] - x[None]
    r = np.linalg.norm(xij, axis=2)
    ratio = V * W(k, r, h).sum(1)
    g = V * grad_W(k, xij, h)
    grad_i = g.sum(1)
    xb = m.boundary_x.numpy().astype(np.float64)
    vb = m.boundary_volume.numpy().astype(np.float64)
    xib = x[:, None] - xb[None]
    ratio += (W(k, np.linalg.norm(xib, axis=2), h) * vb[None]).sum(1)
    gb = grad_W(k, xib, h) * vb[None, :, None]
    grad_i += gb.sum(1)
    c = np.maximum(ratio - 1.0, 0.0)
    lam = -c / ((grad_i**2).sum(1) + (g**2).sum((1, 2)) + sim.solver.epsilon)
    return m.rest_density * ratio, lam, c, g, gb


def prepared(kernel="cubic", tensile=False, seed=0, device=None):
    """A compressed, jittered block with x* = x, neighbours and density + lambda computed."""
    sim = Simulation(pbf_scene(smoothing_kernel=kernel, pbf={"tensile_correction": tensile}), device=device)
    rng = np.random.default_rng(seed)
    m = sim.model
    x = m.to_local(sim.get_field("particle_x")).astype(np.float64)
    lo = x.min(0)
    x = lo + 0.92 * (x - lo) + rng.uniform(-0.1, 0.1, x.shape) * m.spacing  # 8 % compressed, towards the floor
    sim.set_field("particle_x", m.to_world(x))
    sim.solver.restore_arrays({})  # x* = x
    stage(sim, "neighbors").run(sim, 0.0)
    stage(sim, "density").run(sim, 0.0)
    return sim, m.to_local(sim.get_field("particle_x")).astype(np.float64)


@pytest.mark.parametrize("kernel", ["cubic", "quintic", "quadric"])
def test_density_and_lambda_stage(kernel, device):
    sim, x = prepared(kernel, device=device)
    rho, lam, c, _, _ = oracle_density_lambda(sim, x)
    np.testing.assert_allclose(sim.get_field("particle_density"), rho, rtol=2e-4)
    got = sim.get_field("particle_lambda")
    np.testing.assert_allclose(got, lam, rtol=2e-3, atol=2e-3 * np.abs(lam).max())
    assert (c > 0).sum() > 20 and (c == 0).any()  # constraint clamp exercised both ways
    err = sim.solver.last_error_sum
    assert err == pytest.approx(c.sum(), rel=1e-3)


@pytest.mark.parametrize("tensile", [False, True])
def test_position_correction_stage(tensile, device):
    sim, x = prepared(tensile=tensile, seed=1, device=device)
    m = sim.model
    p = sim.scene.pbf
    sim.solver.max_step = 1e30  # the trust region off: compare the raw eq. 18
    lam = sim.get_field("particle_lambda").astype(np.float64)
    _, _, _, g, gb = oracle_density_lambda(sim, x)
    s = lam[:, None] + lam[None]
    if tensile:
        k, h = m.smoothing.name, m.smoothing_length
        r = np.linalg.norm(x[:, None] - x[None], axis=2)
        wq = W(k, p.tensile_dq * h, h)
        s = s - p.tensile_k * (W(k, r, h) / wq) ** p.tensile_n / sim.solver.rest_denominator
    dx = (s[:, :, None] * g).sum(1)
    dx_b = lam[:, None] * gb.sum(1)
    dx += dx_b
    sim.fields["boundary_force"].zero_()
    dt = 2e-3
    sim.solver.correction(dt)
    got = sim.get_field("position_correction")
    scale = np.abs(dx).max()
    np.testing.assert_allclose(got, dx, rtol=2e-3, atol=2e-3 * scale)
    np.testing.assert_allclose(sim.get_field("boundary_force"), m.particle_mass * dx_b / dt**2,
                               rtol=2e-3, atol=2e-3 * m.particle_mass * np.abs(dx_b).max() / dt**2)
    assert np.abs(dx_b).max() > 0.05 * scale  # the wall term is exercised
    np.testing.assert_allclose(m.to_local(sim.get_field("particle_x")) + 0 * x, x, atol=1e-6)  # x untouched
    np.testing.assert_allclose(sim.fields["predicted_x"].numpy(), x + got, atol=1e-5)
    assert sim.solver.last_iteration_correction == pytest.approx(np.linalg.norm(dx, axis=1).max(), rel=2e-3)


def test_graph_and_time_step(device):
    sim = Simulation(pbf_scene(material={"xsph": 0.05, "viscosity": 1e-3, "boundary_friction": 0.2},
                               pbf={"vorticity": 0.01}), device=device)
    assert sim.graph.names() == ["stabilize", "predict", "neighbors", "density", "solve", "update", "vorticity",
                                 "viscosity", "apply_forces", "xsph"]
    bare = Simulation(pbf_scene(container=False, gravity=[0.0, 0.0, 0.0]), device=device)
    assert bare.graph.names() == ["stabilize", "predict", "neighbors", "density", "solve", "update"]
    m = sim.model
    dt = min(b.seconds for b in sim.time_step_bounds(2.0))
    solve = m.spacing * np.sqrt(2 * sim.solver.kappa * sim.scene.pbf.target_iterations
                                * sim.scene.pbf.target_density_error / (9.81 * sim.solver.fluid_depth))
    assert dt == pytest.approx(min(0.4 * m.spacing / (2.0 + 9.81 / 24), 0.125 * (m.support_radius / 2) ** 2 / 1e-3,
                                   solve))
    for _ in range(3):  # every optional stage runs
        sim.step(2e-3)
    assert np.isfinite(sim.get_field("particle_v")).all()


# --- the report's failure case --------------------------------------------------------------
def test_block_compressed_20_percent_against_the_floor_does_not_explode(device):
    """Report 4.5: particles pushed over rest density made the solver explode. A block sampled at
    0.8 d (rho ~ 1.95 rho0) on the floor: the start-of-step error is projected out of x without
    becoming velocity (pre-stabilisation), no correction reaches the particle radius after that, no
    particle leaves the box and speeds stay at dam-break level."""
    sc = pbf_scene(particle_radius=0.025, container={"min": [0, 0, 0], "max": [0.5, 0.5, 0.5]},
                   fluid=[{"min": [0, 0, 0], "max": [0.25, 0.25, 0.25], "spacing_scale": 0.8}])
    sim = Simulation(sc, device=device)
    m = sim.model
    rho0 = sim.get_field("particle_density") / m.rest_density - 1
    assert np.maximum(rho0, 0).mean() > 0.5  # it really starts ~ 1.7-1.95 rho0
    dt = 4e-3
    sim.solver.trace = True
    sim.step(dt)
    assert sim.solver.last_stabilization > 0
    v = np.linalg.norm(sim.get_field("particle_v"), axis=1)
    assert v.max() < 0.5  # the compression did not turn into velocity (it exploded at ~50 m/s without)
    largest = []
    for _ in range(25):
        sim.step(dt)
        largest += [c for _, c in sim.solver.last_trace]
        assert sim.solver.last_density_error <= sc.pbf.target_density_error
    assert max(largest) < m.particle_radius
    x = m.to_local(sim.get_field("particle_x"))
    assert np.isfinite(x).all()
    assert (x > m.container_lo).all() and (x < m.container_hi).all()
    assert np.linalg.norm(sim.get_field("particle_v"), axis=1).max() < math.sqrt(2 * 9.81 * 0.5)


# --- whole scenes ---------------------------------------------------------------------------
def test_hydrostatic_tank_error_and_bottom_force(device):
    sc = load_scene("hydrostatic")
    sc.solver = "pbf"
    sim = Simulation(sc, device=device)
    m = sim.model
    weight = m.particle_mass * m.fluid_count * 9.81
    target = sc.pbf.target_density_error
    for _ in range(2):
        st = sim.advance_frame()
        assert st.solver["density_error"]["max"] <= target and st.outside == 0
    dt = sim.frame_dt / st.steps
    forces = []
    for _ in range(2 * st.steps):
        sim.step(dt)
        assert sim.solver.last_density_error <= target
        forces.append(sim.get_field("boundary_force")[:, 2].sum())
    assert np.mean(forces) == pytest.approx(weight, rel=0.03)
    x = m.to_local(sim.get_field("particle_x"))
    assert (x > m.container_lo).all() and (x < m.container_hi).all()


def test_dam_break_coarse(device):
    sc = load_scene("dam_break")
    sc.solver = "pbf"
    sc.particle_radius = 0.05
    sim = Simulation(sc, device=device)
    for _ in range(4):
        st = sim.advance_frame()
        assert st.solver["density_error"]["max"] <= sc.pbf.target_density_error
        assert st.outside == 0 and st.non_finite == 0
        assert st.solver["max_correction"]["max"] < 0.5 * sim.model.particle_radius  # trust region idle
    assert 0.5 < st.max_speed < 1.5 * math.sqrt(2 * 9.81 * 1.0)


def with_solver(sim, **options):
    """sim with a PBF solver of these options (a new step graph)."""
    sim.set_solver("pbf", **options)
    return sim


def test_neighbor_modes_agree(device):
    """Neighbour lists (margin: built once per step; rebuild: before every density pass) and the
    hash-grid reference (rebuild, margin) give the same motion."""
    res = []
    for lists, mode in ((True, "margin"), (True, "rebuild"), (False, "rebuild"), (False, "margin")):
        sim = with_solver(Simulation(pbf_scene(material={"xsph": 0.05, "viscosity": 1e-3, "boundary_friction": 0.2},
                                               pbf={"vorticity": 0.01}), device=device),
                          neighbor_mode=mode, lists=lists)
        for _ in range(5):
            sim.step(4e-3)
        res.append(sim.get_field("particle_x"))
    for other in res[1:]:
        np.testing.assert_allclose(res[0], other, atol=1e-4 * 0.1)


def test_lists_margin_rebuilds_only_on_drift(device):
    """The lists are searched with H_s + margin and rebuilt when x* drifted more than margin / 2:
    a tiny margin rebuilds before (nearly) every density pass of an iteration after the first, the
    default one about once per step, and both agree."""
    res, builds = [], []
    for margin in (0.2, 1e-4):
        sim = with_solver(Simulation(block_on_floor(nx=8, ny=8, nz=6), device=device), margin=margin)
        sim.solver.last_drift = 0.0
        start = sim.solver.grid_builds
        iterations = 0
        for _ in range(5):
            sim.step(4e-3)
            iterations += sim.solver.last_iterations
        builds.append((sim.solver.grid_builds - start, iterations))
        res.append(sim.get_field("particle_x"))
    (wide, it_wide), (narrow, it_narrow) = builds
    assert wide == 5 and narrow > 5 + 0.5 * (it_narrow - 5)
    np.testing.assert_allclose(res[0], res[1], atol=1e-6)


def test_bitwise_reproducible_over_thread_counts(monkeypatch, device):
    """Kernels split over CPU threads write only their own particles, and the error sum and the
    maxima are reduced in a fixed order: 1, 2 or 3 threads give bitwise the same state."""
    res = []
    for threads in ("1", "2", "3"):
        monkeypatch.setenv("WARP_SPH_CPU_THREADS", threads)
        sim = Simulation(block_on_floor(nx=16, ny=16, nz=12, material={"xsph": 0.05, "viscosity": 1e-3},
                                        pbf={"vorticity": 0.01}), device=device)
        assert sim.model.fluid_count >= 3 * 1024  # three ranges of the split launch
        errors = []
        for _ in range(3):
            sim.step(4e-3)
            errors.append((sim.solver.last_density_error, sim.solver.last_max_correction, sim.solver.last_iterations))
        res.append((sim.get_field("particle_x"), sim.get_field("particle_v"), errors))
    for x, v, errors in res[1:]:
        assert np.array_equal(x, res[0][0]) and np.array_equal(v, res[0][1])
        assert errors == res[0][2]


def block_on_floor(kernel="cubic", nx=6, ny=6, nz=4, **kw):
    r = 0.025
    d = 2 * r
    gap = 1.1 * d
    size = [nx * d + 2 * gap - d, ny * d + 2 * gap - d, 1.0]
    return pbf_scene(particle_radius=r, smoothing_kernel=kernel, container={"min": [0, 0, 0], "max": size},
                     fluid=[{"min": [0, 0, 0], "max": [size[0], size[1], nz * d + gap]}], **kw)


@pytest.mark.parametrize("kernel", ["cubic", "quintic", "quadric"])
def test_same_start_no_initial_explosion(kernel, device):
    sim = Simulation(block_on_floor(kernel), device=device)
    rho = sim.get_field("particle_density") / sim.model.rest_density - 1
    assert rho.max() < 0.02  # the wall gap is computed per kernel
    for _ in range(10):
        sim.step(4e-3)
    # Free fall over these 40 ms would give 0.39 m/s; the report's kernel swap exploded at m/s.
    # Measured max speeds: cubic 0.21, quadric 0.23, quintic 0.45 m/s, all at the block's bottom
    # corners and edges (Jacobi: the bulk's lambda_j push a wall-corner particle before its own
    # wall term answers), so "small" here means below the 0.39 m/s scale, not zero. Medians: cubic
    # 0.12, quadric 0.15, quintic 0.23 m/s: the quintic block sinks into its start (mean v_z -0.17 m/s),
    # caught by two iterations per step whose long-wave correction is D0 / (D0 + eps) = 0.61 of a full
    # one at the default relaxation (issue #31; at relaxation 1e-4: median 0.19, mean v_z -0.13 m/s).
    v = np.linalg.norm(sim.get_field("particle_v"), axis=1)
    assert v.max() < 0.6 and np.median(v) < 0.25


def test_block_at_rest_stays_at_rest_for_ten_thousand_steps(device):
    """A 6x6x4 block on the floor between walls (cubic, dt = 2 ms) settles, then holds max |v| below
    1e-3 m/s for 10^4 steps (issue 4). Plain Jacobi (relaxation 1e-4 D0, the old default) overshoots:
    on a disordered packing every step injects a little energy and the block keeps creeping at
    ~1e-2 m/s (measured, even with 30 iterations per step). Under-relaxing with eps = 5 D0 and a
    little viscosity (2e-3 m^2/s) lets it settle. Settling is a sequence of rearrangements whose
    end varies with the block (measured: 8,000-18,000 steps for 5x5x4, 6x6x4, 6x6x5 blocks and the
    three kernels), so the test settles until a 1,000-step window stays below 1e-3 m/s."""
    sim = Simulation(block_on_floor(material={"xsph": 0.1, "viscosity": 2e-3}, pbf={"relaxation": 5.0}), device=device)

    def window_max(steps):
        largest = 0.0
        for k in range(steps):
            sim.step(2e-3)
            if k % 10 == 0:
                largest = max(largest, float(np.linalg.norm(sim.get_field("particle_v"), axis=1).max()))
        return largest

    settle = 0
    while window_max(1000) >= 1e-3:
        settle += 1000
        assert settle < 20_000, "the block did not settle within 20,000 steps"
    x_settled = sim.get_field("particle_x").copy()
    assert window_max(10_000) < 1e-3
    # creep: 1e-3 m/s over the 20 s would be 2 cm = 0.4 d; measured 6.7 mm = 0.13 d, the largest
    # single-particle displacement (surface particles still slide slowly, at ~3e-4 m/s on average)
    moved = np.linalg.norm(sim.get_field("particle_x") - x_settled, axis=1).max()
    assert moved < 0.2 * sim.model.spacing
    assert sim.solver.last_density_error <= sim.scene.pbf.target_density_error
    x = sim.model.to_local(sim.get_field("particle_x"))
    assert (x > sim.model.container_lo).all() and (x < sim.model.container_hi).all()
