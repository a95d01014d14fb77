"""Divergence-free SPH (Bender & Koschier 2015, 2017) in SPlisHSPlasH's current form (>= 2.12).

Notation (research note ``dfsph.md`` section 0): V = m / rho0 [m^3] the rest volume of a fluid
particle, g_ij = grad_i W(x_i - x_j) [1/m^4], G_ij = V g_ij [1/m] (the pair cache), the boundary
method's gradient term gb_ib (Akinci: V_b g_ib) [1/m]; rho_hat = rho / rho0;

    s_i       = sum_j G_ij + sum_b gb_ib                                   [1/m]
    D_i       = |s_i|^2 + sum_j |G_ij|^2      (fluid j only: walls do not move)   [1/m^2]
    f_i       = 1 / D_i  (0 when D_i d^2 <= 1e-6: a nearly isolated particle)      [m^2]
    delta_i(u)= sum_j (u_i - u_j) . G_ij + sum_b (u_i - u_b) . gb_ib           [1/s or 1/s^2]
                (the compression rate of a velocity field u: D rho_hat_i / Dt = delta_i(v);
                for accelerations u_b = 0)
    a_i(P)    = -sum_j (P_i + P_j) G_ij - P_i sum_b gb_ib = -P_i s_i - sum_j P_j G_ij   [m/s^2]
                (P = p / rho^2 rho0 [m^2/s^2]; a wall mirrors the particle's own P)

A solve makes delta (divergence solve) or the predicted density (density solve) vanish with
Jacobi sweeps, relaxation omega (0.5):

    (A P)_i = scale delta_i(a(P)),   residual r_i = b_i - (A P)_i,
    P_i    <- max(0, P_i - omega f_i r_i / scale),   A_ii = -scale D_i,
    divergence: scale = dt,   b_i = -delta_i(v),                        error e_i = max(-r_i, 0) [1/s]
    density:    scale = dt^2, b_i = (1 - rho_hat_i) - dt delta_i(v*),   error e_i = max(-r_i, 0) [-]

The error counts compression only and is measured with P before the sweep's update; particles with
fewer neighbours than a threshold (20 of 26 on a cubic lattice) leave the divergence error.
The density solve ends on its target's crossing (``solve_control``, ``finish_sweeps``): passing at
sweep k with errors E_(k-1) > target >= E_k it returns P_(k-1) + theta (P_k - P_(k-1)),
theta = (E_(k-1) - target) / (E_(k-1) - E_k), a pressure continuous in the fluid's state where the
sweep count changes (whole sweeps made a resting tank bounce).

Neighbours, the factor f_i and the pair cache (``DfsphPairs``: G_ij in compressed rows) come from one
search per step (``kernels/dfsph_search.py``); the passes here read the pair cache as one stream and
evaluate no smoothing kernel.
Kernels taking ``tid_offset`` are split over CPU cores and write only their own particle (no
atomics); sums over the particles are chunk sums in a fixed order (``kernels/reduction.py``)
finished by one thread (``solve_control``), so results are bitwise reproducible for any thread
count. The iteration kernels take the solve's ``control`` array and return at once when it says
the solve is done, so a device can run blocks of iterations between host reads.

This file: a(P) over the pair cache and the passes around the solves (the divergence solve's end, the density
solve's source, the integration, the bodies' pressure term); the solves' sweeps, control array and stop test
(``solve_control``, ``finish_sweeps``) and the stabilisation: ``kernels/dfsph_solve.py``.
"""
import warp as wp

from .dfsph_search import DfsphPairs
from .neighbors import NeighborList, particle_in_cell_order

@wp.func
def pair_pressure_acceleration(pairs: DfsphPairs, pressure: wp.array(dtype=float), i: int) -> wp.vec3:
    """a_i(P) = -P_i s_i - sum_j P_j G_ij [m/s^2] from the pair cache."""
    a = -pressure[i] * pairs.gradient_sum[i]
    k = pairs.offset[i]
    k_end = k + pairs.count[i]
    while k < k_end:
        a -= pressure[pairs.index[k]] * pairs.gradient[k]
        k += 1
    return a


@wp.kernel(enable_backward=False)
def finish_divergence(
    tid_offset: int,
    # Model:
    particle_mass: float,
    dt: float,
    # In:
    fluid_neighbors: NeighborList,
    pairs: DfsphPairs,
    pressure: wp.array(dtype=float),
    # State in/out:
    particle_v: wp.array(dtype=wp.vec3),
    boundary_force: wp.array(dtype=wp.vec3),
    # Out:
    divergence_warm_out: wp.array(dtype=float),
):
    """After the divergence solve: v_i += dt a_i(P^v) [m/s]; the walls' force on i,
    -m P^v_i sum_b gb_ib [N], added to the boundary force; P~^v_i = P^v_i dt kept for the next
    step's warm start [m^2/s]."""
    i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
    p = pressure[i]
    particle_v[i] = particle_v[i] + dt * pair_pressure_acceleration(pairs, pressure, i)
    boundary_force[i] = boundary_force[i] - (particle_mass * p) * pairs.boundary_gradient[i]
    divergence_warm_out[i] = p * dt


