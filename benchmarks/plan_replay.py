"""Replay the recorded ``warp-sph bench plan`` cases: the step's cost fitted again from each record's points.

``python -m warp_sph.benchmarks.plan_replay [--detail-only] [PLAN.jsonl ...]`` (default
``benchmarks/results/plan.jsonl``; ``--detail-only``: the records with the run's step detail) takes every record
that kept its calibration points and its whole run's figures, fits the chosen solver's step cost again from those
points with the present code (``warp_sph.plan.models.step_cost_fields``), and predicts the chosen setting's wall time
with the record's own other models and its predicted steps: wall = load + set-up(N) + steps x step(Nf, Nb, d) +
frames x export wait(N); the whole run's course C is taken again from its frames' CPU time where the record kept them
(``points.course_ratio``; records before 2026-11-27 did not: their own C). Printed per record: the recorded prediction and the replayed one [s], the actual wall time
and actual / replayed (and the step's cost per fluid particle-step, replayed and actual [us], where the record has
the run's step time), then how many cases lie within 25 % (the goal of issue 37) and the geometric mean of the ratio.
Only the step's cost changes between the code a record was made with and the replay: the steps, the chosen setting
and the other models are the record's, so a rule is judged on the same settings the runs measured.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

GOAL = 0.25  # |actual / predicted - 1| at most (issue 37)


def _law(d):
    from warp_sph.plan.fit import PowerLaw

    return PowerLaw(d["coefficient"], d["exponent"], d.get("measured")) if d else None


def replay_model(record: dict):
    """(SolverModel of the record's chosen solver with the step cost fitted again from its points, the points)."""
    from warp_sph.plan.fit import Line, StepCost
    from warp_sph.plan.models import SolverModel, applied_cost_ratio, step_cost_fields
    from warp_sph.plan.points import Point, course_ratio
    from warp_sph.core.launch import MIN_RANGE

    plan = record["plan"]
    solver = record["solver"]
    m = plan["models"][solver]
    t0 = m.get("tolerance")
    pts = [Point(solver=q["solver"], particle_radius=q["particle_radius"], tolerance=q["tolerance"], fluid=q["fluid"],
                 boundary=q["boundary"], frames=q["frames"], steps=q["steps"], step_time=q["step_time"],
                 sweeps=q.get("sweeps", 0.0), first_in_process=q.get("first_in_process", False))
           for q in plan["points"] if q["solver"] == solver and q["status"] == "completed" and not q.get("whole_run")
           and (q["tolerance"] == t0 or t0 is None)]
    fields = step_cost_fields(pts, 2 * MIN_RANGE)  # every record was made on a CPU
    # the course C from the record's whole run where it kept its frames' CPU time (``points.course_ratio``), applied as
    # a plan applies it; else the record's own C
    cost_ratio = m.get("cost_ratio", 1.0)
    whole = [q for q in plan["points"] if q["solver"] == solver and q.get("whole_run") and q.get("frame_cpu")
             and (q["tolerance"] == t0 or t0 is None)]
    if whole and pts:
        w = max(whole, key=lambda q: q["particle_radius"])
        ratio, window = course_ratio(Point(solver=solver, particle_radius=w["particle_radius"],
                                           frame_steps=w["frame_steps"], frame_cpu=w["frame_cpu"]),
                                     min(p.frames for p in pts))
        cost_ratio = applied_cost_ratio(ratio, window) if ratio is not None else cost_ratio
    model = SolverModel(
        solver=solver, steps_per_second=None, error=None, step_time=fields.pop("step_time"),
        setup_time=Line(**m["setup_time"]), frame_overhead=Line(**m["frame_overhead"]), fluid_count=None,
        boundary_count=None, load_time=m["load_time"], calibrated_radii=m["calibrated_radii"],
        calibrated_particles=m["calibrated_particles"], tolerance=t0, tolerances=m.get("tolerances", []),
        tolerance_exponents=m.get("tolerance_exponents", {}), cost_ratio=cost_ratio,
        sweeps=_law(m.get("sweeps")), sweeps_bounds=tuple(m.get("sweeps_bounds", (0.0, 0.0))),
        sweeps_fluid=m.get("sweeps_fluid", 0), sweeps_reference=m.get("sweeps_reference", 0.0),
        solve_share=m.get("solve_share", 0.0), **fields)
    assert isinstance(model.step_time, StepCost)
    return model, pts


def replay(record: dict) -> dict:
    """The replayed prediction of one record: wall [s], step [s] and their ratios to the run."""
    model, _ = replay_model(record)
    plan, c = record["plan"], record["plan"]["chosen"]
    d = 2.0 * c["particle_radius"]
    nf, nb = c["fluid_particles"], c["boundary_particles"]
    step = model.step_cost(nf, nb, d) * model.tolerance_factor("step_time", c["tolerance"])
    n = nf + nb
    frames = plan["frames"] - 1  # the plan counts the initial frame; its prediction the advanced ones
    wall = model.load_time + model.setup_time(n) + c["steps"] * step + frames * model.frame_overhead(n)
    actual = record["actual"]["wall_time"]
    out = {"label": record["label"], "date": record["date"], "solver": c["solver"], "fluid": nf,
           "recorded": c["wall_time"], "replayed": wall, "actual": actual, "ratio": actual / wall,
           "recorded_ratio": record["wall_ratio"], "step": step}
    detail = record.get("detail") or {}
    if detail.get("step_time"):
        out["step_actual"] = detail["step_time"]["actual"]
        out["fluid_actual"] = record.get("fluid_particles") or nf
    return out


def records(paths) -> list[dict]:
    """The records of ``paths`` a replay can use: completed, with calibration points, a chosen setting and a run."""
    out = []
    for path in paths:
        for line in Path(path).read_text().splitlines():
            r = json.loads(line)
            if r.get("kind") == "plan" and r.get("status") == "completed" and (r.get("plan") or {}).get("points") \
                    and r.get("actual"):
                out.append(r)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="*", default=[str(Path(__file__).parent / "results" / "plan.jsonl")])
    ap.add_argument("--detail-only", action="store_true", help="only the records with the run's step detail")
    args = ap.parse_args(argv)
    rows = [replay(r) for r in records(args.paths) if not args.detail_only or r.get("detail")]
    print(f"{'case':18} {'date':16} {'solver':6} {'fluid':>7} {'recorded':>9} {'replayed':>9} {'actual':>8} "
          f"{'rec. ratio':>10} {'ratio':>6} {'us/fps pred':>11} {'actual':>7}")
    for x in rows:
        us = f"{1e6 * x['step'] / x['fluid']:11.3f}"
        ua = f"{1e6 * x['step_actual'] / x['fluid_actual']:7.3f}" if "step_actual" in x else f"{'-':>7}"
        print(f"{x['label']:18} {x['date'][:16]:16} {x['solver']:6} {x['fluid']:7d} {x['recorded']:9.2f} "
              f"{x['replayed']:9.2f} {x['actual']:8.2f} {x['recorded_ratio']:10.3f} {x['ratio']:6.3f} {us} {ua}")
    for scene in sorted({x["label"].rsplit("-", 1)[0] for x in rows}):
        sel = [x["ratio"] for x in rows if x["label"].startswith(scene + "-")]
        ok = sum(abs(v - 1.0) <= GOAL for v in sel)
        gm = math.exp(sum(math.log(v) for v in sel) / len(sel))
        print(f"{scene}: {ok}/{len(sel)} within {100 * GOAL:.0f} %, geometric mean actual / replayed {gm:.3f}, "
              f"range {min(sel):.3f}-{max(sel):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
