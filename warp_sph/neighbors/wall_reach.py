"""The static walls in reach of each sub-cell, built once per run (``WallReach``; device half
``kernels/wall_reach.py``), so a step's boundary search tests one short list per fluid particle
instead of walking the wall grid's rows: DFSPH's (``kernels/dfsph_factor.py``, ``walls``) and the boundary
lists WCSPH and PBF build (``kernels/neighbors.py`` ``neighbor_list_kernel``, ``walls``).

The static boundary particles do not move, and the search's cell grids keep one frame for the whole run
(``simulation_neighbor_lists``), so the boundary particles within H_s of each sub-cell of that frame
(``WALL_SUBCELLS`` per cell along each axis) are found once. The lists are in the walk's order (ascending
sorted index), so the results are bitwise those of the per-step walk. Moving boundary particles (rigid
bodies) keep the per-step walk of their own grid.

Used by ``methods/solvers/dfsph_search.py`` and ``methods/solvers/wcsph_lists.py`` ``static_wall_lists``.
"""
from __future__ import annotations

import warp as wp

from ..core.launch import launch
from ..kernels import wall_reach as _walls

#: sub-cells per cell of the search grid along each axis (0: walk the wall grid every step instead). The
#: reach of a sub-cell of side a is its box grown by H_s: with cells of H_s, 1 -> 2 -> 4 sub-cells shrink it
#: from 20.6 to 10.5 to 6.9 H_s^3 (the search sphere: 4.2 H_s^3). Measured on the dam break (docs/performance.md
#: "Neighbour search"): 21.7 / 10.2 / 5.9 wall candidates per particle, but the same time at 1
#: and 2 (4 is slower: 432 list entries per wall particle) for 4x the memory at 2, so 1.
WALL_SUBCELLS = 1
#: most sub-cells (their list starts: 4 B each); fewer sub-cells per cell on larger grids
MAX_SUBCELLS = 1 << 23
#: margin [cells] added to the reach, so that rounding in a fluid particle's sub-cell never drops a wall
REACH_MARGIN = 1.0e-3


class WallReach:
    """The static boundary particles within ``radius`` [m] of each sub-cell of ``cells`` (the static
    boundary ``CellGrid``, built): ``start`` (first list entry of each sub-cell, shape (count + 1,)) and
    ``entry`` (sorted boundary indices k, ascending within each list). ``inv_size`` = 1 / sub-cell size
    [1/m], ``dims`` the sub-cell grid, ``subcells`` per cell along each axis."""

    def __init__(self, cells, radius: float, subcells: int = WALL_SUBCELLS, device="cpu"):
        self.cells = cells
        dims = [int(cells.dims[a]) for a in range(3)]
        while subcells > 1 and cells.cell_count * subcells ** 3 > MAX_SUBCELLS:
            subcells //= 2
        self.subcells = int(subcells)
        self.dims = wp.vec3i(*(d * self.subcells for d in dims))
        self.inv_size = float(cells.inv_cell_size * self.subcells)
        self.count = cells.cell_count * self.subcells ** 3
        self.radius = float(radius)
        cell_reach = self.radius * cells.inv_cell_size
        reach = cell_reach + REACH_MARGIN
        self.start = wp.zeros(self.count + 1, dtype=wp.int32, device=device)
        counts = wp.zeros(self.count + 1, dtype=wp.int32, device=device)
        nothing = wp.zeros(1, dtype=wp.int32, device=device)
        grid = [cells.lo, cells.inv_cell_size, cells.dims, cells.cell_start, cells.sorted_x, self.subcells, cell_reach,
                reach]
        launch(_walls.walls_in_reach, self.count, grid + [0, nothing], [counts, nothing], device=device)
        wp.utils.array_scan(counts, self.start, inclusive=False)
        total = int(self.start[self.count:].numpy()[0])
        self.entry = wp.zeros(max(total, 1), dtype=wp.int32, device=device)
        launch(_walls.walls_in_reach, self.count, grid + [1, self.start], [counts, self.entry], device=device)
        self.entries = total

    @property
    def nbytes(self) -> int:
        """Memory of the lists and their starts [bytes]."""
        return 4 * (self.count + 1 + self.entry.shape[0])
