"""Preview pictures: look at a run without leaving the terminal.

``preview_run`` ray traces recorded frames of a run folder into PNG (and GIF) files, headless:
particles coloured by speed, or the reconstructed surface mesh, with the obstacles and moving
bodies. The pieces: ``render.py`` (the ray tracer, host half of ``kernels/render.py``),
``run_files.py`` (reading the run folder), ``images.py`` (PNG/GIF files; Pillow, the optional extra
``warp-sph[preview]``). Their public names are re-exported here.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.atomic import not_a_folder
from .images import save_gif, save_png
from .render import (
    BACKGROUND,
    DEFAULT_SIZE,
    OBSTACLE_COLOR,
    PARTICLE_COLOR,
    SURFACE_COLOR,
    Camera,
    Light,
    PreviewError,
    auto_camera,
    check_size,
    particle_colors,
    render_mesh,
    render_particles,
)
from .run_files import (
    BODY_COLOR,
    SPRAY_PRIM,
    SURFACE_PRIM,
    SurfaceReader,
    body_meshes,
    load_frame,
    obstacle_meshes,
    read_run,
)

FAST_PARTICLE_COLOR = (0.80, 0.92, 1.00)  # foam white-blue for the fastest particles

__all__ = ["BACKGROUND", "BODY_COLOR", "DEFAULT_SIZE", "FAST_PARTICLE_COLOR", "OBSTACLE_COLOR", "PARTICLE_COLOR",
           "SPRAY_PRIM", "SURFACE_COLOR", "SURFACE_PRIM", "Camera", "Light", "PreviewError", "SurfaceReader",
           "auto_camera", "body_meshes", "load_frame", "obstacle_meshes", "preview_run", "render_mesh",
           "render_particles", "save_gif", "save_png", "speed_colors"]


def speed_colors(v: np.ndarray | None, speed_scale: float, count: int) -> np.ndarray:
    """Water blue for slow particles, fading to foam white at ``speed_scale`` [m/s] and above."""
    if v is None or speed_scale <= 0.0:
        return particle_colors(None, count)
    s = np.clip(np.linalg.norm(v, axis=1) / speed_scale, 0.0, 1.0)[:, None] ** 0.75
    return ((1.0 - s) * np.asarray(PARTICLE_COLOR) + s * np.asarray(FAST_PARTICLE_COLOR)).astype(np.float32)


def _check_out_dir(out_dir: Path) -> None:
    """Refuse, before any rendering, an output folder that is a file or lies under one (nothing is
    written beside it or over it)."""
    where = not_a_folder(out_dir)
    if where:
        raise PreviewError(f"--out {out_dir} {where}, not a folder; preview writes its PNG files (and GIF) into a "
                           "folder: choose a new or existing folder")


def _check_not_users(out_dir: Path, run_dir: Path, names: list[str], overwrite: bool) -> None:
    """Refuse, before any rendering, to replace a file in a folder other than the run's own
    ``preview/`` (where these names are the run's files, ``run_folder.RUN_FILE_PATTERNS``) unless
    ``overwrite``: a picture a user keeps under one of those names is never replaced silently."""
    if overwrite or out_dir.resolve() == (run_dir / "preview").resolve():
        return
    there = [n for n in names if (out_dir / n).exists()]
    if there:
        more = f" (and {len(there) - 1} more of the files it would write)" if len(there) > 1 else ""
        raise PreviewError(f"--out {out_dir} already holds {there[0]}{more}; pass --overwrite to replace them, or "
                           f"choose another --out (previews in the run's own folder {run_dir / 'preview'} are "
                           "replaced without asking)")


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
    overwrite: bool = False,
) -> list[Path]:
    """Render recorded frames of a run folder to ``out/<mode>_{frame:06d}.png``; returns the paths written.

    frames: frame numbers; None means the last recorded frame (every recorded frame when ``gif``).
    mode: "particles" (spheres coloured by speed) or "surface" (the USD surface mesh).
    camera: None frames the container (or, without one, the fluid over all chosen frames).
    out: output folder, default ``run_dir/preview``. gif: also write ``out/<mode>.gif`` when more
    than one frame is rendered, at ``fps`` (default: the scene's frame rate). The mode is in every
    file name, so particle and surface previews of one frame sit side by side.
    overwrite: replace files of those names in an ``out`` other than ``run_dir/preview`` (otherwise
    PreviewError before rendering); the run's own preview folder is always rewritten.
    """
    run_dir = Path(run_dir)
    if mode not in ("particles", "surface"):
        raise PreviewError(f"preview mode must be 'particles' or 'surface', got {mode!r}")
    size = check_size(size)
    meta, recorded = read_run(run_dir)
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
    _check_out_dir(out_dir)
    names = [f"{mode}_{frame:06d}.png" for frame in frames] + ([f"{mode}.gif"] if gif and len(frames) > 1 else [])
    _check_not_users(out_dir, run_dir, names, overwrite)

    surface = SurfaceReader(run_dir) if mode == "surface" else None
    solids = obstacle_meshes(run_dir, scene, surface)
    bodies = body_meshes(meta)  # moving rigid bodies, per frame

    def load(frame):
        if surface is not None:
            return surface.frame(frame)
        return load_frame(run_dir, frame)

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
            x, v = load_frame(run_dir, frame)
            colors = speed_colors(v, speed_scale, len(x))
            image = render_particles(x, radius, camera, size, container, colors, device, light=light,
                                     solids=solids + bodies.get(frame, []))
        written.append(save_png(image, out_dir / f"{mode}_{frame:06d}.png"))
        if gif:
            images.append(image)
    if gif and len(images) > 1:
        rate = float(fps if fps is not None else scene.get("fps", 30.0))
        written.append(save_gif(images, out_dir / f"{mode}.gif", rate))
    return written
