"""PBF's per-step cost cuts against the passes they replace: the fused search + first density pass
(``kernels/pbf_search.py``) is bitwise the list build + density pass; the stabilize stage's density
pass at x reuses the last step's lists (no second build per step) and reads the same error."""
import numpy as np

from small_scenes import small_tank
from warp_sph.methods.solvers.pbf import PbfSolver
from warp_sph.run.simulation import Simulation


def fixed_step_tank(**kw):
    """A block falling onto the floor of a tank, with a fixed step well below the adaptive one (the
    stabilize stage then measures the error at x every step: ``Solver.error_share`` < 1)."""
    r = 0.025
    d = 2 * r
    size = [12 * d, 8 * d, 0.8]
    return small_tank("pbf_cost", solver="pbf", particle_radius=r, container={"min": [0, 0, 0], "max": size},
                      fluid=[{"min": [0, 0, 0.1], "max": [6 * d, size[1], 0.45]}],
                      time={"fixed_dt": 1.0 / 24 / 48}, **kw)


def run_frames(sim, frames=3):
    errors = []
    for _ in range(frames):
        stats = sim.advance_frame()
        errors.append(stats.solver["density_error"]["mean"])
    return sim.get_field("particle_x"), sim.get_field("particle_v"), errors


def unfused(monkeypatch):
    """The passes before the fusion: a full list build in "neighbors", the list density pass in "density"."""
    monkeypatch.setattr(PbfSolver, "run_neighbors", lambda self, sim, dt: self.build_neighbors())
    monkeypatch.setattr(PbfSolver, "run_density", lambda self, sim, dt: self.density_pass())


def test_fused_search_and_density_is_bitwise_the_build_and_pass(monkeypatch, device):
    fused = Simulation(fixed_step_tank(), device=device)
    with monkeypatch.context() as m:
        unfused(m)
        ref = Simulation(fixed_step_tank(), device=device)
    a, b = run_frames(fused), run_frames(ref)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and a[2] == b[2]
    assert fused.solver.grid_builds == ref.solver.grid_builds


def test_stabilize_reuses_the_lists_and_reads_the_same_error(device):
    """Before: every step built the lists twice (at x for the stabilize stage's error, at x* for the solve).
    Now once per step plus once per frame (the frame's first step: the particles changed places between
    frames) plus the solve's drift rebuilds; the positions agree with the two-build step to rounding.
    The frames put the particles in and out of cell order: lists kept across that are stale (a first
    version of this change read them: 4 mm off after one frame); ``pbf_neighbor_slot`` catches it."""
    reuse = Simulation(fixed_step_tank(), device=device)
    ref = Simulation(fixed_step_tank(), device=device)
    ref.solver.reuse_neighbors = ref.solver.build_neighbors  # the old stabilize stage: a build at x
    frames = 3
    b0, r0 = reuse.solver.grid_builds, ref.solver.grid_builds
    (xa, va, ea), (xb, vb, eb) = run_frames(reuse, frames), run_frames(ref, frames)
    steps = reuse.state.step
    assert reuse.state.step == ref.state.step == frames * 48
    assert ref.solver.grid_builds - r0 >= 2 * steps  # the two builds per step of the old stabilize stage
    assert reuse.solver.grid_builds - b0 < 1.3 * steps
    # the same pairs in the same order while no particle changes cells (here: bitwise); else rounding only
    np.testing.assert_allclose(xa, xb, atol=1e-6)
    np.testing.assert_allclose(va, vb, atol=1e-4)
    np.testing.assert_allclose(ea, eb, rtol=1e-3, atol=1e-7)



def uneven_steps(sim, steps=6):
    """A frame, then ``steps`` substeps of growing dt (each launch's dt-dependent arguments change every step)."""
    sim.advance_frame()
    base = sim.frame_dt / 64
    with sim.in_cell_order():
        for k in range(steps):
            sim.step(base * (1.0 + 0.25 * k))
    return sim.get_field("particle_x"), sim.get_field("particle_v")


def test_replayed_launches_bitwise_the_plain_ones(device):
    """On the CPU the passes replay recorded launches (``PbfPasses._run``, ``core.launch.Replays``): a replay must
    re-bind every argument that changed since it was recorded (here dt and the correction's 1 / dt^2, which change
    every step), or it would run on stale values (checked: replays that never re-bind fail this test). A tank with
    a frame and then steps of growing dt, and the fixed-step tank (its stabilize stage: the constraint offset),
    with replays and with plain launches: bitwise the same positions and velocities."""
    for scene in (small_tank("pbf_replay", solver="pbf"), fixed_step_tank()):
        replayed = Simulation(scene, device=device)
        plain = Simulation(scene, device=device)
        plain.solver._replays = None  # every launch through core.launch.launch
        a, b = uneven_steps(replayed), uneven_steps(plain)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
        assert (replayed.solver._replays is not None) == replayed.model.device.is_cpu


