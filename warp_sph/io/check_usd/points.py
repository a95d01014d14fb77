"""Per-prim checks shared by every point-holding prim (time samples, extent, points, per-point arrays,
primvars) and the UsdGeomPoints prim."""
from __future__ import annotations

import numpy as np
from pxr import Usd, UsdGeom

from .common import MAX_TIMES_LISTED, Report, TimeIssues, _fmt_t, _get, _np, _sample_times


# --------------------------------------------------------------------------------------------
# per-prim checks
# --------------------------------------------------------------------------------------------

def check_samples(attr: Usd.Attribute, name: str, path: str, frame_range, rep: Report, prim: dict,
                  min_frames: int) -> list:
    """Check the time samples of the primary attribute; return the times to validate (None = default)."""
    times = _sample_times(attr)
    prim["n_samples"] = len(times)
    if times:
        prim["first_sample"], prim["last_sample"] = times[0], times[-1]
    if not attr or not attr.HasAuthoredValue():
        rep.error(f"{path}: '{name}' is not authored", prim)
        return []
    if not times:
        expected = frame_range[2] if frame_range else 1
        if expected > 1:
            rep.error(f"{path}: '{name}' has no time samples (static) but the stage spans {expected} frames", prim)
        else:
            rep.warn(f"{path}: '{name}' has only a default value, no time samples", prim)
        return [None]
    if frame_range:
        start, end, n_frames = frame_range
        if len(times) != n_frames:
            rep.error(f"{path}: '{name}' has {len(times)} time samples, the stage frame range "
                      f"{_fmt_t(start)}..{_fmt_t(end)} has {n_frames} frames", prim)
        off_grid = [t for t in times if not float(t).is_integer()]
        outside = [t for t in times if t < start or t > end]
        if off_grid:
            rep.warn(f"{path}: '{name}' has {len(off_grid)} samples off integer frames (e.g. "
                     f"{', '.join(_fmt_t(t) for t in off_grid[:MAX_TIMES_LISTED])}); Blender reads time "
                     "code N at frame N", prim)
        if outside:
            rep.error(f"{path}: '{name}' has {len(outside)} samples outside the stage range "
                      f"{_fmt_t(start)}..{_fmt_t(end)} (e.g. "
                      f"{', '.join(_fmt_t(t) for t in outside[:MAX_TIMES_LISTED])})", prim)
    if min_frames and len(times) < min_frames:
        rep.error(f"{path}: '{name}' has {len(times)} time samples, fewer than --min-frames {min_frames}", prim)
    return times


def check_extent(gprim, path: str, times: list, pts_by_time: dict, rep: Report, prim: dict, pad_by_time=None):
    ext_attr = gprim.GetExtentAttr()
    if not ext_attr or not ext_attr.HasAuthoredValue():
        rep.error(f"{path}: 'extent' is not authored (author it at every frame; "
                  "UsdGeom.Boundable.ComputeExtentFromPlugins or min/max of the points)", prim)
        prim["extent"] = "missing"
        return
    ext_times = _sample_times(ext_attr)
    prim["extent"] = f"{len(ext_times)} samples" if ext_times else "static"
    pts_sampled = any(t is not None for t in times)
    if pts_sampled and not ext_times:
        rep.warn(f"{path}: 'extent' is static while 'points' is time-sampled; author extent per frame", prim)
    elif pts_sampled and len(ext_times) < len([t for t in times if t is not None]):
        rep.warn(f"{path}: 'extent' has {len(ext_times)} samples, 'points' has "
                 f"{len([t for t in times if t is not None])}; USD holds the previous extent in between", prim)
    issues, soft = TimeIssues(), TimeIssues()
    for t in times:
        pts = pts_by_time.get(t)
        if pts is None or len(pts) == 0:
            continue
        ext = _np(_get(ext_attr, t), np.float64)
        if ext is None or ext.shape != (2, 3) or not np.all(np.isfinite(ext)):
            issues.add("extent is not two finite float3 values", t)
            continue
        lo, hi = ext
        if np.any(lo > hi):
            issues.add("extent min > max", t)
            continue
        pmin, pmax = pts.min(axis=0), pts.max(axis=0)
        tol = 1e-5 * max(1.0, float(np.max(np.abs(ext))))
        if np.any(pmin < lo - tol) or np.any(pmax > hi + tol):
            issues.add("points outside extent", t,
                       f"points {np.round(pmin, 6).tolist()}..{np.round(pmax, 6).tolist()}, "
                       f"extent {np.round(lo, 6).tolist()}..{np.round(hi, 6).tolist()}")
        elif pad_by_time and pad_by_time.get(t):
            pad = pad_by_time[t]
            if np.any(pmin - pad < lo - tol) or np.any(pmax + pad > hi + tol):
                soft.add("extent contains the point centres but not their widths/2 "
                         "(USD's ComputeExtent for Points includes the radius)", t)
    issues.flush(rep, prim, path, as_error=True)
    soft.flush(rep, prim, path, as_error=False)


def read_points(attr, times, path, rep, prim, issues: TimeIssues) -> dict:
    out = {}
    counts = []
    for t in times:
        val = _get(attr, t)
        if val is None:
            issues.add("'points' has no value", t)
            continue
        pts = _np(val, np.float64).reshape(-1, 3)
        if not np.all(np.isfinite(pts)):
            bad = int(np.count_nonzero(~np.all(np.isfinite(pts), axis=1)))
            issues.add("non-finite point(s)", t, f"{bad} of {len(pts)} points")
        out[t] = pts
        counts.append(len(pts))
    if counts:
        prim["count_min"], prim["count_max"] = int(min(counts)), int(max(counts))
        if min(counts) == 0:
            rep.warn(f"{path}: 'points' is empty at {counts.count(0)} sample(s)", prim)
    return out


