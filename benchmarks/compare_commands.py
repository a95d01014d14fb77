"""``warp-sph bench splishsplash`` and ``bench surface``: warp-sph beside another tool in the same run
(SPlisHSPlasH, splashsurf). The other subcommands and the helpers these share are ``commands.py``."""
from __future__ import annotations

from .arguments import check_names, parse_resolutions
from .commands import finish_report, save_records
from .records import host_info, now


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
    out = save_records("splishsplash", records, args, argv, invocation, log)
    for q in speed_ratios(records):
        log(f"{q['solver']}: warp-sph time / SPlisHSPlasH time = {q['ratio']:.2f} wall"
            + (f", {q['cpu_ratio']:.2f} CPU" if q.get("cpu_ratio") else "") + " "
            f"(SPlisHSPlasH on {q['threads']} threads); mean density error {100 * (q['ours_error'] or 0):.3f} % "
            f"vs {100 * (q['ref_error'] or 0):.3f} %")
    return finish_report(out, args, records, log)


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
    out = save_records("splishsplash", records, args, argv, invocation, log)
    for q in S.adaptive_ratios(records):
        log(f"{q['fluid_particles']} particles: warp-sph dfsph / SPlisHSPlasH {q['case']} = {q['ratio']:.2f} wall"
            + (f", {q['cpu_ratio']:.2f} CPU" if q.get("cpu_ratio") else "")
            + f" (SPlisHSPlasH on {q['threads']} threads); mean density error {100 * (q['ours_error'] or 0):.3f} % "
            f"vs {100 * (q['ref_error'] or 0):.3f} %")
    return finish_report(out, args, records, log)


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
    out = save_records("surface", records, args, argv, now(), log)
    return finish_report(out, args, records, log)
