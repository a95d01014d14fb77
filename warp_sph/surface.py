"""Fluid surface reconstruction: splatted colour field on a dense grid + marching cubes.

Device code: ``kernels/surface.py``. Steps per call of :meth:`SurfaceReconstructor.extract`:

1. bounding box of the particles on the device (atomic min / max), one host read of 6 floats;
2. a dense grid over that box plus a margin of (support radius + one cell) on every side, so the
   field is exactly 0 on the outer nodes and every iso-surface closes inside the grid;
3. the colour field Phi(x) = sum_j (m_j / rho_j) W(|x - x_j|, h) (report eq. 25) splatted from the
   particles onto the nodes;
4. the iso-surface Phi = iso_level by ``warp.geometry.IsoSurfaceMarchingCubes`` (or
   ``IsoSurfaceNets``), in grid-index coordinates;
5. host post-processing (numpy): outward winding, welding of vertices that sit on a grid node,
   removal of degenerate and cancelling triangles, unreferenced vertices, and the map from grid
   units to metres.

Why iso = 0.5: in a uniform fluid Phi ~ 1 and outside Phi = 0; at a flat free surface the
field of a half-space is, by symmetry of W, 0.5 exactly on the plane through the outermost
particle layer's "volume boundary" (the particles' volumes m/rho tile the fluid, so the plane
half a spacing beyond the last particle centres is where half of each kernel's mass lies in the
fluid). The half-level therefore reproduces the fluid volume N m / rho; measured on a sphere of
particles it gives the volume within a few per cent (tests/test_surface.py).
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import warp as wp
import warp.geometry

from .errors import SceneError
from .kernels import surface as _dev
from .smoothing import get_smoothing_kernel

#: default grid cell size per particle radius (scene key ``output.surface_cell_per_radius``)
DEFAULT_CELL_PER_RADIUS = 0.5
#: default iso level of Phi (scene key ``output.surface_iso``)
DEFAULT_ISO_LEVEL = 0.5
#: largest dense grid, in nodes, before the cell is coarsened. Marching cubes needs about
#: 40 B per node (field, per-edge counts, scans and vertex ids), so 2^25 nodes ~ 1.3 GB.
DEFAULT_MAX_GRID_NODES = 2**25

_METHODS = {
    "marching_cubes": warp.geometry.IsoSurfaceMarchingCubes,
    "surface_nets": warp.geometry.IsoSurfaceNets,
}

# a vertex closer than this (grid units, per axis) to a node is snapped onto it and welded
_SNAP = 1.0e-4


class SurfaceReconstructor:
    """Triangle mesh of the fluid surface from particle positions and densities.

    Args:
        smoothing: smoothing kernel name ("cubic", "quintic", "quadric").
        h: smoothing length [m].
        particle_mass: particle mass m [kg].
        particle_radius: particle radius r [m] (spacing d = 2 r).
        cell_size: grid cell edge [m]; default proposal 0.5 r.
        iso_level: level of Phi (dimensionless, 0 < iso < 1) taken as the surface; default 0.5.
        device: Warp device.
        method: "marching_cubes" (default) or "surface_nets".
        max_grid_nodes: beyond this many grid nodes the cell is coarsened (with a warning) so the
            grid holds at most this many nodes.
    """

    def __init__(
        self,
        smoothing: str,
        h: float,
        particle_mass: float,
        particle_radius: float,
        cell_size: float,
        iso_level: float = DEFAULT_ISO_LEVEL,
        device="cpu",
        method: str = "marching_cubes",
        max_grid_nodes: int = DEFAULT_MAX_GRID_NODES,
    ):
        kernel = get_smoothing_kernel(smoothing)
        if not (h > 0.0 and particle_mass > 0.0 and particle_radius > 0.0 and cell_size > 0.0):
            raise SceneError(
                f"surface reconstruction needs h, particle_mass, particle_radius and cell_size > 0; got "
                f"h={h}, particle_mass={particle_mass}, particle_radius={particle_radius}, cell_size={cell_size}"
            )
        if not 0.0 < iso_level < 1.0:
            raise SceneError(f"surface iso level must lie in (0, 1) (Phi ~ 1 inside the fluid); got {iso_level}")
        if method not in _METHODS:
            raise SceneError(f"unknown surface method {method!r}; expected one of {', '.join(_METHODS)}")
        self.smoothing = smoothing
        self.h = float(h)
        self.support_radius = kernel.support_radius(self.h)
        self.particle_mass = float(particle_mass)
        self.particle_radius = float(particle_radius)
        self.cell_size = float(cell_size)
        self.iso_level = float(iso_level)
        self.device = wp.get_device(device)
        self.method = method
        self.max_grid_nodes = int(max_grid_nodes)
        self._splat = _dev.splat_field_kernel(smoothing)
        self._lower = wp.empty(3, dtype=float, device=self.device)
        self._upper = wp.empty(3, dtype=float, device=self.device)
        self._field: wp.array | None = None
        #: grid of the last call: origin [m] (float64), cell size [m], node counts
        self.grid_origin = np.zeros(3)
        self.grid_cell_size = self.cell_size
        self.grid_shape = (0, 0, 0)

    # -- steps -------------------------------------------------------------------------------
    def particle_bounds(self, particle_x: wp.array) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) corners of the particles' bounding box [m], reduced on the device."""
        self._lower.fill_(math.inf)
        self._upper.fill_(-math.inf)
        wp.launch(_dev.particle_bounds, dim=len(particle_x), inputs=[particle_x],
                  outputs=[self._lower, self._upper], device=self.device)
        return self._lower.numpy().astype(np.float64), self._upper.numpy().astype(np.float64)

    def _plan_grid(self, lower: np.ndarray, upper: np.ndarray) -> None:
        """Grid over [lower, upper] + margin (support radius + one cell); coarsened if too large."""
        cell = self.cell_size
        for _ in range(8):
            margin = self.support_radius + cell
            shape = np.ceil((upper - lower + 2.0 * margin) / cell).astype(np.int64) + 1
            nodes = int(np.prod(shape))
            if nodes <= self.max_grid_nodes:
                break
            cell *= 1.01 * (nodes / self.max_grid_nodes) ** (1.0 / 3.0)
        if cell != self.cell_size:
            warnings.warn(
                f"surface grid of {np.prod(np.ceil((upper - lower + 2.0 * (self.support_radius + self.cell_size)) / self.cell_size) + 1):.3g} "
                f"nodes exceeds max_grid_nodes={self.max_grid_nodes}; cell coarsened from {self.cell_size:.4g} m "
                f"to {cell:.4g} m for this frame",
                RuntimeWarning,
                stacklevel=3,
            )
        self.grid_cell_size = cell
        self.grid_origin = lower - margin
        self.grid_shape = tuple(int(n) for n in shape)

    def compute_field(self, particle_x: wp.array, particle_density: wp.array) -> wp.array:
        """Plan the grid around the particles and splat Phi onto its nodes; returns the 3D field.

        Phi(x_node) = sum_j (m / rho_j) W(|x_node - x_j|, h) (report eq. 25), dimensionless.
        """
        lower, upper = self.particle_bounds(particle_x)
        self._plan_grid(lower, upper)
        if self._field is None or self._field.shape != self.grid_shape:
            self._field = wp.zeros(self.grid_shape, dtype=float, device=self.device)
        else:
            self._field.zero_()
        wp.launch(
            self._splat,
            dim=len(particle_x),
            inputs=[self.particle_mass, self.h, self.support_radius, particle_x, particle_density,
                    wp.vec3(*self.grid_origin.astype(np.float32)), float(self.grid_cell_size)],
            outputs=[self._field],
            device=self.device,
        )
        return self._field

    def extract(self, particle_x: wp.array, particle_density: wp.array) -> tuple[np.ndarray, np.ndarray]:
        """Surface mesh of the fluid.

        Args:
            particle_x: positions [m], wp.array of vec3, shape (N,).
            particle_density: densities [kg/m^3], shape (N,).

        Returns:
            vertices (V, 3) float32 [m] and triangles (T, 3) int32, wound counter-clockwise seen
            from outside (outward normals), welded (a closed blob is watertight: every edge in
            exactly two triangles), without triangles that repeat a vertex or have zero area.
            No particles give an empty mesh.
        """
        if len(particle_x) != len(particle_density):
            raise ValueError(f"{len(particle_x)} positions but {len(particle_density)} densities")
        if len(particle_x) == 0:
            return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
        field = self.compute_field(particle_x, particle_density)
        # grid-index coordinates (node (i, j, k) at (i, j, k)): exact node positions for welding
        verts, indices = _METHODS[self.method].extract(field, self.iso_level)
        return self._finish(verts.numpy(), indices.numpy())

    # -- host post-processing ----------------------------------------------------------------
    def _finish(self, g: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Orient, weld and clean the raw extractor output (grid units) and map it to metres."""
        # Warp's extractors wind CCW seen from outside where the field is *below* the threshold
        # inside (signed-distance convention); Phi is above it inside, so reverse every triangle.
        tris = indices.reshape(-1, 3)[:, ::-1].astype(np.int64)
        if len(tris) == 0:
            return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
        nv = len(g)
        if self.method == "marching_cubes":
            # Weld vertices that sit on a grid node (edge parameter 0 or 1 up to rounding): the
            # vertices of different edges of that node share the position but not the index.
            node = np.rint(g)
            on_node = np.all(np.abs(g - node) < _SNAP, axis=1)
            if on_node.any():
                tris = self._weld_on_nodes(g, node, on_node, tris)
                g = np.where(on_node[:, None], node, g)
        # metres (float64 -> float32); zero-area triangles are judged on the final coordinates
        verts = (self.grid_origin + g * self.grid_cell_size).astype(np.float32)
        v = verts.astype(np.float64)
        a, b, c = v[tris[:, 0]], v[tris[:, 1]], v[tris[:, 2]]
        cross = np.cross(b - a, c - a)
        keep = np.any(cross != 0.0, axis=1)
        keep &= (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
        if not keep.all():
            tris = tris[keep]
        # drop unreferenced vertices
        used = np.zeros(nv, dtype=bool)
        used[tris.reshape(-1)] = True
        if used.all():
            return verts, tris.astype(np.int32)
        remap = np.cumsum(used, dtype=np.int64) - 1
        return np.ascontiguousarray(verts[used]), remap[tris].astype(np.int32)

    def _weld_on_nodes(self, g, node, on_node, tris):
        """Map every on-node vertex to the first vertex on the same node; drop the triangles this
        makes degenerate and the pairs it folds onto each other (same three vertices twice)."""
        nx, ny, nz = self.grid_shape
        ids = np.flatnonzero(on_node)
        n = node[ids].astype(np.int64)
        key = (n[:, 0] * ny + n[:, 1]) * nz + n[:, 2]
        _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        target = np.arange(len(g), dtype=np.int64)
        target[ids] = ids[first][inverse.reshape(-1)]
        tris = target[tris]
        tris = tris[(tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])]
        srt = np.sort(tris, axis=1)
        key = (srt[:, 0] * len(g) + srt[:, 1]) * len(g) + srt[:, 2] if len(g) < 2**21 else None
        if key is None:
            _, inv, counts = np.unique(srt, axis=0, return_inverse=True, return_counts=True)
        else:
            _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
        return tris[counts[inv.reshape(-1)] == 1]
