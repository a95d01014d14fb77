"""PBF's passes over neighbour lists (equations and units: ``kernels/pbf.py``): the cubic spline's value and
gradient without branches, the boundary's share of the density ratio and of grad_i C, the ``PairCache`` of the first
density pass (the pairs closer than H_s with V grad W_ij, also WCSPH's with grad W: ``wcsph_lists.py``), that pass
(density, C, lambda; its two halves shared with the fused search of ``pbf_search.py``) and the Jacobi correction from
the cache. The hash-grid reference variant of the two passes is in ``pbf_hash_grid.py``.
"""
import functools

import warp as wp

from .neighbors import NeighborList, NoBoundaryParams, neighbor_count, particle_in_cell_order
from .pbf import constraint_lambda
from .smoothing import PI, SMOOTHING_FUNCTIONS


@wp.func
def cubic_value_gradient_select(x_ij: wp.vec3, h: float) -> wp.vec4:
    """(W(|x_ij|, h), grad_i W) of the cubic spline [1/m^3, 1/m^4] without branches: with t2 = max(2 - q, 0) and
    t1 = max(1 - q, 0), W = a/6 (t2^3 - 4 t1^3) and dW/dq = a/6 (12 t1^2 - 3 t2^2), a = 3 / (2 pi h^3) (the
    two pieces of ``smoothing.cubic_value`` in one expression: equal to rounding; both 0 from q = 2 on). A
    list pass over pairs of random distances mispredicts the pieces' branches at about every other pair."""
    r = wp.length(x_ij)
    q = r / h
    t2 = wp.max(2.0 - q, 0.0)
    t1 = wp.max(1.0 - q, 0.0)
    a6 = 1.0 / (4.0 * PI * h * h * h)  # a / 6
    w = a6 * (t2 * t2 * t2 - 4.0 * t1 * t1 * t1)
    dwdq = a6 * (12.0 * t1 * t1 - 3.0 * t2 * t2)  # 0 at q = 0
    g = x_ij * (dwdq / (h * wp.max(r, 1.0e-30)))
    return wp.vec4(w, g[0], g[1], g[2])


@wp.func
def cubic_value_gradient_reciprocal(x_ij: wp.vec3, h: float) -> wp.vec4:
    """``cubic_value_gradient_select`` with one division per pair, off the value's path: q = r (1/h) (1/h hoisted
    out of a pair loop) and grad_i W = x_ij (a6 / h) (12 t1^2 - 3 t2^2) (1 / r), 1 / r formed beside the polynomial
    [1/m^3, 1/m^4]. Equal to ``cubic_value_gradient_select`` to a few rounding errors (the density to 4e-7 relative,
    dam break), not bitwise; the sqrt and the two divisions in a row of that form were the latency of PBF's pair
    passes (issue #32: the density pass's pair loop 1.85 -> 1.65 ms at 6,859 particles, one thread)."""
    r = wp.length(x_ij)
    inv_r = 1.0 / wp.max(r, 1.0e-30)
    inv_h = 1.0 / h
    q = r * inv_h
    t2 = wp.max(2.0 - q, 0.0)
    t1 = wp.max(1.0 - q, 0.0)
    a6 = 1.0 / (4.0 * PI * h * h * h)  # a / 6
    w = a6 * (t2 * t2 * t2 - 4.0 * t1 * t1 * t1)
    dwdr = (a6 * inv_h) * (12.0 * t1 * t1 - 3.0 * t2 * t2)  # dW/dr, 0 at q = 0
    g = x_ij * (dwdr * inv_r)
    return wp.vec4(w, g[0], g[1], g[2])


def pair_value_gradient_function(smoothing: str):
    """The ``@wp.func (x_ij, h) -> vec4(W, grad_i W)`` of PBF's passes over the fluid pairs (density, lambda,
    pair cache, the constraint pass at x: one expression for all): ``cubic_value_gradient_reciprocal`` for the
    cubic spline, else ``value_gradient_function``."""
    if smoothing == "cubic":
        return cubic_value_gradient_reciprocal
    return value_gradient_function(smoothing)


