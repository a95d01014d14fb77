"""Implicit viscosity of Weiler, Koschier, Brand & Bender 2018 ("A Physically Consistent Implicit
Viscosity Solver for SPH Fluids", CGF 37(2)) as SPlisHSPlasH implements it; host half
``warp_sph/methods/forces/weiler2018.py``, equations also in the research note ``forces.md`` section 3.2.

Backward Euler on the velocities, with nu the kinematic viscosity [m^2/s] (mu = rho0 nu), nu_b the
boundary's, h the smoothing length, x_ij = x_i - x_j, g_ij = grad_i W_ij = psi_ij x_ij (psi <= 0); the
0.01 h^2 (Monaghan's; SPlisHSPlasH writes 0.01 H_s^2 with its "h" the support radius) is also the
explicit form's (``kernels/explicit_viscosity.py``):

    (A v)_i = v_i - (dt / rho_i) [ 10 mu sum_j (m / rho_j) (v_ij . x_ij) / (r^2 + 0.01 h^2) g_ij
                                 + 10 mu_b sum_b (rho0 V_b / rho_i) (v_i . x_ib) / (r^2 + 0.01 h^2) g_ib ]
    b_i     = v*_i - (dt / rho_i) 10 mu_b sum_b (rho0 V_b / rho_i) (v_b . x_ib) / (r^2 + 0.01 h^2) g_ib

Written with the pair weights K_ij = -dt 10 nu rho0 m psi_ij / (rho_i rho_j (r^2 + 0.01 h^2)) >= 0
(symmetric in ij: every particle has the mass m) and K_ib = -dt 10 nu_b rho0^2 V_b psi_ib /
(rho_i^2 (r^2 + 0.01 h^2)) >= 0, and the pair vectors e_ij = sqrt(K_ij) x_ij:

    (A u)_i = u_i + B_i u_i + sum_j e_ij (e_ij . (u_i - u_j)),   B_i = sum_b K_ib x_ib x_ib^T,
    c_i     = sum_b K_ib (v_b . x_ib) x_ib                       (b = v* + c),

so A = I + (a graph Laplacian of positive semi-definite 3x3 blocks) + (PSD diagonal blocks):
symmetric positive definite. The solve is for dv = v_new - v* (float32 keeps the digits of a small
correction to a large velocity): A dv = r0 with r0 = c - (A - I) v*, by preconditioned conjugate
gradients with the 3x3 block-Jacobi preconditioner M^-1 = blockdiag(A)^-1 (SPlisHSPlasH's
USE_BLOCKDIAGONAL_PRECONDITIONER), warm-started from the last step's dv (SPlisHSPlasH m_vDiff).
Stop when |r| <= tolerance |r0| (or the float32 floor 1e-7 |v*|), or after max_iterations.

The pair vectors, blocks and c come from one neighbour pass per step (``setup_kernel``); each CG
iteration is three particle passes (matvec, update, direction) and two reductions, with no kernel
evaluation. Sums over particles are chunk sums in index order finished by one thread (float64),
so results are bitwise reproducible for any CPU thread count; the iteration kernels return at once
when the control array says done, so a device can run blocks of iterations between host reads. Those
iteration kernels and the control array's slots are ``weiler2018_cg.py``.
"""
import functools

import warp as wp

from .neighbors import NeighborList, neighbor_count, particle_in_cell_order
from .smoothing import SMOOTHING_FUNCTIONS
from .weiler2018_cg import CONTROL_DONE

