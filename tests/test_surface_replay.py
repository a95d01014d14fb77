"""Replayed surface launches (warp_sph/surface/replay.py): a recording reused with new sizes, new
arrays and new scalars gives what a fresh launch gives, split over threads or not."""
import numpy as np
import pytest
import warp as wp

from warp_sph.kernels import surface_smoothing as _dev
from warp_sph.surface.replay import replay


@pytest.mark.parametrize("threads", [1, 2])
def test_replay_follows_new_sizes_arrays_and_scalars(monkeypatch, threads):
    """x_v += offset w_v n_v (offset_along_normals) through one recording, over a sequence of calls
    that change the size, swap arrays and change the scalar: each call must match NumPy on
    [0, dim) and leave the rest of the array alone."""
    monkeypatch.setenv("WARP_SPH_CPU_THREADS", str(threads))
    rng = np.random.default_rng(7)
    n = 64
    weights = [rng.random(n).astype(np.float32) for _ in range(2)]
    normals = [rng.standard_normal((n, 3)).astype(np.float32) for _ in range(2)]
    w = [wp.array(a, dtype=float, device="cpu") for a in weights]
    nrm = [wp.array(a, dtype=wp.vec3, device="cpu") for a in normals]
    x0 = rng.standard_normal((n, 3)).astype(np.float32)
    x = wp.array(x0, dtype=wp.vec3, device="cpu")
    expected = x0.copy()
    tag = object()  # a call site of its own
    for dim, offset, k in [(40, 0.5, 0), (40, 0.5, 0), (17, 0.5, 0), (17, -2.0, 1), (64, 3.0, 0), (9, 1.0, 1)]:
        replay(_dev.offset_along_normals, dim, [offset, w[k], nrm[k]], [x], "cpu", 4, tag)
        expected[:dim] += (np.float32(offset) * weights[k][:dim])[:, None] * normals[k][:dim]
        np.testing.assert_allclose(x.numpy(), expected, rtol=1e-6, atol=1e-6)