def value_gradient_function(smoothing: str):
    """A ``@wp.func (x_ij, h) -> vec4(W, grad_i W)`` for the smoothing kernel: the cubic spline's without
    branches (``cubic_value_gradient_select``: equal to ``smoothing.cubic_value`` and ``cubic_gradient`` to
    rounding; WCSPH's pair passes); the others call the kernel's value and gradient. PBF's passes take
    ``pair_value_gradient_function``."""
    if smoothing == "cubic":
        return cubic_value_gradient_select
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.func(module="unique")
    def value_gradient(x_ij: wp.vec3, h: float) -> wp.vec4:
        g = wp.static(gradient)(x_ij, h)
        return wp.vec4(wp.static(value)(wp.length(x_ij), h), g[0], g[1], g[2])

    return value_gradient


@functools.cache
def boundary_share_function(smoothing: str, boundary_terms):
    """A ``@wp.func (ratio, i, x_i, h, H^2, params, lists, x_b, V_b) -> vec4(ratio', g)``: the boundary's share
    of PBF's density ratio rho_i / rho0 (eq. 13: ratio' = ratio + sum_b term(W_ib, V_b), added in the lists'
    order so a kernel that sums its fluid part first gets bitwise the old inline sum) and of grad_i C
    (g = sum_b term(grad_i W_ib, V_b) [1/m], eq. 19) over particle i's boundary neighbours closer than H."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]
    BoundaryParams = boundary_terms.Params
    density_term, gradient_term = boundary_terms.density, boundary_terms.gradient

    @wp.func(module="unique")
    def boundary_share(ratio: float, i: int, xi: wp.vec3, h: float, support2: float, boundary_params: BoundaryParams,
                       boundary_neighbors: NeighborList, boundary_x: wp.array(dtype=wp.vec3),
                       boundary_volume: wp.array(dtype=float)) -> wp.vec4:
        grad_b = wp.vec3(0.0)
        k = int(0)
        k_end = int(neighbor_count(boundary_neighbors, i))
        while k < k_end:
            b = boundary_neighbors.index[i, k]
            x_ib = xi - boundary_x[b]
            if wp.dot(x_ib, x_ib) < support2:
                vb = boundary_volume[b]
                ratio += wp.static(density_term)(boundary_params, wp.static(value)(wp.length(x_ib), h), vb)
                grad_b += wp.static(gradient_term)(boundary_params, wp.static(gradient)(x_ib, h), vb)
            k += 1
        return wp.vec4(ratio, grad_b[0], grad_b[1], grad_b[2])

    return boundary_share


@wp.struct
class PairCache:
    """Pairs of the last density pass, for the correction at the same positions (lists only).

    Row t holds the pairs of particle i = order[t], the particle that thread t of the list passes visits
    (``particle_in_cell_order``): the passes then stream through the rows in memory order. count[t]: pairs closer
    than the support radius, shape (fluid_count,); index[t, k]: neighbour j; gradient[t, k] = V grad_i W_ij [1/m];
    value[t, k] = W_ij [1/m^3] (s_corr only, else shape (1, 1)); boundary_gradient[i] = sum_b V_b grad_i W_ib
    [1/m] (by particle). The 2-D arrays have the fluid list's capacity per row.
    """

    count: wp.array(dtype=wp.int32)
    index: wp.array2d(dtype=wp.int32)
    gradient: wp.array2d(dtype=wp.vec3)
    value: wp.array2d(dtype=float)
    boundary_gradient: wp.array(dtype=wp.vec3)


@functools.cache
def density_lambda_functions(smoothing: str, boundary_terms, tensile: bool):
    """(cached_pair_sums, write_density_lambda): the two halves of PBF's first density pass that the list pass
    (``density_lambda_pairs_kernel``) and the fused search (``pbf_search.search_density_lambda_kernel``) share, so
    the two stay bitwise one another's.

    cached_pair_sums(t, pair_count, x_i, h, V, predicted_x, pairs) -> (sum_j W_ij [1/m^3], grad_i C = sum_j
    V grad_i W_ij [1/m], sum_j |V grad_i W_ij|^2 [1/m^2]) over the pairs already in row t of the ``PairCache``
    (index[t, k < pair_count]), in the row's order; stores V grad_i W_ij [and W_ij with ``tensile``] beside them.

    write_density_lambda(...): from those sums and the boundary's share (eq. 13 and 19), the row's pair count, the
    boundary gradient, density rho_i = rho0 (V sum_j W_ij + boundary) [kg/m^3], C_i (eq. 17) and lambda_i (eq. 19)."""
    value_gradient = pair_value_gradient_function(smoothing)
    with_boundary = boundary_terms is not None and boundary_terms.density is not None
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    boundary_share = boundary_share_function(smoothing, boundary_terms) if with_boundary else None

    @wp.func(module="unique")
    def cached_pair_sums(t: int, pair_count: int, xi: wp.vec3, h: float, volume: float,
                         predicted_x: wp.array(dtype=wp.vec3), pairs_out: PairCache):
        w_sum = float(0.0)
        grad_i = wp.vec3(0.0)
        grad_sq = float(0.0)
        k = int(0)
        while k < pair_count:
            x_ij = xi - predicted_x[pairs_out.index[t, k]]
            wg = wp.static(value_gradient)(x_ij, h)
            w = wg[0]
            w_sum += w
            g = volume * wp.vec3(wg[1], wg[2], wg[3])
            grad_i += g
            grad_sq += wp.dot(g, g)
            pairs_out.gradient[t, k] = g
            if wp.static(tensile):
                pairs_out.value[t, k] = w
            k += 1
        return w_sum, grad_i, grad_sq

    @wp.func(module="unique")
    def write_density_lambda(
        t: int,
        i: int,
        xi: wp.vec3,
        pair_count: int,
        w_sum: float,
        grad_fluid: wp.vec3,
        grad_sq: float,
        # Model:
        volume: float,
        h: float,
        support2: float,
        rest_density: float,
        relaxation_epsilon: float,
        boundary_params: BoundaryParams,
        boundary_neighbors: NeighborList,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        constraint_offset: wp.array(dtype=float),
        # Out:
        pairs_out: PairCache,
        particle_density_out: wp.array(dtype=float),
        particle_lambda_out: wp.array(dtype=float),
        particle_constraint_out: wp.array(dtype=float),
    ):
        pairs_out.count[t] = pair_count
        ratio = volume * w_sum
        grad_b = wp.vec3(0.0)
        if wp.static(with_boundary):
            rb = wp.static(boundary_share)(ratio, i, xi, h, support2, boundary_params, boundary_neighbors, boundary_x,
                                           boundary_volume)
            ratio = rb[0]
            grad_b = wp.vec3(rb[1], rb[2], rb[3])
        pairs_out.boundary_gradient[i] = grad_b
        grad_i = grad_fluid + grad_b
        c_lam = constraint_lambda(ratio - constraint_offset[i], grad_i, grad_sq, relaxation_epsilon)
        particle_density_out[i] = rest_density * ratio
        particle_lambda_out[i] = c_lam[1]
        particle_constraint_out[i] = c_lam[0]

    return cached_pair_sums, write_density_lambda


@functools.cache
def density_lambda_pairs_kernel(smoothing: str, boundary_terms, tensile: bool):
    """Density (eq. 7/13), constraint C (eq. 17) and Lagrange multiplier lambda (eq. 19) at the
    predicted positions over neighbour lists; keeps what the correction needs at these positions in a
    ``PairCache``: the pairs within the support radius (the lists hold a margin more) with
    V grad W_ij [and W_ij], and the boundary gradient sum. boundary_terms: the boundary method's
    ``BoundaryTerms`` (its density and gradient terms; None or without them: fluid only)."""
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    cached_pair_sums, write_density_lambda = density_lambda_functions(smoothing, boundary_terms, tensile)

    @wp.kernel(enable_backward=False, module="unique")
    def compute_density_lambda_pairs(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        relaxation_epsilon: float,
        boundary_params: BoundaryParams,
        boundary_neighbors: NeighborList,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: NeighborList,
        predicted_x: wp.array(dtype=wp.vec3),
        constraint_offset: wp.array(dtype=float),
        # Out:
        particle_density_out: wp.array(dtype=float),
        particle_lambda_out: wp.array(dtype=float),
        particle_constraint_out: wp.array(dtype=float),
        pairs_out: PairCache,
    ):
        t = wp.tid() + tid_offset  # the pair cache's row
        i = particle_in_cell_order(fluid_neighbors, t)
        xi = predicted_x[i]
        h = smoothing_length
        support2 = support_radius * support_radius
        volume = particle_mass / rest_density
        # the listed pairs closer than H_s into the cache's index row without a branch per pair (each listed j is
        # written at the next free slot, which only those pairs advance), then their terms in the same order
        n = int(0)
        k = int(0)
        k_end = int(neighbor_count(fluid_neighbors, i))
        while k < k_end:
            j = fluid_neighbors.index[i, k]
            x_ij = xi - predicted_x[j]
            pairs_out.index[t, n] = j  # (n <= k: within the row)
            n += wp.where(wp.dot(x_ij, x_ij) < support2, 1, 0)
            k += 1
        w_sum, grad_i, grad_sq = cached_pair_sums(t, n, xi, h, volume, predicted_x, pairs_out)
        write_density_lambda(t, i, xi, n, w_sum, grad_i, grad_sq, volume, h, support2, rest_density, relaxation_epsilon,
                             boundary_params, boundary_neighbors, boundary_x, boundary_volume, constraint_offset,
                             pairs_out, particle_density_out, particle_lambda_out, particle_constraint_out)

    return compute_density_lambda_pairs


@functools.cache
def correction_pairs_kernel(with_boundary: bool, tensile: bool, with_pressure_term: bool = False):
    """Jacobi correction (eq. 18) from a ``PairCache`` of the density pass at the same positions:
    dx_i = sum_j (lambda_i + lambda_j + s_corr_ij) V grad W_ij + lambda_i sum_b V_b grad W_ib, no
    kernel evaluation (the smoothing kernel entered through the cache). Same outputs as
    ``correction_kernel``, and x*_i += dx_i in place (``apply_correction``'s sum: no thread reads
    another's position, the pairs came from the cache). with_pressure_term: also add pressure_term_scale lambda_i to
    ``boundary_pressure_term`` (moving bodies: with scale -1 / (rho0 dt^2) the walls' acceleration
    lambda_i V_b grad W_ib / dt^2 of i is the Akinci pressure term -rho0 V_b term_i grad W_ib)."""

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
        pressure_term_scale: float,
        # State in:
        fluid_neighbors: NeighborList,
        pairs: PairCache,
        particle_lambda: wp.array(dtype=float),
        # Out:
        position_correction_out: wp.array(dtype=wp.vec3),
        boundary_force_out: wp.array(dtype=wp.vec3),
        correction_size_out: wp.array(dtype=float),
        boundary_pressure_term_out: wp.array(dtype=float),
        predicted_x: wp.array(dtype=wp.vec3),
    ):
        t = wp.tid() + tid_offset  # the pair cache's row
        i = particle_in_cell_order(fluid_neighbors, t)
        lam_i = particle_lambda[i]
        dx = wp.vec3(0.0)
        k = int(0)
        k_end = int(pairs.count[t])
        while k < k_end:
            s = lam_i + particle_lambda[pairs.index[t, k]]
            if wp.static(tensile):
                s -= tensile_k * wp.pow(pairs.value[t, k] * tensile_inv_w, float(tensile_n)) * tensile_scale
            dx += s * pairs.gradient[t, k]
            k += 1
        if wp.static(with_boundary):
            dx_b = lam_i * pairs.boundary_gradient[i]
            dx += dx_b
            boundary_force_out[i] = boundary_force_out[i] + (particle_mass * inv_dt2) * dx_b
            if wp.static(with_pressure_term):
                boundary_pressure_term_out[i] = boundary_pressure_term_out[i] + pressure_term_scale * lam_i
        size = wp.length(dx)
        if size > max_step:
            dx = dx * (max_step / size)
        position_correction_out[i] = dx
        correction_size_out[i] = size
        predicted_x[i] = predicted_x[i] + dx

    return compute_correction_pairs
