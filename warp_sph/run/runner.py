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
import math
import queue
import sys
import threading
import time
from pathlib import Path

import numpy as np
import warp as wp

from ..io import run_folder as rf
from ..core.device import resolve_device
from ..core.errors import OutputError, SimulationError, WarpSphError
from .checkpoints import check_checkpoint, checkpoint_info, scene_hash, versions
from .preflight import preflight_checks
from .simulation import Simulation

#: scenes whose float32 world coordinates would round positions by more than this fraction of the
#: particle radius are exported relative to their origin (USD) and recorded in float64 (frames)
WORLD_FLOAT32_TOLERANCE = 0.01


class Progress:
    """A one-line progress bar with ETA on stderr (plain lines every few seconds when not a TTY)."""

    def __init__(self, total: int, enabled: bool = True, stream=None, unit: str = "frames"):
        self.total = max(total, 1)
        self.unit = unit
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.perf_counter()
        self.last = 0.0
        self.done0 = None

    def update(self, done: int, info: str = "") -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.done0 is None:
            self.done0 = done
            self.t0 = now
        if not self.tty and now - self.last < 5.0 and done < self.total:
            return
        self.last = now
        elapsed = now - self.t0
        rate = (done - self.done0) / elapsed if elapsed > 0 and done > self.done0 else 0.0
        eta = (self.total - done) / rate if rate > 0 else float("nan")
        width = 28
        filled = int(width * done / self.total)
        bar = "#" * filled + "-" * (width - filled)
        eta_s = f"{eta:6.0f}s" if math.isfinite(eta) else "     ?s"
        line = f"[{bar}] {done}/{self.total} {self.unit}  {elapsed:6.1f}s elapsed  ETA {eta_s}  {info}"
        if self.tty:
            self.stream.write("\r" + line[:160].ljust(160))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()


