"""Boundary particles of a rigid body, in its own frame, with their Akinci 2012 volumes.

Surface samples about one spacing d apart, as the static obstacles are sampled
(``scene.sampling``): a box on its faces with ``meshes.box_surface`` (square lattice), a mesh with
``meshes.sample_surface``, a sphere on a Fibonacci lattice of round(4 pi R^2 / d^2) points (the
same area per point as a square lattice of spacing d).

Inset: the fluid keeps its particle centres about one wall gap g (``Scene.wall_gap``, ~1.1 d) from
boundary particles, so a fluid particle's volume ends g - r from them: a body sampled on its true
surface displaces a shell of that thickness too. Measured with the prototype in notes/rigid.md: a
0.2 x 0.2 x 0.1 m box held fully under water at r = 12.5 mm felt 58-66 N against Archimedes'
39.2 N sampled on its surface, and 35-42 N (mean 38.5 N) sampled on the surface moved inward by
g - r. ``sample_body(..., inset=g - r)`` samples that inset surface, so buoyancy sees the true volume.

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

from ..core.errors import SceneError
from ..core.launch import launch
from ..core.smoothing import get_smoothing_kernel
from ..kernels import density as _density_dev
from ..neighbors import NeighborGrid
from ..scene.meshes import TriangleMesh, box_surface, sample_surface
from .spec import BodyGeometry, body_geometry, body_inset, posed


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


def inset_mesh(mesh: TriangleMesh, inset: float) -> TriangleMesh:
    """The closed outward-wound ``mesh`` with every face plane moved inward by ``inset`` [m]: vertex v
    moves by -inset u_v, u_v the least-squares solution of u . n_f = 1 over its faces' unit normals
    n_f (exact at box corners and edges, the normal on smooth parts), |u_v| capped at 3."""
    if inset == 0.0:
        return mesh
    a, b, c = mesh.triangle_corners()
    n = np.cross(b - a, c - a)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    nv = len(mesh.vertices)
    A = np.zeros((nv, 3, 3))
    rhs = np.zeros((nv, 3))
    for k in range(3):
        np.add.at(A, mesh.triangles[:, k], n[:, :, None] * n[:, None, :])
        np.add.at(rhs, mesh.triangles[:, k], n)
    u = np.einsum("vij,vj->vi", np.linalg.pinv(A, rcond=1e-6, hermitian=True), rhs)
    length = np.linalg.norm(u, axis=1, keepdims=True)
    u *= np.minimum(1.0, 3.0 / np.maximum(length, 1e-300))
    return TriangleMesh(mesh.vertices - inset * u, mesh.triangles)


def surface_samples(geometry: BodyGeometry, spacing: float, inset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Points [m] about ``spacing`` apart on the body's surface moved inward by ``inset`` [m], in the
    body frame, and their outward normals."""
    if geometry.shape == "box":
        h = geometry.half_extents - inset
        return box_surface(-h, h, spacing, inward=False)
    if geometry.shape == "sphere":
        return fibonacci_sphere(geometry.radius - inset, spacing)
    return sample_surface(inset_mesh(geometry.mesh, inset), spacing)


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
        launch(_density_dev.boundary_volume_kernel(kernel.name), x.shape[0],
               [float(smoothing_length), float(support), grid.id, x], [volume], device=device)
    return volume.numpy()


def sample_body(geometry: BodyGeometry, spacing: float, smoothing: str, smoothing_length: float,
                inset: float = 0.0, device=None) -> BodySamples:
    """The body's boundary particles (``surface_samples`` on the surface moved inward by ``inset`` [m];
    the coupling passes wall_gap - r, see the module docstring) and their Akinci volumes.
    Raises SceneError when the inset leaves no body (a size under 2 inset)."""
    if geometry.shape == "box" and not np.all(geometry.half_extents > inset):
        raise SceneError(f"body box of size {list(2 * geometry.half_extents)} m is too thin for its boundary inset "
                         f"of {inset:g} m on each side (wall gap - r); make it larger than {2 * inset:g} m or "
                         "the particles smaller")
    if geometry.shape == "sphere" and not geometry.radius > inset:
        raise SceneError(f"body sphere of radius {geometry.radius:g} m is not larger than its boundary inset "
                         f"{inset:g} m (wall gap - r); make it larger or the particles smaller")
    x, n = surface_samples(geometry, spacing, inset)
    vol = akinci_volumes(x, smoothing, smoothing_length, device=device)
    return BodySamples(local_x=np.ascontiguousarray(x, dtype=np.float64),
                       normals=np.ascontiguousarray(n, dtype=np.float32), volume=vol.astype(np.float32))


def sample_scene_bodies(scene, device=None) -> tuple[list[BodyGeometry], list[BodySamples], np.ndarray]:
    """Every ``[[bodies]]`` entry of ``scene`` sampled for the coupling: (geometries, samples in the
    body frames, their world positions at t = 0 (K, 3) [m] float64, body after body). The samples are
    inset by wall gap - r (module docstring)."""
    geometries, samples, world = [], [], []
    inset = body_inset(scene)
    for body in scene.bodies:
        geo = body_geometry(body)
        s = sample_body(geo, scene.spacing, scene.smoothing_kernel, scene.smoothing_length, inset=inset, device=device)
        R, c = posed(geo, body)
        geometries.append(geo)
        samples.append(s)
        world.append(s.local_x @ R.T + c)
    x = np.concatenate(world) if world else np.zeros((0, 3))
    return geometries, samples, x
