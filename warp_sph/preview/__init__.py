"""Headless previews of a run: particles and surface ray-cast with Warp, saved as PNG and GIF."""
from .render_run import Camera, Light, PreviewError, auto_camera, preview_run, render_mesh, render_particles, save_gif, save_png

__all__ = ["Camera", "Light", "PreviewError", "auto_camera", "preview_run", "render_mesh", "render_particles",
           "save_gif", "save_png"]
