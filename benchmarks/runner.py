"""``warp-sph bench``: the command line of the benchmarks (measure the trade between speed and accuracy).

    warp-sph bench sweep --scene dam_break --param solver=wcsph,pbf --param time.cfl=0.2,0.4 --frames 25
    warp-sph bench sweep --preset quick            # tiny, for CI and tests
    warp-sph bench sweep --preset tradeoff         # the results page
    warp-sph bench scaling                         # time and memory per particle against N
    warp-sph bench matrix                          # every scene x every solver x resolution
    warp-sph bench executors                       # a sweep on the serial executor and on a LocalCluster
    warp-sph bench splishsplash                    # side by side with SPlisHSPlasH (pysplishsplash)
    warp-sph bench surface                         # surface reconstruction per frame
    warp-sph bench bodies                          # moving rigid bodies against the same static obstacles
    warp-sph bench emission                        # what emitters and sinks add per particle-step, per solver
    warp-sph bench forces                          # each force's cost per particle-step beside its solver's
    warp-sph bench whitewater                      # a splash scene with whitewater on against off
    warp-sph bench validation                      # every solver against experiments (benchmarks/validation.py)
    warp-sph bench extremes                        # every solver at the extremes: completed, stopped or refused
    warp-sph bench plan                            # warp-sph plan: predicted against actual wall time and error
    warp-sph bench report                          # RESULTS.md from the JSON lines

Results go to ``runs/bench/`` (JSON lines and ``RESULTS.md``) unless ``--out DIR``; ``--publish``
writes the committed ``benchmarks/results/`` and rebuilds ``benchmarks/RESULTS.md``. ``sweep``,
``scaling`` and ``matrix`` run their cases on the executors of ``warp-sph sweep`` (``--workers N``:
a Dask LocalCluster; ``--scheduler ADDR``: an existing cluster; default serial). The runs
themselves are in ``cases.py``; records and where they go in ``records.py``; tables and plots in
``report.py``.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

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


def number(kind: type, minimum: float, strict: bool = True, many: bool = False):
    """argparse type: a number of ``kind`` (int or float) above ``minimum`` (or at it, ``strict=False``),
    finite; ``many``: comma-separated such numbers, kept as the text the commands split. A bad value is
    argparse's one-line error, exit status 2."""
    what = f"{'comma-separated ' if many else 'an '}{'integer' if kind is int else 'number'}{'s' if many else ''} " \
           f"{'>' if strict else '>='} {minimum:g}"

    def check(text: str):
        try:
            values = [kind(v.strip()) for v in (text.split(",") if many else [text]) if v.strip()]
            ok = bool(values) and all(math.isfinite(v) and (v > minimum if strict else v >= minimum) for v in values)
        except ValueError:
            ok = False
        if not ok:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return text if many else values[0]

    return check


positive_int = number(int, 0)
positive_float = number(float, 0)
positive_ints = number(int, 0, many=True)
positive_floats = number(float, 0, many=True)
nonnegative_floats = number(float, 0, strict=False, many=True)


def whitewater_rates(text: str) -> list[str]:
    """argparse type of ``bench whitewater --rates``: comma-separated names of ``whitewater.RATES``."""
    from .whitewater import RATES

    names = [r.strip() for r in text.split(",") if r.strip()]
    if not names or any(r not in RATES for r in names):
        raise argparse.ArgumentTypeError(f"expected comma-separated rate sets of {', '.join(RATES)}, got {text!r}")
    return names


def check_names(option: str, text: str | None, known) -> None:
    """Refuse unknown scene or solver names before any case runs (one line, exit status 2)."""
    from warp_sph.core.errors import WarpSphError

    if not text:
        return
    bad = [v.strip() for v in text.split(",") if v.strip() and v.strip() not in known]
    if bad:
        raise WarpSphError(f"bench: {option} {text!r}: unknown {', '.join(map(repr, bad))}; "
                           f"expected some of {', '.join(known)}")


def _out(args) -> Path:
    return results_dir(getattr(args, "out", None), getattr(args, "publish", False))


def _executor(args, log):
    from warp_sph.sweep import make_executor

    return make_executor(workers=getattr(args, "workers", None), scheduler=getattr(args, "scheduler", None), log=log)


def _run(specs, args, log) -> list[dict]:
    from .cases import run_specs

    return run_specs(specs, isolate=not args.in_process, log=log, executor=_executor(args, log))


