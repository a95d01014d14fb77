"""DFSPH's search skin (``dfsph.search_skin``): the pair values from lists within H_s + skin against the
brute-force NumPy oracle of ``test_dfsph.py`` while the lists are reused and after a rebuild, the rebuild
rule (a particle moved more than skin / 2), and runs equal to the per-step search up to float rounding
and bitwise equal over CPU thread counts."""
import numpy as np
import pytest

from small_scenes import small_tank, stage
from test_dfsph import Oracle, assert_rows_apart, block_on_floor, prepared
from warp_sph.run.simulation import Simulation

SKIN = 0.5  # [spacings d]


def check_search_against_oracle(sim, o):
    """The search's outputs (density, factor, s_i, wall gradient, pair rows, source, active) against ``o``."""
    m = sim.model
    pairs = sim.fields["dfsph_pairs"]
    np.testing.assert_allclose(sim.get_field("particle_density") / m.rest_density, o.rho_hat, rtol=2e-5)
    np.testing.assert_allclose(sim.get_field("dfsph_factor"), o.f, rtol=2e-4)
    np.testing.assert_allclose(pairs.gradient_sum.numpy(), o.s, rtol=1e-3, atol=1e-4 * np.abs(o.s).max())
    np.testing.assert_allclose(pairs.boundary_gradient.numpy(), o.sb, rtol=1e-3, atol=1e-4 * np.abs(o.sb).max())
    count, offset = pairs.count.numpy(), pairs.offset.numpy()
    np.testing.assert_array_equal(count, o.mask.sum(1))
    index, grad = pairs.index.numpy(), pairs.gradient.numpy()
    assert_rows_apart(offset, count, index.shape[0])
    for i in range(m.fluid_count):
        js = index[offset[i]:offset[i] + count[i]]
        assert sorted(js) == sorted(np.nonzero(o.mask[i])[0])
        np.testing.assert_allclose(grad[offset[i]:offset[i] + count[i]], o.G[i, js], rtol=1e-3,
                                   atol=1e-5 * np.abs(o.G).max())
    div = o.delta(o.v)
    np.testing.assert_allclose(sim.get_field("dfsph_divergence_source"), -div, rtol=1e-3, atol=1e-4 * np.abs(div).max())
    np.testing.assert_array_equal(pairs.active.numpy() == 1, o.neighbors >= sim.solver.neighbor_threshold)


def move(sim, rng, distance):
    """Every particle moved by ``distance`` [m] in a random direction; the new oracle."""
    m = sim.model
    x = m.to_local(sim.get_field("particle_x")).astype(np.float64)
    step = rng.normal(size=x.shape)
    x += distance * step / np.linalg.norm(step, axis=1, keepdims=True)
    sim.set_field("particle_x", m.to_world(x))
    stage(sim, "neighbors").run(sim, 0.0)
    stage(sim, "density").run(sim, 3e-3)
    x = m.to_local(sim.get_field("particle_x")).astype(np.float64)
    return Oracle(sim, x, sim.get_field("particle_v").astype(np.float64))


def test_skin_lists_are_reused_below_half_the_skin_and_match_the_oracle(device):
    """Lists within H_s + 0.5 d: after moves of 0.24 d per particle (below skin / 2) they are not rebuilt and
    still give every pair closer than H_s (pairs that entered the support since the build included); a
    move of 0.3 d rebuilds them; the values match the oracle throughout."""
    sim, o = prepared(device=device, dfsph={"search_skin": SKIN})
    d = sim.model.spacing
    assert sim.solver.nl.search_radius == pytest.approx(sim.model.support_radius + SKIN * d)
    builds = sim.solver.list_builds  # the start's, and the compressed block's
    stage(sim, "density").run(sim, 3e-3)
    assert sim.solver.list_builds == builds
    check_search_against_oracle(sim, o)
    rng = np.random.default_rng(7)
    first = o.mask
    o = move(sim, rng, 0.24 * d)  # 0.24 d from the build
    assert sim.solver.list_builds == builds
    assert (o.mask & ~first).sum() > 10  # pairs that were farther than H_s at the build
    check_search_against_oracle(sim, o)
    o = move(sim, rng, 0.3 * d)  # farther than 0.25 d from the build: rebuilt
    assert sim.solver.list_builds == builds + 1
    check_search_against_oracle(sim, o)


