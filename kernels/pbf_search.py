"""PBF's step search fused with its first density pass: one kernel walks the cell grid of the fluid
(``warp_sph.neighbors.NeighborLists``), writes the fluid neighbour lists (search radius H_s + margin)
and, over the listed pairs closer than H_s, sums the density, C and lambda of ``kernels/pbf.py``
(eq. 7/13, 17, 19) and fills its ``PairCache``, so the step's first density pass costs no second walk
over the lists. The pairs are visited in the lists' order (cell order, then index), as the list pass
``density_lambda_pairs_kernel`` visits them: the sums, and so the results, are bitwise the same.
The boundary lists are built before it (``NeighborLists.build_boundary_lists``): it reads them.
Also the check that lists kept from an earlier step still serve (``neighbor_drift_chunks``) and the
density pass at x that only needs C (``constraint_pairs_kernel``: the stabilize stage's offset).
"""
import functools

import warp as wp

from .neighbors import NeighborList, NoBoundaryParams, neighbor_count, walk_candidates
from .pbf_pairs import PairCache, density_lambda_functions, pair_value_gradient_function
from .smoothing import SMOOTHING_FUNCTIONS


@functools.cache
def search_density_lambda_kernel(smoothing: str, boundary_terms, tensile: bool):
    """Fluid neighbour lists within ``search_radius`` [m] (as ``neighbors.neighbor_list_kernel``: count exact,
    entries past the capacity dropped, max_count_out[i] their largest count) plus, over the stored pairs
    closer than the support radius, what ``pbf_pairs.density_lambda_pairs_kernel`` writes: density [kg/m^3],
    lambda [m^2], C [-] and the ``PairCache`` (with the list pass's two halves, ``pbf_pairs.density_lambda_functions``)."""
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    cached_pair_sums, write_density_lambda = density_lambda_functions(smoothing, boundary_terms, tensile)

    @wp.kernel(enable_backward=False, module="unique")
    def search_density_lambda(
        tid_offset: int,
        # Grid of the fluid (sorted on predicted_x):
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
        relaxation_epsilon: float,
        boundary_params: BoundaryParams,
        boundary_neighbors: NeighborList,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        predicted_x: wp.array(dtype=wp.vec3),
        constraint_offset: wp.array(dtype=float),
        # Out:
        fluid_neighbors: NeighborList,
        max_count_out: wp.array(dtype=wp.int32),
        particle_density_out: wp.array(dtype=float),
        particle_lambda_out: wp.array(dtype=float),
        particle_constraint_out: wp.array(dtype=float),
        pairs_out: PairCache,
        neighbor_slot_out: wp.array(dtype=wp.int32),
    ):
        t = wp.tid() + tid_offset  # the pair cache's row
        i = int(fluid_neighbors.order[t])
        xi = predicted_x[i]
        q = (xi - grid_lo) * inv_cell_size
        qr = search_radius * inv_cell_size
        radius2 = search_radius * search_radius
        capacity = fluid_neighbors.index.shape[1]
        h = smoothing_length
        support2 = support_radius * support_radius
        volume = particle_mass / rest_density
        # the branch-free walk (``neighbors.walk_candidates``: 7.2 -> 5.8 ms per pass on the dam break) stores the
        # candidates' sorted indices, then the listed pairs in the same order
        n = walk_candidates(q, qr, xi, radius2, grid_dims, cell_start, sorted_points, fluid_neighbors.index, i, 0)
        # the listed pairs: their indices, and those closer than H_s into the cache's index row without a branch
        # (each at the next free slot, which only those advance); then those pairs' terms in the same order
        p = int(0)
        m = int(0)
        m_end = wp.min(n, capacity)
        while m < m_end:
            k = fluid_neighbors.index[i, m]
            j = cell_point[k]
            fluid_neighbors.index[i, m] = j
            x_ij = xi - sorted_points[k]
            pairs_out.index[t, p] = j  # (p <= m: within the row)
            p += wp.where(wp.dot(x_ij, x_ij) < support2, 1, 0)
            m += 1
        # (predicted_x, not sorted_points: the same x*, read as the list pass reads them)
        w_sum, grad_i, grad_sq = cached_pair_sums(t, p, xi, h, volume, predicted_x, pairs_out)
        fluid_neighbors.count[i] = n
        neighbor_slot_out[i] = i  # (``pbf.neighbor_drift_chunks``: the lists' indices hold while this does)
        if n > capacity:  # per particle, no atomics (the boundary lists' launch wrote before this one)
            max_count_out[i] = wp.max(max_count_out[i], n)
        write_density_lambda(t, i, xi, p, w_sum, grad_i, grad_sq, volume, h, support2, rest_density, relaxation_epsilon,
                             boundary_params, boundary_neighbors, boundary_x, boundary_volume, constraint_offset,
                             pairs_out, particle_density_out, particle_lambda_out, particle_constraint_out)

    return search_density_lambda


