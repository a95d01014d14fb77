"""DFSPH's per-step neighbour search, factor and pair cache: the search half of ``kernels/dfsph.py``
(notation there: V = m / rho0 [m^3], G_ij = V grad_i W_ij [1/m], the boundary term gb_ib [1/m],
s_i, D_i, f_i = 1 / D_i [m^2], delta_i(u)); host half ``warp_sph/methods/solvers/dfsph_search.py``.

Neighbours and the factor come from one search per step (``fluid_search_kernel`` then
``boundary_factor_kernel``, over the cell grids of ``warp_sph.neighbors.NeighborLists``, walked with
``cell_rows`` / ``row_points`` of ``kernels/neighbors.py`` as every list build is): each pair within
the support radius is found once, and its G_ij goes straight into row i of the pair cache
(``DfsphPairs``, row i at i x the list capacity), read as one stream per particle by every later pass;
the solves evaluate no smoothing kernel (with the search skin the pairs come from lists, in compressed
rows: ``kernels/dfsph_skin.py``). The same search writes the fluid and boundary
neighbour lists (fluid lists without i itself) that the shared viscosity and XSPH stages read.
Kernels taking ``tid_offset`` are split over CPU cores and write only their own particle (no
atomics), so results are bitwise reproducible for any thread count.
"""
import functools

import warp as wp

from .neighbors import NoBoundaryParams, cell_of, cell_rows, row_points
from .smoothing import SMOOTHING_FUNCTIONS


@wp.struct
class DfsphPairs:
    """The step's fluid pairs in compressed rows, and what the solves need per particle.

    Pairs of particle i (neighbours j != i closer than the support radius): entries
    offset[i] .. offset[i] + count[i] - 1 of index (neighbour j) and gradient (G_ij = V grad_i W_ij
    [1/m]); the 1-D arrays hold fluid_count x the list capacity entries (the per-step search puts row i
    at i x capacity; the search skin's rows are compressed, one after the other). gradient_sum[i] = s_i [1/m]; boundary_gradient[i] = sum_b gb_ib [1/m];
    boundary_velocity[i] = sum_b v_b . gb_ib [1/s]; active[i] = 1 when i has at least the threshold
    of neighbours (fluid, plus boundary when the boundary enters the density): its divergence error
    counts.
    """

    offset: wp.array(dtype=wp.int32)
    count: wp.array(dtype=wp.int32)
    index: wp.array(dtype=wp.int32)
    gradient: wp.array(dtype=wp.vec3)
    gradient_sum: wp.array(dtype=wp.vec3)
    boundary_gradient: wp.array(dtype=wp.vec3)
    boundary_velocity: wp.array(dtype=float)
    active: wp.array(dtype=wp.int32)