class Exporter:
    """Writes each frame's outputs: recorded frame (npz), USD points + surface, mesh sequence."""

    def __init__(self, sim: Simulation, out: Path, resume_after_frame: int | None = None):
        self.sim = sim
        self.out = Path(out)
        o = sim.scene.output
        self.record = bool(o.record_frames)
        # far from (0, 0, 0): exact world positions need float64 (frames, meshes) or the USD origin
        self.far = world_float32_error(sim) > WORLD_FLOAT32_TOLERANCE * sim.model.particle_radius
        self.usd_path = usd_file(self.out, sim.scene.name)
        self.usd = None
        self.surface = None
        self.mesh_writer = None
        m = sim.model
        if o.surface and (o.usd or o.mesh_sequence):
            from ..surface.reconstruction import SurfaceReconstructor, surface_settings

            # split_threads off: it runs beside the simulation, which keeps every core busy
            self.surface = SurfaceReconstructor(m.smoothing.name, m.smoothing_length, m.particle_radius,
                                                device=sim.device, split_threads=False,
                                                **surface_settings(o, m.particle_radius))
        if o.usd:
            from ..io.reexport import scene_static_meshes
            from ..io.export_usd import UsdWriter

            statics = [] if resume_after_frame is not None else scene_static_meshes(sim.scene.to_dict())
            self.primvars = tuple(n for n in o.particle_primvars
                                  if n == "density" or (n == "pressure" and "particle_pressure" in sim.fields))
            self.usd = UsdWriter(self.usd_path, fps=sim.scene.fps,
                                 particle_radius=m.particle_radius, static_meshes=statics,
                                 primvars=self.primvars, with_surface=self.surface is not None,
                                 with_normals=self.surface is not None and self.surface.with_normals,
                                 with_spray=self.surface is not None and self.surface.grid.spray_neighbors > 0,
                                 resume_after_frame=resume_after_frame, overwrite=False,
                                 origin=m.origin if self.far else None)
            if sim.bodies is not None:  # mesh prims with a time-sampled transform (a resume only checks them)
                for name, geo in zip(sim.bodies.names, sim.bodies.geometries):
                    self.usd.add_body(name, geo.vertices, geo.triangles)
        if o.mesh_sequence and self.surface is not None:
            from ..io.export_mesh import MeshSequenceWriter

            (self.out / "mesh").mkdir(exist_ok=True)
            self.mesh_writer = MeshSequenceWriter(self.out / "mesh", o.mesh_sequence)
        if self.record:
            (self.out / "frames").mkdir(exist_ok=True)
        self.seconds = 0.0
        self.surface_seconds: dict[str, float] = {}  # filled with every stage on the first frame
        self.surface_counts = {"frames": 0, "triangles": 0, "vertices": 0, "spray": 0, "band_fallback": 0}

    def report(self) -> dict:
        """Per-frame export figures for run.json: USD bytes per frame, surface stage times [ms],
        mean triangle, vertex and spray counts."""
        out = {}
        if self.usd is not None and self.usd.frame_bytes:
            b = self.usd.frame_bytes
            out.update(usd_bytes_per_frame=float(np.mean(b)), usd_bytes_per_frame_max=int(max(b)),
                       usd_bytes_written=int(sum(b)), usd_write_ms=1e3 * float(np.mean(self.usd.write_seconds)))
        n = self.surface_counts["frames"]
        if n:
            out["surface_ms"] = {k: 1e3 * v / n for k, v in self.surface_seconds.items()}
            out.update({f"surface_{k}_per_frame": v / n for k, v in self.surface_counts.items() if k != "frames"})
        return out

    def snapshot(self, checkpoint: dict | None = None) -> dict:
        """Device copies of what a frame export needs (taken on the simulation thread).

        checkpoint: the host part of a checkpoint (``checkpoints.checkpoint_info``) to write after the frame.
        """
        f = self.sim.fields
        snap = {"x": wp.clone(f["particle_x"]), "v": wp.clone(f["particle_v"]),
                "density": wp.clone(f["particle_density"])}
        if "particle_pressure" in f:
            snap["pressure"] = wp.clone(f["particle_pressure"])
        if checkpoint is not None:
            snap["checkpoint"] = checkpoint
        if self.sim.bodies is not None:
            snap["bodies"] = self.sim.bodies.export_poses()
        return snap

    def write(self, frame: int, t: float, snap: dict) -> None:
        t0 = time.perf_counter()
        m = self.sim.model
        world = np.float64 if self.far else np.float32
        x_world = m.to_world(snap["x"].numpy())  # float64
        v = snap["v"].numpy()
        rho = snap["density"].numpy()
        surface = spray = None
        if self.surface is not None:
            # from the recorded world positions, re-localised as `warp-sph export` does, so a re-export
            # with the same settings gives this very surface (decimation amplifies 1-ulp differences)
            x_local = (x_world.astype(world).astype(np.float64) - m.origin).astype(np.float32)
            mesh = self.surface.reconstruct(wp.array(x_local, dtype=wp.vec3, device=self.sim.device))
            surface = (m.to_world(mesh.vertices), mesh.triangles, mesh.normals)
            spray = (x_world[mesh.spray], v[mesh.spray])
            for k, sec in mesh.timings.items():
                self.surface_seconds[k] = self.surface_seconds.get(k, 0.0) + sec
            c = self.surface_counts
            c["frames"] += 1
            c["triangles"] += len(mesh.triangles)
            c["vertices"] += len(mesh.vertices)
            c["spray"] += int(mesh.spray.sum())
            c["band_fallback"] += mesh.stats.get("band_fallback", 0)
        self._check_space(frame, len(x_world), surface, "checkpoint" in snap)
        if self.record:
            rf.atomic_save_npz(rf.frame_path(self.out, frame), x=x_world.astype(world), v=v, density=rho,
                               time=np.float64(t))
        if surface is not None and self.mesh_writer is not None:
            self.mesh_writer.write_frame(frame, surface[0].astype(world), surface[1])
        if self.usd is not None:
            primvars = {}
            for name in self.primvars:
                if name == "density":
                    primvars["density"] = rho
                elif name == "pressure" and "pressure" in snap:
                    primvars["pressure"] = snap["pressure"].numpy()
            self.usd.write_frame(frame, x_world, v, primvars=primvars, surface=surface, spray=spray,
                                 bodies=snap.get("bodies"))
        if "checkpoint" in snap:  # after the frame's outputs: checkpoint k implies frames <= k are saved
            (self.out / "checkpoints").mkdir(exist_ok=True)
            rf.atomic_save_npz(rf.checkpoint_path(self.out, frame), particle_x_local=snap["x"].numpy(),
                               particle_v=v, **snap["checkpoint"])
        self.seconds += time.perf_counter() - t0

    def _check_space(self, frame: int, n: int, surface, checkpoint: bool) -> None:
        """Refuse a frame (one line, nothing of it written) when the disk cannot hold its files: the
        recorded frame, mesh file, USD samples and checkpoint [bytes, generous estimates]."""
        per_particle = (40 if self.record else 0) + (32 if self.usd is not None else 0) + (28 if checkpoint else 0)
        need = n * per_particle + (1 << 16)
        if surface is not None:
            verts, tris = surface[0].shape[0], surface[1].shape[0]
            if self.usd is not None:
                need += 12 * verts + 16 * tris
            if self.mesh_writer is not None:
                need += 80 * verts + 40 * tris  # text OBJ: ~3 x 25 characters per vertex
        rf.check_free_space(self.out / "run.json", need, f"frame {frame}")

    def close(self) -> None:
        if self.usd is not None:
            self.usd.close()


