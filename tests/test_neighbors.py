"""Hash-grid neighbour search equals brute force, at negative coordinates and far from the origin."""
import numpy as np
import pytest
import warp as wp

from warp_sph.neighbors import NeighborGrid, neighbor_lists


@pytest.mark.parametrize("offset", [0.0, -3.7, 1.0e2, -1.0e3, 1.0e4])
def test_matches_brute_force(offset, device):
    rng = np.random.default_rng(int(abs(offset)) + 7)
    radius = 0.1
    pts = (rng.uniform(-0.6, 0.6, (1500, 3)) + offset).astype(np.float32)
    x = wp.array(pts, dtype=wp.vec3, device=device)
    grid = NeighborGrid(radius, device=device)
    grid.build(x)
    counts, lists = neighbor_lists(grid, x, x)
    diff = pts[:, None, :].astype(np.float64) - pts[None, :, :].astype(np.float64)
    dist = np.linalg.norm(diff, axis=2)
    ambiguous = np.abs(dist - radius) < 1e-5 * max(1.0, abs(offset))
    for i in range(len(pts)):
        ref = set(np.nonzero(dist[i] < radius)[0])
        got = set(lists[i].tolist())
        sym = (ref ^ got) - set(np.nonzero(ambiguous[i])[0])
        assert not sym, (i, sorted(sym)[:5])
    assert counts.sum() > 3 * len(pts)  # not a vacuous comparison


def test_query_points_other_than_grid_points(device):
    """Boundary-style search: query a static grid from other points."""
    rng = np.random.default_rng(5)
    radius = 0.07
    b = rng.uniform(-1, 0, (800, 3)).astype(np.float32)
    q = rng.uniform(-1, 0, (300, 3)).astype(np.float32)
    bx = wp.array(b, dtype=wp.vec3, device=device)
    grid = NeighborGrid(radius, device=device)
    grid.build(bx)
    _, lists = neighbor_lists(grid, bx, wp.array(q, dtype=wp.vec3, device=device))
    dist = np.linalg.norm(q[:, None].astype(np.float64) - b[None].astype(np.float64), axis=2)
    for i in range(len(q)):
        assert set(lists[i].tolist()) == set(np.nonzero(dist[i] < radius)[0])
