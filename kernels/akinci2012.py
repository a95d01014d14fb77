"""Akinci et al. 2012 boundary particles (report eq. 13-16, 22-24): the terms of ``kernels/boundary.py``.

One layer of boundary particles b with volumes V_b = 1 / sum_k W_bk (report eq. 15,
``boundary_volume_kernel`` in ``kernels/density.py``); pseudo-mass Psi_b = rho0 V_b (eq. 14).
"""
import warp as wp

from .boundary import BoundaryTerms


@wp.struct
class AkinciParams:
    """rest_density rho0 [kg/m^3]; friction sigma [-]; smoothing_length h [m]; speed_of_sound c_s [m/s];
    eps_h2 = 0.01 h^2 [m^2] (report eq. 23); particle_friction: sigma per boundary particle [-] (the
    per-particle friction term only; moving bodies with their own ``fluid_friction``)."""

    rest_density: float
    friction: float
    smoothing_length: float
    speed_of_sound: float
    eps_h2: float
    particle_friction: wp.array(dtype=float)


@wp.func
def akinci_density(params: AkinciParams, w_ib: float, volume_b: float) -> float:
    """V_b W_ib: rho_i / rho0 gains sum_b V_b W_ib (report eq. 13)."""
    return volume_b * w_ib


@wp.func
def akinci_gradient(params: AkinciParams, grad_ib: wp.vec3, volume_b: float) -> wp.vec3:
    """V_b grad_i W_ib [1/m]."""
    return volume_b * grad_ib


@wp.func
def akinci_pressure(params: AkinciParams, grad_ib: wp.vec3, volume_b: float, p_rho2: float) -> wp.vec3:
    """-Psi_b (p/rho^2)_b grad_i W_ib [m/s^2] (report eq. 16 with the wall's p/rho^2)."""
    psi = params.rest_density * volume_b
    return -psi * p_rho2 * grad_ib


@wp.func
def friction_acceleration(params: AkinciParams, sigma: float, x_ib: wp.vec3, v_ib: wp.vec3, grad_ib: wp.vec3,
                          volume_b: float, rho_i: float) -> wp.vec3:
    """Boundary friction (report eq. 22-24) [m/s^2]: -Psi_b Pi_ib grad W_ib with
    Pi_ib = -nu_b min(v_ib . x_ib, 0) / (|x_ib|^2 + 0.01 h^2), nu_b = sigma h c_s / (2 rho_i)."""
    vx = wp.dot(v_ib, x_ib)
    if vx >= 0.0:
        return wp.vec3(0.0)
    nu_b = sigma * params.smoothing_length * params.speed_of_sound / (2.0 * rho_i)
    pi_ib = -nu_b * vx / (wp.dot(x_ib, x_ib) + params.eps_h2)
    return -((params.rest_density * volume_b) * pi_ib) * grad_ib


@wp.func
def akinci_friction(params: AkinciParams, b: int, x_ib: wp.vec3, v_ib: wp.vec3, grad_ib: wp.vec3, volume_b: float,
                    rho_i: float) -> wp.vec3:
    """Boundary friction with one sigma = params.friction for every boundary particle [m/s^2]."""
    return friction_acceleration(params, params.friction, x_ib, v_ib, grad_ib, volume_b, rho_i)


@wp.func
def akinci_particle_friction(params: AkinciParams, b: int, x_ib: wp.vec3, v_ib: wp.vec3, grad_ib: wp.vec3,
                             volume_b: float, rho_i: float) -> wp.vec3:
    """Boundary friction with sigma = params.particle_friction[b] (a body's own fluid friction) [m/s^2]."""
    return friction_acceleration(params, params.particle_friction[b], x_ib, v_ib, grad_ib, volume_b, rho_i)


#: Akinci walls without friction, and with it (a separate specialisation: no friction loop when sigma = 0)
AKINCI2012 = BoundaryTerms("akinci2012", AkinciParams, density=akinci_density, gradient=akinci_gradient,
                           pressure=akinci_pressure)
AKINCI2012_FRICTION = BoundaryTerms("akinci2012+friction", AkinciParams, density=akinci_density,
                                    gradient=akinci_gradient, pressure=akinci_pressure, force=akinci_friction)
#: friction with a sigma per boundary particle (moving bodies with their own fluid_friction)
AKINCI2012_PARTICLE_FRICTION = BoundaryTerms("akinci2012+friction", AkinciParams, density=akinci_density,
                                             gradient=akinci_gradient, pressure=akinci_pressure,
                                             force=akinci_particle_friction)
