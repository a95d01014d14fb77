"""``kernels/pair_sum.neighbor_sum``: the one neighbour loop of the explicit forces, over neighbour lists
and over a hash grid, against a NumPy brute-force sum (pairs closer than H; with or without j = i)."""
import functools

import numpy as np
import pytest
import warp as wp

from warp_sph.kernels import neighbors as _nb
from warp_sph.kernels.pair_sum import neighbor_sum

H = 0.3


@wp.struct
class WeightPairs:
    weight: wp.array(dtype=float)


@wp.func
def weighted_pair(d: WeightPairs, i: int, j: int, x_ij: wp.vec3) -> wp.vec3:
    """w_j x_ij + (i, j) as a vector, so that a missing, doubled or foreign pair shows."""
    return d.weight[j] * x_ij + wp.vec3(0.0, 0.0, 1.0e-3 * float(j + 1))


@functools.cache
def sum_kernel(neighbors: str, skip_self: bool):
    Neighbors = {"list": _nb.NeighborList, "grid": wp.uint64}[neighbors]
    total = neighbor_sum(weighted_pair, WeightPairs, neighbors, skip_self)

    @wp.kernel(enable_backward=False, module="unique")
    def run(pair_neighbors: Neighbors, x: wp.array(dtype=wp.vec3), weight: wp.array(dtype=float),
            support_radius: float, out: wp.array(dtype=wp.vec3)):
        i = wp.tid()
        d = WeightPairs()
        d.weight = weight
        out[i] = wp.static(total)(pair_neighbors, x, i, x[i], support_radius, d)

    return run


@pytest.mark.parametrize("neighbors", ["list", "grid"])
@pytest.mark.parametrize("skip_self", [False, True])
def test_neighbor_sum_matches_brute_force(neighbors, skip_self):
    rng = np.random.default_rng(3)
    x = rng.uniform(0.0, 1.0, (300, 3)).astype(np.float32)
    w = rng.uniform(0.5, 2.0, 300).astype(np.float32)
    x_ij = x[:, None, :].astype(np.float64) - x[None, :, :]
    near = np.linalg.norm(x_ij, axis=2) < H
    if skip_self:
        np.fill_diagonal(near, False)
    pair = w[None, :, None] * x_ij
    pair[..., 2] += 1e-3 * (np.arange(300) + 1)[None, :]
    expected = (pair * near[..., None]).sum(axis=1)

    device = "cpu"
    xs = wp.array(x, dtype=wp.vec3, device=device)
    if neighbors == "list":
        # lists hold every point within 1.5 H (as the step's lists hold a skin), in shuffled order
        listed = np.linalg.norm(x_ij, axis=2) < 1.5 * H
        capacity = int(listed.sum(axis=1).max())
        index = np.zeros((300, capacity), dtype=np.int32)
        for i in range(300):
            js = rng.permutation(np.flatnonzero(listed[i]))
            index[i, :len(js)] = js
        nl = _nb.NeighborList()
        nl.count = wp.array(listed.sum(axis=1).astype(np.int32), dtype=wp.int32, device=device)
        nl.index = wp.array(index, dtype=wp.int32, device=device)
        nl.order = wp.array(np.arange(300, dtype=np.int32), dtype=wp.int32, device=device)
        arg = nl
    else:
        grid = wp.HashGrid(8, 8, 8, device=device)
        grid.build(xs, H)
        arg = grid.id
    out = wp.zeros(300, dtype=wp.vec3, device=device)
    wp.launch(sum_kernel(neighbors, skip_self), dim=300, device=device,
              inputs=[arg, xs, wp.array(w, dtype=float, device=device), H, out])
    np.testing.assert_allclose(out.numpy(), expected, rtol=1e-5, atol=2e-5)
