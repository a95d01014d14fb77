"""WCSPH's kept neighbour lists (``wcsph.search_skin``, ``warp_sph/methods/solvers/wcsph_lists.py``): the lists
are searched on a fraction of the steps, the density and the pair cache the forces read match a brute-force
NumPy oracle on steps that reused the lists, the run agrees with the per-step search (skin 0) to rounding, and
the split over CPU threads changes nothing."""
import numpy as np
import pytest

from small_scenes import small_tank
from warp_sph.core.smoothing import evaluate
from warp_sph.run.simulation import Simulation


def falling_block(skin: float, **kw):
    """A block falling into a tank at WCSPH's acoustic step (some hundred particles, walls on every side)."""
    return small_tank("wcsph_skin", solver="wcsph", wcsph={"search_skin": skin}, particle_radius=0.03,
                      fluid=[{"shape": "box", "min": [0.0, 0.0, 0.1], "max": [0.4, 0.3, 0.5]}], **kw)


def oracle(sim, x):
    """rho_i = m sum_j W_ij + rho0 sum_b V_b W_ib at positions x over every particle closer than H_s (brute
    force), and the fluid pairs (i, j != i) closer than H_s with grad_i W_ij."""
    m = sim.model
    x = x.astype(np.float64)
    bx = m.boundary_x.numpy().astype(np.float64)
    vb = m.boundary_volume.numpy().astype(np.float64)
    H = m.support_radius
    d = x[:, None, :] - x[None, :, :]
    r = np.linalg.norm(d, axis=2)
    near = r < H
    w, g = evaluate(m.smoothing.name, d[near], m.smoothing_length)
    wf = np.zeros(r.shape)
    wf[near] = w
    db = x[:, None, :] - bx[None, :, :]
    rb = np.linalg.norm(db, axis=2)
    nb = rb < H
    wbv, _ = evaluate(m.smoothing.name, db[nb], m.smoothing_length)
    wb = np.zeros(rb.shape)
    wb[nb] = wbv
    rho = m.particle_mass * wf.sum(axis=1) + m.rest_density * (wb * vb[None, :]).sum(axis=1)
    grads = {}
    ii, jj = np.nonzero(near)
    for (i, j), gij in zip(zip(ii, jj), g):
        if i != j:
            grads[(int(i), int(j))] = gij
    return rho, grads


def check_step(sim, kept, band: float = 0.0):
    """One step: its density and pair cache against the oracle at the positions its density stage read. band: pairs
    within band * H_s of H_s may be on either side (a block still on its lattice has pairs at exactly H_s = 2 d,
    which float32 and float64 distances put on different sides; W and grad W are 0 there)."""
    x = sim.fields["particle_x"].numpy().copy()
    sim.step(sim.frame_dt / 64)
    rho = sim.fields["particle_density"].numpy()
    ref_rho, ref_pairs = oracle(sim, x)
    np.testing.assert_allclose(rho, ref_rho, rtol=2e-5)
    count, index, grad = kept.pairs.count.numpy(), kept.pairs.index.numpy(), kept.pairs.gradient.numpy()
    order = kept.nl.fluid.order.numpy()  # row t of the cache holds the pairs of particle order[t]
    got = {(int(order[t]), int(index[t, k])): grad[t, k] for t in range(sim.model.fluid_count) for k in range(count[t])}
    differ = set(got) ^ set(ref_pairs)
    if band > 0.0 and differ:
        r = np.array([np.linalg.norm(x[i].astype(np.float64) - x[j]) for i, j in differ])
        assert np.all(np.abs(r / sim.model.support_radius - 1.0) < band), r
        got = {k: v for k, v in got.items() if k not in differ}
        ref_pairs = {k: v for k, v in ref_pairs.items() if k not in differ}
    else:
        assert not differ  # exactly the pairs closer than H_s, none lost by the kept lists
    scale = max(float(np.abs(g).max()) for g in ref_pairs.values())
    for key, g in ref_pairs.items():
        np.testing.assert_allclose(got[key], g, atol=1e-5 * scale)


@pytest.mark.parametrize("skin", [0.5, 0.02])
def test_kept_lists_density_and_pairs_match_brute_force(skin, device):
    """Steps that reuse the lists and steps that search (the small skin: the drift passes skin / 2 within a few
    steps, and a list kept past it would miss pairs that came closer than H_s)."""
    sim = Simulation(falling_block(skin), device=device)
    kept = sim.solver.kept_lists
    for _ in range(3):
        sim.advance_frame()
    if skin >= 0.5:
        assert kept.builds < 0.5 * kept.steps  # most steps read the kept lists
    with sim.in_cell_order():  # (the frame's order: a CPU array's numpy() is a view, read inside)
        first = kept.builds
        check_step(sim, kept)  # the particles were reordered since the lists were searched: a search
        assert kept.builds == first + 1
        for _ in range(12):
            check_step(sim, kept)
        searches = kept.builds - first - 1
    if skin >= 0.5:
        assert searches < 12
    else:
        assert searches >= 1  # the drift passed skin / 2