@functools.cache
def setup_kernel(smoothing: str, with_boundary: bool):
    """Per step: the pair vectors e_ij, the boundary block B_i and right-hand side c_i, and the
    inverse of the diagonal block M_i = I + B_i + sum_j e_ij e_ij^T (module docstring)."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.kernel(enable_backward=False, module="unique")
    def weiler_setup(
        tid_offset: int,
        # Model:
        particle_mass: float,
        rest_density: float,
        smoothing_length: float,
        support_radius: float,
        viscosity: float,
        boundary_viscosity: float,
        dt: float,
        boundary_neighbors: NeighborList,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_v: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: NeighborList,
        particle_x: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        # Out:
        pair_out: wp.array2d(dtype=wp.vec3),
        block_inverse_out: wp.array(dtype=wp.mat33),
        boundary_block_out: wp.array(dtype=wp.mat33),
        boundary_rhs_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = particle_x[i]
        rho_i = particle_density[i]
        h = smoothing_length
        eps = 0.01 * h * h
        fluid_weight = 10.0 * dt * viscosity * rest_density * particle_mass / rho_i
        block = wp.identity(n=3, dtype=float)
        k = int(0)
        k_end = int(neighbor_count(fluid_neighbors, i))
        while k < k_end:
            j = fluid_neighbors.index[i, k]
            x_ij = xi - particle_x[j]
            r2 = wp.dot(x_ij, x_ij)
            e = wp.vec3(0.0)
            if j != i and r2 > 0.0 and r2 < support_radius * support_radius:
                psi = wp.dot(wp.static(gradient)(x_ij, h), x_ij) / r2
                weight = -fluid_weight * psi / (particle_density[j] * (r2 + eps))
                e = wp.sqrt(wp.max(weight, 0.0)) * x_ij
            pair_out[i, k] = e
            block += wp.outer(e, e)
            k += 1
        if wp.static(with_boundary):
            bblock = wp.mat33(0.0)
            c = wp.vec3(0.0)
            boundary_weight = 10.0 * dt * boundary_viscosity * rest_density * rest_density / (rho_i * rho_i)
            k = int(0)
            k_end = int(neighbor_count(boundary_neighbors, i))
            while k < k_end:
                b = boundary_neighbors.index[i, k]
                x_ib = xi - boundary_x[b]
                r2 = wp.dot(x_ib, x_ib)
                if r2 > 0.0 and r2 < support_radius * support_radius:
                    psi = wp.dot(wp.static(gradient)(x_ib, h), x_ib) / r2
                    weight = wp.max(-boundary_weight * boundary_volume[b] * psi / (r2 + eps), 0.0)
                    bblock += weight * wp.outer(x_ib, x_ib)
                    c += (weight * wp.dot(boundary_v[b], x_ib)) * x_ib
                k += 1
            block += bblock
            boundary_block_out[i] = bblock
            boundary_rhs_out[i] = c
        block_inverse_out[i] = wp.inverse(block)

    return weiler_setup


@wp.func
def laplacian(fluid_neighbors: NeighborList, pairs: wp.array2d(dtype=wp.vec3), u: wp.array(dtype=wp.vec3),
              i: int) -> wp.vec3:
    """sum_j e_ij (e_ij . (u_i - u_j)): the fluid part of (A - I) u at particle i."""
    ui = u[i]
    s = wp.vec3(0.0)
    k = int(0)
    k_end = int(neighbor_count(fluid_neighbors, i))
    while k < k_end:
        e = pairs[i, k]
        s += wp.dot(e, ui - u[fluid_neighbors.index[i, k]]) * e
        k += 1
    return s


@functools.cache
def start_kernel(with_boundary: bool):
    """The solve's start: dv = warm (the last step's dv), r0 = c - (A - I) v* (written to
    ``start_residual_out``), r = r0 - A dv, z = M^-1 r, p = z. v* = particle_v + velocity_shift (the
    step's dt g when the solver adds gravity after the solve: a uniform shift enters only the walls'
    term)."""

    @wp.kernel(enable_backward=False, module="unique")
    def weiler_start(
        tid_offset: int,
        # In:
        fluid_neighbors: NeighborList,
        pairs: wp.array2d(dtype=wp.vec3),
        block_inverse: wp.array(dtype=wp.mat33),
        boundary_block: wp.array(dtype=wp.mat33),
        boundary_rhs: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        velocity_shift: wp.vec3,
        warm: wp.array(dtype=wp.vec3),
        # Out:
        solution_out: wp.array(dtype=wp.vec3),
        start_residual_out: wp.array(dtype=wp.vec3),
        residual_out: wp.array(dtype=wp.vec3),
        preconditioned_out: wp.array(dtype=wp.vec3),
        direction_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        x0 = warm[i]
        r0 = -laplacian(fluid_neighbors, pairs, particle_v, i)
        ax = x0 + laplacian(fluid_neighbors, pairs, warm, i)
        if wp.static(with_boundary):
            bb = boundary_block[i]
            r0 += boundary_rhs[i] - bb * (particle_v[i] + velocity_shift)
            ax += bb * x0
        r = r0 - ax
        z = block_inverse[i] * r
        solution_out[i] = x0
        start_residual_out[i] = r0
        residual_out[i] = r
        preconditioned_out[i] = z
        direction_out[i] = z

    return weiler_start


@functools.cache
def matvec_kernel(with_boundary: bool):
    """q = A p (nothing once ``control`` says done)."""

    @wp.kernel(enable_backward=False, module="unique")
    def weiler_matvec(
        tid_offset: int,
        # In:
        fluid_neighbors: NeighborList,
        pairs: wp.array2d(dtype=wp.vec3),
        boundary_block: wp.array(dtype=wp.mat33),
        direction: wp.array(dtype=wp.vec3),
        control: wp.array(dtype=wp.float64),
        # Out:
        product_out: wp.array(dtype=wp.vec3),
    ):
        if control[CONTROL_DONE] != wp.float64(0.0):
            return
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        p = direction[i]
        q = p + laplacian(fluid_neighbors, pairs, direction, i)
        if wp.static(with_boundary):
            q += boundary_block[i] * p
        product_out[i] = q

    return weiler_matvec


@functools.cache
def finish_kernel(with_boundary: bool):
    """After the solve: v += dv, warm = dv for the next step; with boundary viscosity the walls' force on
    i, m (c_i - B_i (v_i + velocity_shift)) / dt [N], added to the boundary force."""

    @wp.kernel(enable_backward=False, module="unique")
    def weiler_finish(
        tid_offset: int,
        # Model:
        particle_mass: float,
        dt: float,
        velocity_shift: wp.vec3,
        # In:
        fluid_neighbors: NeighborList,
        boundary_block: wp.array(dtype=wp.mat33),
        boundary_rhs: wp.array(dtype=wp.vec3),
        solution: wp.array(dtype=wp.vec3),
        # State in/out:
        particle_v: wp.array(dtype=wp.vec3),
        boundary_force: wp.array(dtype=wp.vec3),
        # Out:
        warm_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        dv = solution[i]
        v = particle_v[i] + dv
        particle_v[i] = v
        warm_out[i] = dv
        if wp.static(with_boundary):
            a_b = (boundary_rhs[i] - boundary_block[i] * (v + velocity_shift)) / dt
            boundary_force[i] = boundary_force[i] + particle_mass * a_b

    return weiler_finish
