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
