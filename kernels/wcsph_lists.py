"""WCSPH's pass over neighbour lists kept over several steps (``wcsph.search_skin``; host:
``warp_sph/methods/solvers/wcsph_lists.py``): the density (report eq. 7/13) over lists that hold pairs up to
H_s + a skin, and the step's ``PairCache`` (``kernels/pbf_pairs.py``) of the pairs closer than H_s with grad W, which
the force kernel (``wcsph.acceleration_kernel``, neighbors "pairs") reads."""
import functools

import warp as wp

from .neighbors import NeighborList, NoBoundaryParams, neighbor_count, particle_in_cell_order, walk_candidates
from .pbf_pairs import PairCache, cubic_value_gradient_select, value_gradient_function
from .smoothing import SMOOTHING_FUNCTIONS


@functools.cache
def boundary_density_sum_function(smoothing: str, boundary_terms):
    """A @wp.func: sum_b density_b(W_ib, V_b) [-] over particle i's listed boundary particles closer than H_s (the
    wall's share of report eq. 13 before the factor rho0), in the lists' order; shared by the list pass and the
    fused search (one copy of the loop, the same expressions)."""
    value = SMOOTHING_FUNCTIONS[smoothing][0]
    density_term = boundary_terms.density

    @wp.func
    def boundary_density_sum(boundary_params: boundary_terms.Params, boundary_neighbors: NeighborList,
                             boundary_x: wp.array(dtype=wp.vec3), boundary_volume: wp.array(dtype=float), i: int,
                             xi: wp.vec3, h: float, support2: float):
        boundary_sum = float(0.0)
        k = int(0)
        k_end = int(neighbor_count(boundary_neighbors, i))
        while k < k_end:
            b = boundary_neighbors.index[i, k]
            x_ib = xi - boundary_x[b]
            if wp.dot(x_ib, x_ib) < support2:
                w = wp.static(value)(wp.length(x_ib), h)
                boundary_sum += wp.static(density_term)(boundary_params, w, boundary_volume[b])
            k += 1
        return boundary_sum

    return boundary_density_sum


@functools.cache
def density_pair_functions(smoothing: str, boundary_terms):
    """(add_pair, write_density): the per-pair body and the density tail that the list pass
    (``density_pairs_kernel``) and the fused search (``search_density_pairs_kernel``) share, so the two stay
    bitwise one another's.

    add_pair(t, n, i, j, x_ij, h, H_s^2, pairs, total) -> (total', n'): listed pair ij added to total = sum_j W_ij
    [1/m^3] and, when closer than H_s and j != i, stored at slot n of the ``PairCache``'s row t (j, grad_i W_ij
    [1/m^4]); the cubic spline without branches (``cubic_value_gradient_select``: W = 0 and grad W = 0 from H_s on,
    every pair written at the next free slot, which only the cached pairs advance).

    write_density(t, i, x_i, n, total, ...): the row's pair count and rho_i = m total + rho0 sum_b density_b(W_ib,
    V_b) [kg/m^3] (report eq. 7/13)."""
    select = smoothing == "cubic"
    value_gradient = cubic_value_gradient_select if select else value_gradient_function(smoothing)
    with_boundary = boundary_terms is not None and boundary_terms.density is not None
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    boundary_density_sum = boundary_density_sum_function(smoothing, boundary_terms) if with_boundary else None

    @wp.func(module="unique")
    def add_pair(t: int, n: int, i: int, j: int, x_ij: wp.vec3, h: float, support2: float, pairs_out: PairCache,
                 total: float):
        if wp.static(select):
            wg = cubic_value_gradient_select(x_ij, h)
            total += wg[0]
            pairs_out.index[t, n] = j
            pairs_out.gradient[t, n] = wp.vec3(wg[1], wg[2], wg[3])
            n += wp.where((wp.dot(x_ij, x_ij) < support2) and (j != i), 1, 0)
        else:
            if wp.dot(x_ij, x_ij) < support2:
                wg = wp.static(value_gradient)(x_ij, h)
                total += wg[0]
                if j != i:
                    pairs_out.index[t, n] = j
                    pairs_out.gradient[t, n] = wp.vec3(wg[1], wg[2], wg[3])
                    n += 1
        return total, n

    @wp.func(module="unique")
    def write_density(t: int, i: int, xi: wp.vec3, n: int, total: float, particle_mass: float, h: float,
                      support2: float, rest_density: float, boundary_params: BoundaryParams,
                      boundary_neighbors: NeighborList, boundary_x: wp.array(dtype=wp.vec3),
                      boundary_volume: wp.array(dtype=float), pairs_out: PairCache,
                      particle_density_out: wp.array(dtype=float)):
        pairs_out.count[t] = n
        rho = particle_mass * total
        if wp.static(with_boundary):
            rho += rest_density * wp.static(boundary_density_sum)(boundary_params, boundary_neighbors, boundary_x,
                                                                  boundary_volume, i, xi, h, support2)
        particle_density_out[i] = rho

    return add_pair, write_density


