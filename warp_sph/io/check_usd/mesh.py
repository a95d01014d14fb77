"""The UsdGeomMesh prim: topology at every sample, winding of closed surfaces, degenerate triangles."""
from __future__ import annotations

import numpy as np
from pxr import UsdGeom

from .common import Report, TimeIssues, _fmt_t, _get, _np, _sample_times
from .points import check_extent, check_per_point_array, check_primvars, check_samples, read_points


def _fan_triangles(cnt: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons given counts and flat indices -> (T, 3) vertex indices."""
    if len(cnt) and np.all(cnt == 3):
        return idx.reshape(-1, 3)
    starts = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    ntri = np.maximum(cnt - 2, 0)
    face = np.repeat(np.arange(len(cnt)), ntri)
    k = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1
    s0 = starts[face]
    return np.stack([idx[s0], idx[s0 + k], idx[s0 + k + 1]], axis=1)


def mesh_winding(pts: np.ndarray, cnt: np.ndarray, idx: np.ndarray, left_handed: bool) -> tuple[str, float]:
    """Classify a mesh's face winding: 'outward', 'inward', 'open' or 'inconsistent' (+ signed volume).

    For a closed mesh with right-handed (counter-clockwise) winding, outward normals give a positive
    signed volume. Blender flips faces of leftHanded meshes on import, so we do the same here.
    """
    tri = _fan_triangles(cnt, idx)
    if left_handed:
        tri = tri[:, ::-1]
    if len(tri) == 0:
        return "open", 0.0
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    n = int(pts.shape[0])
    directed = e[:, 0].astype(np.int64) * n + e[:, 1]
    undirected = np.minimum(e[:, 0], e[:, 1]).astype(np.int64) * n + np.maximum(e[:, 0], e[:, 1])
    _, und_counts = np.unique(undirected, return_counts=True)
    closed = bool(np.all(und_counts == 2))
    p0, p1, p2 = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    vol = float(np.einsum("ij,ij->i", p0, np.cross(p1, p2)).sum() / 6.0)
    if len(np.unique(directed)) != len(directed):
        return "inconsistent", vol
    if not closed:
        return "open", vol
    return ("outward" if vol > 0 else "inward"), vol


def check_mesh_prim(m: UsdGeom.Mesh, frame_range, rep: Report, min_frames: int) -> dict:
    path = str(m.GetPath())
    prim = {"path": path, "type": "Mesh", "errors": [], "warnings": []}
    times = check_samples(m.GetPointsAttr(), "points", path, frame_range, rep, prim, min_frames)
    issues = TimeIssues()
    warn_issues = TimeIssues()
    pts_by_time = read_points(m.GetPointsAttr(), times, path, rep, prim, issues)
    cnt_attr, idx_attr = m.GetFaceVertexCountsAttr(), m.GetFaceVertexIndicesAttr()
    for a, nm in ((cnt_attr, "faceVertexCounts"), (idx_attr, "faceVertexIndices")):
        if not a or not a.HasAuthoredValue():
            rep.error(f"{path}: '{nm}' is not authored", prim)
    prim["topology_samples"] = len(_sample_times(idx_attr))
    face_counts = {}
    fmin, fmax = None, None
    topo_varies = False
    prev_sig = None
    for t in times:
        pts = pts_by_time.get(t)
        cnt = _np(_get(cnt_attr, t), np.int64)
        idx = _np(_get(idx_attr, t), np.int64)
        if cnt is None or idx is None or pts is None:
            continue
        sig = (len(pts), len(cnt), len(idx))
        topo_varies |= prev_sig is not None and sig != prev_sig
        prev_sig = sig
        nf = len(cnt)
        fmin = nf if fmin is None else min(fmin, nf)
        fmax = nf if fmax is None else max(fmax, nf)
        face_counts[t] = (nf, len(idx))
        if nf and np.any(cnt < 3):
            issues.add("face(s) with fewer than 3 vertices", t, f"{int(np.count_nonzero(cnt < 3))} faces")
        if int(cnt.sum()) != len(idx):
            issues.add("sum(faceVertexCounts) != len(faceVertexIndices)", t, f"{int(cnt.sum())} vs {len(idx)}")
            continue
        if len(idx) and (idx.min() < 0 or idx.max() >= len(pts)):
            bad = int(np.count_nonzero((idx < 0) | (idx >= len(pts))))
            issues.add("faceVertexIndices out of range [0, len(points))", t,
                       f"{bad} bad indices, min {int(idx.min())}, max {int(idx.max())}, {len(pts)} points")
            continue
        if nf and np.all(cnt == 3):
            tri = idx.reshape(-1, 3)
            degen = int(np.count_nonzero((tri[:, 0] == tri[:, 1]) | (tri[:, 1] == tri[:, 2]) |
                                         (tri[:, 0] == tri[:, 2])))
            if degen:
                warn_issues.add("triangle(s) repeat a vertex (Blender reports invalid face data "
                                "and runs mesh validation, which may drop data)", t, f"{degen} triangles")
    if fmin is not None:
        prim["faces_min"], prim["faces_max"] = int(fmin), int(fmax)
    prim["topology_varies"] = bool(topo_varies)
    if topo_varies and prim["topology_samples"] and prim["topology_samples"] < len([t for t in times if t is not None]):
        rep.warn(f"{path}: topology changes over time but faceVertexIndices has only "
                 f"{prim['topology_samples']} samples for {len(times)} points samples; author counts and "
                 "indices at every frame", prim)
    scheme = m.GetSubdivisionSchemeAttr().Get()
    prim["subdivisionScheme"] = str(scheme)
    if scheme != UsdGeom.Tokens.none:
        rep.warn(f"{path}: subdivisionScheme is '{scheme}' (the USD fallback is catmullClark); author 'none' "
                 "for a marching-cubes surface so renderers do not subdivide it", prim)
    # face winding on up to three samples (first, middle, last): water needs outward normals for refraction
    left = m.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
    valid_t = [t for t in times if t in face_counts]
    probe = sorted({valid_t[0], valid_t[len(valid_t) // 2], valid_t[-1]}, key=lambda x: (x is None, x)) if valid_t else []
    windings = {}
    for t in probe:
        cnt = _np(_get(cnt_attr, t), np.int64)
        idx = _np(_get(idx_attr, t), np.int64)
        pts = pts_by_time[t]
        if int(cnt.sum()) != len(idx) or (len(idx) and (idx.min() < 0 or idx.max() >= len(pts))):
            continue
        windings[t] = mesh_winding(pts, cnt, idx, left)[0]
    if windings:
        kinds = sorted(set(windings.values()))
        prim["winding"] = "/".join(kinds)
        inward = [t for t, w in windings.items() if w == "inward"]
        bad = [t for t, w in windings.items() if w == "inconsistent"]
        if inward:
            rep.warn(f"{path}: closed surface has inward-facing normals at time "
                     f"{', '.join(_fmt_t(t) for t in inward)} (signed volume < 0); flip the triangle winding "
                     "or set orientation = leftHanded, or refraction/shading in Blender is inverted", prim)
        if bad:
            rep.warn(f"{path}: inconsistent face winding (a directed edge is used twice) at time "
                     f"{', '.join(_fmt_t(t) for t in bad)}", prim)
    if topo_varies and UsdGeom.Subset.GetAllGeomSubsets(m):
        rep.warn(f"{path}: GeomSubsets on a mesh with changing topology; their face indices go stale "
                 "between frames", prim)
    extras = []
    if check_per_point_array(m.GetVelocitiesAttr(), "velocities", path, times, pts_by_time, issues):
        extras.append("velocities")
    n_attr = m.GetNormalsAttr()
    if n_attr and n_attr.HasAuthoredValue():
        extras.append("normals")
        ninterp = m.GetNormalsInterpolation()
        for t in times:
            n = _get(n_attr, t)
            if n is None or t not in face_counts or pts_by_time.get(t) is None:
                continue
            want = {UsdGeom.Tokens.vertex: len(pts_by_time[t]), UsdGeom.Tokens.varying: len(pts_by_time[t]),
                    UsdGeom.Tokens.faceVarying: face_counts[t][1],
                    UsdGeom.Tokens.uniform: face_counts[t][0]}.get(ninterp)
            if want is not None and len(n) != want:
                issues.add(f"{ninterp} normals have the wrong length (Blender ignores them)", t,
                           f"{len(n)} values, expected {want}")
    extras += check_primvars(m, path, times, pts_by_time, issues, rep, prim, face_counts)
    prim["extras"] = extras
    issues.flush(rep, prim, path)
    warn_issues.flush(rep, prim, path, as_error=False)
    check_extent(m, path, times, pts_by_time, rep, prim)
    return prim
