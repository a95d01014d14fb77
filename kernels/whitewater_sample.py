"""The fluid around a secondary particle (whitewater), sampled from a node grid instead of walked per particle.

What a secondary particle at x reads of the fluid (fluid neighbours j within the support H):
    S(x) = (sum_j W(|x - x_j|) v_j,  sum_j W(|x - x_j|),  #{j : |x - x_j| < H})      [m/s /m^3, 1/m^3, -]
giving the kernel-averaged velocity v~_f = S_0..2 / S_3 and the neighbour count S_4.

Exact, that is one walk over the fluid cells per secondary particle (``fluid_sum``). Sampled, S is
evaluated once per step at the nodes x_n = node_lo + s (a, b, c) of a grid of spacing s next to a
secondary particle (``mark_nodes`` flags them and their rows, ``node_sums`` walks the fluid once per
flagged node, one thread per flagged row),
and each particle interpolates trilinearly: S~(x) = sum_n lambda_n(x) S(x_n) over its cell's 8 nodes
(``sample_nodes``). S~_0..2 / S~_3 is again a weighted average of the fluid's velocities (weights
sum_n lambda_n W(|x_n - x_j|) >= 0), so a uniform flow is sampled exactly; the count is interpolated
(a real number). Each flag is written 1 by any number of particles and cleared by its node's own
thread, and every sum is a gather: deterministic, no atomics.
"""
import functools

import warp as wp

from .neighbors import cell_rows, row_points
from .smoothing import SMOOTHING_FUNCTIONS

#: (sum_j W v_j [3], sum_j W, neighbour count): what a secondary particle reads of the fluid
vec5 = wp.types.vector(length=5, dtype=float)


@functools.cache
def fluid_sum_func(smoothing: str):
    """wp.func S(x) by one walk over the fluid cell grid (``CellGrid``: cells of at least ``search_radius``; the
    shared walk of kernels/neighbors.py, ``cell_rows`` / ``row_points``)."""
    value, _ = SMOOTHING_FUNCTIONS[smoothing]

    @wp.func
    def fluid_sum(
        x: wp.vec3,
        smoothing_length: float,
        support_radius: float,
        grid_lo: wp.vec3,
        inv_cell_size: float,
        grid_dims: wp.vec3i,
        cell_start: wp.array(dtype=wp.int32),
        cell_point: wp.array(dtype=wp.int32),
        search_radius: float,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
    ) -> vec5:
        support2 = support_radius * support_radius
        q = (x - grid_lo) * inv_cell_size
        qr = search_radius * inv_cell_size
        rows = cell_rows(q, qr, grid_dims)
        count = float(0.0)
        weight = float(0.0)
        v_sum = wp.vec3(0.0)
        for z in range(rows[2], rows[3] + 1):
            for y in range(rows[0], rows[1] + 1):
                span = row_points(q, qr, y, z, grid_dims, cell_start)
                for s in range(span[0], span[1]):
                    j = cell_point[s]
                    r = x - particle_x[j]
                    r2 = wp.dot(r, r)
                    if r2 < support2:
                        w = wp.static(value)(wp.sqrt(r2), smoothing_length)
                        count += 1.0
                        weight += w
                        v_sum += w * particle_v[j]
        return vec5(v_sum[0], v_sum[1], v_sum[2], weight, count)

    return fluid_sum


@wp.func
def node_cell(x: wp.vec3, node_lo: wp.vec3, inv_spacing: float, node_dims: wp.vec3i) -> wp.vec4:
    """(a, b, c) of the node cell holding x and 1, or 0 in the last slot when x is outside the node grid;
    the fractions are q - (a, b, c) with q = (x - node_lo) / s."""
    q = (x - node_lo) * inv_spacing
    a = wp.floor(q[0])
    b = wp.floor(q[1])
    c = wp.floor(q[2])
    inside = float(0.0)  # written so that a NaN coordinate is outside
    if a >= 0.0 and b >= 0.0 and c >= 0.0:
        if a < float(node_dims[0] - 1) and b < float(node_dims[1] - 1) and c < float(node_dims[2] - 1):
            inside = 1.0
    return wp.vec4(a, b, c, inside)