@functools.cache
def density_pairs_kernel(smoothing: str, boundary_terms=None):
    """rho_i = m sum_j W_ij + rho0 sum_b density_b(W_ib, V_b) [kg/m^3] (report eq. 7/13) over neighbour lists that
    hold pairs up to H_s + a skin (``wcsph.search_skin``; pairs at or beyond H_s add nothing), and the step's
    ``PairCache`` of the pairs closer than H_s (j != i): index j and grad_i W_ij [1/m^4] in the lists' order, which
    the force kernel (``acceleration_kernel``, neighbors "pairs") reads instead of evaluating the kernel again.
    The density is bitwise the list pass's (``density.density_kernel``) and the fused search's over the same lists;
    the cached gradient bitwise ``gradient(x_ij, h)`` (``pbf_pairs.value_gradient_function``); the cubic spline is
    evaluated without branches (``cubic_value_gradient_select``, equal to rounding) and the cache is filled
    without a branch per pair (every listed pair is written at the next free slot, which only the pairs closer
    than H_s advance)."""
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    add_pair, write_density = density_pair_functions(smoothing, boundary_terms)

    @wp.kernel(enable_backward=False, module="unique")
    def compute_density_pairs(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        boundary_params: BoundaryParams,
        boundary_neighbors: NeighborList,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: NeighborList,
        particle_x: wp.array(dtype=wp.vec3),
        # Out:
        particle_density_out: wp.array(dtype=float),
        pairs_out: PairCache,
    ):
        t = wp.tid() + tid_offset  # the pair cache's row (``pbf_pairs.PairCache``)
        i = particle_in_cell_order(fluid_neighbors, t)
        xi = particle_x[i]
        h = smoothing_length
        support2 = support_radius * support_radius
        total = float(0.0)
        n = int(0)
        k = int(0)
        k_end = int(neighbor_count(fluid_neighbors, i))
        while k < k_end:
            j = fluid_neighbors.index[i, k]
            total, n = add_pair(t, n, i, j, xi - particle_x[j], h, support2, pairs_out, total)
            k += 1
        write_density(t, i, xi, n, total, particle_mass, h, support2, rest_density, boundary_params,
                      boundary_neighbors, boundary_x, boundary_volume, pairs_out, particle_density_out)

    return compute_density_pairs


