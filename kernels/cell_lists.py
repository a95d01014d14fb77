"""Building the dense cell grid of ``warp_sph/neighbors/cell_lists.py`` (``CellGrid``): each point's cell key, the
cells' start offsets after the sort, the points gathered in cell order, and the mask of the cells near the moving
boundary particles. The walks over the grid are in ``neighbors.py``."""
import warp as wp

from .neighbors import cell_of


@wp.kernel(enable_backward=False)
def compute_cell_keys(
    tid_offset: int,
    # Grid:
    grid_lo: wp.vec3,
    inv_cell_size: float,
    grid_dims: wp.vec3i,
    # In:
    points: wp.array(dtype=wp.vec3),
    # Out (length 2 n for the radix sort):
    cell_key_out: wp.array(dtype=wp.int32),
    cell_point_out: wp.array(dtype=wp.int32),
):
    """Linear cell index (x fastest) of every point, and the identity permutation."""
    i = wp.tid() + tid_offset
    c = cell_of(points[i], grid_lo, inv_cell_size, grid_dims)
    cell_key_out[i] = c[0] + grid_dims[0] * (c[1] + grid_dims[1] * c[2])
    cell_point_out[i] = i


@wp.kernel(enable_backward=False)
def compute_cell_start(
    tid_offset: int,
    # In:
    point_count: int,
    cell_count: int,
    cell_key: wp.array(dtype=wp.int32),
    # Out:
    cell_start_out: wp.array(dtype=wp.int32),
):
    """cell_start[c] = first sorted index with key >= c, for c = 0..cell_count (point_count + 1 threads).
    Every entry is written by exactly one thread."""
    k = wp.tid() + tid_offset
    below = int(-1)
    if k > 0:
        below = int(cell_key[k - 1])
    above = cell_count
    if k < point_count:
        above = int(cell_key[k])
    for c in range(below + 1, above + 1):
        cell_start_out[c] = k


@wp.kernel(enable_backward=False)
def gather_sorted_points(
    tid_offset: int,
    # In:
    points: wp.array(dtype=wp.vec3),
    cell_point: wp.array(dtype=wp.int32),
    # Out:
    sorted_points_out: wp.array(dtype=wp.vec3),
):
    k = wp.tid() + tid_offset
    sorted_points_out[k] = points[cell_point[k]]


@wp.kernel(enable_backward=False)
def mark_near_cells(
    tid_offset: int,
    # Grid:
    grid_lo: wp.vec3,
    inv_cell_size: float,
    grid_dims: wp.vec3i,
    # In:
    points: wp.array(dtype=wp.vec3),
    # Out (cleared by the caller):
    cell_mask_out: wp.array(dtype=wp.uint8),
):
    """cell_mask = 1 in the cell of every point and its 26 neighbours (the mask of the moving boundary
    particles, rebuilt when they move). Threads only ever write 1: the result is the same in any order."""
    c = cell_of(points[wp.tid() + tid_offset], grid_lo, inv_cell_size, grid_dims)
    for dz in range(-1, 2):
        z = c[2] + dz
        if z >= 0 and z < grid_dims[2]:
            for dy in range(-1, 2):
                y = c[1] + dy
                if y >= 0 and y < grid_dims[1]:
                    for dx in range(-1, 2):
                        x = c[0] + dx
                        if x >= 0 and x < grid_dims[0]:
                            cell_mask_out[x + grid_dims[0] * (y + grid_dims[1] * z)] = wp.uint8(1)
