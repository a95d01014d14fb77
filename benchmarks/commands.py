"""The subcommands of ``warp-sph bench``: each ``cmd_<name>(args, argv, log)`` runs its cases, appends
the records (``records.py``), logs its summary and rebuilds the report; returns the exit status
(``bench splishsplash`` and ``bench surface``, beside another tool: ``compare_commands.py``).
The parser that calls them is ``runner.py``; the cases themselves are in ``cases.py`` and the
benchmark's own module (``emission.py``, ``bodies.py``, ...).
"""
from __future__ import annotations

from pathlib import Path

from .arguments import check_names
from .records import append_records, command_text, host_info, now, report_path, results_dir, stamp

#: Named sweeps. Each preset is a list of sweeps (scene, parameter lists, fixed overrides, frames).
PRESETS: dict[str, list[dict]] = {
    "quick": [
        {"scene": "dam_break", "frames": 3,
         "set": ["particle_radius=0.1"],
         "params": {"solver": ["wcsph", "pbf"], "smoothing_kernel": ["cubic", "quintic"]}},
        {"scene": "hydrostatic", "frames": 2,
         "set": ["particle_radius=0.05"],
         "params": {"solver": ["wcsph"]}},
    ],
    "tradeoff": [
        {"scene": "dam_break", "frames": 25,
         "set": ["particle_radius=0.025"],
         "params": {"solver": ["wcsph", "pbf"], "smoothing_kernel": ["cubic", "quintic", "quadric"],
                    "time.cfl": ["0.2", "0.4", "0.8"]}},
        {"scene": "hydrostatic", "frames": 25,
         "set": ["particle_radius=0.025"],
         "params": {"solver": ["wcsph", "pbf"], "smoothing_kernel": ["cubic", "quintic", "quadric"]}},
    ],
    # implicit viscosity (weiler2018) at nu = 1 m^2/s against none, the honey scene's first second (issue #33's
    # goal: at most 2x the cost per simulated second); docs/viscosity.md
    "viscosity": [
        {"scene": "honey", "frames": 24,
         "set": [],
         "params": {"forces": ["[]", '[{method = "weiler2018", viscosity = 1.0, boundary_viscosity = 1.0}]'],
                    "particle_radius": ["0.01", "0.005"]}},
    ],
}

#: Resolutions of the scaling benchmark: particle radius [m] for the 1 m dam-break cube.
SCALING_RADII = (0.025, 0.0125, 0.008, 0.00625)  # 6,859 / 59,319 / 226,981 / 493,039 fluid particles


def _out(args) -> Path:
    return results_dir(getattr(args, "out", None), getattr(args, "publish", False))


def _executor(args, log):
    from warp_sph.sweep import make_executor

    return make_executor(workers=getattr(args, "workers", None), scheduler=getattr(args, "scheduler", None), log=log)


def refuse_unloadable(specs) -> None:
    """SceneError (one line, exit status 2) when no case's scene loads and all fail with the same error (an
    unknown key or a bad value in --param or --set), before any case runs; a case that loads beside ones that
    do not lets the runs go on (each bad one is a failed record, as in ``warp-sph sweep``)."""
    from warp_sph.core.errors import SceneError
    from warp_sph.scene import load_scene

    errors = set()
    for spec in specs:
        try:
            load_scene(spec.scene, overrides=list(spec.overrides))
        except SceneError as exc:
            errors.add(str(exc).splitlines()[0])
        else:
            return
    if len(errors) == 1:
        raise SceneError(f"bench: {'every case' if len(specs) > 1 else 'the case'}: {errors.pop()}")


def _run(specs, args, log) -> list[dict]:
    from .cases import run_specs

    refuse_unloadable(specs)
    return run_specs(specs, isolate=not args.in_process, log=log, executor=_executor(args, log))


def save_records(kind: str, records: list[dict], args, argv: list[str], invocation: str, log) -> Path:
    stamp(records, command_text(argv), invocation)
    out = _out(args)
    path = append_records(out, kind, records)
    log(f"wrote {len(records)} records to {path}")
    return out


