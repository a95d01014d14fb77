"""Device code of the narrow band of the sparse surface grid (``surface_grid.py``): block classes
(band, inside, outside), the meshed blocks (band blocks and the ghost blocks below them) and what
their cells see beyond their upper faces. Host launcher: ``warp_sph/surface/band.py``.
"""
import warp as wp

from .surface_grid import CLASS_BAND, CLASS_INSIDE, CLASS_OUTSIDE, SPRAY, STATE_INSIDE, STATE_OUTSIDE, SURFACE
from .surface_rows import row_range_block


@wp.kernel(enable_backward=False)
def classify_blocks(
    tid_offset: int,
    # Grid:
    grid_origin: wp.vec3,
    cell_size: float,
    block_nodes: int,
    # Parameters: band radius D [m] around surface particles; exact = 1 marks every block within the
    # support radius of a (non-spray) particle as band instead
    band_radius: float,
    support_radius: float,
    exact: int,
    # In:
    block_coord: wp.array(dtype=wp.vec3i),
    block_neighbor: wp.array2d(dtype=wp.int32),
    layer_start: wp.array2d(dtype=wp.int32),
    block_count: wp.array(dtype=wp.int32),
    sorted_x: wp.array(dtype=wp.vec3),
    particle_flag: wp.array(dtype=wp.int32),
    # Out: CLASS_BAND if a surface particle lies within D of the block's nodes, else CLASS_INSIDE if
    # any (non-spray) particle does, else CLASS_OUTSIDE
    block_class_out: wp.array(dtype=wp.int32),
):
    c = wp.tid() + tid_offset
    b = block_coord[c]
    lo = grid_origin + wp.vec3(float(b[0] * block_nodes), float(b[1] * block_nodes), float(b[2] * block_nodes)) * cell_size
    hi = lo + wp.vec3(float(block_nodes - 1) * cell_size)
    band2 = band_radius * band_radius
    if exact != 0:
        band2 = support_radius * support_radius
    cls = CLASS_OUTSIDE
    reach = wp.sqrt(band2) / cell_size
    for row in range(9):
        rng = row_range_block(block_neighbor, layer_start, block_count, c, row, reach, block_nodes)
        t = rng[0]
        while t < rng[1]:
            flag = particle_flag[t]
            if flag != SPRAY:
                x = sorted_x[t]
                d = wp.vec3(wp.max(wp.max(lo[0] - x[0], x[0] - hi[0]), 0.0),
                            wp.max(wp.max(lo[1] - x[1], x[1] - hi[1]), 0.0),
                            wp.max(wp.max(lo[2] - x[2], x[2] - hi[2]), 0.0))
                if wp.dot(d, d) <= band2:
                    if flag == SURFACE or exact != 0:
                        block_class_out[c] = CLASS_BAND
                        return
                    cls = CLASS_INSIDE
            t += 1
    block_class_out[c] = cls


@wp.kernel(enable_backward=False)
def mark_meshed_blocks(
    tid_offset: int,
    # In:
    block_class: wp.array(dtype=wp.int32),
    block_neighbor: wp.array2d(dtype=wp.int32),
    # Out: 1 for band blocks and for the blocks below them (offsets in {-1, 0}^3), pre-zeroed;
    # 1 for an inside block next to an outside one (6 faces; a missing block is outside)
    meshed_out: wp.array(dtype=wp.int32),
    contact_out: wp.array(dtype=wp.int32),
):
    """Blocks whose cells marching cubes visits: every cell with a band node as a corner is owned
    by a band block or by one of the 7 blocks below it ("ghost" blocks, Phi taken as 1 or 0 by
    their class). Concurrent threads only ever write 1, so the plain stores may race."""
    c = wp.tid() + tid_offset
    cls = block_class[c]
    if cls == CLASS_BAND:
        meshed_out[c] = 1
        for o in range(1, 8):
            n = block_neighbor[c, 13 - (o & 1) - 3 * ((o >> 1) & 1) - 9 * (o >> 2)]
            if n >= 0:
                meshed_out[n] = 1
    elif cls == CLASS_INSIDE:
        touch = int(0)
        for f in range(6):
            axis = f / 2
            step = 2 * (f % 2) - 1
            n = block_neighbor[c, 13 + step * wp.where(axis == 0, 1, wp.where(axis == 1, 3, 9))]
            if n < 0:
                touch = 1
            elif block_class[n] == CLASS_OUTSIDE:
                touch = 1
        contact_out[c] = touch


@wp.kernel(enable_backward=False)
def compact_meshed(
    tid_offset: int,
    # In: class and meshed flag per candidate block, inclusive scan of the flags
    block_class: wp.array(dtype=wp.int32),
    meshed: wp.array(dtype=wp.int32),
    meshed_scan: wp.array(dtype=wp.int32),
    # Out: state per candidate block (meshed index >= 0, else STATE_INSIDE / STATE_OUTSIDE by class);
    # candidate index of each meshed block and 1 where it is a band block (0: ghost)
    block_state_out: wp.array(dtype=wp.int32),
    meshed_block_out: wp.array(dtype=wp.int32),
    meshed_band_out: wp.array(dtype=wp.int32),
):
    c = wp.tid() + tid_offset
    if meshed[c] != 0:
        k = meshed_scan[c] - 1
        block_state_out[c] = k
        meshed_block_out[k] = c
        meshed_band_out[k] = int(block_class[c] == CLASS_BAND)
    elif block_class[c] == CLASS_INSIDE:
        block_state_out[c] = STATE_INSIDE
    else:
        block_state_out[c] = STATE_OUTSIDE


@wp.kernel(enable_backward=False)
def meshed_upper_neighbors(
    tid_offset: int,
    # In:
    meshed_block: wp.array(dtype=wp.int32),
    block_neighbor: wp.array2d(dtype=wp.int32),
    block_state: wp.array(dtype=wp.int32),
    # Out: per meshed block, the state of the blocks at offsets (o & 1, o >> 1 & 1, o >> 2), o = 0..7
    meshed_upper_out: wp.array2d(dtype=wp.int32),
):
    """What a meshed block's cells see at their upper corners: meshed index, STATE_INSIDE or STATE_OUTSIDE."""
    k = wp.tid() + tid_offset
    c = meshed_block[k]
    for o in range(8):
        n = block_neighbor[c, 13 + (o & 1) + 3 * ((o >> 1) & 1) + 9 * (o >> 2)]  # 13 = offset (0, 0, 0)
        state = STATE_OUTSIDE
        if n >= 0:
            state = block_state[n]
        meshed_upper_out[k, o] = state
