"""Boundary particles of a rigid body, in its own frame, with their Akinci 2012 volumes.

Surface samples about one spacing d apart, as the static obstacles are sampled
(``scene.sampling``): a box on its faces with ``box_surface`` (square lattice), a mesh with
``meshes.sample_surface``, a sphere on a Fibonacci lattice of round(4 pi R^2 / d^2) points (the
same area per point as a square lattice of spacing d).

Volumes: V_b = 1 / sum_k W(x_b - x_k) over the body's own samples k (b included), as
SPlisHSPlasH computes them once per dynamic body with only its own point set active
(BoundaryModel_Akinci2012::computeBoundaryVolume). They depend only on the body-frame samples,
so they are computed once and move with the body.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.smoothing import get_smoothing_kernel
from ..kernels import density as _density_dev
from ..neighbors import NeighborGrid
from ..scene.meshes import sample_surface
from ..scene.sampling import box_surface
from .spec import BodyGeometry


@dataclass
class BodySamples:
    """Boundary particles of one body in its frame (origin at the centre of mass).

    local_x: positions [m], shape (K, 3), float64; normals: outward unit normals, (K, 3);
    volume: Akinci V_b [m^3], shape (K,), float32 (Psi_b = rho0 V_b [kg]).
    """

    local_x: np.ndarray
    normals: np.ndarray
    volume: np.ndarray

    @property
    def count(self) -> int:
        return int(self.local_x.shape[0])


def fibonacci_sphere(radius: float, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """round(4 pi R^2 / d^2) points (at least 12) on the sphere of ``radius`` [m] centred at the origin,
    on a Fibonacci lattice (golden-angle spiral, equal area per point); returns (points, normals)."""
    n = max(12, int(round(4.0 * math.pi * radius * radius / (spacing * spacing))))
    k = np.arange(n, dtype=np.float64)
    z = 1.0 - (2.0 * k + 1.0) / n
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    normals = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    return radius * normals, normals


def surface_samples(geometry: BodyGeometry, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Surface points [m] about ``spacing`` apart in the body frame, and their outward normals."""
    if geometry.shape == "box":
        h = geometry.half_extents
        return box_surface(-h, h, spacing, inward=False)
    if geometry.shape == "sphere":
        return fibonacci_sphere(geometry.radius, spacing)
    return sample_surface(geometry.mesh, spacing)


def akinci_volumes(local_x: np.ndarray, smoothing: str, smoothing_length: float, device=None) -> np.ndarray:
    """V_b = 1 / sum_k W(x_b - x_k) [m^3] over the points ``local_x`` themselves (b included), with the
    project's ``boundary_volume_kernel`` (the kernel the static boundary volumes use)."""
    kernel = get_smoothing_kernel(smoothing)
    support = kernel.support_radius(smoothing_length)
    x = wp.array(np.asarray(local_x, dtype=np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)
    volume = wp.zeros(x.shape[0], dtype=float, device=device)
    if x.shape[0]:
        grid = NeighborGrid(support, device=device)
        grid.build(x)
        wp.launch(_density_dev.boundary_volume_kernel(kernel.name), dim=x.shape[0],
                  inputs=[float(smoothing_length), float(support), grid.id, x], outputs=[volume], device=device)
    return volume.numpy()


def sample_body(geometry: BodyGeometry, spacing: float, smoothing: str, smoothing_length: float,
                device=None) -> BodySamples:
    """The body's boundary particles (``surface_samples``) and their Akinci volumes (``akinci_volumes``)."""
    x, n = surface_samples(geometry, spacing)
    vol = akinci_volumes(x, smoothing, smoothing_length, device=device)
    return BodySamples(local_x=np.ascontiguousarray(x, dtype=np.float64),
                       normals=np.ascontiguousarray(n, dtype=np.float32), volume=vol.astype(np.float32))
