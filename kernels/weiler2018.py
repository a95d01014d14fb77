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
when the control array says done, so a device can run blocks of iterations between host reads.
"""
import functools

import warp as wp

from .neighbors import NeighborList, neighbor_count, particle_in_cell_order
from .smoothing import SMOOTHING_FUNCTIONS

# slots of the CG control array (float64)
CONTROL_DONE = 0        # 1 once converged, max_iterations ran or the search direction vanished
CONTROL_ITERATIONS = 1  # CG iterations run
CONTROL_RZ = 2          # r . M^-1 r of the current residual
CONTROL_RR = 3          # |r|^2 of the current residual [m^2/s^2]
CONTROL_THRESHOLD = 4   # |r|^2 at which the solve stops [m^2/s^2]
CONTROL_ALPHA = 5       # step length of the current iteration
CONTROL_BETA = 6        # direction update of the current iteration
CONTROL_START = 7       # |r0| (the residual at dv = 0) [m/s]
CONTROL_COUNT = 8

#: the float32 floor of the stop test, relative to |v*|
FLOAT32_FLOOR = 1.0e-7


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


@wp.kernel(enable_backward=False)
def update(
    tid_offset: int,
    # In:
    fluid_neighbors: NeighborList,
    block_inverse: wp.array(dtype=wp.mat33),
    direction: wp.array(dtype=wp.vec3),
    product: wp.array(dtype=wp.vec3),
    control: wp.array(dtype=wp.float64),
    # In/out:
    solution: wp.array(dtype=wp.vec3),
    residual: wp.array(dtype=wp.vec3),
    # Out:
    preconditioned_out: wp.array(dtype=wp.vec3),
):
    """dv += alpha p, r -= alpha q, z = M^-1 r (nothing once done)."""
    if control[CONTROL_DONE] != wp.float64(0.0):
        return
    i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
    alpha = float(control[CONTROL_ALPHA])
    solution[i] = solution[i] + alpha * direction[i]
    r = residual[i] - alpha * product[i]
    residual[i] = r
    preconditioned_out[i] = block_inverse[i] * r


@wp.kernel(enable_backward=False)
def new_direction(
    tid_offset: int,
    # In:
    fluid_neighbors: NeighborList,
    preconditioned: wp.array(dtype=wp.vec3),
    control: wp.array(dtype=wp.float64),
    # In/out:
    direction: wp.array(dtype=wp.vec3),
):
    """p = z + beta p (nothing once done)."""
    if control[CONTROL_DONE] != wp.float64(0.0):
        return
    i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
    direction[i] = preconditioned[i] + float(control[CONTROL_BETA]) * direction[i]


@wp.kernel(enable_backward=False)
def dot_chunks(
    chunk: int,
    # In:
    a: wp.array(dtype=wp.vec3),
    b: wp.array(dtype=wp.vec3),
    c: wp.array(dtype=wp.vec3),
    d: wp.array(dtype=wp.vec3),
    control: wp.array(dtype=wp.float64),
    # Out:
    partial_ab_out: wp.array(dtype=wp.float64),
    partial_cd_out: wp.array(dtype=wp.float64),
):
    """partial_ab_out[k], partial_cd_out[k] = the sums of a_i . b_i and c_i . d_i over chunk k, in index
    order (float64; nothing once done). Two dot products in one pass over the particles."""
    if control[CONTROL_DONE] != wp.float64(0.0):
        return
    k = wp.tid()
    lo = k * chunk
    hi = wp.min(lo + chunk, a.shape[0])
    ab = wp.float64(0.0)
    cd = wp.float64(0.0)
    for i in range(lo, hi):
        ab += wp.float64(wp.dot(a[i], b[i]))
        cd += wp.float64(wp.dot(c[i], d[i]))
    partial_ab_out[k] = ab
    partial_cd_out[k] = cd


@wp.func
def total(partial: wp.array(dtype=wp.float64)) -> wp.float64:
    """Sum of the chunk sums, in a fixed order."""
    s = wp.float64(0.0)
    for k in range(partial.shape[0]):
        s += partial[k]
    return s


@wp.kernel(enable_backward=False)
def reset_control(control_out: wp.array(dtype=wp.float64)):
    """A solve starts: not done (the start's reductions run)."""
    for k in range(CONTROL_COUNT):
        control_out[k] = wp.float64(0.0)


@wp.kernel(enable_backward=False)
def start_control(
    # In:
    partial_rz: wp.array(dtype=wp.float64),
    partial_rr: wp.array(dtype=wp.float64),
    partial_start: wp.array(dtype=wp.float64),
    partial_velocity: wp.array(dtype=wp.float64),
    tolerance: float,
    max_iterations: int,
    # Out:
    control_out: wp.array(dtype=wp.float64),
):
    """One thread: the stop threshold |r|^2 <= tolerance^2 |r0|^2 + (1e-7 |v*|)^2; done at once when
    the warm start already meets it (or max_iterations is 0)."""
    rz = total(partial_rz)
    rr = total(partial_rr)
    start = total(partial_start)
    floor = wp.float64(FLOAT32_FLOOR) * wp.float64(FLOAT32_FLOOR) * total(partial_velocity)
    threshold = wp.float64(tolerance) * wp.float64(tolerance) * start + floor
    control_out[CONTROL_ITERATIONS] = wp.float64(0.0)
    control_out[CONTROL_RZ] = rz
    control_out[CONTROL_RR] = rr
    control_out[CONTROL_THRESHOLD] = threshold
    control_out[CONTROL_ALPHA] = wp.float64(0.0)
    control_out[CONTROL_BETA] = wp.float64(0.0)
    control_out[CONTROL_START] = wp.sqrt(start)
    done = wp.float64(0.0)
    if rr <= threshold or max_iterations <= 0 or rz <= wp.float64(0.0):
        done = wp.float64(1.0)
    control_out[CONTROL_DONE] = done


@wp.kernel(enable_backward=False)
def alpha_control(
    # In:
    partial_pq: wp.array(dtype=wp.float64),
    # In/out:
    control: wp.array(dtype=wp.float64),
):
    """One thread: alpha = (r . z) / (p . A p); done when p . A p <= 0 (p vanished: A is SPD)."""
    if control[CONTROL_DONE] != wp.float64(0.0):
        return
    pq = total(partial_pq)
    if pq <= wp.float64(0.0):
        control[CONTROL_DONE] = wp.float64(1.0)
        return
    control[CONTROL_ALPHA] = control[CONTROL_RZ] / pq


@wp.kernel(enable_backward=False)
def beta_control(
    # In:
    partial_rz: wp.array(dtype=wp.float64),
    partial_rr: wp.array(dtype=wp.float64),
    max_iterations: int,
    # In/out:
    control: wp.array(dtype=wp.float64),
):
    """One thread: iterations += 1; beta = (r . z)_new / (r . z)_old; done when |r|^2 <= threshold or
    max_iterations ran."""
    if control[CONTROL_DONE] != wp.float64(0.0):
        return
    rz = total(partial_rz)
    rr = total(partial_rr)
    it = control[CONTROL_ITERATIONS] + wp.float64(1.0)
    control[CONTROL_ITERATIONS] = it
    control[CONTROL_RR] = rr
    old = control[CONTROL_RZ]
    control[CONTROL_RZ] = rz
    if old > wp.float64(0.0):
        control[CONTROL_BETA] = rz / old
    else:
        control[CONTROL_BETA] = wp.float64(0.0)
    if rr <= control[CONTROL_THRESHOLD] or it >= wp.float64(max_iterations) or rz <= wp.float64(0.0):
        control[CONTROL_DONE] = wp.float64(1.0)


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
