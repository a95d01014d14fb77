"""Explicit viscosity (SPlisHSPlasH's 'standard' Laplacian form, Morris et al. 1997 / Monaghan 2005):

    a_i = 10 nu sum_j (2 m / (rho_i + rho_j)) (v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij   [m/s^2]

over fluid neighbours j != i (nu kinematic [m^2/s]); the symmetric density weight makes the pair forces
equal and opposite (linear and angular momentum conserved; a rigid rotation gives exactly 0).
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import particle_in_cell_order
from .pair_sum import neighbor_sum
from .smoothing import SMOOTHING_FUNCTIONS


@wp.func
def viscosity_acceleration(viscosity: float, particle_mass: float, rho_i: float, rho_j: float,
                           v_ij: wp.vec3, x_ij: wp.vec3, eps_h2: float, grad: wp.vec3) -> wp.vec3:
    """Explicit viscosity of pair ij [m/s^2] (module docstring), nu in m^2/s."""
    r2 = wp.dot(x_ij, x_ij)
    return (20.0 * viscosity * particle_mass / (rho_i + rho_j)) * wp.dot(v_ij, x_ij) / (r2 + eps_h2) * grad


@wp.struct
class ViscosityPairs:
    """What the viscosity pair term reads: nu [m^2/s], m [kg], h [m], 0.01 h^2 [m^2], v [m/s], rho [kg/m^3]."""
    viscosity: float
    particle_mass: float
    smoothing_length: float
    eps_h2: float
    particle_v: wp.array(dtype=wp.vec3)
    particle_density: wp.array(dtype=float)


@functools.cache
def viscosity_pair(smoothing: str):
    """``viscosity_acceleration`` of fluid pair ij [m/s^2] (``ViscosityPairs``)."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.func(module="unique")
    def pair(d: ViscosityPairs, i: int, j: int, x_ij: wp.vec3) -> wp.vec3:
        return viscosity_acceleration(d.viscosity, d.particle_mass, d.particle_density[i], d.particle_density[j],
                                      d.particle_v[i] - d.particle_v[j], x_ij, d.eps_h2,
                                      wp.static(gradient)(x_ij, d.smoothing_length))

    return pair


@functools.cache
def viscosity_kernel(smoothing: str, neighbors: str = "grid"):
    """Adds the explicit viscosity acceleration a_i [m/s^2] (module docstring) to ``acceleration``."""
    Neighbors = NEIGHBOR_TYPES[neighbors]
    viscosity_sum = neighbor_sum(viscosity_pair(smoothing), ViscosityPairs, neighbors, skip_self=True)

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
        h = smoothing_length
        d = ViscosityPairs()
        d.viscosity = viscosity
        d.particle_mass = particle_mass
        d.smoothing_length = h
        d.eps_h2 = 0.01 * h * h
        d.particle_v = particle_v
        d.particle_density = particle_density
        a = wp.static(viscosity_sum)(fluid_neighbors, particle_x, i, particle_x[i], support_radius, d)
        acceleration[i] = acceleration[i] + a

    return explicit_viscosity
