"""One warp-sph benchmark run (``RunSpec`` -> record), in this process or a fresh one, and a list of
runs on a sweep executor (``warp_sph.sweep``: serial, or a Dask LocalCluster / cluster).

By default each run is a fresh subprocess, so peak memory belongs to that run alone and a crash
costs one record, not the benchmark. On Dask, each worker starts that subprocess (it inherits the
worker's ``WARP_SPH_CPU_THREADS`` pin); timings of runs that share the cores are not those of a
quiet machine: use the serial executor for figures you compare.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from . import metrics as M
from .peak_memory import MemoryWindow
from .records import SCHEMA, host_info, label, now, print_row


@dataclass
class RunSpec:
    """One benchmark run of warp-sph.

    frames: frames to advance after the initial state (accuracy runs); steps: substeps at the
    initial CFL step instead of frames (speed-only runs, the scaling benchmark), timed in
    ``repeats`` consecutive blocks of which the fastest counts (this VM's speed drifts by ±20 %).
    time_limit: stop after this many seconds of stepping wall time (status "time_limit").
    traffic_steps: with ``steps``, that many more steps after the timed blocks, their kernel launches' array bytes
    counted (``traffic.step_traffic``: a model of the bytes a step moves, not a measurement).
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
    traffic_steps: int = 0  # steps run after the timed ones counting their launches' array bytes (traffic.py)


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


def _memory_metrics(sim, rss_before: int, window: MemoryWindow | None = None) -> dict:
    import warp as wp

    from warp_sph.neighbors import GRID_DIM
    from warp_sph.run.working_set import read_bytes

    # the case's own peak against the RSS right before it was built (peak_memory.py), read first
    peak = window.close(sim.model.fluid_count) if window is not None else {}
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
           "rss_growth_per_particle": (host["rss_bytes"] - rss_before) / n,
           "read_bytes": read_bytes(sim)}  # what one pass over the step's arrays reads (run.json read_bytes)
    out.update(peak)
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
              "label": label(spec.params), "params": spec.params, "spec": asdict(spec),
              "date": now(), "host": host_info(), "versions": versions(), "status": "failed"}
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
        # the case's peak: VmHWM reset here, after the warm-up loaded the kernels (peak_memory.py)
        window = MemoryWindow().open()
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
            "time", "steps", "particles", "dt", "wall", "cpu", "frame_stage_cpu", "max_speed", "density_error_mean", "density_error_max",
            "density_error_min", "kinetic_energy", "potential_energy", "total_energy", "front",
            "volume_drift", "solver_iterations", "solver_iterations_max")}
        if hydro:
            series["pressure_error_mean_abs"] = []
        state = {"v0": None, "hydro": None}

        def observe(stats, wall, cpu=None):
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
            its = (stats.solver or {}).get("iterations", {}) if stats is not None else {}
            for k, val in (("time", sim.state.time), ("steps", stats.steps if stats else 0),
                           ("particles", m.fluid_count),  # emitters and sinks change it (docs/emitters.md)
                           ("dt", stats.dt_max if stats else 0.0), ("wall", wall), ("cpu", cpu),
                           # per-frame stages outside the substeps (emitters, sinks): their CPU seconds so far
                           ("frame_stage_cpu", sum(t.cpu_seconds for t in sim.graph.frame_timings.values())),
                           ("max_speed", float(np.linalg.norm(v, axis=1).max())),
                           ("density_error_mean", de["mean"]), ("density_error_max", de["max"]),
                           ("density_error_min", de["min"]), ("kinetic_energy", ke), ("potential_energy", pe),
                           ("total_energy", ke + pe), ("front", M.surge_front(x, wall_x)),
                           ("volume_drift", vol / state["v0"] - 1.0), ("solver_iterations", its.get("mean")),
                           ("solver_iterations_max", its.get("max"))):
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
        traffic: dict = {}
        wall = 0.0
        cpu = 0.0  # process CPU seconds of the frames (all threads): a load-independent measure of work
        extra_series: dict[str, list] = {}
        steps = 0
        iterations = None
        if spec.steps > 0:
            # speed only: fixed substeps at the initial CFL step
            stats0 = sim.statistics()
            dt = sim.time_step(stats0.max_speed)
            # (wall [s], iterations per step, process CPU [s], divergence iterations per step) of each block
            blocks = []
            with sim.in_cell_order():  # as advance_frame steps them
                for _ in range(max(1, int(spec.repeats))):
                    its, div_its = [], []
                    t1 = time.perf_counter()
                    c1 = time.process_time()
                    for _ in range(spec.steps):
                        sim.step(dt)
                        st = sim.solver.step_statistics()  # host values, no sync
                        its.append(st.get("iterations"))
                        div_its.append(st.get("divergence_iterations"))
                    wp.synchronize_device(sim.device)
                    blocks.append((time.perf_counter() - t1, its, time.process_time() - c1, div_its))
            wall, iterations, cpu, div_iterations = min(blocks, key=lambda b: b[0])
            record["block_seconds"] = [b[0] for b in blocks]
            record["block_cpu_seconds"] = [b[2] for b in blocks]
            steps = spec.steps
            stats = sim.statistics(steps=steps, dt_min=dt, dt_max=dt)
            try:
                sim.check_health(stats)
            except SimulationError as e:
                status, record["error"] = "unstable", str(e)
            observe(stats, wall)
            if spec.traffic_steps > 0:  # after the timed blocks and the statistics: a model, not timed
                from .traffic import step_traffic

                traffic = step_traffic(sim, dt, spec.traffic_steps)
        else:
            observe(None, 0.0, 0.0)
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
                observe(stats, wall, cpu)  # cumulative seconds of the frames so far
                if spec.time_limit is not None and wall > spec.time_limit:
                    status = "time_limit"
                    break
        simulated = float(sim.state.time)
        if spec.steps > 0:
            simulated = steps * dt  # the fastest block's simulated time
        met = {"setup_seconds": setup_s, "warm_up_seconds": warm_s, "wall_seconds": wall,
               "simulated_seconds": simulated, "steps": steps, "frames": len(series["time"]) - 1}
        met.update(M.speed_metrics(wall, simulated, steps, m.fluid_count))
        met.update(_memory_metrics(sim, rss0, window))
        if traffic:
            met.update(traffic)
            met["passes_per_step"] = traffic["launch_bytes_per_step"] / met["read_bytes"] if met["read_bytes"] else None
        if spec.steps > 0 and iterations and None not in iterations:
            # iterative solvers: the iterations a step needs grow with the fluid's depth in particles
            # (Jacobi), so the cost of one particle-iteration is the flat measure of the kernels
            met["solver_iterations_mean"] = float(np.mean(iterations))
            met["ns_per_particle_iteration"] = 1e9 * wall / (m.fluid_count * float(np.sum(iterations)))
        if spec.steps > 0:
            # process CPU time of the fastest block (every thread): the load-independent measure of work
            met["cpu_seconds"] = cpu
            met["cpu_ns_per_particle_step"] = 1e9 * cpu / (steps * m.fluid_count) if steps and m.fluid_count else None
            if div_iterations and None not in div_iterations:
                met["divergence_iterations_mean"] = float(np.mean(div_iterations))
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
                met["solver_iterations_max"] = float(max(i for i in series["solver_iterations_max"] if i is not None))
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
        if sim.graph.frame_timings:  # per-frame work outside the substeps: emitters and sinks
            record["frame_stage_times"] = sim.graph.frame_timing_table()
        record["series"] = series
        record["status"] = status
    except Exception as e:  # noqa: BLE001 - a failed case is a record, not the end of the sweep
        record["error"] = f"{type(e).__name__}: {e}"
        record["traceback"] = traceback.format_exc(limit=6)
    return M.nan_to_none(record)


