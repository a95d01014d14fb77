"""DFSPH's Jacobi solves on the device (equations, notation and units: ``kernels/dfsph.py``; host:
``warp_sph/methods/solvers/dfsph_solve.py``): the solve's control array, the Chebyshev weight, one sweep (the pressure
acceleration a(P), the Jacobi update, the error chunks, ``solve_control``: the stop test by one thread), the end on
the target's crossing (``finish_sweeps``) and the stabilisation's source and position shift.

Kernels taking ``tid_offset`` are split over CPU cores and write only their own particle (no atomics); the iteration
kernels take the solve's ``control`` array and return at once when it says the solve is done.
"""
import warp as wp

from .dfsph import pair_pressure_acceleration
from .dfsph_search import DfsphPairs
from .neighbors import NeighborList, particle_in_cell_order

# slots of a solve's control array (float64)
CONTROL_DONE = 0        # 1 once the stop test passed or max_iterations ran
CONTROL_ITERATIONS = 1  # iterations run
CONTROL_ERROR = 2       # mean error of the last iteration (before its update) [-] or [1/s]
CONTROL_WEIGHT = 3      # Chebyshev weight of the next sweep (1: plain Jacobi)
CONTROL_SWEEP = 4       # sweeps run (the index of the next one)
CONTROL_LAST_WEIGHT = 5 # weight the last sweep applied
CONTROL_LAST_ERROR = 6  # mean error of the iteration before the last [-] or [1/s]
CONTROL_FRACTION = 7    # share theta of the last sweep's update the solve keeps (``finish_sweeps``)
CONTROL_COUNT = 8
#: plain Jacobi sweeps before the Chebyshev acceleration starts (Wang 2015: a few)
CHEBYSHEV_DELAY = 2


@wp.func
def chebyshev_weight(sweep: float, rho: float, last: float) -> float:
    """Weight of sweep ``sweep`` (0-based) of the Chebyshev
    semi-iterative method (Wang 2015, eq. 12) for a sweep of spectral radius rho: 1 for the first
    CHEBYSHEV_DELAY sweeps or rho = 0, then 2 / (2 - rho^2), then 4 / (4 - rho^2 w_last)."""
    if rho <= 0.0 or sweep < float(CHEBYSHEV_DELAY):
        return 1.0
    if sweep == float(CHEBYSHEV_DELAY):
        return 2.0 / (2.0 - rho * rho)
    return 4.0 / (4.0 - rho * rho * last)


@wp.kernel(enable_backward=False)
def pressure_acceleration(
    tid_offset: int,
    # In:
    fluid_neighbors: NeighborList,
    pairs: DfsphPairs,
    pressure: wp.array(dtype=float),
    control: wp.array(dtype=wp.float64),
    # Out:
    acceleration_out: wp.array(dtype=wp.vec3),
):
    """First pass of a Jacobi sweep: a_i(P) [m/s^2]; nothing once ``control`` says done."""
    if control[CONTROL_DONE] != wp.float64(0.0):
        return
    i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
    acceleration_out[i] = pair_pressure_acceleration(pairs, pressure, i)


@wp.kernel(enable_backward=False)
def jacobi_update(
    tid_offset: int,
    # In:
    fluid_neighbors: NeighborList,
    pairs: DfsphPairs,
    factor: wp.array(dtype=float),
    source: wp.array(dtype=float),
    acceleration: wp.array(dtype=wp.vec3),
    scale: float,
    relaxation: float,
    active_only: int,
    control: wp.array(dtype=wp.float64),
    keep_previous: int,
    # In/out:
    pressure: wp.array(dtype=float),
    previous: wp.array(dtype=float),
    # Out:
    error_out: wp.array(dtype=float),
):
    """Second pass of a Jacobi sweep: (A P)_i = scale delta_i(a), r_i = b_i - (A P)_i, error
    max(-r_i, 0) (0 for inactive particles when ``active_only``), P^J_i = max(0, P_i - omega f_i r_i /
    scale); with the Chebyshev weight w = control[CONTROL_WEIGHT] != 1 (Wang 2015) P_i <- max(0, Q_i +
    w (P^J_i - Q_i)), Q the P of the sweep before, else P_i <- P^J_i; Q_i <- the old P_i when
    ``keep_previous`` (the accelerated solve; plain Jacobi never reads Q). Reads only its own P_i, so
    P is updated in place."""
    if control[CONTROL_DONE] != wp.float64(0.0):
        return
    i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
    ai = acceleration[i]
    div = wp.dot(ai, pairs.gradient_sum[i])
    k = pairs.offset[i]
    k_end = k + pairs.count[i]
    while k < k_end:
        div -= wp.dot(acceleration[pairs.index[k]], pairs.gradient[k])
        k += 1
    r = source[i] - scale * div
    p = pressure[i]
    e = wp.max(-r, 0.0)
    if active_only != 0 and pairs.active[i] == 0:
        e = 0.0
    error_out[i] = e
    pj = wp.max(p - relaxation * factor[i] * r / scale, 0.0)
    chebyshev = float(control[CONTROL_WEIGHT])
    if chebyshev != 1.0:
        q = previous[i]
        pj = wp.max(q + chebyshev * (pj - q), 0.0)
    if keep_previous != 0:
        previous[i] = p
    pressure[i] = pj


