"""A run's outputs for each frame: ``Exporter`` writes frames/*.npz, the USD time samples, the surface
mesh sequence and the checkpoints from a snapshot taken on the simulation thread; ``ExportThread``
runs it on a background thread, behind the simulation by as many frames as ``SNAPSHOT_QUEUE_BYTES``
of snapshots hold (see ``runner.py``).
"""
from __future__ import annotations

import queue
import threading
import time
from pathlib import Path

import numpy as np
import warp as wp

from ..io import atomic
from ..io import run_folder as rf
from .memory import SNAPSHOT_QUEUE_BYTES
from .simulation import Simulation


#: scenes whose float32 world coordinates would round positions by more than this fraction of the
#: particle radius are exported relative to their origin (USD) and recorded in float64 (frames)
WORLD_FLOAT32_TOLERANCE = 0.01


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

            # split over the CPU threads unless an ExportThread runs it beside the simulation (use_all_cores)
            self.surface = SurfaceReconstructor(m.smoothing.name, m.smoothing_length, m.particle_radius,
                                                device=sim.device, **surface_settings(o, m.particle_radius))
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
                                 with_whitewater=sim.whitewater is not None,
                                 whitewater_width=(float(sim.scene.whitewater.point_width) * m.particle_radius
                                                   if sim.whitewater is not None else 0.0),
                                 resume_after_frame=resume_after_frame, overwrite=False,
                                 origin=m.origin if self.far else None)
            if sim.bodies is not None:  # mesh prims with a time-sampled transform (a resume only checks them)
                for name, geo in zip(sim.bodies.names, sim.bodies.geometries):
                    self.usd.add_body(name, geo.vertices, geo.triangles)
            if sim.colliders is not None:  # animated obstacles: the same prims, in their local frames
                for c in sim.colliders.colliders:
                    self.usd.add_body(c.name, c.vertices, c.triangles)
        if o.mesh_sequence and self.surface is not None:
            from ..io.export_mesh import MeshSequenceWriter

            (self.out / "mesh").mkdir(exist_ok=True)
            self.mesh_writer = MeshSequenceWriter(self.out / "mesh", o.mesh_sequence)
        if self.record:
            (self.out / "frames").mkdir(exist_ok=True)
        self.seconds = 0.0
        self.surface_seconds: dict[str, float] = {}  # filled with every stage on the first frame
        self.surface_counts = {"frames": 0, "triangles": 0, "vertices": 0, "spray": 0, "band_fallback": 0}

    def use_all_cores(self, enabled: bool) -> None:
        """Whether the surface splits its kernels over the CPU threads (from the next frame on; the
        mesh is bitwise the same either way). Off while the simulation runs beside the export: the
        simulation's split launches keep every core busy, and a split export would take its cores and
        queue behind its launches (run.json ``export_wait_time`` stays 0 either way: the export runs
        behind, from queued snapshots); on for the frames still queued after the last step."""
        if self.surface is not None:
            self.surface.split_threads = bool(enabled)

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
        if "particle_id" in f:  # emitters and sinks: persistent particle ids (``warp_sph.run.emission``)
            snap["id"] = wp.clone(f["particle_id"])
        if checkpoint is not None:
            snap["checkpoint"] = checkpoint
        if self.sim.bodies is not None:
            snap["bodies"] = self.sim.bodies.export_poses()
        if self.sim.colliders is not None:
            snap["bodies"] = {**snap.get("bodies", {}), **self.sim.colliders.export_poses()}
        if self.sim.whitewater is not None:  # host copies of the live particles, per kind
            snap["whitewater"] = self.sim.whitewater.snapshot()
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
            ids = {"id": snap["id"].numpy()} if "id" in snap else {}
            atomic.atomic_save_npz(rf.frame_path(self.out, frame), x=x_world.astype(world), v=v, density=rho,
                                   time=np.float64(t), **ids)
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
                                 bodies=snap.get("bodies"), whitewater=snap.get("whitewater"),
                                 ids=snap["id"].numpy() if "id" in snap else None)
        if "checkpoint" in snap:  # after the frame's outputs: checkpoint k implies frames <= k are saved
            (self.out / "checkpoints").mkdir(exist_ok=True)
            atomic.atomic_save_npz(rf.checkpoint_path(self.out, frame), particle_x_local=snap["x"].numpy(),
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
        atomic.check_free_space(self.out / "run.json", need, f"frame {frame}")

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




def snapshot_bytes(snap: dict) -> int:
    """Bytes of the device arrays in a frame snapshot, and of its whitewater's host copies (a queue of
    frames with a large whitewater capacity is bounded by them too)."""
    ww = sum(int(np.asarray(a).nbytes) for arrays in (snap.get("whitewater") or {}).values() for a in arrays)
    return sum(int(a.capacity) for a in snap.values() if isinstance(a, wp.array)) + ww


class ExportThread:
    """Runs Exporter.write on a worker thread, in frame order; re-raises its errors. Frames queue up
    while their snapshots hold at most ``max_bytes`` (always at least ``depth`` frames); ``submit``
    blocks only beyond that. Each frame's outputs depend on its snapshot alone, so the queue depth
    changes when they are written, never what."""

    def __init__(self, exporter: Exporter, depth: int = 2, max_bytes: int = SNAPSHOT_QUEUE_BYTES):
        self.exporter = exporter
        self.depth = int(depth)
        self.max_bytes = int(max_bytes)
        self.q: queue.Queue = queue.Queue()
        self.room = threading.Condition()
        self.queued = 0  # frames submitted and not yet written
        self.queued_bytes = 0
        self.blocked_seconds = 0.0  # time submit waited for room in the queue
        self.error: BaseException | None = None
        exporter.use_all_cores(False)  # beside the simulation
        self.thread = threading.Thread(target=self._work, name="warp-sph-export", daemon=True)
        self.thread.start()

    def _work(self):
        while True:
            item = self.q.get()
            if item is None:
                return
            if self.error is None:
                try:
                    self.exporter.write(*item[:3])
                except BaseException as e:  # reported on the simulation thread
                    self.error = e
            with self.room:
                self.queued -= 1
                self.queued_bytes -= item[3]
                self.room.notify_all()

    def submit(self, frame, t, snap):
        self.check()
        size = snapshot_bytes(snap)
        with self.room:
            if self.queued >= self.depth and self.queued_bytes + size > self.max_bytes:
                t0 = time.perf_counter()
                while self.queued >= self.depth and self.queued_bytes + size > self.max_bytes and self.error is None:
                    self.room.wait()
                self.blocked_seconds += time.perf_counter() - t0
            self.queued += 1
            self.queued_bytes += size
        self.q.put((frame, t, snap, size))

    def check(self):
        if self.error is not None:
            self.reported = True
            raise self.error

    def finish(self):
        """Called after the last step: writes the queued frames (on every core: the simulation is done)."""
        self.exporter.use_all_cores(True)
        self.q.put(None)
        self.thread.join()
        if not getattr(self, "reported", False):  # raised once only (a submit may have raised it)
            self.check()
