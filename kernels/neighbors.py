"""Neighbour search kernels: per-step neighbour lists over a dense cell grid (with the fused WCSPH
density sum) and the cell walk's functions. Building the cell grid is in ``cell_lists.py``, the cell-order gathers
in ``particle_order.py``, list collection over a hash grid (diagnostics, tests) in ``hash_grid.py``."""
import functools

import warp as wp

from .wall_reach import subcell_of
from .smoothing import SMOOTHING_FUNCTIONS


# --- Per-step neighbour lists over a dense cell grid ------------------------------------------
# Particles are sorted by cell (x fastest), so the three cells (cx-1 .. cx+1) of one (cy, cz) row are
# one contiguous index range: a query visits 9 ranges with a tight inner loop, not 27 hash cells.
# Coordinates outside the grid are clamped to its border cells; clamping keeps cells of points
# closer than the cell size adjacent, so results stay exact (only slower for far-out particles).
# Kernels that take ``tid_offset`` first are launched in disjoint ranges by ``warp_sph.launch``.
# Loops over a neighbour list are ``while k < k_end`` loops in every kernel: Warp's CPU code for
# ``for k in range(n)`` with a run-time n was measured 11-20 % slower (59k particles, one thread:
# PBF density pass 49 -> 44 ms, correction 23 -> 19 ms, WCSPH forces 25 -> 21.5 ms).


@wp.struct
class NeighborList:
    """Fixed-capacity neighbour lists of the fluid particles.

    count: neighbours of particle i within the support radius (exact, may exceed the capacity),
    shape (fluid_count,); index: their indices, index[i, k] for k < min(count[i], capacity),
    shape (fluid_count, capacity); order: fluid particles in cell order (thread -> particle),
    shape (fluid_count,).
    """

    count: wp.array(dtype=wp.int32)
    index: wp.array2d(dtype=wp.int32)
    order: wp.array(dtype=wp.int32)


@wp.func
def particle_in_cell_order(neighbors: NeighborList, tid: int) -> int:
    """Particle visited by thread tid (cell order, for memory locality)."""
    return neighbors.order[tid]


@wp.func
def particle_in_cell_order(neighbors: wp.uint64, tid: int) -> int:
    """Particle visited by thread tid of a hash grid (cell order)."""
    return wp.hash_grid_point_id(neighbors, tid)


@wp.func
def neighbor_count(neighbors: NeighborList, i: int) -> int:
    """Neighbours stored for particle i (the count clipped to the capacity)."""
    return wp.min(neighbors.count[i], neighbors.index.shape[1])


@wp.func
def cell_of(x: wp.vec3, grid_lo: wp.vec3, inv_cell_size: float, grid_dims: wp.vec3i) -> wp.vec3i:
    """Cell coordinates of x, clamped to the grid."""
    q = (x - grid_lo) * inv_cell_size
    return wp.vec3i(
        wp.clamp(int(wp.floor(q[0])), 0, grid_dims[0] - 1),
        wp.clamp(int(wp.floor(q[1])), 0, grid_dims[1] - 1),
        wp.clamp(int(wp.floor(q[2])), 0, grid_dims[2] - 1),
    )


@wp.func
def cell_rows(q: wp.vec3, qr: float, grid_dims: wp.vec3i) -> wp.vec4i:
    """The cell rows a query reaches: (y0, y1, z0, z1), the rows (y, z) with y0 <= y <= y1 and
    z0 <= z <= z1 within qr cells of the point q (both in cell units: (x - grid_lo) / cell size),
    clamped to the grid. With ``row_points`` the one cell walk of every search over a ``CellGrid``."""
    return wp.vec4i(wp.clamp(int(wp.floor(q[1] - qr)), 0, grid_dims[1] - 1),
                    wp.clamp(int(wp.floor(q[1] + qr)), 0, grid_dims[1] - 1),
                    wp.clamp(int(wp.floor(q[2] - qr)), 0, grid_dims[2] - 1),
                    wp.clamp(int(wp.floor(q[2] + qr)), 0, grid_dims[2] - 1))


