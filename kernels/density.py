"""SPH density summation (report eq. 7, with Akinci boundaries eq. 8/13-15)."""
import functools

import warp as wp

from .neighbors import NeighborList, NoBoundaryParams, neighbor_count, particle_in_cell_order
from .smoothing import SMOOTHING_FUNCTIONS

NEIGHBOR_TYPES = {"grid": wp.uint64, "list": NeighborList}
"""Neighbour iteration chosen at compile time: "grid" (``fluid_neighbors``/``boundary_neighbors`` are
wp.HashGrid ids, queried per pass) or "list" (``NeighborList`` structs built once per step)."""


@functools.cache
def density_kernel(smoothing: str, boundary_terms=None, neighbors: str = "grid"):
    """rho_i = m sum_j W_ij + rho0 sum_b density_b(W_ib, V_b) [kg/m^3] (Akinci: density_b = V_b W_ib,
    report eq. 13); one thread per particle. boundary_terms: the boundary method's ``BoundaryTerms``
    (None, or one without a density term: fluid only)."""
    value, _ = SMOOTHING_FUNCTIONS[smoothing]
    with_boundary = boundary_terms is not None and boundary_terms.density is not None
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    density_term = boundary_terms.density if with_boundary else None
    lists = neighbors == "list"
    Neighbors = NEIGHBOR_TYPES[neighbors]

    @wp.kernel(enable_backward=False, module="unique")
    def compute_density(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        boundary_params: BoundaryParams,
        boundary_neighbors: Neighbors,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: Neighbors,
        particle_x: wp.array(dtype=wp.vec3),
        # Out:
        particle_density_out: wp.array(dtype=float),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = particle_x[i]
        total = float(0.0)
        if wp.static(lists):
            k = int(0)
            k_end = int(neighbor_count(fluid_neighbors, i))
            while k < k_end:
                total += wp.static(value)(wp.length(xi - particle_x[fluid_neighbors.index[i, k]]), smoothing_length)
                k += 1
        else:
            query = wp.hash_grid_query(fluid_neighbors, xi, support_radius)
            j = int(0)
            while wp.hash_grid_query_next(query, j):
                r = wp.length(xi - particle_x[j])
                if r < support_radius:
                    total += wp.static(value)(r, smoothing_length)
        rho = particle_mass * total
        if wp.static(with_boundary):
            boundary_sum = float(0.0)
            if wp.static(lists):
                k = int(0)
                k_end = int(neighbor_count(boundary_neighbors, i))
                while k < k_end:
                    b = boundary_neighbors.index[i, k]
                    w = wp.static(value)(wp.length(xi - boundary_x[b]), smoothing_length)
                    boundary_sum += wp.static(density_term)(boundary_params, w, boundary_volume[b])
                    k += 1
            else:
                bquery = wp.hash_grid_query(boundary_neighbors, xi, support_radius)
                b = int(0)
                while wp.hash_grid_query_next(bquery, b):
                    r = wp.length(xi - boundary_x[b])
                    if r < support_radius:
                        boundary_sum += wp.static(density_term)(boundary_params, wp.static(value)(r, smoothing_length),
                                                                boundary_volume[b])
            rho += rest_density * boundary_sum
        particle_density_out[i] = rho

    return compute_density


@functools.cache
def boundary_volume_kernel(smoothing: str):
    """Akinci 2012 boundary volume V_b = 1 / sum_k W_bk over boundary neighbours (report eq. 15) [m^3]."""
    value, _ = SMOOTHING_FUNCTIONS[smoothing]

    @wp.kernel(enable_backward=False, module="unique")
    def compute_boundary_volume(
        # Model:
        smoothing_length: float,
        support_radius: float,
        boundary_grid: wp.uint64,
        boundary_x: wp.array(dtype=wp.vec3),
        # Out:
        boundary_volume_out: wp.array(dtype=float),
    ):
        tid = wp.tid()
        b = wp.hash_grid_point_id(boundary_grid, tid)
        xb = boundary_x[b]
        total = float(0.0)
        query = wp.hash_grid_query(boundary_grid, xb, support_radius)
        k = int(0)
        while wp.hash_grid_query_next(query, k):
            r = wp.length(xb - boundary_x[k])
            if r < support_radius:
                total += wp.static(value)(r, smoothing_length)
        boundary_volume_out[b] = 1.0 / total

    return compute_boundary_volume
