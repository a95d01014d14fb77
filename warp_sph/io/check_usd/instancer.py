"""The UsdGeomPointInstancer prim (static in Blender 4.2: a warning)."""
from __future__ import annotations

import numpy as np
from pxr import UsdGeom

from .common import Report, TimeIssues, _get, _np
from .points import check_per_point_array, check_samples, read_points


def check_instancer_prim(pi: UsdGeom.PointInstancer, frame_range, rep: Report, min_frames: int) -> dict:
    path = str(pi.GetPath())
    prim = {"path": path, "type": "PointInstancer", "errors": [], "warnings": []}
    rep.warn(f"{path}: PointInstancer found; Blender imports it as a point cloud + Geometry Nodes "
             "'Instance on Points', and Blender 4.2 LTS reads only its first time sample (static; 5.0.1 "
             "animates it); the SPH export should use UsdGeomPoints", prim)
    times = check_samples(pi.GetPositionsAttr(), "positions", path, frame_range, rep, prim, min_frames)
    issues = TimeIssues()
    pts_by_time = read_points(pi.GetPositionsAttr(), times, path, rep, prim, issues)
    n_proto = len(pi.GetPrototypesRel().GetTargets())
    for t in times:
        pts = pts_by_time.get(t)
        pidx = _np(_get(pi.GetProtoIndicesAttr(), t), np.int64)
        if pts is None:
            continue
        if pidx is None:
            issues.add("'protoIndices' not authored", t)
        elif len(pidx) != len(pts):
            issues.add("'protoIndices' length != number of positions", t, f"{len(pidx)} for {len(pts)}")
        elif len(pidx) and (pidx.min() < 0 or pidx.max() >= n_proto):
            issues.add(f"'protoIndices' out of range for {n_proto} prototypes", t)
    for a, nm in ((pi.GetScalesAttr(), "scales"), (pi.GetOrientationsAttr(), "orientations"),
                  (pi.GetVelocitiesAttr(), "velocities")):
        check_per_point_array(a, nm, path, times, pts_by_time, issues)
    issues.flush(rep, prim, path)
    # instancer extent includes prototype bounds; only check that it is authored
    if not pi.GetExtentAttr().HasAuthoredValue():
        rep.warn(f"{path}: 'extent' is not authored", prim)
    return prim
