"""Position-based fluids over ``wp.HashGrid`` queries: the reference variant of the density/lambda pass
and the Jacobi correction (``pbf.py`` has the neighbour-list kernels the solver runs by default).

Queries use ``query_radius`` >= the support radius (the grid may have been built on slightly older
positions) and keep only pairs closer than the support radius. Equations as in ``pbf.py``.
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import NoBoundaryParams, particle_in_cell_order
from .pbf import constraint_lambda
from .smoothing import SMOOTHING_FUNCTIONS


@functools.cache
def density_lambda_kernel(smoothing: str, boundary_terms):
    """Density (eq. 7/13), constraint C (eq. 17) and Lagrange multiplier lambda (eq. 19) at the
    predicted positions, in one hash-grid pass (the reference variant of
    ``pbf_pairs.density_lambda_pairs_kernel``). Writes C_i to ``particle_constraint_out``."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]
    with_boundary = boundary_terms is not None and boundary_terms.density is not None
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    density_term = boundary_terms.density if with_boundary else None
    gradient_term = boundary_terms.gradient if with_boundary else None
    Neighbors = NEIGHBOR_TYPES["grid"]

    @wp.kernel(enable_backward=False, module="unique")
    def compute_density_lambda(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        relaxation_epsilon: float,
        query_radius: float,
        boundary_params: BoundaryParams,
        boundary_neighbors: Neighbors,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: Neighbors,
        predicted_x: wp.array(dtype=wp.vec3),
        constraint_offset: wp.array(dtype=float),
        # Out:
        particle_density_out: wp.array(dtype=float),
        particle_lambda_out: wp.array(dtype=float),
        particle_constraint_out: wp.array(dtype=float),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = predicted_x[i]
        h = smoothing_length
        volume = particle_mass / rest_density
        w_sum = float(0.0)
        grad_i = wp.vec3(0.0)
        grad_sq = float(0.0)
        query = wp.hash_grid_query(fluid_neighbors, xi, query_radius)
        j = int(0)
        while wp.hash_grid_query_next(query, j):
            x_ij = xi - predicted_x[j]
            r = wp.length(x_ij)
            if r < support_radius:
                w_sum += wp.static(value)(r, h)
                g = volume * wp.static(gradient)(x_ij, h)
                grad_i += g
                grad_sq += wp.dot(g, g)
        ratio = volume * w_sum
        if wp.static(with_boundary):
            bquery = wp.hash_grid_query(boundary_neighbors, xi, support_radius)
            b = int(0)
            while wp.hash_grid_query_next(bquery, b):
                x_ib = xi - boundary_x[b]
                r = wp.length(x_ib)
                if r < support_radius:
                    vb = boundary_volume[b]
                    ratio += wp.static(density_term)(boundary_params, wp.static(value)(r, h), vb)
                    grad_i += wp.static(gradient_term)(boundary_params, wp.static(gradient)(x_ib, h), vb)
        c_lam = constraint_lambda(ratio - constraint_offset[i], grad_i, grad_sq, relaxation_epsilon)
        particle_density_out[i] = rest_density * ratio
        particle_lambda_out[i] = c_lam[1]
        particle_constraint_out[i] = c_lam[0]

    return compute_density_lambda


@functools.cache
def correction_kernel(smoothing: str, boundary_terms, tensile: bool):
    """Jacobi position correction dx_i (eq. 18) over the hash grid (the reference variant of
    ``pbf_pairs.correction_pairs_kernel``), optional tensile term
    s_corr = -k (W_ij / W(dq))^n * tensile_scale [m^2] (Macklin & Mueller 2013 eq. 13, made
    dimensionally consistent: tensile_scale = 1 / rest-lattice denominator, so s_corr acts like a
    constraint violation of k). Adds m dx_i^boundary / dt^2 to the boundary force [N] and writes
    |dx_i| before the trust-region clamp to ``correction_size_out`` [m]."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]
    Neighbors = NEIGHBOR_TYPES["grid"]
    with_boundary = boundary_terms is not None and boundary_terms.gradient is not None
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    gradient_term = boundary_terms.gradient if with_boundary else None

    @wp.func(module="unique")
    def pair_weight(lam_i: float, lam_j: float, r: float, h: float, tensile_k: float, tensile_n: int,
                    tensile_inv_w: float, tensile_scale: float) -> float:
        s = lam_i + lam_j
        if wp.static(tensile):
            s -= tensile_k * wp.pow(wp.static(value)(r, h) * tensile_inv_w, float(tensile_n)) * tensile_scale
        return s

    @wp.kernel(enable_backward=False, module="unique")
    def compute_correction(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        query_radius: float,
        tensile_k: float,
        tensile_n: int,
        tensile_inv_w: float,
        tensile_scale: float,
        inv_dt2: float,
        max_step: float,
        boundary_params: BoundaryParams,
        boundary_neighbors: Neighbors,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: Neighbors,
        predicted_x: wp.array(dtype=wp.vec3),
        particle_lambda: wp.array(dtype=float),
        # Out:
        position_correction_out: wp.array(dtype=wp.vec3),
        boundary_force_out: wp.array(dtype=wp.vec3),
        correction_size_out: wp.array(dtype=float),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = predicted_x[i]
        lam_i = particle_lambda[i]
        h = smoothing_length
        volume = particle_mass / rest_density
        dx = wp.vec3(0.0)
        query = wp.hash_grid_query(fluid_neighbors, xi, query_radius)
        j = int(0)
        while wp.hash_grid_query_next(query, j):
            x_ij = xi - predicted_x[j]
            r = wp.length(x_ij)
            if r < support_radius:
                s = pair_weight(lam_i, particle_lambda[j], r, h, tensile_k, tensile_n, tensile_inv_w,
                                tensile_scale)
                dx += (volume * s) * wp.static(gradient)(x_ij, h)
        if wp.static(with_boundary):
            dx_b = wp.vec3(0.0)
            if lam_i != 0.0:
                bquery = wp.hash_grid_query(boundary_neighbors, xi, support_radius)
                b = int(0)
                while wp.hash_grid_query_next(bquery, b):
                    x_ib = xi - boundary_x[b]
                    if wp.length(x_ib) < support_radius:
                        dx_b += lam_i * wp.static(gradient_term)(boundary_params, wp.static(gradient)(x_ib, h),
                                                                 boundary_volume[b])
            dx += dx_b
            boundary_force_out[i] = boundary_force_out[i] + (particle_mass * inv_dt2) * dx_b
        size = wp.length(dx)
        if size > max_step:
            dx = dx * (max_step / size)
        position_correction_out[i] = dx
        correction_size_out[i] = size

    return compute_correction