def _save(kind: str, records: list[dict], args, argv: list[str], invocation: str, log) -> Path:
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
            raise SystemExit(f"warp-sph bench: unknown preset {args.preset!r}; presets: {', '.join(PRESETS)}")
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
    return _finish(_save("sweep", records, args, argv, invocation, log), args, records, log)


def cmd_scaling(args, argv: list[str], log=print) -> int:
    from warp_sph.sweep.cases import split_values

    from .cases import RunSpec
    from .records import solver_names

    check_names("--solver", args.solver, solver_names())
    radii = [float(r) for r in split_values(args.radii)] if args.radii else list(SCALING_RADII)

    def fixed(r: float) -> list[str]:
        """--fixed-dt: the step at r = 0.025 m scaled with r, so that every resolution runs at the same CFL
        number (the scene's step for a fluid at rest is about a frame, no step a run takes)."""
        return [f"time.fixed_dt={args.fixed_dt * r / 0.025:.6g}"] if args.fixed_dt else []

    specs = [RunSpec(scene=args.scene, overrides=[f"particle_radius={r}", f"solver={args.solver}"] + fixed(r) + list(args.set),
                     steps=args.steps, repeats=args.repeats, device=args.device, kind="scaling", name="scaling",
                     params={"scene": args.scene, "solver": args.solver, "particle_radius": r}) for r in radii]
    invocation = now()
    records = _run(specs, args, log)
    return _finish(_save("scaling", records, args, argv, invocation, log), args, records, log)


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
    out = _save("matrix", records, args, argv, invocation, log)
    _finish(out, args, records, log)
    return 1 if any(r["status"] == "failed" for r in records) else 0


def cmd_executors(args, argv: list[str], log=print) -> int:
    from .executor_speed import measure

    invocation = now()
    records = measure(workers=args.workers, particle_radius=args.particle_radius, frames=args.frames,
                      repeats=args.repeats, log=log)
    return _finish(_save("executors", records, args, argv, invocation, log), args, records, log)


def cmd_splishsplash(args, argv: list[str], log=print) -> int:
    from warp_sph.sweep.cases import split_values

    from . import splishsplash as S
    from .splishsplash_report import speed_ratios

    invocation = now()
    if args.publish and not args.skip_warp_sph:
        ok, why = S.available()
        if not ok:
            from warp_sph.core.errors import WarpSphError

            raise WarpSphError(f"bench splishsplash --publish: SPlisHSPlasH cannot run here ({why}), and the "
                               "published page compares both engines in the same run: pip install pysplishsplash")
    if args.adaptive:
        return _splishsplash_adaptive(args, argv, invocation, log)
    check_names("--solvers", args.solvers, S.FIXED_STEP_SOLVERS)
    records = S.run_comparison(
        particle_radius=args.particle_radius, frames=args.frames, threads=args.threads or 1,
        solvers=split_values(args.solvers) if args.solvers else list(S.FIXED_STEP_SOLVERS),
        dt={"wcsph": args.dt_wcsph, "pbf": args.dt_pbf, "dfsph": args.dt_dfsph},
        device=args.device, isolate=not args.in_process, skip_warp_sph=args.skip_warp_sph,
        splishsplash_gap=args.splishsplash_gap, warp_sph_overrides=args.warp_sph_set, repeats=args.repeats,
        log=log)
    out = _save("splishsplash", records, args, argv, invocation, log)
    for q in speed_ratios(records):
        log(f"{q['solver']}: warp-sph time / SPlisHSPlasH time = {q['ratio']:.2f} wall"
            + (f", {q['cpu_ratio']:.2f} CPU" if q.get("cpu_ratio") else "") + " "
            f"(SPlisHSPlasH on {q['threads']} threads); mean density error {100 * (q['ours_error'] or 0):.3f} % "
            f"vs {100 * (q['ref_error'] or 0):.3f} %")
    return _finish(out, args, records, log)