@wp.func
def row_reach(q: wp.vec3, qr: float, y: int, z: int, grid_dims: wp.vec3i) -> float:
    """Half-length [cells] along x of the chord that the sphere of radius qr cells around q cuts from row
    (y, z) (sqrt(qr^2 - dy^2 - dz^2), dy and dz the row's distance from q; border rows extend to infinity,
    matching the clamped cells of outside points); -1 when the row is out of reach."""
    dz = float(0.0)
    if z > 0 and q[2] < float(z):
        dz = float(z) - q[2]
    if z < grid_dims[2] - 1 and q[2] > float(z + 1):
        dz = q[2] - float(z + 1)
    dy = float(0.0)
    if y > 0 and q[1] < float(y):
        dy = float(y) - q[1]
    if y < grid_dims[1] - 1 and q[1] > float(y + 1):
        dy = q[1] - float(y + 1)
    rest = qr * qr - dy * dy - dz * dz
    if rest <= 0.0:
        return -1.0
    return wp.sqrt(rest)


@wp.func
def row_points(q: wp.vec3, qr: float, y: int, z: int, grid_dims: wp.vec3i, cell_start: wp.array(dtype=wp.int32)) -> wp.vec2i:
    """Sorted indices [k0, k1) of the points in the cells of row (y, z) within qr cells of q (cell
    units): the row's x range trimmed to the sphere (border rows extend to infinity, matching the
    clamped cells of outside points); k1 <= k0 when the row is out of reach."""
    xr = row_reach(q, qr, y, z, grid_dims)
    if xr < 0.0:
        return wp.vec2i(0, 0)
    row = grid_dims[0] * (y + grid_dims[1] * z)
    x0 = wp.clamp(int(wp.floor(q[0] - xr)), 0, grid_dims[0] - 1)
    x1 = wp.clamp(int(wp.floor(q[0] + xr)), 0, grid_dims[0] - 1)
    return wp.vec2i(cell_start[row + x0], cell_start[row + x1 + 1])


@wp.func
def walk_nth_candidate(q: wp.vec3, qr: float, xi: wp.vec3, radius2: float, grid_dims: wp.vec3i,
                       cell_start: wp.array(dtype=wp.int32), sorted_points: wp.array(dtype=wp.vec3), nth: int) -> int:
    """Sorted index of the nth (from 0) point closer than sqrt(radius2) to xi in the walk's order (``cell_rows``,
    ``row_points``), -1 if there are fewer: the last slot of a full list, which the branch-free walks of
    ``neighbor_list_kernel`` and the fused searches overwrite with later candidates, is restored from it."""
    found = int(-1)
    count = int(0)
    rows = cell_rows(q, qr, grid_dims)
    for z in range(rows[2], rows[3] + 1):
        for y in range(rows[0], rows[1] + 1):
            span = row_points(q, qr, y, z, grid_dims, cell_start)
            k = span[0]
            k_end = span[1]
            while k < k_end:
                d = xi - sorted_points[k]
                if wp.dot(d, d) < radius2:
                    if count == nth:
                        found = k
                    count += 1
                k += 1
    return found


@wp.func
def walk_candidates(q: wp.vec3, qr: float, xi: wp.vec3, radius2: float, grid_dims: wp.vec3i,
                    cell_start: wp.array(dtype=wp.int32), sorted_points: wp.array(dtype=wp.vec3),
                    index: wp.array2d(dtype=wp.int32), i: int, first: int) -> int:
    """The branch-free cell walk of ``neighbor_list_kernel`` and the fused searches: the sorted indices of the
    points closer than sqrt(radius2) to xi, in the walk's order, into index[i, first:] (up to the row's capacity);
    returns first + their count (exact). A tight loop stores every candidate at the next free slot (clamped to the
    last) and advances the count only for those within the radius (no branch to mispredict per candidate); a full
    list's last slot, overwritten by later candidates, is restored by a second walk (``walk_nth_candidate``), and
    a row already full at ``first`` (an append) keeps its last entry."""
    capacity = index.shape[1]
    last = capacity - 1
    kept = index[i, last]
    n = first
    rows = cell_rows(q, qr, grid_dims)
    for z in range(rows[2], rows[3] + 1):
        for y in range(rows[0], rows[1] + 1):
            span = row_points(q, qr, y, z, grid_dims, cell_start)
            k = span[0]
            k_end = span[1]
            while k < k_end:  # a while loop: measured 20 % faster than range() here
                d = xi - sorted_points[k]
                index[i, wp.min(n, last)] = k
                n += wp.where(wp.dot(d, d) < radius2, 1, 0)
                k += 1
    if first >= capacity:
        index[i, last] = kept
    elif n >= capacity:  # full: the last slot was overwritten by later candidates
        index[i, last] = walk_nth_candidate(q, qr, xi, radius2, grid_dims, cell_start, sorted_points, last - first)
    return n


