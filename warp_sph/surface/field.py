"""The colour field on the band blocks of a :class:`~warp_sph.surface.grid.SparseGrid`.

Device code: ``kernels/surface_field.py``. Band blocks get Phi = sum_j f_j / rho~_j (and
Psi = sum_j n_j f_j / rho~_j for the smoothing's feature weights) from the
particles of their 27 neighbour blocks (a thread per block, or per node layer of a block on a GPU;
each writes only its own nodes, no atomics); ghost blocks get 1 (inside) or 0 (outside).
"""
from __future__ import annotations

import warp as wp

from ..kernels import surface_field as _dev
from .grid import BLOCK_MIN_RANGE, SparseGrid, launch


def compute_field(grid: SparseGrid) -> wp.array:
    """Phi on the nodes of the grid's meshed blocks: B^3 values per block (``grid.field``), and Psi
    (``grid.weighted_field``, the weighted neighbour count times Phi, Shepard-interpolated)."""
    b = grid.block_nodes
    grid.field = grid._buf.get("field", grid.meshed_count * b**3, float)
    grid.weighted_field = grid._buf.get("wfield", grid.meshed_count * b**3, float)
    launch(_dev.splat_band, grid.meshed_count * grid.slabs,
           [grid.support_radius, wp.vec3(*grid.grid_origin), grid.cell_size, b, grid.slabs,
            grid.meshed_block, grid.block_class, grid.block_coord, grid.block_neighbor, grid.layer_start,
            grid.block_count, grid.sorted_x, grid.inv_kernel_sum, grid.weighted_count],
           [grid.field, grid.weighted_field], device=grid.device, min_range=max(1, BLOCK_MIN_RANGE * grid.slabs))
    return grid.field