def check_per_point_array(attr, label, path, times, pts_by_time, issues: TimeIssues, allow_constant=False):
    """Optional per-point arrays: velocities, ids, accelerations, vertex primvars."""
    if not attr or not attr.HasAuthoredValue():
        return False
    for t in times:
        pts = pts_by_time.get(t)
        val = _get(attr, t)
        if pts is None or val is None:
            continue
        arr = np.asarray(val)
        n = arr.shape[0] if arr.ndim else 1
        if allow_constant and n == 1:
            continue
        if n != len(pts):
            issues.add(f"'{label}' length != number of points", t, f"{n} for {len(pts)}")
        elif arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
            issues.add(f"'{label}' has non-finite values", t)
    return True


def check_points_prim(p: UsdGeom.Points, frame_range, rep: Report, min_frames: int) -> dict:
    path = str(p.GetPath())
    prim = {"path": path, "type": "Points", "errors": [], "warnings": []}
    times = check_samples(p.GetPointsAttr(), "points", path, frame_range, rep, prim, min_frames)
    issues = TimeIssues()
    pts_by_time = read_points(p.GetPointsAttr(), times, path, rep, prim, issues)

    # widths
    w_attr = p.GetWidthsAttr()
    pad_by_time = {}
    if not w_attr or not w_attr.HasAuthoredValue():
        rep.error(f"{path}: 'widths' is not authored (Blender radius = width/2; without it the "
                  "point cloud gets Blender's default radius)", prim)
        prim["widths"] = "missing"
    else:
        interp = p.GetWidthsInterpolation()
        prim["widths"] = f"{interp}, {len(_sample_times(w_attr))} samples"
        for t in times:
            pts = pts_by_time.get(t)
            w = _np(_get(w_attr, t), np.float64)
            if w is None:
                issues.add("'widths' has no value", t)
                continue
            if w.size == 0:
                if pts is None or len(pts) > 0:
                    issues.add("'widths' is empty", t)
                continue
            if not np.all(np.isfinite(w)) or np.any(w <= 0):
                issues.add("'widths' not all finite and > 0", t, f"min {np.nanmin(w):g}")
            if interp == UsdGeom.Tokens.constant:
                if w.size != 1:
                    issues.add("constant 'widths' does not have exactly 1 value", t, f"{w.size} values")
            elif interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
                if pts is not None and w.size != len(pts):
                    issues.add(f"{interp} 'widths' length != number of points", t, f"{w.size} for {len(pts)}")
            else:
                issues.add(f"'widths' interpolation '{interp}' is not constant/vertex/varying", t)
            if w.size and np.all(np.isfinite(w)):
                pad_by_time[t] = float(np.max(w)) * 0.5
    extras = []
    if check_per_point_array(p.GetVelocitiesAttr(), "velocities", path, times, pts_by_time, issues):
        extras.append("velocities")
    if check_per_point_array(p.GetAccelerationsAttr(), "accelerations", path, times, pts_by_time, issues):
        extras.append("accelerations")
    if check_per_point_array(p.GetIdsAttr(), "ids", path, times, pts_by_time, issues):
        extras.append("ids")
    n_attr = p.GetNormalsAttr()
    if check_per_point_array(n_attr, "normals", path, times, pts_by_time, issues):
        extras.append("normals")
    extras += check_primvars(p, path, times, pts_by_time, issues, rep, prim, face_counts=None)
    prim["extras"] = extras
    issues.flush(rep, prim, path)
    check_extent(p, path, times, pts_by_time, rep, prim, pad_by_time=pad_by_time)
    return prim


def check_primvars(gprim, path, times, pts_by_time, issues, rep, prim, face_counts) -> list:
    names = []
    for pv in UsdGeom.PrimvarsAPI(gprim).GetPrimvarsWithValues():
        name = pv.GetPrimvarName()
        if name in ("displayColor", "displayOpacity") and pv.GetInterpolation() == UsdGeom.Tokens.constant:
            continue
        names.append(f"primvars:{name}")
        if not pv.GetTypeName().isArray:
            continue
        interp = pv.GetInterpolation()
        if pv.IsIndexed():
            continue  # indexed primvars: element count is the index count; skip size checks
        for t in times:
            pts = pts_by_time.get(t)
            val = pv.Get() if t is None else pv.Get(Usd.TimeCode(t))
            if pts is None or val is None:
                continue
            n = len(val)
            if interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying) and n != len(pts):
                issues.add(f"{interp} primvar '{name}' length != number of points", t, f"{n} for {len(pts)}")
            elif interp == UsdGeom.Tokens.constant and n != 1 and pv.GetElementSize() == 1:
                issues.add(f"constant primvar '{name}' has more than 1 element", t, f"{n} elements")
            elif face_counts is not None and t in face_counts:
                nf, nc = face_counts[t]
                if interp == UsdGeom.Tokens.uniform and n != nf:
                    issues.add(f"uniform primvar '{name}' length != number of faces", t, f"{n} for {nf}")
                if interp == UsdGeom.Tokens.faceVarying and n != nc:
                    issues.add(f"faceVarying primvar '{name}' length != number of face corners", t, f"{n} for {nc}")
    return names
