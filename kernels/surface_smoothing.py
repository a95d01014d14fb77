"""Device code of the surface mesh post-processing: connectivity, weighted Laplacian smoothing of
positions, vertex normals and their smoothing.

Feature-weighted smoothing after Loeschner, Boettcher, Jeske & Bender (VMV 2023, as in splashsurf):
each vertex has a weight w = smoothstep(n_v / N) from the weighted neighbour count n of the
particles around it (computed with the vertex, ``surface_marching.emit_vertices``), so vertices
near well-supported particles (flat, bulk fluid) are smoothed fully and those near thin sheets,
jets and droplets (few neighbours) barely move. Host launcher: ``warp_sph/surface/smoothing.py``.
"""
import warp as wp


@wp.kernel(enable_backward=False)
def count_vertex_faces(
    # In:
    triangles: wp.array(dtype=wp.vec3i),
    # Out: faces per vertex (pre-zeroed; atomic, a serial launch on the CPU)
    vertex_face_count_out: wp.array(dtype=wp.int32),
):
    t = wp.tid()
    tri = triangles[t]
    for m in range(3):
        wp.atomic_add(vertex_face_count_out, tri[m], 1)


@wp.kernel(enable_backward=False)
def fill_vertex_faces(
    # In:
    triangles: wp.array(dtype=wp.vec3i),
    vertex_face_start: wp.array(dtype=wp.int32),
    # Out: cursor per vertex (pre-zeroed) and the faces of each vertex in [start, start + count)
    vertex_face_cursor_out: wp.array(dtype=wp.int32),
    vertex_face_out: wp.array(dtype=wp.int32),
):
    """Vertex -> face lists (atomic cursors: a serial launch on the CPU; the order of a list is
    made deterministic afterwards by ``vertex_neighbors``)."""
    t = wp.tid()
    tri = triangles[t]
    for m in range(3):
        v = tri[m]
        slot = wp.atomic_add(vertex_face_cursor_out, v, 1)
        vertex_face_out[vertex_face_start[v] + slot] = t


@wp.kernel(enable_backward=False)
def vertex_neighbors(
    tid_offset: int,
    # In:
    triangles: wp.array(dtype=wp.vec3i),
    vertex_face_start: wp.array(dtype=wp.int32),
    vertex_face_count: wp.array(dtype=wp.int32),
    # Out: sorted faces of each vertex (in place) and its distinct neighbours, sorted, at
    # [2 start, 2 start + count) (a vertex of k faces has at most 2 k neighbours)
    vertex_face_io: wp.array(dtype=wp.int32),
    neighbor_out: wp.array(dtype=wp.int32),
    neighbor_count_out: wp.array(dtype=wp.int32),
):
    v = wp.tid() + tid_offset
    start = vertex_face_start[v]
    n = vertex_face_count[v]
    # insertion sort of the (few) faces: a deterministic order whatever the fill order was
    a = start + 1
    while a < start + n:
        f = vertex_face_io[a]
        b = a - 1
        while b >= start and vertex_face_io[b] > f:
            vertex_face_io[b + 1] = vertex_face_io[b]
            b -= 1
        vertex_face_io[b + 1] = f
        a += 1
    base = 2 * start
    count = int(0)
    s = start
    while s < start + n:
        tri = triangles[vertex_face_io[s]]
        for m in range(3):
            u = tri[m]
            if u != v:
                # insert u into the sorted list unless present
                b = base + count - 1
                while b >= base and neighbor_out[b] > u:
                    b -= 1
                if b < base or neighbor_out[b] != u:
                    e = base + count
                    while e > b + 1:
                        neighbor_out[e] = neighbor_out[e - 1]
                        e -= 1
                    neighbor_out[b + 1] = u
                    count += 1
        s += 1
    neighbor_count_out[v] = count


@wp.kernel(enable_backward=False)
def laplacian_step(
    tid_offset: int,
    # Parameters: step factor (beta = 1 for splashsurf's weighted Laplacian; Taubin's lambda / mu)
    beta: float,
    # In:
    vertex_x: wp.array(dtype=wp.vec3),
    vertex_weight: wp.array(dtype=float),
    vertex_face_start: wp.array(dtype=wp.int32),
    neighbor: wp.array(dtype=wp.int32),
    neighbor_count: wp.array(dtype=wp.int32),
    # Out:
    vertex_x_out: wp.array(dtype=wp.vec3),
):
    """x_v <- x_v + beta w_v (mean of the one ring - x_v) (Jacobi: reads one buffer, writes another)."""
    v = wp.tid() + tid_offset
    x = vertex_x[v]
    n = neighbor_count[v]
    base = 2 * vertex_face_start[v]
    if n == 0:
        vertex_x_out[v] = x
        return
    acc = wp.vec3(0.0)
    s = base
    while s < base + n:
        acc += vertex_x[neighbor[s]]
        s += 1
    vertex_x_out[v] = x + (beta * vertex_weight[v]) * (acc / float(n) - x)


