"""A run made from a plan: the scene's [plan] prediction beside what happened (run.json ``plan``)."""
from __future__ import annotations

import dataclasses


def compare_with_plan(predicted, run_info: dict, folder=None) -> dict:
    """run.json's ``plan``: ``predicted`` (the scene's [plan] table), ``actual`` (wall time [s], mean density
    error [-] over the frames after the first, substeps, fluid particles; for a plan on an error against an
    experiment, ``metric_error`` from the probe files in ``folder`` once the run completed) and their ratios
    actual / predicted. The figures are of the run so far (a run in progress or stopped compares what it did)."""
    pred = dataclasses.asdict(predicted) if dataclasses.is_dataclass(predicted) else dict(predicted)
    frames = [f for f in run_info.get("frames", []) if f.get("frame", 0) > 1]
    actual = {"wall_time": float(run_info.get("wall_time", 0.0)),
              "density_error": sum(f["density_error_mean"] for f in frames) / len(frames) if frames else 0.0,
              "steps": int(run_info.get("steps", 0)), "fluid_particles": int(run_info.get("fluid_particles", 0)),
              "frames": len(run_info.get("frames", [])), "frames_requested": int(run_info.get("frames_requested", 0))}
    metric = pred.get("metric") or "density"
    if metric != "density" and folder is not None and run_info.get("status") == "completed":
        actual["metric_error"] = _metric_error(metric, folder, run_info)
    ratio = {k: actual[k] / pred[k] for k in ("wall_time", "density_error", "steps", "fluid_particles", "metric_error")
             if pred.get(k) and actual.get(k) is not None}
    scene = run_info.get("scene") or {}
    whole = int(round(float(scene.get("duration", 0.0)) * float(scene.get("fps", 0.0)))) + 1
    out = {"predicted": pred, "actual": actual, "ratio": ratio, "status": run_info.get("status", ""),
           "whole_scene": actual["frames"] == whole}
    if pred.get("budget"):
        out["within_budget"] = actual["wall_time"] <= pred["budget"]
    return out


def _metric_error(metric: str, folder, run_info: dict) -> float | None:
    """The run's error ``metric`` against its experiment (``metrics.evaluate_reference``), None where unmeasurable."""
    from ..scene import scene_from_dict
    from .metrics import evaluate_reference

    scene = scene_from_dict(run_info["scene"])
    info = dict(run_info, probes=run_info.get("probes") or {p.name: {} for p in scene.probes})
    return evaluate_reference(scene, folder, info).get(metric)


def summary_line(plan: dict) -> str:
    """One line for the end of ``warp-sph run``: predicted against actual wall time and error."""
    p, a = plan["predicted"], plan["actual"]
    line = (f"plan: wall time {a['wall_time']:.3g} s (predicted {p['wall_time']:.3g} s), mean density error "
            f"{100 * a['density_error']:.3g} % (predicted {100 * p['density_error']:.3g} %)")
    if p.get("metric") and p.get("metric") != "density" and "metric_error" in a:
        got = "not measurable" if a["metric_error"] is None else f"{100 * a['metric_error']:.3g} %"
        line += f", {p['metric']} error {got} (predicted {100 * p.get('metric_error', 0.0):.3g} %)"
    if not plan.get("whole_scene", True):
        line += f" (this run wrote {a['frames']} frames; the prediction is for the scene's whole duration)"
    if p.get("budget"):
        line += f"; budget {p['budget']:.3g} s {'kept' if plan.get('within_budget') else 'exceeded'}"
    return line
