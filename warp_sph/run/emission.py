"""A changing particle count: emitters add fluid, sinks and open container faces remove it (``[[emitters]]``,
``[[sinks]]``, ``container.open``, docs/emitters.md).

Every per-particle array holds ``model.capacity`` values, allocated once; the active particles are the
prefix [0, n) with n = ``model.fluid_count``, and ``sim.fields`` / ``sim.state`` hold prefix views of
the arrays, so every launch, the neighbour search and every statistic see n particles only. The count
changes at the start of a frame, outside the cell order, decided on the host from the time:

1. sinks: the particles inside a sink box, or past an open face of the container (``container.open``: a
   half-space sink), are removed; the others keep their order (a stable compaction: one indexed copy with
   the kept indices, on the device, and one copy back, per field that outlives a substep: x, v, the ids and
   the solver's and forces' carried fields; every other field is written by a stage before any stage reads
   it, the step graph's contract);
2. emitters: the layers that entered since the last frame (layer k of an emitter at
   t_k = start + k d / v, ``warp_sph.scene.emitters``) are written into the slots [n, n + k) with
   their ballistic age a = t - t_k: x = x_nozzle + v n a + g a^2 / 2, v = v n + g a; the carried fields
   of those slots (warm starts, carried force fields) start at 0. A new particle closer than
   ``BLOCKED_GAP`` d to a particle already there is not emitted (a blocked nozzle, ``_unblocked``).

Particle ids (``particle_id``, int32) are persistent: the initial fluid has 0..n0-1, emitted particles
the next ones. A full capacity skips the layers that do not fit (one warning). The energy the particles
brought in minus what the removed ones took out (kinetic + potential) is ``exchanged``: the energy
rule measures from E(0) + exchanged (``warp_sph.run.energy``).
"""
from __future__ import annotations

import warnings

import numpy as np
import warp as wp

from ..core.launch import LIGHT_MIN_RANGE, launch
from ..kernels import neighbors as _dev
from ..scene.emitters import emitter_plan, open_faces

ID_FIELD = "particle_id"
#: a new particle closer than this many spacings to a particle already there is not emitted (a blocked nozzle;
#: an unobstructed jet's layers are d apart, and the energy a closer one adds is measured in docs/emitters.md)
BLOCKED_GAP = 0.95


def open_top(faces, gravity) -> tuple[int, int] | None:
    """The open face (axis, side) gravity points away from, along gravity's largest component; None when
    no open face is (or without gravity)."""
    g = np.asarray(gravity, dtype=np.float64)
    up = int(np.argmax(np.abs(g)))
    side = int(g[up] < 0.0)
    return (up, side) if g[up] != 0.0 and (up, side) in list(faces) else None


def spill_band(reference_speed: float, frame_dt: float, gravity) -> float:
    """[m] How far below an open top's rim a particle thrown over it may be at a frame's end, outside a side
    wall: it falls at most v_ref T + |g| T^2 / 2 in one frame T [s] (v_ref [m/s]: the model's reference
    speed), and the next frame's start removes it."""
    return float(reference_speed) * frame_dt + 0.5 * float(np.linalg.norm(gravity)) * frame_dt ** 2


