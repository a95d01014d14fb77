"""Writing preview images: PNG and looping GIF, atomically (temporary file, then rename).

Pillow, needed only here, is the optional extra ``warp-sph[preview]``.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from .render import PreviewError


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
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        save(tmp)
        os.replace(tmp, path)
    except OSError as exc:  # a read-only folder, a full disk, a folder of that name: one line
        raise PreviewError(f"cannot write {path}: {exc.strerror or exc}") from None
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
