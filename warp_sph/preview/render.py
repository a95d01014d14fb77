"""The ray tracer of the previews: particles as exact spheres, or a triangle mesh, shaded with
Blinn-Phong (report section 3, eq. 2-6, and section 6), with the container drawn faintly.

Host half of ``kernels/render.py`` (same name): builds the camera, light and scenery structs and the
acceleration grid over the spheres, and launches the trace kernels, on Warp's CPU backend or
unchanged on CUDA. Returns images as uint8 arrays; ``images.py`` writes them, ``render_run.py``
renders a run folder.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import warp as wp

from ..core.errors import WarpSphError
from ..core.launch import launch
from ..kernels import render

DEFAULT_SIZE = (640, 360)
PARTICLE_COLOR = (0.16, 0.42, 0.78)  # water blue, linear [0, 1]
SURFACE_COLOR = (0.22, 0.50, 0.85)
OBSTACLE_COLOR = (0.62, 0.58, 0.52)  # stone grey for obstacles in surface previews
BACKGROUND = (0.93, 0.94, 0.96)


class PreviewError(WarpSphError):
    """A preview cannot be made: missing run files, unknown frame, missing Pillow, bad argument."""


@dataclass
class Camera:
    """Pinhole camera, Z up by default.

    position: eye [m]; target: point looked at [m]; up: world direction that appears upwards;
    fov_deg: vertical field of view [degrees].
    """

    position: Sequence[float]
    target: Sequence[float]
    up: Sequence[float] = (0.0, 0.0, 1.0)
    fov_deg: float = 40.0


@dataclass
class Light:
    """Blinn-Phong light and material weights (report eq. 5-6).

    direction: unit-less vector pointing from the scene towards a directional light; None places
    the light above and behind the camera's left shoulder. position: a point light [m] instead
    (overrides ``direction``). The colour is ambient*C + diffuse*(n.l)*C + specular*(n.h)^shininess.
    """

    direction: Sequence[float] | None = None
    position: Sequence[float] | None = None
    ambient: float = 0.28
    diffuse: float = 0.62
    specular: float = 0.35
    shininess: float = 48.0


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0.0:
        raise PreviewError(f"expected a non-zero finite vector, got {v.tolist()}")
    return v / n


def auto_camera(bounds_lo, bounds_hi, fov_deg: float = 40.0, aspect: float = 16.0 / 9.0) -> Camera:
    """A camera framing the box [bounds_lo, bounds_hi] [m] from an elevated 3/4 view, Z up.

    Looks at the box centre from 30 degrees above the horizon, 35 degrees round from the -Y side
    towards +X,
    far enough that the whole box fits the vertical (and, for narrow images, horizontal) field of view.
    """
    lo = np.asarray(bounds_lo, dtype=np.float64).reshape(3)
    hi = np.asarray(bounds_hi, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi >= lo)):
        raise PreviewError(f"camera bounds must be finite with lo <= hi, got {lo.tolist()} .. {hi.tolist()}")
    center = 0.5 * (lo + hi)
    azimuth, elevation = math.radians(-35.0), math.radians(30.0)
    view = np.array(
        [math.cos(elevation) * math.sin(-azimuth), -math.cos(elevation) * math.cos(azimuth), math.sin(elevation)]
    )
    forward = -view
    right = _unit(np.cross(forward, (0.0, 0.0, 1.0)))
    up = np.cross(right, forward)
    # distance at which every box corner projects inside the image (with a small margin)
    tan_v = math.tan(math.radians(fov_deg) / 2.0) * 0.92
    tan_h = tan_v * aspect
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) - center
    size = max(float(np.linalg.norm(hi - lo)), 1.0e-6)
    distance = 0.0
    for c in corners:
        depth = float(c @ forward)
        distance = max(distance, abs(c @ right) / tan_h - depth, abs(c @ up) / tan_v - depth)
    distance = max(distance, 0.5 * size)
    return Camera(position=tuple(center + distance * view), target=tuple(center), fov_deg=fov_deg)


def _camera_struct(camera: Camera, size: tuple[int, int]) -> render.RenderCamera:
    position = np.asarray(camera.position, dtype=np.float64).reshape(3)
    forward = _unit(np.asarray(camera.target, dtype=np.float64).reshape(3) - position)
    up_hint = _unit(camera.up)
    right = np.cross(forward, up_hint)
    if np.linalg.norm(right) < 1.0e-6:  # looking along "up": any perpendicular will do
        right = np.cross(forward, (1.0, 0.0, 0.0) if abs(forward[0]) < 0.9 else (0.0, 1.0, 0.0))
    right = _unit(right)
    up = np.cross(right, forward)
    if not 0.0 < camera.fov_deg < 180.0:
        raise PreviewError(f"camera fov_deg must be in (0, 180), got {camera.fov_deg}")
    s = render.RenderCamera()
    s.position = wp.vec3(*position)
    s.forward = wp.vec3(*forward)
    s.right = wp.vec3(*right)
    s.up = wp.vec3(*up)
    s.tan_half_fov = math.tan(math.radians(camera.fov_deg) / 2.0)
    s.width, s.height = int(size[0]), int(size[1])
    return s


def _light_struct(light: Light | None, cam: render.RenderCamera) -> render.RenderLight:
    light = light or Light()
    s = render.RenderLight()
    if light.direction is None:
        forward, right = np.array(cam.forward), np.array(cam.right)
        direction = _unit(-0.55 * forward - 0.45 * right + 0.75 * np.array([0.0, 0.0, 1.0]))
    else:
        direction = _unit(light.direction)
    s.direction = wp.vec3(*direction)
    s.position = wp.vec3(*(light.position if light.position is not None else (0.0, 0.0, 0.0)))
    s.is_point = int(light.position is not None)
    s.ambient, s.diffuse = float(light.ambient), float(light.diffuse)
    s.specular, s.shininess = float(light.specular), float(light.shininess)
    return s


def _nice_spacing(length: float) -> float:
    """A 1-2-5 grid spacing giving about ten lines over ``length`` [m]."""
    raw = max(length, 1.0e-9) / 10.0
    base = 10.0 ** math.floor(math.log10(raw))
    return min((m * base for m in (1.0, 2.0, 5.0, 10.0)), key=lambda s: abs(s - raw))


def _scenery_struct(container) -> render.RenderScenery:
    s = render.RenderScenery()
    s.background = wp.vec3(*BACKGROUND)
    s.floor_color = wp.vec3(0.55, 0.58, 0.63)
    s.floor_alpha = 0.18
    s.edge_color = wp.vec3(0.25, 0.27, 0.30)
    s.edge_alpha = 0.7
    s.has_container = 0
    s.container_lo = wp.vec3(0.0)
    s.container_hi = wp.vec3(0.0)
    s.floor_spacing = 1.0
    if container is not None:
        lo, hi = (np.asarray(c, dtype=np.float64).reshape(3) for c in container)
        if not np.all(hi > lo):
            raise PreviewError(f"container must have min < max on every axis, got {lo.tolist()} .. {hi.tolist()}")
        s.has_container = 1
        s.container_lo = wp.vec3(*lo)
        s.container_hi = wp.vec3(*hi)
        s.floor_spacing = _nice_spacing(float(max(hi[0] - lo[0], hi[1] - lo[1])))
    return s


def check_size(size) -> tuple[int, int]:
    """(width, height) [pixels] of ``size``, refused with PreviewError below 1 pixel."""
    width, height = (int(v) for v in size)
    if width < 1 or height < 1:
        raise PreviewError(f"image size must be (width, height) >= 1 pixel, got {size}")
    return width, height


def _to_uint8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)


def particle_colors(colors, count: int) -> np.ndarray:
    """(count, 3) float32 RGB in [0, 1] from ``colors`` as ``render_particles`` takes them (None: water blue)."""
    if colors is None:
        return np.tile(np.asarray(PARTICLE_COLOR, dtype=np.float32), (count, 1))
    c = np.asarray(colors)
    scale = 255.0 if np.issubdtype(c.dtype, np.integer) else 1.0
    c = c.astype(np.float32) / scale
    if c.shape == (3,):
        c = np.tile(c, (count, 1))
    if c.shape != (count, 3):
        raise PreviewError(f"colors must have shape (3,) or ({count}, 3), got {np.shape(colors)}")
    return c


class _SphereGrid:
    """Uniform grid listing each sphere in every cell its bounding box overlaps (cell >= 2 r)."""

    def __init__(self, particle_x: wp.array, x_host: np.ndarray, radius: float, device):
        count = x_host.shape[0]
        if count:
            lo = x_host.min(axis=0).astype(np.float64) - radius
            hi = x_host.max(axis=0).astype(np.float64) + radius
        else:
            lo = hi = np.zeros(3)
        extent = np.maximum(hi - lo, 2.0 * radius)
        max_cells = max(64, 4 * count)
        cell = max(2.0 * radius * (1.0 + 1.0e-5), (float(np.prod(extent)) / max_cells) ** (1.0 / 3.0))
        cell = max(cell, float(extent.max()) / 1024.0)
        dims = np.clip(np.ceil(extent / cell).astype(np.int64), 1, 1024)
        self.lo = wp.vec3(*lo)
        self.cell_size = float(cell)
        self.dims = wp.vec3i(*(int(d) for d in dims))
        cells = int(np.prod(dims))
        self.cell_count = wp.zeros(cells, dtype=wp.int32, device=device)
        self.cell_start = wp.empty(cells, dtype=wp.int32, device=device)
        self.cell_particles = wp.empty(max(8 * count, 1), dtype=wp.int32, device=device)
        if count == 0:
            self.cell_start.zero_()
            return
        grid_args = [particle_x, float(radius), self.lo, self.cell_size, self.dims]
        launch(render.count_sphere_cells, count, grid_args, [self.cell_count], device=device)
        wp.utils.array_scan(self.cell_count, self.cell_start, inclusive=False)
        fill = wp.zeros(cells, dtype=wp.int32, device=device)
        launch(render.fill_sphere_cells, count, [*grid_args, self.cell_start], [fill, self.cell_particles],
               device=device)


def render_particles(
    particle_x: np.ndarray,
    radius: float,
    camera: Camera,
    size: tuple[int, int] = DEFAULT_SIZE,
    container: tuple | None = None,
    colors: np.ndarray | None = None,
    device="cpu",
    *,
    light: Light | None = None,
    solids: Sequence[tuple[np.ndarray, np.ndarray]] = (),
    solid_color=OBSTACLE_COLOR,
) -> np.ndarray:
    """Ray trace particles as spheres; returns an (H, W, 3) uint8 RGB image, row 0 at the top.

    particle_x: positions [m], shape (N, 3); radius: sphere radius [m]; container: (lo, hi) [m]
    drawn as faint edges and a gridded floor, or None; colors: (N, 3) or (3,) RGB, floats in
    [0, 1] or integers in [0, 255], default water blue; solids: obstacle and body meshes (vertices [m],
    triangles[, RGB colour]) drawn flat-shaded in their colour, default ``solid_color``.
    """
    width, height = check_size(size)
    x = np.ascontiguousarray(np.asarray(particle_x, dtype=np.float32).reshape(-1, 3))
    if not (radius > 0.0 and math.isfinite(radius)):
        raise PreviewError(f"particle radius must be > 0 [m], got {radius}")
    if not np.all(np.isfinite(x)):
        raise PreviewError("particle positions contain non-finite values")
    colors_host = particle_colors(colors, x.shape[0])
    device = wp.get_device(device)
    cam = _camera_struct(camera, (width, height))
    particle_x_wp = wp.array(x, dtype=wp.vec3, device=device) if len(x) else wp.zeros(1, dtype=wp.vec3, device=device)
    particle_color = wp.array(colors_host if len(x) else np.zeros((1, 3)), dtype=wp.vec3, device=device)
    grid = _SphereGrid(particle_x_wp, x, float(radius), device)
    solids = [s for s in solids if len(s[1])]
    solid_v = [np.asarray(s[0], dtype=np.float32).reshape(-1, 3) for s in solids]
    solid_t = [np.asarray(s[1], dtype=np.int32).reshape(-1, 3) for s in solids]
    has_solid = int(len(solid_t) > 0)
    face_color = np.zeros((1, 3), np.float32)
    if has_solid:
        offsets = np.cumsum([0] + [len(v) for v in solid_v[:-1]])
        solid_mesh = wp.Mesh(points=wp.array(np.concatenate(solid_v), dtype=wp.vec3, device=device),
                             indices=wp.array(np.concatenate([t + o for t, o in zip(solid_t, offsets)]).reshape(-1),
                                              dtype=wp.int32, device=device))
        solid_id = solid_mesh.id
        face_color = np.concatenate([np.tile(np.asarray(s[2] if len(s) > 2 else solid_color, np.float32), (len(t), 1))
                                     for s, t in zip(solids, solid_t)])
    else:
        solid_id = wp.uint64(0)
    image = wp.empty((height, width), dtype=wp.vec3, device=device)
    launch(
        render.trace_particles,
        (height, width),
        [
            cam,
            _light_struct(light, cam),
            _scenery_struct(container),
            particle_x_wp,
            particle_color,
            float(radius),
            grid.lo,
            grid.cell_size,
            grid.dims,
            grid.cell_start,
            grid.cell_count,
            grid.cell_particles,
            solid_id,
            has_solid,
            wp.array(face_color, dtype=wp.vec3, device=device),
        ],
        [image],
        device=device,
    )
    return _to_uint8(image.numpy())


def _vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (unit; zero where no face touches the vertex)."""
    p0, p1, p2 = (vertices[triangles[:, k]].astype(np.float64) for k in range(3))
    face_normal = np.cross(p1 - p0, p2 - p0)  # length = 2 * area
    normals = np.zeros((len(vertices), 3))
    for k in range(3):
        np.add.at(normals, triangles[:, k], face_normal)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return (normals / np.where(length > 0.0, length, 1.0)).astype(np.float32)


