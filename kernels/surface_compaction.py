"""Device code of mesh compaction after vertex merges (edge collapses): triangles renumbered through a
vertex map and dropped when degenerate, unused vertices dropped, both packed by inclusive scans.
Host launcher: ``warp_sph/surface/compaction.py``.
"""
import warp as wp


@wp.kernel(enable_backward=False)
def remap_triangles(
    tid_offset: int,
    # In:
    vertex_map: wp.array(dtype=wp.int32),
    # In/out:
    triangles_io: wp.array(dtype=wp.vec3i),
    # Out: 1 for a triangle that survives (no repeated vertex after the map)
    alive_out: wp.array(dtype=wp.int32),
):
    t = wp.tid() + tid_offset
    tri = triangles_io[t]
    m = wp.vec3i(vertex_map[tri[0]], vertex_map[tri[1]], vertex_map[tri[2]])
    triangles_io[t] = m
    alive_out[t] = int(m[0] != m[1] and m[1] != m[2] and m[0] != m[2])


@wp.kernel(enable_backward=False)
def compact_triangles(
    tid_offset: int,
    # In:
    triangles: wp.array(dtype=wp.vec3i),
    alive: wp.array(dtype=wp.int32),
    alive_scan: wp.array(dtype=wp.int32),
    vertex_index: wp.array(dtype=wp.int32),
    # Out:
    triangles_out: wp.array(dtype=wp.vec3i),
):
    """Keep the live triangles (inclusive scan of ``alive``), their vertices renumbered by vertex_index."""
    t = wp.tid() + tid_offset
    if alive[t] != 0:
        tri = triangles[t]
        triangles_out[alive_scan[t] - 1] = wp.vec3i(vertex_index[tri[0]], vertex_index[tri[1]], vertex_index[tri[2]])


@wp.kernel(enable_backward=False)
def kept_vertices(
    tid_offset: int,
    # In:
    vertex_map: wp.array(dtype=wp.int32),
    # Out: 1 for a vertex no collapse removed
    kept_out: wp.array(dtype=wp.int32),
):
    v = wp.tid() + tid_offset
    kept_out[v] = int(vertex_map[v] == v)


@wp.kernel(enable_backward=False)
def compact_vertices(
    tid_offset: int,
    # In:
    vertex_x: wp.array(dtype=wp.vec3),
    kept: wp.array(dtype=wp.int32),
    kept_scan: wp.array(dtype=wp.int32),
    # Out: positions of the kept vertices; new index of every kept vertex
    vertex_x_out: wp.array(dtype=wp.vec3),
    vertex_index_out: wp.array(dtype=wp.int32),
):
    v = wp.tid() + tid_offset
    if kept[v] != 0:
        k = kept_scan[v] - 1
        vertex_x_out[k] = vertex_x[v]
        vertex_index_out[v] = k


@wp.kernel(enable_backward=False)
def identity_map(
    tid_offset: int,
    # Out:
    vertex_map_out: wp.array(dtype=wp.int32),
    vertex_index_out: wp.array(dtype=wp.int32),
    blocked_with_out: wp.array(dtype=wp.int32),
):
    v = wp.tid() + tid_offset
    vertex_map_out[v] = v
    vertex_index_out[v] = v
    blocked_with_out[v] = -1
