"""Fluid surface reconstruction: spray split, colour field on a sparse narrow band, marching cubes,
feature-weighted smoothing, optional decimation and vertex normals.

Stages of :meth:`SurfaceReconstructor.reconstruct` (each timed, ``SurfaceFrame.timings``):

1. ``particles``: particles sorted into blocks of grid nodes; per particle its neighbour count,
   weighted neighbour count and rho~ (``grid.py``). Spray: fewer than ``spray_neighbors``
   neighbours within the kernel support; spray is left out of the field and returned as points;
2. ``band``: the blocks that can hold the surface (within a band radius of surface particles),
   the "inside" and "outside" blocks, and the ghost blocks below the band (``grid.py``);
3. ``field``: Phi(x) = sum_j f(|x - x_j| / h) / rho~_j (f the kernel's shape; mass and rest density
   cancel, ~1 inside, 0 outside) on the band's nodes only;
4. ``extraction``: marching cubes (``marching.py``), welded by construction (one vertex per
   crossing edge) and wound outward, with each vertex's smoothing weight (from the weighted
   neighbour count field Psi beside Phi); where the band missed part of the surface the field is
   rebuilt exact everywhere within the support (``SurfaceFrame.stats["band_fallback"]``);
5. ``smoothing``: connectivity, ``smoothing_iterations`` weighted Laplacian steps
   (``smoothing.py``); 6. ``decimation`` (``decimation.py``, optional); 7. ``normals``.

Why iso 0.6 and this Phi: with rho~ from the same kernel, unclamped and without walls, Phi is 1 in
the bulk whatever the solver's density, and a flat free surface crosses 0.6 about r beyond the last
particle layer (splashsurf's default and convention, notes/surface.md). The previous Phi = sum m/rho
W with the solver's (clamped) density put the 0.5 level exactly on planes of grid nodes for a rest
lattice, which multiplied triangles there by ~2.5.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ..core.errors import SceneError
from .band import classify
from .field import compute_field
from .grid import SparseGrid, split_launches
from .marching import MarchingCubes
from .smoothing import SMOOTHING_SCHEMES, MeshSmoother, splashsurf_normalization

#: default grid cell size per particle radius (scene key ``output.surface_cell_per_radius``)
DEFAULT_CELL_PER_RADIUS = 2.0
#: default iso level of Phi (scene key ``output.surface_iso``)
DEFAULT_ISO_LEVEL = 0.6
#: default spray threshold: neighbours within the kernel support (``output.surface_spray_neighbors``)
DEFAULT_SPRAY_NEIGHBORS = 5
#: default smoothing iterations (``output.surface_smoothing_iterations``)
DEFAULT_SMOOTHING_ITERATIONS = 5
#: default decimation error bound [r] (``output.surface_decimation_error``; 0: no decimation)
DEFAULT_DECIMATION_ERROR = 0.0
#: collapse rounds per frame with an error bound only (``output.surface_decimation_rounds`` = 0); each
#: round cuts ~1/8 of the triangles and costs about a smoothing pass (docs/performance.md, "The surface's cost")
DEFAULT_DECIMATION_ROUNDS = 2
#: rounds with a triangle budget (0 rounds: until the budget is met, at most this many)
BUDGET_DECIMATION_ROUNDS = 40
#: selection passes per round (Luby-style; a 4th pass still adds ~2 % fewer triangles)
DEFAULT_DECIMATION_PASSES = 4
#: default normal smoothing iterations (``output.surface_normal_smoothing_iterations``)
DEFAULT_NORMAL_SMOOTHING_ITERATIONS = 10

STAGES = ("particles", "band", "field", "extraction", "smoothing", "decimation", "normals")


@dataclass
class SurfaceFrame:
    """One frame's surface, in the coordinates of the particles given.

    vertices: (V, 3) float32 [m]; triangles: (T, 3) int32, counter-clockwise seen from outside;
    normals: (V, 3) float32 unit vertex normals, or None; spray: (N,) bool per particle (True: spray,
    not in the mesh); timings: seconds per stage; stats: counts (band blocks, raw triangles, ...).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray | None
    spray: np.ndarray
    timings: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)


