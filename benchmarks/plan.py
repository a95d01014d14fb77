"""``warp-sph bench plan``: the advisor (``warp-sph plan``) measured on built-in scenes (issue 37).

For each scene and budget: a plan from an empty calibration cache (so the calibration is timed), made in a fresh
process as ``warp-sph plan`` is (the process's first calibration run measures the kernel loads a fresh run pays), the chosen
setting written as a scene (``--apply``), then that scene run whole in a fresh process (``warp-sph run``, the
scene's own outputs) and its run.json's ``plan`` record: predicted against actual wall time and mean density
error. Goals: the actual wall time within 25 % of the prediction and within the budget, the actual error
within 1.5x the predicted, and the calibration under 10 % of the budget.

The scenes are shortened (``--duration``, default 0.5 s simulated) so that the whole benchmark takes minutes.
The load average before and after each case is recorded: on a loaded machine a run is slower than its
calibration measured.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from .records import SCHEMA, host_info, now

#: the goals of issue 37
WALL_GOAL = 0.25          # |actual / predicted - 1| at most
ERROR_GOAL = 1.5          # actual / predicted error at most
CALIBRATION_GOAL = 0.10   # calibration / budget at most
DEFAULT_SCENES = ("hydrostatic", "dam_break")
DEFAULT_BUDGETS = ("60s", "180s")


def add_arguments(p) -> None:
    p.add_argument("--scenes", default=",".join(DEFAULT_SCENES), help="comma-separated built-in scenes "
                   f"(default {','.join(DEFAULT_SCENES)})")
    p.add_argument("--budgets", default=",".join(DEFAULT_BUDGETS), help="comma-separated wall-time budgets "
                   f"(default {','.join(DEFAULT_BUDGETS)})")
    p.add_argument("--duration", type=float, default=0.5, help="simulated time of each scene [s] (default 0.5)")
    p.add_argument("--solvers", default="", help="comma-separated candidate solvers (default: every solver)")


def run_case(scene_name: str, budget_text: str, duration: float, solvers: list[str] | None, work: Path,
             device=None, overrides=(), log=print) -> dict:
    """One scene x budget: plan (empty cache), apply, run whole in a fresh process; the record."""
    from warp_sph.plan import PlanError
    from warp_sph.plan.report import apply_scene, parse_budget
    from warp_sph.scene import load_scene

    budget = parse_budget(budget_text)
    case = f"{scene_name}-{budget_text}"
    folder = work / case
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    record = {"schema": SCHEMA, "kind": "plan", "label": case, "params": {"scene": scene_name, "budget": budget,
              "duration": duration, "solvers": solvers or "all"}, "host": host_info(), "date": now()}
    scene = load_scene(scene_name, overrides=[f"duration={duration}", *overrides])
    t0 = time.perf_counter()
    try:
        # in a fresh process, as `warp-sph plan` runs: its first calibration run loads the kernels every run shares
        p = fresh_process(plan_scene, scene_name, [f"duration={duration}", *overrides], budget_s=budget,
                          device=device, solvers=solvers, cache=folder / "cache")
    except PlanError as exc:
        record.update(status="refused", error=str(exc))
        return record
    plan_seconds = time.perf_counter() - t0
    path = apply_scene(scene, p, folder / "planned.toml")
    c = p.chosen
    log(f"{case}: {c.solver} r = {c.particle_radius:.4g} m, tolerance {c.tolerance}, {c.fluid_particles} fluid, "
        f"predicted {c.wall_time:.3g} s, error {100 * c.density_error:.3g} %; calibration {p.calibration_seconds:.3g} s")
    for note in p.notes:
        log(f"  note: {note}")
    load_before = host_info()["load_average"]
    cmd = [sys.executable, "-m", "warp_sph.cli", "run", str(path), "--out", str(folder / "run"), "--no-progress"]
    if device:
        cmd += ["--device", str(device)]
    r = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ))
    run_json = folder / "run" / "run.json"
    record.update(plan=p.to_dict() | {"candidates": len(p.candidates)}, plan_seconds=plan_seconds,
                  load_before=load_before, load_after=host_info()["load_average"])
    if r.returncode != 0 or not run_json.is_file():
        record.update(status="failed", error=(r.stderr.strip().splitlines() or ["no output"])[-1])
        return record
    info = json.loads(run_json.read_text())
    rec = info["plan"]
    pred, act = rec["predicted"], rec["actual"]
    wall_ratio = act["wall_time"] / pred["wall_time"]
    err_ratio = act["density_error"] / pred["density_error"] if pred["density_error"] > 0 else float("inf")
    record.update(detail=run_detail(p, info))
    record.update(status=info.get("status", "?"), solver=c.solver, particle_radius=c.particle_radius,
                  tolerance=c.tolerance, notes=p.notes, extrapolated=c.extrapolated(),
                  fluid_particles=info["fluid_particles"], predicted=pred, actual=act,
                  wall_ratio=wall_ratio, error_ratio=err_ratio, calibration_seconds=p.calibration_seconds,
                  budget_used={"predicted": pred["wall_time"] / budget, "actual": act["wall_time"] / budget},
                  calibration_share=p.calibration_seconds / budget,
                  count_extrapolation=c.count_extrapolation, spacing_extrapolation=c.spacing_extrapolation,
                  goals={"wall_within_25pct": abs(wall_ratio - 1.0) <= WALL_GOAL,
                         "within_budget": act["wall_time"] <= budget,
                         "error_within_1_5x": err_ratio <= ERROR_GOAL,
                         "calibration_under_10pct": p.calibration_seconds <= CALIBRATION_GOAL * budget})
    shutil.rmtree(folder / "run", ignore_errors=True)  # the USD of a whole run: only its figures are kept
    return record


def run_detail(p, info: dict) -> dict:
    """The chosen setting's step cost and error course, predicted against the whole run's (run.json ``info``): the
    steady step time [s] and per fluid particle-step, the solver's sweeps per step (the calibration's largest count's
    and the run's), the whole-run cost ratio C (measured at the coarsest radius, applied), and the error's later-frames
    ratio R: the plan's (measured at the coarsest radius) against the run's own at the chosen radius (its mean over
    the frames after the calibrated ones over its mean over those)."""
    from warp_sph.plan.calibrate import solver_sweeps

    c = p.chosen
    m = p.models[c.solver]
    d = 2.0 * c.particle_radius
    step = m.step_cost(c.fluid_particles, c.boundary_particles, d) * m.tolerance_factor("step_time", c.tolerance)
    advanced = [f for f in info["frames"] if f["frame"] > 1]
    errors = [float(f["density_error_mean"]) for f in advanced]
    fc = m.calibrated_frames
    frames = len(errors)
    r_run = None
    if frames > fc >= 1 and sum(errors[:fc]) > 0:
        r_run = (sum(errors[fc:]) / len(errors[fc:])) / (sum(errors[:fc]) / fc)
    actual_step = float(info["sim_time_per_step_ms"]) * 1e-3
    largest = max((q for q in p.points if q["solver"] == c.solver and not q["whole_run"] and q["status"] == "completed"
                   and q["tolerance"] == c.tolerance), key=lambda q: q["fluid"], default=None)
    return {"step_time": {"predicted": step, "actual": actual_step},
            "per_fluid_particle_step": {"predicted": step / c.fluid_particles,
                                        "actual": actual_step / max(int(info["fluid_particles"]), 1),
                                        "largest_calibrated": largest["step_time"] / largest["fluid"] if largest else None},
            "sweeps": {"largest_calibrated": largest["sweeps"] if largest else None, "predicted": m.sweeps_at(d),
                       "factor": m.sweep_factor(c.fluid_particles, d), "solve_share": m.solve_share,
                       "actual": solver_sweeps(advanced)},
            "cost_ratio": {"measured": m.cost_ratio_measured, "applied": m.cost_ratio},
            "count_law_exponent": m.count_law.exponent if m.count_law is not None else None,
            "later_ratio": {"plan": m.later_ratio(frames) if m.has_profile(frames) else None, "run": r_run},
            "cpu": cpu_detail(step, largest, info),
            "slowed_points": slowed_detail(m),
            # the run's arrays [bytes] against the CPU's last-level cache (docs/plan-model.md, item 12): the plan's
            # fit at the chosen counts, the run's own, the most any calibration run took
            "array_bytes": {"predicted": m.array_bytes(c.fluid_particles, c.boundary_particles)
                            if m.array_bytes is not None else None, "actual": info.get("array_bytes"),
                            "largest_calibrated": m.array_bytes_calibrated, "cache": m.cache_bytes},
            "density_errors": errors}


def cpu_detail(step: float, largest: dict | None, info: dict) -> dict:
    """The step's process CPU time [s], fair on a loaded machine where wall time is not: the largest calibrated count's
    CPU seconds per wall second of its steps (``points.cpu_per_wall``: the cores it got; a timing point's too), the
    prediction in CPU (the predicted wall ``step`` [s] times that), the run's CPU per step over its frames 2.. (run.json
    ``frame_times``) and run / predicted (None where either was not recorded)."""
    from warp_sph.plan.points import cpu_per_step

    times = info.get("frame_times") or []
    run = cpu_per_step([int(t["steps"]) for t in times], [float(t.get("cpu_time", 0.0)) for t in times])
    per_wall = largest.get("cpu_per_wall") if largest else None
    predicted = step * per_wall if per_wall else None
    return {"largest_calibrated_per_wall": per_wall, "predicted": predicted, "run": run,
            "ratio": run / predicted if run and predicted else None}


def slowed_detail(model) -> list:
    """The chosen solver's calibration points left out of its step cost as slowed by the machine's load
    (``warp_sph.plan.points.slowed_points``): each point's radius [m], fluid count and step time [s], and those of
    the larger count that stepped faster."""
    keys = ("particle_radius", "fluid", "step_time")
    return [{**dict(zip(keys, s[:3])), "faster": dict(zip(keys, s[3:]))} for s in model.slowed]


def plan_scene(scene_name: str, overrides: list, **kwargs):
    """``warp_sph.plan.plan`` of the built-in scene with ``overrides`` (a Scene does not cross processes)."""
    from warp_sph.plan import plan
    from warp_sph.scene import load_scene

    return plan(load_scene(scene_name, overrides=overrides), **kwargs)


def fresh_process(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` in a new Python process (multiprocessing spawn); its result or its exception."""
    import multiprocessing

    with multiprocessing.get_context("spawn").Pool(1) as pool:
        return pool.apply(fn, args, kwargs)


