"""Neighbour search: per-step lists over a dense cell grid (``cell_lists``), ``wp.HashGrid`` queries
(``hash_grid``, the reference variant) and the cell order of particle fields (``particle_order``)."""
from .cell_lists import CellGrid, NeighborLists
from .hash_grid import GRID_DIM, NeighborGrid, fluid_grid_dim, query_neighbors

__all__ = ["CellGrid", "GRID_DIM", "NeighborGrid", "NeighborLists", "fluid_grid_dim", "query_neighbors"]
