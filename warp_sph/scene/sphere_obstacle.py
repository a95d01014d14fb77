"""Sphere obstacles (``[[obstacles]] shape = "sphere"``: ``center`` c [m], ``radius`` R [m]), static or animated.

Surface: the Fibonacci lattice of the spherical bodies (``rigid.sampling.fibonacci_sphere``), round(4 pi R^2 / d^2)
points exactly on |x - c| = R with outward normals, the same area per point as the box faces' square lattice.
Inside: |x - c| <= R. The USD surface of an animated one is the bodies' icosphere (``rigid.spec.sphere_mesh``).
"""
from __future__ import annotations

import numpy as np


def sphere_surface(ob, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """(points [m] (K, 3), outward unit normals (K, 3)) about ``spacing`` apart on the sphere obstacle ``ob``."""
    from ..rigid.sampling import fibonacci_sphere

    p, n = fibonacci_sphere(float(ob.radius), spacing)
    return p + np.asarray(ob.center, dtype=np.float64), n


def sphere_inside(ob, points: np.ndarray) -> np.ndarray:
    """Mask of ``points`` [m] with |x - c| <= R."""
    x = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return np.linalg.norm(x - np.asarray(ob.center, dtype=np.float64), axis=1) <= float(ob.radius)


def sphere_bounds(ob) -> tuple[np.ndarray, np.ndarray]:
    """(c - R, c + R) [m]."""
    c, r = np.asarray(ob.center, dtype=np.float64), float(ob.radius)
    return c - r, c + r


def sphere_triangle_mesh(ob):
    """The obstacle as a closed outward-wound icosphere ``TriangleMesh`` [m] (USD output, overlap checks)."""
    from ..rigid.spec import sphere_mesh
    from .meshes import TriangleMesh

    verts, tris = sphere_mesh(float(ob.radius))
    return TriangleMesh(verts + np.asarray(ob.center, dtype=np.float64), tris)