def run_cases(args, out: Path, log=print) -> list[dict]:
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    budgets = [b.strip() for b in args.budgets.split(",") if b.strip()]
    solvers = [s.strip() for s in args.solvers.split(",") if s.strip()] or None
    work = Path(out) / "plan_cases"
    records = []
    for scene in scenes:
        for budget in budgets:
            records.append(run_case(scene, budget, args.duration, solvers, work, device=args.device,
                                    overrides=args.set, log=log))
            r = records[-1]
            if "goals" in r:
                log(f"  actual {r['actual']['wall_time']:.3g} s ({100 * (r['wall_ratio'] - 1):+.0f} %), error "
                    f"{100 * r['actual']['density_error']:.3g} % ({r['error_ratio']:.2f}x); goals "
                    + ", ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in r["goals"].items()))
            else:
                log(f"  {r['status']}: {r.get('error', '')}")
    shutil.rmtree(work, ignore_errors=True)
    return records


def section(records: list[dict], fmt, head) -> list[str]:
    """Markdown of the latest ``bench plan`` run: per scene and budget, predicted against actual."""
    if not records:
        return []
    lines = ["## The advisor: warp-sph plan against what happened", ""] + head(records)
    lines += ["Each case: `warp-sph plan SCENE --budget B` from an empty calibration cache, the chosen setting "
              "written with `--apply` and run whole in a fresh process (the scene's own outputs; the scenes "
              "shortened to the simulated time in the table). *wall*: run.json's wall time, predicted and actual; "
              "*error*: mean density error (mean over the frames after the first). *calib.*: the calibration's "
              "wall time. *budget used*: the wall time over the budget, predicted and actual (a plan aims at up to "
              "80 % of it, unless the count extrapolation stops it: its note says so). Goals (issue 37): actual wall within 25 % of the prediction and within the budget, "
              "error within 1.5x the predicted, calibration under 10 % of the budget. The load average (1 min) "
              "before and after the run says how loaded the machine was.", ""]
    header = ["scene", "sim. s", "budget", "status", "solver", "r [m]", "tolerance", "fluid N", "count extrap.", "wall pred. [s]",
              "wall actual [s]", "wall ratio", "budget used pred. / actual [%]", "error pred. [%]", "error actual [%]", "error ratio", "calib. [s]",
              "calib. / budget", "goals met", "load before / after"]
    rows = []
    for r in records:
        p = r.get("params") or {}
        pred, act, goals = r.get("predicted") or {}, r.get("actual") or {}, r.get("goals") or {}
        loads = "/".join(fmt((x or [None])[0]) for x in (r.get("load_before"), r.get("load_after")))
        rows.append([p.get("scene", "?"), fmt(p.get("duration")), fmt(p.get("budget")), r.get("status", "?"),
                     r.get("solver", "-"), fmt(r.get("particle_radius")),
                     "-" if r.get("tolerance") is None else fmt(r.get("tolerance")), fmt(r.get("fluid_particles")),
                     fmt(r.get("count_extrapolation")), fmt(pred.get("wall_time")), fmt(act.get("wall_time")),
                     fmt(r.get("wall_ratio")), "/".join(fmt((r.get("budget_used") or {}).get(k), 100)
                                                       for k in ("predicted", "actual")),
                     fmt(pred.get("density_error"), 100), fmt(act.get("density_error"), 100),
                     fmt(r.get("error_ratio")), fmt(r.get("calibration_seconds")), fmt(r.get("calibration_share")),
                     f"{sum(goals.values())}/{len(goals)}" if goals else "-", loads])
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
    done = [r for r in records if r.get("goals")]
    if done:
        names = list(done[0]["goals"])
        lines += ["Goals met: " + ", ".join(f"{k.replace('_', ' ')} {sum(r['goals'][k] for r in done)}/{len(done)}"
                                            for k in names) + ".", ""]
    detailed = [r for r in records if r.get("detail")]
    if detailed:
        lines += ["The chosen setting's step and error course, predicted against the run: the steady time per step, per "
                  "fluid particle-step (and at the largest calibrated count), the solver's sweeps per step (pressure and "
                  "divergence iterations: at the largest calibrated count / predicted / in the run), the whole-run step cost ratio "
                  "C (measured within the coarsest radius's whole run / applied), the error's later-frames ratio R (the "
                  "plan's, measured at the coarsest radius / the run's own at the chosen radius) and the step's process "
                  "CPU time, run / predicted (the predicted step times the largest calibrated count's CPU per wall "
                  "second: fair where the machine's load moved the wall time).", "",
                  "| scene | budget | step pred. / actual [ms] | us per fluid particle-step pred. / actual / largest calib. "
                  "| sweeps calib. / pred. / run | C measured / applied | R plan / run | step CPU run / pred. |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in detailed:
            d = r["detail"]
            lines.append("| " + " | ".join([
                r["params"]["scene"], fmt(r["params"]["budget"]),
                "/".join(fmt(d["step_time"][k], 1e3) for k in ("predicted", "actual")),
                "/".join(fmt(d["per_fluid_particle_step"][k], 1e6) for k in ("predicted", "actual", "largest_calibrated")),
                "/".join(fmt(d["sweeps"].get(k)) for k in ("largest_calibrated", "predicted", "actual")),
                "/".join(fmt(d["cost_ratio"][k]) for k in ("measured", "applied")),
                "/".join(fmt(d["later_ratio"][k]) for k in ("plan", "run")),
                fmt((d.get("cpu") or {}).get("ratio"))]) + " |")
        lines.append("")
    slowed = [f"- {r['params']['scene']} {fmt(r['params']['budget'])} s: r = {fmt(q['particle_radius'])} m "
              f"({q['fluid']} fluid) {fmt(q['step_time'], 1e3)} ms per step, slower than r = "
              f"{fmt(q['faster']['particle_radius'])} m ({q['faster']['fluid']} fluid) at "
              f"{fmt(q['faster']['step_time'], 1e3)} ms" for r in detailed for q in r["detail"].get("slowed_points") or []]
    if detailed:
        lines += ["Calibration points left out of the chosen solver's step cost as slowed by the machine's load (a larger "
                  "count stepped faster): " + ("none." if not slowed else ""), ""] + slowed + ([""] if slowed else [])
    notes = [f"- {r['params']['scene']} {fmt(r['params']['budget'])} s: {n}" for r in records for n in r.get("notes") or []]
    if notes:
        lines += ["What the calibration left out (to keep within 10 % of the budget) and what stopped a plan short "
                  "of the budget:", ""] + notes + [""]
    return lines
