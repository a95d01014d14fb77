"""Device code of the colour field on the band blocks of the sparse surface grid
(``surface_grid.py``). Host launcher: ``warp_sph/surface/field.py``.

    Phi(x) = sum_j f(|x - x_j|) / rho~_j,   rho~_j = sum_k f(|x_j - x_k|)  (k includes j),
    f(r) = (1 - r^2 / R^2)^5 for r < R (R: the smoothing kernel's support radius),
    Psi(x) = sum_j n_j f(|x - x_j|) / rho~_j  (n_j: weighted neighbour count; Psi / Phi feeds the
    smoothing's feature weights, ``surface_marching.emit_vertices``)
"""
import warp as wp

from .surface_grid import CLASS_BAND, CLASS_INSIDE, field_kernel
from .surface_rows import row_range_block


@wp.kernel(enable_backward=False)
def splat_band(
    tid_offset: int,
    # Model:
    support_radius: float,
    # Grid: ``slabs`` threads per band block, each owning B / slabs node layers along x
    grid_origin: wp.vec3,
    cell_size: float,
    block_nodes: int,
    slabs: int,
    # In:
    meshed_block: wp.array(dtype=wp.int32),
    block_class: wp.array(dtype=wp.int32),
    block_coord: wp.array(dtype=wp.vec3i),
    block_neighbor: wp.array2d(dtype=wp.int32),
    layer_start: wp.array2d(dtype=wp.int32),
    block_count: wp.array(dtype=wp.int32),
    sorted_x: wp.array(dtype=wp.vec3),
    inv_kernel_sum: wp.array(dtype=float),
    weighted_count: wp.array(dtype=float),
    # Out: Phi at the nodes of the meshed blocks, B^3 values per block, node (i, j, k) of block k
    # at k B^3 + (i B + j) B + k (local indices); Psi = sum_j n_j f_j / rho~_j at the same nodes
    field_out: wp.array(dtype=float),
    weighted_field_out: wp.array(dtype=float),
):
    """Band blocks: Phi(node) = sum_j f(|node - x_j|) / rho~_j and Psi(node) = sum_j n_j f(|node - x_j|)
    / rho~_j (n_j: weighted neighbour count; Psi / Phi is its Shepard interpolation, the feature
    measure of the smoothing) over the particles near the block, each thread writing only its own
    nodes (no atomics), adding each particle over its support sphere. Ghost blocks: Phi 1 (inside)
    or 0 (outside) by class, Psi 0 (no crossing edge ends at a ghost node in an extracted mesh)."""
    tid = wp.tid() + tid_offset
    k = tid / slabs
    slab = tid - k * slabs
    c = meshed_block[k]
    cls = block_class[c]
    bsz = block_nodes
    b = block_coord[c]
    n0 = wp.vec3i(b[0] * bsz, b[1] * bsz, b[2] * bsz)
    i_lo = n0[0] + (slab * bsz) / slabs
    i_hi = n0[0] + ((slab + 1) * bsz) / slabs - 1
    base = k * bsz * bsz * bsz
    # zero this thread's nodes (ghost blocks: their class value)
    fill = float(0.0)
    if cls == CLASS_INSIDE:
        fill = 1.0
    node = base + (i_lo - n0[0]) * bsz * bsz
    last = base + (i_hi - n0[0] + 1) * bsz * bsz
    while node < last:
        field_out[node] = fill
        weighted_field_out[node] = 0.0
        node += 1
    if cls != CLASS_BAND:
        return
    s_nodes = support_radius / cell_size
    s2 = s_nodes * s_nodes
    inv_s2 = 1.0 / s2
    k_lo = n0[2]
    k_hi = n0[2] + bsz - 1
    for row in range(9):
        rng = row_range_block(block_neighbor, layer_start, block_count, c, row, s_nodes, bsz)
        t = rng[0]
        while t < rng[1]:
            weight = inv_kernel_sum[t]
            if weight > 0.0:
                weight_n = weight * weighted_count[t]
                g = (sorted_x[t] - grid_origin) / cell_size
                i0 = wp.max(int(wp.ceil(g[0] - s_nodes)), i_lo)
                i1 = wp.min(int(wp.floor(g[0] + s_nodes)), i_hi)
                j0 = wp.max(int(wp.ceil(g[1] - s_nodes)), n0[1])
                j1 = wp.min(int(wp.floor(g[1] + s_nodes)), n0[1] + bsz - 1)
                k0 = wp.max(int(wp.ceil(g[2] - s_nodes)), k_lo)
                k1 = wp.min(int(wp.floor(g[2] + s_nodes)), k_hi)
                dz0 = float(k0) - g[2]
                # local node indices are >= 0: wp.max lets the compiler drop Warp's negative-index
                # wrap, and the inner loop (the whole clipped column, f is 0 beyond the
                # support) vectorizes
                kk0 = wp.max(k0 - k_lo, 0)
                kk1 = k1 - k_lo
                i = i0
                while i <= i1:
                    dx = float(i) - g[0]
                    j = j0
                    while j <= j1:
                        dy = float(j) - g[1]
                        r2_xy = dx * dx + dy * dy
                        if r2_xy < s2:
                            col = wp.max(base + ((i - n0[0]) * bsz + (j - n0[1])) * bsz, 0)
                            kk = kk0
                            dz = dz0
                            while kk <= kk1:
                                fk = field_kernel(r2_xy + dz * dz, inv_s2)
                                field_out[col + kk] = field_out[col + kk] + weight * fk
                                weighted_field_out[col + kk] = weighted_field_out[col + kk] + weight_n * fk
                                kk += 1
                                dz += 1.0
                        j += 1
                    i += 1
            t += 1