def parse_resolutions(text: str) -> list[tuple[float, float]]:
    """'0.025:1.0,0.0125:0.3' -> [(0.025, 1.0), (0.0125, 0.3)]: particle radius [m] and simulated seconds."""
    from warp_sph.core.errors import WarpSphError

    out = []
    for item in [v.strip() for v in text.split(",") if v.strip()]:
        r, sep, d = item.partition(":")
        try:
            out.append((float(r), float(d) if sep else 1.0))
        except ValueError:
            raise WarpSphError(f"bench splishsplash: --resolutions {text!r}: expected RADIUS:SECONDS,... "
                               "e.g. 0.025:1.0,0.0125:0.3") from None
        if out[-1][0] <= 0 or out[-1][1] <= 0:
            raise WarpSphError(f"bench splishsplash: --resolutions {text!r}: radius and seconds must be > 0")
    return out


def _splishsplash_adaptive(args, argv: list[str], invocation: str, log) -> int:
    from . import splishsplash as S

    from warp_sph.methods.registry import solver_names
    from warp_sph.sweep.cases import split_values

    resolutions = parse_resolutions(args.resolutions) if args.resolutions else list(S.ADAPTIVE_RESOLUTIONS)
    ours, theirs = list(solver_names()), list(S.ADAPTIVE_SPLISHSPLASH)
    if args.solvers:  # filters both engines' cases: dfsph -> warp-sph dfsph and SPlisHSPlasH's DFSPH cases
        check_names("--solvers", args.solvers, sorted(set(ours) | {method for _, method, _ in theirs}))
        chosen = split_values(args.solvers)
        ours = [s for s in ours if s in chosen]
        theirs = [case for case in theirs if case[1] in chosen]
    records = S.run_adaptive(resolutions, threads=args.threads or 2, warp_sph_solvers=ours, splishsplash_cases=theirs,
                             device=args.device, isolate=not args.in_process,
                             skip_warp_sph=args.skip_warp_sph, warp_sph_overrides=args.warp_sph_set,
                             repeats=args.repeats, log=log)
    out = _save("splishsplash", records, args, argv, invocation, log)
    for q in S.adaptive_ratios(records):
        log(f"{q['fluid_particles']} particles: warp-sph dfsph / SPlisHSPlasH {q['case']} = {q['ratio']:.2f} wall"
            + (f", {q['cpu_ratio']:.2f} CPU" if q.get("cpu_ratio") else "")
            + f" (SPlisHSPlasH on {q['threads']} threads); mean density error {100 * (q['ours_error'] or 0):.3f} % "
            f"vs {100 * (q['ref_error'] or 0):.3f} %")
    return _finish(out, args, records, log)


def cmd_surface(args, argv: list[str], log=print) -> int:
    from warp_sph.run.runner import versions

    from .surface import run_surface_bench, splashsurf_available

    if args.publish and not args.no_splashsurf and not splashsurf_available():
        from warp_sph.core.errors import WarpSphError

        raise WarpSphError("bench surface --publish: pysplashsurf is not installed, and the published page compares "
                           "with splashsurf in the same run: pip install pysplashsurf (or pass --no-splashsurf)")
    radii = [float(v) for v in args.radius.split(",")]
    times = [float(v) for v in args.time.split(",")]
    if len(times) == 1:
        times = times * len(radii)
    threads = [int(v) for v in args.threads.split(",")]
    cases = [c.strip() for c in args.cases.split(",")]
    bad = [c for c in cases if c not in ("frame", "run")]
    if bad:
        from warp_sph.core.errors import WarpSphError

        raise WarpSphError(f"bench surface --cases: unknown case {bad[0]!r}; expected frame, run or both (frame,run)")
    records = []
    if "frame" in cases:
        records += run_surface_bench(radii=radii, times=times, cells=[float(v) for v in args.cell.split(",")],
                                     threads=threads, repeats=args.repeats, splashsurf=not args.no_splashsurf,
                                     device=args.device, log=log)
    if "run" in cases:
        from .surface_run import run_default_run_bench

        records += run_default_run_bench(radii=radii, threads=threads, splashsurf=not args.no_splashsurf,
                                         device=args.device, frames=args.frames, log=log)
    for r in records:
        r.update(host=host_info(), versions=versions(), date=now())
    out = _save("surface", records, args, argv, now(), log)
    return _finish(out, args, records, log)


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
    return _finish(_save("emission", records, args, argv, invocation, log), args, records, log)


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
    return _finish(_save("bodies", records, args, argv, invocation, log), args, records, log)


