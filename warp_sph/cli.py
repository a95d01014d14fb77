"""Command line: ``warp-sph run | scenes | check | export | preview | plot | sweep | plan | bench``.

Errors the user can act on print one line (``warp-sph: error: ...``) and exit with status 2;
no traceback. Ctrl-C stops a run and keeps every frame written so far (exit status 130).
Warp is quiet (no banner, no module-load lines, no "no CUDA driver" note) unless ``--verbose``
or ``WARP_SPH_VERBOSE=1``; its warnings always print.
"""
from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

from .cli_parser import OneLineParser, UsageError as _UsageError, short_usage
from .core.errors import WarpSphError
from .core.version import __version__


class _AllCores:
    """``--workers`` given without N: one worker per core (a non-string const, which argparse does not
    convert, so that an explicit 0 stays distinguishable and is refused)."""

    def __repr__(self):
        return "ALL_CORES"


ALL_CORES = _AllCores()


def _quiet_warp():
    """Start Warp quietly (``warp_sph.core.device``) and return the module."""
    import warp as wp

    from .core.device import init_warp

    init_warp()
    return wp


def _load_scene(name: str, overrides: list[str]):
    """load_scene; an error about a key that --set gave says so (the value is not in the file)."""
    from .core.errors import SceneError
    from .scene import load_scene
    from .scene.load import with_override

    try:
        return load_scene(name, overrides=overrides)
    except SceneError as exc:
        raise SceneError(with_override(str(exc), overrides)) from None


def _cmd_run(args) -> int:
    from .run import runner

    _quiet_warp()
    if args.resume:
        ignored = [flag for flag, given in ((f"the scene {args.scene!r}", args.scene is not None), ("--out", args.out),
                                            ("--set", args.set), ("--overwrite", args.overwrite)) if given]
        if ignored:
            from .core.errors import WarpSphError

            raise WarpSphError(f"--resume continues the run in {args.resume} with its own scene and folder; "
                               f"drop {', '.join(ignored)}")
        info = runner.run(None, device=args.device, frames=args.frames, progress=not args.no_progress,
                          resume=Path(args.resume))
    else:
        scene = _load_scene(args.scene or "dam_break", args.set)
        info = runner.run(scene, out=Path(args.out) if args.out else None, device=args.device,
                          frames=args.frames, overwrite=args.overwrite, progress=not args.no_progress)
    print_summary(info)
    return 0


def print_summary(info: dict) -> None:
    """Print the end-of-run summary of ``warp-sph run`` (frames, steps, density error, export time,
    output) from the dict ``runner.run`` returns."""
    frames = info["frames"]
    steps = sum(f["steps"] for f in frames)
    err = max((f["density_error_max"] for f in frames), default=0.0)
    mean = sum(f["density_error_mean"] for f in frames) / max(1, len(frames))
    out = Path(info["out"])
    usd = sorted(out.glob("*.usdc"))
    fluid = f"{info['fluid_particles']} fluid"
    flow = frames[-1].get("flow") if frames else None
    if flow:  # emitters / sinks: the count changes; say where it ended
        fluid = f"{info['fluid_particles']} -> {flow['particles']} fluid ({flow['emitted']} emitted, {flow['removed']} removed)"
    print(f"{info['status']}: {len(frames)} frames, {steps} steps, {info['simulated_time']:.3f} s simulated "
          f"in {info['wall_time']:.1f} s wall ({fluid}, {info['boundary_particles']} boundary particles)")
    print(f"density error: mean {100 * mean:.3f} %, max {100 * err:.3f} % (largest of any frame); "
          f"{info['sim_time_per_step_ms']:.2f} ms per simulation step")
    ww = frames[-1].get("whitewater") if frames else None
    if ww:  # [whitewater]: the last frame's particles (docs/whitewater.md)
        print(f"whitewater: {ww['spray']} spray, {ww['foam']} foam, {ww['bubbles']} bubbles at the last frame; "
              f"{ww['generated']} generated, {ww['dropped']} dropped (max_particles)")
    if info.get("threaded_export", True):
        print(f"export: {info['export_time']:.1f} s on a background thread while simulating; the simulation "
              f"waited {info.get('export_wait_time', 0.0):.1f} s of it"
              + (f", and it ended {info['export_tail_time']:.1f} s after the last step" if "export_tail_time" in info
                 else ""))
    else:
        print(f"export: {info['export_time']:.1f} s")
    print(f"output: {out}" + (f"  (Blender: File > Import > USD, {usd[0].name})" if usd else ""))
    if "plan" in info:  # made from warp-sph plan --apply: its prediction beside what happened
        from .plan.compare import summary_line

        print(summary_line(info["plan"]))


