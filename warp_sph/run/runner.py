"""Runner: frames at the export rate, CFL substeps, progress, watchdog, exports, checkpoints, resume.

Frame k (k = 1, 2, ...) is the state at t = (k - 1) / fps; frame 1 is the initial state. Exports of
frame k run on a background thread while frame k + 1 is simulated (a CPU ``wp.launch`` releases
the GIL), with at most two frames in flight.

Checkpoints are written by the exporter too, right after the frame's own outputs, from copies of
the state taken on the simulation thread. So checkpoint k on disk implies that frames 1..k are
in frames/, in the USD and in the mesh sequence, and a resume from it (after Ctrl-C, a crash or
SIGKILL) finds every output it continues. On the CPU a resumed run reproduces an uninterrupted
one bit for bit (tests/test_run_outputs.py).
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import warp as wp

from ..io import atomic
from ..io import run_folder as rf
from ..io.probe_files import ProbeFiles
from ..core.device import resolve_device
from .working_set import array_bytes, read_bytes
from ..core.errors import OutputError, SimulationError, WarpSphError
from .checkpoints import check_checkpoint, checkpoint_info, scene_hash, versions
from .preflight import preflight_checks
from .simulation import Simulation
from .exporter import WORLD_FLOAT32_TOLERANCE, Exporter, ExportThread, usd_file, world_float32_error
from .progress import Progress
from .settle import settle

__all__ = ["Exporter", "Progress", "WORLD_FLOAT32_TOLERANCE", "run", "usd_file", "versions", "world_float32_error"]


def run(scene, out: Path | None = None, device: str | None = None, frames: int | None = None,
        overwrite: bool = False, progress: bool = True, resume: Path | None = None,
        threaded_export: bool = True, log=print) -> dict:
    """Simulate ``scene`` into a run folder and return the run.json contents.

    frames: number of frames to write including the initial one (default duration * fps + 1).
    resume: a run folder to continue from its latest checkpoint (scene and folder come from it).
        Every check comes first (run.json, checkpoint, USD): a refused resume changes nothing; one
        that proceeds removes the files of frames after the checkpoint and says so. A finished
        run is reported as complete unless ``frames`` asks for more. A run stopped before its first
        checkpoint (killed in its first second: it had saved no frame after the initial one) starts
        again from frame 1 in its folder, with its scene, and says so: its run files are replaced,
        nothing else. With ``output.checkpoint_every = 0`` a resume is refused.

    Nothing is created before the scene, the device and the folder are known to be usable, and a
    start that fails before its first frame removes what it created.
    """
    t_start = time.perf_counter()
    device = resolve_device(device)  # a bad --device is one line, before any folder exists
    resume_info = None
    restart = ""  # why a --resume starts the run again from frame 1 (it has no checkpoint)
    if resume is not None:
        out = Path(resume)
        scene, total, info = _read_resume(out, frames)
        done = len(info.get("frames") or [])
        if info.get("status") == "completed" and done >= total:
            log(f"{out}: already complete ({done} frames); --frames N with N > {done} extends it")
            return info
        cp_path = rf.latest_checkpoint(out)
        if cp_path is None and scene.output.checkpoint_every == 0:
            raise OutputError(f"{out}: no checkpoint to resume from (output.checkpoint_every = 0); pass the "
                              f"scene with --out {out} --overwrite to run it again from frame 1")
        if cp_path is None:  # checkpoint 1 comes with frame 1: it stopped before its first frame was saved
            restart = "it stopped before its first one"
        else:
            resume_info = (info, cp_path, rf.load_checkpoint(cp_path))
    else:
        out = rf.choose_run_folder(out, scene.name, overwrite)
        total = frames if frames is not None else _default_frames(scene)
    if total < 1:
        raise WarpSphError(f"--frames must be >= 1, got {total}")
    sim = Simulation(scene, device=device)
    preflight_checks(scene, sim, frames=frames)

    created: list[Path] = []
    settled = None  # the packing pass's record (time.settle; a fresh run only)
    if resume_info is not None:
        start_frame, frame_log, exporter = _resume_start(sim, out, total, *resume_info, log=log)
        # the frames' timings up to the checkpoint, as the interrupted run measured them (none before they were kept)
        frame_times = [t for t in resume_info[0].get("frame_times", []) if int(t["frame"]) <= start_frame]
        probe_files = None  # the probes' CSV files (``warp_sph.io.probe_files``)
        if sim.probes is not None:  # rows after the checkpoint's time go; sampling continues after it
            probe_files = ProbeFiles.resume(out, sim.probes.lines, scene.name, sim.state.time)
            sim.probes.restart(sim.state.time)
    else:
        if restart:
            log(f"{out}: no checkpoint to resume from ({restart}): running it again from frame 1 with the scene "
                f"of its {rf.RUN_JSON}, replacing its run files")
        settled = settle(sim, log)  # time.settle: the packing pass before t = 0 (None: off)
        start_frame, frame_log, frame_times = 1, [], []
        exporter, created, probe_files = _fresh_outputs(sim, out, scene, total)

    worker = ExportThread(exporter) if threaded_export else None
    checkpoint_every = int(scene.output.checkpoint_every)
    # seconds the simulation thread spent on exports: [writing them (unthreaded; threaded: the
    # worker's waits for queue room are added), draining it after the last step, copying snapshots]
    export_wait = [0.0, 0.0, 0.0]

    def export(frame, t):
        t0 = time.perf_counter()
        checkpoint = None
        if checkpoint_every > 0 and ((frame - 1) % checkpoint_every == 0 or frame == total):
            checkpoint = checkpoint_info(sim, frame, frame_log, digest)
        snap = exporter.snapshot(checkpoint)
        t1 = time.perf_counter()
        export_wait[2] += t1 - t0
        if worker is not None:
            worker.submit(frame, t, snap)  # its waits for room in the queue: worker.blocked_seconds
        else:
            exporter.write(frame, t, snap)
            export_wait[0] += time.perf_counter() - t1

    run_info = _run_info(scene, sim, total, frame_log, out)
    if resume_info is None and settled is not None:
        run_info["settle"] = settled
    if resume_info is not None:
        run_info["scene"] = resume_info[0]["scene"]  # as stored: checkpoints hash it
    digest = scene_hash(run_info["scene"])

    def save_info(status):
        run_info["status"] = status
        run_info["simulated_time"] = sim.state.time
        run_info["steps"] = sim.state.step
        run_info["wall_time"] = time.perf_counter() - t_start
        run_info["stage_times"] = sim.graph.timing_table()
        run_info["frame_times"] = frame_times
        if status != "running":  # once, at the end (read_bytes reads the lists' counts back from the device)
            run_info["array_bytes"] = array_bytes(sim)  # the arrays' allocation (``working_set``)
            run_info["read_bytes"] = read_bytes(sim)  # what the steps read of them, against the CPU's caches
        if sim.graph.frame_timings:  # per-frame work outside the substeps (emitters and sinks)
            run_info["frame_stage_times"] = sim.graph.frame_timing_table()
        run_info["export_time"] = exporter.seconds
        run_info["export_wait_time"] = export_wait[0] + (worker.blocked_seconds if worker is not None else 0.0)
        run_info["export_tail_time"] = export_wait[1]
        run_info["export_snapshot_time"] = export_wait[2]
        run_info["export"] = exporter.report()
        run_info["threaded_export"] = worker is not None
        _step_times(run_info)
        if sim.scene.plan is not None:  # made from a plan (warp-sph plan --apply): its prediction beside the run
            from ..plan.compare import compare_with_plan

            run_info["plan"] = compare_with_plan(sim.scene.plan, run_info, out)
        if probe_files is not None:
            run_info["probes"] = probe_files.summary(sim.probes.skipped())
        atomic.atomic_write_json(out / rf.RUN_JSON, run_info)

    if exporter.far:
        _note_far_from_origin(sim, log)
    bar = Progress(total, enabled=progress)
    status = "failed"
    started = resume_info is not None
    interrupted = None
    try:
        if resume_info is None:
            stats = sim.statistics()
            sim.check_health(stats)
            sim.last_frame = stats
            d = stats.to_dict()
            d["frame"] = 1
            frame_log.append(d)
            if probe_files is not None:
                sim.probes.sample_now(0.0, start=True)
                probe_files.append(sim.probes.collect())
            export(1, 0.0)
            save_info("running")
            started = True
        for frame in range(start_frame + 1, total + 1):
            t_frame, before, cpu = time.perf_counter(), _stage_seconds(sim), time.process_time()
            first_step = not any(t.calls for t in sim.graph.timings.values())  # this frame loads the kernels
            stats = sim.advance_frame()
            sim.check_health(stats)
            d = stats.to_dict()
            d["frame"] = frame
            # this frame's own timing, apart from the frame log (which a resumed run reproduces bitwise)
            frame_times.append(frame_timing(frame, stats.steps, time.perf_counter() - t_frame,
                                            _stage_seconds(sim) - before, time.process_time() - cpu, first_step))
            if sim.whitewater is not None:  # live spray / foam / bubbles, generated and dropped so far
                d["whitewater"] = sim.whitewater.frame_record()
            frame_log.append(d)
            if probe_files is not None:  # before the frame's checkpoint is queued: its rows are on disk
                probe_files.append(sim.probes.collect())
            export(frame, sim.state.time)
            save_info("running")
            # the same figure as the summary: the largest density error of any frame so far
            worst = max(f["density_error_max"] for f in frame_log)
            bar.update(frame, f"{stats.steps} steps/frame  max density error {100 * worst:.2f} %")
        status = "completed"
    except KeyboardInterrupt as exc:
        status = "interrupted"
        interrupted = exc
        raise
    except SimulationError:
        status = "failed"
        raise
    finally:
        bar.close()
        failing = status != "completed"  # an exception is on its way out
        errors = _close_outputs(worker, exporter, export_wait)
        if errors and status == "completed":
            status = "failed"
        if started:
            try:
                save_info(status)
            except BaseException as exc:
                errors.append(exc)
        if not started and (failing or errors):
            _discard_start(out, created, usd_file(out, scene.name))
        if interrupted is not None and started:  # where a resume restarts (the CLI's interrupt line says it)
            interrupted.resume_hint = _resume_hint(out, frame_log[-1]["frame"] if frame_log else 0)
        if errors:
            if not failing:
                raise errors[0]
            for exc in errors:  # the first error is the one reported
                print(f"warp-sph: also: {exc}", file=sys.stderr)
    return run_info


def _resume_hint(out: Path, last: int) -> str | None:
    """What ``--resume`` of the interrupted run in ``out`` does, whose last frame written is ``last``: it
    restarts from the latest checkpoint, and computes the frames after it again (it removes their files)."""
    cp = rf.latest_checkpoint(out)
    if cp is None:
        return None
    k = rf._frame_number(cp)
    again = f" (frames {k + 1}..{last} are computed again)" if last > k else ""
    return f"warp-sph run --resume {out} continues from its checkpoint of frame {k}{again}"


def _default_frames(scene) -> int:
    """Frames of a whole run, the initial one included: duration * fps + 1."""
    return int(round(scene.duration * scene.fps)) + 1


def _read_resume(out: Path, frames: int | None) -> tuple:
    """(scene, total frames, run.json) of the run in ``out``: the scene as run.json stores it; frames
    as given, else as that run requested, else the whole duration."""
    from ..scene import scene_from_dict

    info = rf.read_run_json(out)
    scene = scene_from_dict(info["scene"], source=str(out / rf.RUN_JSON))
    frames = frames or info.get("frames_requested")
    total = frames if frames is not None else _default_frames(scene)
    return scene, total, info


def _note_far_from_origin(sim: Simulation, log) -> None:
    """Say how much float32 world coordinates would round a scene far from the origin, and that the
    outputs avoid it."""
    log(f"note: the scene lies up to {world_float32_error(sim) * 2.0**24:.4g} m from (0, 0, 0), where float32 "
        f"world coordinates round positions by up to {world_float32_error(sim):.2g} m; the USD holds points "
        "relative to /sph's double-precision translate and recorded frames keep x in float64")


def _resume_start(sim: Simulation, out: Path, total: int, info: dict, cp_path: Path, cp, log) -> tuple:
    """(start frame, frame log, exporter) of a resume: the checkpoint checked against ``sim`` and the
    frames asked for, its state restored, the outputs cut back to it."""
    check_checkpoint(cp, cp_path, info["scene"], sim, log=log)
    start_frame = int(cp["frame"])
    if total < start_frame:
        raise WarpSphError(f"{out}: its latest checkpoint is frame {start_frame}; resume with --frames >= {start_frame} "
                           f"(got {total})")
    frame_log = _restore_state(sim, cp, info, start_frame)
    return start_frame, frame_log, _resume_outputs(sim, out, start_frame, log)


def _restore_state(sim: Simulation, cp, info: dict, start_frame: int) -> list[dict]:
    """Put checkpoint ``cp`` into ``sim``: x (model frame), v, step, frame, time, the solver's and the
    bodies' arrays, the density and the last frame's statistics (with the max speed that sizes the
    next substep). Returns the frame log up to ``start_frame`` (the checkpoint's, else run.json's)."""
    if sim.flow is not None:  # the checkpoint's active count, ids and emitter state first
        sim.flow.restore_arrays(cp)
    sim.state.particle_x.assign(wp.array(cp["particle_x_local"], dtype=wp.vec3, device=sim.device))
    sim.state.particle_v.assign(wp.array(cp["particle_v"], dtype=wp.vec3, device=sim.device))
    sim.state.step = int(cp["step"])
    sim.state.frame = int(cp["state_frame"])
    sim.state.time = float(cp["time"])
    sim.solver.restore_arrays(cp)
    sim.forces.restore_arrays(cp)
    if sim.bodies is not None:
        sim.bodies.restore_arrays(cp)
    for part in sim.parts:  # the others (emitters and sinks came first, above): obstacles, whitewater
        if part is not sim.flow:
            part.restore_arrays(cp)
    sim.refresh_density()
    sim.last_frame = sim.statistics()
    sim.last_frame.max_speed = float(cp["last_max_speed"])
    if "frame_log" in cp:
        return json.loads(str(cp["frame_log"]))
    return [f for f in info.get("frames", []) if f["frame"] <= start_frame]


def _resume_outputs(sim: Simulation, out: Path, start_frame: int, log) -> Exporter:
    """The exporter of a resumed run; then the files of frames after ``start_frame`` are removed (said
    in the log). The USD is checked (and cut back to the checkpoint) before any frame file goes."""
    exporter = Exporter(sim, out, resume_after_frame=start_frame)
    dropped = rf.truncate_run(out, start_frame)
    later = sorted({rf._frame_number(p) for p in dropped})
    log(f"resuming {out} from frame {start_frame} (step {sim.state.step})"
        + (f"; removed {len(dropped)} files of frames {later[0]}..{later[-1]} written after it" if later else ""))
    return exporter


def _fresh_outputs(sim: Simulation, out: Path, scene, total: int) -> tuple[Exporter, list[Path], ProbeFiles | None]:
    """(exporter, folders created, probe CSV files or None) of a new run in ``out``: a previous run there is cleared (--overwrite,
    or a --resume that restarts; ``choose_run_folder`` refused it otherwise); run.json is written first, so
    a run killed from here on leaves a folder that --resume (or --overwrite) takes; if the exporter cannot
    start, what was created goes."""
    if rf.is_run_folder(out):
        rf.clear_run(out)
    created = rf.create_run_folder(out)
    try:
        atomic.atomic_write_json(out / rf.RUN_JSON, {"scene": scene.to_dict(), "versions": versions(),
                                                      "frames_requested": total, "frames": [], "status": "starting",
                                                      "out": str(out)})
        exporter = Exporter(sim, out)
        probe_files = ProbeFiles.create(out, sim.probes.lines, scene.name) if sim.probes is not None else None
        return exporter, created, probe_files
    except BaseException:
        _discard_start(out, created, usd_file(out, scene.name))
        raise


def _run_info(scene, sim: Simulation, total: int, frame_log: list[dict], out: Path) -> dict:
    """run.json at the start: the scene, versions, device, model, particle counts, the step graph's
    stages, the frame log (the same list the run appends to), status "running"."""
    return {
        "scene": scene.to_dict(), "versions": versions(), "device": str(sim.device),
        "model": sim.summary(), "fluid_particles": sim.model.fluid_count,
        "boundary_particles": sim.model.boundary_count, "frames_requested": total,
        "fps": scene.fps, "step_graph": [{"stage": s.name, "reads": list(s.reads), "writes": list(s.writes),
                                         "updates": list(s.updates), "doc": s.doc} for s in sim.graph.stages],
        "frames": frame_log, "status": "running", "out": str(out),
    }


def frame_timing(frame: int, steps: int, wall: float, step_seconds: float, cpu: float = 0.0,
                 first_step: bool = False) -> dict:
    """One entry of run.json ``frame_times``: the frame's number, its substeps, its wall time [s] (``advance_frame``:
    the substeps, the cell-order sort, the statistics, a redone frame's steps), its steps' stage time [s], the
    process's CPU time over the frame [s] (every thread: the export thread's too) and ``first_step``: whether it holds
    the process's first step, whose kernel loads (``first_step_time``) its stage time includes (not after a
    ``time.settle`` pass, which stepped first). A median over the frames' step time is robust to a load spike where
    the run's mean (``sim_time_per_step_ms``) is not (``warp_sph.plan.points``)."""
    return {"frame": int(frame), "steps": int(steps), "wall_time": float(wall), "step_seconds": float(step_seconds),
            "cpu_time": float(cpu), "first_step": bool(first_step)}


