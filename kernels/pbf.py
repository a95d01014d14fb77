"""Position-based fluids (Macklin & Mueller 2013) with the seed report's equations 17-20.

Units (SPlisHSPlasH convention, physics notes section 4): V = m / rho0 [m^3] is the rest volume of
a fluid particle, V_b the Akinci volume of a boundary particle [m^3];

    rho_i / rho0 = V sum_j W_ij + sum_b V_b W_ib                        (report eq. 7/13)
    C_i          = max(rho_i / rho0 - 1 - o_i, 0)                       (eq. 17)         [-]
                   (o_i: the share of the error at x left to later steps, ``constraint_offset``)
    grad_j C_i   = -V grad_i W_ij,  grad_i C_i = V sum_j grad_i W_ij + sum_b V_b grad_i W_ib
                                                                        (eq. 20)         [1/m]
    lambda_i     = -C_i / (|grad_i C_i|^2 + sum_j |grad_j C_i|^2 + eps) (eq. 19)         [m^2]
    dx_i         = sum_j V (lambda_i + lambda_j + s_corr_ij) grad_i W_ij
                   + lambda_i sum_b V_b grad_i W_ib                     (eq. 18)         [m]

The boundary enters through the boundary method's terms (``kernels/boundary.py``; Akinci: V_b W_ib
and V_b grad W_ib). Boundary particles are not corrected, so they are left out of the sum over k of
|grad_k C_i|^2 but kept in grad_i C_i (SPlisHSPlasH). The position correction of particle i by the walls, over dt^2 and
times m, is the force of the walls on it (physics notes 2.1); its negative sums to the wall load.

This file: the per-particle kernels (prediction, the constraint and its lambda, applying the correction, the
velocity update). The passes over neighbour lists, which take the smoothing kernel and the neighbour iteration as
compile-time choices (factory + ``wp.static``), are in ``pbf_pairs.py`` (neighbour lists built once per step with a
search radius enlarged by a margin; the density pass fills a ``PairCache`` that the correction reads), the fused
search in ``pbf_search.py`` and the hash-grid reference variant in ``pbf_hash_grid.py``. Every particle-parallel
kernel takes ``tid_offset``
first (split over CPU cores by ``warp_sph.launch``) and writes only its own particle: no atomics
(CPU atomics are plain read-modify-writes, racy across split ranges). Sums and maxima over the
particles come from per-particle values reduced chunk by chunk (``sum_chunks``,
``max_correction_drift_chunks``) in a fixed order, so they are bitwise reproducible.
"""
import warp as wp

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


@wp.kernel(enable_backward=False)
def clear_float(
    tid_offset: int,
    # Out:
    values_out: wp.array(dtype=float),
):
    """values = 0 (the per-step boundary pressure term of moving bodies)."""
    values_out[wp.tid() + tid_offset] = 0.0


@wp.func
def constraint_lambda(ratio: float, grad_i: wp.vec3, grad_sq: float, relaxation_epsilon: float) -> wp.vec2:
    """(C_i, lambda_i) from rho_i/rho0, grad_i C_i and sum_j |grad_j C_i|^2 (eq. 17, 19)."""
    c = wp.max(ratio - 1.0, 0.0)
    lam = float(0.0)
    if c > 0.0:
        lam = -c / (wp.dot(grad_i, grad_i) + grad_sq + relaxation_epsilon)
    return wp.vec2(c, lam)


@wp.kernel(enable_backward=False)
def constraint_offset(
    tid_offset: int,
    # Model:
    keep: float,
    # In:
    particle_constraint: wp.array(dtype=float),
    # Out:
    constraint_offset_out: wp.array(dtype=float),
):
    """o_i = keep C_i [-]: the share of the error C_i at x (the step's start) that this step leaves to later
    ones (keep = 1 - s, s the Baumgarte share ``Solver.error_share``)."""
    i = wp.tid() + tid_offset
    constraint_offset_out[i] = keep * particle_constraint[i]


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
    dt: float,
    inv_dt: float,
    # State in:
    predicted_x: wp.array(dtype=wp.vec3),
    # State in/out:
    particle_v: wp.array(dtype=wp.vec3),
    particle_x: wp.array(dtype=wp.vec3),
    # Out:
    particle_acceleration_out: wp.array(dtype=wp.vec3),
):
    """v = (x* - x) / dt; x = x*; a = (v_new - v_old) / dt [m/s^2] (v in holds v_old + dt g). The
    velocity is formed as v + (x* - x*_pred) / dt, with x*_pred = x + dt v recomputed as
    ``predict_positions`` formed it: equal in exact arithmetic, but it keeps v to float32 precision
    where (x* - x) / dt would round it to ulp(x) / dt (at dt = 1e-5 s and |x| = 0.3 m, 3 mm/s: gravity's
    g dt^2 is below ulp(x) / 2, so a block would not start to fall)."""
    i = wp.tid() + tid_offset
    x_new = predicted_x[i]
    v = particle_v[i]
    x_pred = particle_x[i] + dt * v
    v_new = v + (x_new - x_pred) * inv_dt
    particle_acceleration_out[i] = (v_new - particle_v[i]) * inv_dt + gravity
    particle_v[i] = v_new
    particle_x[i] = x_new
