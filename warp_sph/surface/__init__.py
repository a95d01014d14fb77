"""Fluid surface reconstruction from particles."""
from .reconstruction import DEFAULT_CELL_PER_RADIUS, DEFAULT_ISO_LEVEL, SurfaceReconstructor

__all__ = ["DEFAULT_CELL_PER_RADIUS", "DEFAULT_ISO_LEVEL", "SurfaceReconstructor"]
