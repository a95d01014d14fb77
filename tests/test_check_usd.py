"""The USD checker shipped as ``warp_sph.io.check_usd``: a good SPH-style USD file and broken
variants give the expected exit code and message (so the checks the other tests rely on can fail)."""
from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile

import numpy as np
import pytest
from pxr import Usd, UsdGeom, Vt

from warp_sph.io import check_usd


def _ext(p, pad=0.0):
    return Vt.Vec3fArray.FromNumpy(np.stack([p.min(0) - pad, p.max(0) + pad]).astype(np.float32))


def _frame(rng, k, n_pts=500):
    pts = rng.random((n_pts, 3), dtype=np.float32)
    pts[:, 2] += 1.0 - 0.05 * k
    n = 3 + k  # surface grid resolution changes every frame -> topology changes
    xs, ys = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    verts = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.5)], 1).astype(np.float32)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    b, c = a + 1, a + n + 1
    tris = np.stack([a, c, c + 1, a, c + 1, b], 1).reshape(-1).astype(np.int32)
    return pts, verts, tris


def write(path, n_frames=8, start=1, radius=0.01, mpu=True, range_=True, widths="vertex", extent=True,
          mutate=None, skip_frame=None, up="Z"):
    """Write the reference layout; `mutate(k, d)` may corrupt frame data before it is authored."""
    rng = np.random.default_rng(0)
    st = Usd.Stage.CreateNew(path)
    if range_:
        st.SetStartTimeCode(start)
        st.SetEndTimeCode(start + n_frames - 1)
    st.SetTimeCodesPerSecond(24)
    st.SetFramesPerSecond(24)
    if up:
        UsdGeom.SetStageUpAxis(st, up)
    if mpu:
        UsdGeom.SetStageMetersPerUnit(st, 1.0)
    st.SetDefaultPrim(UsdGeom.Xform.Define(st, "/sph").GetPrim())
    pp = UsdGeom.Points.Define(st, "/sph/particles")
    m = UsdGeom.Mesh.Define(st, "/sph/surface")
    m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    if widths == "constant":
        pp.CreateWidthsAttr(Vt.FloatArray([2 * radius]))
        pp.SetWidthsInterpolation(UsdGeom.Tokens.constant)
    elif widths == "vertex":
        pp.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
    for k in range(n_frames):
        if skip_frame is not None and k == skip_frame:
            continue
        t = Usd.TimeCode(start + k)
        pts, verts, tris = _frame(rng, k)
        d = {"pts": pts, "verts": verts, "tris": tris, "counts": np.full(len(tris) // 3, 3, np.int32),
             "w": np.full(len(pts), 2 * radius, np.float32), "pext": None, "mext": None}
        if mutate:
            mutate(k, d)
        pp.CreatePointsAttr().Set(Vt.Vec3fArray.FromNumpy(d["pts"]), t)
        if widths == "vertex":
            pp.CreateWidthsAttr().Set(Vt.FloatArray.FromNumpy(d["w"]), t)
        m.CreatePointsAttr().Set(Vt.Vec3fArray.FromNumpy(d["verts"]), t)
        m.CreateFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(d["counts"]), t)
        m.CreateFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(d["tris"]), t)
        if extent:
            finite = d["pts"][np.all(np.isfinite(d["pts"]), axis=1)]
            pp.CreateExtentAttr().Set(d["pext"] if d["pext"] is not None else _ext(finite, radius), t)
            m.CreateExtentAttr().Set(d["mext"] if d["mext"] is not None else _ext(d["verts"]), t)
        st.Save()
    st.Save()
    return path


def run_checker(*args):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = check_usd.main([str(a) for a in args])
    return code, out.getvalue()


def _nan(k, d):
    if k == 3:
        d["pts"][7] = np.nan


def _bad_index(k, d):
    if k == 2:
        d["tris"][5] = len(d["verts"]) + 10


def _bad_counts(k, d):
    if k == 4:
        d["counts"] = d["counts"][:-1]


def _neg_width(k, d):
    if k == 1:
        d["w"][0] = -1.0


def _stale_extent(k, d):
    d["pext"] = _ext(np.zeros((1, 3), np.float32) + np.float32([0.5, 0.5, 1.5]), 0.6)  # frame 0 box, never updated


_CUBE_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
                   np.float32)
_CUBE_Q = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])
_CUBE_T = np.concatenate([_CUBE_Q[:, [0, 1, 2]], _CUBE_Q[:, [0, 2, 3]]]).astype(np.int32)  # outward, CCW


def _closed_outward(k, d):
    d["verts"], d["tris"] = _CUBE_V.copy(), _CUBE_T.reshape(-1).copy()
    d["counts"] = np.full(len(_CUBE_T), 3, np.int32)


def _closed_inward(k, d):
    _closed_outward(k, d)
    d["tris"] = _CUBE_T[:, ::-1].reshape(-1).copy()


def _empty_surface_first_frame(k, d):
    if k == 0:  # marching cubes found no surface yet: an empty mesh with a zero-size extent
        d["verts"] = np.zeros((0, 3), np.float32)
        d["tris"] = np.zeros(0, np.int32)
        d["counts"] = np.zeros(0, np.int32)
        d["mext"] = Vt.Vec3fArray.FromNumpy(np.zeros((2, 3), np.float32))