def _cmd_scenes(args) -> int:
    from .scene import list_scenes

    for name, desc in list_scenes():
        print(f"{name:18s} {desc}")
    return 0


def _cmd_check(args) -> int:
    from .run.preflight import preflight_checks, time_step_summary
    from .run.simulation import Simulation

    wp = _quiet_warp()
    scene = _load_scene(args.scene, args.set)
    sim = Simulation(scene, device=wp.get_device("cpu"))
    preflight_checks(scene, sim)
    s = sim.summary()
    print(f"{scene.name}: ok")
    print(f"  {s['fluid_count']} fluid particles, {s['boundary_count']} boundary particles")
    print(f"  solver {scene.solver}, boundary {scene.boundary}, kernel {s['smoothing_kernel']} "
          f"(h = {s['smoothing_length']:.4g} m, support {s['support_radius']:.4g} m), mass {s['particle_mass']:.4g} kg")
    extra = ", ".join(f"{k.replace('_', ' ')} {v:.4g}" for k, v in s["solver"].items()
                      if isinstance(v, float))
    print(f"  speed of sound {s['speed_of_sound']:.3g} m/s" + (f", {extra}" if extra else ""))
    if "forces" in s:
        print("  forces: " + ", ".join(f"{f['method']} ({f['set_by']})" for f in s["forces"]))
    print(f"  step graph: {' -> '.join(sim.graph.names())}")
    if "bodies" in s:
        b = s["bodies"]
        print(f"  {b['count']} rigid bodies ({', '.join(f'{n} {m:.3g} kg' for n, m in zip(b['names'], b['masses']))}; "
              f"{b['boundary_particles']} of the boundary particles), Newton contacts w = {b['contact_frequency']:.4g} rad/s")
    for line in time_step_summary(scene, sim):
        print(f"  {line}")
    return 0


def _cmd_export(args) -> int:
    from .io.reexport import export_run

    _quiet_warp()
    written = export_run(Path(args.run), fmt=args.format, out=Path(args.out) if args.out else None,
                         cell_per_radius=args.surface_cell, iso=args.surface_iso, frames=args.frames,
                         overwrite=args.overwrite)
    print(f"wrote {written}")
    return 0


def _cmd_preview(args) -> int:
    from .preview.render_run import Camera, preview_run

    from .core.errors import WarpSphError

    frames = None
    if args.frame is not None:
        frames = [args.frame]
    elif args.frames:
        a, sep, b = args.frames.partition(":")
        try:
            frames = list(range(int(a), int(b if sep else a) + 1))
        except ValueError:
            raise WarpSphError(f"--frames {args.frames!r}: expected A:B (two frame numbers) or A") from None
        if not frames:
            raise WarpSphError(f"--frames {args.frames!r}: the first frame is after the last")
    camera = None
    if args.camera:
        try:
            vals = [float(v) for v in args.camera.split(",")]
        except ValueError:
            vals = []
        if len(vals) != 6 or not all(math.isfinite(v) for v in vals):
            raise WarpSphError(f"--camera {args.camera!r}: expected px,py,pz,tx,ty,tz (six numbers [m])")
        if vals[:3] == vals[3:]:
            raise WarpSphError(f"--camera {args.camera!r}: the position and the target are the same point; the "
                               "camera looks from px,py,pz towards a different tx,ty,tz [m]")
        camera = Camera(position=tuple(vals[:3]), target=tuple(vals[3:]))
    w, sep, h = args.size.lower().partition("x")
    try:
        size = (int(w), int(h))
    except ValueError:
        size = (0, 0)
    if not sep or size[0] < 1 or size[1] < 1 or max(size) > 16384:
        raise WarpSphError(f"--size {args.size!r}: expected WxH, two whole numbers of pixels from 1 to 16384, "
                           "e.g. 640x360")
    _quiet_warp()
    paths = preview_run(Path(args.run), frames=frames, mode="surface" if args.surface else "particles",
                        camera=camera, size=size, out=Path(args.out) if args.out else None,
                        gif=args.gif, overwrite=args.overwrite)
    for p in paths:
        print(p)
    return 0