def cmd_forces(args, argv: list[str], log=print) -> int:
    from . import forces as F

    specs = F.specs(args.scene, args.frames, args.repeats, solvers=[s for s in args.solvers.split(",") if s],
                    forces=[f for f in args.forces.split(",") if f], device=args.device, overrides=args.set)
    invocation = now()
    records = _run(specs, args, log)
    for s in F.summary(records):
        log(f"{s['solver']} + {s['force']}: the force {s['force_ns']:.0f} ns per particle-step, the step "
            f"{s['step_ns']:.0f} (without forces {s['bare_step_ns'] or float('nan'):.0f})")
    return _finish(_save("forces", records, args, argv, invocation, log), args, records, log)


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
    return _finish(_save("whitewater", records, args, argv, invocation, log), args, records, log)


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
    out = _save("validation", records, args, argv, invocation, log)
    from . import validation_report as VR
    from .report import load_records

    merged = VR.latest_per_run(load_records(out).get("validation", []))  # cases re-run one at a time keep the rest
    for case in cases:
        path = VR.plot_case(case, [r for r in merged if r.get("case") == case], out / f"validation_{case}.png")
        if path:
            log(f"plot: {path}")
    path = VR.plot_trade(merged, out / "validation_tradeoff.png")
    if path:
        log(f"plot: {path}")
    return _finish(out, args, records, log)


def cmd_extremes(args, argv: list[str], log=print) -> int:
    from warp_sph.sweep.cases import split_values

    from .extremes import extreme_cases, run_cases
    from .records import solver_names

    check_names("--solvers", args.solvers, solver_names())
    cases = extreme_cases(split_values(args.solvers) if args.solvers else None, quick=args.quick)
    if args.families:
        families = split_values(args.families)
        cases = [c for c in cases if c.family in families]
    invocation = now()
    records = run_cases(cases, device=args.device, log=log)
    bad = [r for r in records if r["bad"]]
    log(f"extremes: {len(records)} cases, {len(bad)} silent bad")
    for r in bad:
        log(f"  bad: {r['label']}: {r['verdict']}")
    out = _save("extremes", records, args, argv, invocation, log)
    if not args.no_report:
        from .report import write_report

        log(f"report: {write_report(out, md_path=report_path(out), log=log)}")
    return 1 if bad else 0


def cmd_plan(args, argv: list[str], log=print) -> int:
    from .plan import run_cases

    invocation = now()
    records = run_cases(args, _out(args), log=log)
    return _finish(_save("plan", records, args, argv, invocation, log), args, records, log)


