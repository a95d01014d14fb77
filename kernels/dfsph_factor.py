"""DFSPH's boundary search and factor: the second kernel of the step's one search (after
``fluid_search_kernel`` of ``kernels/dfsph_search.py``; notation there), the walk over the static (and
moving) boundary cell grids, or over the search skin's boundary lists, then f_i = 1 / D_i [m^2], the
divergence source and its warm start. Host half ``warp_sph/methods/solvers/dfsph_search.py``.
Threads write only their own particle (no atomics): bitwise reproducible for any thread count.
"""
import functools

import warp as wp

from .wall_reach import subcell_of
from .neighbors import NoBoundaryParams, cell_of, cell_rows, row_points
from .smoothing import SMOOTHING_FUNCTIONS


@functools.cache
def boundary_factor_kernel(smoothing: str, boundary_terms, search: bool, moving: bool = False, lists: bool = False,
                           walls: bool = False):
    """The boundary half of the search and the factor (threads in cell order): with ``search``, every
    boundary particle b within the support radius goes into the boundary neighbour list (cells with
    no boundary particle within one cell are skipped by the mask), and, when the boundary method's
    ``BoundaryTerms`` has density and gradient terms, into rho_i (rho0 density_b), s_i (gb_ib) and
    delta_i(v) (v_i - v_b). With ``moving`` (rigid bodies) a second grid, over the moving boundary
    particles (boundary indices moving_start + k), is walked after the static one, its neighbours
    listed after the static ones. With ``walls`` the static grid is not walked: the particle's sub-cell
    list of static boundary particles in reach (``kernels/wall_reach.py``, built once per run) is
    tested, in the walk's order (the same neighbours and sums, bitwise). With ``lists`` (the search skin)
    nothing is walked: the boundary
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

    if with_terms:
        @wp.func(module="unique")
        def add_pair_terms(boundary_params: BoundaryParams, x_ib: wp.vec3, dd: float, h: float, vol: float,
                           vb: wp.vec3, ratio: float, sb: wp.vec3, bvel: float):
            """One boundary particle b's terms added to (ratio, sb, bvel): the density term of W(|x_ib|), its
            gradient term gb_ib and v_b . gb_ib (the boundary method's ``BoundaryTerms``, volume V_b)."""
            gb = wp.static(gradient_term)(boundary_params, wp.static(gradient)(x_ib, h), vol)
            return (ratio + wp.static(density_term)(boundary_params, wp.static(value)(wp.sqrt(dd), h), vol),
                    sb + gb, bvel + wp.dot(vb, gb))
    else:
        add_pair_terms = None

    @wp.func(module="unique")
    def add_if_near(
        i: int,
        xi: wp.vec3,
        k: int,
        radius2: float,
        index_offset: int,
        h: float,
        cell_point: wp.array(dtype=wp.int32),
        sorted_points: wp.array(dtype=wp.vec3),
        sorted_volume: wp.array(dtype=float),
        boundary_params: BoundaryParams,
        boundary_v: wp.array(dtype=wp.vec3),
        neighbor_index_out: wp.array2d(dtype=wp.int32),
        nb_in: int,
        ratio_in: float,
        sb_in: wp.vec3,
        bvel_in: float,
    ):
        """Sorted boundary point k tested against x_i: when |x_ib|^2 < radius2 [m^2], b = cell_point[k] + index_offset
        is listed at nb (below the capacity), nb goes up by one and its terms are added to (ratio, sb, bvel). The one
        per-point body of ``walk_boundary`` and ``reach_boundary``."""
        nb = nb_in
        ratio = ratio_in
        sb = sb_in
        bvel = bvel_in
        x_ib = xi - sorted_points[k]
        dd = wp.dot(x_ib, x_ib)
        if dd < radius2:
            b = cell_point[k] + index_offset
            if nb < neighbor_index_out.shape[1]:
                neighbor_index_out[i, nb] = b
            nb += 1
            if wp.static(with_terms):
                ratio, sb, bvel = wp.static(add_pair_terms)(boundary_params, x_ib, dd, h, sorted_volume[k],
                                                            boundary_v[b], ratio, sb, bvel)
        return nb, ratio, sb, bvel

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
            rows = cell_rows(q, qr, grid_dims)
            for z in range(rows[2], rows[3] + 1):  # a branch per candidate: most boundary candidates are kept
                for y in range(rows[0], rows[1] + 1):
                    span = row_points(q, qr, y, z, grid_dims, cell_start)
                    k = span[0]
                    k_end = span[1]
                    while k < k_end:
                        nb, ratio, sb, bvel = add_if_near(i, xi, k, radius2, index_offset, h, cell_point,
                                                          sorted_points, sorted_volume, boundary_params, boundary_v,
                                                          neighbor_index_out, nb, ratio, sb, bvel)
                        k += 1
        return nb, ratio, sb, bvel

    @wp.func(module="unique")
    def reach_boundary(
        i: int,
        xi: wp.vec3,
        grid_lo: wp.vec3,
        wall_inv_size: float,
        wall_dims: wp.vec3i,
        wall_start: wp.array(dtype=wp.int32),
        wall_entry: wp.array(dtype=wp.int32),
        cell_point: wp.array(dtype=wp.int32),
        sorted_points: wp.array(dtype=wp.vec3),
        sorted_volume: wp.array(dtype=float),
        smoothing_length: float,
        support_radius: float,
        boundary_params: BoundaryParams,
        boundary_v: wp.array(dtype=wp.vec3),
        neighbor_index_out: wp.array2d(dtype=wp.int32),
        ratio_in: float,
        sb_in: wp.vec3,
        bvel_in: float,
    ):
        """``walk_boundary`` over the static grid, from the sub-cell list of x_i (sorted indices k in the
        walk's order): the same neighbours, listed first, and the same terms in the same order."""
        nb = int(0)
        ratio = ratio_in
        sb = sb_in
        bvel = bvel_in
        h = smoothing_length
        radius2 = support_radius * support_radius
        s = subcell_of(xi, grid_lo, wall_inv_size, wall_dims)
        e = wall_start[s]
        e_end = wall_start[s + 1]
        while e < e_end:
            nb, ratio, sb, bvel = add_if_near(i, xi, wall_entry[e], radius2, 0, h, cell_point, sorted_points,
                                              sorted_volume, boundary_params, boundary_v, neighbor_index_out, nb,
                                              ratio, sb, bvel)
            e += 1
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
                    ratio, sb, bvel = wp.static(add_pair_terms)(boundary_params, x_ib, dd, h, boundary_volume[b],
                                                                boundary_v[b], ratio, sb, bvel)
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
        # Static boundary particles in reach of each sub-cell (with ``walls``, ``kernels/wall_reach.py``):
        wall_inv_size: float,
        wall_dims: wp.vec3i,
        wall_start: wp.array(dtype=wp.int32),
        wall_entry: wp.array(dtype=wp.int32),
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
        if wp.static(search and not lists and walls):
            nb, ratio, sb, bvel = reach_boundary(i, xi, grid_lo, wall_inv_size, wall_dims, wall_start, wall_entry,
                                                 cell_point, sorted_points, sorted_volume, smoothing_length,
                                                 support_radius, boundary_params, boundary_v, neighbor_index_out,
                                                 ratio, sb, bvel)
        if wp.static(search and not lists and not walls):
            nb, ratio, sb, bvel = walk_boundary(i, xi, grid_lo, inv_cell_size, grid_dims, cell_start,
                                                cell_point, sorted_points, sorted_volume, cell_mask, use_mask, 0,
                                                smoothing_length, support_radius, boundary_params, boundary_v,
                                                neighbor_index_out, nb, ratio, sb, bvel)
        if wp.static(search and not lists):
            if wp.static(moving):
                nb, ratio, sb, bvel = walk_boundary(i, xi, moving_lo, moving_inv_cell_size, moving_dims,
                                                    moving_cell_start, moving_cell_point,
                                                    moving_sorted_points, moving_sorted_volume, moving_cell_mask,
                                                    moving_use_mask,
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