def _cmd_sweep(args) -> int:
    import shlex

    from .sweep import build_cases, is_sweep_file, load_sweep_file, make_executor, run_sweep
    from .sweep.cases import SweepError, parse_params

    _quiet_warp()
    if args.frames is not None and args.frames < 1:
        raise SweepError(f"--frames {args.frames}: expected >= 1")
    if args.device and args.scheduler is None:  # the workers of an external cluster may have other devices
        from .core.device import resolve_device

        resolve_device(args.device)
    if is_sweep_file(args.scene):
        if args.param:
            raise SweepError(f"{args.scene} is a sweep file: put the --param lists in its [sweep] param table")
        cases = load_sweep_file(args.scene, frames=args.frames, fixed=args.set)
    else:
        cases = build_cases(args.scene, parse_params(args.param, args.set), fixed=args.set, frames=args.frames)
    out = Path(args.out) if args.out else Path("runs") / f"sweep-{Path(args.scene).stem}"
    workers = args.workers
    if workers is ALL_CORES:  # --workers without N
        workers = 0
    elif workers is not None and workers < 1:
        raise SweepError(f"--workers {workers}: expected a number of worker processes >= 1 (--workers alone "
                         "starts one per core)")
    executor = make_executor(workers=workers, scheduler=args.scheduler)
    command = "warp-sph " + " ".join(shlex.quote(a) for a in (args.argv or []))
    try:
        summary = run_sweep(cases, out, executor, device=args.device, progress=not args.no_progress, command=command)
    except KeyboardInterrupt:
        print(f"\nwarp-sph: interrupted; the cases finished so far are kept in {out}; run the same command "
              "again to resume", file=sys.stderr)
        return 130
    counts = summary.counts()
    print(f"{len(summary.rows)} cases: " + ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
          + f"; summary {out / 'sweep.jsonl'}, results page {out / 'sweep.md'}")
    return 0 if set(counts) <= {"completed"} else 1


def _cmd_plot(args) -> int:
    from .preview.plot_probes import plot_run

    for path in plot_run(Path(args.run), out=Path(args.out) if args.out else None, overwrite=args.overwrite):
        print(path)
    return 0


def _cmd_plan(args) -> int:
    from .plan.report import run_command

    _quiet_warp()
    return run_command(args)


