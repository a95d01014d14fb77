"""Weakly compressible SPH (Becker & Teschner 2007): equation of state and accelerations.

Pressure acceleration (report eq. 10), Akinci 2012 boundary pressure (eq. 16) or the penalty
boundary force (eq. 12, Becker & Teschner), explicit viscosity and Akinci boundary friction
(eq. 22-24), gravity.
"""
import functools

import warp as wp

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
        # Model:
        rest_density: float,
        stiffness: float,
        # State in:
        particle_density: wp.array(dtype=float),
        # Out:
        particle_pressure_out: wp.array(dtype=float),
    ):
        i = wp.tid()
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
                        mirrored_pressure: bool):
    """a_i = -sum_j m (p_i/rho_i^2 + p_j/rho_j^2) grad W_ij (eq. 10)
             + 10 nu sum_j (2m/(rho_i+rho_j)) (v_ij . x_ij)/(|x_ij|^2 + 0.01 h^2) grad W_ij  (viscosity)
             + boundary terms + g                                                    [m/s^2]

    boundary: "none", "akinci2012" (a_i -= sum_b Psi_b p_i/rho_i^2 grad W_ib, eq. 16, plus friction
    eq. 22-24 with nu_b = sigma h c_s / (2 rho_i)) or "penalty" (eq. 12 with B_R = 0.02 c_s^2).
    Also writes the force of the boundary on each particle [N] (its negative sums to the wall load).
    """
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]
    akinci = boundary == "akinci2012"
    penalty = boundary == "penalty"

    @wp.kernel(enable_backward=False, module="unique")
    def compute_acceleration(
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        gravity: wp.vec3,
        viscosity: float,
        boundary_friction: float,
        speed_of_sound: float,
        boundary_grid: wp.uint64,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_grid: wp.uint64,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        particle_pressure: wp.array(dtype=float),
        # Out:
        particle_acceleration_out: wp.array(dtype=wp.vec3),
        boundary_force_out: wp.array(dtype=wp.vec3),
    ):
        tid = wp.tid()
        i = wp.hash_grid_point_id(fluid_grid, tid)
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
        query = wp.hash_grid_query(fluid_grid, xi, support_radius)
        j = int(0)
        while wp.hash_grid_query_next(query, j):
            if j != i:
                x_ij = xi - particle_x[j]
                r = wp.length(x_ij)
                if r < support_radius:
                    grad = wp.static(gradient)(x_ij, h)
                    rho_j = particle_density[j]
                    a -= particle_mass * (p_rho2_i + particle_pressure[j] / (rho_j * rho_j)) * grad
                    if wp.static(with_viscosity):
                        v_ij = vi - particle_v[j]
                        a += viscosity_acceleration(viscosity, particle_mass, rho_i, rho_j, v_ij, x_ij, eps_h2, grad)
        a_boundary = wp.vec3(0.0)
        if wp.static(akinci):
            nu_b = boundary_friction * h * speed_of_sound / (2.0 * rho_i)
            bquery = wp.hash_grid_query(boundary_grid, xi, support_radius)
            b = int(0)
            while wp.hash_grid_query_next(bquery, b):
                x_ib = xi - boundary_x[b]
                r = wp.length(x_ib)
                if r < support_radius:
                    grad = wp.static(gradient)(x_ib, h)
                    psi = rest_density * boundary_volume[b]
                    a_boundary -= psi * p_rho2_b * grad
                    if wp.static(with_friction):
                        a_boundary += boundary_friction_acceleration(nu_b, psi, vi, x_ib, eps_h2, grad)
        if wp.static(penalty):
            # q relative to half the support, so the force acts over the kernel's support radius
            h_b = 0.5 * support_radius
            strength = 0.02 * speed_of_sound * speed_of_sound
            bquery = wp.hash_grid_query(boundary_grid, xi, support_radius)
            b = int(0)
            while wp.hash_grid_query_next(bquery, b):
                x_ib = xi - boundary_x[b]
                r = wp.length(x_ib)
                if r < support_radius and r > 1.0e-6 * h_b:
                    # equal masses: m_b / (m_i + m_b) = 1/2
                    a_boundary += (0.5 * strength / r * penalty_weight(r / h_b) / r) * x_ib
        boundary_force_out[i] = particle_mass * a_boundary
        particle_acceleration_out[i] = a + a_boundary + gravity

    return compute_acceleration
