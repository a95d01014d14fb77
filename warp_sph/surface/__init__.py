"""Fluid surface reconstruction from particles (sparse narrow-band grid, marching cubes, smoothing)."""
from .reconstruction import (DEFAULT_CELL_PER_RADIUS, DEFAULT_ISO_LEVEL, DEFAULT_SPRAY_NEIGHBORS, SurfaceFrame,
                             SurfaceReconstructor, surface_settings)

__all__ = ["DEFAULT_CELL_PER_RADIUS", "DEFAULT_ISO_LEVEL", "DEFAULT_SPRAY_NEIGHBORS", "SurfaceFrame",
           "SurfaceReconstructor", "surface_settings"]