class SurfaceReconstructor:
    """Triangle mesh of the fluid surface and the spray particles, from particle positions.

    Args:
        smoothing: smoothing kernel name ("cubic", "quintic", "quadric"); Phi uses its shape.
        h: smoothing length [m].
        particle_radius: particle radius r [m] (spacing d = 2 r).
        cell_size: grid cell edge [m]; DEFAULT_CELL_PER_RADIUS * r by default in scenes.
        iso_level: level of Phi taken as the surface, 0 < iso < 1 (default 0.6).
        device: Warp device.
        spray_neighbors: particles with fewer neighbours within the kernel support are spray
            (0: no spray, every particle is meshed).
        smoothing_iterations: feature-weighted smoothing iterations (0: raw marching cubes).
        smoothing_scheme: "taubin" (volume-preserving pair per iteration) or "laplacian" (splashsurf).
        normal_smoothing_iterations: one-ring averaging steps of the vertex normals.
        normals: compute vertex normals.
        decimation: None, or a :class:`~warp_sph.surface.decimation.Decimator` applied after smoothing.
        split_threads: split kernels over the CPU threads (off for a reconstruction running beside
            the simulation, which keeps the cores busy).
        narrow_band: evaluate Phi only near surface particles (off: on every block within the support
            radius of a particle; the same mesh, slower: tests/test_surface.py).
    """

    def __init__(self, smoothing: str, h: float, particle_radius: float, cell_size: float,
                 iso_level: float = DEFAULT_ISO_LEVEL, device="cpu", *,
                 spray_neighbors: int = DEFAULT_SPRAY_NEIGHBORS,
                 smoothing_iterations: int = DEFAULT_SMOOTHING_ITERATIONS, smoothing_scheme: str = "laplacian",
                 normal_smoothing_iterations: int = DEFAULT_NORMAL_SMOOTHING_ITERATIONS, normals: bool = True,
                 decimation=None, split_threads: bool = True, narrow_band: bool = True):
        if not (h > 0.0 and particle_radius > 0.0 and cell_size > 0.0):
            raise SceneError(f"surface reconstruction needs h, particle_radius and cell_size > 0; got h={h}, "
                             f"particle_radius={particle_radius}, cell_size={cell_size}")
        if not 0.0 < iso_level < 1.0:
            raise SceneError(f"surface iso level must lie in (0, 1) (Phi ~ 1 inside the fluid); got {iso_level}")
        if smoothing_scheme not in SMOOTHING_SCHEMES:
            raise SceneError(f"unknown surface smoothing scheme {smoothing_scheme!r}; expected one of "
                             f"{', '.join(SMOOTHING_SCHEMES)}")
        if spray_neighbors < 0 or smoothing_iterations < 0 or normal_smoothing_iterations < 0:
            raise SceneError("surface spray_neighbors and smoothing iterations must be >= 0")
        self.device = wp.get_device(device)
        self.iso_level = float(iso_level)
        self.particle_radius = float(particle_radius)
        self.cell_size = float(cell_size)
        self.smoothing_iterations = int(smoothing_iterations)
        self.smoothing_scheme = smoothing_scheme
        self.normal_smoothing_iterations = int(normal_smoothing_iterations)
        self.with_normals = bool(normals)
        self.decimation = decimation
        self.split_threads = bool(split_threads)
        self.narrow_band = bool(narrow_band)
        self.grid = SparseGrid(smoothing, h, particle_radius, cell_size, spray_neighbors=spray_neighbors,
                               device=self.device)
        self.support_radius = self.grid.support_radius
        self.marching = MarchingCubes(self.device)
        self.smoother = MeshSmoother(smoothing, h, self.support_radius,
                                     splashsurf_normalization(self.support_radius, particle_radius), self.device)

    def _tick(self, timings: dict, stage: str, t0: float) -> float:
        wp.synchronize_device(self.device)
        t = time.perf_counter()
        timings[stage] = timings.get(stage, 0.0) + (t - t0)
        return t

    def reconstruct(self, particle_x: wp.array) -> SurfaceFrame:
        """Surface mesh and spray of the particles at ``particle_x`` [m] (wp.array of vec3, shape (N,))."""
        n = len(particle_x)
        timings = {s: 0.0 for s in STAGES}
        empty = SurfaceFrame(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32),
                             np.zeros((0, 3), np.float32) if self.with_normals else None, np.zeros(n, bool), timings,
                             {"raw_triangles": 0, "band_fallback": 0})
        if n == 0:
            return empty
        split_launches(self.split_threads)
        grid, mc = self.grid, self.marching
        t = time.perf_counter()
        grid.build(particle_x)
        spray = grid.spray_mask()
        t = self._tick(timings, "particles", t)
        stats = {"spray": int(spray.sum()), "band_fallback": 0}
        if spray.all():
            empty.spray = spray
            empty.stats.update(stats)
            return empty
        exact = not self.narrow_band
        while True:
            consistent = classify(grid, exact=exact)
            t = self._tick(timings, "band", t)
            inexact = 0
            if consistent:
                compute_field(grid)
                t = self._tick(timings, "field", t)
                inexact = mc.count(grid, self.iso_level)
                t = self._tick(timings, "extraction", t)
            if exact or (consistent and inexact == 0):
                break
            exact = True  # the band missed part of the surface: exact everywhere within the support
            stats["band_fallback"] = 1
        vertex_x, vertex_weight, triangles = mc.extract(grid, self.iso_level, self.smoother.normalization)
        t = self._tick(timings, "extraction", t)
        stats.update(candidate_blocks=grid.candidate_count, meshed_blocks=grid.meshed_count,
                     band_blocks=int(grid.meshed_band.numpy()[: grid.meshed_count].sum()),
                     block_nodes=grid.block_nodes, raw_vertices=len(vertex_x), raw_triangles=len(triangles))
        sm = self.smoother
        conn = None
        if self.smoothing_iterations > 0 and len(triangles):
            conn = sm.connectivity.build(len(vertex_x), triangles)
            vertex_x = sm.smooth(vertex_x, vertex_weight, conn, self.smoothing_iterations, self.smoothing_scheme, triangles)
            t = self._tick(timings, "smoothing", t)
        if self.decimation is not None and len(triangles):
            vertex_x, triangles = self.decimation.decimate(vertex_x, triangles, conn)
            conn = None
            t = self._tick(timings, "decimation", t)
        normals = None
        if self.with_normals:
            if len(triangles):
                if conn is None:
                    conn = sm.connectivity.build(len(vertex_x), triangles)
                normals = sm.normals(vertex_x, triangles, conn, self.normal_smoothing_iterations).numpy()
            else:
                normals = np.zeros((0, 3), np.float32)
        verts = vertex_x.numpy()
        tris = triangles.numpy().reshape(-1, 3)
        t = self._tick(timings, "normals", t)
        stats.update(vertices=len(verts), triangles=len(tris))
        return SurfaceFrame(verts, tris, normals, spray, timings, stats)

    def extract(self, particle_x: wp.array) -> tuple[np.ndarray, np.ndarray]:
        """Vertices (V, 3) float32 [m] and triangles (T, 3) int32 of :meth:`reconstruct`."""
        frame = self.reconstruct(particle_x)
        return frame.vertices, frame.triangles