@wp.struct
class NoBoundaryParams:
    """Placeholder for kernels specialised without a boundary method."""

    unused: float


@functools.cache
def neighbor_list_kernel(smoothing: str = "", boundary_terms=None, walls: bool = False):
    """Kernel that builds fixed-capacity neighbour lists over a ``CellGrid`` (one thread per query
    point, in the order ``query_order``); with ``smoothing`` it also sums the density of the same
    pairs (the WCSPH density pass fused into the search, report eq. 7/13).

    Lists: the indices of the points within search_radius of each query point (|x_ij| < radius),
    in cell order; the count is exact, entries past the capacity are dropped and max_count_out[i]
    keeps the largest such count of particle i (cleared by the host after reading it; the frame is then
    redone with longer lists, and the density of that pass sums only the stored pairs).

    Density (``smoothing``) over the listed pairs [kg/m^3]: the fluid launch (no ``boundary_terms``)
    writes density_out[i] = weight_scale sum_j W_ij (weight_scale = m); the boundary launch (with the
    boundary method's ``BoundaryTerms``, after it) adds weight_scale sum_b density(W_ib, w_b)
    (weight_scale = rho0, w_b = sorted_weight[k] = the boundary volume V_b in cell order).

    cell_mask (``use_mask``): 0 for cells with no point of the searched set within one cell, so
    a query there finds nothing without visiting any cell (the boundary lists of the interior).
    index_offset: added to every listed index (the searched set's first index in its arrays);
    append != 0: the lists already hold neighbours (count per particle), new ones go after them
    (the moving boundary particles after the static ones); a masked particle then keeps its list.

    Rows of cells (fixed y, z) farther than the radius are skipped and each row's x range is trimmed
    to the sphere, so the cells visited hug the sphere (cells may be smaller than the radius). Border
    cells extend to infinity here, matching the clamping of out-of-grid points.

    keep_distance >= 0 (static points searched alone, no append, no density): a query point within keep_distance
    [m] of keep_x[i], where its row was last searched, keeps its row (which then holds every point closer than
    search_radius - keep_distance, in the same sorted order); the others search and set keep_x[i] = x_i.

    ``walls`` (static boundary particles): the cells are not walked; the points tested are those of the
    query's sub-cell list (``kernels/wall_reach.py``, built once per run over the same grid: wall_inv_size,
    wall_dims, wall_start, wall_entry), the points the walk could reach in its order, so the lists and sums
    are bitwise the walk's while the lists hold every pair (on an overflow this path sums every point within
    the radius, the walk only the stored ones; the frame is redone with longer lists either way)."""
    with_density = bool(smoothing)
    value = SMOOTHING_FUNCTIONS[smoothing or "cubic"][0]
    boundary_density = with_density and boundary_terms is not None and boundary_terms.density is not None
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    density_term = boundary_terms.density if boundary_density else None

    @wp.kernel(enable_backward=False, module="unique")
    def build_neighbor_list(
        tid_offset: int,
        # Grid of the searched points:
        grid_lo: wp.vec3,
        inv_cell_size: float,
        grid_dims: wp.vec3i,
        cell_start: wp.array(dtype=wp.int32),
        cell_point: wp.array(dtype=wp.int32),
        sorted_points: wp.array(dtype=wp.vec3),
        sorted_weight: wp.array(dtype=float),
        cell_mask: wp.array(dtype=wp.uint8),
        use_mask: int,
        index_offset: int,
        append: int,
        search_radius: float,
        # Density sum (with ``smoothing``):
        smoothing_length: float,
        weight_scale: float,
        boundary_params: BoundaryParams,
        # Sub-cell lists of the searched points (with ``walls``):
        wall_inv_size: float,
        wall_dims: wp.vec3i,
        wall_start: wp.array(dtype=wp.int32),
        wall_entry: wp.array(dtype=wp.int32),
        # Kept rows (keep_distance >= 0):
        keep_distance: float,
        keep_x: wp.array(dtype=wp.vec3),
        # Query points (threads in the order ``query_order``):
        query_order: wp.array(dtype=wp.int32),
        query_x: wp.array(dtype=wp.vec3),
        # Out:
        neighbor_count_out: wp.array(dtype=wp.int32),
        neighbor_index_out: wp.array2d(dtype=wp.int32),
        max_count_out: wp.array(dtype=wp.int32),
        density_out: wp.array(dtype=float),
    ):
        i = int(query_order[wp.tid() + tid_offset])
        xi = query_x[i]
        if keep_distance >= 0.0:  # row i holds the points within the radius of keep_x[i]: kept while i is near it
            if wp.length(xi - keep_x[i]) <= keep_distance:
                return
            keep_x[i] = xi
        if use_mask != 0:
            c = cell_of(xi, grid_lo, inv_cell_size, grid_dims)
            if cell_mask[c[0] + grid_dims[0] * (c[1] + grid_dims[1] * c[2])] == wp.uint8(0):
                if append == 0:
                    neighbor_count_out[i] = 0
                return
        q = (xi - grid_lo) * inv_cell_size
        qr = search_radius * inv_cell_size
        radius2 = search_radius * search_radius
        capacity = neighbor_index_out.shape[1]
        n = int(0)
        if append != 0:
            n = neighbor_count_out[i]
        total = float(0.0)
        if wp.static(walls):
            s = subcell_of(xi, grid_lo, wall_inv_size, wall_dims)
            e = wall_start[s]
            e_end = wall_start[s + 1]
            while e < e_end:
                k = wall_entry[e]
                d = xi - sorted_points[k]
                dd = wp.dot(d, d)
                if dd < radius2:
                    if n < capacity:
                        neighbor_index_out[i, n] = cell_point[k] + index_offset
                    n += 1
                    if wp.static(with_density):
                        w = wp.static(value)(wp.sqrt(dd), smoothing_length)
                        if wp.static(boundary_density):
                            w = wp.static(density_term)(boundary_params, w, sorted_weight[k])
                        total += w
                e += 1
        else:
            # the branch-free walk (``walk_candidates``: 5.5 -> 3.4 ms for the dam break's fluid lists) stores the
            # candidates' sorted indices; then the stored ones, in the same order, get their index and density term
            first = n
            n = walk_candidates(q, qr, xi, radius2, grid_dims, cell_start, sorted_points, neighbor_index_out, i, first)
            e = first
            e_end = wp.min(n, capacity)
            while e < e_end:
                k = neighbor_index_out[i, e]
                neighbor_index_out[i, e] = cell_point[k] + index_offset
                if wp.static(with_density):
                    d = xi - sorted_points[k]
                    w = wp.static(value)(wp.sqrt(wp.dot(d, d)), smoothing_length)
                    if wp.static(boundary_density):
                        w = wp.static(density_term)(boundary_params, w, sorted_weight[k])
                    total += w
                e += 1
        neighbor_count_out[i] = n
        if n > capacity:  # per particle, no atomics: split launches write disjoint particles
            max_count_out[i] = wp.max(max_count_out[i], n)
        if wp.static(with_density):
            rho = weight_scale * total
            if wp.static(boundary_density):
                rho = density_out[i] + rho
            density_out[i] = rho
        # (append: a second searched set, e.g. the moving boundary particles after the static ones, adds
        # its neighbours after those already listed, with indices index_offset + its own, and its density)

    return build_neighbor_list