def test_skin_run_equals_the_per_step_search_to_rounding(device):
    """A dam break in a small tank, 40 steps: with the skin the lists are built on fewer steps than the
    search runs, and positions stay within 1e-5 d of the per-step search's (the sums run in another order)."""
    def run(skin):
        sim = Simulation(small_tank("skin", dfsph={"search_skin": skin}), device=device)
        for _ in range(40):
            sim.step(4e-3)
        return sim, sim.get_field("particle_x")

    _, x0 = run(0.0)
    sim, x1 = run(1.0)
    assert 1 < sim.solver.list_builds < 40
    assert np.abs(x0 - x1).max() < 1e-5 * sim.model.spacing


def test_skin_run_is_bitwise_reproducible_over_thread_counts(monkeypatch, device):
    """With the skin (lists reused after the first step), 1 and 3 CPU threads give bitwise the same state."""
    res = []
    for threads in ("1", "3"):
        monkeypatch.setenv("WARP_SPH_CPU_THREADS", threads)
        sim = Simulation(block_on_floor(nx=16, ny=16, nz=12, dfsph={"search_skin": SKIN}), device=device)
        assert sim.model.fluid_count >= 3 * 1024  # three ranges of the split launch
        for _ in range(3):
            sim.step(4e-3)
        assert sim.solver.list_builds < 4  # the initial density, then 3 steps
        res.append((sim.get_field("particle_x"), sim.get_field("particle_v")))
    assert np.array_equal(res[0][0], res[1][0]) and np.array_equal(res[0][1], res[1][1])


def test_search_reports_full_lists_and_keeps_its_rows_apart_until_they_grow(device):
    """Lists of 8 (fewer than a particle's neighbours): the search reports the largest count that did not
    fit and writes no row past its room (at most 8 each, the rows apart); after the lists grow to that count the search equals the oracle again."""
    sim, o = prepared(device=device)
    nl = sim.solver.nl
    nl._allocate(nl.fluid, 8)
    stage(sim, "density").run(sim, 3e-3)
    worst = nl.overflow()
    assert worst == (o.mask.sum(1) + 1).max()  # i itself and its neighbours within H_s
    pairs = sim.fields["dfsph_pairs"]
    count, offset = pairs.count.numpy(), pairs.offset.numpy()
    # at most 8 pairs a row (the search's room, row i at i x 8; on the CPU packed after it), the rows apart
    assert (count <= 8).all() and (count < o.mask.sum(1)).any()
    assert_rows_apart(offset, count, pairs.index.shape[0])
    nl.grow(worst)
    stage(sim, "density").run(sim, 3e-3)
    assert nl.overflow() == 0
    check_search_against_oracle(sim, o)


@pytest.mark.parametrize("threads", ["1", "2", "3"])
def test_per_step_pair_rows_are_packed_in_cell_order_per_thread_range(monkeypatch, threads):
    """On the CPU the per-step search writes its pair rows packed: thread r's range of sorted indices
    [n r / R, n (r + 1) / R) starts at its first index x capacity, and the rows follow in cell order (the
    order the solves visit), each at the exclusive scan of the counts before it (a NumPy oracle of that
    scan); the packed rows still match the brute-force oracle (pairs, gradients, every other output)."""
    monkeypatch.setenv("WARP_SPH_CPU_THREADS", threads)
    sim, o = prepared(device="cpu")
    stage(sim, "density").run(sim, 3e-3)
    check_search_against_oracle(sim, o)
    pairs, nl = sim.fields["dfsph_pairs"], sim.fields["neighbor_lists"]
    n, capacity = sim.model.fluid_count, nl.capacities[0]
    offset, count = pairs.offset.numpy()[:n], pairs.count.numpy()[:n]
    order = nl.fluid_cells.cell_point.numpy()[:n]  # particle at each sorted index
    assert not np.array_equal(order, np.arange(n))  # cell order differs from index order here
    ranges = int(threads)
    for r in range(ranges):
        lo, hi = n * r // ranges, n * (r + 1) // ranges
        rows = order[lo:hi]
        scan = lo * capacity + np.concatenate([[0], np.cumsum(count[rows])[:-1]])
        np.testing.assert_array_equal(offset[rows], scan)


