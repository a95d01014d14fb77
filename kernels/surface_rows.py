"""Device helpers of the surface's block grid (``kernels/surface_grid.py``): the particle range
of a row of three neighbour blocks restricted to a window along x (``row_span``), whole blocks
(``row_range``), around a point (``row_range_near``) or around a block (``row_range_block``), and a
point's position in a block's node units. Used by the grid, band, field and smoothing kernels; no
host counterpart.

Within a block the particles are sorted by their node layer along x (l = floor(g_x) - B b_x, 0..B-1;
``layer_start[c, l]``: first sorted particle of layer l of block c, ``layer_start[c, B]`` its end),
and the blocks of a row have consecutive keys, so the particles of a row whose node x lies in a
window are one contiguous range: a query visits only the layers its reach touches (5 of a row's 12
for a point at 2 cells' reach in blocks of 4 nodes) instead of whole blocks."""
import warp as wp


@wp.func
def row_span(
    block_neighbor: wp.array2d(dtype=wp.int32),
    layer_start: wp.array2d(dtype=wp.int32),
    block_count: wp.array(dtype=wp.int32),
    c: int,
    row: int,
    x_lo: float,
    x_hi: float,
    block_nodes: int,
) -> wp.vec2i:
    """Sorted particle range [begin, end) of the node layers x_lo..x_hi (node units from block c's
    lowest node; the layers of floor(x_lo) .. floor(x_hi)) of the three blocks of neighbour row
    ``row`` (dy = row % 3 - 1, dz = row / 3 - 1) around block c. Their keys and layers are
    consecutive, so the range is contiguous (module docstring)."""
    begin = int(2147483647)
    end = int(-1)
    f_lo = int(wp.floor(x_lo))
    f_hi = int(wp.floor(x_hi))
    for dx in range(3):
        l0 = wp.max(f_lo - (dx - 1) * block_nodes, 0)
        l1 = wp.min(f_hi - (dx - 1) * block_nodes, block_nodes - 1)
        if l0 <= l1:
            n = block_neighbor[c, row * 3 + dx]
            if n >= 0:
                if block_count[n] > 0:
                    begin = wp.min(begin, layer_start[n, l0])
                    end = wp.max(end, layer_start[n, l1 + 1])
    if end <= begin:
        return wp.vec2i(0, 0)
    return wp.vec2i(begin, end)


@wp.func
def row_range(
    block_neighbor: wp.array2d(dtype=wp.int32),
    layer_start: wp.array2d(dtype=wp.int32),
    block_count: wp.array(dtype=wp.int32),
    c: int,
    row: int,
    block_nodes: int,
) -> wp.vec2i:
    """``row_span`` of the whole row: the three blocks dx = -1..1."""
    return row_span(block_neighbor, layer_start, block_count, c, row, float(-block_nodes),
                    float(2 * block_nodes - 1), block_nodes)


@wp.func
def row_range_block(
    block_neighbor: wp.array2d(dtype=wp.int32),
    layer_start: wp.array2d(dtype=wp.int32),
    block_count: wp.array(dtype=wp.int32),
    c: int,
    row: int,
    reach: float,
    block_nodes: int,
) -> wp.vec2i:
    """``row_span`` of the layers within ``reach`` (node units) of block c's nodes along x (0..B-1)."""
    reach_m = reach + 0.01
    return row_span(block_neighbor, layer_start, block_count, c, row, -reach_m, float(block_nodes - 1) + reach_m,
                    block_nodes)


@wp.func
def row_range_near(
    block_neighbor: wp.array2d(dtype=wp.int32),
    layer_start: wp.array2d(dtype=wp.int32),
    block_count: wp.array(dtype=wp.int32),
    c: int,
    row: int,
    local: wp.vec3,
    reach: float,
    block_nodes: int,
) -> wp.vec2i:
    """``row_range`` restricted to the particles within ``reach`` of a point at ``local`` (node units,
    from block c's lowest node; both in node units): a row whose y or z slab lies farther is left
    out, and of the others only the node layers within reach along x are visited. Every particle
    left out is farther than ``reach`` (by more than a rounding margin), so a sum over the particles
    within ``reach`` adds the same terms in the same order as over the whole row."""
    reach_m = reach + 0.01
    bn = float(block_nodes)
    dy = row % 3 - 1
    dz = row / 3 - 1
    if (dy == -1 and local[1] > reach_m) or (dy == 1 and bn - local[1] > reach_m):
        return wp.vec2i(0, 0)
    if (dz == -1 and local[2] > reach_m) or (dz == 1 and bn - local[2] > reach_m):
        return wp.vec2i(0, 0)
    return row_span(block_neighbor, layer_start, block_count, c, row, local[0] - reach_m, local[0] + reach_m,
                    block_nodes)


@wp.func
def block_local(x: wp.vec3, grid_origin: wp.vec3, cell_size: float, block_nodes: int, b: wp.vec3i) -> wp.vec3:
    """Position x [m] in node units from the lowest node of block b."""
    g = (x - grid_origin) / cell_size
    return g - wp.vec3(float(b[0] * block_nodes), float(b[1] * block_nodes), float(b[2] * block_nodes))
