"""Preview pictures: look at a run without leaving the terminal.

Ray traces recorded frames into PNG (and GIF) files, headless, on Warp's CPU backend or unchanged on
CUDA: particles as exact spheres, or the reconstructed surface mesh, shaded with Blinn-Phong (report
section 3, eq. 2-6, and section 6), with the container drawn faintly. Device code lives in
``kernels/render.py``; this module builds the camera, light and acceleration grid and launches it.

Pillow, needed only to write image files, is the optional extra ``warp-sph[preview]``.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import warp as wp

from ..core.errors import WarpSphError
from ..kernels import render

DEFAULT_SIZE = (640, 360)
PARTICLE_COLOR = (0.16, 0.42, 0.78)  # water blue, linear [0, 1]
FAST_PARTICLE_COLOR = (0.80, 0.92, 1.00)  # foam white-blue for the fastest particles
SURFACE_COLOR = (0.22, 0.50, 0.85)
OBSTACLE_COLOR = (0.62, 0.58, 0.52)  # stone grey for obstacles in surface previews
BODY_COLOR = (0.78, 0.45, 0.18)  # orange-brown wood for moving rigid bodies
BACKGROUND = (0.93, 0.94, 0.96)
SURFACE_PRIM = "/sph/surface"
SPRAY_PRIM = "/sph/spray"


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


def _check_size(size) -> tuple[int, int]:
    width, height = (int(v) for v in size)
    if width < 1 or height < 1:
        raise PreviewError(f"image size must be (width, height) >= 1 pixel, got {size}")
    return width, height


def _to_uint8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)


def _particle_colors(colors, count: int) -> np.ndarray:
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
        wp.launch(render.count_sphere_cells, dim=count, inputs=grid_args, outputs=[self.cell_count], device=device)
        wp.utils.array_scan(self.cell_count, self.cell_start, inclusive=False)
        fill = wp.zeros(cells, dtype=wp.int32, device=device)
        wp.launch(
            render.fill_sphere_cells,
            dim=count,
            inputs=[*grid_args, self.cell_start],
            outputs=[fill, self.cell_particles],
            device=device,
        )


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
    width, height = _check_size(size)
    x = np.ascontiguousarray(np.asarray(particle_x, dtype=np.float32).reshape(-1, 3))
    if not (radius > 0.0 and math.isfinite(radius)):
        raise PreviewError(f"particle radius must be > 0 [m], got {radius}")
    if not np.all(np.isfinite(x)):
        raise PreviewError("particle positions contain non-finite values")
    colors_host = _particle_colors(colors, x.shape[0])
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
    wp.launch(
        render.trace_particles,
        dim=(height, width),
        inputs=[
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
        outputs=[image],
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
    width, height = _check_size(size)
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
    wp.launch(
        render.trace_mesh,
        dim=(height, width),
        inputs=[
            cam,
            _light_struct(light, cam),
            _scenery_struct(container),
            mesh_id,
            indices,
            normals,
            has_mesh,
            face_color,
        ],
        outputs=[image],
        device=device,
    )
    return _to_uint8(image.numpy())


def _pil():
    try:
        from PIL import Image
    except ImportError as err:
        raise PreviewError(
            "writing preview images needs Pillow, the optional extra warp-sph[preview]: in the checkout, "
            "pip install -e '.[preview]' (into the environment warp-sph runs in, e.g. .venv/bin/pip)"
        ) from err
    return Image


def _atomic_save(path, save) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        save(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def _check_image(image) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise PreviewError(f"expected an (H, W, 3) uint8 image, got shape {image.shape} dtype {image.dtype}")
    return image


def save_png(image: np.ndarray, path) -> Path:
    """Write an (H, W, 3) uint8 image as PNG, atomically (temporary file, then rename)."""
    Image = _pil()
    picture = Image.fromarray(_check_image(image))
    return _atomic_save(path, lambda tmp: picture.save(tmp, format="PNG"))


def save_gif(images: Sequence[np.ndarray], path, fps: float) -> Path:
    """Write (H, W, 3) uint8 images as a looping GIF at ``fps`` frames per second, atomically."""
    Image = _pil()
    if not images:
        raise PreviewError("a GIF needs at least one image")
    if not fps > 0.0:
        raise PreviewError(f"GIF fps must be > 0, got {fps}")
    pictures = [Image.fromarray(_check_image(im)) for im in images]
    duration = max(int(round(1000.0 / fps)), 20)
    return _atomic_save(
        path,
        lambda tmp: pictures[0].save(
            tmp, format="GIF", save_all=True, append_images=pictures[1:], duration=duration, loop=0
        ),
    )


def _read_run(run_dir: Path) -> tuple[dict, list[int]]:
    meta_path = run_dir / "run.json"
    if not meta_path.is_file():
        raise PreviewError(f"{run_dir} is not a run folder: {meta_path.name} is missing")
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError as err:
        raise PreviewError(f"{meta_path}: not valid JSON ({err})") from err
    if "frames" in meta:
        recorded = sorted(int(f["frame"]) for f in meta["frames"])
    else:
        recorded = sorted(int(p.stem.split("_")[-1]) for p in (run_dir / "frames").glob("frame_*.npz"))
    return meta, recorded


def _frame_path(run_dir: Path, frame: int) -> Path:
    return run_dir / "frames" / f"frame_{frame:06d}.npz"


def _load_frame(run_dir: Path, frame: int) -> tuple[np.ndarray, np.ndarray | None]:
    path = _frame_path(run_dir, frame)
    if not path.is_file():
        raise PreviewError(f"frame {frame} is listed but its file {path} is missing")
    with np.load(path) as data:
        return np.asarray(data["x"], dtype=np.float32), (np.asarray(data["v"]) if "v" in data else None)


class _SurfaceReader:
    """The surface mesh (prim /sph/surface) of a run's USD file, one time sample per frame."""

    def __init__(self, run_dir: Path):
        from pxr import Usd, UsdGeom

        files = sorted(p for ext in ("usdc", "usd", "usda") for p in run_dir.glob(f"*.{ext}"))
        if not files:
            raise PreviewError(f"surface preview needs the run's USD file, none found in {run_dir}")
        try:  # the run's own file (named after its scene) before any other USD in the folder
            from ..io.run_folder import safe_name

            own = run_dir / f"{safe_name(json.loads((run_dir / 'run.json').read_text())['scene']['name'])}.usdc"
        except (OSError, ValueError, KeyError, TypeError):
            own = None
        self.path = own if own is not None and own.is_file() else files[0]
        self._usd = Usd
        try:
            self.stage = Usd.Stage.Open(str(self.path))
        except Exception as exc:  # pxr's Tf.ErrorException: a damaged file
            lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
            raise PreviewError(f"{self.path} does not open: {lines[0] if lines else exc}") from None
        prim = self.stage.GetPrimAtPath(SURFACE_PRIM)
        if not prim or not prim.IsValid():
            raise PreviewError(
                f"{self.path} has no surface mesh at {SURFACE_PRIM} (was the run made without surface export?)"
            )
        self.mesh = UsdGeom.Mesh(prim)
        self._geom = UsdGeom
        parent = self.stage.GetPrimAtPath(SURFACE_PRIM).GetParent()
        #: obstacle meshes beside the surface (the container is drawn as the box outline)
        self.solid_prims = [p for p in parent.GetChildren() if p.IsA(UsdGeom.Mesh)
                            and p.GetName() not in ("surface", "container")]

    def _world(self, prim, points: np.ndarray, time) -> np.ndarray:
        """Points of ``prim`` in world coordinates [m] (a run far from the origin writes them
        relative to /sph's translate), in float64 until the renderer takes them."""
        m = np.asarray(self._geom.XformCache(time).GetLocalToWorldTransform(prim), dtype=np.float64)
        if np.array_equal(m, np.eye(4)):
            return points
        return points.astype(np.float64) @ m[:3, :3] + m[3, :3]

    def frame(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Surface mesh of ``frame`` [m], with the spray points (/sph/spray) added as small spheres of
        their width, so the preview shows what a render with a foam material would."""
        points_attr = self.mesh.GetPointsAttr()
        if frame not in {int(round(t)) for t in points_attr.GetTimeSamples()} and points_attr.GetNumTimeSamples():
            raise PreviewError(f"{self.path}: {SURFACE_PRIM} has no surface for frame {frame}")
        time = self._usd.TimeCode(frame)
        points = np.asarray(points_attr.Get(time) or [], dtype=np.float32).reshape(-1, 3)
        counts = np.asarray(self.mesh.GetFaceVertexCountsAttr().Get(time) or [], dtype=np.int64)
        indices = np.asarray(self.mesh.GetFaceVertexIndicesAttr().Get(time) or [], dtype=np.int64)
        points = self._world(self.mesh.GetPrim(), points, time)
        triangles = _triangulate(counts, indices)
        spray = self.stage.GetPrimAtPath(SPRAY_PRIM)
        if spray and spray.IsValid():
            sp = self._geom.Points(spray)
            centers = np.asarray(sp.GetPointsAttr().Get(time) or [], dtype=np.float32).reshape(-1, 3)
            widths = np.asarray(sp.GetWidthsAttr().Get(time) or [0.0], dtype=np.float32)
            if len(centers):
                sv, st = _sphere_mesh(self._world(spray, centers, time),
                                      0.5 * (widths if len(widths) == len(centers) else widths[:1]))
                triangles = np.concatenate([triangles, st + len(points)])
                points = np.concatenate([points, sv.astype(points.dtype)])
        return points, triangles

    def first_time(self) -> float:
        times = self.mesh.GetPointsAttr().GetTimeSamples()
        return float(times[0]) if times else 1.0

    def solids(self, frame: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Obstacle meshes (world vertices [m], triangles) at ``frame``."""
        out = []
        time = self._usd.TimeCode(frame)
        for prim in self.solid_prims:
            mesh = self._geom.Mesh(prim)
            points = np.asarray(mesh.GetPointsAttr().Get(time) or [], dtype=np.float32).reshape(-1, 3)
            counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(time) or [], dtype=np.int64)
            indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(time) or [], dtype=np.int64)
            if len(points) and len(counts):
                out.append((self._world(prim, points, time), _triangulate(counts, indices)))
        return out


