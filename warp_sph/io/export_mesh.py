"""Surface mesh sequences through meshio: one file per frame, ``surface_{frame:06d}.{fmt}``.

Each file is written to a temporary file in the same folder and moved into place with
``os.replace`` (atomic on POSIX and Windows), so a crash never leaves a half-written frame under
the final name.
"""
from __future__ import annotations

import os

import meshio
import numpy as np

from ..core.errors import OutputError
from . import atomic

#: format name -> meshio file_format
MESH_FORMATS = {"obj": "obj", "ply": "ply", "vtk": "vtk"}


class MeshSequenceWriter:
    """Writes the fluid surface of each frame as ``folder/surface_{frame:06d}.{fmt}``.

    Args:
        folder: output folder (created if missing).
        fmt: "obj", "ply" (binary) or "vtk" (legacy, binary).
    """

    def __init__(self, folder, fmt: str = "obj"):
        if fmt not in MESH_FORMATS:
            raise ValueError(f"unknown mesh format {fmt!r}; expected one of {', '.join(MESH_FORMATS)}")
        self.folder = os.fspath(folder)
        self.fmt = fmt
        try:
            os.makedirs(self.folder, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot create mesh output folder {self.folder}: {exc}") from exc

    def path(self, frame: int) -> str:
        """File of frame ``frame``."""
        return os.path.join(self.folder, f"surface_{int(frame):06d}.{self.fmt}")

    def write_frame(self, frame: int, vertices: np.ndarray, triangles: np.ndarray) -> str:
        """Write one frame's surface: vertices (V, 3) [m] (float32, or float64 kept as such),
        triangles (T, 3) (CCW from outside).

        Returns the path written. An empty surface gives a valid file with no faces.
        """
        verts = np.asarray(vertices)  # float64 kept (a scene far from the origin), else float32
        verts = np.ascontiguousarray(verts, dtype=np.float64 if verts.dtype == np.float64 else np.float32).reshape(-1, 3)
        tris = np.ascontiguousarray(triangles, dtype=np.int32).reshape(-1, 3)
        if len(tris) and (tris.min() < 0 or tris.max() >= len(verts)):
            raise ValueError(f"triangle indices out of range 0..{len(verts) - 1}")
        # an empty surface gets no cell block (meshio's VTK writer fails on an empty one)
        mesh = meshio.Mesh(verts, [("triangle", tris)] if len(tris) else [])
        final = self.path(frame)
        atomic.atomic_write_with(final, lambda tmp: meshio.write(tmp, mesh, file_format=MESH_FORMATS[self.fmt]))
        return final
