"""Surface tension and adhesion of Akinci, Akinci & Teschner 2013 ("Versatile Surface Tension and
Adhesion for SPH Fluids", ACM TOG 32(6)), in SPlisHSPlasH's form (notes/forces.md section 2.1).

Two passes over the fluid neighbours (H = support radius, x_ij = x_i - x_j, x^_ij = x_ij / |x_ij|):

1. normals  n_i = H sum_j (m / rho_j) grad_i W_ij                       [-], |n| ~ 0 in the bulk
2. force    a_i = - sum_j K_ij [ gamma m C(r_ij) x^_ij + gamma_k (n_i - n_j) ]
                  - beta rho0 sum_b V_b A(r_ib) x^_ib                    [m/s^2]
   with K_ij = 2 rho0 / (rho_i + rho_j), gamma [m^4/(kg s^2)] (cohesion), gamma_k [m/s^2] (curvature),
   beta [m^4/(kg s^2)] (adhesion to boundary particles b of volume V_b [m^3]).

Cohesion kernel (support H):  C(r) = 32/(pi H^9) (H - r)^3 r^3                 H/2 < r <= H
                              C(r) = 32/(pi H^9) [2 (H - r)^3 r^3 - H^6/64]     0 < r <= H/2
Adhesion kernel:              A(r) = 0.007/H^3.25 (-4 r^2/H + 6 r - 2 H)^(1/4)   H/2 < r <= H, else 0.

Pair terms are antisymmetric in ij, so the fluid's total momentum is conserved; the fluid's
acceleration from the walls, times m, can be added to the boundary force [N].
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import particle_in_cell_order
from .pair_sum import neighbor_sum
from .smoothing import PI, SMOOTHING_FUNCTIONS

#: pairs closer than this fraction of H get no cohesion direction (coincident particles)
MIN_DISTANCE_FRACTION = wp.constant(1.0e-5)


@wp.func
def cohesion_kernel(r: float, support: float) -> float:
    """Akinci 2013 cohesion spline C(r) [1/m^3]: attracts for r > 0.273 H, repels closer, 0 past H."""
    if r > support or r <= 0.0:
        return 0.0
    h3 = support * support * support
    a = 32.0 / (PI * h3 * h3 * h3)
    t = (support - r) * r
    t3 = t * t * t
    if r > 0.5 * support:
        return a * t3
    return a * (2.0 * t3 - h3 * h3 / 64.0)


@wp.func
def adhesion_kernel(r: float, support: float) -> float:
    """Akinci 2013 adhesion spline A(r) [1/m^3]: zero inside H/2, peaks at 3H/4, zero past H."""
    if r > support or r <= 0.5 * support:
        return 0.0
    q = -4.0 * r * r / support + 6.0 * r - 2.0 * support
    return 0.007 / wp.pow(support, 3.25) * wp.pow(wp.max(q, 0.0), 0.25)


@wp.struct
class NormalPairs:
    """What the normal's pair term reads: m [kg], h [m], rho [kg/m^3]."""
    particle_mass: float
    smoothing_length: float
    particle_density: wp.array(dtype=float)


