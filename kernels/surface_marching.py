"""Device code of marching cubes on the sparse block grid (``kernels/surface_grid.py``).

Every node of a meshed block owns the cell whose lower corner it is and the three edges leaving it
towards +x, +y, +z. A crossing edge (one end >= iso, the other below) gets one vertex, linearly
interpolated as in ``warp.geometry.IsoSurfaceMarchingCubes``; a cell's triangles come from the
classic case table (``marching_cubes_tables.py``), the same as Warp's. Nodes of blocks that are not
meshed read 1 (inside) or 0 (outside). Three passes per unit (a block, or a slab of node layers of
it on a GPU): count, vertices, triangles; the host scans the counts between them, so the output is
ordered by block and deterministic. Host launcher: ``warp_sph/surface/marching.py``.
"""
import warp as wp

from .marching_cubes_tables import EDGE_OWNER, TRI_EDGES, TRI_RANGE

#: the tables as flat tuples for the host to upload
EDGE_OWNER_FLAT = tuple(v for e in EDGE_OWNER for v in e)
TRI_RANGE_TABLE = TRI_RANGE
TRI_EDGE_TABLE = TRI_EDGES


@wp.func
def node_slot(meshed_upper: wp.array2d(dtype=wp.int32), k: int, li: int, lj: int, lk: int, bsz: int) -> int:
    """Field index of local node (li, lj, lk) of meshed block k, each in 0..B (B: the next block);
    -1 (outside) or -2 (inside) where that block is not meshed."""
    o = int(0)
    if li >= bsz:
        li -= bsz
        o += 1
    if lj >= bsz:
        lj -= bsz
        o += 2
    if lk >= bsz:
        lk -= bsz
        o += 4
    s = k
    if o > 0:
        s = meshed_upper[k, o]
        if s < 0:
            return s
    return (s * bsz * bsz + li * bsz + lj) * bsz + lk


@wp.func
def slot_value(field: wp.array(dtype=float), slot: int) -> float:
    if slot >= 0:
        return field[slot]
    if slot == -2:
        return 1.0
    return 0.0


@wp.func
def slot_exact(meshed_band: wp.array(dtype=wp.int32), slot: int, block_volume: int) -> int:
    """1 where the node's value is Phi itself (a band block), 0 for ghost or unmeshed nodes."""
    if slot < 0:
        return 0
    return meshed_band[slot / block_volume]


@wp.kernel(enable_backward=False)
def block_value_range(
    tid_offset: int,
    # Grid:
    block_nodes: int,
    # In:
    field: wp.array(dtype=float),
    # Out: smallest and largest Phi of each meshed block
    block_min_out: wp.array(dtype=float),
    block_max_out: wp.array(dtype=float),
):
    k = wp.tid() + tid_offset
    vol = block_nodes * block_nodes * block_nodes
    s = wp.max(k * vol, 0)
    lo = field[s]
    hi = lo
    end = s + vol
    while s < end:
        v = field[s]
        lo = wp.min(lo, v)
        hi = wp.max(hi, v)
        s += 1
    block_min_out[k] = lo
    block_max_out[k] = hi


@wp.func
def block_uniform(
    meshed_upper: wp.array2d(dtype=wp.int32),
    block_min: wp.array(dtype=float),
    block_max: wp.array(dtype=float),
    k: int,
    iso_level: float,
) -> bool:
    """True when every node of block k and of the 7 blocks above it lies on one side of the level, so
    no cell of block k is crossed."""
    inside = block_min[k] >= iso_level
    outside = block_max[k] < iso_level
    for o in range(1, 8):
        s = meshed_upper[k, o]
        if s >= 0:
            inside = inside and block_min[s] >= iso_level
            outside = outside and block_max[s] < iso_level
        elif s == -2:
            outside = False
        else:
            inside = False
    return inside or outside