def open_face_sinks(faces, lo_c, hi_c, gravity, band: float = 0.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Sink boxes (lo, hi) [m] (infinite sides) of the open faces (axis, side) of the container lo_c..hi_c.
    A face is the half-space past its plane, except the top (``open_top``): a particle above the top's
    opening is in flight and falls back, so the top removes what is past a side face's plane (thrown over
    the rim) and no lower than ``band`` [m] below the rim (``spill_band``: spilled down the wall's outside)."""
    top = open_top(faces, gravity)
    out = []
    for axis, side in faces:
        lo, hi = np.full(3, -np.inf), np.full(3, np.inf)
        if (axis, side) != top:
            (lo if side else hi)[axis] = (hi_c if side else lo_c)[axis]
            out.append((lo, hi))
            continue
        if side:
            lo[axis] = hi_c[axis] - band
        else:
            hi[axis] = lo_c[axis] + band
        for b in range(3):  # past each side face's plane, over the rim
            if b == axis:
                continue
            for t in (0, 1):
                blo, bhi = lo.copy(), hi.copy()
                (blo if t else bhi)[b] = (hi_c if t else lo_c)[b]
                out.append((blo, bhi))
    return out


class ParticleFlow:
    """The emitters and sinks of a simulation (see the module docstring); ``sim.flow``."""

    #: key of this part in run.json's summary (``Simulation.parts``)
    name = "flow"

    def __init__(self, sim):
        self.sim = sim
        m, scene = sim.model, sim.scene
        self.plans = [emitter_plan(e, scene.spacing, scene.duration) for e in scene.emitters]
        self.local_points = [m.to_local(p.points) for p in self.plans]
        self.sinks = [(m.to_local(np.asarray(s.min)), m.to_local(np.asarray(s.max))) for s in scene.sinks]
        #: the container's open faces (axis, side), each removing what lies past it (``open_face_sinks``)
        self.open_faces = open_faces(scene)
        #: the open top (axis, side) or None, and how far below its rim spilled fluid is removed [m]
        self.top = open_top(self.open_faces, m.gravity)
        self.spill_band = spill_band(m.reference_speed, 1.0 / float(scene.fps), m.gravity) if self.top else 0.0
        self.open_sinks = open_face_sinks(self.open_faces, m.container_lo, m.container_hi, m.gravity, self.spill_band)
        self.sinks += self.open_sinks
        self.layers = np.zeros(len(self.plans), dtype=np.int64)  # layers emitted so far, per emitter
        self.initial = m.fluid_count
        self.next_id = m.fluid_count
        self.emitted = 0
        self.removed = 0
        self.skipped = 0   # particles not emitted: the capacity was full
        self.blocked = 0   # particles not emitted: a particle already there (``_unblocked``)
        self.exchanged = 0.0  # [J] kinetic + potential brought in by emission minus taken out by sinks
        self.exchanged_scale = 0.0  # [J] emitted energy above the floor (grows the energy rule's scale)
        self.last_speed = 0.0  # [m/s] fastest emitted particle of the last frame
        self._warned = False
        #: name -> the capacity-sized array behind the field's prefix view
        self.full: dict[str, wp.array] = {}
        for name in ("particle_x", "particle_v"):
            a = getattr(sim.state, name)
            full = wp.zeros(m.capacity, dtype=a.dtype, device=sim.device)
            wp.copy(full, a, count=a.shape[0])
            self.full[name] = full
        ids = wp.array(np.arange(m.capacity, dtype=np.int32), dtype=wp.int32, device=sim.device)
        self.full[ID_FIELD] = ids
        self._keep = wp.zeros(m.capacity, dtype=wp.int32, device=sim.device)
        self._tmp: dict = {}   # dtype -> capacity-sized scratch of the removal's gather
        self._host: dict = {}  # use -> host staging array (``_staging``)
        self.set_count(m.fluid_count)

    # --- the active prefix ------------------------------------------------------------------
    def adopt(self, name: str, full: wp.array) -> wp.array:
        """Register the capacity-sized ``full`` array of field ``name``; returns its active view."""
        self.full[name] = full
        return full[: self.sim.model.fluid_count]

    def set_count(self, n: int) -> None:
        """Make n the active count: model.fluid_count, the prefix views in sim.fields and sim.state."""
        sim = self.sim
        sim.model.fluid_count = int(n)
        for name, full in self.full.items():
            sim.fields[name] = full[: int(n)]
        sim.state.particle_x = sim.fields["particle_x"]
        sim.state.particle_v = sim.fields["particle_v"]

    def carried(self) -> list[tuple[str, wp.array]]:
        """(name, capacity array) of the fields that outlive a substep: x, v, the ids, the solver's and the
        forces' carried fields (the others are produced by a stage before any stage reads them)."""
        sim = self.sim
        names = {"particle_x", "particle_v", ID_FIELD} | set(sim.solver.carried_fields()) | set(sim.forces.carried_fields())
        return [(name, full) for name, full in self.full.items() if name in names]

    # --- a frame's start ----------------------------------------------------------------------
    def begin_frame(self) -> bool:
        """Sinks, then emitters, at the state's time (see the module docstring); True when particles were
        removed or added.

        Timed as per-frame stages of the step graph (``StepGraph.timed``, run.json ``frame_stage_times``):
        ``flow_sinks`` (the sink test and the gather), ``flow_emitters`` (the new layers) and ``flow_count``
        (the active prefix views of the new count, made once per frame). Nothing else runs for them: no
        density refresh (every solver's first stages compute the density of the new count) and no extra
        neighbour search or sort (the substeps search, and the frame sorts into cell order, as without them).
        """
        graph, n0 = self.sim.graph, self.sim.model.fluid_count
        n, before = n0, (self.removed, self.emitted)
        if self.sinks:
            with graph.timed("flow_sinks"):
                n = self._remove(n)
        if self.plans:
            with graph.timed("flow_emitters"):
                n = self._emit(n)
        if n != n0:  # (as many removed as emitted: the views of n0 are those of n)
            with graph.timed("flow_count"):
                self.set_count(n)
        return (self.removed, self.emitted) != before

    def _energy(self, x: np.ndarray, v: np.ndarray) -> tuple[float, float]:
        """(kinetic + potential [J] in the local frame, the same above the floor [J]) of particles x, v."""
        m = self.sim.model
        g = np.asarray(m.gravity, dtype=np.float64)
        mass = float(m.particle_mass)
        ke = 0.5 * mass * float(np.sum(v.astype(np.float64) ** 2))
        pe = -mass * float(np.sum(x.astype(np.float64) @ g))
        watch = self.sim.watchdog.energy if getattr(self.sim, "watchdog", None) is not None else None
        floor_pe = mass * len(x) * float(np.linalg.norm(g)) * (watch.floor if watch is not None else 0.0)
        return ke + pe, ke + pe - floor_pe

    def _staging(self, use: str, dtype) -> wp.array:
        """The host array of ``use`` (capacity values of ``dtype``, twice that for "xv"; allocated once, pinned
        for a CUDA device): values written into its ``numpy()`` view reach the device's arrays by one copy, with no
        allocation. One per use: a copy from pinned memory may still be queued when the next use writes
        (each is written once per frame, and every frame reads the device back before the next one)."""
        buf = self._host.get(use)
        if buf is None:
            size = (2 if use == "xv" else 1) * self.sim.model.capacity  # "xv": x and v of the new particles
            buf = self._host[use] = wp.empty(size, dtype=dtype, device="cpu", pinned=self.sim.device.is_cuda)
        return buf

    def _remove(self, n: int) -> int:
        """The particles of [0, n) inside a sink box removed, the others in order in [0, left); returns left."""
        sim = self.sim
        x = sim.fields["particle_x"].numpy()
        inside = np.zeros(n, dtype=bool)
        for lo, hi in self.sinks:
            inside |= np.all((x >= lo) & (x <= hi), axis=1)
        k = int(inside.sum())
        if not k:
            return n
        v = sim.fields["particle_v"].numpy()
        e, _ = self._energy(x[inside], v[inside])
        self.exchanged -= e
        left = n - k
        host = self._staging("keep", wp.int32)
        host.numpy()[:left] = np.flatnonzero(~inside)
        wp.copy(self._keep, host, count=left)
        # the stable compaction: one copy through an index view into a scratch array of the field's type
        # (a native copy, on the host or the device), and one copy back, per field that outlives a substep
        order = self._keep[:left]
        views = {}
        for name, full in self.carried():
            t = views.get(full.dtype)
            if t is None:
                scratch = self._tmp.get(full.dtype)
                if scratch is None:
                    scratch = self._tmp[full.dtype] = wp.empty(self.sim.model.capacity, dtype=full.dtype,
                                                               device=sim.device)
                t = views[full.dtype] = scratch[:left]
            wp.copy(t, wp.indexedarray(full, [order]))
            wp.copy(full, t, count=left)
        self.removed += k
        return left

    def _emit(self, n: int) -> int:
        """The layers due by the state's time written into the slots [n, n + k); returns n + k."""
        sim, m = self.sim, self.sim.model
        t = sim.state.time
        g = np.asarray(m.gravity, dtype=np.float64)
        xs, vs = [], []
        for k, plan in enumerate(self.plans):
            due = plan.layers_by(t)
            for layer in range(int(self.layers[k]), due):
                age = t - (plan.start + layer * plan.period)
                vel = plan.speed * plan.direction
                xs.append(self.local_points[k] + vel * age + 0.5 * g * age * age)
                vs.append(np.broadcast_to(vel + g * age, xs[-1].shape))
            self.layers[k] = max(int(self.layers[k]), due)
        if not xs:
            self.last_speed = 0.0
            return n
        x = np.concatenate(xs).astype(np.float32)
        v = np.concatenate(vs).astype(np.float32)
        x, v = self._unblocked(x, v, n)
        room = m.capacity - n
        if len(x) > room:
            self.skipped += len(x) - room
            if not self._warned:
                warnings.warn(f"t = {t:.4g} s: the particle capacity max_particles = {m.capacity} is full; emission "
                              "continues only as sinks free slots (raise max_particles)", RuntimeWarning, stacklevel=3)
                self._warned = True
            x, v = x[:room], v[:room]
        k = len(x)
        if not k:
            return n
        self.last_speed = float(np.sqrt(np.max(np.sum(v.astype(np.float64) ** 2, axis=1))))
        own = ("particle_x", "particle_v", ID_FIELD)  # written whole below
        for name, full in self.carried():
            if name not in own:
                full[n:n + k].zero_()
        xv = self._staging("xv", wp.vec3)
        xv.numpy()[: 2 * k] = np.concatenate([x, v])
        wp.copy(self.full["particle_x"], xv, dest_offset=n, count=k)
        wp.copy(self.full["particle_v"], xv, dest_offset=n, src_offset=k, count=k)
        ids = self._staging("ids", wp.int32)
        ids.numpy()[:k] = np.arange(self.next_id, self.next_id + k, dtype=np.int32)
        wp.copy(self.full[ID_FIELD], ids, dest_offset=n, count=k)
        self.next_id += k
        self.emitted += k
        e, above = self._energy(x, v)
        self.exchanged += e
        self.exchanged_scale += max(above, 0.0)
        return n + k

    def _unblocked(self, x: np.ndarray, v: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The new particles x, v [local m, m/s] without those closer than ``BLOCKED_GAP`` d to one of the n
        active particles: fluid that has not cleared the nozzle (slowed by a pool that rose to it) would be
        overlapped, and an overlap a fraction of d wide is a density spike an equation of state (WCSPH)
        turns into an explosion. The inflow is reduced by what the blocked slots would have carried
        (``blocked``, run.json's flow record)."""
        if not n:
            return x, v
        gap = BLOCKED_GAP * self.sim.scene.spacing
        old = self.sim.fields["particle_x"].numpy()
        near = old[np.all((old >= x.min(axis=0) - gap) & (old <= x.max(axis=0) + gap), axis=1)]
        if not len(near):
            return x, v
        free = np.empty(len(x), dtype=bool)
        step = max(1, (1 << 20) // len(near))  # new particles per block: at most ~1M distances at once
        for a in range(0, len(x), step):
            d2 = np.sum((x[a:a + step, None, :] - near[None, :, :]) ** 2, axis=2)
            free[a:a + step] = d2.min(axis=1) >= gap * gap
        self.blocked += int(len(x) - free.sum())
        return x[free], v[free]

    # --- records and checkpoints ----------------------------------------------------------------
    def record(self) -> dict:
        """Per-frame counts for run.json: active particles, emitted and removed so far, skipped (capacity), blocked."""
        return {"particles": int(self.sim.model.fluid_count), "emitted": int(self.emitted),
                "removed": int(self.removed), "skipped": int(self.skipped), "blocked": int(self.blocked)}

    def checkpoint_arrays(self) -> dict:
        return {"flow_layers": self.layers.copy(), "flow_ids": self.sim.fields[ID_FIELD].numpy().copy(),
                "flow_counters": np.array([self.next_id, self.emitted, self.removed, self.skipped, int(self._warned),
                                           self.blocked],
                                          dtype=np.int64),
                "flow_energy": np.array([self.exchanged, self.exchanged_scale, self.last_speed], dtype=np.float64)}

    def restore_arrays(self, cp) -> None:
        """Before the state's arrays are assigned: the active count of checkpoint ``cp``, the ids, the counters."""
        n = len(cp["particle_x_local"])
        self.set_count(n)
        self.layers = np.array(cp["flow_layers"], dtype=np.int64)
        self.sim.fields[ID_FIELD].assign(wp.array(np.asarray(cp["flow_ids"], np.int32), dtype=wp.int32,
                                                  device=self.sim.device))
        counters = [int(c) for c in cp["flow_counters"]]
        self.next_id, self.emitted, self.removed, self.skipped, warned = counters[:5]
        self.blocked = counters[5] if len(counters) > 5 else 0  # (a checkpoint from before the count)
        self._warned = bool(warned)
        self.exchanged, self.exchanged_scale, self.last_speed = (float(c) for c in cp["flow_energy"])

    def summary(self) -> dict:
        return {"capacity": int(self.sim.model.capacity),
                "emitters": [{"particles_per_layer": len(p.points), "speed": p.speed, "flow_rate": p.flow_rate,
                              "layer_period": p.period, "layers": p.layers} for p in self.plans],
                "sinks": len(self.sinks) - len(self.open_sinks),
                "open_faces": [("-+"[side] + "xyz"[axis]) for axis, side in self.open_faces]}