def _stage_seconds(sim) -> float:
    """[s] the step stages' wall time so far in this process (``StepGraph.timings``, every call)."""
    return sum(t.seconds for t in sim.graph.timings.values())


def _step_times(run_info: dict) -> None:
    """first_step_time [s] and sim_time_per_step_ms from run_info's stage_times: per step of this
    session, the first step apart (its stages load or compile the kernels)."""
    rows = run_info["stage_times"]
    steps_here = max((t["calls"] for t in rows), default=0)
    run_info["first_step_time"] = sum(t["first_call_seconds"] for t in rows)
    steady = sum(t["seconds"] - t["first_call_seconds"] for t in rows)
    run_info["sim_time_per_step_ms"] = 1e3 * (steady / (steps_here - 1) if steps_here > 1
                                              else run_info["first_step_time"])


def _close_outputs(worker: ExportThread | None, exporter: Exporter, export_wait: list[float]) -> list[BaseException]:
    """Drain the export thread (its wait added to ``export_wait[1]``) and close the exporter; the errors
    either raised (an export error such as a full disk is re-raised by the thread), in order."""
    errors: list[BaseException] = []
    if worker is not None:
        t0 = time.perf_counter()
        try:
            worker.finish()  # re-raises an export error (disk full, ...)
        except BaseException as exc:
            errors.append(exc)
        export_wait[1] += time.perf_counter() - t0
    try:
        exporter.close()
    except BaseException as exc:
        errors.append(exc)
    return errors


def _discard_start(out: Path, created: list[Path], usd: Path) -> None:
    """Remove what a start that failed before its first frame wrote: the run's own files and the
    folders it created (a folder that existed before stays, and so does any other file)."""
    rf.remove_files([usd] + rf.run_files(out))
    for sub in ("frames", "checkpoints", "mesh"):
        try:
            (Path(out) / sub).rmdir()
        except OSError:
            pass
    rf.remove_new_folders(created)