def render_mesh(
    vertices: np.ndarray,
    triangles: np.ndarray,
    camera: Camera,
    size: tuple[int, int] = DEFAULT_SIZE,
    container: tuple | None = None,
    device="cpu",
    *,
    color=SURFACE_COLOR,
    light: Light | None = None,
    solids: Sequence[tuple[np.ndarray, np.ndarray]] = (),
    solid_color=OBSTACLE_COLOR,
) -> np.ndarray:
    """Ray trace a triangle mesh (smooth normals, two-sided); returns an (H, W, 3) uint8 image.

    vertices: (V, 3) [m]; triangles: (T, 3) vertex indices; container as in ``render_particles``.
    solids: obstacle and body meshes (vertices [m], triangles[, RGB colour]) drawn flat-shaded in their
    colour, default ``solid_color``.
    """
    width, height = check_size(size)
    v = np.ascontiguousarray(np.asarray(vertices, dtype=np.float32).reshape(-1, 3))
    tri = np.ascontiguousarray(np.asarray(triangles, dtype=np.int32).reshape(-1, 3))
    if len(tri) and (tri.min() < 0 or tri.max() >= len(v)):
        raise PreviewError(f"triangle indices must lie in [0, {len(v)}), got [{tri.min()}, {tri.max()}]")
    colors = [np.tile(np.asarray(color, dtype=np.float32), (len(tri), 1))]
    for solid in solids:  # unshared vertices per triangle: vertex normals = face normals (flat)
        sv, st = solid[0], solid[1]
        sv = np.asarray(sv, dtype=np.float32).reshape(-1, 3)
        st = np.asarray(st, dtype=np.int64).reshape(-1, 3)
        if len(st) == 0:
            continue
        if st.min() < 0 or st.max() >= len(sv):
            raise PreviewError(f"obstacle triangle indices must lie in [0, {len(sv)})")
        tri = np.concatenate([tri, (len(v) + np.arange(3 * len(st), dtype=np.int32)).reshape(-1, 3)])
        v = np.concatenate([v, sv[st.reshape(-1)]])
        colors.append(np.tile(np.asarray(solid[2] if len(solid) > 2 else solid_color, dtype=np.float32), (len(st), 1)))
    face_colors = np.ascontiguousarray(np.concatenate(colors)) if len(tri) else np.zeros((1, 3), np.float32)
    device = wp.get_device(device)
    cam = _camera_struct(camera, (width, height))
    has_mesh = int(len(tri) > 0)
    if has_mesh:
        points = wp.array(v, dtype=wp.vec3, device=device)
        indices = wp.array(tri.reshape(-1), dtype=wp.int32, device=device)
        mesh = wp.Mesh(points=points, indices=indices)
        mesh_id = mesh.id
        normals = wp.array(_vertex_normals(v, tri), dtype=wp.vec3, device=device)
    else:
        indices = wp.zeros(3, dtype=wp.int32, device=device)
        normals = wp.zeros(1, dtype=wp.vec3, device=device)
        mesh_id = wp.uint64(0)
    face_color = wp.array(face_colors, dtype=wp.vec3, device=device)
    image = wp.empty((height, width), dtype=wp.vec3, device=device)
    launch(
        render.trace_mesh,
        (height, width),
        [
            cam,
            _light_struct(light, cam),
            _scenery_struct(container),
            mesh_id,
            indices,
            normals,
            has_mesh,
            face_color,
        ],
        [image],
        device=device,
    )
    return _to_uint8(image.numpy())
