"""Command line: ``warp-sph run | scenes | check | export | preview | plot | sweep | plan | bench``.

Errors the user can act on print one line (``warp-sph: error: ...``) and exit with status 2;
no traceback. Ctrl-C stops a run and keeps every frame written so far (exit status 130).
Warp is quiet (no banner, no module-load lines, no "no CUDA driver" note) unless ``--verbose``
or ``WARP_SPH_VERBOSE=1``; its warnings always print.
"""
from __future__ import annotations

import argparse
import sys
import warnings

from . import cli_commands as cc
from .cli_parser import ALL_CORES, OneLineParser, UsageError as _UsageError, short_usage
from .core.errors import WarpSphError
from .core.version import __version__


def _cmd_bench(args) -> int:
    from .benchmarks.runner import main as bench_main

    cc.quiet_warp()
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
    r.set_defaults(func=cc.cmd_run)

    s = sub.add_parser("scenes", parents=[common], help="list the built-in scenes")
    s.set_defaults(func=cc.cmd_scenes)

    c = sub.add_parser("check", parents=[common], help="validate a scene (and sample it) without running")
    c.add_argument("scene", nargs="?", default="dam_break", help="built-in scene name or path to a .toml file (default: dam_break)")
    c.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value by key path, as for run (repeatable)")
    c.set_defaults(func=cc.cmd_check)

    e = sub.add_parser("export", parents=[common], help="re-export a run's recorded frames (surface, USD or mesh sequence) without simulating")
    e.add_argument("run", help="run folder")
    e.add_argument("--format", default="usd", choices=["usd", "obj", "ply", "vtk"],
                   help="usd: particles, surface and static meshes in one .usdc; obj, ply, vtk: one surface file per frame (default: usd)")
    e.add_argument("--out", help="output file (usd) or folder (meshes); default inside the run folder under export/")
    e.add_argument("--surface-cell", type=float, default=None, help="surface grid cell per particle radius (default: the run's)")
    e.add_argument("--surface-iso", type=float, default=None, help="iso level of the colour field (default: the run's)")
    e.add_argument("--frames", default=None, help="A:B frame range (default: all recorded)")
    e.add_argument("--overwrite", action="store_true", help="replace existing export files")
    e.set_defaults(func=cc.cmd_export)

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
    v.set_defaults(func=cc.cmd_preview)

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
    w.set_defaults(func=cc.cmd_sweep)

    pl = sub.add_parser("plot", parents=[common], help="plot a run's probes ([[probes]]) to PNG (needs the plots extra)")
    pl.add_argument("run", help="run folder")
    pl.add_argument("--out", help="output folder (default: RUN/plots)")
    pl.add_argument("--overwrite", action="store_true", help="replace plots of the same names in --out "
                    "(those in RUN/plots are always replaced)")
    pl.set_defaults(func=cc.cmd_plot)

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
    n.set_defaults(func=cc.cmd_plan)

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

