"""Device code of the surface decimation: quadric-error edge collapses (Garland & Heckbert 1997)
in parallel rounds of independent collapses.

Each round: every edge gets the cost of collapsing it into one vertex, Q(p) = p^T (Q_a + Q_b) p
(Q: the planes of the faces around a vertex, accumulated over earlier collapses; the cost is the
sum of the squared distances from them), at the better of the quadric's optimum and the edge midpoint;
edges that would make the mesh non-manifold (link condition), turn a face too far or leave a vertex
of valence < 3 are skipped. Edges are ordered by cost bucket (factors of 8), randomly within a bucket; an edge
collapses when it comes first for both its ends and before the first edge of every neighbour of
its ends, so the collapses of one round touch disjoint faces and run in parallel without atomics. Host launcher: ``warp_sph/surface/decimation.py``; the
mesh is compacted afterwards by ``surface_compaction.py``.
"""
import warp as wp

#: cost of an edge that may not collapse
BLOCKED = wp.constant(3.0e38)
#: multipliers of the edge hash (Knuth's 2^32 / golden ratio, xxHash's PRIME32_2); typed uint32
#: constants, so the generated C++ holds them as unsigned literals (a bare literal above 2^31 - 1
#: inside a kernel becomes an int32 constant that overflows, and clang warns on the first compile)
HASH_MUL_A = wp.constant(wp.uint32(2654435761))
HASH_MUL_B = wp.constant(wp.uint32(2246822519))


@wp.func
def plane_quadric(a: wp.vec3, b: wp.vec3, c: wp.vec3) -> wp.mat44:
    """K = p p^T for the plane p = (n, -n . a) of triangle (a, b, c), n its unit normal (0 if degenerate)."""
    n = wp.cross(b - a, c - a)
    length = wp.length(n)
    if length <= 0.0:
        return wp.mat44(0.0)
    n = n / length
    p = wp.vec4(n[0], n[1], n[2], -wp.dot(n, a))
    return wp.outer(p, p)


@wp.func
def quadric_cost(q: wp.mat44, x: wp.vec3) -> float:
    """Sum of the squared distances [m^2] of x from the planes summed in q (Garland & Heckbert): a
    bound e^2 on it keeps x within e of every one of them."""
    p = wp.vec4(x[0], x[1], x[2], 1.0)
    return wp.max(wp.dot(p, q * p), 0.0)


@wp.kernel(enable_backward=False)
def vertex_quadrics(
    tid_offset: int,
    # In:
    vertex_x: wp.array(dtype=wp.vec3),
    triangles: wp.array(dtype=wp.vec3i),
    face_start: wp.array(dtype=wp.int32),
    face_count: wp.array(dtype=wp.int32),
    faces: wp.array(dtype=wp.int32),
    # Out:
    quadric_out: wp.array(dtype=wp.mat44),
):
    """Q_v = sum of the plane quadrics of the faces around v [m^2 at a point: sum of squared distances]."""
    v = wp.tid() + tid_offset
    q = wp.mat44(0.0)
    s = face_start[v]
    while s < face_start[v] + face_count[v]:
        tri = triangles[faces[s]]
        q += plane_quadric(vertex_x[tri[0]], vertex_x[tri[1]], vertex_x[tri[2]])
        s += 1
    quadric_out[v] = q


@wp.func
def keeps_faces(
    vertex_x: wp.array(dtype=wp.vec3),
    triangles: wp.array(dtype=wp.vec3i),
    face_start: wp.array(dtype=wp.int32),
    face_count: wp.array(dtype=wp.int32),
    faces: wp.array(dtype=wp.int32),
    v: int,
    u: int,
    p: wp.vec3,
    min_cos: float,
) -> bool:
    """Moving v to p turns no face of v (except those with u, which vanish) by more than acos(min_cos)
    and degenerates none."""
    s = face_start[v]
    while s < face_start[v] + face_count[v]:
        tri = triangles[faces[s]]
        if tri[0] != u and tri[1] != u and tri[2] != u:
            a = vertex_x[tri[0]]
            b = vertex_x[tri[1]]
            c = vertex_x[tri[2]]
            n0 = wp.cross(b - a, c - a)
            if tri[0] == v:
                a = p
            elif tri[1] == v:
                b = p
            else:
                c = p
            n1 = wp.cross(b - a, c - a)
            l0 = wp.length(n0)
            l1 = wp.length(n1)
            if l1 <= 1.0e-3 * l0 or wp.dot(n0, n1) < min_cos * l0 * l1:
                return False
        s += 1
    return True