@wp.kernel(enable_backward=False)
def face_cross(
    tid_offset: int,
    # In:
    vertex_x: wp.array(dtype=wp.vec3),
    triangles: wp.array(dtype=wp.vec3i),
    # Out: per face (x_b - x_a) x (x_c - x_a) (twice its area along its normal) [m^2]
    face_cross_out: wp.array(dtype=wp.vec3),
):
    """Each face's cross product, once per face (``vertex_normals`` gathers them instead of
    recomputing every face at its three corners: 0.42 -> 0.30 ms CPU at 8.8k vertices)."""
    t = wp.tid() + tid_offset
    tri = triangles[t]
    a = vertex_x[tri[0]]
    cr = wp.cross(vertex_x[tri[1]] - a, vertex_x[tri[2]] - a)
    face_cross_out[t] = cr


@wp.kernel(enable_backward=False)
def vertex_normals(
    tid_offset: int,
    # In:
    face_cross: wp.array(dtype=wp.vec3),
    vertex_face_start: wp.array(dtype=wp.int32),
    vertex_face_count: wp.array(dtype=wp.int32),
    vertex_face: wp.array(dtype=wp.int32),
    # Out: unit area-weighted normals (zero for an isolated vertex)
    vertex_normal_out: wp.array(dtype=wp.vec3),
):
    """n_v = normalize(sum over the faces of v of (x_b - x_a) x (x_c - x_a)) (area weighted;
    the crosses from ``face_cross``)."""
    v = wp.tid() + tid_offset
    start = vertex_face_start[v]
    end = start + vertex_face_count[v]
    acc = wp.vec3(0.0)
    s = start
    while s < end:
        acc += face_cross[vertex_face[s]]
        s += 1
    vertex_normal_out[v] = wp.normalize(acc)  # the zero vector where acc is 0


@wp.kernel(enable_backward=False)
def smooth_normals_step(
    tid_offset: int,
    # In:
    vertex_normal: wp.array(dtype=wp.vec3),
    vertex_face_start: wp.array(dtype=wp.int32),
    neighbor: wp.array(dtype=wp.int32),
    neighbor_count: wp.array(dtype=wp.int32),
    # Out:
    vertex_normal_out: wp.array(dtype=wp.vec3),
):
    """n_v <- normalize(n_v + sum of the one ring's n) (Jacobi)."""
    v = wp.tid() + tid_offset
    acc = vertex_normal[v]
    base = 2 * vertex_face_start[v]
    s = base
    while s < base + neighbor_count[v]:
        acc += vertex_normal[neighbor[s]]
        s += 1
    vertex_normal_out[v] = wp.normalize(acc)  # the zero vector where acc is 0


@wp.kernel(enable_backward=False)
def volume_area_terms(
    tid_offset: int,
    # In:
    vertex_x: wp.array(dtype=wp.vec3),
    vertex_weight: wp.array(dtype=float),
    triangles: wp.array(dtype=wp.vec3i),
    vertex_face_start: wp.array(dtype=wp.int32),
    vertex_face_count: wp.array(dtype=wp.int32),
    vertex_face: wp.array(dtype=wp.int32),
    # Out: per vertex (w_v A_v [m^2], 6 x the signed volume terms of the faces whose first corner it is
    # [m^3]), A_v = a third of the area of the faces around v; and the unit vertex normal
    terms_out: wp.array(dtype=wp.vec2),
    vertex_normal_out: wp.array(dtype=wp.vec3),
):
    """One pass for the volume restoration: the enclosed volume V = sum_t (x_a - o) . ((x_b - o) x
    (x_c - o)) / 6 = sum_t (x_a - o) . ((x_b - x_a) x (x_c - x_a)) / 6 (o = x of vertex 0, so float32
    keeps its precision; each face counted at its first corner), the weighted vertex areas and the
    area-weighted normals."""
    v = wp.tid() + tid_offset
    o = vertex_x[0]
    acc = wp.vec3(0.0)
    vol = float(0.0)
    s = vertex_face_start[v]
    while s < vertex_face_start[v] + vertex_face_count[v]:
        tri = triangles[vertex_face[s]]
        a = vertex_x[tri[0]]
        cr = wp.cross(vertex_x[tri[1]] - a, vertex_x[tri[2]] - a)
        acc += cr
        if tri[0] == v:
            vol += wp.dot(a - o, cr)
        s += 1
    length = wp.length(acc)
    vertex_normal_out[v] = wp.normalize(acc)
    # sum of face areas = sum |cross| / 2 >= |sum cross| / 2 (equal on a flat fan): good enough for a weight
    terms_out[v] = wp.vec2(vertex_weight[v] * length / 6.0, vol)


@wp.kernel(enable_backward=False)
def offset_along_normals(
    tid_offset: int,
    # Parameters: offset per unit weight [m]
    offset: float,
    # In:
    vertex_weight: wp.array(dtype=float),
    vertex_normal: wp.array(dtype=wp.vec3),
    # In/out:
    vertex_x_io: wp.array(dtype=wp.vec3),
):
    """x_v += offset w_v n_v: gives back the volume smoothing took, where it took it."""
    v = wp.tid() + tid_offset
    vertex_x_io[v] = vertex_x_io[v] + (offset * vertex_weight[v]) * vertex_normal[v]