def _obstacles(run_dir: Path, scene: dict, surface) -> list[tuple[np.ndarray, np.ndarray]]:
    """The run's obstacle meshes in world coordinates [m]: from its USD (where they were written)
    when there is one, else from the scene in run.json (mesh files loaded again)."""
    if surface is None:
        try:
            surface = _SurfaceReader(run_dir)
        except PreviewError:
            surface = None
    if surface is not None:
        return surface.solids(surface.first_time())
    from ..io.reexport import scene_static_meshes

    return [(v, t) for name, v, t in scene_static_meshes(scene) if name != "container"]


def _bodies(meta: dict) -> dict[int, list[tuple[np.ndarray, np.ndarray, tuple]]]:
    """{frame: [(world vertices [m], triangles, BODY_COLOR), ...]}: each rigid body of the run's scene
    (its shape in the body frame, ``rigid.spec.body_geometry``) at the pose run.json recorded for the frame."""
    entries = (meta.get("scene") or {}).get("bodies") or []
    if not entries:
        return {}
    from ..rigid.spec import Body, body_geometry, body_name, quat_to_matrix

    shapes = {}
    for i, entry in enumerate(entries):
        try:
            geo = body_geometry(Body(**entry))
        except Exception as exc:  # a mesh file moved away since the run
            raise PreviewError(f"bodies[{i}] of run.json cannot be drawn: {' '.join(str(exc).split())[:160]}") from None
        shapes[body_name(Body(**entry), i)] = geo
    out = {}
    for record in meta.get("frames") or []:
        solids = []
        for name, pose in (record.get("bodies") or {}).items():
            geo = shapes.get(name)
            if geo is None:
                continue
            R = quat_to_matrix(pose["orientation"])
            solids.append((geo.vertices @ R.T + np.asarray(pose["position"]), geo.triangles, BODY_COLOR))
        out[int(record["frame"])] = solids
    return out


