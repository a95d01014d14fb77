"""One SPlisHSPlasH case (``pysplishsplash``), run in a subprocess: its scene file, its run, its record.

``pysplishsplash`` 2.19 imports only with ``LD_PRELOAD=/lib/x86_64-linux-gnu/libGLdispatch.so.0`` (its GUI
libraries), so the case runs ``python splishsplash_driver.py CONFIG.json OUT.npz`` with that environment
and ``OMP_NUM_THREADS``; the record's metrics are computed from the positions, velocities and densities
the driver saved per frame, as for a warp-sph run. The comparisons that run these cases beside warp-sph
are ``splishsplash.py``.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from .splishsplash_scene import TIME_STEP_CLASSES, box_obj_text, from_y_up, scene_json, time_step_values, to_y_up

GL_PRELOAD = "/lib/x86_64-linux-gnu/libGLdispatch.so.0"


def _env(threads: int) -> dict:
    env = dict(os.environ)
    pre = env.get("LD_PRELOAD", "")
    if os.path.exists(GL_PRELOAD) and GL_PRELOAD not in pre.split(":"):
        env["LD_PRELOAD"] = f"{GL_PRELOAD}:{pre}" if pre else GL_PRELOAD
    env["OMP_NUM_THREADS"] = str(int(threads))
    return env


def available(timeout: float = 120.0) -> tuple[bool, str]:
    """(True, version) when pysplishsplash imports in a subprocess with the GL preload; else
    (False, why)."""
    code = "import importlib.metadata as m, pysplishsplash; print(m.version('pysplishsplash'))"
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              timeout=timeout, env=_env(1))
    except (OSError, subprocess.TimeoutExpired) as e:
        return False, f"could not start Python to import pysplishsplash: {e}"
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()
        why = tail[-1] if tail else f"exit status {proc.returncode}"
        if "No module named" in why:
            why = "pysplishsplash is not installed (pip install pysplishsplash)"
        return False, why
    return True, proc.stdout.strip().splitlines()[-1]


def _series_from_frames(x_y_up, v_y_up, rho, t, steps, mass, rest_density, gravity, floor, wall_x) -> tuple[dict, dict]:
    from . import metrics as M

    series = {k: [] for k in ("time", "steps", "density_error_mean", "density_error_max", "density_error_min",
                              "kinetic_energy", "potential_energy", "total_energy", "front", "volume_drift",
                              "max_speed")}
    v0 = None
    for k in range(len(t)):
        x = from_y_up(x_y_up[k]).astype(np.float64)
        v = from_y_up(v_y_up[k]).astype(np.float64)
        # SPlisHSPlasH computes densities in its first step: at t = 0 its density field is still 0
        de = M.density_error_stats(rho[k], rest_density) if np.any(rho[k]) else {"mean": None, "max": None, "min": None}
        ke = M.kinetic_energy(v, mass)
        pe = M.potential_energy(x, mass, gravity, floor)
        vol = M.compression_volume(rho[k], mass, rest_density)
        v0 = vol if v0 is None else v0
        for key, val in (("time", float(t[k])), ("steps", int(steps[k])), ("density_error_mean", de["mean"]),
                         ("density_error_max", de["max"]), ("density_error_min", de["min"]),
                         ("kinetic_energy", ke), ("potential_energy", pe), ("total_energy", ke + pe),
                         ("front", M.surge_front(x, wall_x)), ("volume_drift", vol / v0 - 1.0),
                         ("max_speed", float(np.linalg.norm(v, axis=1).max()))):
            series[key].append(val)
    x0 = from_y_up(x_y_up[0]).astype(np.float64)
    g = np.asarray(gravity, dtype=np.float64)
    gn = float(np.linalg.norm(g))
    scale = len(x0) * mass * gn * float(((x0 - floor) @ (-g / gn)).mean())
    es = M.energy_summary(series["total_energy"], scale)
    acc = {"density_error_mean_avg": M.series_summary(series["density_error_mean"][1:])["mean"],
           "density_error_mean_max": M.series_summary(series["density_error_mean"][1:])["max"],
           "density_error_max": M.series_summary(series["density_error_max"][1:])["max"],
           "volume_drift_final": series["volume_drift"][-1],
           "volume_drift_max_abs": max(abs(v) for v in series["volume_drift"]),
           "energy_change_final": es["change_final"], "energy_rise_max": es["rise_max"],
           "front_final": series["front"][-1]}
    return series, acc


def run_splishsplash_case(scene_dict: dict, model: dict, fluid_min, fluid_max, solver: str, dt: float,
                          frames: int, threads: int, timeout: float | None = None, adaptive: bool = False,
                          time_step: dict | None = None, label: str | None = None) -> dict:
    """One SPlisHSPlasH case; returns a benchmark record (status "failed" with the reason on error).
    adaptive: its CFL step (dt is then only the initial step); time_step: the method's parameters by
    TimeStep name (default: warp-sph's settings, ``time_step_values``); label: the case's name."""
    from . import metrics as M
    from .records import SCHEMA, host_info, now as _now

    params = {"engine": "splishsplash", "solver": solver, "dt": None if adaptive else dt,
              "particle_radius": scene_dict["particle_radius"]}
    if adaptive:
        params.update(mode="adaptive", case=label or solver, parameters=dict(time_step or {}))
    record = {"schema": SCHEMA, "kind": "splishsplash", "name": "splishsplash", "engine": "splishsplash",
              "label": f"splishsplash {label or solver}", "params": params, "date": _now(), "host": host_info(),
              "threads": threads, "device": "cpu", "device_name": "CPU", "scene": scene_dict, "status": "failed"}
    if time_step is None:
        time_step = time_step_values(scene_dict, model, solver)
    ok, version = available()
    if not ok:
        record["status"] = "skipped"
        record["error"] = version
        return record
    record["versions"] = {"pysplishsplash": version, "numpy": np.__version__}
    with tempfile.TemporaryDirectory(prefix="warp-sph-sph-") as tmp:
        tmp = Path(tmp)
        c = scene_dict["container"]
        (tmp / "box.obj").write_text(box_obj_text(to_y_up(c["min"]), to_y_up(c["max"])))
        sj = scene_json(scene_dict, model, fluid_min, fluid_max, solver, dt, str(tmp / "box.obj"), adaptive=adaptive,
                        time_step=time_step)
        (tmp / "scene.json").write_text(json.dumps(sj, indent=1))
        record["splishsplash_scene"] = sj
        cfg = {"scene_file": str(tmp / "scene.json"), "output_dir": str(tmp / "out"), "fps": scene_dict["fps"],
               "frames": frames, "dt": dt, "time_step": time_step}
        (tmp / "config.json").write_text(json.dumps(cfg))
        cmd = [sys.executable, str(Path(__file__).resolve().with_name("splishsplash_driver.py")), str(tmp / "config.json"),
               str(tmp / "out.npz")]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=_env(threads))
        except subprocess.TimeoutExpired:
            record["error"] = "SPlisHSPlasH run timed out"
            return record
        if proc.returncode != 0 or not (tmp / "out.npz").is_file():
            record["error"] = f"SPlisHSPlasH exited with status {proc.returncode}: {(proc.stderr or proc.stdout)[-600:]}"
            return record
        data = np.load(tmp / "out.npz")
        info = json.loads(str(data["info"]))
    record["splishsplash"] = info
    n = info["fluid_particles"]
    record["fluid_particles"] = n
    record["boundary_particles"] = info.get("boundary_particles")
    c = scene_dict["container"]
    floor = np.asarray(c["min"], dtype=np.float64)
    series, acc = _series_from_frames(data["x"], data["v"], data["rho"], data["t"], data["steps"], info["mass"],
                                      info["rest_density"], scene_dict["gravity"], floor, float(c["min"][0]))
    met = {"setup_seconds": info["setup_seconds"], "wall_seconds": info["wall_seconds"],
           "simulated_seconds": info["simulated_seconds"], "steps": info["steps"], "frames": len(series["time"]) - 1}
    met.update(M.speed_metrics(info["wall_seconds"], info["simulated_seconds"], info["steps"], n))
    met.update(acc)
    # the case's peak RSS in the driver's process (peak_memory.MemoryWindow; the same keys as warp-sph's records)
    met.update(info.get("memory") or {})
    if info.get("cpu_seconds") is not None and info["simulated_seconds"] > 0:
        met["cpu_seconds"] = info["cpu_seconds"]
        met["cpu_per_simulated_second"] = info["cpu_seconds"] / info["simulated_seconds"]
    if info["steps"]:
        met["dt_mean"] = info["simulated_seconds"] / info["steps"]
    if adaptive and info.get("time_step_class") != TIME_STEP_CLASSES.get(solver):
        record["error"] = f"SPlisHSPlasH ran {info.get('time_step_class')}, expected {TIME_STEP_CLASSES.get(solver)}"
        return M.nan_to_none(record)
    its = [float(i) for i in data["iterations"][1:] if np.isfinite(i)]
    series["solver_iterations"] = [None] + its if its else [None] * len(series["time"])
    if its:
        met["solver_iterations_mean"] = float(np.mean(its))
    its_v = [float(i) for i in data["iterations_v"][1:] if np.isfinite(i)] if "iterations_v" in data.files else []
    if its_v:
        met["divergence_iterations_mean"] = float(np.mean(its_v))
    record["metrics"] = met
    record["series"] = series
    record["status"] = "ok"
    return M.nan_to_none(record)