def cmd_sweep(args, argv: list[str], log=print) -> int:
    from warp_sph.sweep.cases import expand_product, parse_param

    from .cases import RunSpec

    if args.preset:
        if args.preset not in PRESETS:
            from warp_sph.core.errors import WarpSphError

            raise WarpSphError(f"bench sweep: --preset {args.preset!r}: unknown preset; expected one of {', '.join(PRESETS)}")
        sweeps = PRESETS[args.preset]
        name = args.preset
    else:
        params = dict(parse_param(p) for p in args.param)
        sweeps = [{"scene": args.scene, "frames": args.frames or 2, "set": [], "params": params}]
        name = args.name or "custom"
    specs = []
    for sw in sweeps:
        frames = args.frames if (args.frames and args.preset) else sw["frames"]
        for combo in expand_product(sw["params"]):
            overrides = list(sw.get("set", [])) + list(args.set) + [f"{k}={v}" for k, v in combo.items()]
            specs.append(RunSpec(scene=sw["scene"], overrides=overrides, frames=frames, device=args.device,
                                 kind="sweep", name=name, params={"scene": sw["scene"], **combo},
                                 time_limit=args.time_limit))
    invocation = now()
    records = _run(specs, args, log)
    return finish_report(save_records("sweep", records, args, argv, invocation, log), args, records, log)


def cmd_scaling(args, argv: list[str], log=print) -> int:
    from warp_sph.sweep.cases import split_values

    from .cases import RunSpec
    from .records import solver_names
    from .traffic import TRAFFIC_STEPS

    check_names("--solver", args.solver, solver_names())
    radii = [float(r) for r in split_values(args.radii)] if args.radii else list(SCALING_RADII)

    def fixed(r: float) -> list[str]:
        """--fixed-dt: the step at r = 0.025 m scaled with r, so that every resolution runs at the same CFL
        number (the scene's step for a fluid at rest is about a frame, no step a run takes)."""
        return [f"time.fixed_dt={args.fixed_dt * r / 0.025:.6g}"] if args.fixed_dt else []

    specs = [RunSpec(scene=args.scene, overrides=[f"particle_radius={r}", f"solver={args.solver}"] + fixed(r) + list(args.set),
                     steps=args.steps, repeats=args.repeats, device=args.device, kind="scaling", name="scaling",
                     traffic_steps=TRAFFIC_STEPS,
                     params={"scene": args.scene, "solver": args.solver, "particle_radius": r}) for r in radii]
    invocation = now()
    records = _run(specs, args, log)
    return finish_report(save_records("scaling", records, args, argv, invocation, log), args, records, log)


def cmd_matrix(args, argv: list[str], log=print) -> int:
    from warp_sph.sweep.cases import split_values

    from .matrix import matrix_specs, status_word
    from .records import scene_names, solver_names

    check_names("--scenes", args.scenes, scene_names())
    check_names("--solvers", args.solvers, solver_names())
    specs = matrix_specs(scenes=split_values(args.scenes) if args.scenes else None,
                         solvers=split_values(args.solvers) if args.solvers else None,
                         radii=[float(r) for r in split_values(args.radii)] if args.radii else None,
                         frames=args.frames, device=args.device, time_limit=args.time_limit, overrides=args.set)
    invocation = now()
    records = _run(specs, args, log)
    counts: dict[str, int] = {}
    for r in records:
        counts[status_word(r)] = counts.get(status_word(r), 0) + 1
    log("matrix: " + ", ".join(f"{n} {w}" for w, n in sorted(counts.items())))
    out = save_records("matrix", records, args, argv, invocation, log)
    finish_report(out, args, records, log)
    return 1 if any(r["status"] == "failed" for r in records) else 0


def cmd_executors(args, argv: list[str], log=print) -> int:
    from .executor_speed import measure

    invocation = now()
    records = measure(workers=args.workers, particle_radius=args.particle_radius, frames=args.frames,
                      repeats=args.repeats, log=log)
    return finish_report(save_records("executors", records, args, argv, invocation, log), args, records, log)