@wp.kernel(enable_backward=False)
def count_cells(
    tid_offset: int,
    # Grid:
    block_nodes: int,
    slabs: int,
    iso_level: float,
    # In:
    field: wp.array(dtype=float),
    meshed_upper: wp.array2d(dtype=wp.int32),
    meshed_band: wp.array(dtype=wp.int32),
    block_min: wp.array(dtype=float),
    block_max: wp.array(dtype=float),
    tri_range: wp.array(dtype=wp.int32),
    # Out: per node (field index) its crossing edges (bits 0-2) | case code << 3 (not written in a
    # block no cell of which is crossed: its unit counts are 0 and later passes skip it); per unit its
    # vertex and triangle counts and the crossing edges with an end that is not exact (ghost or unmeshed)
    node_code_out: wp.array(dtype=wp.int32),
    unit_vertices_out: wp.array(dtype=wp.int32),
    unit_triangles_out: wp.array(dtype=wp.int32),
    unit_inexact_out: wp.array(dtype=wp.int32),
):
    unit = wp.tid() + tid_offset
    k = unit / slabs
    slab = unit - k * slabs
    bsz = block_nodes
    vol = bsz * bsz * bsz
    li = (slab * bsz) / slabs
    li_end = ((slab + 1) * bsz) / slabs
    nv = int(0)
    nt = int(0)
    inexact = int(0)
    band = meshed_band[k]
    if block_uniform(meshed_upper, block_min, block_max, k, iso_level):
        li = li_end
    while li < li_end:
        lj = int(0)
        while lj < bsz:
            lk = int(0)
            while lk < bsz:
                s0 = (k * bsz * bsz + li * bsz + lj) * bsz + lk
                interior = li < bsz - 1 and lj < bsz - 1 and lk < bsz - 1  # all 8 corners in this block
                sx = s0 + bsz * bsz
                sy = s0 + bsz
                sz = s0 + 1
                if not interior:
                    sx = node_slot(meshed_upper, k, li + 1, lj, lk, bsz)
                    sy = node_slot(meshed_upper, k, li, lj + 1, lk, bsz)
                    sz = node_slot(meshed_upper, k, li, lj, lk + 1, bsz)
                v0 = field[s0] >= iso_level
                vx = slot_value(field, sx) >= iso_level
                vy = slot_value(field, sy) >= iso_level
                vz = slot_value(field, sz) >= iso_level
                mask = int(0)
                if vx != v0:
                    mask |= 1
                    if band == 0 or slot_exact(meshed_band, sx, vol) == 0:
                        inexact += 1
                if vy != v0:
                    mask |= 2
                    if band == 0 or slot_exact(meshed_band, sy, vol) == 0:
                        inexact += 1
                if vz != v0:
                    mask |= 4
                    if band == 0 or slot_exact(meshed_band, sz, vol) == 0:
                        inexact += 1
                nv += int(mask & 1) + int((mask >> 1) & 1) + int((mask >> 2) & 1)
                # corners in the order of the case table: (0,0,0) (1,0,0) (1,1,0) (0,1,0) (0,0,1) (1,0,1) (1,1,1) (0,1,1)
                s2 = sx + bsz
                s5 = sx + 1
                s6 = sx + bsz + 1
                s7 = sy + 1
                if not interior:
                    s2 = node_slot(meshed_upper, k, li + 1, lj + 1, lk, bsz)
                    s5 = node_slot(meshed_upper, k, li + 1, lj, lk + 1, bsz)
                    s6 = node_slot(meshed_upper, k, li + 1, lj + 1, lk + 1, bsz)
                    s7 = node_slot(meshed_upper, k, li, lj + 1, lk + 1, bsz)
                v2 = slot_value(field, s2) >= iso_level
                v5 = slot_value(field, s5) >= iso_level
                v6 = slot_value(field, s6) >= iso_level
                v7 = slot_value(field, s7) >= iso_level
                case = int(v0) | (int(vx) << 1) | (int(v2) << 2) | (int(vy) << 3)
                case = case | (int(vz) << 4) | (int(v5) << 5) | (int(v6) << 6) | (int(v7) << 7)
                nt += (tri_range[case + 1] - tri_range[case]) / 3
                node_code_out[s0] = mask | (case << 3)
                lk += 1
            lj += 1
        li += 1
    unit_vertices_out[unit] = nv
    unit_triangles_out[unit] = nt
    unit_inexact_out[unit] = inexact


@wp.kernel(enable_backward=False)
def emit_vertices(
    tid_offset: int,
    # Grid:
    grid_origin: wp.vec3,
    cell_size: float,
    block_nodes: int,
    slabs: int,
    iso_level: float,
    # In:
    field: wp.array(dtype=float),
    weighted_field: wp.array(dtype=float),
    meshed_upper: wp.array2d(dtype=wp.int32),
    meshed_block: wp.array(dtype=wp.int32),
    block_coord: wp.array(dtype=wp.vec3i),
    node_code: wp.array(dtype=wp.int32),
    unit_vertices: wp.array(dtype=wp.int32),
    unit_vertex_start: wp.array(dtype=wp.int32),
    # Out: first vertex of each node (field index), vertex positions [m] and Psi at the vertices
    node_vertex_out: wp.array(dtype=wp.int32),
    vertex_x_out: wp.array(dtype=wp.vec3),
    vertex_psi_out: wp.array(dtype=float),
):
    """One vertex per crossing edge, at x_a + t (x_b - x_a), t = (iso - Phi_a) / (Phi_b - Phi_a); Psi
    interpolated with the same t (``vertex_weights`` turns it into the smoothing weight; computing
    the weight here made this node scan 4x slower on the CPU)."""
    unit = wp.tid() + tid_offset
    k = unit / slabs
    slab = unit - k * slabs
    bsz = block_nodes
    c = meshed_block[k]
    b = block_coord[c]
    li = (slab * bsz) / slabs
    li_end = ((slab + 1) * bsz) / slabs
    if unit_vertices[unit] == 0:
        li = li_end
    vid = unit_vertex_start[unit]
    while li < li_end:
        lj = int(0)
        while lj < bsz:
            lk = int(0)
            while lk < bsz:
                s0 = (k * bsz * bsz + li * bsz + lj) * bsz + lk
                mask = node_code[s0] & 7
                if mask != 0:
                    node_vertex_out[s0] = vid
                    f0 = field[s0]
                    p0 = weighted_field[s0]
                    g = wp.vec3(float(b[0] * bsz + li), float(b[1] * bsz + lj), float(b[2] * bsz + lk))
                    for a in range(3):
                        if (mask >> a) & 1 != 0:
                            s1 = node_slot(meshed_upper, k, li + int(a == 0), lj + int(a == 1), lk + int(a == 2), bsz)
                            f1 = slot_value(field, s1)
                            p1 = float(0.0)
                            if s1 >= 0:
                                p1 = weighted_field[s1]
                            t = wp.clamp((iso_level - f0) / (f1 - f0), 0.0, 1.0)
                            p = g
                            p[a] = p[a] + t
                            vertex_x_out[vid] = grid_origin + p * cell_size
                            vertex_psi_out[vid] = p0 + t * (p1 - p0)
                            vid += 1
                lk += 1
            lj += 1
        li += 1


