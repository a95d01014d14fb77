"""Marching cubes on the sparse block grid of :class:`~warp_sph.surface.grid.SparseGrid`.

Device code: ``kernels/surface_marching.py`` (same case table as Warp's
``IsoSurfaceMarchingCubes``, which needs a dense grid: tests/test_surface.py checks that both give
the same triangles on the same field). Three passes over the meshed blocks (count, vertices,
triangles) with two scans between them; one host read of the totals.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ..core.buffers import ArrayPool
from ..core.errors import SimulationError
from ..core.launch import LIGHT_MIN_RANGE
from ..kernels import surface_marching as _dev
from .grid import BLOCK_MIN_RANGE, LIGHT_BLOCK_MIN_RANGE, SparseGrid, launch, read_int32


class MarchingCubes:
    """Extracts the iso-surface Phi = iso_level from a built :class:`SparseGrid`."""

    def __init__(self, device):
        self.device = wp.get_device(device)
        self.tri_range = wp.array(np.asarray(_dev.TRI_RANGE_TABLE, np.int32), dtype=wp.int32, device=self.device)
        self.tri_edges = wp.array(np.asarray(_dev.TRI_EDGE_TABLE, np.int32), dtype=wp.int32, device=self.device)
        self.edge_owner = wp.array(np.asarray(_dev.EDGE_OWNER_FLAT, np.int32), dtype=wp.int32, device=self.device)
        self._buf = ArrayPool(self.device)
        self.vertex_count = 0
        self.triangle_count = 0

    def count(self, grid: SparseGrid, iso_level: float) -> int:
        """Pass 1: crossing edges and cases of every node; returns the crossing edges with an end whose
        value is not exact (a ghost or unmeshed block: the band missed part of the surface)."""
        units = grid.meshed_count * grid.slabs
        b = grid.block_nodes
        self.units = units
        self.node_code = self._buf.get("code", grid.meshed_count * b**3, wp.int32)
        self.unit_vertices = self._buf.get("uv", units, wp.int32)
        self.unit_triangles = self._buf.get("ut", units, wp.int32)
        unit_inexact = self._buf.get("ui", units, wp.int32)
        block_min = self._buf.get("bmin", grid.meshed_count, float)
        block_max = self._buf.get("bmax", grid.meshed_count, float)
        launch(_dev.block_value_range, grid.meshed_count, [b, grid.field], [block_min, block_max], device=self.device,
               min_range=LIGHT_BLOCK_MIN_RANGE)
        launch(_dev.count_cells, units, [b, grid.slabs, float(iso_level), grid.field, grid.meshed_upper,
                                         grid.meshed_band, block_min, block_max, self.tri_range],
               [self.node_code, self.unit_vertices, self.unit_triangles, unit_inexact], device=self.device,
               min_range=max(1, BLOCK_MIN_RANGE * grid.slabs))
        if units == 0:
            return 0
        return int(unit_inexact.numpy()[:units].sum())

    def extract(self, grid: SparseGrid, iso_level: float, weight_normalization: float = 1.0
                ) -> tuple[wp.array, wp.array, wp.array]:
        """Passes 2 and 3 (after :meth:`count`): vertex positions [m] (V,) vec3, the smoothing's feature
        weight of each vertex (V,) float in [0, 1] (smoothstep of the interpolated weighted neighbour
        count / ``weight_normalization``; ``kernels/surface_marching.emit_vertices``), and triangles
        (T,) vec3i wound counter-clockwise seen from outside."""
        units = self.units
        b = grid.block_nodes
        if units == 0:
            self.vertex_count = self.triangle_count = 0
            return (self._buf.get("vx", 1, wp.vec3)[:0], self._buf.get("vw", 1, float)[:0],
                    self._buf.get("tri", 1, wp.vec3i)[:0])
        v_start = self._buf.get("uvs", units, wp.int32)
        t_start = self._buf.get("uts", units, wp.int32)
        wp.utils.array_scan(self.unit_vertices[:units], v_start[:units], inclusive=False)
        wp.utils.array_scan(self.unit_triangles[:units], t_start[:units], inclusive=False)
        n_v = read_int32(v_start, units - 1) + read_int32(self.unit_vertices, units - 1)
        n_t = read_int32(t_start, units - 1) + read_int32(self.unit_triangles, units - 1)
        self.vertex_count, self.triangle_count = n_v, n_t
        node_vertex = self._buf.get("nv", grid.meshed_count * b**3, wp.int32)
        vertex_x = self._buf.get("vx", n_v, wp.vec3)
        vertex_weight = self._buf.get("vw", n_v, float)
        triangles = self._buf.get("tri", n_t, wp.vec3i)
        missing = self._buf.get("um", units, wp.int32)
        launch(_dev.emit_vertices, units,
               [wp.vec3(*grid.grid_origin), grid.cell_size, b, grid.slabs, float(iso_level), grid.field, grid.weighted_field, grid.meshed_upper, grid.meshed_block, grid.block_coord, self.node_code,
                self.unit_vertices, v_start],
               [node_vertex, vertex_x, vertex_weight], device=self.device, min_range=max(1, BLOCK_MIN_RANGE * grid.slabs))
        launch(_dev.vertex_weights, n_v, [float(iso_level), float(weight_normalization)], [vertex_weight],
               device=self.device, min_range=LIGHT_MIN_RANGE)
        launch(_dev.emit_triangles, units,
               [b, grid.slabs, grid.meshed_upper, self.node_code, node_vertex, self.unit_triangles, t_start, self.tri_range,
                self.tri_edges, self.edge_owner],
               [triangles, missing], device=self.device, min_range=max(1, BLOCK_MIN_RANGE * grid.slabs))
        lost = int(missing.numpy()[:units].sum())
        if lost:
            raise SimulationError(f"surface reconstruction: {lost} triangle corners lost their vertex "
                                  "(inconsistent block classification)")
        return vertex_x[:n_v], vertex_weight[:n_v], triangles[:n_t]
