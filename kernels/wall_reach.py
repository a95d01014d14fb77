"""The static walls in reach of each cell, built once per run (host half ``warp_sph/neighbors/wall_reach.py``).

The fluid's cell grid frame (the static boundary ``CellGrid``'s lo and cell size, fixed for the run) is
cut into sub-cells, ``subcells`` per cell along each axis. For each sub-cell the list holds the static
boundary particles (their sorted index k in the boundary grid) within the reach r [cells] of the
sub-cell's box, in ascending k: the order the per-step cell walk (``cell_rows`` / ``row_points``) visits
them in. Border sub-cells extend to infinity outward (fluid points outside the grid are clamped into
them). A fluid particle in sub-cell s then tests only the list of s; every boundary particle within
r of it is in that list, in the walk's order, so the neighbours and their sums are those of the walk.
"""
import warp as wp


@wp.func
def subcell_of(x: wp.vec3, grid_lo: wp.vec3, inv_size: float, dims: wp.vec3i) -> int:
    """Linear index (x fastest) of the sub-cell of x [m] (inv_size: 1 / sub-cell size [1/m]), clamped to the
    sub-cell grid of ``dims``."""
    q = (x - grid_lo) * inv_size
    sx = wp.clamp(int(wp.floor(q[0])), 0, dims[0] - 1)
    sy = wp.clamp(int(wp.floor(q[1])), 0, dims[1] - 1)
    sz = wp.clamp(int(wp.floor(q[2])), 0, dims[2] - 1)
    return sx + dims[0] * (sy + dims[1] * sz)


@wp.func
def gap_to_box(q: float, lo: float, hi: float) -> float:
    """Distance from q to the interval [lo, hi] along one axis (0 inside)."""
    if q < lo:
        return lo - q
    if q > hi:
        return q - hi
    return 0.0


@wp.kernel(enable_backward=False)
def walls_in_reach(
    tid_offset: int,
    # Boundary cell grid (cell units: q = (x - grid_lo) / cell size):
    grid_lo: wp.vec3,
    inv_cell_size: float,
    grid_dims: wp.vec3i,
    cell_start: wp.array(dtype=wp.int32),
    sorted_points: wp.array(dtype=wp.vec3),
    # Sub-cells:
    subcells: int,
    cell_reach: float,
    reach: float,
    fill: int,
    entry_start: wp.array(dtype=wp.int32),
    # Out: counts (fill = 0) or the lists (fill = 1, at entry_start[s]):
    count_out: wp.array(dtype=wp.int32),
    entry_out: wp.array(dtype=wp.int32),
):
    """One thread per sub-cell s: the boundary particles k within ``reach`` [cells] of its box (border
    sub-cells open outward), counted (fill = 0) or written in ascending k from entry_start[s] (fill = 1).
    Only cells that the cell walk of a point in the sub-cell's parent cell can visit are read: those less
    than ``cell_reach`` = H_s / cell size [cells] of whole cells away (the walk's rows skip the others),
    so the rounding margin in ``reach`` adds no particle the walk would not test."""
    s = wp.tid() + tid_offset
    nx = grid_dims[0] * subcells
    ny = grid_dims[1] * subcells
    nz = grid_dims[2] * subcells
    sx = s % nx
    sy = (s // nx) % ny
    sz = s // (nx * ny)
    inv = 1.0 / float(subcells)
    big = 1.0e30
    lo = wp.vec3(float(sx) * inv, float(sy) * inv, float(sz) * inv)
    hi = wp.vec3(float(sx + 1) * inv, float(sy + 1) * inv, float(sz + 1) * inv)
    if sx == 0:
        lo = wp.vec3(-big, lo[1], lo[2])
    if sx == nx - 1:
        hi = wp.vec3(big, hi[1], hi[2])
    if sy == 0:
        lo = wp.vec3(lo[0], -big, lo[2])
    if sy == ny - 1:
        hi = wp.vec3(hi[0], big, hi[2])
    if sz == 0:
        lo = wp.vec3(lo[0], lo[1], -big)
    if sz == nz - 1:
        hi = wp.vec3(hi[0], hi[1], big)
    c0 = wp.vec3i(wp.clamp(int(wp.floor(wp.max(lo[0] - reach, -1.0))), 0, grid_dims[0] - 1),
                  wp.clamp(int(wp.floor(wp.max(lo[1] - reach, -1.0))), 0, grid_dims[1] - 1),
                  wp.clamp(int(wp.floor(wp.max(lo[2] - reach, -1.0))), 0, grid_dims[2] - 1))
    c1 = wp.vec3i(wp.clamp(int(wp.floor(wp.min(hi[0] + reach, float(grid_dims[0])))), 0, grid_dims[0] - 1),
                  wp.clamp(int(wp.floor(wp.min(hi[1] + reach, float(grid_dims[1])))), 0, grid_dims[1] - 1),
                  wp.clamp(int(wp.floor(wp.min(hi[2] + reach, float(grid_dims[2])))), 0, grid_dims[2] - 1))
    reach2 = reach * reach
    # only cells the walk of a point of the parent cell p can visit: whole cells between them < cell_reach
    p = wp.vec3i(sx // subcells, sy // subcells, sz // subcells)
    n = int(0)
    out = int(0)
    if fill != 0:
        out = entry_start[s]
    for z in range(c0[2], c1[2] + 1):
        gz = float(wp.max(wp.abs(z - p[2]) - 1, 0))
        for y in range(c0[1], c1[1] + 1):
            gy = float(wp.max(wp.abs(y - p[1]) - 1, 0))
            row = grid_dims[0] * (y + grid_dims[1] * z)
            for x in range(c0[0], c1[0] + 1):
                gx = float(wp.max(wp.abs(x - p[0]) - 1, 0))
                if gx * gx + gy * gy + gz * gz < cell_reach * cell_reach:
                    k = cell_start[row + x]
                    k_end = cell_start[row + x + 1]
                    while k < k_end:
                        q = (sorted_points[k] - grid_lo) * inv_cell_size
                        dx = gap_to_box(q[0], lo[0], hi[0])
                        dy = gap_to_box(q[1], lo[1], hi[1])
                        dz = gap_to_box(q[2], lo[2], hi[2])
                        if dx * dx + dy * dy + dz * dz < reach2:
                            if fill != 0:
                                entry_out[out + n] = k
                            n += 1
                        k += 1
    if fill == 0:
        count_out[s] = n
