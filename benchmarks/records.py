"""Benchmark records: the schema, where they are written, host description and small shared helpers.

Every benchmark command appends one JSON line per run (``SCHEMA``) to ``<results>/<kind>.jsonl``;
``report.py`` makes tables and plots from those files only. This module imports no other
benchmark module (``runner.py`` is only the command line; ``cases.py`` runs warp-sph; ``report.py``,
``matrix.py``, ``splishsplash.py`` build on these records), so there is no import cycle.

Where results go: the committed results page (``benchmarks/RESULTS.md`` and ``benchmarks/results/``)
changes only when asked (``--publish``); by default every command writes to ``runs/bench/`` in the
working directory (its report ``runs/bench/RESULTS.md``), or to ``--out DIR``.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import shlex
from pathlib import Path

SCHEMA = "warp-sph-bench/1"
#: the committed results (JSON lines and plots); RESULTS.md lies beside this folder
RESULTS_DIR = Path(__file__).resolve().parent / "results"
#: the default for every command: a user folder, relative to the working directory
USER_RESULTS_DIR = Path("runs") / "bench"
KINDS = ("sweep", "scaling", "splishsplash", "surface", "matrix", "executors", "bodies", "emission", "validation",
         "extremes", "whitewater", "plan")


def solver_names() -> tuple[str, ...]:
    """Every solver a benchmark list covers: the solver registry's names (the one place benchmarks
    read them)."""
    from warp_sph.methods.registry import solver_names as registered

    return registered()


def scene_names() -> tuple[str, ...]:
    """The built-in scenes, sorted by name."""
    from warp_sph.scene import list_scenes

    return tuple(name for name, _ in list_scenes())


def results_dir(out: str | None, publish: bool = False) -> Path:
    """--out DIR; else the committed results with --publish; else the user folder runs/bench."""
    if out:
        return Path(out)
    return RESULTS_DIR if publish else USER_RESULTS_DIR


def report_path(results: Path) -> Path:
    """RESULTS.md beside the committed results folder, else inside the results folder."""
    results = Path(results)
    return results.parent / "RESULTS.md" if results.resolve() == RESULTS_DIR else results / "RESULTS.md"


def host_info() -> dict:
    """nproc, CPU model (from /proc/cpuinfo), platform, load average and thread-related environment."""
    from warp_sph.core.device import cpu_model

    model = cpu_model()
    try:
        load = [round(v, 2) for v in os.getloadavg()]
    except OSError:
        load = None
    return {"nproc": os.cpu_count(), "cpu_model": model, "hostname": platform.node(), "load_average": load,
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
            "warp_sph_cpu_threads": os.environ.get("WARP_SPH_CPU_THREADS")}


def now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).astimezone().isoformat(timespec="seconds")


def label(params: dict) -> str:
    return " ".join(f"{k}={v}" for k, v in params.items()) or "default"


def append_records(out: Path, kind: str, records: list[dict]) -> Path:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{kind}.jsonl"
    with open(path, "a") as f:
        for r in records:
            f.write(json.dumps(r, allow_nan=False) + "\n")
    return path


def print_profile_record(record: dict, out: str | None, time_key: str = "when") -> dict:
    """A profile script's record (impact_edge.py, surface_tension.py, ...) stamped with the UTC time under
    ``time_key``, the machine, its 1-minute load and Warp's version; printed as one JSON line and appended to
    the JSON-lines file ``out`` (None or "": printed only). Returns the stamped record."""
    import time

    import warp as wp

    record = {**record, time_key: time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "machine": platform.node(),
              "load": os.getloadavg()[0], "warp": wp.__version__}
    line = json.dumps(record)
    print(line, flush=True)
    if out:
        with open(out, "a") as f:
            f.write(line + "\n")
    return record


def stamp(records: list[dict], command: str, invocation: str) -> None:
    for r in records:
        r["command"] = command
        r["invocation"] = invocation


def command_text(argv: list[str]) -> str:
    """The command as typed, with the environment settings that change what is measured (the CPU
    threads warp-sph splits its kernels over) in front, so that a published command reproduces."""
    env = "".join(f"{k}={shlex.quote(os.environ[k])} " for k in ("WARP_SPH_CPU_THREADS",) if os.environ.get(k))
    return env + "warp-sph bench " + " ".join(shlex.quote(a) for a in argv)


def print_row(r: dict, log) -> None:
    m = r.get("metrics") or {}

    def f(k, scale=1.0, fmt="{:.3g}"):
        v = m.get(k)
        return fmt.format(v * scale) if isinstance(v, (int, float)) else "-"

    log(f"  [{r['status']:>10}] {r.get('engine', '')} {r['label']}: N={r.get('fluid_particles', '-')} "
        f"wall/sim-s {f('wall_per_simulated_second')}  ns/particle-step {f('ns_per_particle_step')}  "
        f"mean density err {f('density_error_mean_avg', 100)} %  front {f('front_final')} m"
        + (f"  ({r.get('error')})" if r.get("error") else ""))
