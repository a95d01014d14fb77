"""One case of a sweep: an ordinary run into ``DIR/<case>``, and its summary row.

``run_case`` runs in whichever process the executor picks (this one, or a Dask worker) and never
raises for a failed case: its row says ``status`` ("completed", "stopped" when the watchdog
stopped the run, "failed" for a bad value or any other error) and the one-line ``error``.
A case folder that holds a run of the same scene and frames that completed is not run again
(resume); one left incomplete (a killed worker, Ctrl-C) continues from its latest checkpoint, or
starts again when it has none; one holding a run of another scene is refused, never overwritten.
"""
from __future__ import annotations

import json
import os
import platform
import resource
import time
import warnings
from pathlib import Path

import numpy as np

#: the fields of a summary row, in order (sweep.jsonl holds one row per case); submitted, started,
#: finished, received: wall-clock times [s since the epoch] (started/finished where the case ran,
#: submitted/received on the client)
ROW_KEYS = ("case", "params", "scene", "status", "error", "folder", "fluid_particles", "frames", "steps",
            "simulated_time", "wall_time", "wall_per_simulated_second", "step_wall_per_simulated_second",
            "density_error_mean", "density_error_max", "front", "peak_rss_bytes", "peak_rss_scope",
            "host", "pid", "attempts", "submitted", "started", "finished", "received")


# --------------------------------------------------------------------------------------------
# Peak memory of one case in a long-lived process
# --------------------------------------------------------------------------------------------
def reset_peak_rss() -> bool:
    """Reset this process's resident-set high-water mark (VmHWM) to its current RSS (Linux
    /proc/self/clear_refs, "5"), so the peak after a case is that case's. False where unsupported."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def peak_rss_bytes() -> int:
    """VmHWM of this process [bytes] (Linux), else getrusage's ru_maxrss (the process's lifetime peak)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


# --------------------------------------------------------------------------------------------
# Metrics shared with the benchmarks (benchmarks/metrics.py re-exports them)
# --------------------------------------------------------------------------------------------
def surge_front(x: np.ndarray, wall: float = 0.0, axis: int = 0, quantile: float = 0.999) -> float:
    """Dam-break surge-front position [m]: the ``quantile`` of the particles' coordinate along
    ``axis`` (default: the 99.9th percentile of x, so the outermost 0.1 % of particles, single
    splashes, are ignored: the smallest value with at least that fraction of particles at or behind
    it, no interpolation into the outliers), measured from the wall at coordinate ``wall`` [m].

    x: positions [m], shape (n, 3) (or (n,) coordinates along ``axis``).
    """
    x = np.asarray(x, dtype=np.float64)
    coord = x[:, axis] if x.ndim == 2 else x
    if coord.size == 0:
        return float("nan")
    return float(np.quantile(coord, quantile, method="inverted_cdf") - wall)


def pareto_front(cost, error) -> list[bool]:
    """Which points are Pareto-optimal when both cost and error are to be minimised: no other point is
    at least as good in both and better in one. Points with a missing or non-finite value never are."""
    c = np.array([np.nan if v is None else v for v in cost], dtype=np.float64)
    e = np.array([np.nan if v is None else v for v in error], dtype=np.float64)
    ok = np.isfinite(c) & np.isfinite(e)
    out = []
    for i in range(len(c)):
        if not ok[i]:
            out.append(False)
            continue
        dominated = np.any(ok & (c <= c[i]) & (e <= e[i]) & ((c < c[i]) | (e < e[i])))
        out.append(not bool(dominated))
    return out


# --------------------------------------------------------------------------------------------
# The run folder of a case
# --------------------------------------------------------------------------------------------
def _json_roundtrip(obj):
    from ..io.atomic import to_json

    return json.loads(to_json(obj))


def requested_frames(case: dict, scene) -> int:
    return case["frames"] if case.get("frames") else int(round(scene.duration * scene.fps)) + 1


def folder_state(folder: Path, scene, frames: int) -> str:
    """"empty" (nothing there), "complete" (a completed run of this scene and frame count),
    "incomplete" (a run of this scene that did not finish), "leftovers" (files of a run killed
    before it wrote run.json), "other" (anything else)."""
    from ..io import run_folder as rf

    folder = Path(folder)
    if not folder.exists() or (folder.is_dir() and not any(folder.iterdir())):
        return "empty"
    if not rf.is_run_folder(folder):
        return "leftovers" if _run_leftovers(folder) is not None else "other"
    try:
        info = rf.read_run_json(folder)
    except Exception:  # noqa: BLE001 - an unreadable run.json (killed mid-write is impossible: atomic)
        return "other"
    if info.get("scene") != _json_roundtrip(scene.to_dict()):
        return "other"
    if info.get("status") == "completed" and info.get("frames_requested") == frames:
        return "complete"
    return "incomplete"


_RUN_SUBFOLDERS = {"frames": (".npz",), "checkpoints": (".npz",), "mesh": (".obj", ".ply", ".vtk")}


def _run_leftovers(folder: Path) -> list[Path] | None:
    """The files of a run killed before it wrote its run.json (the USD stage, frames, checkpoints,
    mesh files, temporary files of atomic writes), or None when the folder holds anything else."""
    files = []
    for p in Path(folder).iterdir():
        if p.is_dir() and p.name in _RUN_SUBFOLDERS:
            for q in p.iterdir():
                if not (q.is_file() and (q.suffix in _RUN_SUBFOLDERS[p.name] or q.name.startswith("."))):
                    return None
                files.append(q)
        elif p.is_file() and (p.suffix == ".usdc" or p.name.startswith(".")):
            files.append(p)
        else:
            return None
    return files