def test_static_wall_lists_bitwise_the_walk(device):
    """PBF's boundary lists from the per-run lists of the static walls in reach of each cell
    (``NeighborLists.static_walls``, DFSPH's ``WallReach`` at the lists' radius) against the per-search walk of the
    wall grid: the same walls in the same order, so positions and velocities are bitwise equal."""
    runs = []
    for walls in (True, False):
        sim = Simulation(fixed_step_tank(), device=device)
        nl = sim.fields["neighbor_lists"]
        assert nl.static_walls is not None and nl.static_walls.cells is nl.boundary_cells
        if not walls:
            nl.static_walls = None
        runs.append(run_frames(sim, 2))
    assert np.array_equal(runs[0][0], runs[1][0]) and np.array_equal(runs[0][1], runs[1][1])


def test_static_wall_lists_match_the_walk_outside_the_grid(device):
    """The boundary lists of points all over the wall grid, beyond its border included (clamped into the border
    cells), from the static walls' per-cell lists and from the walk: the same counts and the same indices in the
    same order, each wall closer than the search radius listed (a NumPy brute force)."""
    import warp as wp

    sim = Simulation(fixed_step_tank(), device=device)
    nl = sim.fields["neighbor_lists"]
    n = sim.model.fluid_count
    bc = nl.boundary_cells
    lo = np.array([bc.lo[a] for a in range(3)])
    hi = lo + np.array([bc.dims[a] for a in range(3)]) / bc.inv_cell_size
    rng = np.random.default_rng(7)
    x = (lo - 0.1 + rng.random((n, 3)) * (hi - lo + 0.2)).astype(np.float32)
    xs = wp.array(x, dtype=wp.vec3, device=sim.model.device)
    nl.sort(xs)
    got = []
    for walls in (nl.static_walls, None):
        nl.static_walls = walls
        nl.build_boundary_lists(xs)
        got.append((nl.boundary.count.numpy()[:n].copy(), nl.boundary.index.numpy()[:n].copy()))
    (count, index), (ref_count, ref_index) = got
    assert np.array_equal(count, ref_count)
    assert count.max() <= index.shape[1] and count.sum() > n  # none dropped: the comparison covers every entry
    for i in range(n):
        assert np.array_equal(index[i, :count[i]], ref_index[i, :count[i]])
    bx = sim.model.boundary_x.numpy()
    r = np.linalg.norm(x[:, None, :].astype(np.float64) - bx[None, :, :], axis=2)
    near = r < nl.search_radius * (1 - 1e-5)
    for i in range(0, n, 7):
        assert set(np.nonzero(near[i])[0]) <= set(index[i, :count[i]].tolist())


def _rows_by_particle(nl):
    """The fluid lists as {particle: list of neighbours} (count clipped to the capacity)."""
    count, index = nl.fluid.count.numpy(), nl.fluid.index.numpy()
    return count, [index[i, :min(c, index.shape[1])].tolist() for i, c in enumerate(count)]


def test_fused_searches_keep_full_lists_the_walk_prefix(device):
    """The fused searches of PBF (search + density) and WCSPH (kept lists: search + density + pairs) store their
    candidates without a branch and restore a full list's last slot: with lists as long as the median count, the
    counts stay exact and every list is the first entries of the complete one (also those exactly full); the
    density of a particle whose list holds all its neighbours is bitwise the complete lists'."""
    from small_scenes import small_tank as tank

    for solver in ("pbf", "wcsph"):
        sim = Simulation(fixed_step_tank() if solver == "pbf" else
                         tank("wcsph_full", solver="wcsph", particle_radius=0.025), device=device)
        sim.advance_frame()
        s = sim.solver
        if solver == "pbf":
            nl = s.nl

            def search():
                s.sort_neighbors()
                s.search_density_pass()
        else:
            kept = s.kept_lists
            nl = kept.nl

            def search():
                kept._search, kept._search_walls = True, True
                nl.sort(sim.fields["particle_x"])
                kept.run_density(sim, 0.0)
        search()
        count, full_rows = _rows_by_particle(nl)
        density = sim.fields["particle_density"].numpy().copy()
        capacity = int(np.median(count))
        nl._allocate(nl.fluid, capacity)
        search()
        small_count, rows = _rows_by_particle(nl)
        np.testing.assert_array_equal(small_count, count)
        assert (count == capacity).any() and (count > capacity).any(), solver
        for i, row in enumerate(rows):
            assert row == full_rows[i][:capacity], (solver, i, count[i])
        fits = count <= capacity
        np.testing.assert_array_equal(sim.fields["particle_density"].numpy()[fits], density[fits])