def cmd_emission(args, argv: list[str], log=print) -> int:
    from . import emission as E
    from .records import solver_names

    check_names("--solvers", args.solvers, solver_names())
    solvers = [s.strip() for s in args.solvers.split(",") if s.strip()] if args.solvers else list(solver_names())
    specs = E.specs(args.scene, args.frames, args.repeats, solvers=solvers,
                    radius_text=args.radii, fixed=not args.no_fixed, device=args.device, overrides=args.set)
    invocation = now()
    records = _run(specs, args, log)
    for c in E.summary(records):
        b = c["best"]
        if b is None:
            continue
        side = f"; side by side {100 * c['side_by_side']:+.1f} %" if c["side_by_side"] is not None else ""
        log(f"emission {c['solver']} r = {c['particle_radius']:g} m: flow {b['flow_ms']:.3g} of {b['run_ms']:.4g} ms "
            f"CPU per frame, +{100 * b['share']:.2f} % per particle-step (goal <= +{100 * E.GOAL:.0f} %: "
            f"{'met' if c['met'] else 'not met'}){side}")
    return finish_report(save_records("emission", records, args, argv, invocation, log), args, records, log)


def cmd_bodies(args, argv: list[str], log=print) -> int:
    from . import bodies as B

    out = _out(args)
    specs = B.specs(args.scene, args.frames, args.repeats, out / "bodies_as_obstacles", device=args.device,
                    overrides=args.set)
    invocation = now()
    records = _run(specs, args, log)
    s = B.summary(records)
    if s:
        log(f"bodies: {s['bodies_ms']:.3g} ms per step, as static obstacles {s['obstacles_ms']:.3g} ms (fastest of "
            f"{args.repeats} each): {100 * s['extra']:+.1f} % (goal <= +{100 * B.GOAL:.0f} %: "
            f"{'met' if s['met'] else 'not met'})")
    return finish_report(save_records("bodies", records, args, argv, invocation, log), args, records, log)


def cmd_forces(args, argv: list[str], log=print) -> int:
    from warp_sph.methods import registry

    from . import forces as F

    check_names("--solvers", args.solvers, registry.solver_names())
    check_names("--forces", args.forces, registry.force_names())
    specs = F.specs(args.scene, args.frames, args.repeats, solvers=[s for s in args.solvers.split(",") if s],
                    forces=[f for f in args.forces.split(",") if f], device=args.device, overrides=args.set)
    invocation = now()
    records = _run(specs, args, log)
    for s in F.summary(records):
        log(f"{s['solver']} + {s['force']}: the force {s['force_ns']:.0f} ns per particle-step, the step "
            f"{s['step_ns']:.0f} (without forces {s['bare_step_ns'] or float('nan'):.0f})")
    return finish_report(save_records("forces", records, args, argv, invocation, log), args, records, log)


def cmd_whitewater(args, argv: list[str], log=print) -> int:
    from . import whitewater as W

    specs = W.specs(args.scene, args.frames, args.repeats, device=args.device, overrides=args.set,
                    rates=args.rates)
    invocation = now()
    records = _run(specs, args, log)
    for s in W.summaries(records):
        share = f"; the stage {100 * s['stage_share']:.1f} % of the stage time" if s["stage_share"] is not None else ""
        log(f"whitewater, {W._rates_text(s)}: {s['on_ms']:.4g} CPU ms per step on, {s['off_ms']:.4g} off (fastest of "
            f"{args.repeats} each): {100 * s['extra']:+.1f} %{share} (goal <= +{100 * W.GOAL:.0f} %: "
            f"{'met' if s['met'] else 'not met'})")
    return finish_report(save_records("whitewater", records, args, argv, invocation, log), args, records, log)


