"""The handlers of ``warp-sph run | scenes | check | export | preview | plot | sweep | plan``: each takes the
parsed arguments (``warp_sph.cli.build_parser``), does the command and returns its exit status; errors the user
can act on are raised as WarpSphError (``warp_sph.cli.main`` prints them as one line, exit status 2).
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

from .cli_parser import ALL_CORES


def quiet_warp():
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


def cmd_run(args) -> int:
    from .run import runner

    quiet_warp()
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


def cmd_scenes(args) -> int:
    from .scene import list_scenes

    for name, desc in list_scenes():
        print(f"{name:18s} {desc}")
    return 0


def cmd_check(args) -> int:
    from .run.preflight import preflight_checks, time_step_summary
    from .run.simulation import Simulation

    wp = quiet_warp()
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


def cmd_export(args) -> int:
    from .io.reexport import export_run

    quiet_warp()
    written = export_run(Path(args.run), fmt=args.format, out=Path(args.out) if args.out else None,
                         cell_per_radius=args.surface_cell, iso=args.surface_iso, frames=args.frames,
                         overwrite=args.overwrite)
    print(f"wrote {written}")
    return 0


def cmd_preview(args) -> int:
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
    quiet_warp()
    paths = preview_run(Path(args.run), frames=frames, mode="surface" if args.surface else "particles",
                        camera=camera, size=size, out=Path(args.out) if args.out else None,
                        gif=args.gif, overwrite=args.overwrite)
    for p in paths:
        print(p)
    return 0


def cmd_sweep(args) -> int:
    import shlex

    from .sweep import build_cases, is_sweep_file, load_sweep_file, make_executor, run_sweep
    from .sweep.cases import SweepError, parse_params

    quiet_warp()
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


def cmd_plot(args) -> int:
    from .preview.plot_probes import plot_run

    for path in plot_run(Path(args.run), out=Path(args.out) if args.out else None, overwrite=args.overwrite):
        print(path)
    return 0


def cmd_plan(args) -> int:
    from .plan.report import run_command

    quiet_warp()
    return run_command(args)
