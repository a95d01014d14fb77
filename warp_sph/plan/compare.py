"""A run made from a plan: the scene's [plan] prediction beside what happened (run.json ``plan``)."""
from __future__ import annotations

import dataclasses


def compare_with_plan(predicted, run_info: dict) -> dict:
    """run.json's ``plan``: ``predicted`` (the scene's [plan] table), ``actual`` (wall time [s], mean density
    error [-] over the frames after the first, substeps, fluid particles) and their ratios actual / predicted.
    The figures are of the run so far (a run in progress or stopped compares what it did)."""
    pred = dataclasses.asdict(predicted) if dataclasses.is_dataclass(predicted) else dict(predicted)
    frames = [f for f in run_info.get("frames", []) if f.get("frame", 0) > 1]
    actual = {"wall_time": float(run_info.get("wall_time", 0.0)),
              "density_error": sum(f["density_error_mean"] for f in frames) / len(frames) if frames else 0.0,
              "steps": int(run_info.get("steps", 0)), "fluid_particles": int(run_info.get("fluid_particles", 0))}
    ratio = {k: actual[k] / pred[k] for k in actual if pred.get(k)}
    out = {"predicted": pred, "actual": actual, "ratio": ratio, "status": run_info.get("status", "")}
    if pred.get("budget"):
        out["within_budget"] = actual["wall_time"] <= pred["budget"]
    return out