@wp.func
def edge_slot(
    face_start: wp.array(dtype=wp.int32),
    neighbors: wp.array(dtype=wp.int32),
    neighbor_count: wp.array(dtype=wp.int32),
    v: int,
    u: int,
) -> int:
    """Slot of neighbour u in v's (sorted) neighbour list; -1 if absent."""
    base = 2 * face_start[v]
    s = base
    while s < base + neighbor_count[v]:
        w = neighbors[s]
        if w == u:
            return s
        if w > u:
            return -1
        s += 1
    return -1


@wp.kernel(enable_backward=False)
def edge_costs(
    tid_offset: int,
    # In:
    vertex_x: wp.array(dtype=wp.vec3),
    quadric: wp.array(dtype=wp.mat44),
    blocked_with: wp.array(dtype=wp.int32),
    face_start: wp.array(dtype=wp.int32),
    neighbors: wp.array(dtype=wp.int32),
    neighbor_count: wp.array(dtype=wp.int32),
    # Out: per neighbour slot of v the cost of the edge [m^2: summed squared distance from the planes the
    # merged vertex stands for] (computed by the lower end, which also writes the upper end's slot) and,
    # at the lower end's slot, the merged vertex [m]
    edge_cost_out: wp.array(dtype=float),
    edge_x_out: wp.array(dtype=wp.vec3),
):
    """Cost of every edge; edges failing the link condition (exactly the two opposite vertices are
    common neighbours), leaving a vertex of valence < 3, or blocked by an earlier face check are BLOCKED."""
    v = wp.tid() + tid_offset
    base_v = 2 * face_start[v]
    nv = neighbor_count[v]
    xv = vertex_x[v]
    s = base_v
    while s < base_v + nv:
        u = neighbors[s]
        cost = BLOCKED
        pos = xv
        if u > v and blocked_with[v] != u and blocked_with[u] != v:
            base_u = 2 * face_start[u]
            nu = neighbor_count[u]
            common = int(0)
            thin = int(0)
            a = base_v
            b = base_u
            while a < base_v + nv and b < base_u + nu:
                na = neighbors[a]
                nb = neighbors[b]
                if na == nb:
                    common += 1
                    if neighbor_count[na] <= 3:
                        thin = 1
                    a += 1
                    b += 1
                elif na < nb:
                    a += 1
                else:
                    b += 1
            if common == 2 and thin == 0 and (nv > 3 or nu > 3):
                q = quadric[v] + quadric[u]
                xu = vertex_x[u]
                mid = 0.5 * (xv + xu)
                pos = mid
                cost = quadric_cost(q, mid)
                a3 = wp.mat33(q[0, 0], q[0, 1], q[0, 2], q[1, 0], q[1, 1], q[1, 2], q[2, 0], q[2, 1], q[2, 2])
                det = wp.determinant(a3)
                tr = q[0, 0] + q[1, 1] + q[2, 2]
                if det > 1.0e-6 * tr * tr * tr:
                    opt = -(wp.inverse(a3) * wp.vec3(q[0, 3], q[1, 3], q[2, 3]))
                    # keep the optimum only near the edge (ill-conditioned quadrics throw it far away)
                    if wp.length(opt - mid) <= 0.5 * wp.length(xu - xv):
                        c_opt = quadric_cost(q, opt)
                        if c_opt < cost:
                            cost = c_opt
                            pos = opt
        if u > v:  # the lower end writes both slots of the edge (its own and u's slot for v)
            edge_cost_out[s] = cost
            edge_x_out[s] = pos
            edge_cost_out[edge_slot(face_start, neighbors, neighbor_count, u, v)] = cost
        s += 1


