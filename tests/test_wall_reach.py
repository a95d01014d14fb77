"""DFSPH's static walls in reach of each sub-cell (``WallReach``, built once per run): every wall particle
within the radius of a query is in its sub-cell's list, in the cell walk's order (ascending sorted index),
against a brute-force NumPy oracle (queries and walls outside the grid included); finer sub-cells give
shorter lists; and a DFSPH run with the lists (and with a moving body, whose grid is still walked) is bitwise
the run that walks the wall grid every step."""
import numpy as np
import pytest
import warp as wp

from small_scenes import small_tank
from warp_sph.kernels.wall_reach import subcell_of
from warp_sph.neighbors import wall_reach
from warp_sph.neighbors.cell_lists import CellGrid
from warp_sph.run.simulation import Simulation


@wp.kernel(enable_backward=False)
def listed_in_reach(grid_lo: wp.vec3, inv_size: float, dims: wp.vec3i, start: wp.array(dtype=wp.int32),
                    entry: wp.array(dtype=wp.int32), sorted_points: wp.array(dtype=wp.vec3), radius: float,
                    queries: wp.array(dtype=wp.vec3), found_out: wp.array2d(dtype=wp.int32),
                    listed_out: wp.array(dtype=wp.int32)):
    """The listed points of each query's sub-cell closer than radius, in list order (-1 after the last)."""
    i = wp.tid()
    xi = queries[i]
    s = subcell_of(xi, grid_lo, inv_size, dims)
    n = int(0)
    e = start[s]
    while e < start[s + 1]:
        k = entry[e]
        d = xi - sorted_points[k]
        if wp.dot(d, d) < radius * radius and n < found_out.shape[1]:
            found_out[i, n] = k
            n += 1
        e += 1
    listed_out[i] = start[s + 1] - start[s]


def walls_and_queries(rng, radius):
    """Wall points on the faces of a box (two layers, some past the grid's end) and queries around them."""
    pts = rng.uniform(-0.5, 0.5, size=(1500, 3))
    face = rng.integers(0, 3, size=len(pts))
    pts[np.arange(len(pts)), face] = np.where(rng.random(len(pts)) < 0.5, -1, 1) * rng.uniform(0.45, 0.5 + radius,
                                                                                                  len(pts))
    queries = rng.uniform(-0.62, 0.62, size=(3000, 3))  # some beyond the grid of [-0.55, 0.55]^3
    return pts.astype(np.float32), queries.astype(np.float32)


@pytest.mark.parametrize("subcells", [1, 2, 4])
def test_sub_cell_lists_hold_every_wall_in_reach_in_walk_order(subcells, device):
    """Every wall point closer than the radius to a query is found from the query's sub-cell list, in
    ascending sorted index (the order of the cell walk), for queries inside and outside the grid."""
    radius = 0.1
    rng = np.random.default_rng(7 + subcells)
    pts, queries = walls_and_queries(rng, radius)
    grid = CellGrid(radius, [-0.55] * 3, [0.55] * 3, len(pts), device=device)
    grid.build(wp.array(pts, dtype=wp.vec3, device=device))
    reach = wall_reach.WallReach(grid, radius, subcells, device=device)
    assert reach.subcells == subcells and reach.entries > 0
    start, entry = reach.start.numpy(), reach.entry.numpy()
    for s in np.nonzero(np.diff(start) > 1)[0][:200]:
        assert (np.diff(entry[start[s]:start[s + 1]]) > 0).all()  # ascending k in every list
    found = wp.full((len(queries), 64), -1, dtype=wp.int32, device=device)
    listed = wp.zeros(len(queries), dtype=wp.int32, device=device)
    wp.launch(listed_in_reach, len(queries), [grid.lo, reach.inv_size, reach.dims, reach.start, reach.entry,
                                              grid.sorted_x, radius, wp.array(queries, dtype=wp.vec3, device=device)],
              [found, listed], device=device)
    found = found.numpy()
    sorted_x = grid.sorted_x.numpy().astype(np.float64)
    dist = np.linalg.norm(queries[:, None, :].astype(np.float64) - sorted_x[None], axis=2)
    close = 0
    for i in range(len(queries)):
        expect = np.nonzero(dist[i] < radius)[0]  # ascending sorted index
        got = found[i][found[i] >= 0]
        borderline = np.abs(dist[i] - radius) < 1e-5 * radius  # rounding may go either way
        assert np.array_equal(got[~borderline[got]], expect[~borderline[expect]])
        close += len(expect)
    assert close > 2 * len(queries)  # the queries do meet walls


