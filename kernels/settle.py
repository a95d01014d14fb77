"""The packing pass before t = 0 (``warp_sph.run.settle``): the fluid's mean speed, then its velocity damped."""
import warp as wp


@wp.kernel(enable_backward=False)
def speed_sum_and_damp(
    chunk: int,
    keep: float,
    # In / out:
    velocity: wp.array(dtype=wp.vec3),
    # Out:
    partial_out: wp.array(dtype=float),
):
    """partial_out[k] = sum of |v_i| [m/s] over i in [k chunk, (k + 1) chunk), summed in index order (bitwise
    reproducible for any thread count); then v_i = keep v_i (keep in [0, 1): the damping of the pass)."""
    k = wp.tid()
    lo = k * chunk
    hi = wp.min(lo + chunk, velocity.shape[0])
    s = float(0.0)
    for i in range(lo, hi):
        v = velocity[i]
        s += wp.length(v)
        velocity[i] = keep * v
    partial_out[k] = s
