"""``warp-sph bench``: measure the trade between speed and accuracy.

    warp-sph bench sweep --scene dam_break --param solver=wcsph,pbf --param time.cfl=0.2,0.4 --frames 25
    warp-sph bench sweep --preset quick            # tiny, for CI and tests
    warp-sph bench sweep --preset tradeoff         # the results page
    warp-sph bench scaling                         # time and memory per particle against N
    warp-sph bench splishsplash                    # side by side with SPlisHSPlasH (pysplishsplash)
    warp-sph bench report                          # benchmarks/RESULTS.md from the JSON lines

Every run appends one JSON line (``SCHEMA``) to ``<out>/<kind>.jsonl``: versions, device, host,
the resolved scene, scalar metrics and per-frame series. Tables and plots are made from those
files only (``report.py``). By default each run is a fresh subprocess, so peak memory belongs to
that run alone and a crash costs one record, not the sweep.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import itertools
import json
import math
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from . import metrics as M

SCHEMA = "warp-sph-bench/1"
RESULTS_DIR = Path(__file__).resolve().parent / "results"
KINDS = ("sweep", "scaling", "splishsplash")

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
}

#: Resolutions of the scaling benchmark: particle radius [m] for the 1 m dam-break cube
#: (about 8k, 30k, 91k and 287k fluid particles, a factor 36).
SCALING_RADII = (0.025, 0.0125, 0.008, 0.00625)  # 6,859 / 59,319 / 226,981 / 493,039 fluid particles


# --------------------------------------------------------------------------------------------
# Host description
# --------------------------------------------------------------------------------------------
def host_info() -> dict:
    """nproc, CPU model (from /proc/cpuinfo), platform and thread-related environment."""
    model = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {"nproc": os.cpu_count(), "cpu_model": model, "hostname": platform.node(),
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS")}


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).astimezone().isoformat(timespec="seconds")


# --------------------------------------------------------------------------------------------
# One warp-sph run
# --------------------------------------------------------------------------------------------
@dataclass
class RunSpec:
    """One benchmark run of warp-sph.

    frames: frames to advance after the initial state (accuracy runs); steps: substeps at the
    initial CFL step instead of frames (speed-only runs, the scaling benchmark), timed in
    ``repeats`` consecutive blocks of which the fastest counts (this VM's speed drifts by ±20 %).
    time_limit: stop after this many seconds of stepping wall time (status "time_limit").
    """

    scene: str = "dam_break"
    overrides: list[str] = field(default_factory=list)
    frames: int = 2
    steps: int = 0
    device: str | None = None
    kind: str = "sweep"
    name: str = "custom"
    params: dict = field(default_factory=dict)
    time_limit: float | None = None
    hydrostatic: bool | None = None   # None: when the scene's name starts with "hydrostatic"
    warm_up: bool = True
    repeats: int = 1


def _label(params: dict) -> str:
    return " ".join(f"{k}={v}" for k, v in params.items()) or "default"


def _fluid_volume(scene) -> float:
    v = 0.0
    for b in scene.fluid:
        if b.shape == "sphere":
            v += 4.0 / 3.0 * math.pi * b.radius ** 3
        else:
            v += float(np.prod(np.subtract(b.max, b.min)))
    return v


def _warm_up(scene, device) -> float:
    """Compile every kernel the run needs on a coarse copy of the scene (about 500 particles), so that
    no compile time lands in the timed steps. Returns the seconds it took."""
    from warp_sph.scene import scene_from_dict
    from warp_sph.run.simulation import Simulation

    t0 = time.perf_counter()
    n_est = _fluid_volume(scene) / scene.spacing ** 3
    data = scene.to_dict()
    if n_est > 500:
        data["particle_radius"] = scene.particle_radius * (n_est / 500.0) ** (1.0 / 3.0)
    try:
        warm = Simulation(scene_from_dict(data, source=scene.source), device=device)
        dt = warm.time_step(0.0)
        warm.step(dt)
        warm.statistics()
        warm.solver.step_statistics()
        import warp as wp

        wp.synchronize_device(warm.device)
    except Exception:  # a scene too coarse to sample: the timed run compiles instead
        pass
    return time.perf_counter() - t0


def _memory_metrics(sim, rss_before: int) -> dict:
    import warp as wp

    from warp_sph.neighbors import GRID_DIM

    arrays = [a for a in sim.fields.values() if isinstance(a, wp.array)]
    m = sim.model
    arrays += [getattr(m, k) for k in ("boundary_x", "boundary_volume") if isinstance(getattr(m, k, None), wp.array)]
    arrays += [sim.state.particle_x, sim.state.particle_v]
    for v in vars(sim.solver).values() if hasattr(sim.solver, "__dict__") else ():
        if isinstance(v, wp.array):
            arrays.append(v)
    a_bytes = M.array_bytes(arrays)
    g_bytes = M.hash_grid_bytes(GRID_DIM, m.fluid_count)
    if m.boundary_count:
        g_bytes += M.hash_grid_bytes(GRID_DIM, m.boundary_count)
    host = M.host_memory()
    n = max(1, m.fluid_count)
    out = {"array_bytes": a_bytes, "hash_grid_bytes_estimate": g_bytes,
           "bytes_per_particle": (a_bytes + g_bytes) / n,
           "array_bytes_per_particle": a_bytes / n,
           "peak_rss_bytes": host["peak_rss_bytes"], "rss_growth_bytes": host["rss_bytes"] - rss_before,
           "rss_growth_per_particle": (host["rss_bytes"] - rss_before) / n}
    out.update(M.device_memory(sim.device))
    return out


def _energy_scale(x: np.ndarray, mass: float, gravity, floor_point) -> float:
    """M |g| h_com: potential energy of the centre of mass above the floor [J]."""
    g = np.asarray(gravity, dtype=np.float64)
    gn = float(np.linalg.norm(g))
    if gn == 0:
        return float("nan")
    up = -g / gn
    h = float(((np.asarray(x, dtype=np.float64) - floor_point) @ up).mean())
    return len(x) * mass * gn * h


def run_warp_sph(spec: RunSpec) -> dict:
    """Run one benchmark case in this process and return its record (never raises for a failed run:
    the record says ``status`` "failed" or "unstable" and why)."""
    import warp as wp

    from warp_sph.core.errors import SimulationError
    from warp_sph.run.runner import versions
    from warp_sph.scene import load_scene

    record = {"schema": SCHEMA, "kind": spec.kind, "name": spec.name, "engine": "warp-sph",
              "label": _label(spec.params), "params": spec.params, "spec": asdict(spec),
              "date": _now(), "host": host_info(), "versions": versions(), "status": "failed"}
    try:
        scene = load_scene(spec.scene, overrides=list(spec.overrides))
        record["scene"] = scene.to_dict()
        hydro = spec.hydrostatic if spec.hydrostatic is not None else scene.name.startswith("hydrostatic")
        device = wp.get_device(spec.device)
        record["device"] = str(device)
        record["device_name"] = getattr(device, "name", str(device))
        warm_s = _warm_up(scene, device) if spec.warm_up else 0.0

        from warp_sph.run.simulation import Simulation

        rss0 = M.current_rss_bytes()
        t0 = time.perf_counter()
        sim = Simulation(scene, device=device)
        wp.synchronize_device(sim.device)
        setup_s = time.perf_counter() - t0
        m = sim.model
        record.update(fluid_particles=m.fluid_count, boundary_particles=m.boundary_count, model=m.summary(),
                      step_graph=[s.name for s in sim.graph.stages])
        wall_x = float(scene.container.min[0]) if scene.container is not None else 0.0
        floor = np.asarray(scene.container.min if scene.container is not None else (0.0, 0.0, 0.0), dtype=np.float64)
        series: dict[str, list] = {k: [] for k in (
            "time", "steps", "dt", "wall", "max_speed", "density_error_mean", "density_error_max",
            "density_error_min", "kinetic_energy", "potential_energy", "total_energy", "front",
            "volume_drift", "solver_iterations")}
        if hydro:
            series["pressure_error_mean_abs"] = []
        state = {"v0": None, "hydro": None}

        def observe(stats, wall):
            x = sim.get_field("particle_x")
            v = sim.get_field("particle_v")
            rho = sim.get_field("particle_density")
            ke = M.kinetic_energy(v, m.particle_mass)
            pe = M.potential_energy(x, m.particle_mass, m.gravity, floor)
            vol = M.compression_volume(rho, m.particle_mass, m.rest_density)
            if state["v0"] is None:
                state["v0"] = vol
                state["escale"] = _energy_scale(x, m.particle_mass, m.gravity, floor)
            de = M.density_error_stats(rho, m.rest_density)
            it = (stats.solver or {}).get("iterations", {}).get("mean") if stats is not None else None
            for k, val in (("time", sim.state.time), ("steps", stats.steps if stats else 0),
                           ("dt", stats.dt_max if stats else 0.0), ("wall", wall),
                           ("max_speed", float(np.linalg.norm(v, axis=1).max())),
                           ("density_error_mean", de["mean"]), ("density_error_max", de["max"]),
                           ("density_error_min", de["min"]), ("kinetic_energy", ke), ("potential_energy", pe),
                           ("total_energy", ke + pe), ("front", M.surge_front(x, wall_x)),
                           ("volume_drift", vol / state["v0"] - 1.0), ("solver_iterations", it)):
                series[k].append(val)
            if hydro:
                p = sim.fields.get("particle_pressure")
                if p is not None:
                    g = float(np.linalg.norm(m.gravity))
                    up = -np.asarray(m.gravity, dtype=np.float64) / g
                    h = M.hydrostatic_pressure_error(x @ up, p.numpy(), m.rest_density, g, m.spacing,
                                                     exclude_depth=2.0 * m.smoothing_length)
                    state["hydro"] = h
                    series["pressure_error_mean_abs"].append(h["mean_abs"])
                else:
                    series["pressure_error_mean_abs"].append(None)

        status = "ok"
        wall = 0.0
        cpu = 0.0  # process CPU seconds of the frames (all threads): a load-independent measure of work
        extra_series: dict[str, list] = {}
        steps = 0
        iterations = None
        if spec.steps > 0:
            # speed only: fixed substeps at the initial CFL step
            stats0 = sim.statistics()
            dt = sim.time_step(stats0.max_speed)
            blocks = []  # (wall [s], iterations per step) of each block of spec.steps substeps
            with sim.in_cell_order():  # as advance_frame steps them
                for _ in range(max(1, int(spec.repeats))):
                    its = []
                    t1 = time.perf_counter()
                    for _ in range(spec.steps):
                        sim.step(dt)
                        its.append(sim.solver.step_statistics().get("iterations"))  # host values, no sync
                    wp.synchronize_device(sim.device)
                    blocks.append((time.perf_counter() - t1, its))
            wall, iterations = min(blocks, key=lambda b: b[0])
            record["block_seconds"] = [b[0] for b in blocks]
            steps = spec.steps
            stats = sim.statistics(steps=steps, dt_min=dt, dt_max=dt)
            try:
                sim.check_health(stats)
            except SimulationError as e:
                status, record["error"] = "unstable", str(e)
            observe(stats, wall)
        else:
            observe(None, 0.0)
            for _ in range(spec.frames):
                t1 = time.perf_counter()
                c1 = time.process_time()
                try:
                    stats = sim.advance_frame()
                    wall += time.perf_counter() - t1
                    cpu += time.process_time() - c1
                    steps += stats.steps
                    sim.check_health(stats)
                    for key in ("divergence_iterations",):
                        v = (stats.solver or {}).get(key, {}).get("mean")
                        if v is not None:
                            extra_series.setdefault(key, []).append(v)
                except SimulationError as e:
                    wall += time.perf_counter() - t1
                    cpu += time.process_time() - c1
                    status, record["error"] = "unstable", str(e)
                    break
                observe(stats, wall)
                if spec.time_limit is not None and wall > spec.time_limit:
                    status = "time_limit"
                    break
        simulated = float(sim.state.time)
        if spec.steps > 0:
            simulated = steps * dt  # the fastest block's simulated time
        met = {"setup_seconds": setup_s, "warm_up_seconds": warm_s, "wall_seconds": wall,
               "simulated_seconds": simulated, "steps": steps, "frames": len(series["time"]) - 1}
        met.update(M.speed_metrics(wall, simulated, steps, m.fluid_count))
        met.update(_memory_metrics(sim, rss0))
        if spec.steps > 0 and iterations and None not in iterations:
            # iterative solvers: the iterations a step needs grow with the fluid's depth in particles
            # (Jacobi), so the cost of one particle-iteration is the flat measure of the kernels
            met["solver_iterations_mean"] = float(np.mean(iterations))
            met["ns_per_particle_iteration"] = 1e9 * wall / (m.fluid_count * float(np.sum(iterations)))
        if spec.steps <= 0:
            met["density_error_mean_avg"] = M.series_summary(series["density_error_mean"][1:])["mean"]
            met["density_error_mean_max"] = M.series_summary(series["density_error_mean"][1:])["max"]
            met["density_error_max"] = M.series_summary(series["density_error_max"][1:])["max"]
            vd = [abs(v) for v in series["volume_drift"]]
            met["volume_drift_final"] = series["volume_drift"][-1]
            met["volume_drift_max_abs"] = max(vd)
            es = M.energy_summary(series["total_energy"], state.get("escale", float("nan")))
            met["energy_change_final"] = es["change_final"]
            met["energy_rise_max"] = es["rise_max"]
            met["front_final"] = series["front"][-1]
            its = [i for i in series["solver_iterations"] if i is not None]
            if its:
                met["solver_iterations_mean"] = float(np.mean(its))
            if extra_series.get("divergence_iterations"):
                met["divergence_iterations_mean"] = float(np.mean(extra_series["divergence_iterations"]))
            if simulated > 0:
                met["cpu_seconds"] = cpu
                met["cpu_per_simulated_second"] = cpu / simulated
            if steps:
                met["dt_mean"] = simulated / steps
            if hydro and state["hydro"] is not None:
                h = state["hydro"]
                met["pressure_error_mean_abs"] = h["mean_abs"]
                met["pressure_error_max_abs"] = h["max_abs"]
                met["pressure_error_mean"] = h["mean"]
                record["pressure_profile"] = h["profile"]
        record["metrics"] = met
        record["stage_times"] = M.stage_fractions(sim.graph.timing_table())
        record["series"] = series
        record["status"] = status
    except Exception as e:  # noqa: BLE001 - a failed case is a record, not the end of the sweep
        record["error"] = f"{type(e).__name__}: {e}"
        record["traceback"] = traceback.format_exc(limit=6)
    return M.nan_to_none(record)


def _run_isolated(spec: RunSpec, timeout: float | None = None) -> dict:
    """run_warp_sph in a fresh Python process (clean peak memory; a crash costs one record)."""
    with tempfile.TemporaryDirectory(prefix="warp-sph-bench-") as tmp:
        spec_path, out_path = Path(tmp) / "spec.json", Path(tmp) / "record.json"
        spec_path.write_text(json.dumps(asdict(spec)))
        cmd = [sys.executable, "-m", "warp_sph.benchmarks.runner", "_one", str(spec_path), str(out_path)]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            proc = None
        if out_path.is_file():
            return json.loads(out_path.read_text())
        why = "timed out" if proc is None else f"exit status {proc.returncode}: {(proc.stderr or '')[-800:]}"
        return {"schema": SCHEMA, "kind": spec.kind, "name": spec.name, "engine": "warp-sph",
                "label": _label(spec.params), "params": spec.params, "spec": asdict(spec), "date": _now(),
                "host": host_info(), "status": "failed", "error": f"benchmark process {why}"}


# --------------------------------------------------------------------------------------------
# Sweeps
# --------------------------------------------------------------------------------------------
def parse_param(text: str) -> tuple[str, list[str]]:
    """``key=v1,v2,...`` -> (key, [v1, v2, ...]); values stay TOML value text for load_scene."""
    key, sep, values = text.partition("=")
    if not sep or not key.strip() or not values.strip():
        raise ValueError(f"--param {text!r}: expected KEY=V1,V2,... e.g. solver=wcsph,pbf")
    return key.strip(), [v.strip() for v in _split_values(values)]


def _split_values(text: str) -> list[str]:
    """Split on commas outside brackets, so vectors survive: ``gravity=[0,0,-9.81],[0,0,-5]``."""
    out, depth, cur = [], 0, ""
    for ch in text:
        if ch == "[":
            depth += 1
        elif ch == "]":
            depth -= 1
        if ch == "," and depth == 0:
            out.append(cur)
            cur = ""
        else:
            cur += ch
    out.append(cur)
    return [v for v in out if v.strip()]


def expand_sweep(params: dict[str, list[str]]) -> list[dict[str, str]]:
    """Cartesian product of the parameter lists, in the order given (the last key varies fastest)."""
    keys = list(params)
    return [dict(zip(keys, combo)) for combo in itertools.product(*(params[k] for k in keys))] if keys else [{}]


def _append_records(out: Path, kind: str, records: list[dict]) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{kind}.jsonl"
    with open(path, "a") as f:
        for r in records:
            f.write(json.dumps(r, allow_nan=False) + "\n")
    return path


def _print_row(r: dict, log) -> None:
    m = r.get("metrics") or {}

    def f(k, scale=1.0, fmt="{:.3g}"):
        v = m.get(k)
        return fmt.format(v * scale) if isinstance(v, (int, float)) else "-"

    log(f"  [{r['status']:>10}] {r.get('engine', '')} {r['label']}: N={r.get('fluid_particles', '-')} "
        f"wall/sim-s {f('wall_per_simulated_second')}  ns/particle-step {f('ns_per_particle_step')}  "
        f"mean density err {f('density_error_mean_avg', 100)} %  front {f('front_final')} m"
        + (f"  ({r.get('error')})" if r.get("error") else ""))


def run_specs(specs: list[RunSpec], isolate: bool = True, log=print) -> list[dict]:
    records = []
    for k, spec in enumerate(specs, 1):
        log(f"[{k}/{len(specs)}] {spec.scene} {' '.join(spec.overrides)}")
        r = _run_isolated(spec) if isolate else run_warp_sph(spec)
        records.append(r)
        _print_row(r, log)
    return records


def _stamp(records: list[dict], command: str, invocation: str) -> None:
    for r in records:
        r["command"] = command
        r["invocation"] = invocation


def _command_text(argv: list[str]) -> str:
    return "warp-sph bench " + " ".join(shlex.quote(a) for a in argv)


def cmd_sweep(args, argv: list[str], log=print) -> int:
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
        for combo in expand_sweep(sw["params"]):
            overrides = list(sw.get("set", [])) + list(args.set) + [f"{k}={v}" for k, v in combo.items()]
            specs.append(RunSpec(scene=sw["scene"], overrides=overrides, frames=frames, device=args.device,
                                 kind="sweep", name=name, params={"scene": sw["scene"], **combo},
                                 time_limit=args.time_limit))
    invocation = _now()
    records = run_specs(specs, isolate=not args.in_process, log=log)
    _stamp(records, _command_text(argv), invocation)
    out = Path(args.out) if args.out else RESULTS_DIR
    path = _append_records(out, "sweep", records)
    log(f"wrote {len(records)} records to {path}")
    return _finish(out, args, records, log)


def cmd_scaling(args, argv: list[str], log=print) -> int:
    radii = [float(r) for r in _split_values(args.radii)] if args.radii else list(SCALING_RADII)
    specs = []
    for r in radii:
        overrides = [f"particle_radius={r}", f"solver={args.solver}"] + list(args.set)
        specs.append(RunSpec(scene=args.scene, overrides=overrides, steps=args.steps, repeats=args.repeats,
                             device=args.device,
                             kind="scaling", name="scaling",
                             params={"scene": args.scene, "solver": args.solver, "particle_radius": r}))
    invocation = _now()
    records = run_specs(specs, isolate=not args.in_process, log=log)
    _stamp(records, _command_text(argv), invocation)
    out = Path(args.out) if args.out else RESULTS_DIR
    path = _append_records(out, "scaling", records)
    log(f"wrote {len(records)} records to {path}")
    return _finish(out, args, records, log)


def cmd_splishsplash(args, argv: list[str], log=print) -> int:
    from . import splishsplash as S

    invocation = _now()
    if args.adaptive:
        return _splishsplash_adaptive(args, argv, invocation, log)
    records = S.run_comparison(
        particle_radius=args.particle_radius, frames=args.frames, threads=args.threads or 1,
        solvers=[s.strip() for s in args.solvers.split(",") if s.strip()],
        dt={"wcsph": args.dt_wcsph, "pbf": args.dt_pbf, "dfsph": args.dt_dfsph},
        device=args.device, isolate=not args.in_process, skip_warp_sph=args.skip_warp_sph,
        splishsplash_gap=args.splishsplash_gap, warp_sph_overrides=args.warp_sph_set, log=log)
    _stamp(records, _command_text(argv), invocation)
    out = Path(args.out) if args.out else RESULTS_DIR
    path = _append_records(out, "splishsplash", records)
    log(f"wrote {len(records)} records to {path}")
    from .report import speed_ratios

    for q in speed_ratios(records):
        log(f"{q['solver']}: warp-sph time / SPlisHSPlasH time = {q['ratio']:.2f} "
            f"(SPlisHSPlasH on {q['threads']} threads); mean density error {100 * (q['ours_error'] or 0):.3f} % "
            f"vs {100 * (q['ref_error'] or 0):.3f} %")
    return _finish(out, args, records, log)


def parse_resolutions(text: str) -> list[tuple[float, float]]:
    """'0.025:1.0,0.0125:0.3' -> [(0.025, 1.0), (0.0125, 0.3)]: particle radius [m] and simulated seconds."""
    out = []
    for item in _split_values(text):
        r, sep, d = item.partition(":")
        try:
            out.append((float(r), float(d) if sep else 1.0))
        except ValueError:
            raise SystemExit(f"warp-sph bench splishsplash: --resolutions {text!r}: expected RADIUS:SECONDS,... "
                             "e.g. 0.025:1.0,0.0125:0.3") from None
        if out[-1][0] <= 0 or out[-1][1] <= 0:
            raise SystemExit(f"warp-sph bench splishsplash: --resolutions {text!r}: radius and seconds must be > 0")
    return out


def _splishsplash_adaptive(args, argv: list[str], invocation: str, log) -> int:
    from . import splishsplash as S

    resolutions = parse_resolutions(args.resolutions) if args.resolutions else list(S.ADAPTIVE_RESOLUTIONS)
    records = S.run_adaptive(resolutions, threads=args.threads or 2, device=args.device, isolate=not args.in_process,
                             skip_warp_sph=args.skip_warp_sph, warp_sph_overrides=args.warp_sph_set, log=log)
    _stamp(records, _command_text(argv), invocation)
    out = Path(args.out) if args.out else RESULTS_DIR
    path = _append_records(out, "splishsplash", records)
    log(f"wrote {len(records)} records to {path}")
    for q in S.adaptive_ratios(records):
        log(f"{q['fluid_particles']} particles: warp-sph dfsph / SPlisHSPlasH {q['case']} = {q['ratio']:.2f} wall"
            + (f", {q['cpu_ratio']:.2f} CPU" if q.get("cpu_ratio") else "")
            + f" (SPlisHSPlasH on {q['threads']} threads); mean density error {100 * (q['ours_error'] or 0):.3f} % "
            f"vs {100 * (q['ref_error'] or 0):.3f} %")
    return _finish(out, args, records, log)


def _finish(out: Path, args, records: list[dict], log) -> int:
    if not getattr(args, "no_report", False):
        from .report import write_report

        md = write_report(out, log=log)
        log(f"report: {md}")
    failed = [r for r in records if r["status"] == "failed"]
    for r in failed:
        log(f"failed: {r.get('engine', '')} {r['label']}: {r.get('error')}")
    return 1 if failed else 0


def cmd_surface(args, argv: list[str], log=print) -> int:
    from warp_sph.run.runner import versions

    from .surface import run_surface_bench

    radii = [float(v) for v in args.radius.split(",")]
    times = [float(v) for v in args.time.split(",")]
    if len(times) == 1:
        times = times * len(radii)
    records = run_surface_bench(radii=radii, times=times, cells=[float(v) for v in args.cell.split(",")],
                                methods=args.method.split(","), device=args.device, log=log)
    for r in records:
        r.update(host=host_info(), versions=versions(), date=_now())
    _stamp(records, _command_text(argv), _now())
    out = Path(args.out) if args.out else RESULTS_DIR
    path = _append_records(out, "surface", records)
    log(f"results: {path}")
    if not args.no_report:
        return cmd_report(argparse.Namespace(out=args.out, markdown=None), argv, log=log)
    return 0


def cmd_report(args, argv: list[str], log=print) -> int:
    from .report import write_report

    out = Path(args.out) if args.out else RESULTS_DIR
    md = write_report(out, md_path=Path(args.markdown) if args.markdown else None, log=log)
    log(f"report: {md}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="warp-sph bench", description="Benchmarks: speed, accuracy and their trade. "
                                "Results go to JSON lines in --out (default benchmarks/results) and "
                                "benchmarks/RESULTS.md.")
    sub = p.add_subparsers(dest="command")

    def common(q):
        q.add_argument("--out", help="results folder (default: benchmarks/results; RESULTS.md beside it)")
        q.add_argument("--device", default=None, help="Warp device (cpu, cuda:0; default: Warp's default)")
        q.add_argument("--in-process", action="store_true",
                       help="run cases in this process (faster start; peak memory then covers every case so far)")
        q.add_argument("--no-report", action="store_true", help="do not regenerate the Markdown report and plots")
        q.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                       help="scene override applied to every case (repeatable)")

    s = sub.add_parser("sweep", help="cartesian product of --param lists (or a --preset)")
    s.add_argument("--scene", default="dam_break", help="built-in scene or .toml path (default: dam_break)")
    s.add_argument("--param", action="append", default=[], metavar="KEY=V1,V2",
                   help="scene key path and the values to sweep, e.g. solver=wcsph,pbf (repeatable)")
    s.add_argument("--frames", type=int, default=None, help="frames to simulate per case (default 2; presets set their own)")
    s.add_argument("--preset", help=f"named sweep: {', '.join(PRESETS)}")
    s.add_argument("--name", help="name of this sweep in the report (default: custom)")
    s.add_argument("--time-limit", type=float, default=None, help="stop a case after this many seconds of stepping")
    common(s)
    s.set_defaults(func=cmd_sweep)

    c = sub.add_parser("scaling", help="time and memory per particle against particle count")
    c.add_argument("--scene", default="dam_break")
    c.add_argument("--radii", default=None, help=f"comma-separated particle radii [m] (default {','.join(map(str, SCALING_RADII))})")
    c.add_argument("--steps", type=int, default=20, help="substeps timed per resolution (default 20)")
    c.add_argument("--repeats", type=int, default=3,
                   help="time that many consecutive blocks of --steps substeps and keep the fastest (default 3)")
    c.add_argument("--solver", default="wcsph")
    common(c)
    c.set_defaults(func=cmd_scaling)

    x = sub.add_parser("splishsplash", help="the same dam break in warp-sph and SPlisHSPlasH (pysplishsplash)")
    x.add_argument("--particle-radius", type=float, default=0.025)
    x.add_argument("--frames", type=int, default=25, help="frames at 24 fps (default 25: about 1 s)")
    x.add_argument("--threads", type=int, default=None,
                   help="OMP_NUM_THREADS for SPlisHSPlasH (default 1; 2 with --adaptive)")
    x.add_argument("--adaptive", action="store_true",
                   help="each engine's own adaptive step (SPlisHSPlasH cflMethod 1) and defaults: every warp-sph "
                        "solver and SPlisHSPlasH's DFSPH, IISPH, PBF and WCSPH (stiffness 50,000) at each "
                        "--resolutions; one speed/accuracy plot per resolution")
    x.add_argument("--resolutions", default=None, metavar="R:S,...",
                   help="with --adaptive: particle radius [m] and simulated seconds per resolution "
                        "(default 0.025:1.0,0.0125:0.3: 6,859 particles for 1 s, 59,319 for 0.3 s)")
    x.add_argument("--solvers", default="wcsph,pbf,dfsph", help="wcsph,pbf (both engines), dfsph (SPlisHSPlasH only)")
    x.add_argument("--dt-wcsph", type=float, default=None, help="fixed step for WCSPH [s] (default: CFL 0.4 bound)")
    x.add_argument("--dt-pbf", type=float, default=None, help="fixed step for PBF [s] (default 0.002 * r/0.025)")
    x.add_argument("--dt-dfsph", type=float, default=None, help="fixed step for DFSPH [s] (default: as PBF)")
    x.add_argument("--skip-warp-sph", action="store_true", help="only the SPlisHSPlasH runs")
    x.add_argument("--splishsplash-gap", type=float, default=None, metavar="D",
                   help="place SPlisHSPlasH's fluid D spacings from the walls (default: on warp-sph's lattice)")
    x.add_argument("--warp-sph-set", action="append", default=[], metavar="KEY=VALUE",
                   help="scene override for warp-sph's runs only (repeatable; wcsph.* keys for its WCSPH run, "
                        "pbf.* for its PBF run), e.g. wcsph.speed_of_sound_factor=11; SPlisHSPlasH keeps the "
                        "stiffness and time step of the scene without it")
    common(x)
    x.set_defaults(func=cmd_splishsplash)

    u = sub.add_parser("surface", help="surface reconstruction time per frame on dam-break particles")
    common(u)
    u.add_argument("--radius", default="0.025", help="particle radii [m], comma separated (default 0.025: 6,859 particles)")
    u.add_argument("--time", default="0.3", help="simulated time [s] of the particles, per radius or one for all (default 0.3)")
    u.add_argument("--cell", default="0.5,0.75", help="cell sizes per particle radius (default 0.5,0.75)")
    u.add_argument("--method", default="marching_cubes,surface_nets", help="extraction methods (default both)")
    u.set_defaults(func=cmd_surface)

    r = sub.add_parser("report", help="regenerate RESULTS.md, tables and plots from the JSON lines")
    r.add_argument("--out", help="results folder (default: benchmarks/results)")
    r.add_argument("--markdown", help="report path (default: RESULTS.md beside the default results folder, else in it)")
    r.set_defaults(func=cmd_report)
    return p


def _quiet_warp() -> None:
    """Warp's start-up and module-load messages off (WARP_SPH_VERBOSE=1 keeps them). Warp 1.19 reads
    ``config.log_level``; older versions ``config.quiet``."""
    if os.environ.get("WARP_SPH_VERBOSE", ""):
        return
    import warp as wp

    wp.config.quiet = True
    if hasattr(wp, "LOG_WARNING"):
        wp.config.log_level = wp.LOG_WARNING


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "_one":  # internal: one case in a fresh process
        spec = RunSpec(**json.loads(Path(argv[1]).read_text()))
        _quiet_warp()
        record = run_warp_sph(spec)
        Path(argv[2]).write_text(json.dumps(record, allow_nan=False))
        return 0
    if argv and argv[0] == "_splishsplash":  # internal: one SPlisHSPlasH case (LD_PRELOAD set by the parent)
        from .splishsplash import driver_main

        return driver_main(argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    _quiet_warp()
    return args.func(args, argv)


if __name__ == "__main__":
    sys.exit(main())
