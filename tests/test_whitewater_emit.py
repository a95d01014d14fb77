"""Whitewater's emission pass runs one thread per new particle (``kernels/whitewater.emit_kernel``): each
thread finds the fluid slot its particle belongs to by a binary search of the counts' exclusive scan
(``emitting_slot``), checked here against NumPy's searchsorted on counts with runs of zeros."""
import numpy as np
import warp as wp

from warp_sph.kernels.whitewater import emitting_slot


@wp.kernel(enable_backward=False)
def _slots(n: int, offset: wp.array(dtype=wp.int32), out: wp.array(dtype=wp.int32)):
    k = wp.tid()
    out[k] = emitting_slot(k, n, offset)


def test_emitting_slot_matches_searchsorted():
    rng = np.random.default_rng(7)
    for n in (1, 2, 5, 1000):
        counts = rng.integers(0, 4, size=n) * (rng.random(n) < 0.3)  # mostly zeros
        counts[-1] = 2  # a last slot that emits (its threads end the range)
        if n > 2:
            counts[0] = 0  # and a first that does not
        offset = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)
        total = int(counts.sum())
        out = wp.zeros(total, dtype=wp.int32, device="cpu")
        wp.launch(_slots, total, inputs=[n, wp.array(offset, dtype=wp.int32, device="cpu")], outputs=[out],
                  device="cpu")
        want = np.searchsorted(offset, np.arange(total), side="right") - 1
        got = out.numpy()
        assert np.array_equal(got, want)
        assert np.all(counts[got] > 0)  # every new particle belongs to a slot that generates
        assert np.array_equal(np.bincount(got, minlength=n), counts)  # each slot gets exactly its count