@wp.kernel(enable_backward=False)
def error_chunks(
    chunk: int,
    # In:
    error: wp.array(dtype=float),
    control: wp.array(dtype=wp.float64),
    # Out:
    partial_out: wp.array(dtype=float),
):
    """partial_out[k] = sum of error over chunk k, in index order; nothing once done."""
    if control[CONTROL_DONE] != wp.float64(0.0):
        return
    k = wp.tid()
    lo = k * chunk
    hi = wp.min(lo + chunk, error.shape[0])
    s = float(0.0)
    for i in range(lo, hi):
        s += error[i]
    partial_out[k] = s


@wp.kernel(enable_backward=False)
def solve_control(
    # In:
    partial: wp.array(dtype=float),
    count: int,
    target: float,
    min_iterations: int,
    max_iterations: int,
    rho: float,
    continuous: int,
    # In/out:
    control: wp.array(dtype=wp.float64),
):
    """One thread: mean error = sum(partial) / count (float64, fixed order); iterations += 1; done
    when (error <= target and iterations >= min_iterations) or iterations >= max_iterations.
    Chebyshev (rho > 0): the weight of the next sweep; the weight this sweep applied is kept.
    Once done, the share theta of the last sweep's update P_k - P_(k-1) the solve keeps (``finish_sweeps``):
    ``continuous`` and the stop test first passed at this iteration k > min_iterations (errors E_(k-1) >
    target >= E_k, each measured with P before the iteration's update): theta = (E_(k-1) - target) /
    (E_(k-1) - E_k), the linear crossing of the target, so the pressure the solve returns is a continuous
    function of the fluid's state where the sweep count changes (P_(k-1) + theta (P_k - P_(k-1)) tends
    to P_k from both sides). Else theta = 1, or 0 after a Chebyshev-weighted last sweep without
    ``continuous`` (its extrapolated update is not checked)."""
    if control[CONTROL_DONE] != wp.float64(0.0):
        return
    s = wp.float64(0.0)
    for k in range(partial.shape[0]):
        s += wp.float64(partial[k])
    err = s / wp.float64(wp.max(count, 1))
    it = control[CONTROL_ITERATIONS] + wp.float64(1.0)
    control[CONTROL_ITERATIONS] = it
    last_err = control[CONTROL_ERROR]
    control[CONTROL_LAST_ERROR] = last_err
    control[CONTROL_ERROR] = err
    w = control[CONTROL_WEIGHT]
    control[CONTROL_LAST_WEIGHT] = w
    if rho > 0.0:
        sweep = control[CONTROL_SWEEP] + wp.float64(1.0)
        control[CONTROL_SWEEP] = sweep
        control[CONTROL_WEIGHT] = wp.float64(chebyshev_weight(float(sweep), rho, float(w)))
    t = wp.float64(target)
    if (err <= t and it >= wp.float64(min_iterations)) or it >= wp.float64(max_iterations):
        control[CONTROL_DONE] = wp.float64(1.0)
        theta = wp.float64(1.0)
        if continuous != 0:
            if err <= t and it > wp.float64(min_iterations) and last_err > t:
                theta = (last_err - t) / (last_err - err)
        elif w != wp.float64(1.0):
            theta = wp.float64(0.0)
        control[CONTROL_FRACTION] = theta


@wp.kernel(enable_backward=False)
def reset_control(control_out: wp.array(dtype=wp.float64)):
    """A solve starts: not done, no iterations, no error, plain weights."""
    for k in range(CONTROL_COUNT):
        control_out[k] = wp.float64(0.0)
    control_out[CONTROL_WEIGHT] = wp.float64(1.0)
    control_out[CONTROL_LAST_WEIGHT] = wp.float64(1.0)
    control_out[CONTROL_FRACTION] = wp.float64(1.0)


@wp.kernel(enable_backward=False)
def finish_sweeps(
    tid_offset: int,
    # In:
    fluid_neighbors: NeighborList,
    control: wp.array(dtype=wp.float64),
    previous: wp.array(dtype=float),
    # In/out:
    pressure: wp.array(dtype=float),
):
    """After a solve that kept Q = P_(k-1): P_i <- Q_i + theta (P_i - Q_i), theta = control[CONTROL_FRACTION]
    (``solve_control``; nothing when theta = 1). A mix of two non-negative P stays non-negative."""
    theta = float(control[CONTROL_FRACTION])
    if theta == 1.0:
        return
    i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
    q = previous[i]
    pressure[i] = q + theta * (pressure[i] - q)


@wp.kernel(enable_backward=False)
def stabilize_source(
    tid_offset: int,
    # Model:
    rest_density: float,
    # In:
    fluid_neighbors: NeighborList,
    particle_density: wp.array(dtype=float),
    # Out:
    source_out: wp.array(dtype=float),
    pressure_out: wp.array(dtype=float),
):
    """Source of a position correction at rest: b_i = 1 - rho_hat_i [-], P_i = 0."""
    i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
    source_out[i] = 1.0 - particle_density[i] / rest_density
    pressure_out[i] = 0.0


@wp.kernel(enable_backward=False)
def shift_positions(
    tid_offset: int,
    # In:
    fluid_neighbors: NeighborList,
    pairs: DfsphPairs,
    pressure: wp.array(dtype=float),
    max_shift: float,
    # State in/out:
    particle_x: wp.array(dtype=wp.vec3),
):
    """Position correction without velocity: x_i += a_i(P) [m] (P solved with scale 1, so P is in
    m^2), its length capped at ``max_shift`` [m]."""
    i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
    dx = pair_pressure_acceleration(pairs, pressure, i)
    size = wp.length(dx)
    if size > max_shift:
        dx = dx * (max_shift / size)
    particle_x[i] = particle_x[i] + dx
