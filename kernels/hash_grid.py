"""Neighbour lists collected over a ``wp.HashGrid`` (host: ``warp_sph/neighbors/hash_grid.py``; diagnostics and
tests, not the step)."""
import warp as wp


@wp.kernel(enable_backward=False)
def collect_neighbors(
    # In:
    grid: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    query_x: wp.array(dtype=wp.vec3),
    radius: float,
    capacity: int,
    # Out:
    neighbor_count_out: wp.array(dtype=int),
    neighbor_index_out: wp.array2d(dtype=int),
):
    """Indices j with |query_x[i] - points[j]| < radius (up to ``capacity`` per query; the count is exact)."""
    i = wp.tid()
    xi = query_x[i]
    count = int(0)
    query = wp.hash_grid_query(grid, xi, radius)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        if wp.length(xi - points[j]) < radius:
            if count < capacity:
                neighbor_index_out[i, count] = j
            count += 1
    neighbor_count_out[i] = count