@wp.kernel(enable_backward=False)
def vertex_weights(
    tid_offset: int,
    # Parameters: iso level (Phi at every vertex) and N of the weights
    iso_level: float,
    weighted_count_normalization: float,
    # In/out: Psi at the vertices in, smoothing weights in [0, 1] out
    vertex_weight_io: wp.array(dtype=float),
):
    """The smoothing weight of each vertex (Loeschner et al. 2023, as splashsurf): n_v = Psi / Phi at
    the vertex (Phi = iso there), the Shepard interpolation of the particles' weighted neighbour counts;
    x = clamp(n_v / N, 0, 1), w = 6 x^5 - 15 x^4 + 10 x^3."""
    v = wp.tid() + tid_offset
    x = wp.clamp(vertex_weight_io[v] / (iso_level * weighted_count_normalization), 0.0, 1.0)
    vertex_weight_io[v] = x * x * x * (10.0 + x * (6.0 * x - 15.0))


@wp.kernel(enable_backward=False)
def emit_triangles(
    tid_offset: int,
    # Grid:
    block_nodes: int,
    slabs: int,
    # In:
    meshed_upper: wp.array2d(dtype=wp.int32),
    node_code: wp.array(dtype=wp.int32),
    node_vertex: wp.array(dtype=wp.int32),
    unit_triangles: wp.array(dtype=wp.int32),
    unit_triangle_start: wp.array(dtype=wp.int32),
    tri_range: wp.array(dtype=wp.int32),
    tri_edges: wp.array(dtype=wp.int32),
    edge_owner: wp.array(dtype=wp.int32),
    # Out: triangles (vertex indices, counter-clockwise seen from outside: Phi is high inside, so the
    # table's winding is reversed); per unit the edges whose owner has no vertex (never, unless the
    # classification failed)
    triangles_out: wp.array(dtype=wp.vec3i),
    unit_missing_out: wp.array(dtype=wp.int32),
):
    unit = wp.tid() + tid_offset
    k = unit / slabs
    slab = unit - k * slabs
    bsz = block_nodes
    li = (slab * bsz) / slabs
    li_end = ((slab + 1) * bsz) / slabs
    tri = unit_triangle_start[unit]
    missing = int(0)
    if unit_triangles[unit] == 0:
        li = li_end
    while li < li_end:
        lj = int(0)
        while lj < bsz:
            lk = int(0)
            while lk < bsz:
                s0 = (k * bsz * bsz + li * bsz + lj) * bsz + lk
                case = node_code[s0] >> 3
                e = tri_range[case]
                e_end = tri_range[case + 1]
                while e < e_end:
                    ids = wp.vec3i()
                    for m in range(3):
                        edge = tri_edges[e + m]
                        axis = edge_owner[4 * edge + 3]
                        so = node_slot(meshed_upper, k, li + edge_owner[4 * edge], lj + edge_owner[4 * edge + 1],
                                       lk + edge_owner[4 * edge + 2], bsz)
                        vid = int(0)
                        if so >= 0:
                            owner_mask = node_code[so] & 7
                            vid = node_vertex[so]
                            if axis > 0 and (owner_mask & 1) != 0:
                                vid += 1
                            if axis > 1 and (owner_mask & 2) != 0:
                                vid += 1
                        else:
                            missing += 1
                        ids[m] = vid
                    triangles_out[tri] = wp.vec3i(ids[0], ids[2], ids[1])
                    tri += 1
                    e += 3
                lk += 1
            lj += 1
        li += 1
    unit_missing_out[unit] = missing
