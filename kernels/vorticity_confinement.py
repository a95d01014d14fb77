"""Vorticity confinement (Fedkiw et al. 2001; Macklin & Mueller 2013 eq. 15-16): the vorticity and the
confinement acceleration a_i = eps v_ref (N x omega_i) [m/s^2], N = grad|omega| / |grad|omega||."""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import neighbor_count, particle_in_cell_order
from .smoothing import SMOOTHING_FUNCTIONS


@functools.cache
def vorticity_kernel(smoothing: str, neighbors: str = "grid"):
    """Vorticity omega_i = sum_j (m/rho_j) grad_i W_ij x (v_j - v_i) [1/s] (Macklin & Mueller 2013 eq. 15)."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]
    lists = neighbors == "list"
    Neighbors = NEIGHBOR_TYPES[neighbors]

    @wp.kernel(enable_backward=False, module="unique")
    def compute_vorticity(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        # State in:
        fluid_neighbors: Neighbors,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        # Out:
        particle_vorticity_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = particle_x[i]
        vi = particle_v[i]
        w = wp.vec3(0.0)
        if wp.static(lists):
            k = int(0)
            k_end = int(neighbor_count(fluid_neighbors, i))
            while k < k_end:
                j = fluid_neighbors.index[i, k]
                x_ij = xi - particle_x[j]
                if wp.length(x_ij) < support_radius:
                    w += (particle_mass / particle_density[j]) * wp.cross(
                        wp.static(gradient)(x_ij, smoothing_length), particle_v[j] - vi)
                k += 1
        else:
            query = wp.hash_grid_query(fluid_neighbors, xi, support_radius)
            j = int(0)
            while wp.hash_grid_query_next(query, j):
                x_ij = xi - particle_x[j]
                if wp.length(x_ij) < support_radius:
                    w += (particle_mass / particle_density[j]) * wp.cross(
                        wp.static(gradient)(x_ij, smoothing_length), particle_v[j] - vi)
        particle_vorticity_out[i] = w

    return compute_vorticity


@functools.cache
def confinement_kernel(smoothing: str, neighbors: str = "grid"):
    """Vorticity confinement (Macklin & Mueller 2013 eq. 16): eta = grad |omega| (SPH difference
    gradient), N = eta / |eta|; adds a_i = vorticity v_ref (N x omega_i) [m/s^2] to ``acceleration``;
    v_ref [m/s] makes the strength dimensionless."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]
    lists = neighbors == "list"
    Neighbors = NEIGHBOR_TYPES[neighbors]

    @wp.kernel(enable_backward=False, module="unique")
    def compute_confinement(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        vorticity: float,
        reference_speed: float,
        # State in:
        fluid_neighbors: Neighbors,
        particle_x: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        particle_vorticity: wp.array(dtype=wp.vec3),
        # In/out:
        acceleration: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = particle_x[i]
        wi = particle_vorticity[i]
        mag_i = wp.length(wi)
        eta = wp.vec3(0.0)
        if wp.static(lists):
            k = int(0)
            k_end = int(neighbor_count(fluid_neighbors, i))
            while k < k_end:
                j = fluid_neighbors.index[i, k]
                x_ij = xi - particle_x[j]
                if wp.length(x_ij) < support_radius:
                    eta += (particle_mass / particle_density[j] * (wp.length(particle_vorticity[j]) - mag_i)) * wp.static(
                        gradient)(x_ij, smoothing_length)
                k += 1
        else:
            query = wp.hash_grid_query(fluid_neighbors, xi, support_radius)
            j = int(0)
            while wp.hash_grid_query_next(query, j):
                x_ij = xi - particle_x[j]
                if wp.length(x_ij) < support_radius:
                    eta += (particle_mass / particle_density[j] * (wp.length(particle_vorticity[j]) - mag_i)) * wp.static(
                        gradient)(x_ij, smoothing_length)
        n = wp.length(eta)
        if n > 1.0e-12:
            acceleration[i] = acceleration[i] + (vorticity * reference_speed / n) * wp.cross(eta, wi)

    return compute_confinement
