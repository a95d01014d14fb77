"""Where the wall time of a DFSPH step goes on the CPU: launches, Python time, the idle worker thread.

    python -m benchmarks.dfsph_step_profile                     # dam break r = 0.025 m, from 0.3 s, 3 frames
    python -m benchmarks.dfsph_step_profile --radius 0.025 --start 0.3 --frames 3 --threads 2

Runs the dam break (solver dfsph, its adaptive step, no output) to ``--start`` seconds (splashing)
twice, once per path of the solves' sweeps (``PATHS``: a split launch per pass, or one
``core.launch.run_loop`` per solve; bitwise the same states), then measures each:
- plain: wall and process CPU time per step, nothing instrumented, in alternating rounds of
  ``--frames`` frames (A B A B: the machine's load drifts);
- instrumented: every kernel run on the CPU (``warp.context.Launch.launch``, through which every
  ``wp.launch`` is routed here by recording it first) is timed on the thread that runs it. Per step:
  kernel runs, wall, the main thread's kernel time and its Python time (wall minus that), each worker
  thread's kernel time and its idle time (wall minus its kernel time: the serial stretches, the
  hand-offs; replays go through Warp's launch here, ``core.launch.PREPARED_REPLAY`` off, so the
  per-launch argument packing the plain rounds skip is in this round's Python time), host reads
  (``wp.array.numpy`` calls), the threads' synchronisations (barrier rounds,
  wakes of the persistent threads, split launches on the fallback pool), and the kernels by total time.
The instrumentation adds a few microseconds per run; compare its wall with the plain one. Last, the
cost of one split-launch hand-off, of the thread pool's it replaced, and of one pass of ``run_loop``'s barrier
(``handoff``), whether a kernel's range costs more CPU while the other thread runs (``concurrency``), and
what packing the pair rows saves per Jacobi sweep (``compressed_rows``).
One JSON object on stdout. Wrap it in ``flock /tmp/warp_sph_bench.lock`` on a shared machine.
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import threading
import time


def _simulation(radius: float):
    from warp_sph.run.simulation import Simulation
    from warp_sph.scene import load_scene

    sc = load_scene("dam_break", overrides=[f"particle_radius={radius}", "solver=dfsph", "output.usd=false",
                                            "output.surface=false"])
    return Simulation(sc)


def _frames(sim, frames: int) -> int:
    steps = 0
    for _ in range(frames):
        steps += sim.advance_frame().steps
    return steps


PATHS = {"launch per pass": False, "run_loop": True}  # DfsphSolver.sweep_loop of each path


def _instrumented(sim, frames: int) -> dict:
    import warp as wp
    from warp._src import context as ctx

    kernel_s = collections.defaultdict(float)   # per thread id
    runs = collections.defaultdict(int)         # per thread id
    by_kernel = collections.defaultdict(lambda: [0, 0.0])
    reads = [0]
    lock = threading.Lock()
    plain_launch, plain_run, plain_numpy = wp.launch, ctx.Launch.launch, wp.array.numpy

    def timed_run(self, *a, **kw):
        t = time.perf_counter()
        plain_run(self, *a, **kw)
        dt = time.perf_counter() - t
        tid = threading.get_ident()
        key = self.kernel.key.split("__")[0] if self.kernel is not None else "?"
        with lock:
            kernel_s[tid] += dt
            runs[tid] += 1
            by_kernel[key][0] += 1
            by_kernel[key][1] += dt

    def recorded_launch(*a, record_cmd=False, **kw):
        cmd = plain_launch(*a, record_cmd=True, **kw)
        if record_cmd:
            return cmd
        if cmd is not None:
            cmd.launch()
        return None

    def counted_numpy(self):
        reads[0] += 1
        return plain_numpy(self)

    # the threads' synchronisations: barrier rounds (counted on the main thread), wakes of the persistent
    # threads (a run_loop or a split launch), split launches on the fallback thread pool
    from concurrent.futures import ThreadPoolExecutor

    from warp_sph.core import launch as L

    syncs = collections.Counter()
    plain_wait, plain_start, plain_submit = L._Barrier.wait, L._LoopWorkers.start, ThreadPoolExecutor.submit

    def counted_wait(self):
        if threading.get_ident() == main:
            syncs["barrier_rounds"] += 1
        return plain_wait(self)

    def counted_start(self, *a, **kw):
        syncs["thread_wakes"] += 1
        return plain_start(self, *a, **kw)

    def counted_submit(self, *a, **kw):
        syncs["pool_submits"] += 1
        return plain_submit(self, *a, **kw)

    main = threading.get_ident()
    # replays through warp's Launch.launch (timed above), not core.launch's prepared calls that bypass it
    prepared, L.PREPARED_REPLAY = L.PREPARED_REPLAY, False
    ctx.Launch.launch, wp.launch, wp.array.numpy = timed_run, recorded_launch, counted_numpy
    L._Barrier.wait, L._LoopWorkers.start, ThreadPoolExecutor.submit = counted_wait, counted_start, counted_submit
    try:
        t0, c0 = time.perf_counter(), time.process_time()
        steps = _frames(sim, frames)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        ctx.Launch.launch, wp.launch, wp.array.numpy = plain_run, plain_launch, plain_numpy
        L.PREPARED_REPLAY = prepared
        L._Barrier.wait, L._LoopWorkers.start, ThreadPoolExecutor.submit = plain_wait, plain_start, plain_submit
    main_k = kernel_s.get(main, 0.0)
    workers = [{"kernel_ms_per_step": 1e3 * s / steps, "idle_ms_per_step": 1e3 * (wall - s) / steps,
                "runs_per_step": runs[t] / steps} for t, s in kernel_s.items() if t != main]
    return {
        "steps": steps, "wall_ms_per_step": 1e3 * wall / steps, "cpu_ms_per_step": 1e3 * cpu / steps,
        "kernel_runs_per_step": sum(runs.values()) / steps,
        "main_kernel_ms_per_step": 1e3 * main_k / steps,
        "main_python_ms_per_step": 1e3 * (wall - main_k) / steps,
        "main_runs_per_step": runs.get(main, 0) / steps,
        "workers": workers,
        "host_reads_per_step": reads[0] / steps,
        "syncs_per_step": {k: v / steps for k, v in sorted(syncs.items())},
        "solver_last": sim.solver.step_statistics(),
        "kernels": {k: {"runs_per_step": n / steps, "ms_per_step": 1e3 * s / steps, "us_per_run": 1e6 * s / max(n, 1)}
                    for k, (n, s) in sorted(by_kernel.items(), key=lambda kv: -kv[1][1])},
    }


def handoff_costs(rounds: int = 5000) -> dict:
    """Microseconds (wall and process CPU) per synchronisation of 2 threads doing nothing else: the split
    launch's hand-off (``_run_split``: wake a persistent thread, run, meet at the barrier), the thread
    pool's it replaced (``pool_handoff_us``: submit, run, wait for the future; still the fallback inside a
    loop), and a pass of ``run_loop``'s barrier (``_Barrier.wait`` on both threads)."""
    from concurrent.futures import ThreadPoolExecutor

    from warp_sph.core import launch as L

    def noop():
        pass

    out = {}
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(rounds):
        L._run_split([noop, noop])
    out["split_handoff_us"] = (1e6 * (time.perf_counter() - t0) / rounds, 1e6 * (time.process_time() - c0) / rounds)
    with ThreadPoolExecutor(max_workers=1) as pool:
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(rounds):
            f = pool.submit(noop)
            noop()
            f.result()
        out["pool_handoff_us"] = (1e6 * (time.perf_counter() - t0) / rounds, 1e6 * (time.process_time() - c0) / rounds)
    barrier = L._Barrier(2)
    other = threading.Thread(target=lambda: [barrier.wait() for _ in range(rounds)])
    t0, c0 = time.perf_counter(), time.process_time()
    other.start()
    for _ in range(rounds):
        barrier.wait()
    other.join()
    out["barrier_us"] = (1e6 * (time.perf_counter() - t0) / rounds, 1e6 * (time.process_time() - c0) / rounds)
    return {k: {"wall": round(w, 1), "cpu": round(c, 1)} for k, (w, c) in out.items()}


