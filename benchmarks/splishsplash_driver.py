"""The SPlisHSPlasH side of ``warp-sph bench splishsplash``: runs inside a subprocess started with
``LD_PRELOAD`` (``splishsplash_case._env``), as ``python splishsplash_driver.py CONFIG.json OUT.npz``:
simulate the translated scene, record positions, velocities and densities per frame.
Imports only the standard library and NumPy (and ``pysplishsplash``), never Warp.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np


def driver_main(argv: list[str]) -> int:
    """drive CONFIG.json OUT.npz: simulate, record positions/velocities/densities per frame."""
    cfg = json.loads(Path(argv[0]).read_text())
    out = Path(argv[1])
    import pysplishsplash as sph

    frame_dt = 1.0 / float(cfg["fps"])
    frames = int(cfg["frames"])
    stop = frames * frame_dt + 0.5 * float(cfg["dt"])
    base = sph.Exec.SimulatorBase()
    base.init(useGui=False, sceneFile=cfg["scene_file"], outputDir=cfg["output_dir"], useCache=False,
              initialPause=False, stopAt=stop)
    rec = {"x": [], "v": [], "rho": [], "t": [], "steps": [], "iterations": [], "iterations_v": [], "cb": 0.0,
           "cb_cpu": 0.0}
    state = {"steps": 0, "next": frame_dt}

    def grab(t):
        sim = sph.Simulation.getCurrent()
        f = sim.getFluidModel(0)
        n = f.numActiveParticles()
        rec["x"].append(np.array(np.asarray(f.getFieldBuffer("position"))[:n], dtype=np.float32))
        rec["v"].append(np.array(np.asarray(f.getFieldBuffer("velocity"))[:n], dtype=np.float32))
        rec["rho"].append(np.array(np.asarray(f.getFieldBuffer("density"))[:n], dtype=np.float32))
        rec["t"].append(t)
        rec["steps"].append(state["steps"])
        its = state.pop("its", [])
        rec["iterations"].append(float(np.mean(its)) if its else np.nan)
        its_v = state.pop("its_v", [])
        rec["iterations_v"].append(float(np.mean(its_v)) if its_v else np.nan)

    def on_step():
        c0 = time.perf_counter()
        p0 = time.process_time()
        state["steps"] += 1
        if state["steps"] == 1:  # boundary models exist only once the run has started
            sim = sph.Simulation.getCurrent()
            info["boundary_models"] = int(sim.numberOfBoundaryModels())
            if info["boundary_models"]:
                info["boundary_particles"] = int(sim.getBoundaryModel(0).numberOfParticles())
        t = sph.TimeManager.getCurrent().getTime()
        state["time"] = t
        ts = sph.Simulation.getCurrent().getTimeStep()
        for key, name in (("its", "SOLVER_ITERATIONS"), ("its_v", "SOLVER_ITERATIONS_V")):
            if hasattr(ts, name):
                try:
                    state.setdefault(key, []).append(ts.getValueUInt(getattr(ts, name)))
                except Exception:
                    pass
        if t >= state["next"] - 1e-9 * frame_dt:
            grab(t)
            state["next"] += frame_dt
        rec["cb"] += time.perf_counter() - c0
        rec["cb_cpu"] += time.process_time() - p0

    base.setTimeStepCB(on_step)
    t0 = time.perf_counter()
    base.initSimulation()
    setup = time.perf_counter() - t0
    sim = sph.Simulation.getCurrent()
    f = sim.getFluidModel(0)
    ts = sim.getTimeStep()
    applied = {}
    for name, value in (cfg.get("time_step") or {}).items():
        pid = getattr(ts, name)
        if isinstance(value, bool):
            ts.setValueBool(pid, value)
            applied[name] = bool(ts.getValueBool(pid))
        elif isinstance(value, int):
            try:
                ts.setValueUInt(pid, value)
                applied[name] = int(ts.getValueUInt(pid))
            except Exception:
                ts.setValueInt(pid, value)
                applied[name] = int(ts.getValueInt(pid))
        else:
            ts.setValueFloat(pid, float(value))
            applied[name] = float(ts.getValueFloat(pid))
    info = {"time_step_parameters": applied, "time_step_class": type(ts).__name__, "fluid_particles": int(f.numActiveParticles()),
            "mass": float(f.getMass(0)), "rest_density": float(f.getDensity0()),
            "simulation_method": int(sim.getSimulationMethod()),
            "boundary_handling": str(sim.getBoundaryHandlingMethod())}
    grab(0.0)
    t1 = time.perf_counter()
    c1 = time.process_time()
    base.runSimulation()
    wall = time.perf_counter() - t1 - rec["cb"]
    cpu = time.process_time() - c1 - rec["cb_cpu"]
    base.cleanup()
    info.update(setup_seconds=setup, wall_seconds=wall, cpu_seconds=cpu, steps=state["steps"],
                simulated_seconds=float(state.get("time", 0.0)))
    np.savez(out, x=np.stack(rec["x"]), v=np.stack(rec["v"]), rho=np.stack(rec["rho"]),
             t=np.asarray(rec["t"]), steps=np.asarray(rec["steps"]), iterations=np.asarray(rec["iterations"]),
             iterations_v=np.asarray(rec["iterations_v"]), info=json.dumps(info))
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 3:
        sys.exit(driver_main(sys.argv[1:]))
    print("usage: splishsplash_driver.py CONFIG.json OUT.npz (internal; use 'warp-sph bench splishsplash')")
    sys.exit(2)