@functools.cache
def search_density_pairs_kernel(smoothing: str, boundary_terms=None):
    """A search step's fluid lists within ``search_radius`` = H_s + skin [m] (as ``neighbors.neighbor_list_kernel``:
    count exact, entries past the capacity dropped, max_count_out[i] their largest count) and, in the same walk
    over the cells, what ``density_pairs_kernel`` then computes over those lists: the density [kg/m^3] and the
    ``PairCache``. The stored pairs in the lists' order with the same expressions (sorted_points[k] is a copy of
    x_j), so bitwise that pass; the boundary lists are built before it (it reads them), as in PBF's fused
    search (``kernels/pbf_search.py``)."""
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    add_pair, write_density = density_pair_functions(smoothing, boundary_terms)

    @wp.kernel(enable_backward=False, module="unique")
    def search_density_pairs(
        tid_offset: int,
        # Grid of the fluid (sorted on particle_x):
        grid_lo: wp.vec3,
        inv_cell_size: float,
        grid_dims: wp.vec3i,
        cell_start: wp.array(dtype=wp.int32),
        cell_point: wp.array(dtype=wp.int32),
        sorted_points: wp.array(dtype=wp.vec3),
        search_radius: float,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        boundary_params: BoundaryParams,
        boundary_neighbors: NeighborList,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        particle_x: wp.array(dtype=wp.vec3),
        # Out:
        fluid_neighbors: NeighborList,
        max_count_out: wp.array(dtype=wp.int32),
        particle_density_out: wp.array(dtype=float),
        pairs_out: PairCache,
    ):
        t = wp.tid() + tid_offset  # the pair cache's row (``pbf_pairs.PairCache``)
        i = particle_in_cell_order(fluid_neighbors, t)
        xi = particle_x[i]
        q = (xi - grid_lo) * inv_cell_size
        qr = search_radius * inv_cell_size
        radius2 = search_radius * search_radius
        capacity = fluid_neighbors.index.shape[1]
        h = smoothing_length
        support2 = support_radius * support_radius
        total = float(0.0)
        # the branch-free walk (``neighbors.walk_candidates``) stores the candidates' sorted indices, then
        # density_pairs_kernel's body over the stored pairs in the same order
        m = walk_candidates(q, qr, xi, radius2, grid_dims, cell_start, sorted_points, fluid_neighbors.index, i, 0)
        n = int(0)  # cached pairs
        e = int(0)
        e_end = wp.min(m, capacity)
        while e < e_end:
            k = fluid_neighbors.index[i, e]
            j = cell_point[k]
            fluid_neighbors.index[i, e] = j
            total, n = add_pair(t, n, i, j, xi - sorted_points[k], h, support2, pairs_out, total)
            e += 1
        fluid_neighbors.count[i] = m
        if m > capacity:  # per particle, no atomics (the boundary lists' launch wrote before this one)
            max_count_out[i] = wp.max(max_count_out[i], m)
        write_density(t, i, xi, n, total, particle_mass, h, support2, rest_density, boundary_params,
                      boundary_neighbors, boundary_x, boundary_volume, pairs_out, particle_density_out)

    return search_density_pairs


@wp.kernel(enable_backward=False)
def displacement_bounds_chunks(
    chunk: int,
    count: int,
    # In:
    particle_x: wp.array(dtype=wp.vec3),
    neighbor_x: wp.array(dtype=wp.vec3),
    neighbor_slot: wp.array(dtype=wp.int32),
    wall_x: wp.array(dtype=wp.vec3),
    # Out:
    partial_out: wp.array2d(dtype=float),
):
    """Per chunk of the first ``count`` particles, of the displacements d_i = x_i - x_i(search) [m]: the largest
    |d_i| (column 0) and the bounding box of the d_i, its lower corner negated (columns 1-3) and its upper corner
    (columns 4-6), so that the host's maximum over the chunks gives both; the largest |x_i - wall_x_i| (column 7,
    the drift since the static-wall lists were searched); 1e30 everywhere when a particle is no longer at the index
    it had at the search (neighbor_slot[i] != i: reordered, the lists' indices are stale).
    Maxima only: the result does not depend on the thread count."""
    k = wp.tid()
    lo = k * chunk
    hi = wp.min(lo + chunk, count)
    drift = float(0.0)
    neg_lo = wp.vec3(-1.0e30)
    up = wp.vec3(-1.0e30)
    wall_drift = float(0.0)
    for i in range(lo, hi):
        d = particle_x[i] - neighbor_x[i]
        wall_drift = wp.max(wall_drift, wp.length(particle_x[i] - wall_x[i]))
        if neighbor_slot[i] != i:
            drift = 1.0e30
            wall_drift = 1.0e30
            d = wp.vec3(1.0e30)
            neg_lo = wp.vec3(1.0e30)
        drift = wp.max(drift, wp.length(d))
        neg_lo = wp.max(neg_lo, -d)
        up = wp.max(up, d)
    partial_out[k, 0] = drift
    partial_out[k, 1] = neg_lo[0]
    partial_out[k, 2] = neg_lo[1]
    partial_out[k, 3] = neg_lo[2]
    partial_out[k, 4] = up[0]
    partial_out[k, 5] = up[1]
    partial_out[k, 6] = up[2]
    partial_out[k, 7] = wall_drift