def run_isolated(spec: RunSpec, timeout: float | None = None) -> dict:
    """run_warp_sph in a fresh Python process (clean peak memory; a crash costs one record)."""
    with tempfile.TemporaryDirectory(prefix="warp-sph-bench-") as tmp:
        spec_path, out_path = Path(tmp) / "spec.json", Path(tmp) / "record.json"
        spec_path.write_text(json.dumps(asdict(spec)))
        cmd = [sys.executable, "-m", "warp_sph.benchmarks.cases", str(spec_path), str(out_path)]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            proc = None
        if out_path.is_file():
            return json.loads(out_path.read_text())
        why = "timed out" if proc is None else f"exit status {proc.returncode}: {(proc.stderr or '')[-800:]}"
        return {"schema": SCHEMA, "kind": spec.kind, "name": spec.name, "engine": "warp-sph",
                "label": label(spec.params), "params": spec.params, "spec": asdict(spec), "date": now(),
                "host": host_info(), "status": "failed", "error": f"benchmark process {why}"}


def run_task(task: dict) -> dict:
    """Executor task: ``{"spec": asdict(RunSpec), "isolate": bool}`` -> the run's record."""
    spec = RunSpec(**task["spec"])
    if task.get("isolate", True):
        return run_isolated(spec, timeout=task.get("timeout"))
    from warp_sph.core.device import init_warp

    init_warp()
    return run_warp_sph(spec)


def _failed(spec: RunSpec, error: str) -> dict:
    return {"schema": SCHEMA, "kind": spec.kind, "name": spec.name, "engine": "warp-sph", "label": label(spec.params),
            "params": spec.params, "spec": asdict(spec), "date": now(), "host": host_info(), "status": "failed",
            "error": error}


def run_specs(specs: list[RunSpec], isolate: bool = True, log=print, executor=None, progress: bool = False) -> list[dict]:
    """Run every spec on ``executor`` (default: serial, in this process's order) and return the
    records in the order of ``specs``, printing a row for each as it finishes."""
    from warp_sph.run.progress import Progress
    from warp_sph.sweep.executors import SerialExecutor

    executor = executor or SerialExecutor(log=log)
    records: list[dict | None] = [None] * len(specs)
    tasks = [(f"{k:04d} {label(s.params)}", {"spec": asdict(s), "isolate": isolate}) for k, s in enumerate(specs)]
    bar = Progress(len(specs), enabled=progress, unit="runs")
    done = 0
    if isinstance(executor, SerialExecutor) and len(specs) > 1:
        log(f"{len(specs)} runs, one after the other" + (", each in a fresh process" if isolate else ""))
    with executor:
        if not isinstance(executor, SerialExecutor):
            log(f"{len(specs)} run(s) on {executor.describe()}")
        for o in executor.map(run_task, tasks):
            k = int(o.key.split(" ", 1)[0])
            r = o.result if o.result is not None else _failed(specs[k], f"benchmark task: {o.error}")
            records[k] = r
            done += 1
            log(f"[{done}/{len(specs)}] {specs[k].scene} {' '.join(specs[k].overrides)}")
            print_row(r, log)
            bar.update(done, r.get("label", ""))
    bar.close()
    return [r for r in records if r is not None]


if __name__ == "__main__":  # one run in a fresh process: python -m warp_sph.benchmarks.cases SPEC.json RECORD.json
    from warp_sph.core.device import init_warp

    init_warp()
    _record = run_warp_sph(RunSpec(**json.loads(Path(sys.argv[1]).read_text())))
    Path(sys.argv[2]).write_text(json.dumps(_record, allow_nan=False))