def test_padded_pair_rows_of_a_device_run_on_the_cpu_give_the_same_search():
    """The search's padded layout (a device's: one thread per particle, row i at i x capacity), run on the
    CPU: the rows start at i x capacity, match the brute-force oracle, and hold bitwise the pairs, gradients
    and sums of the packed CPU search (the same pairs in the same order)."""
    from warp_sph.kernels.dfsph_search import fluid_search_kernel

    out = {}
    for packed in (True, False):
        sim, o = prepared(device="cpu")
        solver = sim.solver
        solver._packed_rows = packed
        solver._search = fluid_search_kernel(sim.model.smoothing.name, packed=packed)
        stage(sim, "density").run(sim, 3e-3)
        check_search_against_oracle(sim, o)
        pairs = sim.fields["dfsph_pairs"]
        n, capacity = sim.model.fluid_count, solver.nl.capacities[0]
        offset, count = pairs.offset.numpy()[:n], pairs.count.numpy()[:n]
        rows = [(pairs.index.numpy()[a:a + c], pairs.gradient.numpy()[a:a + c]) for a, c in zip(offset, count)]
        out[packed] = (offset, rows, sim.get_field("particle_density"), sim.get_field("dfsph_factor"))
    np.testing.assert_array_equal(out[False][0], np.arange(n) * capacity)
    for (ia, ga), (ib, gb) in zip(out[True][1], out[False][1]):
        assert np.array_equal(ia, ib) and np.array_equal(ga, gb)
    assert np.array_equal(out[True][2], out[False][2]) and np.array_equal(out[True][3], out[False][3])


def run_frames(sim, frames):
    for _ in range(frames):
        sim.advance_frame()
    return [sim.get_field(name) for name in ("particle_x", "particle_v", "particle_density")]


def test_fluid_list_rows_sized_from_the_rest_neighbour_count(device):
    """DFSPH's fluid list rows (and the pair cache's allocation) hold 1.3 times the neighbours a particle has at
    rest density within H_s, (4/3) pi H_s^3 / V (``cell_lists.list_capacity``, as PBF's rows: 44 slots), not the
    lists' general 64 per support volume; three frames of a dam break in a small tank fit them (no overflow, no
    redone frame)."""
    import math
    import warnings

    sim = Simulation(small_tank("rows"), device=device)
    m, nl = sim.model, sim.solver.nl
    at_rest = 4.0 / 3.0 * math.pi * m.support_radius ** 3 / (m.particle_mass / m.rest_density)  # 33.5 on d^3 = V
    capacity = nl.capacities[0]
    assert capacity == math.ceil(1.3 * at_rest) == 44 < 64
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # an overflow warns and redoes the frame
        run_frames(sim, 3)
    assert nl.capacities[0] == capacity
    assert sim.fields["dfsph_pairs"].index.shape[0] == max(m.capacity, 1) * capacity
    assert int(nl.fluid.count.numpy()[: m.fluid_count].max()) < capacity


def test_overflowing_fluid_list_rows_grow_and_redo_the_frame_bitwise(device):
    """Rows too short for a particle's neighbours (cut to 20 slots after the start) overflow: the frame is redone
    with grown lists (``run.frame_loop``) and the run is bitwise the one whose rows were long enough throughout (the
    same pairs in the same order); the pair cache follows the lists' capacity."""
    ref = Simulation(small_tank("rows"), device=device)
    short = Simulation(small_tank("rows"), device=device)
    nl = short.solver.nl
    nl._allocate(nl.fluid, 20)
    with pytest.warns(RuntimeWarning, match="the lists grow and the frame is redone"):
        a = run_frames(short, 2)
    b = run_frames(ref, 2)
    capacity = nl.capacities[0]
    assert capacity > 20 and short.fields["dfsph_pairs"].index.shape[0] == short.model.capacity * capacity
    assert all(np.array_equal(u, w) for u, w in zip(a, b))