def cmd_validation(args, argv: list[str], log=print) -> int:
    from warp_sph.run.checkpoints import versions

    from . import validation as V
    from .records import solver_names

    cases = V.case_names(args.cases)
    check_names("--solvers", args.solvers, solver_names())
    solvers = [s.strip() for s in args.solvers.split(",") if s.strip()] if args.solvers else list(solver_names())
    resolutions = ["coarse", "fine"] if args.resolution == "both" else [args.resolution]
    invocation = now()
    if args.radius is not None and not args.radius > 0.0:
        from warp_sph.core.errors import WarpSphError

        raise WarpSphError(f"bench validation: --radius {args.radius!r}: expected a particle radius > 0 [m]")
    V.check_scenes(cases, solvers, resolutions, extra=args.set, radius=args.radius)  # bad --set: one line, exit 2
    ensemble = V.ensemble_settings(args.ensemble, args.jitter)  # bad --ensemble / --jitter: one line, exit 2
    records = V.run_validation(cases, solvers, resolutions, Path(args.runs), device=args.device, extra=args.set, log=log,
                               radius=args.radius, ensemble=ensemble)
    for r in records:
        r.update(host=host_info(), versions=versions(), date=now())
    out = save_records("validation", records, args, argv, invocation, log)
    from .report import load_records
    from .validation_plots import plot_case, plot_trade
    from .validation_report import latest_per_run

    merged = latest_per_run(load_records(out).get("validation", []))  # cases re-run one at a time keep the rest
    for case in cases:
        path = plot_case(case, [r for r in merged if r.get("case") == case], out / f"validation_{case}.png")
        if path:
            log(f"plot: {path}")
    path = plot_trade(merged, out / "validation_tradeoff.png")
    if path:
        log(f"plot: {path}")
    return finish_report(out, args, records, log)


def cmd_extremes(args, argv: list[str], log=print) -> int:
    from warp_sph.sweep.cases import split_values

    from .extremes import extreme_cases, run_cases
    from .records import solver_names

    check_names("--solvers", args.solvers, solver_names())
    cases = extreme_cases(split_values(args.solvers) if args.solvers else None, quick=args.quick)
    if args.families:
        check_names("--families", args.families, sorted({c.family for c in extreme_cases(None)}, key=str))
        families = split_values(args.families)
        cases = [c for c in cases if c.family in families]
    invocation = now()
    records = run_cases(cases, device=args.device, log=log)
    bad = [r for r in records if r["bad"]]
    log(f"extremes: {len(records)} cases, {len(bad)} silent bad")
    for r in bad:
        log(f"  bad: {r['label']}: {r['verdict']}")
    out = save_records("extremes", records, args, argv, invocation, log)
    if not args.no_report:
        from .report import write_report

        log(f"report: {write_report(out, md_path=report_path(out), log=log)}")
    return 1 if bad else 0


def cmd_plan(args, argv: list[str], log=print) -> int:
    from .plan import run_cases

    invocation = now()
    records = run_cases(args, _out(args), log=log)
    return finish_report(save_records("plan", records, args, argv, invocation, log), args, records, log)


def finish_report(out: Path, args, records: list[dict], log) -> int:
    if not getattr(args, "no_report", False):
        from .report import write_report

        log(f"report: {write_report(out, md_path=report_path(out), log=log)}")
    failed = [r for r in records if r["status"] == "failed"]
    for r in failed:
        log(f"failed: {r.get('engine', '')} {r['label']}: {r.get('error')}")
    return 1 if failed else 0


def cmd_report(args, argv: list[str], log=print) -> int:
    from .report import write_report

    out = _out(args)
    if not any(out.glob("*.jsonl")):  # a new folder or a typo: an empty page written there helps no one
        from warp_sph.core.errors import WarpSphError

        raise WarpSphError(f"bench report: {out} holds no benchmark records (*.jsonl); expected the results folder "
                           "of a benchmark run (--out DIR as given to it; default runs/bench)")
    md = write_report(out, md_path=Path(args.markdown) if args.markdown else report_path(out), log=log)
    log(f"report: {md}")
    return 0

