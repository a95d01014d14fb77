"""The whitewater point sets of a run's USD file (``[whitewater]``, docs/whitewater.md):

    /sph/whitewater              Xform
    /sph/whitewater/spray        Points: points, velocities [m/s], extent (+/- width / 2), widths (constant
    /sph/whitewater/foam         interpolation, one value: point_width r), primvars:age [s] (vertex), all
    /sph/whitewater/bubbles      time-sampled every frame; the count changes per frame

A set that is empty at a frame holds one placeholder point, 1e-4 r wide, at rest, of age 0, at the
lowest fluid particle (as /sph/spray, ``usd_layout``): an empty Points sample is flagged by
``check_usd.py --strict`` and some importers. A Blender user gives each set its own material.
"""
from __future__ import annotations

import numpy as np
from pxr import Sdf, UsdGeom, Vt

from ..core.errors import OutputError
from .usd_layout import define_points, extent, vec3f

#: the parent prim and the sets under it
ROOT = "/sph/whitewater"
SETS = ("spray", "foam", "bubbles")


def define(stage, with_velocities: bool) -> None:
    """Create /sph/whitewater and its three Points prims (no samples yet)."""
    UsdGeom.Xform.Define(stage, ROOT)
    for name in SETS:
        points = define_points(stage, f"{ROOT}/{name}", with_velocities)
        UsdGeom.PrimvarsAPI(points).CreatePrimvar("age", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)


def check(stage, path: str, wanted: bool) -> None:
    """OutputError when a file to resume has (or lacks) the whitewater sets this run writes."""
    has = stage.GetPrimAtPath(ROOT).IsValid()
    if has != wanted:
        raise OutputError(f"cannot resume: {path} {'lacks' if wanted else 'has'} {ROOT}")


class WhitewaterPoints:
    """The bound attributes of the three sets; ``write`` adds one frame's samples."""

    def __init__(self, stage, with_velocities: bool):
        self.attrs = {}
        for name in SETS:
            points = UsdGeom.Points(stage.GetPrimAtPath(f"{ROOT}/{name}"))
            if not points:
                raise OutputError(f"{stage.GetRootLayer().realPath}: {ROOT}/{name} is not a Points prim")
            self.attrs[name] = (points.GetPointsAttr(), points.GetExtentAttr(), points.GetWidthsAttr(),
                                points.GetVelocitiesAttr() if with_velocities else None,
                                UsdGeom.PrimvarsAPI(points).GetPrimvar("age").GetAttr())

    def write(self, t, sets: dict, width: float, placeholder: np.ndarray, placeholder_width: float, local) -> int:
        """One frame: ``sets`` {name: (positions (K, 3) [m] world, velocities (K, 3) [m/s], ages (K,) [s])}
        (a missing name is empty), ``width`` [m] of their points; ``placeholder`` a point [m] in the file's
        coordinates and its width [m], written for an empty set; ``local`` turns
        world positions into the file's. Returns the bytes added (estimate)."""
        unknown = set(sets) - set(SETS)
        if unknown:
            raise ValueError(f"whitewater sets {sorted(unknown)}; expected some of {SETS}")
        added = 0
        for name, (points, ext, widths, velocities, age) in self.attrs.items():
            x, v, a = sets.get(name, (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)))
            x = local(x) if len(x) else np.zeros((0, 3), np.float32)
            v = np.ascontiguousarray(v, dtype=np.float32).reshape(-1, 3)
            a = np.ascontiguousarray(a, dtype=np.float32).reshape(-1)
            if not len(v) == len(a) == len(x):
                raise ValueError(f"whitewater {name}: {len(x)} points, {len(v)} velocities, {len(a)} ages")
            w = float(width)
            if len(x) == 0:
                x = np.asarray(placeholder, dtype=np.float32).reshape(1, 3)
                v, a, w = np.zeros((1, 3), np.float32), np.zeros(1, np.float32), float(placeholder_width)
            points.Set(vec3f(x), t)
            widths.Set(Vt.FloatArray([w]), t)
            ext.Set(extent(x, 0.5 * w), t)
            if velocities is not None:
                velocities.Set(vec3f(v), t)
            age.Set(Vt.FloatArray.FromNumpy(a), t)
            added += 2 * x.nbytes + a.nbytes + 96
        return added
