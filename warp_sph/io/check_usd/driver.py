"""Open the stage, check every prim, print the report; the command line."""
from __future__ import annotations

import argparse
import json
import os
import sys

from pxr import Usd, UsdGeom

from .common import Report, _fmt_t
from .instancer import check_instancer_prim
from .mesh import check_mesh_prim
from .points import check_points_prim
from .stage import check_stage

# --------------------------------------------------------------------------------------------
# driver
# --------------------------------------------------------------------------------------------

def run(path: str, min_frames: int = 0) -> Report:
    rep = Report(path)
    if not os.path.exists(path):
        rep.error(f"cannot open: no such file: {path}")
        rep.stage = {"opened": False}
        return rep
    reason = "unknown error"
    try:
        stage = Usd.Stage.Open(path)
    except Exception as exc:  # usd-core raises Tf.ErrorException for unreadable layers
        stage = None
        reason = " ".join(str(exc).split())[:500]
    if not stage:
        rep.error(f"cannot open with Usd.Stage.Open: {reason}")
        rep.stage = {"opened": False}
        return rep
    frame_range = check_stage(stage, rep, min_frames)
    rep.stage["opened"] = True
    found = 0
    for p in stage.Traverse(Usd.TraverseInstanceProxies()):
        if p.IsA(UsdGeom.Points):
            rep.prims.append(check_points_prim(UsdGeom.Points(p), frame_range, rep, min_frames))
            found += 1
        elif p.IsA(UsdGeom.Mesh):
            rep.prims.append(check_mesh_prim(UsdGeom.Mesh(p), frame_range, rep, min_frames))
            found += 1
        elif p.IsA(UsdGeom.PointInstancer):
            rep.prims.append(check_instancer_prim(UsdGeom.PointInstancer(p), frame_range, rep, min_frames))
    try:  # total bytes of every layer the stage used, value-clip layers included
        layers = [lyr for lyr in stage.GetUsedLayers(includeClipLayers=True) if lyr.realPath]
        rep.stage["layers"] = len(layers)
        rep.stage["total_bytes"] = sum(os.path.getsize(lyr.realPath) for lyr in layers
                                       if lyr.realPath and os.path.isfile(lyr.realPath))
    except Exception:  # anonymous layers, older usd-core
        rep.stage["total_bytes"] = rep.stage.get("file_bytes")
    n_points = sum(1 for x in rep.prims if x["type"] == "Points")
    if not found:
        rep.error("no UsdGeomPoints or UsdGeomMesh prim found on the stage")
    elif n_points == 0:
        rep.warn("no UsdGeomPoints prim found (expected the fluid particles as points)")
    return rep


def print_human(rep: Report, out=None, strict: bool = False):
    out = out or sys.stdout
    d = rep.to_dict()
    s = d["stage"]
    print(f"check_usd: {rep.path}", file=out)
    if s.get("opened"):
        size = s.get("total_bytes") or s.get("file_bytes")
        n_layers = s.get("layers", 1)
        size_txt = (f", {size / 1e6:.1f} MB" if size else "") + (f" in {n_layers} layers" if n_layers > 1 else "")
        frames = s.get("n_frames")
        per_frame = f", {size / frames / 1e6:.2f} MB/frame" if size and frames else ""
        print(f"  format {s['format']}{size_txt}{per_frame}", file=out)

        def flag(key):
            return "" if s.get(key + "_authored") else " (not authored)"
        print(f"  upAxis {s['upAxis']}{flag('upAxis')}, metersPerUnit {s['metersPerUnit']:g}{flag('metersPerUnit')}, "
              f"timeCodesPerSecond {s['timeCodesPerSecond']:g}{flag('timeCodesPerSecond')}, "
              f"framesPerSecond {s['framesPerSecond']:g}{flag('framesPerSecond')}", file=out)
        if s.get("startTimeCode") is not None:
            print(f"  time codes {_fmt_t(s['startTimeCode'])}..{_fmt_t(s['endTimeCode'])}"
                  f" ({s.get('n_frames', '?')} frames)", file=out)
        else:
            print("  time codes: not authored", file=out)
    for p in d["prims"]:
        status = "FAIL" if p["errors"] else ("warn" if p["warnings"] else "ok")
        parts = [f"samples {p.get('n_samples', 0)}"]
        if "count_min" in p:
            c = (f"{p['count_min']}" if p["count_min"] == p["count_max"]
                 else f"{p['count_min']}..{p['count_max']}")
            parts.append(f"{'points' if p['type'] != 'Mesh' else 'verts'} {c}")
        if "faces_min" in p:
            f = f"{p['faces_min']}" if p["faces_min"] == p["faces_max"] else f"{p['faces_min']}..{p['faces_max']}"
            parts.append(f"faces {f}" + (" (topology varies)" if p.get("topology_varies") else ""))
        if p.get("winding"):
            parts.append(f"winding {p['winding']}")
        if "widths" in p:
            parts.append(f"widths {p['widths']}")
        if "extent" in p:
            parts.append(f"extent {p['extent']}")
        if p.get("extras"):
            parts.append("+ " + ", ".join(p["extras"]))
        print(f"  [{status:4s}] {p['type']:14s} {p['path']}: " + "; ".join(parts), file=out)
    for m in d["infos"]:
        print(f"  info: {m}", file=out)
    for m in d["warnings"]:
        print(f"  WARNING: {m}", file=out)
    for m in d["errors"]:
        print(f"  ERROR: {m}", file=out)
    verdict = "OK" if d["ok"] and not (strict and d["n_warnings"]) else "FAILED" + (" (--strict)" if d["ok"] else "")
    print(f"{verdict}: {d['n_errors']} error(s), {d['n_warnings']} warning(s)", file=out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Validate a Blender-bound SPH USD export (points + mesh time samples).")
    ap.add_argument("path", help=".usd / .usda / .usdc file")
    ap.add_argument("--min-frames", type=int, default=0, metavar="N",
                    help="fail unless the frame range and every points/mesh prim hold at least N frames")
    ap.add_argument("--json", action="store_true", help="print a JSON report instead of text")
    ap.add_argument("--strict", action="store_true", help="treat warnings as errors (exit 1)")
    args = ap.parse_args(argv)
    if args.min_frames < 0:
        ap.error("--min-frames must be >= 0")
    rep = run(args.path, args.min_frames)
    if args.json:
        json.dump(rep.to_dict(), sys.stdout, indent=1, default=str)
        sys.stdout.write("\n")
    else:
        print_human(rep, strict=args.strict)
    if not rep.stage.get("opened"):
        return 2
    if rep.errors or (args.strict and rep.warnings):
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
