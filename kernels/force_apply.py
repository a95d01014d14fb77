"""The velocity kick of the non-pressure forces: v += dt a_forces + the boundary method's force term.

``apply_kernel`` reads the accelerations the explicit forces summed (``force_acceleration`` [m/s^2])
and evaluates the boundary method's non-pressure term (Akinci friction, a penalty force:
``BoundaryTerms.force``) at the same velocity, then updates v in place (each thread reads only its
own particle's velocity). Specialised at compile time: without forces it reads no acceleration,
without a boundary force term it visits no boundary particle.
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import NoBoundaryParams, neighbor_count, particle_in_cell_order
from .smoothing import SMOOTHING_FUNCTIONS


@functools.cache
def apply_kernel(smoothing: str, boundary_terms, with_forces: bool, neighbors: str = "grid"):
    """dv = dt a_forces + dt a_boundary; v += dv [m/s]. A dissipative boundary term (friction) is clamped so
    that it never reverses the particle's velocity; m a_boundary [N] is added to the boundary force."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]
    lists = neighbors == "list"
    Neighbors = NEIGHBOR_TYPES[neighbors]
    with_force = boundary_terms is not None and boundary_terms.force is not None
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    force_term = boundary_terms.force if with_force else None
    dissipative = with_force and boundary_terms.dissipative

    @wp.kernel(enable_backward=False, module="unique")
    def apply_forces(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        dt: float,
        boundary_params: BoundaryParams,
        boundary_neighbors: Neighbors,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_v: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: Neighbors,
        particle_x: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        force_acceleration: wp.array(dtype=wp.vec3),
        # State in/out:
        particle_v: wp.array(dtype=wp.vec3),
        boundary_force_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        vi = particle_v[i]
        dv = wp.vec3(0.0)
        if wp.static(with_forces):
            dv = dt * force_acceleration[i]
        if wp.static(with_force):
            xi = particle_x[i]
            h = smoothing_length
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
        particle_v[i] = vi + dv

    return apply_forces