@functools.cache
def normal_pair(smoothing: str):
    """(m / rho_j) grad_i W_ij [1/m] (``NormalPairs``)."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.func(module="unique")
    def pair(d: NormalPairs, i: int, j: int, x_ij: wp.vec3) -> wp.vec3:
        return (d.particle_mass / d.particle_density[j]) * wp.static(gradient)(x_ij, d.smoothing_length)

    return pair


@functools.cache
def normals_kernel(smoothing: str, neighbors: str = "list"):
    """n_i = H sum_j (m / rho_j) grad_i W_ij [-] (Akinci 2013 eq. 9; fluid neighbours only)."""
    Neighbors = NEIGHBOR_TYPES[neighbors]
    normal_sum = neighbor_sum(normal_pair(smoothing), NormalPairs, neighbors)

    @wp.kernel(enable_backward=False, module="unique")
    def compute_normals(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        # State in:
        fluid_neighbors: Neighbors,
        particle_x: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        # Out:
        particle_normal_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        d = NormalPairs()
        d.particle_mass = particle_mass
        d.smoothing_length = smoothing_length
        d.particle_density = particle_density
        n = wp.static(normal_sum)(fluid_neighbors, particle_x, i, particle_x[i], support_radius, d)
        particle_normal_out[i] = support_radius * n

    return compute_normals


@wp.func
def pair_acceleration(cohesion: float, curvature: float, particle_mass: float, rest_density: float,
                      support_radius: float, rho_i: float, rho_j: float, x_ij: wp.vec3, n_i: wp.vec3,
                      n_j: wp.vec3) -> wp.vec3:
    """-K_ij [gamma m C(r) x^_ij + gamma_k (n_i - n_j)] [m/s^2], K_ij = 2 rho0 / (rho_i + rho_j)."""
    r = wp.length(x_ij)
    k_ij = 2.0 * rest_density / (rho_i + rho_j)
    a = -curvature * (n_i - n_j)
    if r > MIN_DISTANCE_FRACTION * support_radius:
        a -= (cohesion * particle_mass * cohesion_kernel(r, support_radius) / r) * x_ij
    return k_ij * a


@wp.struct
class TensionPairs:
    """What the cohesion + curvature pair term reads: gamma [m^4/(kg s^2)], gamma_k [m/s^2], m [kg],
    rho0 [kg/m^3], H [m], rho [kg/m^3], n [-]."""
    cohesion: float
    curvature: float
    particle_mass: float
    rest_density: float
    support_radius: float
    particle_density: wp.array(dtype=float)
    particle_normal: wp.array(dtype=wp.vec3)


@functools.cache
def tension_pair(with_curvature: bool):
    """``pair_acceleration`` of fluid pair ij [m/s^2] (``TensionPairs``); without curvature n = 0 (not read)."""

    @wp.func(module="unique")
    def pair(d: TensionPairs, i: int, j: int, x_ij: wp.vec3) -> wp.vec3:
        n_i = wp.vec3(0.0)
        n_j = wp.vec3(0.0)
        if wp.static(with_curvature):
            n_i = d.particle_normal[i]
            n_j = d.particle_normal[j]
        return pair_acceleration(d.cohesion, d.curvature, d.particle_mass, d.rest_density, d.support_radius,
                                 d.particle_density[i], d.particle_density[j], x_ij, n_i, n_j)

    return pair


@wp.struct
class AdhesionPairs:
    """What the adhesion pair term reads: beta [m^4/(kg s^2)], rho0 [kg/m^3], H [m], V_b [m^3]."""
    adhesion: float
    rest_density: float
    support_radius: float
    boundary_volume: wp.array(dtype=float)


@wp.func
def adhesion_pair(d: AdhesionPairs, i: int, b: int, x_ib: wp.vec3) -> wp.vec3:
    """-beta rho0 V_b A(r_ib) x^_ib [m/s^2] of boundary particle b (``AdhesionPairs``), 0 closer than
    MIN_DISTANCE_FRACTION H."""
    r = wp.length(x_ib)
    a = wp.vec3(0.0)
    if r > MIN_DISTANCE_FRACTION * d.support_radius:
        a = -((d.adhesion * d.rest_density * d.boundary_volume[b] * adhesion_kernel(r, d.support_radius) / r) * x_ib)
    return a


@functools.cache
def force_kernel(with_adhesion: bool, with_reaction: bool, neighbors: str = "list", with_curvature: bool = True):
    """a_i [m/s^2] of cohesion + curvature (+ adhesion to the boundary particles) added to
    ``force_acceleration``; with_reaction: m a_i(walls) [N] is added to the boundary force;
    with_curvature=False: no curvature term (the normals are not read)."""
    Neighbors = NEIGHBOR_TYPES[neighbors]
    tension_sum = neighbor_sum(tension_pair(with_curvature), TensionPairs, neighbors, skip_self=True)
    adhesion_sum = neighbor_sum(adhesion_pair, AdhesionPairs, neighbors)

    @wp.kernel(enable_backward=False, module="unique")
    def compute_surface_tension(
        tid_offset: int,
        # Model:
        particle_mass: float,
        rest_density: float,
        support_radius: float,
        cohesion: float,
        curvature: float,
        adhesion: float,
        boundary_neighbors: Neighbors,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: Neighbors,
        particle_x: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        particle_normal: wp.array(dtype=wp.vec3),
        # Out (updated):
        force_acceleration: wp.array(dtype=wp.vec3),
        boundary_force: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = particle_x[i]
        t = TensionPairs()
        t.cohesion = cohesion
        t.curvature = curvature
        t.particle_mass = particle_mass
        t.rest_density = rest_density
        t.support_radius = support_radius
        t.particle_density = particle_density
        t.particle_normal = particle_normal
        a = wp.static(tension_sum)(fluid_neighbors, particle_x, i, xi, support_radius, t)
        if wp.static(with_adhesion):
            b = AdhesionPairs()
            b.adhesion = adhesion
            b.rest_density = rest_density
            b.support_radius = support_radius
            b.boundary_volume = boundary_volume
            a_b = wp.static(adhesion_sum)(boundary_neighbors, boundary_x, i, xi, support_radius, b)
            a += a_b
            if wp.static(with_reaction):
                boundary_force[i] = boundary_force[i] + particle_mass * a_b
        force_acceleration[i] = force_acceleration[i] + a

    return compute_surface_tension