def usd_file(out: Path, scene_name: str) -> Path:
    """The run's USD: ``out/<safe_name(scene name)>.usdc``, always inside ``out``."""
    return Path(out) / f"{rf.safe_name(scene_name)}.usdc"


def world_float32_error(sim: Simulation) -> float:
    """Largest rounding of a position [m] stored as float32 world coordinates: half an ulp at the
    largest |x| of the container (or the fluid's initial bounds, doubled about their centre,
    without one), |x| 2^-24."""
    m = sim.model
    if m.container_lo is not None:
        corners = np.stack([m.container_lo, m.container_hi]).astype(np.float64) + m.origin
    else:
        x = np.asarray(sim.sampled.fluid_x, dtype=np.float64)
        lo, hi = x.min(axis=0), x.max(axis=0)
        c, half = 0.5 * (lo + hi), (hi - lo)
        corners = np.stack([c - half, c + half])
    return float(np.abs(corners).max()) * 2.0**-24


class _ExportThread:
    """Runs Exporter.write on a worker thread, at most ``depth`` frames behind; re-raises its errors."""

    def __init__(self, exporter: Exporter, depth: int = 2):
        self.exporter = exporter
        self.q: queue.Queue = queue.Queue(maxsize=depth)
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._work, name="warp-sph-export", daemon=True)
        self.thread.start()

    def _work(self):
        while True:
            item = self.q.get()
            if item is None:
                return
            if self.error is None:
                try:
                    self.exporter.write(*item)
                except BaseException as e:  # reported on the simulation thread
                    self.error = e

    def submit(self, frame, t, snap):
        self.check()
        self.q.put((frame, t, snap))

    def check(self):
        if self.error is not None:
            self.reported = True
            raise self.error

    def finish(self):
        self.q.put(None)
        self.thread.join()
        if not getattr(self, "reported", False):  # raised once only (a submit may have raised it)
            self.check()


