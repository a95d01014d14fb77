"""Side by side with SPlisHSPlasH (the ``pysplishsplash`` wheel), optional.

The same dam break runs in both engines: the same box (the scene's container, its six faces as
Akinci 2012 boundary particles), the same fluid lattice (SPlisHSPlasH's block is placed so that its
particles land on warp-sph's sampled positions), the same particle radius, a fixed time step,
WCSPH (SPlisHSPlasH's stiffness and exponent set to warp-sph's equation of state) and PBF
(same iteration limits and target error), plus SPlisHSPlasH's DFSPH as a reference. The same
metrics are computed from the positions, velocities and densities each engine reports per frame.

Differences that remain (stated in the report): SPlisHSPlasH's particle mass is 0.8 d^3 rho0,
warp-sph's is calibrated so that a rest lattice has rho0; SPlisHSPlasH samples the box walls with
its own surface sampler and places the fluid against them with its own gap; SPlisHSPlasH is Y-up
(coordinates are swapped on the way in and out); SPlisHSPlasH runs OpenMP with OMP_NUM_THREADS
threads, warp-sph's CPU backend runs each kernel on one thread.

``pysplishsplash`` 2.19 imports only with ``LD_PRELOAD=/lib/x86_64-linux-gnu/libGLdispatch.so.0``
(its GUI libraries), so each SPlisHSPlasH case runs in a subprocess with that environment:
``python splishsplash_driver.py CONFIG.json OUT.npz`` (``splishsplash_driver.py``, which imports no
Warp).
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

GL_PRELOAD = "/lib/x86_64-linux-gnu/libGLdispatch.so.0"

#: SPlisHSPlasH scene-file codes (its scene-file documentation).
SIMULATION_METHODS = {"wcsph": 0, "pbf": 2, "dfsph": 4}
BOUNDARY_AKINCI2012 = 0
KERNEL_CUBIC = 0


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


# --------------------------------------------------------------------------------------------
# Scene translation (Z-up warp-sph -> Y-up SPlisHSPlasH)
# --------------------------------------------------------------------------------------------
def to_y_up(v) -> list[float]:
    """(x, y, z) Z-up -> (x, z, y) Y-up."""
    return [float(v[0]), float(v[2]), float(v[1])]


def from_y_up(a: np.ndarray) -> np.ndarray:
    """(n, 3) Y-up -> Z-up."""
    return np.asarray(a)[:, [0, 2, 1]]


def box_obj_text(lo, hi) -> str:
    """A closed box lo..hi as OBJ text (8 vertices, 12 triangles)."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    verts = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
             (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
    faces = [(1, 3, 2), (1, 4, 3), (5, 6, 7), (5, 7, 8), (1, 2, 6), (1, 6, 5),
             (2, 3, 7), (2, 7, 6), (3, 4, 8), (3, 8, 7), (4, 1, 5), (4, 5, 8)]
    lines = [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in verts] + [f"f {a} {b} {c}" for a, b, c in faces]
    return "\n".join(lines) + "\n"


_JSON_KEYS = {"STIFFNESS": "stiffness", "EXPONENT": "exponent", "MAX_ITERATIONS": "maxIterations",
              "MIN_ITERATIONS": "minIterations", "MAX_ERROR": "maxError", "MAX_ITERATIONS_V": "maxIterationsV",
              "MAX_ERROR_V": "maxErrorV", "USE_DIVERGENCE_SOLVER": "enableDivergenceSolver",
              "VELOCITY_UPDATE_METHOD": "velocityUpdateMethod"}


def time_step_values(scene: dict, model: dict, solver: str) -> dict:
    """Pressure-solver parameters for SPlisHSPlasH's TimeStep class, by its parameter name.

    WCSPH: p = stiffness ((rho/rho0)^exponent - 1) with warp-sph's K and exponent 1 (linear) or 7
    (Tait). PBF: warp-sph's iteration limits and target average density error (SPlisHSPlasH's
    maxError is in percent). DFSPH: SPlisHSPlasH's defaults (0.01 % density, 0.1 % divergence).
    """
    if solver == "wcsph":
        return {"STIFFNESS": float(model["stiffness"]),
                "EXPONENT": 7.0 if model.get("equation_of_state") == "tait" else 1.0}
    if solver == "pbf":
        pbf = scene.get("pbf", {})
        return {"MAX_ITERATIONS": int(pbf.get("max_iterations", 50)), "MIN_ITERATIONS": int(pbf.get("min_iterations", 2)),
                "MAX_ERROR": 100.0 * float(pbf.get("target_density_error", 0.005)), "VELOCITY_UPDATE_METHOD": 0}
    if solver == "dfsph":
        return {"MAX_ITERATIONS": 100, "MIN_ITERATIONS": 2, "MAX_ERROR": 0.01, "MAX_ITERATIONS_V": 100,
                "MAX_ERROR_V": 0.1, "USE_DIVERGENCE_SOLVER": True}
    raise ValueError(f"unknown solver {solver!r}")


def scene_json(scene: dict, model: dict, fluid_min, fluid_max, solver: str, dt: float, box_obj: str) -> dict:
    """SPlisHSPlasH scene (JSON structure) for a warp-sph scene dict with a box container and box fluid.

    model: warp-sph ``Model.summary()`` (stiffness, equation of state); fluid_min/max: corners of
    warp-sph's sampled fluid lattice (particle centres) [m], Z-up. SPlisHSPlasH fills a block
    start..end with particles at start + d, ..., end - d, so start/end are the lattice corners -/+ d.
    """
    d = 2.0 * float(scene["particle_radius"])
    g = to_y_up(scene["gravity"])
    conf = {
        "particleRadius": float(scene["particle_radius"]),
        "simulationMethod": SIMULATION_METHODS[solver],
        "boundaryHandlingMethod": BOUNDARY_AKINCI2012,
        "kernel": KERNEL_CUBIC, "gradKernel": KERNEL_CUBIC,
        "gravitation": g,
        "timeStepSize": float(dt), "cflMethod": 0,
        "numberOfStepsPerRenderUpdate": 1,
        "enableVTKExport": False, "enablePartioExport": False,
    }
    ts = time_step_values(scene, model, solver)
    block = {"wcsph": "WCSPH", "pbf": "PBF", "dfsph": "DFSPH"}[solver]
    conf[block] = {_JSON_KEYS[k]: (bool(v) if isinstance(v, bool) else v) for k, v in ts.items()}
    lo = np.minimum(to_y_up(np.asarray(fluid_min) - d), to_y_up(np.asarray(fluid_max) + d))
    hi = np.maximum(to_y_up(np.asarray(fluid_min) - d), to_y_up(np.asarray(fluid_max) + d))
    return {
        "Configuration": conf,
        "Materials": [{"id": "Fluid", "density0": float(scene["material"]["rest_density"]),
                       "viscosityMethod": 0, "surfaceTensionMethod": 0, "vorticityMethod": 0,
                       "dragMethod": 0, "elasticityMethod": 0}],
        "RigidBodies": [{"geometryFile": box_obj, "translation": [0.0, 0.0, 0.0], "scale": [1.0, 1.0, 1.0],
                         "rotationAxis": [1.0, 0.0, 0.0], "rotationAngle": 0.0,
                         "isDynamic": False, "isWall": True, "mapInvert": True, "mapThickness": 0.0,
                         "mapResolution": [20, 20, 20]}],
        "FluidBlocks": [{"denseMode": 0, "start": [float(v) for v in lo], "end": [float(v) for v in hi],
                         "translation": [0.0, 0.0, 0.0], "scale": [1.0, 1.0, 1.0], "initialVelocity": [0.0, 0.0, 0.0]}],
    }


# --------------------------------------------------------------------------------------------
# The comparison (parent process)
# --------------------------------------------------------------------------------------------
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
                          frames: int, threads: int, timeout: float | None = None) -> dict:
    """One SPlisHSPlasH case; returns a benchmark record (status "failed" with the reason on error)."""
    from . import metrics as M
    from .records import SCHEMA, host_info, now as _now

    params = {"engine": "splishsplash", "solver": solver, "dt": dt, "particle_radius": scene_dict["particle_radius"]}
    record = {"schema": SCHEMA, "kind": "splishsplash", "name": "splishsplash", "engine": "splishsplash",
              "label": f"splishsplash {solver}", "params": params, "date": _now(), "host": host_info(),
              "threads": threads, "device": "cpu", "device_name": "CPU", "scene": scene_dict, "status": "failed"}
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
        sj = scene_json(scene_dict, model, fluid_min, fluid_max, solver, dt, str(tmp / "box.obj"))
        (tmp / "scene.json").write_text(json.dumps(sj, indent=1))
        record["splishsplash_scene"] = sj
        cfg = {"scene_file": str(tmp / "scene.json"), "output_dir": str(tmp / "out"), "fps": scene_dict["fps"],
               "frames": frames, "dt": dt, "time_step": time_step_values(scene_dict, model, solver)}
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
    its = [float(i) for i in data["iterations"][1:] if np.isfinite(i)]
    series["solver_iterations"] = [None] + its if its else [None] * len(series["time"])
    if its:
        met["solver_iterations_mean"] = float(np.mean(its))
    record["metrics"] = met
    record["series"] = series
    record["status"] = "ok"
    return M.nan_to_none(record)


