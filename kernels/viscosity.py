"""Viscosity terms shared by the solvers (one source for WCSPH and PBF)."""
import warp as wp


@wp.func
def viscosity_acceleration(viscosity: float, particle_mass: float, rho_i: float, rho_j: float,
                           v_ij: wp.vec3, x_ij: wp.vec3, eps_h2: float, grad: wp.vec3) -> wp.vec3:
    """Explicit viscosity of pair ij [m/s^2] (SPlisHSPlasH 'standard' form, nu in m^2/s):
    10 nu (2 m / (rho_i + rho_j)) (v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij.
    The symmetric density weight makes the pair forces equal and opposite (momentum conserved)."""
    r2 = wp.dot(x_ij, x_ij)
    return (20.0 * viscosity * particle_mass / (rho_i + rho_j)) * wp.dot(v_ij, x_ij) / (r2 + eps_h2) * grad


@wp.func
def boundary_friction_acceleration(nu_b: float, psi: float, v_i: wp.vec3, x_ib: wp.vec3, eps_h2: float,
                                   grad: wp.vec3) -> wp.vec3:
    """Akinci 2012 boundary friction of fluid particle i from boundary particle b [m/s^2]
    (report eq. 22-24): -Psi_b Pi_ib grad W_ib with Pi_ib = -nu_b min(v_ib . x_ib, 0)/(|x_ib|^2 + eps h^2)
    and nu_b = sigma h c_s / (2 rho_i); the wall is at rest (v_b = 0)."""
    vx = wp.dot(v_i, x_ib)
    if vx >= 0.0:
        return wp.vec3(0.0)
    pi_ib = -nu_b * vx / (wp.dot(x_ib, x_ib) + eps_h2)
    return -(psi * pi_ib) * grad