CASES = [
    # name, writer kwargs, checker extra args, expected exit code, substrings expected in the report
    ("good", {}, [], 0, ["OK: 0 error(s), 0 warning(s)"]),
    ("good_constant_widths", {"widths": "constant"}, [], 0, ["widths constant"]),
    ("good_start0", {"start": 0}, [], 0, ["time codes 0..7"]),
    ("min_frames_ok", {}, ["--min-frames", 8], 0, ["OK"]),
    ("min_frames_fail", {}, ["--min-frames", 9], 1, ["fewer than --min-frames 9"]),
    ("no_meters_per_unit", {"mpu": False}, [], 1, ["metersPerUnit not authored"]),
    ("no_up_axis", {"up": None}, [], 1, ["upAxis not authored"]),
    ("y_up", {"up": "Y"}, [], 0, ["upAxis = Y", "1 warning(s)"]),
    ("no_time_range", {"range_": False}, [], 1, ["startTimeCode/endTimeCode not authored"]),
    ("nan_points", {"mutate": _nan}, [], 1, ["non-finite point(s) at time 4"]),
    ("no_widths", {"widths": None}, [], 1, ["'widths' is not authored"]),
    ("negative_width", {"mutate": _neg_width}, [], 1, ["'widths' not all finite and > 0"]),
    ("index_out_of_range", {"mutate": _bad_index}, [], 1, ["faceVertexIndices out of range", "at time 3"]),
    ("counts_mismatch", {"mutate": _bad_counts}, [], 1, ["sum(faceVertexCounts)"]),
    ("no_extent", {"extent": False}, [], 1, ["'extent' is not authored"]),
    ("stale_extent", {"mutate": _stale_extent}, [], 1, ["points outside extent"]),
    ("dropped_frame", {"skip_frame": 5}, [], 1, ["has 7 time samples", "8 frames"]),
    ("empty_surface_frame", {"mutate": _empty_surface_first_frame}, [], 0, ["verts 0..", "faces 0.."]),
    ("closed_outward", {"mutate": _closed_outward}, [], 0, ["winding outward", "0 warning(s)"]),
    ("closed_inward", {"mutate": _closed_inward}, [], 0, ["inward-facing normals", "1 warning(s)"]),
    ("closed_inward_strict", {"mutate": _closed_inward}, ["--strict"], 1, ["inward-facing normals"]),
]


def _case(tmp, name, kwargs, extra, want_code, want_text):
    path = write(os.path.join(tmp, f"{name}.usdc"), **kwargs)
    code, text = run_checker(path, *extra)
    assert code == want_code, f"{name}: exit {code}, expected {want_code}\n{text}"
    for w in want_text:
        assert w in text, f"{name}: expected {w!r} in report\n{text}"
    return text


def test_cases():
    """Check every good and broken variant gives the expected exit code and message."""
    with tempfile.TemporaryDirectory() as tmp:
        for case in CASES:
            _case(tmp, *case)


def test_json_output():
    """Emit parseable JSON with per-prim errors for a broken file."""
    with tempfile.TemporaryDirectory() as tmp:
        path = write(os.path.join(tmp, "j.usdc"), mutate=_bad_index)
        code, text = run_checker(path, "--json")
        rep = json.loads(text)
        assert code == 1 and rep["ok"] is False
        mesh = [p for p in rep["prims"] if p["type"] == "Mesh"][0]
        assert mesh["errors"] and mesh["topology_varies"] is True
        assert rep["stage"]["n_frames"] == 8


def test_unreadable_files():
    """Exit 2 for a missing file and for a truncated crate file."""
    with tempfile.TemporaryDirectory() as tmp:
        code, text = run_checker(os.path.join(tmp, "nope.usdc"))
        assert code == 2 and "no such file" in text
        good = write(os.path.join(tmp, "t.usdc"))
        bad = os.path.join(tmp, "truncated.usdc")
        with open(good, "rb") as f, open(bad, "wb") as g:
            g.write(f.read()[:4096])
        code, text = run_checker(bad)
        assert code == 2 and "cannot open" in text, text


SHARED_VALIDATOR = "/work/shared/tools/check_usd.py"
PACKAGE_ORDER = ["common", "stage", "points", "mesh", "instancer", "driver"]


@pytest.mark.skipif(not os.path.exists(SHARED_VALIDATOR), reason="the shared validator is not on this machine")
def test_package_holds_the_shared_validator_line_for_line():
    """The package's modules, in PACKAGE_ORDER after their imports, are the shared validator's body: only
    --strict's FAILED verdict differs (warp_sph/io/check_usd/__init__.py says so), blank lines aside."""
    import difflib
    from pathlib import Path

    def body(text, start=None):  # the lines after the imports (or from ``start``), blank lines left out
        lines = text.split("\n")
        first = (lines.index(start) if start else
                 1 + max(i for i, line in enumerate(lines) if line.startswith(("from ", "import "))))
        return [line for line in lines[first:] if line.strip()]

    folder = Path(check_usd.__file__).parent
    ours = [line for m in PACKAGE_ORDER for line in body((folder / f"{m}.py").read_text())]
    shared = Path(SHARED_VALIDATOR).read_text()
    theirs = body(shared, next(line for line in shared.split("\n") if line.startswith("MAX_TIMES_LISTED")))
    changed = [line for line in difflib.unified_diff(theirs, ours, lineterm="", n=0)
               if line[:1] in "+-" and not line.startswith(("+++", "---"))]
    assert changed == [
        "-def print_human(rep: Report, out=None):",
        "+def print_human(rep: Report, out=None, strict: bool = False):",
        '-    verdict = "OK" if d["ok"] else "FAILED"',
        '+    verdict = "OK" if d["ok"] and not (strict and d["n_warnings"]) else "FAILED" + (" (--strict)" if d["ok"] else "")',
        "-        print_human(rep)",
        "+        print_human(rep, strict=args.strict)",
    ], "\n".join(changed)