@wp.kernel(enable_backward=False)
def neighbor_drift_chunks(
    chunk: int,
    count: int,
    # In:
    predicted_x: wp.array(dtype=wp.vec3),
    neighbor_x: wp.array(dtype=wp.vec3),
    neighbor_slot: wp.array(dtype=wp.int32),
    # Out:
    partial_out: wp.array(dtype=float),
):
    """Per chunk of the first ``count`` particles: the largest distance of x*_i from where its neighbours
    were searched [m], or 1e30 when a particle is no longer at the index it had then (neighbor_slot[i] != i:
    the particles were reordered since, and the lists' indices are stale)."""
    k = wp.tid()
    lo = k * chunk
    hi = wp.min(lo + chunk, count)
    drift = float(0.0)
    for i in range(lo, hi):
        if neighbor_slot[i] != i:
            drift = 1.0e30
        drift = wp.max(drift, wp.length(predicted_x[i] - neighbor_x[i]))
    partial_out[k] = drift


@wp.kernel(enable_backward=False)
def identity_slots(
    tid_offset: int,
    # Out:
    slot_out: wp.array(dtype=wp.int32),
):
    """slot_i = i: where each particle is when its neighbours are searched (``neighbor_drift_chunks``)."""
    i = wp.tid() + tid_offset
    slot_out[i] = i


@functools.cache
def constraint_kernel(smoothing: str, boundary_terms):
    """Density [kg/m^3] and C [-] alone (eq. 7/13, 17) over the neighbour lists: what the stabilize stage's
    constraint offset reads at x (no lambda, no pair cache: the step's density stage writes those at x*).
    The same pairs, order and expressions as ``pbf_pairs.density_lambda_pairs_kernel``: bitwise its density and C."""
    value = SMOOTHING_FUNCTIONS[smoothing][0]
    value_gradient = pair_value_gradient_function(smoothing)  # the fluid pairs' W as the density passes evaluate it
    with_boundary = boundary_terms is not None and boundary_terms.density is not None
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    density_term = boundary_terms.density if with_boundary else None

    @wp.kernel(enable_backward=False, module="unique")
    def compute_constraint(
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
        predicted_x: wp.array(dtype=wp.vec3),
        constraint_offset: wp.array(dtype=float),
        # Out:
        particle_density_out: wp.array(dtype=float),
        particle_constraint_out: wp.array(dtype=float),
    ):
        i = int(fluid_neighbors.order[wp.tid() + tid_offset])
        xi = predicted_x[i]
        h = smoothing_length
        support2 = support_radius * support_radius
        volume = particle_mass / rest_density
        w_sum = float(0.0)
        k = int(0)
        k_end = int(neighbor_count(fluid_neighbors, i))
        while k < k_end:
            x_ij = xi - predicted_x[fluid_neighbors.index[i, k]]
            if wp.dot(x_ij, x_ij) < support2:
                w_sum += wp.static(value_gradient)(x_ij, h)[0]
            k += 1
        ratio = volume * w_sum
        if wp.static(with_boundary):
            k = int(0)
            k_end = int(neighbor_count(boundary_neighbors, i))
            while k < k_end:
                b = boundary_neighbors.index[i, k]
                x_ib = xi - boundary_x[b]
                if wp.dot(x_ib, x_ib) < support2:
                    ratio += wp.static(density_term)(boundary_params, wp.static(value)(wp.length(x_ib), h),
                                                     boundary_volume[b])
                k += 1
        particle_density_out[i] = rest_density * ratio
        particle_constraint_out[i] = wp.max((ratio - constraint_offset[i]) - 1.0, 0.0)  # as constraint_lambda

    return compute_constraint