@functools.cache
def fluid_search_kernel(smoothing: str):
    """The fluid search in one pass per particle i (threads in cell order, k_i = i's sorted index) over
    the fluid cell grid. First the walk: the sorted indices k of every point within the support radius
    (i itself included), in walk order, into row i of neighbor_index_out (the first ``capacity``; when
    more are found the last slot keeps being overwritten, and the step is redone with larger lists),
    without a branch per candidate (an unpredictable branch per candidate was measured 15 % slower).
    Then, over that row while it is in cache, the kept points in walk order: the fluid neighbour list
    (j != i, rewritten in place; the count is exact; when i and its neighbours do not fit the capacity,
    entries are dropped and max_count_out[i] keeps the largest such number), row i of the pair cache
    (offset i x capacity, count, index j, G_ij) and the fluid parts of: rho_i = m sum_j W_ij (self
    included) [kg/m^3], s_i, sum_j |G_ij|^2 and delta_i(v) [1/s] (finished by ``boundary_factor_kernel``)."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.kernel(enable_backward=False, module="unique")
    def search_fluid(
        tid_offset: int,
        # Fluid cell grid:
        grid_lo: wp.vec3,
        inv_cell_size: float,
        grid_dims: wp.vec3i,
        cell_start: wp.array(dtype=wp.int32),
        cell_point: wp.array(dtype=wp.int32),
        sorted_points: wp.array(dtype=wp.vec3),
        support_radius: float,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        rest_density: float,
        # State in:
        particle_v: wp.array(dtype=wp.vec3),
        # Out:
        neighbor_count_out: wp.array(dtype=wp.int32),
        neighbor_index_out: wp.array2d(dtype=wp.int32),
        max_count_out: wp.array(dtype=wp.int32),
        pair_offset_out: wp.array(dtype=wp.int32),
        pair_count_out: wp.array(dtype=wp.int32),
        pair_index_out: wp.array(dtype=wp.int32),
        pair_gradient_out: wp.array(dtype=wp.vec3),
        particle_density_out: wp.array(dtype=float),
        gradient_sum_out: wp.array(dtype=wp.vec3),
        square_sum_out: wp.array(dtype=float),
        divergence_out: wp.array(dtype=float),
    ):
        k_self = wp.tid() + tid_offset
        i = int(cell_point[k_self])
        xi = sorted_points[k_self]
        q = (xi - grid_lo) * inv_cell_size
        qr = support_radius * inv_cell_size
        radius2 = support_radius * support_radius
        capacity = neighbor_index_out.shape[1]
        rows = cell_rows(q, qr, grid_dims)
        last = capacity - 1
        found = int(0)
        self_rank = capacity  # where i itself falls among the found (kept when < capacity)
        for z in range(rows[2], rows[3] + 1):
            for y in range(rows[0], rows[1] + 1):
                span = row_points(q, qr, y, z, grid_dims, cell_start)
                k = span[0]
                k_end = span[1]
                while k < k_end:
                    x_ij = xi - sorted_points[k]
                    neighbor_index_out[i, wp.min(found, last)] = k
                    self_rank = wp.where(k == k_self, found, self_rank)
                    found += wp.where(wp.dot(x_ij, x_ij) < radius2, 1, 0)
                    k += 1
        # the values over the row just written, in walk order; i itself adds W(0) to the density and is
        # dropped from the lists
        keep = wp.min(found, capacity) - wp.where(self_rank < capacity, 1, 0)
        vi = particle_v[i]
        h = smoothing_length
        volume = particle_mass / rest_density
        base = i * capacity
        w_sum = float(0.0)
        s = wp.vec3(0.0)
        sq = float(0.0)
        div = float(0.0)
        n = int(0)
        e = int(0)
        e_end = wp.min(found, capacity)
        while e < e_end:
            k = neighbor_index_out[i, e]
            x_ij = xi - sorted_points[k]
            w_sum += wp.static(value)(wp.length(x_ij), h)
            j = cell_point[k]
            if j != i and n < keep:
                g = volume * wp.static(gradient)(x_ij, h)
                s += g
                sq += wp.dot(g, g)
                div += wp.dot(vi - particle_v[j], g)
                neighbor_index_out[i, n] = j
                pair_index_out[base + n] = j
                pair_gradient_out[base + n] = g
                n += 1
            e += 1
        pair_offset_out[i] = base
        pair_count_out[i] = n
        if found > capacity:  # pairs were dropped: the frame is redone with larger lists
            max_count_out[i] = wp.max(max_count_out[i], found)  # per particle, no atomics
            n = found - 1
        neighbor_count_out[i] = n
        particle_density_out[i] = particle_mass * w_sum
        gradient_sum_out[i] = s
        square_sum_out[i] = sq
        divergence_out[i] = div

    return search_fluid


@functools.cache
def boundary_factor_kernel(smoothing: str, boundary_terms, search: bool, moving: bool = False, lists: bool = False):
    """The boundary half of the search and the factor (threads in cell order): with ``search``, every
    boundary particle b within the support radius goes into the boundary neighbour list (cells with
    no boundary particle within one cell are skipped by the mask), and, when the boundary method's
    ``BoundaryTerms`` has density and gradient terms, into rho_i (rho0 density_b), s_i (gb_ib) and
    delta_i(v) (v_i - v_b). With ``moving`` (rigid bodies) a second grid, over the moving boundary
    particles (boundary indices moving_start + k), is walked after the static one, its neighbours
    listed after the static ones. With ``lists`` (the search skin) nothing is walked: the boundary
    neighbour list (built within H_s + skin, boundary indices) is read and its particles b closer than
    the support radius add the same terms (x_b from boundary_x, V_b from boundary_volume), in the
    list's order. Then, from the fluid parts: f_i = 1 / D_i (0 when D_i <= factor_floor),
    the divergence source -delta_i(v), active_i, the divergence warm start P^v_i = warm_start
    P~^v_i / dt where delta_i(v) > 0 and i is active (P~^v = P^v dt of the last step [m^2/s]), the
    compression max(rho_i / rho0 - 1, 0) [-] (the stabilisation test reads its mean), the solves'
    acceleration scratch and the boundary force cleared."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]
    with_terms = search and boundary_terms is not None and boundary_terms.gradient is not None
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    density_term = boundary_terms.density if with_terms else None
    gradient_term = boundary_terms.gradient if with_terms else None

    @wp.func(module="unique")
    def walk_boundary(
        i: int,
        xi: wp.vec3,
        grid_lo: wp.vec3,
        inv_cell_size: float,
        grid_dims: wp.vec3i,
        cell_start: wp.array(dtype=wp.int32),
        cell_point: wp.array(dtype=wp.int32),
        sorted_points: wp.array(dtype=wp.vec3),
        sorted_volume: wp.array(dtype=float),
        cell_mask: wp.array(dtype=wp.uint8),
        use_mask: int,
        index_offset: int,
        smoothing_length: float,
        support_radius: float,
        boundary_params: BoundaryParams,
        boundary_v: wp.array(dtype=wp.vec3),
        neighbor_index_out: wp.array2d(dtype=wp.int32),
        nb_in: int,
        ratio_in: float,
        sb_in: wp.vec3,
        bvel_in: float,
    ):
        """One boundary cell grid's particles b within the support radius of x_i: listed after the nb_in
        already listed (index index_offset + the grid's own), their terms added to (ratio, sb, bvel)."""
        nb = nb_in
        ratio = ratio_in
        sb = sb_in
        bvel = bvel_in
        h = smoothing_length
        skip = int(0)
        if use_mask != 0:
            c = cell_of(xi, grid_lo, inv_cell_size, grid_dims)
            if cell_mask[c[0] + grid_dims[0] * (c[1] + grid_dims[1] * c[2])] == wp.uint8(0):
                skip = 1
        if skip == 0:
            q = (xi - grid_lo) * inv_cell_size
            qr = support_radius * inv_cell_size
            radius2 = support_radius * support_radius
            capacity = neighbor_index_out.shape[1]
            rows = cell_rows(q, qr, grid_dims)
            for z in range(rows[2], rows[3] + 1):  # a branch per candidate: most boundary candidates are kept
                for y in range(rows[0], rows[1] + 1):
                    span = row_points(q, qr, y, z, grid_dims, cell_start)
                    k = span[0]
                    k_end = span[1]
                    while k < k_end:
                        x_ib = xi - sorted_points[k]
                        dd = wp.dot(x_ib, x_ib)
                        if dd < radius2:
                            b = cell_point[k] + index_offset
                            if nb < capacity:
                                neighbor_index_out[i, nb] = b
                            nb += 1
                            if wp.static(with_terms):
                                vol = sorted_volume[k]
                                ratio += wp.static(density_term)(boundary_params,
                                                                 wp.static(value)(wp.sqrt(dd), h), vol)
                                gb = wp.static(gradient_term)(boundary_params, wp.static(gradient)(x_ib, h), vol)
                                sb += gb
                                bvel += wp.dot(boundary_v[b], gb)
                        k += 1
        return nb, ratio, sb, bvel

    @wp.func(module="unique")
    def list_boundary(
        i: int,
        xi: wp.vec3,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        neighbor_count: wp.array(dtype=wp.int32),
        neighbor_index: wp.array2d(dtype=wp.int32),
        smoothing_length: float,
        support_radius: float,
        boundary_params: BoundaryParams,
        boundary_v: wp.array(dtype=wp.vec3),
        ratio_in: float,
        sb_in: wp.vec3,
        bvel_in: float,
    ):
        """The listed boundary particles b (within H_s + skin when listed) closer than the support radius:
        their count and their terms added to (ratio, sb, bvel)."""
        nb = int(0)
        ratio = ratio_in
        sb = sb_in
        bvel = bvel_in
        h = smoothing_length
        radius2 = support_radius * support_radius
        e = int(0)
        e_end = wp.min(neighbor_count[i], neighbor_index.shape[1])
        while e < e_end:
            b = neighbor_index[i, e]
            x_ib = xi - boundary_x[b]
            dd = wp.dot(x_ib, x_ib)
            if dd < radius2:
                nb += 1
                if wp.static(with_terms):
                    vol = boundary_volume[b]
                    ratio += wp.static(density_term)(boundary_params, wp.static(value)(wp.sqrt(dd), h), vol)
                    gb = wp.static(gradient_term)(boundary_params, wp.static(gradient)(x_ib, h), vol)
                    sb += gb
                    bvel += wp.dot(boundary_v[b], gb)
            e += 1
        return nb, ratio, sb, bvel

    @wp.kernel(enable_backward=False, module="unique")
    def boundary_factor(
        tid_offset: int,
        # Boundary cell grid (the static particles):
        grid_lo: wp.vec3,
        inv_cell_size: float,
        grid_dims: wp.vec3i,
        cell_start: wp.array(dtype=wp.int32),
        cell_point: wp.array(dtype=wp.int32),
        sorted_points: wp.array(dtype=wp.vec3),
        sorted_volume: wp.array(dtype=float),
        cell_mask: wp.array(dtype=wp.uint8),
        use_mask: int,
        # Moving boundary cell grid (with ``moving``; boundary indices moving_start + its own):
        moving_lo: wp.vec3,
        moving_inv_cell_size: float,
        moving_dims: wp.vec3i,
        moving_cell_start: wp.array(dtype=wp.int32),
        moving_cell_point: wp.array(dtype=wp.int32),
        moving_sorted_points: wp.array(dtype=wp.vec3),
        moving_sorted_volume: wp.array(dtype=float),
        moving_cell_mask: wp.array(dtype=wp.uint8),
        moving_use_mask: int,
        moving_start: int,
        # Model:
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        factor_floor: float,
        neighbor_threshold: int,
        boundary_params: BoundaryParams,
        boundary_v: wp.array(dtype=wp.vec3),
        # Warm start:
        warm_start: float,
        inv_dt: float,
        # State in:
        fluid_order: wp.array(dtype=wp.int32),
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        divergence_warm: wp.array(dtype=float),
        fluid_count: wp.array(dtype=wp.int32),
        square_sum: wp.array(dtype=float),
        # Boundary particles (with ``lists``):
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # In/out (fluid parts in, totals out):
        particle_density: wp.array(dtype=float),
        gradient_sum: wp.array(dtype=wp.vec3),
        divergence: wp.array(dtype=float),
        # Out (the boundary neighbour list: in with ``lists``):
        neighbor_count_out: wp.array(dtype=wp.int32),
        neighbor_index_out: wp.array2d(dtype=wp.int32),
        max_count_out: wp.array(dtype=wp.int32),
        boundary_gradient_out: wp.array(dtype=wp.vec3),
        boundary_velocity_out: wp.array(dtype=float),
        active_out: wp.array(dtype=wp.int32),
        factor_out: wp.array(dtype=float),
        divergence_pressure_out: wp.array(dtype=float),
        acceleration_out: wp.array(dtype=wp.vec3),
        compression_out: wp.array(dtype=float),
        boundary_force_out: wp.array(dtype=wp.vec3),
    ):
        i = int(fluid_order[wp.tid() + tid_offset])
        xi = particle_x[i]
        vi = particle_v[i]
        ratio = particle_density[i] / rest_density
        s = gradient_sum[i]
        div = divergence[i]
        sb = wp.vec3(0.0)
        bvel = float(0.0)
        nb = int(0)
        if wp.static(search and lists):
            nb, ratio, sb, bvel = list_boundary(i, xi, boundary_x, boundary_volume, neighbor_count_out,
                                                neighbor_index_out, smoothing_length, support_radius,
                                                boundary_params, boundary_v, ratio, sb, bvel)
        if wp.static(search and not lists):
            nb, ratio, sb, bvel = walk_boundary(i, xi, grid_lo, inv_cell_size, grid_dims, cell_start, cell_point,
                                                sorted_points, sorted_volume, cell_mask, use_mask, 0,
                                                smoothing_length, support_radius, boundary_params, boundary_v,
                                                neighbor_index_out, nb, ratio, sb, bvel)
            if wp.static(moving):
                nb, ratio, sb, bvel = walk_boundary(i, xi, moving_lo, moving_inv_cell_size, moving_dims,
                                                    moving_cell_start, moving_cell_point, moving_sorted_points,
                                                    moving_sorted_volume, moving_cell_mask, moving_use_mask,
                                                    moving_start, smoothing_length, support_radius,
                                                    boundary_params, boundary_v, neighbor_index_out, nb, ratio,
                                                    sb, bvel)
            if nb > neighbor_index_out.shape[1]:
                max_count_out[i] = wp.max(max_count_out[i], nb)
            neighbor_count_out[i] = nb
        s += sb
        div += wp.dot(vi, sb) - bvel
        d = wp.dot(s, s) + square_sum[i]
        f = float(0.0)
        if d > factor_floor:
            f = 1.0 / d
        neighbors = fluid_count[i]
        if wp.static(with_terms):
            neighbors += nb
        active = int(0)
        if neighbors >= neighbor_threshold:
            active = 1
        p = float(0.0)
        if div > 0.0 and active == 1:
            p = warm_start * divergence_warm[i] * inv_dt
        particle_density[i] = rest_density * ratio
        gradient_sum[i] = s
        divergence[i] = -div
        boundary_gradient_out[i] = sb
        boundary_velocity_out[i] = bvel
        active_out[i] = active
        factor_out[i] = f
        divergence_pressure_out[i] = p
        acceleration_out[i] = wp.vec3(0.0)
        compression_out[i] = wp.max(ratio - 1.0, 0.0)
        boundary_force_out[i] = wp.vec3(0.0)

    return boundary_factor
