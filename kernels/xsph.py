"""XSPH velocity filter (report eq. 21)."""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import neighbor_count, particle_in_cell_order
from .smoothing import SMOOTHING_FUNCTIONS


@functools.cache
def xsph_kernel(smoothing: str, neighbors: str = "grid"):
    """XSPH (report eq. 21): dv_i = eps sum_j (m/rho_j) (v_j - v_i) W_ij [m/s].
    neighbors: "grid" or "list" (see ``density.NEIGHBOR_TYPES``)."""
    value, _ = SMOOTHING_FUNCTIONS[smoothing]
    lists = neighbors == "list"
    Neighbors = NEIGHBOR_TYPES[neighbors]

    @wp.kernel(enable_backward=False, module="unique")
    def compute_xsph(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        xsph: float,
        # State in:
        fluid_neighbors: Neighbors,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        # Out:
        velocity_correction_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = particle_x[i]
        vi = particle_v[i]
        dv = wp.vec3(0.0)
        if wp.static(lists):
            k = int(0)
            k_end = int(neighbor_count(fluid_neighbors, i))
            while k < k_end:
                j = fluid_neighbors.index[i, k]
                r = wp.length(xi - particle_x[j])
                dv += (particle_mass / particle_density[j] * wp.static(value)(r, smoothing_length)) * (particle_v[j] - vi)
                k += 1
        else:
            query = wp.hash_grid_query(fluid_neighbors, xi, support_radius)
            j = int(0)
            while wp.hash_grid_query_next(query, j):
                r = wp.length(xi - particle_x[j])
                if r < support_radius:
                    dv += (particle_mass / particle_density[j] * wp.static(value)(r, smoothing_length)) * (particle_v[j] - vi)
        velocity_correction_out[i] = xsph * dv

    return compute_xsph
