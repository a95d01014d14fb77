"""``warp-sph bench executors``: the same sweep on the serial executor and on a Dask LocalCluster.

Eight small dam-break cases (solver x kernel x CFL at r = 0.05 m, 729 fluid particles, 2 s
simulated, no USD or surface: ``executor_cases``) run as ``warp-sph sweep`` runs them, once
serially in this process and once on a LocalCluster of ``workers`` processes, alternating, each
into a fresh temporary folder (nothing is skipped). Kernels are compiled before the first timing.

Figures per repeat: the serial wall time; the LocalCluster's wall time including its start and
close (what a user waits for) and without them (first submission to last result); their ratios;
the scheduler's overhead per case: the time from when a case could start (submitted, and its
worker free) until it started, plus the time from its end until the client had its result; and
whether both executors gave the same per-case results (they must: bitwise on the CPU).
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

from .records import SCHEMA, host_info, now

PARAMS = {"solver": ["wcsph", "pbf"], "smoothing_kernel": ["cubic", "quintic"], "time.cfl": ["0.2", "0.4"]}


def executor_cases(particle_radius: float = 0.05, frames: int = 49):
    from warp_sph.sweep import build_cases

    return build_cases("dam_break", PARAMS, fixed=[f"particle_radius={particle_radius}", "output.usd=false",
                                                   "output.surface=false"], frames=frames)


def overhead_parts(rows: list[dict]) -> list[tuple[float, float]]:
    """Per case (dispatch, result) [s]: dispatch = started - max(submitted, end of the previous case
    on the same worker process), result = received - finished. Rows need submitted, started,
    finished, received, host and pid (one machine's clock)."""
    out = []
    by_worker: dict[tuple, list[dict]] = {}
    for r in rows:
        by_worker.setdefault((r.get("host"), r.get("pid")), []).append(r)
    for seq in by_worker.values():
        prev_end = None
        for r in sorted(seq, key=lambda r: r["started"]):
            ready = r["submitted"] if prev_end is None else max(r["submitted"], prev_end)
            out.append((max(0.0, r["started"] - ready), max(0.0, r["received"] - r["finished"])))
            prev_end = r["finished"]
    return out


def scheduler_overhead(rows: list[dict]) -> list[float]:
    """Per case [s]: dispatch + result latency (``overhead_parts``)."""
    return [a + b for a, b in overhead_parts(rows)]


_COMPARED = ("status", "fluid_particles", "frames", "steps", "simulated_time", "density_error_mean",
             "density_error_max", "front")


def measure(workers: int = 2, particle_radius: float = 0.05, frames: int = 49, repeats: int = 1,
            log=print) -> list[dict]:
    """Records (one per repeat) of the serial and LocalCluster runs of ``executor_cases``."""
    from warp_sph.sweep import DaskExecutor, SerialExecutor, run_sweep
    from warp_sph.sweep.summary import read_rows

    quiet = dict(progress=False, log=lambda *a, **k: None)
    cases = executor_cases(particle_radius, frames)
    records = []
    with tempfile.TemporaryDirectory(prefix="warp-sph-executors-") as tmp:
        tmp = Path(tmp)
        run_sweep(cases[:1], tmp / "warm", SerialExecutor(), **quiet)  # compile before any timing
        for rep in range(repeats):
            load0 = host_info()["load_average"]
            t0 = time.perf_counter()
            run_sweep(cases, tmp / f"serial{rep}", SerialExecutor(), **quiet)
            serial_s = time.perf_counter() - t0
            log(f"repeat {rep + 1}: serial {serial_s:.2f} s")
            t0 = time.perf_counter()
            ex = DaskExecutor(workers=workers, log=lambda *a: None)
            with ex:
                started_s = time.perf_counter() - t0
                run_sweep(cases, tmp / f"dask{rep}", ex, **quiet)
            dask_s = time.perf_counter() - t0
            serial, dask = read_rows(tmp / f"serial{rep}"), read_rows(tmp / f"dask{rep}")
            rows = list(dask.values())
            window = max(r["received"] for r in rows) - min(r["submitted"] for r in rows)
            over = scheduler_overhead(rows)
            same = all(serial[c.name].get(k) == dask[c.name].get(k) for c in cases for k in _COMPARED)
            ok = all(r["status"] == "completed" for r in list(serial.values()) + rows)
            rec = {"schema": SCHEMA, "kind": "executors", "name": "executors", "engine": "warp-sph",
                   "label": f"{len(cases)} cases, {workers} workers", "date": now(), "host": host_info(),
                   "status": "ok" if ok and same else "failed",
                   "params": {"cases": len(cases), "workers": workers, "particle_radius": particle_radius,
                              "frames": frames, "repeat": rep + 1},
                   "metrics": {"serial_seconds": serial_s, "local_cluster_seconds": dask_s,
                               "cluster_start_seconds": started_s, "cases_window_seconds": window,
                               "ratio": dask_s / serial_s, "ratio_cases_window": window / serial_s,
                               "overhead_per_case_mean": sum(over) / len(over), "overhead_per_case_max": max(over),
                               "overhead_dispatch": [a for a, _ in overhead_parts(rows)],
                               "overhead_result": [b for _, b in overhead_parts(rows)],
                               "case_seconds_serial": [serial[c.name]["finished"] - serial[c.name]["started"] for c in cases],
                               "case_seconds_local_cluster": [dask[c.name]["finished"] - dask[c.name]["started"]
                                                              for c in cases],
                               "case_worker": [dask[c.name]["pid"] for c in cases],
                               "worker_processes": len({(r["host"], r["pid"]) for r in rows}),
                               "results_identical": same, "load_average_before": load0,
                               "load_average_after": host_info()["load_average"]}}
            if not same:
                rec["error"] = "the LocalCluster's per-case results differ from the serial executor's"
            if not ok:
                rec["error"] = "a case did not complete: " + "; ".join(
                    f"{r['case']}: {r.get('error')}" for r in list(serial.values()) + rows if r["status"] != "completed")
            m = rec["metrics"]
            log(f"repeat {rep + 1}: LocalCluster of {workers} {dask_s:.2f} s (start {started_s:.2f} s, cases "
                f"{window:.2f} s): {m['ratio']:.2f}x serial ({m['ratio_cases_window']:.2f}x without start/close); "
                f"scheduler overhead per case {m['overhead_per_case_mean']:.3f} s mean, "
                f"{m['overhead_per_case_max']:.3f} s max; identical results: {same}; load {load0}")
            records.append(rec)
    return records


def section(records: list[dict], fmt, head) -> list[str]:
    """Markdown of the latest executor comparison."""
    if not records:
        return []
    p = records[0].get("params") or {}
    lines = ["## Sweep executors: serial against a Dask LocalCluster", ""] + head(records)
    lines += [f"{p.get('cases')} dam-break cases (solver x kernel x CFL, r = {p.get('particle_radius')} m, "
              f"{p.get('frames')} frames, no USD or surface), as `warp-sph sweep` runs them: serially in one "
              f"process, then on a LocalCluster of {p.get('workers')} worker processes (one Warp CPU thread each). "
              "*LocalCluster* includes starting and closing the cluster; *cases only* runs from the first "
              "submission to the last result. *Overhead per case*: from when a case could start (submitted, "
              "its worker free) to its start, plus from its end to the client having its result. The machine is "
              "shared: the load average before each repeat is listed.", ""]
    header = ["repeat", "serial [s]", "LocalCluster [s]", "ratio", "cases only [s]", "ratio (cases only)",
              "cluster start [s]", "overhead/case mean [s]", "overhead/case max [s]", "same results", "load average"]
    rows = []
    for r in records:
        m = r.get("metrics") or {}
        rows.append([str((r.get("params") or {}).get("repeat", "?")), fmt(m.get("serial_seconds")),
                     fmt(m.get("local_cluster_seconds")), fmt(m.get("ratio")), fmt(m.get("cases_window_seconds")),
                     fmt(m.get("ratio_cases_window")), fmt(m.get("cluster_start_seconds")),
                     fmt(m.get("overhead_per_case_mean")), fmt(m.get("overhead_per_case_max")),
                     "yes" if m.get("results_identical") else "**no**",
                     ", ".join(str(v) for v in (m.get("load_average_before") or [])) or "-"])
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
    lines += [f"- {r['label']}: {r.get('error')}" for r in records if r.get("error")]
    return lines + [""]