@wp.func
def edge_key(cost: float, cost_scale: float, a: int, b: int) -> wp.int64:
    """Priority of edge {a, b}: its cost bucket (a factor 8 of cost each, from cost_scale up),
    then a hash of the edge. Edges of one bucket collapse in random order: a cost order alone has few
    local minima on a smooth surface (long monotone runs), which stalls the parallel rounds."""
    bucket = wp.int64(0)
    if cost > cost_scale:
        bucket = wp.int64(wp.min(int(wp.log2(cost / cost_scale) / 3.0) + 1, 1000000))
    lo = wp.min(a, b)
    hi = wp.max(a, b)
    h = (wp.uint32(lo) * HASH_MUL_A) ^ (wp.uint32(hi) * HASH_MUL_B)
    h = (h ^ (h >> wp.uint32(15))) * HASH_MUL_A
    return (bucket << wp.int64(32)) | wp.int64(h >> wp.uint32(1))


@wp.func
def key_less(k0: wp.int64, a0: int, b0: int, k1: wp.int64, a1: int, b1: int) -> bool:
    """Strict total order of edges (key, then ends), the same in every thread."""
    if k0 != k1:
        return k0 < k1
    if wp.min(a0, b0) != wp.min(a1, b1):
        return wp.min(a0, b0) < wp.min(a1, b1)
    return wp.max(a0, b0) < wp.max(a1, b1)


@wp.kernel(enable_backward=False)
def vertex_best_edge(
    tid_offset: int,
    # Parameters: cost of the first priority bucket [m^2]
    cost_scale: float,
    # In:
    face_start: wp.array(dtype=wp.int32),
    neighbors: wp.array(dtype=wp.int32),
    neighbor_count: wp.array(dtype=wp.int32),
    edge_cost: wp.array(dtype=float),
    locked: wp.array(dtype=wp.int32),
    # Out: per vertex its first edge by priority (``edge_key``) to an unlocked vertex: key, cost, other
    # end (-1: none, or v locked), slot in v's list (holds the merged vertex when v is the lower end)
    best_key_out: wp.array(dtype=wp.int64),
    best_cost_out: wp.array(dtype=float),
    best_other_out: wp.array(dtype=wp.int32),
    best_slot_out: wp.array(dtype=wp.int32),
):
    v = wp.tid() + tid_offset
    base = 2 * face_start[v]
    best_k = wp.int64(0)
    best_c = BLOCKED
    best_u = int(-1)
    best_s = int(-1)
    s = base
    end = base + neighbor_count[v]
    if locked[v] != 0:
        end = base
    while s < end:
        u = neighbors[s]
        slot = s
        c = edge_cost[s]
        if c < BLOCKED and locked[u] == 0:
            k = edge_key(c, cost_scale, u, v)
            if best_u < 0 or key_less(k, u, v, best_k, best_u, v):
                best_k = k
                best_c = c
                best_u = u
                best_s = slot
        s += 1
    best_key_out[v] = best_k
    best_cost_out[v] = best_c
    best_other_out[v] = best_u
    best_slot_out[v] = best_s


@wp.func
def beats_ring(
    face_start: wp.array(dtype=wp.int32),
    neighbors: wp.array(dtype=wp.int32),
    neighbor_count: wp.array(dtype=wp.int32),
    best_key: wp.array(dtype=wp.int64),
    best_other: wp.array(dtype=wp.int32),
    x: int,
    v: int,
    u: int,
    key: wp.int64,
) -> bool:
    """Edge {v, u} comes before the first edge of every neighbour of x other than v and u."""
    base = 2 * face_start[x]
    s = base
    while s < base + neighbor_count[x]:
        w = neighbors[s]
        if w != v and w != u:
            o = best_other[w]
            if o >= 0:
                if not key_less(key, v, u, best_key[w], w, o):
                    return False
        s += 1
    return True


