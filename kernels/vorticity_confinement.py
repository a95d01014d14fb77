"""Vorticity confinement (Fedkiw et al. 2001; Macklin & Mueller 2013 eq. 15-16): the vorticity and the
confinement acceleration a_i = eps v_ref (N x omega_i) [m/s^2], N = grad|omega| / |grad|omega||."""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import particle_in_cell_order
from .pair_sum import neighbor_sum
from .smoothing import SMOOTHING_FUNCTIONS


@wp.struct
class VorticityPairs:
    """What the vorticity's pair term reads: m [kg], h [m], v [m/s], rho [kg/m^3]."""
    particle_mass: float
    smoothing_length: float
    particle_v: wp.array(dtype=wp.vec3)
    particle_density: wp.array(dtype=float)


@wp.struct
class ConfinementPairs:
    """What the confinement's pair term reads: m [kg], h [m], rho [kg/m^3], omega [1/s], |omega_i| [1/s]."""
    particle_mass: float
    smoothing_length: float
    particle_density: wp.array(dtype=float)
    particle_vorticity: wp.array(dtype=wp.vec3)
    vorticity_magnitude_i: float


@functools.cache
def vorticity_pair(smoothing: str):
    """(m/rho_j) grad_i W_ij x (v_j - v_i) [1/s] (``VorticityPairs``)."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.func(module="unique")
    def pair(d: VorticityPairs, i: int, j: int, x_ij: wp.vec3) -> wp.vec3:
        return (d.particle_mass / d.particle_density[j]) * wp.cross(
            wp.static(gradient)(x_ij, d.smoothing_length), d.particle_v[j] - d.particle_v[i])

    return pair


@functools.cache
def confinement_pair(smoothing: str):
    """(m/rho_j) (|omega_j| - |omega_i|) grad_i W_ij [1/(m s)] (``ConfinementPairs``)."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.func(module="unique")
    def pair(d: ConfinementPairs, i: int, j: int, x_ij: wp.vec3) -> wp.vec3:
        return (d.particle_mass / d.particle_density[j] * (wp.length(d.particle_vorticity[j]) - d.vorticity_magnitude_i)
                ) * wp.static(gradient)(x_ij, d.smoothing_length)

    return pair


@functools.cache
def vorticity_kernel(smoothing: str, neighbors: str = "grid"):
    """Vorticity omega_i = sum_j (m/rho_j) grad_i W_ij x (v_j - v_i) [1/s] (Macklin & Mueller 2013 eq. 15)."""
    Neighbors = NEIGHBOR_TYPES[neighbors]
    vorticity_sum = neighbor_sum(vorticity_pair(smoothing), VorticityPairs, neighbors)

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
        d = VorticityPairs()
        d.particle_mass = particle_mass
        d.smoothing_length = smoothing_length
        d.particle_v = particle_v
        d.particle_density = particle_density
        particle_vorticity_out[i] = wp.static(vorticity_sum)(fluid_neighbors, particle_x, i, particle_x[i],
                                                              support_radius, d)

    return compute_vorticity


@functools.cache
def confinement_kernel(smoothing: str, neighbors: str = "grid"):
    """Vorticity confinement (Macklin & Mueller 2013 eq. 16): eta = grad |omega| (SPH difference
    gradient), N = eta / |eta|; adds a_i = vorticity v_ref (N x omega_i) [m/s^2] to ``acceleration``;
    v_ref [m/s] makes the strength dimensionless."""
    Neighbors = NEIGHBOR_TYPES[neighbors]
    confinement_sum = neighbor_sum(confinement_pair(smoothing), ConfinementPairs, neighbors)

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
        wi = particle_vorticity[i]
        d = ConfinementPairs()
        d.particle_mass = particle_mass
        d.smoothing_length = smoothing_length
        d.particle_density = particle_density
        d.particle_vorticity = particle_vorticity
        d.vorticity_magnitude_i = wp.length(wi)
        eta = wp.static(confinement_sum)(fluid_neighbors, particle_x, i, particle_x[i], support_radius, d)
        n = wp.length(eta)
        if n > 1.0e-12:
            acceleration[i] = acceleration[i] + (vorticity * reference_speed / n) * wp.cross(eta, wi)

    return compute_confinement
