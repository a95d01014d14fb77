"""Cell grids split into slabs along x (``CellGrid(x_split=k)``, ``row_points_split``): the same cells and
cell starts as the unsplit grid, rows trimmed at the slabs' width that still reach every point within the
radius (brute force, points outside the grid's box included) with fewer candidates, and DFSPH's search on
them equal to the unsplit search up to float rounding (the pairs are summed in another order)."""
import numpy as np
import pytest
import warp as wp

from small_scenes import small_tank
from warp_sph.kernels.neighbors import cell_rows, row_points_split
from warp_sph.neighbors.cell_lists import CellGrid


@wp.kernel(enable_backward=False)
def walk_split_rows(grid_lo: wp.vec3, inv_cell_size: float, grid_dims: wp.vec3i, sub_start: wp.array(dtype=wp.int32),
                    x_split: int, cell_point: wp.array(dtype=wp.int32), sorted_x: wp.array(dtype=wp.vec3),
                    radius: float, query_x: wp.array(dtype=wp.vec3),
                    candidates_out: wp.array(dtype=wp.int32), found_out: wp.array2d(dtype=wp.int32)):
    """Every point of the trimmed rows within ``radius`` of query i (the search's walk), and the candidates."""
    i = wp.tid()
    xi = query_x[i]
    q = (xi - grid_lo) * inv_cell_size
    qr = radius * inv_cell_size
    rows = cell_rows(q, qr, grid_dims)
    n = int(0)
    seen = int(0)
    for z in range(rows[2], rows[3] + 1):
        for y in range(rows[0], rows[1] + 1):
            span = row_points_split(q, qr, y, z, grid_dims, sub_start, x_split)
            k = span[0]
            while k < span[1]:
                seen += 1
                d = xi - sorted_x[k]
                if wp.dot(d, d) < radius * radius and n < found_out.shape[1] - 1:  # the last slot: n
                    found_out[i, n] = cell_point[k]
                    n += 1
                k += 1
    candidates_out[i] = seen
    found_out[i, found_out.shape[1] - 1] = n


def walk(grid, points, queries, radius, device):
    cand = wp.zeros(len(queries), dtype=wp.int32, device=device)
    found = wp.zeros((len(queries), 97), dtype=wp.int32, device=device)
    wp.launch(walk_split_rows, len(queries), [grid.lo, grid.inv_cell_size, grid.dims, grid.sub_start, grid.x_split,
                                              grid.cell_point, grid.sorted_x, radius,
                                              wp.array(queries, dtype=wp.vec3, device=device)],
              [cand, found], device=device)
    f = found.numpy()
    assert (f[:, -1] < f.shape[1] - 1).all()  # every neighbour fit
    return cand.numpy(), [set(row[: row[-1]].tolist()) for row in f]


@pytest.mark.parametrize("x_split", [2, 4, 8])
def test_split_rows_reach_every_neighbour_with_fewer_candidates(x_split, device):
    """Points in [-0.5, 0.5]^3 and 30 beyond the grid's box on every side (clamped into its border cells and
    slabs), queried from points and from other places: the walk over the split grid finds exactly the brute-force
    neighbours, the cell starts are the unsplit grid's, the points are sorted by cell, and the candidates drop."""
    rng = np.random.default_rng(3 + x_split)
    radius = 0.1
    pts = rng.uniform(-0.5, 0.5, (2500, 3)).astype(np.float32)
    pts[:30] *= np.float32(1.6)  # beyond the box [-0.55, 0.55]^3 of the grid
    queries = np.concatenate([pts[:400], rng.uniform(-0.7, 0.7, (200, 3)).astype(np.float32)])
    x = wp.array(pts, dtype=wp.vec3, device=device)
    plain = CellGrid(radius, [-0.55] * 3, [0.55] * 3, len(pts), device=device)
    split = CellGrid(radius, [-0.55] * 3, [0.55] * 3, len(pts), device=device, x_split=x_split)
    plain.build(x)
    split.build(x)
    np.testing.assert_array_equal(split.cell_start.numpy(), plain.cell_start.numpy())
    order = split.cell_point.numpy()[: len(pts)]
    assert sorted(order.tolist()) == list(range(len(pts)))
    # within each cell the points follow their slabs: sub_start is non-decreasing and brackets every cell
    sub = split.sub_start.numpy()
    assert (np.diff(sub) >= 0).all() and np.array_equal(sub[::x_split], plain.cell_start.numpy())
    dist = np.linalg.norm(queries[:, None].astype(np.float64) - pts[None].astype(np.float64), axis=2)
    ambiguous = np.abs(dist - radius) < 1e-6
    c_plain, f_plain = walk(plain, pts, queries, radius, device)
    c_split, f_split = walk(split, pts, queries, radius, device)
    for i in range(len(queries)):
        ref = set(np.nonzero(dist[i] < radius)[0]) - set(np.nonzero(ambiguous[i])[0])
        assert f_split[i] - set(np.nonzero(ambiguous[i])[0]) == ref, i
        assert f_split[i] == f_plain[i]
    assert sum(len(f) for f in f_split) > 5 * len(queries)  # not vacuous
    assert c_split.sum() < 0.9 * c_plain.sum()


def test_cell_grid_refuses_a_split_that_is_not_a_power_of_two():
    with pytest.raises(ValueError, match="x_split must be a power of 2"):
        CellGrid(0.1, [0.0] * 3, [1.0] * 3, 10, x_split=3)


def test_dfsph_on_split_cells_equals_unsplit_to_rounding(monkeypatch, device):
    """A dam break in a small tank, 30 steps of DFSPH with the search's grids split 4 x along x (the default)
    and unsplit: the same pair counts after the first step, positions within 1e-5 d (the sums run in
    another order)."""
    import warp_sph.methods.solvers.dfsph as dfsph
    from warp_sph.run.simulation import Simulation

    def run(x_split):
        monkeypatch.setattr(dfsph, "SEARCH_X_SPLIT", x_split)
        sim = Simulation(small_tank("slabs"), device=device)
        assert sim.fields["neighbor_lists"].fluid_cells.x_split == x_split
        sim.step(4e-3)
        counts = sim.fields["dfsph_pairs"].count.numpy()[: sim.model.fluid_count].copy()
        for _ in range(29):
            sim.step(4e-3)
        return counts, sim.get_field("particle_x"), sim.model.spacing

    c1, x1, spacing = run(1)
    c4, x4, _ = run(4)
    assert c1.sum() > 10 * len(c1)
    np.testing.assert_array_equal(c1, c4)
    assert np.abs(x1 - x4).max() < 1e-5 * spacing