@wp.kernel(enable_backward=False)
def density_source(
    tid_offset: int,
    # Model:
    rest_density: float,
    gravity: wp.vec3,
    dt: float,
    warm_start: float,
    error_share: float,
    # In:
    fluid_neighbors: NeighborList,
    pairs: DfsphPairs,
    particle_density: wp.array(dtype=float),
    particle_v: wp.array(dtype=wp.vec3),
    # In/out:
    pressure: wp.array(dtype=float),
    # Out:
    source_out: wp.array(dtype=float),
):
    """Source of the density solve for the predicted velocities v* = v + dt g:
    b_i = s min(1 - rho_hat_i, 0) + max(1 - rho_hat_i, 0) - dt delta_i(v*) [-] (a uniform dt g
    cancels in the fluid pairs and enters only the boundary term): the over-density already at x
    is corrected by the share s = ``error_share`` in this step (Baumgarte; 1 at the adaptive step),
    an under-dense particle keeps all its room. Warm start, in place: P_i <- warm_start P_i (the
    last step's P [m^2/s^2]) where b_i < 0 (the particle is predicted over-dense), else 0."""
    i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
    vi = particle_v[i]
    div = wp.dot(vi + dt * gravity, pairs.boundary_gradient[i]) - pairs.boundary_velocity[i]
    k = pairs.offset[i]
    k_end = k + pairs.count[i]
    while k < k_end:
        div += wp.dot(vi - particle_v[pairs.index[k]], pairs.gradient[k])
        k += 1
    deficit = 1.0 - particle_density[i] / rest_density
    if deficit < 0.0:
        deficit = error_share * deficit
    b = deficit - dt * div
    source_out[i] = b
    p = float(0.0)
    if b < 0.0:
        p = warm_start * pressure[i]
    pressure[i] = p


@wp.kernel(enable_backward=False)
def integrate(
    tid_offset: int,
    # Model:
    particle_mass: float,
    rest_density: float,
    gravity: wp.vec3,
    dt: float,
    # In:
    fluid_neighbors: NeighborList,
    pairs: DfsphPairs,
    pressure: wp.array(dtype=float),
    particle_density: wp.array(dtype=float),
    # State in/out:
    particle_v: wp.array(dtype=wp.vec3),
    particle_x: wp.array(dtype=wp.vec3),
    boundary_force: wp.array(dtype=wp.vec3),
    # Out:
    particle_pressure_out: wp.array(dtype=float),
    particle_acceleration_out: wp.array(dtype=wp.vec3),
):
    """After the density solve: a_i = g + a_i(P); v_i += dt a_i; x_i += dt v_i (symplectic Euler)
    [m/s^2, m/s, m]; the walls' force -m P_i sum_b gb_ib added to the boundary force [N]; the
    pressure p_i = P_i rho_i^2 / rho0 [Pa]. Reads no position of another particle, so x is
    updated in place."""
    i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
    p = pressure[i]
    a = gravity + pair_pressure_acceleration(pairs, pressure, i)
    v = particle_v[i] + dt * a
    particle_v[i] = v
    particle_x[i] = particle_x[i] + dt * v
    boundary_force[i] = boundary_force[i] - (particle_mass * p) * pairs.boundary_gradient[i]
    rho = particle_density[i]
    particle_pressure_out[i] = p * rho * rho / rest_density
    particle_acceleration_out[i] = a


@wp.kernel(enable_backward=False)
def body_pressure_term(
    tid_offset: int,
    # Model:
    rest_density: float,
    with_divergence: int,
    # In:
    fluid_neighbors: NeighborList,
    divergence_pressure: wp.array(dtype=float),
    pressure: wp.array(dtype=float),
    # Out:
    boundary_pressure_term_out: wp.array(dtype=float),
):
    """Moving bodies: the walls' pressure acceleration of the step, averaged over dt (impulse / dt), is
    -(P^v_i + P_i) sum_b gb_ib (each solve changes v once, by dt a(P), with its converged P; the sweeps
    change only P), i.e. the boundary method's pressure term with term_i = (P^v_i + P_i) / rho0
    [m^5/(kg s^2)] (Akinci: -rho0 V_b term_i grad W_ib = -P_i V_b grad W_ib). P^v counts only when the
    divergence solve ran (``with_divergence``)."""
    i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
    p = pressure[i]
    if with_divergence != 0:
        p = divergence_pressure[i] + p
    boundary_pressure_term_out[i] = p / rest_density
