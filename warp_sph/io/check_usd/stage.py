"""Stage metadata: upAxis, metersPerUnit, time codes and frame rate authored; the frame range."""
from __future__ import annotations

import math
import os

from pxr import Usd, UsdGeom

from .common import Report


# --------------------------------------------------------------------------------------------
# stage metadata
# --------------------------------------------------------------------------------------------

def check_stage(stage: Usd.Stage, rep: Report, min_frames: int) -> tuple[float, float, int] | None:
    root = stage.GetRootLayer()
    # Metadata may also come from a session layer; HasAuthored... looks at the whole layer stack.
    info = {
        "format": root.GetFileFormat().formatId,
        "file_bytes": os.path.getsize(rep.path) if os.path.isfile(rep.path) else None,
        "defaultPrim": str(stage.GetDefaultPrim().GetPath()) if stage.GetDefaultPrim() else None,
        "upAxis": str(UsdGeom.GetStageUpAxis(stage)),
        "upAxis_authored": stage.HasAuthoredMetadata("upAxis"),
        "metersPerUnit": UsdGeom.GetStageMetersPerUnit(stage),
        "metersPerUnit_authored": UsdGeom.StageHasAuthoredMetersPerUnit(stage),
        "timeCodesPerSecond": stage.GetTimeCodesPerSecond(),
        "timeCodesPerSecond_authored": stage.HasAuthoredMetadata("timeCodesPerSecond"),
        "framesPerSecond": stage.GetFramesPerSecond(),
        "framesPerSecond_authored": stage.HasAuthoredMetadata("framesPerSecond"),
        "startTimeCode": stage.GetStartTimeCode() if stage.HasAuthoredTimeCodeRange() else None,
        "endTimeCode": stage.GetEndTimeCode() if stage.HasAuthoredTimeCodeRange() else None,
    }
    rep.stage = info

    if not info["upAxis_authored"]:
        rep.error(f"stage: upAxis not authored (USD fallback {info['upAxis']}); Blender rotates a non-Z-up "
                  "stage by +90 degrees about X on import, so a Z-up simulation would lie on its side; "
                  "author upAxis = \"Z\"")
    elif info["upAxis"] != "Z":
        rep.warn(f"stage: upAxis = {info['upAxis']} (the simulator is Z-up); Blender will rotate root objects "
                 "+90 degrees about X")
    if not info["metersPerUnit_authored"]:
        rep.error(f"stage: metersPerUnit not authored (USD fallback {info['metersPerUnit']:g} = centimetres); "
                  "Blender's default 'Apply Unit Conversion Scale' would scale the import by that value; "
                  "author metersPerUnit = 1 for SI metres")
    elif not math.isclose(info["metersPerUnit"], 1.0):
        rep.warn(f"stage: metersPerUnit = {info['metersPerUnit']:g}, not 1 (the simulator works in metres); "
                 "Blender will scale the import by this value")
    if not info["timeCodesPerSecond_authored"]:
        rep.warn("stage: timeCodesPerSecond not authored (fallback "
                 f"{info['timeCodesPerSecond']:g}); author it = framesPerSecond = the export frame rate")
    if not info["framesPerSecond_authored"]:
        rep.warn("stage: framesPerSecond not authored; author it = timeCodesPerSecond = the export frame rate")
    if (info["timeCodesPerSecond_authored"] and info["framesPerSecond_authored"]
            and not math.isclose(info["timeCodesPerSecond"], info["framesPerSecond"])):
        rep.warn(f"stage: timeCodesPerSecond ({info['timeCodesPerSecond']:g}) != framesPerSecond "
                 f"({info['framesPerSecond']:g}); Blender maps time code N to frame N, so sub-frame "
                 "samples land between Blender frames")

    if info["startTimeCode"] is None:
        rep.error("stage: startTimeCode/endTimeCode not authored; Blender's 'Set Frame Range' and this "
                  "checker's frame count need them")
        return None
    start, end = float(info["startTimeCode"]), float(info["endTimeCode"])
    if end < start:
        rep.error(f"stage: endTimeCode {end:g} < startTimeCode {start:g}")
        return None
    if not (start.is_integer() and end.is_integer()):
        rep.warn(f"stage: start/end time codes {start:g}..{end:g} are not integers; Blender sets its "
                 "integer frame range from them")
    n_frames = int(math.floor(end) - math.ceil(start)) + 1
    info["n_frames"] = n_frames
    if min_frames and n_frames < min_frames:
        rep.error(f"stage: frame range {start:g}..{end:g} holds {n_frames} frames, fewer than "
                  f"--min-frames {min_frames}")
    return start, end, n_frames
