"""The conjugate-gradient iteration of the implicit viscosity solve (``weiler2018.py``): the float64 control
array (slots ``CONTROL_*``) that a device updates between iterations, the update and direction passes, and the
chunked dot products finished in a fixed order (bitwise reproducible for any CPU thread count). Every
iteration kernel returns at once when the control array says done. Host half:
``warp_sph/methods/forces/weiler2018.py``.
"""
import warp as wp

from .neighbors import NeighborList, particle_in_cell_order

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