def run(scene, out: Path | None = None, device: str | None = None, frames: int | None = None,
        overwrite: bool = False, progress: bool = True, resume: Path | None = None,
        threaded_export: bool = True, log=print) -> dict:
    """Simulate ``scene`` into a run folder and return the run.json contents.

    frames: number of frames to write including the initial one (default duration * fps + 1).
    resume: a run folder to continue from its latest checkpoint (scene and folder come from it).
        Every check comes first (run.json, checkpoint, USD): a refused resume changes nothing; one
        that proceeds removes the files of frames after the checkpoint and says so. A finished
        run is reported as complete unless ``frames`` asks for more.

    Nothing is created before the scene, the device and the folder are known to be usable, and a
    start that fails before its first frame removes what it created.
    """
    from ..scene import scene_from_dict

    t_start = time.perf_counter()
    device = resolve_device(device)  # a bad --device is one line, before any folder exists
    resume_info = None
    if resume is not None:
        out = Path(resume)
        info = rf.read_run_json(out)
        scene = scene_from_dict(info["scene"], source=str(out / rf.RUN_JSON))
        frames = frames or info.get("frames_requested")
        total = frames if frames is not None else int(round(scene.duration * scene.fps)) + 1
        done = len(info.get("frames") or [])
        if info.get("status") == "completed" and done >= total:
            log(f"{out}: already complete ({done} frames); --frames N with N > {done} extends it")
            return info
        cp_path = rf.latest_checkpoint(out)
        if cp_path is None:
            raise OutputError(f"{out}: no checkpoint to resume from")
        resume_info = (info, cp_path, rf.load_checkpoint(cp_path))
    else:
        out = rf.choose_run_folder(out, scene.name, overwrite)
        total = frames if frames is not None else int(round(scene.duration * scene.fps)) + 1
    if total < 1:
        raise WarpSphError(f"--frames must be >= 1, got {total}")
    sim = Simulation(scene, device=device)
    preflight_checks(scene, sim)

    frame_log: list[dict] = []
    start_frame = 1
    created: list[Path] = []
    if resume_info is not None:
        info, cp_path, cp = resume_info
        check_checkpoint(cp, cp_path, info["scene"], sim, log=log)
        start_frame = int(cp["frame"])
        if total < start_frame:
            raise WarpSphError(f"{out}: its latest checkpoint is frame {start_frame}; resume with --frames >= {start_frame} "
                               f"(got {total})")
        sim.state.particle_x.assign(wp.array(cp["particle_x_local"], dtype=wp.vec3, device=sim.device))
        sim.state.particle_v.assign(wp.array(cp["particle_v"], dtype=wp.vec3, device=sim.device))
        sim.state.step = int(cp["step"])
        sim.state.frame = int(cp["state_frame"])
        sim.state.time = float(cp["time"])
        sim.solver.restore_arrays(cp)
        if sim.bodies is not None:
            sim.bodies.restore_arrays(cp)
        sim.refresh_density()
        sim.last_frame = sim.statistics()
        sim.last_frame.max_speed = float(cp["last_max_speed"])
        if "frame_log" in cp:
            frame_log = json.loads(str(cp["frame_log"]))
        else:
            frame_log = [f for f in info.get("frames", []) if f["frame"] <= start_frame]
        # the USD is checked (and cut back to the checkpoint) before any frame file is removed
        exporter = Exporter(sim, out, resume_after_frame=start_frame)
        dropped = rf.truncate_run(out, start_frame)
        later = sorted({rf._frame_number(p) for p in dropped})
        log(f"resuming {out} from frame {start_frame} (step {sim.state.step})"
            + (f"; removed {len(dropped)} files of frames {later[0]}..{later[-1]} written after it" if later else ""))
    else:
        if rf.is_run_folder(out):  # --overwrite (choose_run_folder refused it otherwise)
            rf.clear_run(out)
        created = rf.create_run_folder(out)
        try:
            exporter = Exporter(sim, out)
        except BaseException:
            _discard_start(out, created, usd_file(out, scene.name))
            raise

    worker = _ExportThread(exporter) if threaded_export else None
    checkpoint_every = int(scene.output.checkpoint_every)
    export_wait = [0.0]  # seconds the simulation thread spent on exports (snapshot, queue, drain)

    def export(frame, t):
        t0 = time.perf_counter()
        checkpoint = None
        if checkpoint_every > 0 and ((frame - 1) % checkpoint_every == 0 or frame == total):
            checkpoint = checkpoint_info(sim, frame, frame_log, digest)
        snap = exporter.snapshot(checkpoint)
        if worker is not None:
            worker.submit(frame, t, snap)
        else:
            exporter.write(frame, t, snap)
        export_wait[0] += time.perf_counter() - t0

    run_info = {
        "scene": scene.to_dict(), "versions": versions(), "device": str(sim.device),
        "model": sim.summary(), "fluid_particles": sim.model.fluid_count,
        "boundary_particles": sim.model.boundary_count, "frames_requested": total,
        "fps": scene.fps, "step_graph": [{"stage": s.name, "reads": list(s.reads), "writes": list(s.writes),
                                         "updates": list(s.updates), "doc": s.doc} for s in sim.graph.stages],
        "frames": frame_log, "status": "running", "out": str(out),
    }
    if resume_info is not None:
        run_info["scene"] = resume_info[0]["scene"]  # as stored: checkpoints hash it
    digest = scene_hash(run_info["scene"])

    def save_info(status):
        run_info["status"] = status
        run_info["simulated_time"] = sim.state.time
        run_info["steps"] = sim.state.step
        run_info["wall_time"] = time.perf_counter() - t_start
        run_info["stage_times"] = sim.graph.timing_table()
        run_info["export_time"] = exporter.seconds
        run_info["export_wait_time"] = export_wait[0]
        run_info["export"] = exporter.report()
        run_info["threaded_export"] = worker is not None
        # per step of this session, the first step apart: its stages load (or compile) the kernels
        rows = run_info["stage_times"]
        steps_here = max((t["calls"] for t in rows), default=0)
        run_info["first_step_time"] = sum(t["first_call_seconds"] for t in rows)
        steady = sum(t["seconds"] - t["first_call_seconds"] for t in rows)
        run_info["sim_time_per_step_ms"] = 1e3 * (steady / (steps_here - 1) if steps_here > 1
                                                  else run_info["first_step_time"])
        rf.atomic_write_json(out / rf.RUN_JSON, run_info)

    if exporter.far:
        log(f"note: the scene lies up to {world_float32_error(sim) * 2.0**24:.4g} m from (0, 0, 0), where float32 "
            f"world coordinates round positions by up to {world_float32_error(sim):.2g} m; the USD holds points "
            "relative to /sph's double-precision translate and recorded frames keep x in float64")
    bar = Progress(total, enabled=progress)
    status = "failed"
    started = resume_info is not None
    try:
        if resume_info is None:
            stats = sim.statistics()
            sim.check_health(stats)
            sim.last_frame = stats
            d = stats.to_dict()
            d["frame"] = 1
            frame_log.append(d)
            export(1, 0.0)
            save_info("running")
            started = True
        for frame in range(start_frame + 1, total + 1):
            stats = sim.advance_frame()
            sim.check_health(stats)
            d = stats.to_dict()
            d["frame"] = frame
            frame_log.append(d)
            export(frame, sim.state.time)
            save_info("running")
            # the same figure as the summary: the largest density error of any frame so far
            worst = max(f["density_error_max"] for f in frame_log)
            bar.update(frame, f"{stats.steps} steps/frame  max density error {100 * worst:.2f} %")
        status = "completed"
    except KeyboardInterrupt:
        status = "interrupted"
        raise
    except SimulationError:
        status = "failed"
        raise
    finally:
        bar.close()
        failing = status != "completed"  # an exception is on its way out
        errors: list[BaseException] = []
        if worker is not None:
            t0 = time.perf_counter()
            try:
                worker.finish()  # re-raises an export error (disk full, ...)
            except BaseException as exc:
                errors.append(exc)
            export_wait[0] += time.perf_counter() - t0
        try:
            exporter.close()
        except BaseException as exc:
            errors.append(exc)
        if errors and status == "completed":
            status = "failed"
        if started:
            try:
                save_info(status)
            except BaseException as exc:
                errors.append(exc)
        if not started and (failing or errors):
            _discard_start(out, created, usd_file(out, scene.name))
        if errors:
            if not failing:
                raise errors[0]
            for exc in errors:  # the first error is the one reported
                print(f"warp-sph: also: {exc}", file=sys.stderr)
    return run_info


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