def _finish(out: Path, args, records: list[dict], log) -> int:
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
    md = write_report(out, md_path=Path(args.markdown) if args.markdown else report_path(out), log=log)
    log(f"report: {md}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from warp_sph.cli_parser import OneLineParser  # argparse's errors as one line (exit status 2)

    p = OneLineParser(prog="warp-sph bench", description="Benchmarks: speed, accuracy and their trade. "
                                "Results go to JSON lines and RESULTS.md in runs/bench (or --out); --publish "
                                "writes the committed benchmarks/results and benchmarks/RESULTS.md.")
    sub = p.add_subparsers(dest="command")

    def where(q):
        g = q.add_mutually_exclusive_group()
        g.add_argument("--out", help="results folder (default: runs/bench; RESULTS.md in it)")
        g.add_argument("--publish", action="store_true",
                       help="write the committed results (benchmarks/results) and rebuild benchmarks/RESULTS.md")

    def common(q, executors=False):
        where(q)
        q.add_argument("--device", default=None, help="Warp device (cpu, cuda:0; default: Warp's default)")
        q.add_argument("--in-process", action="store_true",
                       help="run cases in this process (faster start; peak memory then covers every case so far)")
        q.add_argument("--no-report", action="store_true", help="do not regenerate the Markdown report and plots")
        q.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                       help="scene override applied to every case (repeatable)")
        if executors:
            g = q.add_mutually_exclusive_group()
            g.add_argument("--workers", type=int, nargs="?", const=0, default=None, metavar="N",
                           help="run the cases on a Dask LocalCluster of N processes (default N: the cores); runs "
                                "then share the cores, so compare timings from serial runs only")
            g.add_argument("--scheduler", metavar="tcp://HOST:8786", help="run the cases on an existing Dask cluster")

    s = sub.add_parser("sweep", help="cartesian product of --param lists (or a --preset)")
    s.add_argument("--scene", default="dam_break", help="built-in scene or .toml path (default: dam_break)")
    s.add_argument("--param", action="append", default=[], metavar="KEY=V1,V2",
                   help="scene key path and the values to sweep, e.g. solver=wcsph,pbf (repeatable)")
    s.add_argument("--frames", type=positive_int, default=None, help="frames to simulate per case (default 2; presets set their own)")
    s.add_argument("--preset", help=f"named sweep: {', '.join(PRESETS)}")
    s.add_argument("--name", help="name of this sweep in the report (default: custom)")
    s.add_argument("--time-limit", type=positive_float, default=None, help="stop a case after this many seconds of stepping")
    common(s, executors=True)
    s.set_defaults(func=cmd_sweep)

    c = sub.add_parser("scaling", help="time and memory per particle against particle count")
    c.add_argument("--scene", default="dam_break", help="built-in scene or .toml path (default: dam_break)")
    c.add_argument("--radii", type=positive_floats, default=None, help=f"comma-separated particle radii [m] (default {','.join(map(str, SCALING_RADII))})")
    c.add_argument("--steps", type=positive_int, default=20, help="substeps timed per resolution (default 20)")
    c.add_argument("--repeats", type=positive_int, default=3,
                   help="time that many consecutive blocks of --steps substeps and keep the fastest (default 3)")
    c.add_argument("--solver", default="wcsph", help="solver to scale (default: wcsph)")
    c.add_argument("--fixed-dt", type=positive_float, default=None, metavar="SECONDS",
                   help="fixed step at r = 0.025 m [s], scaled with the particle radius (the same CFL number at "
                        "every resolution; default: the scene's step for the fluid at rest)")
    common(c, executors=True)
    c.set_defaults(func=cmd_scaling)

    m = sub.add_parser("matrix", help="every built-in scene x every solver x resolution: finished or stopped, and why")
    m.add_argument("--radii", type=positive_floats, default=None, help="particle radii [m] for every scene (default: 0.025,0.0125, the dam "
                   "break also 0.008; with a CUDA --device also 0.00625,0.004)")
    m.add_argument("--scenes", default=None, help="comma-separated scenes (default: every built-in scene)")
    m.add_argument("--solvers", default=None, help="comma-separated solvers (default: every solver)")
    m.add_argument("--frames", type=positive_int, default=None, help="frames per case (default: the scene's first second, at most 24)")
    m.add_argument("--time-limit", type=positive_float, default=None, help="stop a case after this many seconds of stepping")
    common(m, executors=True)
    m.set_defaults(func=cmd_matrix)

    e = sub.add_parser("executors", help="the same 8-case sweep on the serial executor and on a Dask LocalCluster")
    e.add_argument("--workers", type=positive_int, default=2, help="LocalCluster worker processes (default 2)")
    e.add_argument("--particle-radius", type=positive_float, default=0.05, help="particle radius of the cases [m] (default 0.05)")
    e.add_argument("--frames", type=positive_int, default=49, help="frames per case including the initial one (default 49: 2 s)")
    e.add_argument("--repeats", type=positive_int, default=2, help="serial and LocalCluster runs, alternating (default 2)")
    e.add_argument("--no-report", action="store_true", help="do not regenerate the Markdown report")
    where(e)
    e.set_defaults(func=cmd_executors)

    x = sub.add_parser("splishsplash", help="the same dam break in warp-sph and SPlisHSPlasH (pysplishsplash)")
    x.add_argument("--particle-radius", type=positive_float, default=0.025,
                   help="particle radius [m] of the fixed-step comparison (default 0.025: 6,859 fluid particles)")
    x.add_argument("--frames", type=positive_int, default=25, help="frames at 24 fps (default 25: about 1 s)")
    x.add_argument("--threads", type=positive_int, default=None,
                   help="OMP_NUM_THREADS for SPlisHSPlasH (default 1; 2 with --adaptive)")
    x.add_argument("--adaptive", action="store_true",
                   help="each engine's own adaptive step (SPlisHSPlasH cflMethod 1) and defaults: every warp-sph "
                        "solver and SPlisHSPlasH's DFSPH, IISPH, PBF and WCSPH (stiffness 50,000) at each "
                        "--resolutions (--solvers picks some); one speed/accuracy plot per resolution")
    x.add_argument("--resolutions", default=None, metavar="R:S,...",
                   help="with --adaptive: particle radius [m] and simulated seconds per resolution "
                        "(default 0.025:1.0,0.0125:0.3: 6,859 particles for 1 s, 59,319 for 0.3 s)")
    x.add_argument("--repeats", type=positive_int, default=1,
                   help="runs of every case, in turns (fixed step: warp-sph and SPlisHSPlasH of each solver "
                        "alternating); the fastest of each counts (default 1)")
    x.add_argument("--solvers", default=None,
                   help="comma-separated solvers; fixed step (default wcsph,pbf,dfsph): wcsph,pbf in both engines, "
                        "dfsph in SPlisHSPlasH only; --adaptive (default: all): each named warp-sph solver and the "
                        "SPlisHSPlasH cases of that method (dfsph, iisph, pbf, wcsph)")
    x.add_argument("--dt-wcsph", type=positive_float, default=None, help="fixed step for WCSPH [s] (default: CFL 0.4 bound)")
    x.add_argument("--dt-pbf", type=positive_float, default=None, help="fixed step for PBF [s] (default 0.002 * r/0.025)")
    x.add_argument("--dt-dfsph", type=positive_float, default=None, help="fixed step for DFSPH [s] (default: as PBF)")
    x.add_argument("--skip-warp-sph", action="store_true", help="only the SPlisHSPlasH runs")
    x.add_argument("--splishsplash-gap", type=float, default=None, metavar="D",
                   help="place SPlisHSPlasH's fluid D spacings from the walls (default: on warp-sph's lattice)")
    x.add_argument("--warp-sph-set", action="append", default=[], metavar="KEY=VALUE",
                   help="scene override for warp-sph's runs only (repeatable; wcsph.* keys for its WCSPH run, "
                        "pbf.* for its PBF run), e.g. wcsph.speed_of_sound_factor=11; SPlisHSPlasH keeps the "
                        "stiffness and time step of the scene without it")
    common(x)
    x.set_defaults(func=cmd_splishsplash)

    u = sub.add_parser("surface", help="surface reconstruction time per frame on dam-break particles, warp-sph "
                       "and splashsurf (pysplashsurf, optional) side by side")
    common(u)
    u.add_argument("--radius", type=positive_floats, default="0.025", help="particle radii [m], comma separated (default 0.025: 6,859 "
                   "particles; 0.0125: 59,319)")
    u.add_argument("--time", type=nonnegative_floats, default="0.3", help="simulated time [s] of the particles, per radius or one for all (default 0.3)")
    u.add_argument("--cell", type=positive_floats, default="0.5", help="cell sizes per particle radius (default 0.5)")
    u.add_argument("--threads", type=positive_ints, default="1,2", help="CPU thread counts, the same for both tools (default 1,2)")
    u.add_argument("--repeats", type=positive_int, default=5, help="timed calls per case, the median counts (default 5)")
    u.add_argument("--no-splashsurf", action="store_true", help="warp-sph only")
    u.add_argument("--cases", default="frame,run", help="frame: one frame at --time, each --cell, warm repeats; "
                   "run: every frame of the default run at the default settings, with the simulation's time per "
                   "frame (default: both)")
    u.add_argument("--frames", type=positive_int, default=None, help="frames of the run case (default: the "
                   "scene's duration * fps + 1, as warp-sph run)")
    u.set_defaults(func=cmd_surface)

    b = sub.add_parser("bodies", help="a scene with moving rigid bodies against the same bodies as static obstacles: "
                       "cost per step")
    b.add_argument("--scene", default="floating_bodies", help="scene with [[bodies]] (default: floating_bodies)")
    b.add_argument("--frames", type=positive_int, default=24, help="frames per run after the initial one (default 24: 1 s)")
    b.add_argument("--repeats", type=positive_int, default=3,
                   help="runs of each variant, alternating; the fastest counts (default 3)")
    common(b)
    b.set_defaults(func=cmd_bodies)

    e = sub.add_parser("emission", help="the cost emitters and sinks add per particle-step: their own stages timed "
                       "in the run (CPU), each solver at two sizes; and the scene without them side by side")
    e.add_argument("--scene", default="river", help="scene with [[emitters]] or [[sinks]] (default: river)")
    e.add_argument("--frames", type=positive_int, default=24, help="frames per run after the initial one (default 24: 1 s)")
    e.add_argument("--repeats", type=positive_int, default=2,
                   help="runs of each case, alternating; the fastest counts (default 2)")
    e.add_argument("--solvers", default=None, help="comma-separated solvers (default: every solver)")
    e.add_argument("--radii", type=positive_floats, default=None, help="comma-separated particle radii [m] (default: "
                   "the scene's and half of it: river 0.025,0.0125)")
    e.add_argument("--no-fixed", action="store_true", help="skip the side-by-side runs without emitters and sinks")
    common(e)
    e.set_defaults(func=cmd_emission)

    f = sub.add_parser("forces", help="each registered force's cost per particle-step beside its solver's (and the "
                       "same scene without forces)")
    f.add_argument("--scene", default="dam_break", help="scene (default: dam_break)")
    f.add_argument("--frames", type=positive_int, default=6, help="frames per run (default 6)")
    f.add_argument("--repeats", type=positive_int, default=2, help="runs of each case, alternating; the fastest counts")
    f.add_argument("--solvers", default="", help="comma-separated solvers (default: every registered solver)")
    f.add_argument("--forces", default="", help="comma-separated forces (default: every registered force)")
    common(f)
    f.set_defaults(func=cmd_forces)

    w = sub.add_parser("whitewater", help="a splash scene with [whitewater] (at the default and at SPlisHSPlasH's "
                       "generation rates) against without: CPU time per step")
    w.add_argument("--scene", default="dam_break", help="scene (default: dam_break)")
    w.add_argument("--frames", type=positive_int, default=30, help="frames per run (default 30: 1.25 s of the dam break)")
    w.add_argument("--repeats", type=positive_int, default=2, help="runs of each variant, alternating; the fastest counts")
    w.add_argument("--rates", type=whitewater_rates, default="default,splishsplash",
                   help="comma-separated generation rate sets with whitewater on: default (the scene keys' defaults, "
                   "k_ta 500, k_wc 6250 1/s), splishsplash (SPlisHSPlasH's 4000, 50000 1/s); default: both")
    common(w)
    w.set_defaults(func=cmd_whitewater)

    from .validation import add_arguments as validation_arguments

    v = sub.add_parser("validation", help="every solver against published experiments (column collapse, dam-break "
                       "wall pressure, hydrostatic tank) at two resolutions: error figures and plots")
    validation_arguments(v)
    common(v)
    v.set_defaults(func=cmd_validation)

    x = sub.add_parser("extremes", help="every solver at the extremes (steps, drops, viscosity, stiffness, body "
                       "densities, a single particle, 1 mm and 1 km scenes): completed, stopped or refused, and no "
                       "silent bad result")
    x.add_argument("--solvers", default=None, help="comma-separated solvers (default: every solver)")
    x.add_argument("--families", default=None, help="comma-separated families: dt, drop, viscosity, stiffness, body, "
                   "single, scale (default: all)")
    x.add_argument("--quick", action="store_true", help="a handful of cases (the test suite's)")
    x.add_argument("--device", default=None, help="Warp device (cpu, cuda:0; default: Warp's default)")
    x.add_argument("--no-report", action="store_true", help="do not regenerate the Markdown report")
    where(x)
    x.set_defaults(func=cmd_extremes)

    from .plan import add_arguments as plan_arguments

    n = sub.add_parser("plan", help="warp-sph plan on built-in scenes: predicted against actual wall time and error "
                       "(small budgets)")
    plan_arguments(n)
    common(n)
    n.set_defaults(func=cmd_plan)

    r = sub.add_parser("report", help="regenerate RESULTS.md, tables and plots from the JSON lines")
    where(r)
    r.add_argument("--markdown", help="report path (default: RESULTS.md in the results folder; with --publish "
                   "benchmarks/RESULTS.md)")
    r.set_defaults(func=cmd_report)
    return p


def main(argv: list[str] | None = None) -> int:
    from warp_sph.core.device import init_warp

    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):  # a usage error: the short usage and the benchmarks (warp_sph.cli_parser)
        from warp_sph.cli_parser import short_usage

        print(short_usage(parser), file=sys.stderr)
        return 2
    if getattr(args, "out", None):  # a results folder: a file there ended the benchmark's run in a traceback
        from warp_sph.core.errors import OutputError

        out = q = Path(args.out)
        while not q.exists() and q != q.parent:
            q = q.parent
        if q.exists() and not q.is_dir():
            raise OutputError(f"--out {out} " + ("is a file" if q == out else f"lies under the file {q}") +
                              "; expected a results folder")
    init_warp()
    return args.func(args, argv)


if __name__ == "__main__":
    sys.exit(main())