def _sphere_mesh(centers: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Icospheres (42 vertices, 80 faces each, wound outward) at ``centers`` [m] with ``radii`` [m]."""
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
                  [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
                  [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    edges = {}
    verts = list(v)
    faces = []
    for a, b, c in f:  # one subdivision: midpoints shared through ``edges``
        m = []
        for p, q in ((a, b), (b, c), (c, a)):
            key = (min(p, q), max(p, q))
            if key not in edges:
                edges[key] = len(verts)
                verts.append(0.5 * (v[p] + v[q]))
            m.append(edges[key])
        faces += [[a, m[0], m[2]], [b, m[1], m[0]], [c, m[2], m[1]], m]
    unit = np.asarray(verts)
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    faces = np.asarray(faces, dtype=np.int64)
    n = len(centers)
    pts = centers[:, None, :] + np.broadcast_to(np.asarray(radii, np.float64).reshape(-1, 1, 1), (n, 1, 1)) * unit[None]
    tris = faces[None] + (np.arange(n) * len(unit))[:, None, None]
    return pts.reshape(-1, 3), tris.reshape(-1, 3).astype(np.int32)


def _triangulate(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Fan-triangulate USD faces (faceVertexCounts, faceVertexIndices) into (T, 3)."""
    if len(counts) == 0:
        return np.zeros((0, 3), dtype=np.int32)
    if np.all(counts == 3):
        return indices.reshape(-1, 3).astype(np.int32)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tris = [
        (indices[s], indices[s + k], indices[s + k + 1]) for s, n in zip(starts, counts) for k in range(1, n - 1)
    ]
    return np.asarray(tris, dtype=np.int32).reshape(-1, 3)


def _speed_colors(v: np.ndarray | None, speed_scale: float, count: int) -> np.ndarray:
    """Water blue for slow particles, fading to foam white at ``speed_scale`` [m/s] and above."""
    if v is None or speed_scale <= 0.0:
        return _particle_colors(None, count)
    s = np.clip(np.linalg.norm(v, axis=1) / speed_scale, 0.0, 1.0)[:, None] ** 0.75
    return ((1.0 - s) * np.asarray(PARTICLE_COLOR) + s * np.asarray(FAST_PARTICLE_COLOR)).astype(np.float32)


def preview_run(
    run_dir,
    frames: list[int] | None = None,
    mode: str = "particles",
    camera: Camera | None = None,
    size: tuple[int, int] = DEFAULT_SIZE,
    out=None,
    *,
    gif: bool = False,
    fps: float | None = None,
    device="cpu",
    light: Light | None = None,
) -> list[Path]:
    """Render recorded frames of a run folder to ``out/<mode>_{frame:06d}.png``; returns the paths written.

    frames: frame numbers; None means the last recorded frame (every recorded frame when ``gif``).
    mode: "particles" (spheres coloured by speed) or "surface" (the USD surface mesh).
    camera: None frames the container (or, without one, the fluid over all chosen frames).
    out: output folder, default ``run_dir/preview``. gif: also write ``out/preview.gif`` when more
    than one frame is rendered, at ``fps`` (default: the scene's frame rate). The mode is in every
    file name, so particle and surface previews of one frame sit side by side.
    """
    run_dir = Path(run_dir)
    if mode not in ("particles", "surface"):
        raise PreviewError(f"preview mode must be 'particles' or 'surface', got {mode!r}")
    size = _check_size(size)
    meta, recorded = _read_run(run_dir)
    if not recorded:
        raise PreviewError(f"{run_dir} has no recorded frames yet")
    if frames is None:
        frames = list(recorded) if gif else [recorded[-1]]
    frames = [int(f) for f in frames]
    missing = sorted(set(frames) - set(recorded))
    if missing:
        raise PreviewError(
            f"frames {missing} are not recorded in {run_dir}; recorded: {recorded[0]}..{recorded[-1]} "
            f"({len(recorded)} frames)"
        )
    scene = meta.get("scene", {})
    radius = float(scene.get("particle_radius", 0.0))
    box = scene.get("container")
    container = (box["min"], box["max"]) if box else None
    out_dir = Path(out) if out is not None else run_dir / "preview"

    surface = _SurfaceReader(run_dir) if mode == "surface" else None
    solids = _obstacles(run_dir, scene, surface)
    bodies = _bodies(meta)  # moving rigid bodies, per frame

    def load(frame):
        if surface is not None:
            return surface.frame(frame)
        return _load_frame(run_dir, frame)

    speed_scale = 0.0
    if camera is None or mode == "particles":
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for frame in frames:
            first, second = load(frame)
            if len(first):
                lo, hi = np.minimum(lo, first.min(axis=0)), np.maximum(hi, first.max(axis=0))
            if surface is None and second is not None and len(second):
                speed_scale = max(speed_scale, float(np.percentile(np.linalg.norm(second, axis=1), 99.0)))
        if camera is None:
            if container is not None:
                lo, hi = np.asarray(container[0], float), np.asarray(container[1], float)
            elif not np.all(np.isfinite(lo)):
                lo, hi = np.zeros(3), np.ones(3)
            camera = auto_camera(lo - radius, hi + radius, aspect=size[0] / size[1])
    if mode == "particles" and not radius > 0.0:
        raise PreviewError(f"{run_dir / 'run.json'}: scene.particle_radius must be > 0, got {radius}")

    images, written = [], []
    for frame in frames:
        if surface is not None:
            vertices, triangles = surface.frame(frame)
            image = render_mesh(vertices, triangles, camera, size, container, device, light=light,
                                solids=solids + bodies.get(frame, []))
        else:
            x, v = _load_frame(run_dir, frame)
            colors = _speed_colors(v, speed_scale, len(x))
            image = render_particles(x, radius, camera, size, container, colors, device, light=light,
                                     solids=solids + bodies.get(frame, []))
        written.append(save_png(image, out_dir / f"{mode}_{frame:06d}.png"))
        if gif:
            images.append(image)
    if gif and len(images) > 1:
        rate = float(fps if fps is not None else scene.get("fps", 30.0))
        written.append(save_gif(images, out_dir / f"{mode}.gif", rate))
    return written
