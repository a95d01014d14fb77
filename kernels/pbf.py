"""Position-based fluids (Macklin & Mueller 2013) with the seed report's equations 17-20.

Units (SPlisHSPlasH convention, physics notes section 4): V = m / rho0 [m^3] is the rest volume of
a fluid particle, V_b the Akinci volume of a boundary particle [m^3];

    rho_i / rho0 = V sum_j W_ij + sum_b V_b W_ib                        (report eq. 7/13)
    C_i          = max(rho_i / rho0 - 1, 0)                             (eq. 17)         [-]
    grad_j C_i   = -V grad_i W_ij,  grad_i C_i = V sum_j grad_i W_ij + sum_b V_b grad_i W_ib
                                                                        (eq. 20)         [1/m]
    lambda_i     = -C_i / (|grad_i C_i|^2 + sum_j |grad_j C_i|^2 + eps) (eq. 19)         [m^2]
    dx_i         = sum_j V (lambda_i + lambda_j + s_corr_ij) grad_i W_ij
                   + lambda_i sum_b V_b grad_i W_ib                     (eq. 18)         [m]

Boundary particles do not move, so they are left out of the sum over k of |grad_k C_i|^2 but kept
in grad_i C_i (SPlisHSPlasH). The position correction of particle i by the walls, over dt^2 and
times m, is the force of the walls on it (physics notes 2.1); its negative sums to the wall load.

Kernels take the smoothing kernel and the neighbour iteration as compile-time choices (factory +
``wp.static``): ``neighbors="grid"`` queries wp.HashGrid ids in every pass, with ``query_radius`` >=
support radius (the grid may have been built on slightly older positions); ``neighbors="list"``
reads ``NeighborList`` structs built once per step with a search radius enlarged by a margin. Both
keep only pairs closer than the support radius. The density/lambda pass and the correction have one
kernel per variant: over lists the density pass fills a ``PairCache`` that the correction reads. Every particle-parallel kernel takes ``tid_offset``
first (split over CPU cores by ``warp_sph.launch``) and writes only its own particle: no atomics
(CPU atomics are plain read-modify-writes, racy across split ranges). Sums and maxima over the
particles come from per-particle values reduced chunk by chunk (``sum_chunks``,
``max_correction_drift_chunks``) in a fixed order, so they are bitwise reproducible.
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import NeighborList, neighbor_count, particle_in_cell_order
from .smoothing import SMOOTHING_FUNCTIONS
from .viscosity import boundary_friction_acceleration, viscosity_acceleration

REDUCE_CHUNK = 256  # particles per partial sum / maximum (fixed: results do not depend on the thread count)


@wp.kernel(enable_backward=False)
def predict_positions(
    tid_offset: int,
    # Model:
    gravity: wp.vec3,
    dt: float,
    # State in:
    particle_x: wp.array(dtype=wp.vec3),
    # State in/out:
    particle_v: wp.array(dtype=wp.vec3),
    # Out:
    predicted_x_out: wp.array(dtype=wp.vec3),
    boundary_force_out: wp.array(dtype=wp.vec3),
):
    """v += dt g; x* = x + dt v [m/s, m]; clears the per-step boundary force."""
    i = wp.tid() + tid_offset
    v = particle_v[i] + dt * gravity
    particle_v[i] = v
    predicted_x_out[i] = particle_x[i] + dt * v
    boundary_force_out[i] = wp.vec3(0.0)


@wp.func
def constraint_lambda(ratio: float, grad_i: wp.vec3, grad_sq: float, relaxation_epsilon: float) -> wp.vec2:
    """(C_i, lambda_i) from rho_i/rho0, grad_i C_i and sum_j |grad_j C_i|^2 (eq. 17, 19)."""
    c = wp.max(ratio - 1.0, 0.0)
    lam = float(0.0)
    if c > 0.0:
        lam = -c / (wp.dot(grad_i, grad_i) + grad_sq + relaxation_epsilon)
    return wp.vec2(c, lam)


@functools.cache
def density_lambda_kernel(smoothing: str, with_boundary: bool):
    """Density (eq. 7/13), constraint C (eq. 17) and Lagrange multiplier lambda (eq. 19) at the
    predicted positions, in one hash-grid pass (neighbour lists: ``density_lambda_pairs_kernel``).
    Writes C_i to ``particle_constraint_out``."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]
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
        boundary_neighbors: Neighbors,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: Neighbors,
        predicted_x: wp.array(dtype=wp.vec3),
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
                    ratio += vb * wp.static(value)(r, h)
                    grad_i += vb * wp.static(gradient)(x_ib, h)
        c_lam = constraint_lambda(ratio, grad_i, grad_sq, relaxation_epsilon)
        particle_density_out[i] = rest_density * ratio
        particle_lambda_out[i] = c_lam[1]
        particle_constraint_out[i] = c_lam[0]

    return compute_density_lambda


