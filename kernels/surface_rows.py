"""Device helpers of the surface's block grid (``kernels/surface_grid.py``): the particle range
of a row of three neighbour blocks (``row_span``), whole (``row_range``) or restricted to the blocks
within a reach of a point (``row_range_near``), and a point's position in a block's node units. Used
by the grid, band, field and smoothing kernels; no host counterpart."""
import warp as wp


@wp.func
def row_span(
    block_neighbor: wp.array2d(dtype=wp.int32),
    block_start: wp.array(dtype=wp.int32),
    block_count: wp.array(dtype=wp.int32),
    c: int,
    row: int,
    dx0: int,
    dx1: int,
) -> wp.vec2i:
    """Sorted particle range [begin, end) of the blocks dx0..dx1 (0..2 for dx = -1..1) of neighbour row
    ``row`` (dy = row % 3 - 1, dz = row / 3 - 1) around block c: their keys are consecutive, so their
    particles are contiguous."""
    begin = int(2147483647)
    end = int(-1)
    for dx in range(dx0, dx1 + 1):
        n = block_neighbor[c, row * 3 + dx]
        if n >= 0:
            cnt = block_count[n]
            if cnt > 0:
                st = block_start[n]
                begin = wp.min(begin, st)
                end = wp.max(end, st + cnt)
    if end < 0:
        return wp.vec2i(0, 0)
    return wp.vec2i(begin, end)


@wp.func
def row_range(
    block_neighbor: wp.array2d(dtype=wp.int32),
    block_start: wp.array(dtype=wp.int32),
    block_count: wp.array(dtype=wp.int32),
    c: int,
    row: int,
) -> wp.vec2i:
    """``row_span`` of the whole row: the three blocks dx = -1..1."""
    return row_span(block_neighbor, block_start, block_count, c, row, 0, 2)


@wp.func
def row_range_near(
    block_neighbor: wp.array2d(dtype=wp.int32),
    block_start: wp.array(dtype=wp.int32),
    block_count: wp.array(dtype=wp.int32),
    c: int,
    row: int,
    local: wp.vec3,
    reach: float,
    block_nodes: int,
) -> wp.vec2i:
    """``row_range`` restricted to the blocks within ``reach`` of a point at ``local`` (node units,
    from block c's lowest node; both in node units): a row whose y or z slab lies farther, and the
    dx = -1 or +1 block of a row when farther, are left out. Every particle left out is farther
    than ``reach`` (by more than a rounding margin), so a sum over the particles within ``reach``
    adds the same terms in the same order as over the whole row."""
    reach_m = reach + 0.01
    bn = float(block_nodes)
    dy = row % 3 - 1
    dz = row / 3 - 1
    if (dy == -1 and local[1] > reach_m) or (dy == 1 and bn - local[1] > reach_m):
        return wp.vec2i(0, 0)
    if (dz == -1 and local[2] > reach_m) or (dz == 1 and bn - local[2] > reach_m):
        return wp.vec2i(0, 0)
    dx0 = int(0)
    dx1 = int(2)
    if local[0] > reach_m:
        dx0 = 1
    if bn - local[0] > reach_m:
        dx1 = 1
    return row_span(block_neighbor, block_start, block_count, c, row, dx0, dx1)


@wp.func
def block_local(x: wp.vec3, grid_origin: wp.vec3, cell_size: float, block_nodes: int, b: wp.vec3i) -> wp.vec3:
    """Position x [m] in node units from the lowest node of block b."""
    g = (x - grid_origin) / cell_size
    return g - wp.vec3(float(b[0] * block_nodes), float(b[1] * block_nodes), float(b[2] * block_nodes))
