"""The narrow band of a :class:`~warp_sph.surface.grid.SparseGrid`: which blocks of nodes get the
exact field (band), which are taken as inside or outside, and which marching cubes visits (band
blocks and the ghost blocks below them). Device code: ``kernels/surface_band.py``.
"""
from __future__ import annotations

import warp as wp

from ..kernels import surface_band as _band
from .grid import BLOCK_MIN_RANGE, LIGHT_BLOCK_MIN_RANGE, SparseGrid, launch, read_int32


def classify(grid: SparseGrid, exact: bool = False) -> bool:
    """Band, inside and outside blocks (module docstring) and the meshed blocks: band blocks and
    the ghost blocks below them. exact: every block within the support radius of a particle is
    band. Returns False when an inside block touches an outside one (the band missed part of the
    surface: classify again with exact=True)."""
    dev = grid.device
    n_cand = grid.candidate_count
    grid.exact = bool(exact)
    grid.block_class = grid._buf.get("bclass", n_cand, wp.int32)
    meshed = grid._buf.get("bmeshed", n_cand, wp.int32)
    contact = grid._buf.get("bcontact", n_cand, wp.int32)
    scan = grid._buf.get("bscan", n_cand, wp.int32)
    launch(_band.classify_blocks, n_cand,
           [wp.vec3(*grid.grid_origin), grid.cell_size, grid.block_nodes, grid.band_radius, grid.support_radius,
            int(exact), grid.block_coord, grid.block_neighbor, grid.layer_start, grid.block_count, grid.sorted_x,
            grid.particle_flag],
           [grid.block_class], device=dev, min_range=BLOCK_MIN_RANGE)
    meshed.zero_()
    contact.zero_()
    launch(_band.mark_meshed_blocks, n_cand, [grid.block_class, grid.block_neighbor], [meshed, contact],
           device=dev, min_range=LIGHT_BLOCK_MIN_RANGE)
    wp.utils.array_scan(meshed[:n_cand], scan[:n_cand], inclusive=True)
    n_meshed = read_int32(scan, n_cand - 1)
    grid.meshed_count = n_meshed
    grid.block_state = grid._buf.get("bstate", n_cand, wp.int32)
    grid.meshed_block = grid._buf.get("meshed", n_meshed, wp.int32)
    grid.meshed_band = grid._buf.get("mband", n_meshed, wp.int32)
    launch(_band.compact_meshed, n_cand, [grid.block_class, meshed, scan],
           [grid.block_state, grid.meshed_block, grid.meshed_band], device=dev, min_range=LIGHT_BLOCK_MIN_RANGE)
    grid.meshed_upper = grid._buf.get("mupper", n_meshed, wp.int32, width=8)
    launch(_band.meshed_upper_neighbors, n_meshed, [grid.meshed_block, grid.block_neighbor, grid.block_state],
           [grid.meshed_upper], device=dev, min_range=LIGHT_BLOCK_MIN_RANGE)
    return exact or not bool(contact.numpy()[:n_cand].any())

