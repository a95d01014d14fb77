"""Sums over particles in a fixed order: bitwise reproducible for any CPU thread count (no atomics)."""
import warp as wp

REDUCE_CHUNK = 256  # particles per partial sum / maximum (fixed: results do not depend on the thread count)


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
def max_speed_chunks(
    chunk: int,
    # In:
    velocity: wp.array(dtype=wp.vec3),
    # Out:
    partial_out: wp.array(dtype=float),
):
    """partial_out[k] = the largest |v|^2 [m^2/s^2] of velocity[k chunk .. (k + 1) chunk - 1]."""
    k = wp.tid()
    lo = k * chunk
    hi = wp.min(lo + chunk, velocity.shape[0])
    s = float(0.0)
    for i in range(lo, hi):
        s = wp.max(s, wp.length_sq(velocity[i]))
    partial_out[k] = s