@wp.kernel(enable_backward=False)
def mark_nodes(tid_offset: int, node_lo: wp.vec3, inv_spacing: float, node_dims: wp.vec3i,
               ww_x: wp.array(dtype=wp.vec3), flag: wp.array(dtype=wp.uint8), row_flag: wp.array(dtype=wp.uint8)):
    """flag = 1 on the 8 nodes of each secondary particle's node cell (inside the node grid), row_flag = 1 on
    their 4 rows (nodes along x)."""
    cell = node_cell(ww_x[wp.tid() + tid_offset], node_lo, inv_spacing, node_dims)
    if cell[3] == 0.0:
        return
    row = int(cell[1]) + node_dims[1] * int(cell[2])
    for dz in range(2):
        for dy in range(2):
            r = row + dy + node_dims[1] * dz
            row_flag[r] = wp.uint8(1)
            flag[int(cell[0]) + node_dims[0] * r] = wp.uint8(1)
            flag[int(cell[0]) + 1 + node_dims[0] * r] = wp.uint8(1)


@functools.cache
def node_sums_kernel(smoothing: str):
    """S(x_n) at every flagged node, one thread per row of nodes (flags cleared on the way); other nodes keep
    stale values, never read."""
    fluid_sum = fluid_sum_func(smoothing)

    @wp.kernel(enable_backward=False, module="unique")
    def whitewater_node_sums(
        tid_offset: int,
        node_lo: wp.vec3,
        spacing: float,
        node_dims: wp.vec3i,
        smoothing_length: float,
        support_radius: float,
        grid_lo: wp.vec3,
        inv_cell_size: float,
        grid_dims: wp.vec3i,
        cell_start: wp.array(dtype=wp.int32),
        cell_point: wp.array(dtype=wp.int32),
        search_radius: float,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        flag: wp.array(dtype=wp.uint8),
        row_flag: wp.array(dtype=wp.uint8),
        node_out: wp.array(dtype=vec5),
    ):
        row = wp.tid() + tid_offset
        if row_flag[row] == wp.uint8(0):
            return
        row_flag[row] = wp.uint8(0)
        b = row % node_dims[1]
        c = row / node_dims[1]
        start = node_dims[0] * row
        for a in range(node_dims[0]):
            n = start + a
            if flag[n] != wp.uint8(0):
                flag[n] = wp.uint8(0)
                x = node_lo + spacing * wp.vec3(float(a), float(b), float(c))
                node_out[n] = fluid_sum(x, smoothing_length, support_radius, grid_lo, inv_cell_size, grid_dims,
                                        cell_start, cell_point, search_radius, particle_x, particle_v)

    return whitewater_node_sums


@wp.func
def sample_nodes(x: wp.vec3, cell: wp.vec4, node_lo: wp.vec3, inv_spacing: float, node_dims: wp.vec3i,
                 node: wp.array(dtype=vec5)) -> vec5:
    """S~(x) = sum over the 8 nodes of x's cell (``node_cell``, inside) of lambda_n S(x_n) (trilinear)."""
    q = (x - node_lo) * inv_spacing
    f = wp.vec3(q[0] - cell[0], q[1] - cell[1], q[2] - cell[2])
    base = int(cell[0]) + node_dims[0] * (int(cell[1]) + node_dims[1] * int(cell[2]))
    out = vec5()
    for dz in range(2):
        wz = 1.0 - f[2]
        if dz == 1:
            wz = f[2]
        for dy in range(2):
            wy = 1.0 - f[1]
            if dy == 1:
                wy = f[1]
            for dx in range(2):
                wx = 1.0 - f[0]
                if dx == 1:
                    wx = f[0]
                out += (wx * wy * wz) * node[base + dx + node_dims[0] * (dy + node_dims[1] * dz)]
    return out