def _wall_rows_complete(sim):
    """Every fluid particle's wall list holds each wall particle closer than H_s to x* (brute force), in ascending
    sorted order (the order a search lists them in); returns the share of lists kept from an earlier search."""
    s, m = sim.solver, sim.model
    nl = s.nl
    # between frames the fields are at stable indices; the lists' row k belongs to the frame's slot k = particle
    # order[k] (``neighbors.particle_order``)
    order = sim._cell_order.order.numpy()[: m.fluid_count]
    x = sim.fields["predicted_x"].numpy()[order].astype(np.float64)
    bx = m.boundary_x.numpy().astype(np.float64)
    rank = np.empty(len(bx), dtype=np.int64)
    rank[nl.boundary_cells.cell_point.numpy()[: len(bx)]] = np.arange(len(bx))  # wall index -> sorted index
    count, index = nl.boundary.count.numpy(), nl.boundary.index.numpy()
    for i in range(m.fluid_count):
        row = index[i, : count[i]]
        near = np.nonzero(np.linalg.norm(bx - x[i], axis=1) < m.support_radius)[0]
        assert set(near.tolist()) <= set(row.tolist()), i
        assert np.all(np.diff(rank[row]) > 0), i
    searched_at = sim.fields["pbf_neighbor_x"].numpy()[order]
    return float(np.mean(np.any(nl.boundary_keep_x.numpy()[: m.fluid_count] != searched_at, axis=1)))


def test_kept_wall_lists_bitwise_the_searched_ones(monkeypatch, device):
    """PBF keeps a particle's static-wall list while it is within 0.9 margin of where the list was searched: the
    lists still hold every wall particle closer than H_s in search order (brute-force oracle), some are kept, and
    the run is bitwise that of wall lists searched every step."""
    kept = Simulation(fixed_step_tank(), device=device)
    with monkeypatch.context() as m:
        m.setattr(PbfSolver, "_wall_keep", property(lambda self: -1.0))
        ref = Simulation(fixed_step_tank(), device=device)
        b = run_frames(ref)
    shares = []
    for _ in range(3):
        kept.advance_frame()
        shares.append(_wall_rows_complete(kept))
    a = (kept.get_field("particle_x"), kept.get_field("particle_v"))
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert max(shares) > 0.2, shares


def test_list_rows_sized_from_the_rest_neighbour_count(device):
    """PBF's fluid list rows (and so the pair cache's) hold ``LIST_HEADROOM`` times the neighbours a particle has
    at rest density within the search radius, (4/3) pi R^3 / V (``cell_lists.list_capacity``), not the lists'
    general 64 per support volume (86 slots at H_s + 0.2 d: the correction then streamed a cache of 1.5x the bytes'
    span, issue #32); three frames of a falling block fit them (no overflow, no redone frame)."""
    import math
    import warnings

    sim = Simulation(fixed_step_tank(), device=device)
    m, nl = sim.model, sim.solver.nl
    volume = m.particle_mass / m.rest_density
    at_rest = 4.0 / 3.0 * math.pi * nl.search_radius ** 3 / volume  # 44.6 at H_s + 0.2 d on d = V^(1/3)
    capacity = nl.capacities[0]
    assert capacity == math.ceil(1.3 * at_rest) < math.ceil(64 * (nl.search_radius / m.support_radius) ** 3)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # an overflow warns and redoes the frame
        run_frames(sim, 3)
    assert nl.capacities[0] == capacity
    assert sim.fields["pbf_pairs"].gradient.shape[1] == capacity
    assert int(nl.fluid.count.numpy()[: m.fluid_count].max()) <= capacity


def test_overflowing_list_rows_grow_and_redo_the_frame_bitwise(device):
    """Rows too short for a particle's neighbours (cut to 20 slots after the start, whose density pass would grow
    them) overflow: the frame is redone with grown lists (``run.frame_loop``) and the run is bitwise the one whose
    rows were long enough from the start (the same pairs in the same order); the pair cache follows the lists'
    capacity."""
    import pytest

    ref = Simulation(fixed_step_tank(), device=device)
    short = Simulation(fixed_step_tank(), device=device)
    nl = short.solver.nl
    nl._allocate(nl.fluid, 20)
    assert short.solver.nl.capacities[0] == 20
    with pytest.warns(RuntimeWarning, match="the lists grow and the frame is redone"):
        a = run_frames(short, 2)
    b = run_frames(ref, 2)
    assert short.solver.nl.capacities[0] > 20
    assert short.fields["pbf_pairs"].gradient.shape[1] == short.solver.nl.capacities[0]
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and a[2] == b[2]