def concurrent_runs(sim, runs: int = 3000) -> dict:
    """Does a kernel cost more CPU when the other thread runs at the same time? The two ranges of one
    Jacobi sweep's ``pressure_acceleration`` launched ``runs`` times each from two threads at once; per
    thread, the median process-CPU microseconds of the runs that ran unpreempted (thread CPU >= 97 % of
    their wall time) alone (< 10 % of their wall time overlapped by an unpreempted run of the other
    thread) and together (> 90 %). Equal medians: running together does not slow a range down."""
    import numpy as np
    import warp as wp

    from warp_sph.kernels import dfsph_solve as _dfsph

    solver, f, n = sim.solver, sim.fields, sim.model.fluid_count
    control = wp.zeros_like(solver._control)  # not done: the sweep runs
    args = [solver.nl.fluid, f["dfsph_pairs"], f["dfsph_pressure"], control]
    half = n // 2
    cmds = [wp.launch(_dfsph.pressure_acceleration, dim=hi - lo, inputs=[lo, *args], outputs=[f["dfsph_acceleration"]],
                      record_cmd=True) for lo, hi in ((0, half), (half, n))]
    times = {0: [], 1: []}

    def loop(k):
        out = times[k]
        for _ in range(runs):
            t0, c0 = time.perf_counter(), time.thread_time()
            cmds[k].launch()
            out.append((t0, time.perf_counter(), c0, time.thread_time()))

    threads = [threading.Thread(target=loop, args=(k,)) for k in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    a = {k: np.array(v) for k, v in times.items()}
    clean = {k: v[(v[:, 3] - v[:, 2]) >= 0.97 * (v[:, 1] - v[:, 0])] for k, v in a.items()}
    out = {}
    for k in (0, 1):
        other = clean[1 - k]
        rows = np.array([(np.clip(np.minimum(other[:, 1], t1) - np.maximum(other[:, 0], t0), 0, None).sum() / (t1 - t0),
                          c1 - c0) for t0, t1, c0, c1 in clean[k]])
        alone, together = rows[rows[:, 0] < 0.1, 1], rows[rows[:, 0] > 0.9, 1]
        out[f"thread_{k}"] = {"alone_runs": len(alone), "together_runs": len(together),
                              "alone_cpu_us": float(1e6 * np.median(alone)) if len(alone) else None,
                              "together_cpu_us": float(1e6 * np.median(together)) if len(together) else None}
    return out


def compressed_rows(sim, sweeps: int = 100, rounds: int = 3) -> dict:
    """What packing the pair rows pays: process CPU microseconds per Jacobi sweep (``pressure_acceleration``
    + ``jacobi_update`` over every particle in one launch each) on the search's pairs laid out padded (row i
    at i x the list capacity, the search's layout on a device) and packed (row i right after row i - 1, as
    the search writes them on the CPU), ``rounds`` alternating rounds of ``sweeps`` sweeps from the
    same P; ``same_pressure``: both give bitwise the same P (the same pairs in the same order)."""
    import numpy as np
    import warp as wp

    from warp_sph.kernels import dfsph_solve as _dfsph
    from warp_sph.kernels.dfsph_search import DfsphPairs

    solver, f, n = sim.solver, sim.fields, sim.model.fluid_count
    capacity = sim.fields["neighbor_lists"].capacities[0]
    with sim.in_cell_order():
        for stage in sim.graph.stages[:2]:  # the neighbours and the search at the frame's positions
            stage.run(sim, sim.frame_dt / 10)
        cache = f["dfsph_pairs"]
        offset, count = cache.offset.numpy()[:n], cache.count.numpy()[:n]
        rows = np.concatenate([np.arange(o, o + c) for o, c in zip(offset, count)])
        index, gradient = cache.index.numpy()[rows], cache.gradient.numpy()[rows]
        layouts = {}
        for name, starts in (("padded", np.arange(n) * capacity), ("packed", np.concatenate([[0], np.cumsum(count)[:-1]]))):
            pairs = DfsphPairs()
            for field in ("count", "gradient_sum", "boundary_gradient", "boundary_velocity", "active"):
                setattr(pairs, field, getattr(cache, field))
            at = np.concatenate([np.arange(s0, s0 + c) for s0, c in zip(starts, count)])
            idx, grad = np.zeros(n * capacity, np.int32), np.zeros((n * capacity, 3), np.float32)
            idx[at], grad[at] = index, gradient
            pairs.offset = wp.array(starts.astype(np.int32), dtype=wp.int32)
            pairs.index, pairs.gradient = wp.array(idx, dtype=wp.int32), wp.array(grad, dtype=wp.vec3)
            layouts[name] = pairs
        control = wp.zeros_like(solver._control)  # not done: the sweeps run
        p, acc = f["dfsph_pressure"], f["dfsph_acceleration"]
        p0 = p.numpy().copy()
        out, final = {name: [] for name in layouts}, {}
        for _ in range(rounds):
            for name, pairs in layouts.items():
                p.assign(p0)
                c0 = time.process_time()
                for _ in range(sweeps):
                    wp.launch(_dfsph.pressure_acceleration, dim=n, inputs=[0, solver.nl.fluid, pairs, p, control],
                              outputs=[acc])
                    wp.launch(_dfsph.jacobi_update, dim=n, inputs=[0, solver.nl.fluid, pairs, f["dfsph_factor"],
                                                                   f["dfsph_density_source"], acc, 1e-6, 0.5, 0, control, 0],
                              outputs=[p, solver._previous, f["dfsph_error"]])
                out[name].append(round(1e6 * (time.process_time() - c0) / sweeps))
                final[name] = p.numpy().copy()
        p.assign(p0)
    return {"cpu_us_per_sweep": out, "row_use": float(count.mean() / capacity),
            "same_pressure": bool(np.array_equal(final["padded"], final["packed"]))}


def profile(radius: float = 0.025, start: float = 0.3, frames: int = 3, rounds: int = 2) -> dict:
    """Both paths of the DFSPH solves (``PATHS``) side by side on two equal simulations: ``rounds``
    alternating rounds of ``frames`` plain frames each, then one instrumented round each."""
    from warp_sph.core.launch import cpu_threads

    sims = {}
    for name, loop in PATHS.items():
        sim = _simulation(radius)
        sim.solver.sweep_loop = loop
        while sim.state.time < start - 1e-9:
            sim.advance_frame()
        sims[name] = sim
    first = next(iter(sims.values()))
    out = {"radius": radius, "start_time": first.state.time, "frames": frames, "rounds": rounds,
           "fluid": first.model.fluid_count, "cpu_threads": cpu_threads(), "load_before": os.getloadavg()}
    plain = {name: [0, 0.0, 0.0] for name in sims}
    for _ in range(rounds):
        for name, sim in sims.items():
            t0, c0 = time.perf_counter(), time.process_time()
            steps = _frames(sim, frames)
            p = plain[name]
            p[0] += steps
            p[1] += time.perf_counter() - t0
            p[2] += time.process_time() - c0
    out["plain"] = {name: {"steps": n, "wall_ms_per_step": 1e3 * w / n, "cpu_ms_per_step": 1e3 * c / n,
                           "cores_busy": c / w} for name, (n, w, c) in plain.items()}
    out["instrumented"] = {name: _instrumented(sim, frames) for name, sim in sims.items()}
    out["handoff"] = handoff_costs()
    out["concurrency"] = concurrent_runs(first)  # (the last step's pairs; only the time matters)
    out["compressed_rows"] = compressed_rows(first)
    out["load_after"] = os.getloadavg()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--radius", type=float, default=0.025, help="particle radius [m] (default 0.025: 6,859 particles)")
    ap.add_argument("--start", type=float, default=0.3, help="simulated seconds run before measuring (default 0.3)")
    ap.add_argument("--frames", type=int, default=3, help="frames per round (default 3)")
    ap.add_argument("--rounds", type=int, default=2, help="plain rounds per path, alternating (default 2)")
    ap.add_argument("--threads", type=int, default=None, help="WARP_SPH_CPU_THREADS (default: every core)")
    a = ap.parse_args(argv)
    if a.threads:
        os.environ["WARP_SPH_CPU_THREADS"] = str(a.threads)
    print(json.dumps(profile(a.radius, a.start, a.frames, a.rounds), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