@wp.kernel(enable_backward=False)
def collapse_edges(
    tid_offset: int,
    # Parameters: largest cost accepted [m^2], smallest cosine between a face's normal before and after
    max_cost: float,
    min_cos: float,
    # In:
    triangles: wp.array(dtype=wp.vec3i),
    face_start: wp.array(dtype=wp.int32),
    face_count: wp.array(dtype=wp.int32),
    faces: wp.array(dtype=wp.int32),
    neighbors: wp.array(dtype=wp.int32),
    neighbor_count: wp.array(dtype=wp.int32),
    best_key: wp.array(dtype=wp.int64),
    best_cost: wp.array(dtype=float),
    best_other: wp.array(dtype=wp.int32),
    best_slot: wp.array(dtype=wp.int32),
    edge_x: wp.array(dtype=wp.vec3),
    # In/out: positions and quadrics (the kept vertex v gets the merged ones); vertex map (u -> v);
    # per vertex an edge whose collapse failed the face check (not tried again)
    vertex_x_io: wp.array(dtype=wp.vec3),
    quadric_io: wp.array(dtype=wp.mat44),
    vertex_map_io: wp.array(dtype=wp.int32),
    blocked_with_io: wp.array(dtype=wp.int32),
    # In/out: 1 where vertex v collapsed an edge this round (set here, cleared by the host per round)
    collapsed_io: wp.array(dtype=wp.int32),
):
    """Collapse {v, u} into v (v < u) when it is both ends' first edge by priority, within max_cost,
    before the first edge of every neighbour of v and u (so the collapses of a round share no face
    and read only positions no other collapse moves), and turns no face too far."""
    v = wp.tid() + tid_offset
    u = best_other[v]
    if u <= v:
        return
    cost = best_cost[v]
    if cost > max_cost or best_other[u] != v:
        return
    key = best_key[v]
    if not beats_ring(face_start, neighbors, neighbor_count, best_key, best_other, v, v, u, key):
        return
    if not beats_ring(face_start, neighbors, neighbor_count, best_key, best_other, u, v, u, key):
        return
    p = edge_x[best_slot[v]]
    if not (keeps_faces(vertex_x_io, triangles, face_start, face_count, faces, v, u, p, min_cos)
            and keeps_faces(vertex_x_io, triangles, face_start, face_count, faces, u, v, p, min_cos)):
        blocked_with_io[v] = u
        return
    vertex_x_io[v] = p
    quadric_io[v] = quadric_io[v] + quadric_io[u]
    vertex_map_io[u] = v
    collapsed_io[v] = 1


@wp.kernel(enable_backward=False)
def lock_collapsed(
    tid_offset: int,
    # In:
    face_start: wp.array(dtype=wp.int32),
    neighbors: wp.array(dtype=wp.int32),
    neighbor_count: wp.array(dtype=wp.int32),
    collapsed: wp.array(dtype=wp.int32),
    best_other: wp.array(dtype=wp.int32),
    # In/out: 1 for v, u and every neighbour of a collapsed edge {v, u} (only 1s are written, so the
    # plain stores may race)
    locked_io: wp.array(dtype=wp.int32),
):
    """After a selection pass: lock the closed one-rings of the collapsed edges, so a further pass of
    the same round selects only edges whose faces no collapse touched (Luby-style rounds)."""
    v = wp.tid() + tid_offset
    if collapsed[v] == 0 or locked_io[v] != 0:
        return
    u = best_other[v]
    for e in range(2):
        x = v
        if e == 1:
            x = u
        locked_io[x] = 1
        s = 2 * face_start[x]
        while s < 2 * face_start[x] + neighbor_count[x]:
            locked_io[neighbors[s]] = 1
            s += 1