def test_reciprocal_cubic_matches_the_cubic_spline():
    """``pbf_pairs.cubic_value_gradient_reciprocal`` (PBF's fluid pair passes: one division per pair) against
    ``smoothing``'s cubic spline from r = 0 to past the support, to float32 rounding; 0 from H_s on."""
    import warp as wp

    from warp_sph.core.smoothing import evaluate
    from warp_sph.kernels.pbf_pairs import cubic_value_gradient_reciprocal

    @wp.kernel
    def evaluate_reciprocal(x: wp.array(dtype=wp.vec3), h: float, out: wp.array(dtype=wp.vec4)):
        i = wp.tid()
        out[i] = cubic_value_gradient_reciprocal(x[i], h)

    h = 0.05
    rng = np.random.default_rng(5)
    directions = rng.normal(size=(400, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    offsets = (directions * np.linspace(0.0, 2.4 * h, 400)[:, None]).astype(np.float32)
    out = wp.zeros(len(offsets), dtype=wp.vec4, device="cpu")
    wp.launch(evaluate_reciprocal, len(offsets), [wp.array(offsets, dtype=wp.vec3, device="cpu"), h, out], device="cpu")
    got = out.numpy()
    w, g = evaluate("cubic", offsets.astype(np.float64), h)
    np.testing.assert_allclose(got[:, 0], w, rtol=2e-6, atol=1e-6 * w.max())
    np.testing.assert_allclose(got[:, 1:], g, rtol=0, atol=2e-6 * np.abs(g).max())
    outside = np.linalg.norm(offsets, axis=1) >= 2.0 * h
    assert outside.any() and not got[outside].any()
    assert not got[0, 1:].any()  # r = 0: no gradient (x_ij = 0 times a finite 1 / max(r, 1e-30))


def test_pair_passes_cache_the_listed_pairs_and_their_gradients(device):
    """The fused search and the list density pass fill the pair cache with exactly the listed pairs closer than H_s,
    in the lists' order, and V grad_i W_ij at x* (``cubic_value_gradient_reciprocal``) to float32 rounding: NumPy
    oracles of the filter and of the cubic spline's gradient (float64)."""
    from warp_sph.core.smoothing import evaluate

    sim = Simulation(fixed_step_tank(), device=device)
    run_frames(sim, 1)
    s, m = sim.solver, sim.model
    volume = m.particle_mass / m.rest_density
    for name, run_pass in (("search", lambda: (s.sort_neighbors(), s.search_density_pass())), ("list", s.density_pass)):
        run_pass()
        pairs, nl = sim.fields["pbf_pairs"], s.nl
        x = sim.fields["predicted_x"].numpy()
        order, lists, listed = nl.fluid.order.numpy(), nl.fluid.index.numpy(), nl.fluid.count.numpy()
        count, index, grad = pairs.count.numpy(), pairs.index.numpy(), pairs.gradient.numpy()
        offsets, cached = [], []
        for t in range(m.fluid_count):
            i = order[t]
            js = lists[i, :listed[i]]
            x_ij = x[i] - x[js]
            inside = np.sum(x_ij * x_ij, axis=1, dtype=np.float32) < np.float32(m.support_radius) ** 2
            assert np.array_equal(index[t, :count[t]], js[inside]), name
            offsets.append(x_ij[inside])
            cached.append(grad[t, :count[t]])
        _, g = evaluate("cubic", np.concatenate(offsets).astype(np.float64), m.smoothing_length)
        got = np.concatenate(cached)
        assert len(got) > 10 * m.fluid_count
        np.testing.assert_allclose(got, volume * g, rtol=0, atol=2e-6 * np.abs(volume * g).max(), err_msg=name)


def test_a_start_denser_than_the_rows_reads_its_whole_density(monkeypatch, device):
    """A block sampled at 0.8 d has about 80 neighbours within H_s + 0.2 d, more than the rows' 1.3x the rest count:
    the start's density pass grows the lists and runs again (as DFSPH's ``refresh_density``), so the start's density
    is bitwise the one of rows long enough from the beginning (the truncated rows read it up to 47 % low)."""
    from warp_sph.methods.solvers import pbf_passes

    def compressed():
        r = 0.025
        return small_tank("pbf_dense_start", solver="pbf", particle_radius=r,
                          container={"min": [0, 0, 0], "max": [0.5, 0.5, 0.5]},
                          fluid=[{"min": [0, 0, 0], "max": [0.25, 0.25, 0.25], "spacing_scale": 0.8}])

    sim = Simulation(compressed(), device=device)
    grown = sim.solver.nl.capacities[0]
    rho = sim.get_field("particle_density")
    monkeypatch.setattr(pbf_passes, "list_capacity", lambda radius, volume: 200)
    long_rows = Simulation(compressed(), device=device)
    assert long_rows.solver.nl.capacities[0] == 200
    assert grown > int(long_rows.solver.nl.fluid.count.numpy().max())  # the rows grew past what the start needs
    assert np.array_equal(rho, long_rows.get_field("particle_density"))