def default_dt(model: dict, solver: str, particle_radius: float) -> float:
    """WCSPH: warp-sph's acoustic CFL bound at cfl 0.4 with the reference speed, 0.4 (H_s/2)/(c_s + v_ref);
    PBF and DFSPH: 2 ms at r = 0.025 m, scaled with r."""
    if solver == "wcsph":
        return 0.4 * 0.5 * model["support_radius"] / (model["speed_of_sound"] + model["reference_speed"])
    return 0.002 * particle_radius / 0.025


def run_comparison(particle_radius: float = 0.025, frames: int = 25, threads: int = 1,
                   solvers=("wcsph", "pbf", "dfsph"), dt: dict | None = None, device=None, isolate: bool = True,
                   skip_warp_sph: bool = False, scene: str = "dam_break", splishsplash_gap: float | None = None,
                   warp_sph_overrides: list[str] | None = None, log=print) -> list[dict]:
    """Run the dam break in warp-sph (wcsph, pbf) and SPlisHSPlasH (wcsph, pbf, dfsph) with fixed steps.

    splishsplash_gap: None places SPlisHSPlasH's fluid on warp-sph's lattice (the same gap to the
    walls); a number moves its block so that the lattice sits that many spacings d from the walls it
    touches (SPlisHSPlasH's PBF blows up at t = 0 with fluid 1.1 d from its walls; 1.5 d is stable).
    warp_sph_overrides: scene overrides for warp-sph's runs only ("wcsph.*" keys for its WCSPH run,
    "pbf.*" keys for its PBF run, others for both); SPlisHSPlasH keeps the parameters (stiffness,
    time step) of the scene without them.
    """
    import warp as wp

    from warp_sph.core.model import build_model
    from warp_sph.scene.sampling import sample_scene
    from warp_sph.scene import load_scene

    from .cases import RunSpec, run_specs

    sc = load_scene(scene, overrides=[f"particle_radius={particle_radius}"])
    sampled = sample_scene(sc)
    model, _ = build_model(sc, sampled, wp.get_device("cpu"))
    summary = model.summary()
    # WCSPH's stiffness as warp-sph's WCSPH derives it (warp_sph.methods.solvers.wcsph)
    eos = sc.wcsph.equation_of_state
    summary["equation_of_state"] = eos
    summary["stiffness"] = (float(sc.wcsph.stiffness) if sc.wcsph.stiffness > 0 else
                            model.rest_density * model.speed_of_sound * model.speed_of_sound / (7.0 if eos == "tait" else 1.0))
    fx = np.asarray(sampled.fluid_x, dtype=np.float64)
    fmin, fmax = fx.min(axis=0), fx.max(axis=0)
    if splishsplash_gap is not None and sc.container is not None:
        lo = np.asarray(sc.container.min, dtype=np.float64)
        gap = fmin - lo
        shift = np.where(gap < 2.0 * sc.spacing, np.maximum(0.0, splishsplash_gap * sc.spacing - gap), 0.0)
        fmin, fmax = fmin + shift, fmax + shift
    dt = {k: v for k, v in (dt or {}).items() if v}
    frame_dt = 1.0 / float(sc.fps)
    dts = {}
    for s in solvers:
        target = dt.get(s) or (dt.get("pbf") if s == "dfsph" else None) or default_dt(summary, s, particle_radius)
        # a whole number of steps per frame, so warp-sph's frame loop takes exactly this step too
        dts[s] = frame_dt / math.ceil(frame_dt / target - 1e-9)
    records = []
    ok, why = available()
    if not ok:
        log(f"SPlisHSPlasH: not run: {why}")
    for s in solvers:
        if s in ("wcsph", "pbf") and not skip_warp_sph:
            own = [o for o in warp_sph_overrides or () if o.split("=", 1)[0].split(".", 1)[0] not in
                   ({"wcsph", "pbf"} - {s})]
            spec = RunSpec(scene=scene, overrides=[f"particle_radius={particle_radius}", f"solver={s}",
                                                   f"time.fixed_dt={dts[s]}", *own],
                           frames=frames, device=device, kind="splishsplash", name="splishsplash",
                           params={"engine": "warp-sph", "solver": s, "dt": dts[s], "particle_radius": particle_radius,
                                   **({"overrides": " ".join(own)} if own else {})})
            r = run_specs([spec], isolate=isolate, log=log)[0]
            r["label"] = f"warp-sph {s}" + (f" ({', '.join(own)})" if own else "")
            from warp_sph.core.launch import cpu_threads

            r["threads"] = cpu_threads()  # warp-sph splits particle-parallel CPU launches over these
            records.append(r)
        log(f"SPlisHSPlasH {s} (dt {dts[s]:.3g} s, OMP_NUM_THREADS={threads})")
        r = run_splishsplash_case(sc.to_dict(), summary, fmin, fmax, s, dts[s], frames, threads)
        r["params"]["fluid_gap"] = "warp-sph" if splishsplash_gap is None else f"{splishsplash_gap:g} d"
        if splishsplash_gap is not None:
            r["label"] += f" (fluid {splishsplash_gap:g} d from the walls)"
        from .records import print_row

        print_row(r, log)
        records.append(r)
    return records