def test_kept_lists_kept_while_the_fluid_moves_as_one(device):
    """A block in free fall, far from the walls: every particle drifts past skin / 2, all by about the same
    displacement d, so no two fluid particles close in, and the walls are closed in on by |d| < skin: the bound
    min(2 max |d|, the diagonal of the box of the d_i and 0) keeps the lists (the old rule, max |d| > skin / 2,
    searched), and they still hold exactly the pairs closer than H_s (brute-force oracle)."""
    sc = small_tank("wcsph_skin_fall", solver="wcsph", wcsph={"search_skin": 0.15}, particle_radius=0.03,
                    container={"min": [0.0, 0.0, 0.0], "max": [0.8, 0.6, 2.0]},
                    fluid=[{"shape": "box", "min": [0.2, 0.15, 1.2], "max": [0.5, 0.4, 1.5]}])
    sim = Simulation(sc, device=device)
    kept = sim.solver.kept_lists
    sim.advance_frame()  # falling at ~0.4 m/s after the frame: ~0.06 skin per step at frame_dt / 64
    kept_past_half = 0.0  # the largest drift on a step that kept the lists
    with sim.in_cell_order():
        for _ in range(13):
            builds = kept.builds
            check_step(sim, kept, band=1e-5)
            if kept.builds == builds:
                kept_past_half = max(kept_past_half, kept.last_drift)
                assert kept.last_spread <= kept.skin
    assert kept_past_half > 0.5 * kept.skin  # the old rule would have searched


def test_kept_lists_run_matches_the_per_step_search(device):
    """Same scene, skin 0 (a search every step, the reference) and 0.5 d: the same pairs, summed in another
    order (cells of H_s + skin instead of H_s), so the runs agree to rounding."""
    a = Simulation(falling_block(0.0), device=device)
    b = Simulation(falling_block(0.5), device=device)
    assert a.solver.kept_lists is None
    for _ in range(2):
        a.advance_frame()
        b.advance_frame()
    assert b.solver.kept_lists.builds < b.state.step
    np.testing.assert_allclose(b.get_field("particle_x"), a.get_field("particle_x"), atol=2e-6)
    np.testing.assert_allclose(b.get_field("particle_v"), a.get_field("particle_v"), atol=2e-4)


@pytest.mark.parametrize("threads", ["1", "3"])
def test_kept_lists_bitwise_over_threads(threads, monkeypatch, device):
    if device != "cpu":
        pytest.skip("the thread split is the CPU path")
    monkeypatch.setenv("WARP_SPH_CPU_THREADS", "2")
    ref = Simulation(falling_block(0.5), device=device)
    ref.advance_frame()
    monkeypatch.setenv("WARP_SPH_CPU_THREADS", threads)
    sim = Simulation(falling_block(0.5), device=device)
    sim.advance_frame()
    assert np.array_equal(sim.get_field("particle_x"), ref.get_field("particle_x"))
    assert np.array_equal(sim.get_field("particle_v"), ref.get_field("particle_v"))


