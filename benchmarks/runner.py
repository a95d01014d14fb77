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
``report.py``. This module is the parser; the subcommands are ``commands.py`` (``cmd_<name>``; those
beside another tool ``compare_commands.py``), the argument types and name checks ``arguments.py``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .arguments import nonnegative_floats, positive_float, positive_floats, positive_int, positive_ints, whitewater_rates
from .commands import (PRESETS, SCALING_RADII, cmd_bodies, cmd_emission, cmd_executors, cmd_extremes, cmd_forces,
                       cmd_matrix, cmd_plan, cmd_report, cmd_scaling, cmd_sweep, cmd_validation, cmd_whitewater)
from .compare_commands import cmd_splishsplash, cmd_surface


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