def test_finer_sub_cells_give_shorter_lists(device):
    """The reach of a sub-cell of side a is its box grown by the radius: 1 -> 2 -> 4 sub-cells per cell
    shrink the mean list at a query (20.6 -> 10.5 -> 6.9 radius^3 of reach for cells of the radius)."""
    radius = 0.1
    pts, queries = walls_and_queries(np.random.default_rng(3), radius)
    grid = CellGrid(radius, [-0.55] * 3, [0.55] * 3, len(pts), device=device)
    grid.build(wp.array(pts, dtype=wp.vec3, device=device))
    means = []
    for subcells in (1, 2, 4):
        reach = wall_reach.WallReach(grid, radius, subcells, device=device)
        found = wp.zeros((len(queries), 1), dtype=wp.int32, device=device)
        listed = wp.zeros(len(queries), dtype=wp.int32, device=device)
        wp.launch(listed_in_reach, len(queries), [grid.lo, reach.inv_size, reach.dims, reach.start, reach.entry,
                                                  grid.sorted_x, radius,
                                                  wp.array(queries, dtype=wp.vec3, device=device)],
                  [found, listed], device=device)
        means.append(listed.numpy().mean())
    assert means[0] > 1.5 * means[1] > 1.5 * 1.2 * means[2] > 0


def test_dfsph_with_wall_lists_is_bitwise_the_wall_walk(monkeypatch, device):
    """A dam break in a small tank, 30 steps: with the walls' sub-cell lists (1, 2 and 4 per cell) the
    state, density and boundary neighbour lists are bitwise those of the per-step wall walk."""
    def run(subcells):
        monkeypatch.setattr(wall_reach, "WALL_SUBCELLS", subcells)
        sim = Simulation(small_tank("walls"), device=device)
        for _ in range(30):
            sim.step(4e-3)
        return check_walls(sim, subcells)

    compare(run, (1, 2, 4))


def test_dfsph_with_a_moving_body_lists_the_static_walls_then_walks_the_body(monkeypatch, device):
    """A box moving in a pool (tests/test_rigid_stages.py), 4 steps: the static walls from their lists and
    the body's particles from the per-step walk of its grid, bitwise the run that walks both."""
    from test_rigid_stages import pool

    def run(subcells):
        monkeypatch.setattr(wall_reach, "WALL_SUBCELLS", subcells)
        sim = Simulation(pool(solver="dfsph"), device=device)
        for _ in range(4):
            sim.step(2e-3)
        assert sim.solver.nl.moving_cells is not None
        S = sim.model.static_boundary_count
        nl, n = sim.fields["neighbor_lists"], sim.model.fluid_count
        assert (nl.boundary.index.numpy()[:n] >= S).any()  # the body is among the neighbours
        return check_walls(sim, subcells)

    compare(run, (1,))


def check_walls(sim, subcells):
    """The state, density and boundary neighbour lists of a run (walls met; lists built unless subcells = 0)."""
    assert (sim.solver._walls is None) == (subcells == 0)
    nl = sim.fields["neighbor_lists"]
    n = sim.model.fluid_count
    count = nl.boundary.count.numpy()[:n]
    assert count.sum() > n  # the walls were met
    index = nl.boundary.index.numpy()[:n]
    rows = [index[i, :c] for i, c in enumerate(count)]
    return [sim.get_field(f) for f in ("particle_x", "particle_v", "particle_density")], count, rows


def compare(run, subcells_list):
    """``run(subcells)`` with the lists equal bit for bit to ``run(0)`` (the wall walk)."""
    walk, walk_count, walk_rows = run(0)
    for subcells in subcells_list:
        fields, count, rows = run(subcells)
        for a, b in zip(walk, fields):
            assert np.array_equal(a, b)
        assert np.array_equal(walk_count, count)
        assert all(np.array_equal(a, b) for a, b in zip(walk_rows, rows))