def _cmd_bench(args) -> int:
    from .benchmarks.runner import main as bench_main

    _quiet_warp()
    return bench_main(list(args.bench_args))


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="warp-sph", description="SPH fluid simulation in NVIDIA Warp, exported to USD for Blender.",
                      epilog="Each command has its own --help (warp-sph run --help). --verbose (before or "
                             "after the command) shows Warp's own start-up and kernel-loading messages.")
    p.add_argument("--verbose", action="store_true", help="show Warp's start-up and module-load messages")
    p.add_argument("--version", action="version", version=f"warp-sph {__version__}",
                   help="print warp-sph's version and exit")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--verbose", action="store_true", default=argparse.SUPPRESS,
                        help="show Warp's start-up and module-load messages")
    sub = p.add_subparsers(dest="command")

    r = sub.add_parser("run", parents=[common], help="simulate a scene (default: dam_break) into a run folder")
    r.add_argument("scene", nargs="?", default=None, help="built-in scene name or path to a .toml file (default: dam_break)")
    r.add_argument("--out", help="output folder (default: runs/<scene>, or runs/<scene>-N if that holds a run)")
    r.add_argument("--frames", type=int, help="frames to write including the initial one (default: duration * fps + 1)")
    r.add_argument("--device", default=None, help="Warp device: cpu or cuda:0 (default: Warp's default device)")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value by key path, e.g. particle_radius=0.02 or material.xsph=0.05 (repeatable)")
    r.add_argument("--overwrite", action="store_true", help="replace a previous run in --out")
    r.add_argument("--resume", metavar="DIR", help="continue the run in DIR from its latest checkpoint "
                   "(its scene and folder; --frames may extend it); on the CPU the result equals an uninterrupted run")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    r.set_defaults(func=_cmd_run)

    s = sub.add_parser("scenes", parents=[common], help="list the built-in scenes")
    s.set_defaults(func=_cmd_scenes)

    c = sub.add_parser("check", parents=[common], help="validate a scene (and sample it) without running")
    c.add_argument("scene", nargs="?", default="dam_break", help="built-in scene name or path to a .toml file (default: dam_break)")
    c.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value by key path, as for run (repeatable)")
    c.set_defaults(func=_cmd_check)

    e = sub.add_parser("export", parents=[common], help="re-export a run's recorded frames (surface, USD or mesh sequence) without simulating")
    e.add_argument("run", help="run folder")
    e.add_argument("--format", default="usd", choices=["usd", "obj", "ply", "vtk"],
                   help="usd: particles, surface and static meshes in one .usdc; obj, ply, vtk: one surface file per frame (default: usd)")
    e.add_argument("--out", help="output file (usd) or folder (meshes); default inside the run folder under export/")
    e.add_argument("--surface-cell", type=float, default=None, help="surface grid cell per particle radius (default: the run's)")
    e.add_argument("--surface-iso", type=float, default=None, help="iso level of the colour field (default: the run's)")
    e.add_argument("--frames", default=None, help="A:B frame range (default: all recorded)")
    e.add_argument("--overwrite", action="store_true", help="replace existing export files")
    e.set_defaults(func=_cmd_export)

    v = sub.add_parser("preview", parents=[common], help="render frames of a run to PNG (and GIF), headless")
    v.add_argument("run", help="run folder")
    g = v.add_mutually_exclusive_group()
    g.add_argument("--frame", type=int, help="one frame (default: the last)")
    g.add_argument("--frames", help="A:B frame range")
    m = v.add_mutually_exclusive_group()
    m.add_argument("--particles", action="store_true", help="render particles as spheres (default)")
    m.add_argument("--surface", action="store_true", help="render the reconstructed surface")
    v.add_argument("--camera", help="px,py,pz,tx,ty,tz camera position and target [m] (default: automatic)")
    v.add_argument("--size", default="640x360", help="WxH pixels (default 640x360)")
    v.add_argument("--gif", action="store_true", help="also write an animated GIF of the frames")
    v.add_argument("--out", help="output folder (default: RUN/preview)")
    v.add_argument("--overwrite", action="store_true", help="replace pictures of the same names in --out "
                   "(those in RUN/preview are always replaced)")
    v.set_defaults(func=_cmd_preview)

    w = sub.add_parser("sweep", help="run the product of --param values (or a TOML sweep file), in this process "
                       "or on Dask", description="Each case is an ordinary run folder DIR/<case>; DIR/sweep.jsonl "
                       "and the results page DIR/sweep.md are written as cases finish. A re-run skips complete "
                       "cases; Ctrl-C cancels cleanly (exit status 130).")
    w.add_argument("scene", help="built-in scene name, scene .toml path, or a sweep .toml file ([sweep] / [[case]])")
    w.add_argument("--param", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="scene key path and the values to sweep (TOML value text), e.g. solver=wcsph,pbf (repeatable; "
                        "the cases are the product)")
    w.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override applied to every case (repeatable)")
    w.add_argument("--frames", type=int, default=None, help="frames per case including the initial one "
                   "(default: the scene's duration * fps + 1)")
    w.add_argument("--out", help="sweep folder (default: runs/sweep-<scene>); re-running into it resumes")
    g = w.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, nargs="?", const=ALL_CORES, default=None, metavar="N",
                   help="run on a Dask LocalCluster of N >= 1 worker processes (--workers alone: one per core), one "
                        "thread each; needs the distributed extra (pip install -e '.[distributed]')")
    g.add_argument("--scheduler", metavar="tcp://HOST:8786", help="submit to an existing Dask cluster "
                   "(workers need warp-sph installed and DIR on a shared file system)")
    w.add_argument("--device", default=None, help="Warp device of every case: cpu or cuda:0 (default: Warp's default)")
    w.add_argument("--no-progress", action="store_true", help="no progress bar")
    w.set_defaults(func=_cmd_sweep)

    pl = sub.add_parser("plot", parents=[common], help="plot a run's probes ([[probes]]) to PNG (needs the plots extra)")
    pl.add_argument("run", help="run folder")
    pl.add_argument("--out", help="output folder (default: RUN/plots)")
    pl.add_argument("--overwrite", action="store_true", help="replace plots of the same names in --out "
                    "(those in RUN/plots are always replaced)")
    pl.set_defaults(func=_cmd_plot)

    n = sub.add_parser("plan", parents=[common], help="the settings that fit a wall-time budget or reach a target "
                       "error, predicted from calibration runs of the scene (docs/plan.md)")
    n.add_argument("scene", help="built-in scene name or path to a .toml file")
    n.add_argument("--budget", help="wall time on this machine: 90s, 10m, 1.5h")
    n.add_argument("--target-error", help="mean density error: 0.5%% or 0.005")
    n.add_argument("--apply", metavar="OUT.toml", help="write the chosen settings and the prediction as a scene file "
                   "(default: print the --set flags)")
    n.add_argument("--force", action="store_true", help="let --apply and --plot replace an existing file")
    n.add_argument("--plot", metavar="PNG", help="the Pareto plot's path (default: beside the calibration cache)")
    n.add_argument("--solvers", help="comma-separated candidate solvers (default: every solver)")
    n.add_argument("--device", default=None, help="Warp device: cpu or cuda:0 (default: Warp's default)")
    n.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="scene override (repeatable)")
    n.add_argument("--cache", metavar="DIR", help="calibration cache (default: ~/.cache/warp-sph/plan)")
    n.add_argument("--refresh", action="store_true", help="calibrate again even when the cache holds it")
    n.add_argument("--no-progress", action="store_true", help="no progress bar")
    n.set_defaults(func=_cmd_plan)

    b = sub.add_parser("bench", help="benchmarks: speed and accuracy (see warp-sph bench --help)", add_help=False)
    b.add_argument("bench_args", nargs=argparse.REMAINDER)  # main() passes everything after "bench" through
    b.set_defaults(func=_cmd_bench)
    return p


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Warnings from warp-sph print as one line, without the source location."""
    stream = file or sys.stderr
    if str(getattr(category, "__module__", "")).startswith("warp_sph") or "warp_sph" in str(filename):
        stream.write(f"warp-sph: warning: {message}\n")
    else:
        stream.write(warnings.formatwarning(message, category, filename, lineno, line))


def main(argv=None) -> int:
    from .core.errors import WarpSphError

    warnings.showwarning = _show_warning
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    try:
        if "bench" in argv:  # everything after "bench" is the benchmark runner's (its own --help included)
            i = argv.index("bench")
            head = argv[:i]
            if all(a == "--verbose" for a in head):
                args = parser.parse_args(head + ["bench"])
                args.bench_args = argv[i + 1:]
            else:
                args = parser.parse_args(argv)
        else:
            args = parser.parse_args(argv)
    except _UsageError as e:
        print(f"warp-sph: error: {e}", file=sys.stderr)
        return 2
    args.argv = argv
    if not getattr(args, "command", None):  # a usage error: the short usage and the commands, not the whole help
        print(short_usage(parser), file=sys.stderr)
        return 2
    if getattr(args, "verbose", False):
        from .core.device import set_verbose

        set_verbose(True)
    try:
        return args.func(args)
    except WarpSphError as e:
        print(f"warp-sph: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        hint = getattr(e, "resume_hint", None)  # a run: where --resume restarts (warp_sph.run.runner)
        print("\nwarp-sph: interrupted; every frame written so far is kept" + (f"; {hint}" if hint else ""),
              file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
