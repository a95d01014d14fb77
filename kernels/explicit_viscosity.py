"""Explicit viscosity (SPlisHSPlasH's 'standard' Laplacian form, Morris et al. 1997 / Monaghan 2005):

    a_i = 10 nu sum_j (2 m / (rho_i + rho_j)) (v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij   [m/s^2]

over fluid neighbours j != i (nu kinematic [m^2/s]); the symmetric density weight makes the pair forces
equal and opposite (linear and angular momentum conserved; a rigid rotation gives exactly 0).
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import neighbor_count, particle_in_cell_order
from .smoothing import SMOOTHING_FUNCTIONS


@wp.func
def viscosity_acceleration(viscosity: float, particle_mass: float, rho_i: float, rho_j: float,
                           v_ij: wp.vec3, x_ij: wp.vec3, eps_h2: float, grad: wp.vec3) -> wp.vec3:
    """Explicit viscosity of pair ij [m/s^2] (module docstring), nu in m^2/s."""
    r2 = wp.dot(x_ij, x_ij)
    return (20.0 * viscosity * particle_mass / (rho_i + rho_j)) * wp.dot(v_ij, x_ij) / (r2 + eps_h2) * grad


@functools.cache
def viscosity_kernel(smoothing: str, neighbors: str = "grid"):
    """Adds the explicit viscosity acceleration a_i [m/s^2] (module docstring) to ``acceleration``."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]
    lists = neighbors == "list"
    Neighbors = NEIGHBOR_TYPES[neighbors]

    @wp.kernel(enable_backward=False, module="unique")
    def explicit_viscosity(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        viscosity: float,
        # State in:
        fluid_neighbors: Neighbors,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        # In/out:
        acceleration: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = particle_x[i]
        vi = particle_v[i]
        h = smoothing_length
        eps_h2 = 0.01 * h * h
        a = wp.vec3(0.0)
        if wp.static(lists):
            k = int(0)
            k_end = int(neighbor_count(fluid_neighbors, i))
            while k < k_end:
                j = fluid_neighbors.index[i, k]
                if j != i:
                    x_ij = xi - particle_x[j]
                    if wp.length(x_ij) < support_radius:
                        a += viscosity_acceleration(viscosity, particle_mass, particle_density[i], particle_density[j],
                                                    vi - particle_v[j], x_ij, eps_h2, wp.static(gradient)(x_ij, h))
                k += 1
        else:
            query = wp.hash_grid_query(fluid_neighbors, xi, support_radius)
            j = int(0)
            while wp.hash_grid_query_next(query, j):
                if j != i:
                    x_ij = xi - particle_x[j]
                    if wp.length(x_ij) < support_radius:
                        a += viscosity_acceleration(viscosity, particle_mass, particle_density[i], particle_density[j],
                                                    vi - particle_v[j], x_ij, eps_h2, wp.static(gradient)(x_ij, h))
        acceleration[i] = acceleration[i] + a

    return explicit_viscosity