def _clear_leftovers(folder: Path) -> None:
    for p in _run_leftovers(folder) or []:
        p.unlink()
    for name in _RUN_SUBFOLDERS:
        d = Path(folder) / name
        if d.is_dir() and not any(d.iterdir()):
            d.rmdir()


def _front(folder: Path, scene, info: dict) -> float | None:
    """Surge front [m] at the last recorded frame, where defined: a container whose +x side the
    fluid did not fill at the start (a dam break); None otherwise or without recorded frames."""
    from ..io import run_folder as rf

    if scene.container is None or not info.get("frames"):
        return None
    first, last = rf.frame_path(folder, 1), rf.frame_path(folder, info["frames"][-1]["frame"])
    if not (first.is_file() and last.is_file()):
        return None
    x0 = np.load(first)["x"]
    if x0.size == 0 or x0[:, 0].max() > float(scene.container.max[0]) - 2.0 * scene.spacing:
        return None
    return surge_front(np.load(last)["x"], wall=float(scene.container.min[0]))


def row_from_run(folder: Path, scene) -> dict:
    """Summary values of a run folder's run.json (and its last recorded frame)."""
    from ..io import run_folder as rf

    info = rf.read_run_json(folder)
    frames = info.get("frames", [])
    sim_t = float(info.get("simulated_time") or 0.0)
    wall = float(info.get("wall_time") or 0.0)
    step_wall = sum(float(s.get("seconds", 0.0)) for s in info.get("stage_times") or [])
    later = frames[1:] or frames
    return {
        "fluid_particles": info.get("fluid_particles"), "frames": len(frames),
        "steps": sum(int(f.get("steps", 0)) for f in frames), "simulated_time": sim_t, "wall_time": wall,
        "wall_per_simulated_second": wall / sim_t if sim_t > 0 else None,
        "step_wall_per_simulated_second": step_wall / sim_t if sim_t > 0 else None,
        "density_error_mean": float(np.mean([f["density_error_mean"] for f in later])) if later else None,
        "density_error_max": float(max(f["density_error_max"] for f in frames)) if frames else None,
        "front": _front(Path(folder), scene, info),
    }


def _first_line(e: BaseException) -> str:
    lines = str(e).strip().splitlines()
    return lines[0] if lines else type(e).__name__


def run_case(task: dict) -> dict:
    """Run one case (``{"case": Case.to_dict(), "folder": path, "device": name or None}``) into its
    folder and return its summary row (``ROW_KEYS``). Never raises for a failed case."""
    from ..core.errors import SimulationError, WarpSphError

    case = task["case"]
    folder = Path(task["folder"])
    row = {k: None for k in ROW_KEYS}
    row.update(case=case["name"], params=case["params"], scene=Path(case["scene"]).stem, folder=str(folder),
               host=platform.node(), pid=os.getpid(), started=time.time(), status="failed")
    scoped = reset_peak_rss()
    scene = None
    try:
        from ..core.device import init_warp
        from ..run import runner

        init_warp()  # quiet, once per process
        from ..scene import load_scene
        from ..scene.unused import UnusedKeyWarning

        with warnings.catch_warnings():  # the sweep's own process said it of this case (driver.plan) already
            warnings.simplefilter("ignore", UnusedKeyWarning)
            scene = load_scene(case["scene"], overrides=list(case["overrides"]))
        frames = requested_frames(case, scene)
        state = folder_state(folder, scene, frames)
        if state == "other":
            raise WarpSphError(f"{folder} holds something other than a run of this case; "
                               f"move it away or choose another --out")
        from ..io import run_folder as rf

        if state == "complete":
            row["status"] = "completed"
        else:
            if state == "leftovers":  # killed before its run.json: start again
                _clear_leftovers(folder)
            folder.parent.mkdir(parents=True, exist_ok=True)
            quiet = dict(progress=False, log=lambda *a, **k: None)
            cp = rf.latest_checkpoint(folder) if state == "incomplete" else None
            if cp is not None and int(np.load(cp)["frame"]) <= frames:  # continue it (bitwise, on the CPU)
                runner.run(None, device=task.get("device"), frames=frames, resume=folder, **quiet)
            else:
                runner.run(scene, out=folder, device=task.get("device"), frames=frames, overwrite=True, **quiet)
            row["status"] = "completed"
    except SimulationError as e:
        row.update(status="stopped", error=_first_line(e))
    except WarpSphError as e:
        row["error"] = _first_line(e)
    except Exception as e:  # noqa: BLE001 - a failed case is a row, not the end of the sweep
        row["error"] = f"{type(e).__name__}: {_first_line(e)}"
    row["peak_rss_bytes"] = peak_rss_bytes()
    row["peak_rss_scope"] = "case" if scoped else "process"
    if scene is not None and (folder / "run.json").is_file():
        try:
            row.update(row_from_run(folder, scene))
        except Exception as e:  # noqa: BLE001 - keep the status; say why the numbers are missing
            row["error"] = row["error"] or f"summary: {type(e).__name__}: {_first_line(e)}"
    row["finished"] = time.time()
    return row
