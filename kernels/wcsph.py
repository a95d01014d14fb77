"""Weakly compressible SPH (Becker & Teschner 2007): equation of state and accelerations.

Pressure acceleration (report eq. 10), Akinci 2012 boundary pressure (eq. 16) or the penalty
boundary force (eq. 12, Becker & Teschner), explicit viscosity and Akinci boundary friction
(eq. 22-24), gravity.
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import neighbor_count, particle_in_cell_order
from .smoothing import SMOOTHING_FUNCTIONS
from .viscosity import boundary_friction_acceleration, viscosity_acceleration

EOS_LINEAR = 0
EOS_TAIT = 1


@functools.cache
def pressure_kernel(equation_of_state: str):
    """Linear p = max(K (rho/rho0 - 1), 0) (report eq. 9, K = B rho0) or Tait
    p = max(K ((rho/rho0)^7 - 1), 0); K = stiffness [Pa]."""
    tait = equation_of_state == "tait"

    @wp.kernel(enable_backward=False, module="unique")
    def compute_pressure(
        tid_offset: int,
        # Model:
        rest_density: float,
        stiffness: float,
        # State in:
        particle_density: wp.array(dtype=float),
        # Out:
        particle_pressure_out: wp.array(dtype=float),
    ):
        i = wp.tid() + tid_offset
        ratio = particle_density[i] / rest_density
        p = float(0.0)
        if wp.static(tait):
            r2 = ratio * ratio
            p = stiffness * (r2 * r2 * r2 * ratio - 1.0)
        else:
            p = stiffness * (ratio - 1.0)
        particle_pressure_out[i] = wp.max(p, 0.0)

    return compute_pressure


@wp.func
def penalty_weight(q: float) -> float:
    """Shape of the Becker & Teschner 2007 boundary force (report eq. 12, q = r/h_b in [0, 2])."""
    if q < 2.0 / 3.0:
        return 2.0 / 3.0
    if q < 1.0:
        return 2.0 * q - 1.5 * q * q
    if q < 2.0:
        t = 2.0 - q
        return 0.5 * t * t
    return 0.0


@functools.cache
def acceleration_kernel(smoothing: str, boundary: str, with_viscosity: bool, with_friction: bool,
                        mirrored_pressure: bool, neighbors: str = "grid"):
    """a_i = -sum_j m (p_i/rho_i^2 + p_j/rho_j^2) grad W_ij (eq. 10)
             + 10 nu sum_j (2m/(rho_i+rho_j)) (v_ij . x_ij)/(|x_ij|^2 + 0.01 h^2) grad W_ij  (viscosity)
             + boundary terms + g                                                    [m/s^2]

    boundary: "none", "akinci2012" (a_i -= sum_b Psi_b p_i/rho_i^2 grad W_ib, eq. 16, plus friction
    eq. 22-24 with nu_b = sigma h c_s / (2 rho_i)) or "penalty" (eq. 12 with B_R = 0.02 c_s^2).
    Also writes the force of the boundary on each particle [N] (its negative sums to the wall load).
    neighbors: "grid" or "list" (see ``density.NEIGHBOR_TYPES``).
    """
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]
    lists = neighbors == "list"
    Neighbors = NEIGHBOR_TYPES[neighbors]

    @wp.func(module="unique")
    def fluid_pair(x_ij: wp.vec3, v_ij: wp.vec3, p_rho2_i: float, p_rho2_j: float, rho_i: float, rho_j: float,
                   particle_mass: float, h: float, eps_h2: float, viscosity: float) -> wp.vec3:
        """Pressure (eq. 10) and viscosity acceleration of i due to fluid neighbour j != i."""
        grad = wp.static(gradient)(x_ij, h)
        a = -particle_mass * (p_rho2_i + p_rho2_j) * grad
        if wp.static(with_viscosity):
            a += viscosity_acceleration(viscosity, particle_mass, rho_i, rho_j, v_ij, x_ij, eps_h2, grad)
        return a

    @wp.func(module="unique")
    def akinci_pair(x_ib: wp.vec3, vi: wp.vec3, psi: float, p_rho2_b: float, nu_b: float, h: float,
                    eps_h2: float) -> wp.vec3:
        """Akinci boundary pressure (eq. 16) and friction (eq. 22-24) of boundary particle b on i."""
        grad = wp.static(gradient)(x_ib, h)
        a = -psi * p_rho2_b * grad
        if wp.static(with_friction):
            a += boundary_friction_acceleration(nu_b, psi, vi, x_ib, eps_h2, grad)
        return a

    @wp.func(module="unique")
    def penalty_pair(x_ib: wp.vec3, h_b: float, strength: float) -> wp.vec3:
        """Becker & Teschner boundary force (eq. 12), equal masses: m_b / (m_i + m_b) = 1/2."""
        r = wp.length(x_ib)
        if r > 1.0e-6 * h_b:
            return (0.5 * strength / r * penalty_weight(r / h_b) / r) * x_ib
        return wp.vec3(0.0)
    akinci = boundary == "akinci2012"
    penalty = boundary == "penalty"

    @wp.kernel(enable_backward=False, module="unique")
    def compute_acceleration(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        gravity: wp.vec3,
        viscosity: float,
        boundary_friction: float,
        speed_of_sound: float,
        boundary_neighbors: Neighbors,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: Neighbors,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        particle_pressure: wp.array(dtype=float),
        # Out:
        particle_acceleration_out: wp.array(dtype=wp.vec3),
        boundary_force_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = particle_x[i]
        vi = particle_v[i]
        rho_i = particle_density[i]
        p_rho2_i = particle_pressure[i] / (rho_i * rho_i)
        # boundary pressure term: eq. 16 uses p_i/rho_i^2; mirrored (SPlisHSPlasH) gives the wall
        # particle the fluid particle's pressure at rest density: p_i/rho_i^2 + p_i/rho0^2
        p_rho2_b = p_rho2_i
        if wp.static(mirrored_pressure):
            p_rho2_b = p_rho2_i + particle_pressure[i] / (rest_density * rest_density)
        h = smoothing_length
        eps_h2 = 0.01 * h * h
        a = wp.vec3(0.0)
        if wp.static(lists):
            k = int(0)
            k_end = int(neighbor_count(fluid_neighbors, i))
            while k < k_end:
                j = fluid_neighbors.index[i, k]
                if j != i:
                    rho_j = particle_density[j]
                    a += fluid_pair(xi - particle_x[j], vi - particle_v[j], p_rho2_i,
                                    particle_pressure[j] / (rho_j * rho_j), rho_i, rho_j, particle_mass, h, eps_h2, viscosity)
                k += 1
        else:
            query = wp.hash_grid_query(fluid_neighbors, xi, support_radius)
            j = int(0)
            while wp.hash_grid_query_next(query, j):
                if j != i:
                    x_ij = xi - particle_x[j]
                    if wp.length(x_ij) < support_radius:
                        rho_j = particle_density[j]
                        a += fluid_pair(x_ij, vi - particle_v[j], p_rho2_i, particle_pressure[j] / (rho_j * rho_j),
                                        rho_i, rho_j, particle_mass, h, eps_h2, viscosity)
        a_boundary = wp.vec3(0.0)
        if wp.static(akinci):
            nu_b = boundary_friction * h * speed_of_sound / (2.0 * rho_i)
            if wp.static(lists):
                k = int(0)
                k_end = int(neighbor_count(boundary_neighbors, i))
                while k < k_end:
                    b = boundary_neighbors.index[i, k]
                    a_boundary += akinci_pair(xi - boundary_x[b], vi, rest_density * boundary_volume[b], p_rho2_b, nu_b,
                                              h, eps_h2)
                    k += 1
            else:
                bquery = wp.hash_grid_query(boundary_neighbors, xi, support_radius)
                b = int(0)
                while wp.hash_grid_query_next(bquery, b):
                    x_ib = xi - boundary_x[b]
                    if wp.length(x_ib) < support_radius:
                        a_boundary += akinci_pair(x_ib, vi, rest_density * boundary_volume[b], p_rho2_b, nu_b, h, eps_h2)
        if wp.static(penalty):
            # q relative to half the support, so the force acts over the kernel's support radius
            h_b = 0.5 * support_radius
            strength = 0.02 * speed_of_sound * speed_of_sound
            if wp.static(lists):
                k = int(0)
                k_end = int(neighbor_count(boundary_neighbors, i))
                while k < k_end:
                    a_boundary += penalty_pair(xi - boundary_x[boundary_neighbors.index[i, k]], h_b, strength)
                    k += 1
            else:
                bquery = wp.hash_grid_query(boundary_neighbors, xi, support_radius)
                b = int(0)
                while wp.hash_grid_query_next(bquery, b):
                    x_ib = xi - boundary_x[b]
                    if wp.length(x_ib) < support_radius:
                        a_boundary += penalty_pair(x_ib, h_b, strength)
        boundary_force_out[i] = particle_mass * a_boundary
        particle_acceleration_out[i] = a + a_boundary + gravity

    return compute_acceleration
