"""Hash-grid neighbour search equals brute force, at negative coordinates and far from the origin."""
import numpy as np
import pytest
import warp as wp

from warp_sph.kernels import akinci2012

from warp_sph.neighbors import NeighborGrid, query_neighbors


@pytest.mark.parametrize("offset", [0.0, -3.7, 1.0e2, -1.0e3, 1.0e4])
def test_matches_brute_force(offset, device):
    rng = np.random.default_rng(int(abs(offset)) + 7)
    radius = 0.1
    pts = (rng.uniform(-0.6, 0.6, (1500, 3)) + offset).astype(np.float32)
    x = wp.array(pts, dtype=wp.vec3, device=device)
    grid = NeighborGrid(radius, device=device)
    grid.build(x)
    counts, lists = query_neighbors(grid, x, x)
    diff = pts[:, None, :].astype(np.float64) - pts[None, :, :].astype(np.float64)
    dist = np.linalg.norm(diff, axis=2)
    ambiguous = np.abs(dist - radius) < 1e-5 * max(1.0, abs(offset))
    for i in range(len(pts)):
        ref = set(np.nonzero(dist[i] < radius)[0])
        got = set(lists[i].tolist())
        sym = (ref ^ got) - set(np.nonzero(ambiguous[i])[0])
        assert not sym, (i, sorted(sym)[:5])
    assert counts.sum() > 3 * len(pts)  # not a vacuous comparison


def test_query_points_other_than_grid_points(device):
    """Boundary-style search: query a static grid from other points."""
    rng = np.random.default_rng(5)
    radius = 0.07
    b = rng.uniform(-1, 0, (800, 3)).astype(np.float32)
    q = rng.uniform(-1, 0, (300, 3)).astype(np.float32)
    bx = wp.array(b, dtype=wp.vec3, device=device)
    grid = NeighborGrid(radius, device=device)
    grid.build(bx)
    _, lists = query_neighbors(grid, bx, wp.array(q, dtype=wp.vec3, device=device))
    dist = np.linalg.norm(q[:, None].astype(np.float64) - b[None].astype(np.float64), axis=2)
    for i in range(len(q)):
        assert set(lists[i].tolist()) == set(np.nonzero(dist[i] < radius)[0])


@pytest.mark.parametrize("cells_per_radius", [1, 2])
def test_neighbor_lists_and_fused_density_match_brute_force(cells_per_radius, device):
    """Per-step lists (fluid-fluid, fluid-boundary) equal brute force, with fluid particles far from
    the boundary (the boundary search is skipped there) and outside the cell grid (clamped cells);
    the density summed during the search equals m sum_j W_ij + rho0 sum_b V_b W_ib in NumPy."""
    from sph_oracle import W
    from warp_sph.neighbors import NeighborLists

    rng = np.random.default_rng(11)
    h = 0.05
    radius = 2.0 * h  # cubic support
    fluid = rng.uniform(-0.5, 0.5, (1200, 3)).astype(np.float32)
    fluid[:20] += np.float32(0.9)  # beyond the grid's box
    b = rng.uniform(-0.5, 0.5, (900, 3)).astype(np.float32)
    b[:, 2] = rng.uniform(-0.62, -0.5, 900)  # a floor slab: most fluid is far from it
    volume = rng.uniform(0.5, 1.5, 900).astype(np.float32) * 1e-4
    mass, rho0 = 0.125, 1000.0
    x = wp.array(fluid, dtype=wp.vec3, device=device)
    lists = NeighborLists(radius, [-0.7] * 3, [0.7] * 3, len(fluid), wp.array(b, dtype=wp.vec3, device=device),
                          fluid_capacity=128, boundary_capacity=128, cells_per_radius=cells_per_radius,
                          device=device, boundary_volume=wp.array(volume, dtype=float, device=device))
    density = wp.zeros(len(fluid), dtype=float, device=device)
    lists.sort(x)
    params = akinci2012.AkinciParams()  # Akinci boundary density: rho0 sum_b V_b W_ib
    lists.build_lists(x, density, "cubic", h, mass, rho0, akinci2012.AKINCI2012, params)
    assert lists.overflow() == 0
    d_ff = np.linalg.norm(fluid[:, None].astype(np.float64) - fluid[None].astype(np.float64), axis=2)
    d_fb = np.linalg.norm(fluid[:, None].astype(np.float64) - b[None].astype(np.float64), axis=2)
    for got, dist in ((lists.fluid, d_ff), (lists.boundary, d_fb)):
        count = got.count.numpy()
        index = got.index.numpy()
        for i in range(len(fluid)):
            ref = set(np.nonzero(dist[i] < radius)[0]) - set(np.nonzero(np.abs(dist[i] - radius) < 1e-6)[0])
            mine = set(index[i, : count[i]].tolist()) - set(np.nonzero(np.abs(dist[i] - radius) < 1e-6)[0])
            assert mine == ref, (i, sorted(mine ^ ref)[:5])
    near = lists.boundary.count.numpy() > 0
    assert 0.03 < near.mean() < 0.5  # both branches of the boundary search are exercised
    assert lists.boundary_mask is not None  # cells of H/2: the mask grows by two cells (the lists above stay exact)
    expected = mass * W("cubic", d_ff, h).sum(axis=1) + rho0 * (W("cubic", d_fb, h) * volume[None]).sum(axis=1)
    np.testing.assert_allclose(density.numpy(), expected, rtol=2e-5)
    # without the density the lists are the same
    lists.build(x)
    np.testing.assert_array_equal(lists.fluid.count.numpy(), (d_ff < radius).sum(axis=1))


def test_full_lists_keep_the_walk_order_prefix(device):
    """Lists too short for some particles (the walks store candidates without a branch and overwrite a full
    list's last slot, then restore it): the count stays exact, the stored entries are the first ``capacity`` of
    the complete lists in the same order (also for a list exactly full), the density sums the stored pairs, and
    max_count records the overflow."""
    from warp_sph.neighbors import NeighborLists

    rng = np.random.default_rng(3)
    radius, h = 0.1, 0.05
    fluid = np.concatenate([rng.uniform(-0.15, 0.15, (1500, 3)), rng.uniform(-0.5, 0.5, (1500, 3))]).astype(np.float32)
    x = wp.array(fluid, dtype=wp.vec3, device=device)

    def built(capacity):
        lists = NeighborLists(radius, [-0.6] * 3, [0.6] * 3, len(fluid), None, fluid_capacity=capacity,
                              boundary_capacity=8, device=device)
        density = wp.zeros(len(fluid), dtype=float, device=device)
        lists.sort(x)
        lists.build_lists(x, density, "cubic", h, 1.0, 1000.0)
        return lists, lists.fluid.count.numpy(), lists.fluid.index.numpy(), density.numpy()

    big, count, index, _ = built(256)
    assert big.overflow() == 0
    capacity = int(np.median(count))
    small, small_count, small_index, small_density = built(capacity)
    np.testing.assert_array_equal(small_count, count)
    full = count >= capacity
    assert (count == capacity).any() and (count > capacity).any() and (count < capacity).any()
    for i in range(len(fluid)):
        c = min(count[i], capacity)
        np.testing.assert_array_equal(small_index[i, :c], index[i, :c])
    assert small.overflow() == count.max()
    # the density of the stored pairs (all of them where the list is not full)
    from sph_oracle import W

    stored = [W("cubic", np.linalg.norm(fluid[i] - fluid[small_index[i, :min(count[i], capacity)]], axis=1), h).sum()
              for i in range(len(fluid))]
    np.testing.assert_allclose(small_density, np.array(stored), rtol=2e-5)
    assert full.any()