def surface_settings(output, particle_radius: float) -> dict:
    """Keyword arguments of :class:`SurfaceReconstructor` from a scene's ``output`` settings (an
    ``OutputParams`` or its dict form), except the kernel and device."""
    get = output.get if isinstance(output, dict) else (lambda k, d=None: getattr(output, k, d))
    budget = int(get("surface_triangle_budget", 0) or 0)
    error = float(get("surface_decimation_error", DEFAULT_DECIMATION_ERROR) or 0.0)
    decimation = None
    if budget or error:
        from .decimation import Decimator

        rounds = int(get("surface_decimation_rounds", 0) or 0)
        if rounds == 0:
            rounds = BUDGET_DECIMATION_ROUNDS if budget else DEFAULT_DECIMATION_ROUNDS
        decimation = Decimator(max_error=error * particle_radius, triangle_budget=budget, length_scale=particle_radius,
                               max_rounds=rounds, passes=DEFAULT_DECIMATION_PASSES)
    return dict(
        cell_size=float(get("surface_cell_per_radius", DEFAULT_CELL_PER_RADIUS)) * particle_radius,
        iso_level=float(get("surface_iso", DEFAULT_ISO_LEVEL)),
        spray_neighbors=int(get("surface_spray_neighbors", DEFAULT_SPRAY_NEIGHBORS)),
        smoothing_iterations=int(get("surface_smoothing_iterations", DEFAULT_SMOOTHING_ITERATIONS)),
        normal_smoothing_iterations=int(get("surface_normal_smoothing_iterations",
                                            DEFAULT_NORMAL_SMOOTHING_ITERATIONS)),
        normals=bool(get("surface_normals", True)),
        decimation=decimation,
    )
