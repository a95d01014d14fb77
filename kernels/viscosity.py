"""Explicit viscosity (shared by the solvers) and the non-pressure forces stage of the implicit solvers.

``viscosity_acceleration`` is the pair term WCSPH inlines in its force kernel; ``viscous_kernel``
turns explicit viscosity and the boundary method's non-pressure force (Akinci friction, a penalty
force: ``BoundaryTerms.force``) into a velocity change dt a, for solvers that correct positions or
velocities implicitly (PBF after its position update).
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import NoBoundaryParams, neighbor_count, particle_in_cell_order
from .smoothing import SMOOTHING_FUNCTIONS


@wp.func
def viscosity_acceleration(viscosity: float, particle_mass: float, rho_i: float, rho_j: float,
                           v_ij: wp.vec3, x_ij: wp.vec3, eps_h2: float, grad: wp.vec3) -> wp.vec3:
    """Explicit viscosity of pair ij [m/s^2] (SPlisHSPlasH 'standard' form, nu in m^2/s):
    10 nu (2 m / (rho_i + rho_j)) (v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij.
    The symmetric density weight makes the pair forces equal and opposite (momentum conserved)."""
    r2 = wp.dot(x_ij, x_ij)
    return (20.0 * viscosity * particle_mass / (rho_i + rho_j)) * wp.dot(v_ij, x_ij) / (r2 + eps_h2) * grad


@wp.func
def artificial_viscosity_acceleration(alpha_h_c: float, particle_mass: float, rho_i: float, rho_j: float,
                                      v_ij: wp.vec3, x_ij: wp.vec3, eps_h2: float, grad: wp.vec3) -> wp.vec3:
    """Artificial viscosity of pair ij [m/s^2] (Monaghan 1992; Becker & Teschner 2007): -m Pi_ij grad W_ij
    with Pi_ij = -nu min(v_ij . x_ij, 0) / (|x_ij|^2 + 0.01 h^2), nu = 2 alpha h c_s / (rho_i + rho_j);
    alpha_h_c = alpha h c_s [m^2/s]. Only approaching pairs: it dissipates compression (impacts), not shear."""
    vx = wp.dot(v_ij, x_ij)
    if vx >= 0.0:
        return wp.vec3(0.0)
    nu = 2.0 * alpha_h_c / (rho_i + rho_j)
    return (particle_mass * nu * vx / (wp.dot(x_ij, x_ij) + eps_h2)) * grad


@functools.cache
def viscous_kernel(smoothing: str, boundary_terms, with_viscosity: bool, neighbors: str = "grid"):
    """Velocity change dt a [m/s] of explicit viscosity (``viscosity_acceleration`` over fluid pairs)
    and of the boundary method's non-pressure force (``boundary_terms.force``; None: none). A
    dissipative boundary force (friction) is clamped so it never reverses the particle's velocity;
    m a_boundary is added to the boundary force [N]."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]
    lists = neighbors == "list"
    Neighbors = NEIGHBOR_TYPES[neighbors]
    with_force = boundary_terms is not None and boundary_terms.force is not None
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    force_term = boundary_terms.force if with_force else None
    dissipative = with_force and boundary_terms.dissipative

    @wp.kernel(enable_backward=False, module="unique")
    def compute_viscous(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        viscosity: float,
        dt: float,
        boundary_params: BoundaryParams,
        boundary_neighbors: Neighbors,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_v: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: Neighbors,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        # Out:
        viscous_dv_out: wp.array(dtype=wp.vec3),
        boundary_force_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = particle_x[i]
        vi = particle_v[i]
        h = smoothing_length
        eps_h2 = 0.01 * h * h
        a = wp.vec3(0.0)
        if wp.static(with_viscosity):
            if wp.static(lists):
                k = int(0)
                k_end = int(neighbor_count(fluid_neighbors, i))
                while k < k_end:
                    j = fluid_neighbors.index[i, k]
                    if j != i:
                        x_ij = xi - particle_x[j]
                        if wp.length(x_ij) < support_radius:
                            a += viscosity_acceleration(viscosity, particle_mass, particle_density[i],
                                                        particle_density[j], vi - particle_v[j], x_ij, eps_h2,
                                                        wp.static(gradient)(x_ij, h))
                    k += 1
            else:
                query = wp.hash_grid_query(fluid_neighbors, xi, support_radius)
                j = int(0)
                while wp.hash_grid_query_next(query, j):
                    if j != i:
                        x_ij = xi - particle_x[j]
                        if wp.length(x_ij) < support_radius:
                            a += viscosity_acceleration(viscosity, particle_mass, particle_density[i],
                                                        particle_density[j], vi - particle_v[j], x_ij, eps_h2,
                                                        wp.static(gradient)(x_ij, h))
        dv = dt * a
        if wp.static(with_force):
            rho_i = particle_density[i]
            a_b = wp.vec3(0.0)
            if wp.static(lists):
                k = int(0)
                k_end = int(neighbor_count(boundary_neighbors, i))
                while k < k_end:
                    b = boundary_neighbors.index[i, k]
                    x_ib = xi - boundary_x[b]
                    if wp.length(x_ib) < support_radius:
                        a_b += wp.static(force_term)(boundary_params, b, x_ib, vi - boundary_v[b],
                                                     wp.static(gradient)(x_ib, h), boundary_volume[b], rho_i)
                    k += 1
            else:
                bquery = wp.hash_grid_query(boundary_neighbors, xi, support_radius)
                b = int(0)
                while wp.hash_grid_query_next(bquery, b):
                    x_ib = xi - boundary_x[b]
                    if wp.length(x_ib) < support_radius:
                        a_b += wp.static(force_term)(boundary_params, b, x_ib, vi - boundary_v[b],
                                                     wp.static(gradient)(x_ib, h), boundary_volume[b], rho_i)
            dv_b = dt * a_b
            if wp.static(dissipative):
                speed = wp.length(vi)
                size = wp.length(dv_b)
                if size > speed:
                    dv_b = dv_b * (speed / size)
            dv += dv_b
            boundary_force_out[i] = boundary_force_out[i] + (particle_mass / dt) * dv_b
        viscous_dv_out[i] = dv

    return compute_viscous