def test_branch_free_cubic_matches_the_cubic_spline():
    """``pbf_pairs.cubic_value_gradient_select`` (the pair passes of PBF and WCSPH) against ``smoothing.cubic_value`` and
    ``cubic_gradient`` from r = 0 to past the support, to float32 rounding; 0 from H_s on."""
    import warp as wp

    from warp_sph.kernels.pbf_pairs import cubic_value_gradient_select

    @wp.kernel
    def evaluate_select(x: wp.array(dtype=wp.vec3), h: float, out: wp.array(dtype=wp.vec4)):
        i = wp.tid()
        out[i] = cubic_value_gradient_select(x[i], h)

    h = 0.05
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(400, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    offsets = (directions * np.linspace(0.0, 2.4 * h, 400)[:, None]).astype(np.float32)
    out = wp.zeros(len(offsets), dtype=wp.vec4, device="cpu")
    wp.launch(evaluate_select, len(offsets), [wp.array(offsets, dtype=wp.vec3, device="cpu"), h, out], device="cpu")
    got = out.numpy()
    w, g = evaluate("cubic", offsets, h)
    np.testing.assert_allclose(got[:, 0], w, rtol=2e-6, atol=1e-6 * w.max())
    np.testing.assert_allclose(got[:, 1:], g, rtol=0, atol=2e-6 * np.abs(g).max())
    outside = np.linalg.norm(offsets, axis=1) >= 2.0 * h
    assert outside.any() and not got[outside].any()


def test_kept_wall_lists_bitwise_the_fresh_ones(device):
    """The fluid-static-wall lists kept across fluid searches (``KeptLists.keep_walls``) against wall lists searched
    at every fluid search: the kept lists hold the same pairs closer than H_s in the same order (plus pairs beyond
    H_s that add nothing), so densities, positions and velocities are bitwise equal, with fewer wall searches."""
    sims = []
    for keep in (True, False):
        sim = Simulation(falling_block(0.2), device=device)
        sim.solver.kept_lists.keep_walls = keep
        for _ in range(5):  # the block lands at the third frame, then sloshes: searches every few steps
            sim.advance_frame()
        sims.append(sim)
    kept, fresh = (sim.solver.kept_lists for sim in sims)
    assert fresh.wall_builds == fresh.builds == kept.builds
    assert kept.wall_builds < 0.8 * kept.builds  # the walls' lists outlived fluid searches
    for name in ("particle_density", "particle_x", "particle_v"):
        assert np.array_equal(sims[0].get_field(name), sims[1].get_field(name)), name


def test_kept_wall_lists_searched_once_a_particle_moved_the_skin(device):
    """A block falling onto the floor with a small skin: the wall lists are kept across fluid searches while no
    particle drifted past the skin since they were searched (a wall particle does not move: a wall pair closes in
    by the fluid particle's drift), and searched again after; every step's density, with the wall term, matches
    the brute-force oracle, which fails once a wall pair closer than H_s is missing from lists kept too long."""
    sim = Simulation(falling_block(0.05), device=device)
    kept = sim.solver.kept_lists
    for _ in range(3):  # landed: the fluid searches about every step, the walls every other
        sim.advance_frame()
    with sim.in_cell_order():
        check_step(sim, kept)  # reordered since the last search: both lists searched
        builds, wall_builds = kept.builds, kept.wall_builds
        kept_over_search = 0  # fluid searches that kept the wall lists
        for _ in range(8):
            b, w = kept.builds, kept.wall_builds
            check_step(sim, kept)
            if kept.wall_builds == w:
                assert kept.last_wall_drift <= kept.skin
                kept_over_search += kept.builds > b
            else:
                assert kept.last_wall_drift == 0.0
        assert kept_over_search >= 1
        assert kept.wall_builds > wall_builds  # the drift passed the skin since the walls were searched
        assert kept.wall_builds - wall_builds < kept.builds - builds


def test_fused_search_bitwise_the_lists_then_the_density_pass(device):
    """A search step's fused walk (``kernels/wcsph_lists.search_density_pairs_kernel``: lists, density and pair
    cache at once) against the lists built first and the density pass over them (``KeptLists.fused_search``
    False): the same pairs in the same order with the same expressions, so bitwise equal."""
    sims = []
    for fused in (True, False):
        sim = Simulation(falling_block(0.2), device=device)
        sim.solver.kept_lists.fused_search = fused
        for _ in range(4):
            sim.advance_frame()
        sims.append(sim)
    assert sims[0].solver.kept_lists.builds == sims[1].solver.kept_lists.builds > 10
    for name in ("particle_density", "particle_x", "particle_v"):
        assert np.array_equal(sims[0].get_field(name), sims[1].get_field(name)), name


def test_static_wall_lists_bitwise_the_walk(device):
    """WCSPH's wall lists from the per-run lists of the static walls in reach of each cell
    (``NeighborLists.static_walls``) against the per-search walk of the wall grid: bitwise equal."""
    sims = []
    for walls in (True, False):
        sim = Simulation(falling_block(0.2), device=device)
        nl = sim.solver.kept_lists.nl
        assert nl.static_walls is not None
        if not walls:
            nl.static_walls = None
        for _ in range(4):
            sim.advance_frame()
        sims.append(sim)
    assert sims[0].solver.kept_lists.wall_builds > 5
    for name in ("particle_density", "particle_x", "particle_v"):
        assert np.array_equal(sims[0].get_field(name), sims[1].get_field(name)), name


def test_replayed_launches_bitwise_the_plain_ones(monkeypatch, device):
    """On the CPU WCSPH's own launches (density over the kept lists, drift check, pressure, forces, integration)
    replay recorded launches (``core.launch.replaying_launch``); each must re-bind the arguments that changed (dt,
    the pair cache after the lists grew, the lists after a search; checked: replays that never re-bind fail this
    test). A frame of the falling block, then steps of growing dt, replayed against plain ``launch``: bitwise the
    same positions and velocities."""
    from warp_sph.core.launch import MIN_RANGE, launch
    from warp_sph.methods.solvers import wcsph as wcsph_solver
    from warp_sph.methods.solvers import wcsph_lists

    def plain_launch(dev):
        def run(kernel, dim, inputs, outputs=(), min_range=MIN_RANGE, tag=None):
            launch(kernel, dim, inputs, outputs, device=dev, min_range=min_range)
        return run

    replayed = Simulation(falling_block(0.2), device=device)
    with monkeypatch.context() as m:
        m.setattr(wcsph_solver, "replaying_launch", plain_launch)
        m.setattr(wcsph_lists, "replaying_launch", plain_launch)
        plain = Simulation(falling_block(0.2), device=device)
    for sim in (replayed, plain):
        sim.advance_frame()
        base = sim.frame_dt / 200
        with sim.in_cell_order():
            for k in range(6):
                sim.step(base * (1.0 + 0.25 * k))
    assert replayed.solver.kept_lists.builds == plain.solver.kept_lists.builds >= 2
    assert np.array_equal(replayed.get_field("particle_x"), plain.get_field("particle_x"))
    assert np.array_equal(replayed.get_field("particle_v"), plain.get_field("particle_v"))
