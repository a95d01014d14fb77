"""The SPlisHSPlasH side of ``warp-sph bench splishsplash``: runs inside a subprocess started with
``LD_PRELOAD`` (``splishsplash_case._env``), as ``python splishsplash_driver.py CONFIG.json OUT.npz``:
simulate the translated scene, record positions, velocities and densities per frame.
Imports only the standard library and NumPy (and ``pysplishsplash``), never Warp.

Memory: the peak RSS of the case (``peak_memory.MemoryWindow``: VmHWM reset after ``import pysplishsplash``,
read after the run, before the frames are gathered) goes into the record. So that the driver's own recording
does not count as SPlisHSPlasH's memory, each frame's arrays go to a file beside OUT.npz (``OUT_frames.bin``) at once
and are read back only after the peak was read.
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

    from peak_memory import MemoryWindow  # a sibling module: this file runs as a script

    window = MemoryWindow().open()  # the baseline: Python, NumPy and SPlisHSPlasH's libraries loaded
    frame_file = open(out.with_name(out.stem + "_frames.bin"), "wb")
    frame_dt = 1.0 / float(cfg["fps"])
    frames = int(cfg["frames"])
    stop = frames * frame_dt + 0.5 * float(cfg["dt"])
    base = sph.Exec.SimulatorBase()
    base.init(useGui=False, sceneFile=cfg["scene_file"], outputDir=cfg["output_dir"], useCache=False,
              initialPause=False, stopAt=stop)
    rec = {"n": [], "t": [], "steps": [], "iterations": [], "iterations_v": [], "cb": 0.0,
           "cb_cpu": 0.0}
    state = {"steps": 0, "next": frame_dt}

    def grab(t):
        sim = sph.Simulation.getCurrent()
        f = sim.getFluidModel(0)
        n = f.numActiveParticles()
        for name in ("position", "velocity", "density"):  # to the file now, read back after the peak
            frame_file.write(np.ascontiguousarray(np.asarray(f.getFieldBuffer(name))[:n], dtype=np.float32).tobytes())
        rec["n"].append(n)
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
    info["memory"] = window.close(info["fluid_particles"])  # before cleanup and before the frames are read back
    base.cleanup()
    frame_file.close()
    info.update(setup_seconds=setup, wall_seconds=wall, cpu_seconds=cpu, steps=state["steps"],
                simulated_seconds=float(state.get("time", 0.0)))
    x, v, rho = read_frames(Path(frame_file.name), rec["n"])
    Path(frame_file.name).unlink()
    np.savez(out, x=x, v=v, rho=rho,
             t=np.asarray(rec["t"]), steps=np.asarray(rec["steps"]), iterations=np.asarray(rec["iterations"]),
             iterations_v=np.asarray(rec["iterations_v"]), info=json.dumps(info))
    return 0


def read_frames(path: Path, counts: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frames ``grab`` wrote to ``path``: per frame n x 3 positions, n x 3 velocities, n densities (float32);
    stacked (frames, n, 3), (frames, n, 3), (frames, n) (every frame has the first frame's n particles)."""
    data = np.fromfile(path, dtype=np.float32)
    n = counts[0]
    frames = data.reshape(len(counts), 7 * n)
    return (frames[:, :3 * n].reshape(-1, n, 3), frames[:, 3 * n:6 * n].reshape(-1, n, 3), frames[:, 6 * n:])


if __name__ == "__main__":
    if len(sys.argv) == 3:
        sys.exit(driver_main(sys.argv[1:]))
    print("usage: splishsplash_driver.py CONFIG.json OUT.npz (internal; use 'warp-sph bench splishsplash')")
    sys.exit(2)