@functools.cache
def correction_kernel(smoothing: str, with_boundary: bool, tensile: bool):
    """Jacobi position correction dx_i (eq. 18) over the hash grid (neighbour lists:
    ``correction_pairs_kernel``), optional tensile term
    s_corr = -k (W_ij / W(dq))^n * tensile_scale [m^2] (Macklin & Mueller 2013 eq. 13, made
    dimensionally consistent: tensile_scale = 1 / rest-lattice denominator, so s_corr acts like a
    constraint violation of k). Adds m dx_i^boundary / dt^2 to the boundary force [N] and writes
    |dx_i| before the trust-region clamp to ``correction_size_out`` [m]."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]
    Neighbors = NEIGHBOR_TYPES["grid"]

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
                        dx_b += (lam_i * boundary_volume[b]) * wp.static(gradient)(x_ib, h)
            dx += dx_b
            boundary_force_out[i] = boundary_force_out[i] + (particle_mass * inv_dt2) * dx_b
        size = wp.length(dx)
        if size > max_step:
            dx = dx * (max_step / size)
        position_correction_out[i] = dx
        correction_size_out[i] = size

    return compute_correction


@wp.struct
class PairCache:
    """Pairs of the last density pass, for the correction at the same positions (lists only).

    count: pairs closer than the support radius per particle, shape (fluid_count,); index[i, k]:
    neighbour j; gradient[i, k] = V grad_i W_ij [1/m]; value[i, k] = W_ij [1/m^3] (s_corr only,
    else shape (1, 1)); boundary_gradient[i] = sum_b V_b grad_i W_ib [1/m]. The 2-D arrays have
    the fluid list's capacity per row.
    """

    count: wp.array(dtype=wp.int32)
    index: wp.array2d(dtype=wp.int32)
    gradient: wp.array2d(dtype=wp.vec3)
    value: wp.array2d(dtype=float)
    boundary_gradient: wp.array(dtype=wp.vec3)


@functools.cache
def density_lambda_pairs_kernel(smoothing: str, with_boundary: bool, tensile: bool):
    """As ``density_lambda_kernel`` over neighbour lists, and it keeps what the correction needs at
    these positions in a ``PairCache``: the pairs within the support radius (the lists hold a
    margin more) with V grad W_ij [and W_ij], and the boundary gradient sum."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.kernel(enable_backward=False, module="unique")
    def compute_density_lambda_pairs(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        relaxation_epsilon: float,
        boundary_neighbors: NeighborList,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: NeighborList,
        predicted_x: wp.array(dtype=wp.vec3),
        # Out:
        particle_density_out: wp.array(dtype=float),
        particle_lambda_out: wp.array(dtype=float),
        particle_constraint_out: wp.array(dtype=float),
        pairs_out: PairCache,
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = predicted_x[i]
        h = smoothing_length
        support2 = support_radius * support_radius
        volume = particle_mass / rest_density
        w_sum = float(0.0)
        grad_i = wp.vec3(0.0)
        grad_sq = float(0.0)
        n = int(0)
        k = int(0)
        k_end = int(neighbor_count(fluid_neighbors, i))
        while k < k_end:
            j = fluid_neighbors.index[i, k]
            x_ij = xi - predicted_x[j]
            if wp.dot(x_ij, x_ij) < support2:
                w = wp.static(value)(wp.length(x_ij), h)
                w_sum += w
                g = volume * wp.static(gradient)(x_ij, h)
                grad_i += g
                grad_sq += wp.dot(g, g)
                pairs_out.index[i, n] = j
                pairs_out.gradient[i, n] = g
                if wp.static(tensile):
                    pairs_out.value[i, n] = w
                n += 1
            k += 1
        pairs_out.count[i] = n
        ratio = volume * w_sum
        grad_b = wp.vec3(0.0)
        if wp.static(with_boundary):
            k = int(0)
            k_end = int(neighbor_count(boundary_neighbors, i))
            while k < k_end:
                b = boundary_neighbors.index[i, k]
                x_ib = xi - boundary_x[b]
                if wp.dot(x_ib, x_ib) < support2:
                    vb = boundary_volume[b]
                    ratio += vb * wp.static(value)(wp.length(x_ib), h)
                    grad_b += vb * wp.static(gradient)(x_ib, h)
                k += 1
        pairs_out.boundary_gradient[i] = grad_b
        grad_i += grad_b
        c_lam = constraint_lambda(ratio, grad_i, grad_sq, relaxation_epsilon)
        particle_density_out[i] = rest_density * ratio
        particle_lambda_out[i] = c_lam[1]
        particle_constraint_out[i] = c_lam[0]

    return compute_density_lambda_pairs


@functools.cache
def correction_pairs_kernel(with_boundary: bool, tensile: bool):
    """Jacobi correction (eq. 18) from a ``PairCache`` of the density pass at the same positions:
    dx_i = sum_j (lambda_i + lambda_j + s_corr_ij) V grad W_ij + lambda_i sum_b V_b grad W_ib, no
    kernel evaluation (the smoothing kernel entered through the cache). Same outputs as
    ``correction_kernel``."""

    @wp.kernel(enable_backward=False, module="unique")
    def compute_correction_pairs(
        tid_offset: int,
        # Model:
        particle_mass: float,
        tensile_k: float,
        tensile_n: int,
        tensile_inv_w: float,
        tensile_scale: float,
        inv_dt2: float,
        max_step: float,
        # State in:
        fluid_neighbors: NeighborList,
        pairs: PairCache,
        particle_lambda: wp.array(dtype=float),
        # Out:
        position_correction_out: wp.array(dtype=wp.vec3),
        boundary_force_out: wp.array(dtype=wp.vec3),
        correction_size_out: wp.array(dtype=float),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        lam_i = particle_lambda[i]
        dx = wp.vec3(0.0)
        k = int(0)
        k_end = int(pairs.count[i])
        while k < k_end:
            s = lam_i + particle_lambda[pairs.index[i, k]]
            if wp.static(tensile):
                s -= tensile_k * wp.pow(pairs.value[i, k] * tensile_inv_w, float(tensile_n)) * tensile_scale
            dx += s * pairs.gradient[i, k]
            k += 1
        if wp.static(with_boundary):
            dx_b = lam_i * pairs.boundary_gradient[i]
            dx += dx_b
            boundary_force_out[i] = boundary_force_out[i] + (particle_mass * inv_dt2) * dx_b
        size = wp.length(dx)
        if size > max_step:
            dx = dx * (max_step / size)
        position_correction_out[i] = dx
        correction_size_out[i] = size

    return compute_correction_pairs


@wp.kernel(enable_backward=False)
def apply_correction(
    tid_offset: int,
    # In:
    position_correction: wp.array(dtype=wp.vec3),
    # State in/out:
    predicted_x: wp.array(dtype=wp.vec3),
):
    """x* += dx [m]."""
    i = wp.tid() + tid_offset
    predicted_x[i] = predicted_x[i] + position_correction[i]


@wp.kernel(enable_backward=False)
def sum_chunks(
    chunk: int,
    # In:
    values: wp.array(dtype=float),
    # Out:
    partial_out: wp.array(dtype=float),
):
    """partial_out[k] = sum of values[k chunk .. (k + 1) chunk - 1], summed in index order."""
    k = wp.tid()
    lo = k * chunk
    hi = wp.min(lo + chunk, values.shape[0])
    s = float(0.0)
    for i in range(lo, hi):
        s += values[i]
    partial_out[k] = s


@wp.kernel(enable_backward=False)
def max_correction_drift_chunks(
    chunk: int,
    # In:
    correction_size: wp.array(dtype=float),
    predicted_x: wp.array(dtype=wp.vec3),
    neighbor_x: wp.array(dtype=wp.vec3),
    # Out:
    partial_out: wp.array2d(dtype=float),
):
    """Per chunk of particles: the largest |dx_i| [m] and the largest distance of x*_i from the
    position its neighbours were searched at [m]."""
    k = wp.tid()
    lo = k * chunk
    hi = wp.min(lo + chunk, correction_size.shape[0])
    largest = float(0.0)
    drift = float(0.0)
    for i in range(lo, hi):
        largest = wp.max(largest, correction_size[i])
        drift = wp.max(drift, wp.length(predicted_x[i] - neighbor_x[i]))
    partial_out[k, 0] = largest
    partial_out[k, 1] = drift


@wp.kernel(enable_backward=False)
def update_velocity(
    tid_offset: int,
    # Model:
    gravity: wp.vec3,
    inv_dt: float,
    # State in:
    predicted_x: wp.array(dtype=wp.vec3),
    # State in/out:
    particle_v: wp.array(dtype=wp.vec3),
    particle_x: wp.array(dtype=wp.vec3),
    # Out:
    particle_acceleration_out: wp.array(dtype=wp.vec3),
):
    """v = (x* - x) / dt; x = x*; a = (v_new - v_old) / dt [m/s^2] (v in holds v_old + dt g)."""
    i = wp.tid() + tid_offset
    x_new = predicted_x[i]
    v_new = (x_new - particle_x[i]) * inv_dt
    particle_acceleration_out[i] = (v_new - particle_v[i]) * inv_dt + gravity
    particle_v[i] = v_new
    particle_x[i] = x_new


@functools.cache
def viscous_kernel(smoothing: str, with_viscosity: bool, with_friction: bool, neighbors: str = "grid"):
    """Velocity change dt a [m/s] of explicit viscosity
    a_i = 10 nu sum_j (m/rho_j) (v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij (as WCSPH) and of
    Akinci boundary friction (report eq. 22-24, nu_b = sigma h c_s / (2 rho_i)); the friction part
    is clamped so it never reverses the particle's velocity, and m a_friction is added to the
    boundary force [N]."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]
    lists = neighbors == "list"
    Neighbors = NEIGHBOR_TYPES[neighbors]

    @wp.kernel(enable_backward=False, module="unique")
    def compute_viscous(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        viscosity: float,
        boundary_friction: float,
        speed_of_sound: float,
        dt: float,
        boundary_neighbors: Neighbors,
        boundary_x: wp.array(dtype=wp.vec3),
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
        if wp.static(with_friction):
            nu_b = boundary_friction * h * speed_of_sound / (2.0 * particle_density[i])
            a_f = wp.vec3(0.0)
            if wp.static(lists):
                k = int(0)
                k_end = int(neighbor_count(boundary_neighbors, i))
                while k < k_end:
                    b = boundary_neighbors.index[i, k]
                    x_ib = xi - boundary_x[b]
                    if wp.length(x_ib) < support_radius:
                        a_f += boundary_friction_acceleration(nu_b, rest_density * boundary_volume[b], vi, x_ib,
                                                              eps_h2, wp.static(gradient)(x_ib, h))
                    k += 1
            else:
                bquery = wp.hash_grid_query(boundary_neighbors, xi, support_radius)
                b = int(0)
                while wp.hash_grid_query_next(bquery, b):
                    x_ib = xi - boundary_x[b]
                    if wp.length(x_ib) < support_radius:
                        a_f += boundary_friction_acceleration(nu_b, rest_density * boundary_volume[b], vi, x_ib,
                                                              eps_h2, wp.static(gradient)(x_ib, h))
            dv_f = dt * a_f
            speed = wp.length(vi)
            size = wp.length(dv_f)
            if size > speed:
                dv_f = dv_f * (speed / size)
            dv += dv_f
            boundary_force_out[i] = boundary_force_out[i] + (particle_mass / dt) * dv_f
        viscous_dv_out[i] = dv

    return compute_viscous


@functools.cache
def vorticity_kernel(smoothing: str, neighbors: str = "grid"):
    """Vorticity omega_i = sum_j (m/rho_j) grad_i W_ij x (v_j - v_i) [1/s] (Macklin & Mueller 2013 eq. 15)."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]
    lists = neighbors == "list"
    Neighbors = NEIGHBOR_TYPES[neighbors]

    @wp.kernel(enable_backward=False, module="unique")
    def compute_vorticity(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        # State in:
        fluid_neighbors: Neighbors,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        # Out:
        particle_vorticity_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = particle_x[i]
        vi = particle_v[i]
        w = wp.vec3(0.0)
        if wp.static(lists):
            k = int(0)
            k_end = int(neighbor_count(fluid_neighbors, i))
            while k < k_end:
                j = fluid_neighbors.index[i, k]
                x_ij = xi - particle_x[j]
                if wp.length(x_ij) < support_radius:
                    w += (particle_mass / particle_density[j]) * wp.cross(
                        wp.static(gradient)(x_ij, smoothing_length), particle_v[j] - vi)
                k += 1
        else:
            query = wp.hash_grid_query(fluid_neighbors, xi, support_radius)
            j = int(0)
            while wp.hash_grid_query_next(query, j):
                x_ij = xi - particle_x[j]
                if wp.length(x_ij) < support_radius:
                    w += (particle_mass / particle_density[j]) * wp.cross(
                        wp.static(gradient)(x_ij, smoothing_length), particle_v[j] - vi)
        particle_vorticity_out[i] = w

    return compute_vorticity


@functools.cache
def confinement_kernel(smoothing: str, neighbors: str = "grid"):
    """Vorticity confinement (Macklin & Mueller 2013 eq. 16): eta = grad |omega| (SPH difference
    gradient), N = eta / |eta|, dv_i = dt vorticity v_ref (N x omega_i) [m/s]; v_ref [m/s] makes
    the strength dimensionless."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]
    lists = neighbors == "list"
    Neighbors = NEIGHBOR_TYPES[neighbors]

    @wp.kernel(enable_backward=False, module="unique")
    def compute_confinement(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        vorticity: float,
        reference_speed: float,
        dt: float,
        # State in:
        fluid_neighbors: Neighbors,
        particle_x: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        particle_vorticity: wp.array(dtype=wp.vec3),
        # Out:
        vorticity_dv_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = particle_x[i]
        wi = particle_vorticity[i]
        mag_i = wp.length(wi)
        eta = wp.vec3(0.0)
        if wp.static(lists):
            k = int(0)
            k_end = int(neighbor_count(fluid_neighbors, i))
            while k < k_end:
                j = fluid_neighbors.index[i, k]
                x_ij = xi - particle_x[j]
                if wp.length(x_ij) < support_radius:
                    eta += (particle_mass / particle_density[j] * (wp.length(particle_vorticity[j]) - mag_i)) * wp.static(
                        gradient)(x_ij, smoothing_length)
                k += 1
        else:
            query = wp.hash_grid_query(fluid_neighbors, xi, support_radius)
            j = int(0)
            while wp.hash_grid_query_next(query, j):
                x_ij = xi - particle_x[j]
                if wp.length(x_ij) < support_radius:
                    eta += (particle_mass / particle_density[j] * (wp.length(particle_vorticity[j]) - mag_i)) * wp.static(
                        gradient)(x_ij, smoothing_length)
        n = wp.length(eta)
        dv = wp.vec3(0.0)
        if n > 1.0e-12:
            dv = (dt * vorticity * reference_speed / n) * wp.cross(eta, wi)
        vorticity_dv_out[i] = dv

    return compute_confinement
