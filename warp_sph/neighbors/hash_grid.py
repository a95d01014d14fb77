"""Neighbour search on ``wp.HashGrid`` (report section 7.1/7.2).

The cell size and the query radius both equal the smoothing kernel's support radius H_s, so a
query returns every particle within H_s (candidates; kernels still filter by distance). The fluid
grid is rebuilt every substep; the boundary grid is built once, because boundary particles never
move. Kernels visit particles in cell order through ``wp.hash_grid_point_id``.
"""
from __future__ import annotations

import warp as wp

GRID_DIM = 128  # hash cells per axis; positions are hashed modulo this, any extent works


class NeighborGrid:
    """A hash grid over one particle set with cell size = search radius [m]."""

    def __init__(self, search_radius: float, device="cpu", dim: int = GRID_DIM):
        if not search_radius > 0.0:
            raise ValueError(f"search radius must be > 0, got {search_radius}")
        self.search_radius = float(search_radius)
        self.grid = wp.HashGrid(dim, dim, dim, device=device)
        self.count = 0

    @property
    def id(self) -> wp.uint64:
        return self.grid.id

    def build(self, points: wp.array) -> None:
        """Rebuild the grid over ``points`` (wp.array of vec3 [m])."""
        self.count = points.shape[0]
        self.grid.build(points, self.search_radius)


def query_neighbors(grid: NeighborGrid, points: wp.array, query_x: wp.array, capacity: int = 256):
    """(counts, list of index arrays): points within the grid's search radius of each query point."""
    import numpy as np

    from ..kernels import neighbors as _dev
    from ..core.launch import launch

    n = query_x.shape[0]
    counts = wp.zeros(n, dtype=int, device=query_x.device)
    index = wp.full((max(n, 1), capacity), -1, dtype=int, device=query_x.device)
    launch(_dev.collect_neighbors, n, [grid.id, points, query_x, grid.search_radius, capacity],
           [counts, index], device=query_x.device)
    c = counts.numpy()
    if n and c.max(initial=0) > capacity:
        raise ValueError(f"a query point has {c.max()} neighbours, more than capacity {capacity}")
    idx = index.numpy()
    return c, [np.sort(idx[i, : c[i]]) for i in range(n)]
