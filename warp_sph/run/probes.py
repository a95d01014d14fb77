"""Probes (``[[probes]]``): wall pressure, water height and surge front sampled during a run.

``Probes(sim)`` turns the scene's probes into points on the device (a pressure probe is one point; a
height or front probe is a line of points ``line_step`` = d/4 apart) and a stage, ``probes``, that runs
after the solver's last stage. Each probe is sampled at t_k = k / rate (k = 1, 2, ...): at the end of
the first substep whose end time reaches t_k, stamped with that time (the state's time after the
substep). A probe on a wall reads the walls' force, which only a substep computes: from a state no substep
has reached (a run's start) its first row is taken at the end of the first substep, not at t = 0. The
decision is host arithmetic on the step's time; the samples stay on the device, in a buffer of one
frame's rows, and the runner reads them once per frame (``collect``). A substep longer than 1 / rate
takes one sample and skips the sample times it stepped over (counted in ``skipped``).
Probes read the state and change nothing (``tests/test_probes.py`` checks it bit for bit).

A frame redone from its start (the watchdog's retry, grown neighbour lists, a cost measurement) puts
the state's time back: the stage sees it and drops the samples taken after it, so every sample time
is sampled once, from the state that is kept.

Readings (``kernels/probes.py``): pressure [Pa], Shepard mean of the fluid around the point with the
hydrostatic carry rho0 g . (x_p - x_j) (Adami et al. 2012), with DualSPHysics' gauge kernel (Wendland C2, h =
sqrt(3) d: ``GAUGE_SMOOTHING_PER_SPACING``), centred at the point clamped into
the container shrunk by the wall gap (a probe on a wall or in a corner reads the first fluid layers, carried
to the wall), 0 where the fill (sum of V W) there is below ``MIN_FILL`` (dry); height [m], the world z where the fill along the vertical line first falls through
1/2; front [m], the world coordinate along the axis of the last point of the line with fill >= 1/2
(interpolated).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.errors import SceneError
from ..core.launch import launch
from ..core.step_graph import Stage
from ..kernels import probes as _dev
from ..neighbors import NeighborGrid, fluid_grid_dim
from .probe_sensors import SensorFaces

#: probe kinds, their unit and the device code of each
KINDS = {"pressure": ("Pa", 0), "height": ("m", 1), "front": ("m", 2)}
#: a pressure probe whose fill sum_j V W is below this reads 0 Pa (dry): a lone splash is not a load [-]
MIN_FILL = 0.1
#: spacing of the points of a height or front line, in particle spacings d [-]
LINE_STEP = 0.25
#: smoothing length of the pressure gauge's Wendland C2 kernel, in particle spacings d [-]: DualSPHysics' 3D
#: h = coefh sqrt(3 dp^2) at coefh = 1 (support 3.46 d; its gauges interpolate with the case's kernel), wide enough
#: to average the lattice's plane-to-plane pressure mode (``kernels/probes.py``)
GAUGE_SMOOTHING_PER_SPACING = math.sqrt(3.0)


@dataclass
class ProbeLine:
    """A probe as points: ``name``, ``kind``, ``rate`` [Hz], ``start`` (world [m]), ``direction`` (unit;
    zero for a pressure probe), ``length`` [m] and the unit of its value."""

    name: str
    kind: str
    rate: float
    start: np.ndarray
    direction: np.ndarray
    length: float
    sensor_diameter: float = 0.0

    @property
    def unit(self) -> str:
        return KINDS[self.kind][0]

    def evaluation_point(self, lo, hi, gap: float) -> np.ndarray:
        """Where a pressure probe's kernel is centred [m]: its point clamped into the container shrunk by the
        wall gap (where the first fluid centres lie), or the point itself without a container."""
        if lo is None:
            return self.start.copy()
        return np.clip(self.start, np.asarray(lo) + gap, np.asarray(hi) - gap)

    def wall(self, lo, hi, gap: float):
        """(axis, side) of the container face a pressure probe lies on (within the wall gap of it; the
        nearest face), or None for a probe inside the fluid (or no container). side -1: the face at lo
        (normal +axis into the fluid), +1: at hi."""
        if self.kind != "pressure" or lo is None:
            return None
        dist = [(float(self.start[a] - lo[a]), a, -1) for a in range(3)] + \
               [(float(hi[a] - self.start[a]), a, 1) for a in range(3)]
        dmin, axis, side = min(dist)
        return (axis, side) if dmin <= gap * (1.0 + 1e-9) else None

    def points(self, step: float) -> np.ndarray:
        """World points [m] the probe reads: the point, or the line every ``step`` metres (both ends in)."""
        if self.kind == "pressure":
            return self.start.reshape(1, 3)
        n = int(math.floor(self.length / step + 1e-9)) + 1
        return self.start + np.outer(np.arange(n) * step, self.direction)

    def offset(self) -> float:
        """Value of the reading at the line's start: its world z (height) or coordinate along the axis (front)."""
        if self.kind == "height":
            return float(self.start[2])
        return float(np.dot(self.start, self.direction))


def wall_coverage(point, axis: int, lo, hi, gap: float, spacing: float, support: float) -> float:
    """C = sum_k K(s_k) d^2 over the in-plane positions of a resting first layer on the face normal to ``axis``
    (the square lattice of ``spacing`` d starting a wall ``gap`` from the face's edges, as the sampler lays a
    block against walls), K the 2D wall kernel of ``support`` (``kernels/probes.wall_kernel_2d``) around
    ``point`` [-]: the area weight of the fluid a uniform traction p acts through, so that p reads p on it
    (1.001 away from the edges, about 1/2 at an edge)."""
    tang = [a for a in range(3) if a != axis]
    h = 0.5 * support
    axes = []
    for a in tang:
        u = lo[a] + gap + spacing * np.arange(int(np.floor((hi[a] - lo[a] - 2.0 * gap) / spacing + 1e-6)) + 1)
        axes.append(u[np.abs(u - point[a]) < support])
    du, dv = np.meshgrid(axes[0] - point[tang[0]], axes[1] - point[tang[1]], indexing="ij")
    q = np.hypot(du, dv) / h
    w = np.where(q < 1.0, 2.0 / 3.0 - q ** 2 + 0.5 * q ** 3, np.where(q < 2.0, (2.0 - np.minimum(q, 2.0)) ** 3 / 6.0, 0.0))
    return float(w.sum() * 15.0 / (7.0 * math.pi * h * h) * spacing * spacing)


def probe_lines(scene) -> list[ProbeLine]:
    """The scene's probes as ``ProbeLine`` (names, directions and lengths resolved as validation left them)."""
    out = []
    for i, p in enumerate(scene.probes):
        start = np.asarray(p.position, dtype=np.float64)
        if p.kind == "pressure":
            direction = np.zeros(3)
        elif p.kind == "height":
            direction = np.array([0.0, 0.0, 1.0])
        else:
            a = np.asarray(p.axis, dtype=np.float64)
            direction = a / np.linalg.norm(a)
        out.append(ProbeLine(p.name or f"probe{i}", p.kind, float(p.rate), start, direction,
                             float(p.length or 0.0), float(getattr(p, "sensor_diameter", 0.0) or 0.0)))
    return out


class _RateGroup:
    """The probes of one sample rate: their points, device tables and the frame's sample buffer."""

    def __init__(self, sim, rate: float, lines: list[ProbeLine], line_step: float):
        m, dev = sim.model, sim.device
        self.rate = rate
        self.lines = lines
        pts, targets, start, end = [], [], [], []
        c = sim.scene.container
        lo, hi = (None, None) if c is None else (c.min, c.max)
        for line in lines:
            p = line.points(line_step)
            targets.append(p)
            if line.kind == "pressure":
                p = line.evaluation_point(lo, hi, sim.scene.wall_gap).reshape(1, 3)
            start.append(sum(len(q) for q in pts))
            pts.append(p)
            end.append(start[-1] + len(p))
        world = np.concatenate(pts)
        self.point_x = wp.array(m.to_local(world), dtype=wp.vec3, device=dev)
        self.point_target = wp.array(m.to_local(np.concatenate(targets)), dtype=wp.vec3, device=dev)
        self.point_fill = wp.zeros(len(world), dtype=float, device=dev)
        self.point_pressure = wp.zeros(len(world), dtype=float, device=dev)
        self.kind = wp.array([KINDS[line.kind][1] for line in lines], dtype=int, device=dev)
        self.start = wp.array(start, dtype=int, device=dev)
        self.end = wp.array(end, dtype=int, device=dev)
        self.offset = wp.array([line.offset() for line in lines], dtype=float, device=dev)
        # pressure probes on a container face read the wall load (``probe_wall_loads``), the others the
        # fluid's pressure field (``point_values_kernel``)
        walls = [(start[q], line, line.wall(lo, hi, sim.scene.wall_gap)) for q, line in enumerate(lines)]
        # a transducer (sensor_diameter > 0) reads its face's load instead (``probe_sensors``)
        sensors = [(q, line, w) for q, (_, line, w) in enumerate(walls) if w is not None and line.sensor_diameter > 0.0]
        walls = [(i, line, w) for i, line, w in walls if w is not None and line.sensor_diameter <= 0.0]
        self.sensors = SensorFaces(sim, sensors) if sensors else None
        self.with_pressure = any(line.kind == "pressure" and line.wall(lo, hi, sim.scene.wall_gap) is None
                                 for line in lines)
        self.wall_count = len(walls)
        if walls:
            wx, wn, wc = [], [], []
            for _, line, (axis, side) in walls:
                x = line.start.copy()
                x[axis] = lo[axis] if side < 0 else hi[axis]
                n = np.zeros(3)
                n[axis] = -side
                wx.append(x)
                wn.append(n)
                wc.append(1.0 / max(wall_coverage(x, axis, lo, hi, sim.scene.wall_gap, m.spacing, m.support_radius), 1e-6))
            self.wall_point = wp.array(m.to_local(np.array(wx)), dtype=wp.vec3, device=dev)
            self.wall_normal = wp.array(np.array(wn), dtype=wp.vec3, device=dev)
            self.wall_inv_coverage = wp.array(wc, dtype=float, device=dev)
            self.wall_index = wp.array([i for i, _, _ in walls], dtype=int, device=dev)
        #: rows of one frame (+2: a frame may end just past a sample time and start on one)
        self.capacity = int(math.ceil(rate / float(sim.scene.fps))) + 2
        self.values = wp.zeros((self.capacity, len(lines)), dtype=float, device=dev)
        self.fills = wp.zeros((self.capacity, len(lines)), dtype=float, device=dev)
        self.times: list[float] = []       # stamps of the rows in the device buffer [s]
        self.host: list[tuple[float, np.ndarray, np.ndarray]] = []  # rows read before the frame ended
        self.next_k = 1
        self.skipped = 0
        self.start_at = None  # a run's start time when its first row waits for the first substep [s]

    def next_index(self, t: float) -> int:
        """The first sample index k with t_k = k / rate after time t [s]."""
        return int(math.floor(t * self.rate * (1.0 + 1e-12) + 1e-9)) + 1

    def due(self, t_end: float) -> bool:
        return self.next_k / self.rate <= t_end * (1.0 + 1e-12) + 1e-12

    def rewind(self, t: float) -> None:
        """Drop the samples stamped after time t [s] (a frame redone from t)."""
        if self.sensors is not None:
            self.sensors.rewind()
        keep = sum(1 for s in self.times if s <= t)
        del self.times[keep:]
        self.host = [row for row in self.host if row[0] <= t]
        self.next_k = 0 if self.start_at is not None and t <= self.start_at else self.next_index(t)

    def flush(self) -> None:
        """Move the device rows to the host (once per frame, or when a caller steps past a frame's rows)."""
        if self.times:
            v, f = self.values.numpy(), self.fills.numpy()
            self.host += [(t, v[r].copy(), f[r].copy()) for r, t in enumerate(self.times)]
            self.times = []


class Probes:
    """The scene's probes on the device, their stage and the samples of the current frame."""

    def __init__(self, sim):

        self.sim = sim
        m = sim.model
        self.lines = probe_lines(sim.scene)
        self.line_step = LINE_STEP * m.spacing
        self.grid = NeighborGrid(m.support_radius, device=sim.device, dim=fluid_grid_dim(m, sim.sampled.fluid_x))
        # one group per (rate, on a wall): a wall load exists only after a substep (``sample_now``)
        c = sim.scene.container
        key = [(line.rate, c is not None and line.wall(c.min, c.max, sim.scene.wall_gap) is not None)
               for line in self.lines]
        self.groups = [_RateGroup(sim, r, [line for line, k in zip(self.lines, key) if k == (r, w)], self.line_step)
                       for r, w in sorted(set(key))]
        self._no_pressure = wp.zeros(1, dtype=float, device=sim.device)
        self._t_last = -math.inf
        self.samples = 0

    # --- checks (before any step) -------------------------------------------------------------
    def check(self, stages) -> None:
        """SceneError (one line) for a pressure probe with a solver whose stages write no pressure, and
        for a rate faster than the time step at the scene's reference speed (``preflight``'s estimate)."""
        sim, scene = self.sim, self.sim.scene
        produced = {name for s in stages for name in s.writes + s.updates}
        c = scene.container
        lo, hi = (None, None) if c is None else (c.min, c.max)
        for i, line in enumerate(self.lines):
            if line.sensor_diameter > 0.0 and line.wall(lo, hi, scene.wall_gap) is None:
                raise SceneError(f"{scene.source}: probes[{i}].sensor_diameter: a transducer lies on a container wall; "
                                 f"expected a pressure probe within the wall gap of a container face, or sensor_diameter = 0")
            if line.kind == "pressure" and line.wall(lo, hi, scene.wall_gap) is not None:
                if "boundary_force" not in produced:
                    raise SceneError(f"{scene.source}: probes[{i}]: a pressure probe on a wall reads the walls' "
                                     f"force on the fluid, which solver {sim.solver.name!r} does not compute")
                continue
            if line.kind == "pressure" and "particle_pressure" not in produced:
                raise SceneError(f"{scene.source}: probes[{i}].kind: 'pressure' needs a solver with a pressure field; "
                                 f"solver {sim.solver.name!r} has none (its position correction is not a pressure): "
                                 "use solver 'dfsph' or 'wcsph', a probe on a container wall (it reads the wall load), or a "
                                 "'height' or 'front' probe")
        t = scene.time
        bound = sim.time_step_bounds(sim.model.reference_speed)[0].seconds
        dt = float(t.fixed_dt) if t.fixed_dt > 0 else min(max(bound, t.dt_min), t.dt_max)
        for i, line in enumerate(self.lines):
            if 1.0 / line.rate < dt * (1.0 - 1e-9):
                raise SceneError(f"{scene.source}: probes[{i}].rate: {line.rate:g} Hz samples every "
                                 f"{1e3 / line.rate:.3g} ms, finer than the time step ({1e3 * dt:.3g} ms at the "
                                 f"reference speed {sim.model.reference_speed:.3g} m/s); expected at most "
                                 f"{math.floor(1.0 / dt):g} Hz, or a smaller time.fixed_dt / time.dt_max")

    # --- the stage ----------------------------------------------------------------------------
    def stage(self, stages) -> Stage:
        """The ``probes`` stage, to run after the solver's ``stages`` (``sim.solver`` set): reads positions
        (and pressures)."""
        self.check(stages)
        reads = ("particle_x",) + (("particle_pressure",) if any(g.with_pressure for g in self.groups) else ()) \
            + (("boundary_force",) if any(g.wall_count or g.sensors is not None for g in self.groups) else ())
        names = ", ".join(f"{line.name} ({line.kind}, {line.rate:g} Hz)" for line in self.lines)
        return Stage("probes", self.run, reads=reads,
                     doc=f"probes {names}: fill sum V W and Shepard pressure (+ rho0 g . (x_p - x_j)) at their "
                         "points, on a wall its load sum_i K(s_i) F_i . n / C, sampled at k / rate; nothing written "
                         "to the state")

    def run(self, sim, dt) -> None:
        t0 = float(sim.state.time)
        t1 = t0 + float(dt)
        if t0 < self._t_last - 1e-12 * max(1.0, abs(t0)):
            for g in self.groups:
                g.rewind(t0)
        self._t_last = t1
        due = [g for g in self.groups if g.due(t1)]
        sensing = [g for g in self.groups if g.sensors is not None]
        if not due and not sensing:
            return
        self.grid.build(sim.fields["particle_x"])
        for g in sensing:  # transducers integrate every substep (the static walls' grid: ``Model``)
            g.sensors.accumulate(sim, self.grid.id, sim.model.boundary_grid_id, dt)
        for g in due:
            self._sample(g, t1)

    def sample_now(self, t: float | None = None, start: bool = False) -> None:
        """Sample every probe at the current state (the runner's initial frame; scripts), stamped t. ``start``
        (a run's initial state, no substep taken): a probe on a wall, whose walls' force no substep has
        computed yet, is sampled at the end of the first substep instead."""
        t = float(self.sim.state.time) if t is None else float(t)
        self.grid.build(self.sim.fields["particle_x"])
        for g in self.groups:
            g.rewind(t)  # steps taken and undone before (a cost measurement) leave no samples
            if g.wall_count and start:  # no walls' force yet: the first row after substep 1 (a redone
                g.start_at, g.next_k = t, 0  # first frame takes it again)
                continue
            self._sample(g, t, scheduled=False)
        self._t_last = t

    def _sample(self, g: _RateGroup, t: float, scheduled: bool = True) -> None:
        m, f, dev = self.sim.model, self.sim.fields, self.sim.device
        if len(g.times) == g.capacity:
            g.flush()
        pressure = f["particle_pressure"] if g.with_pressure else self._no_pressure
        launch(_dev.point_values_kernel(m.smoothing.name, g.with_pressure), g.point_x.shape[0],
               [m.particle_mass / m.rest_density, m.rest_density, wp.vec3(*m.gravity), m.smoothing_length,
                m.support_radius, GAUGE_SMOOTHING_PER_SPACING * m.spacing, self.grid.id, f["particle_x"], pressure,
                g.point_x, g.point_target],
               [g.point_fill, g.point_pressure], device=dev)
        if g.wall_count:
            launch(_dev.probe_wall_loads, g.wall_count,
                   [m.support_radius, self.grid.id, f["particle_x"], f["boundary_force"], g.wall_point, g.wall_normal,
                    g.wall_inv_coverage, g.wall_index], [g.point_pressure], device=dev)
        launch(_dev.probe_readings, len(g.lines),
               [g.kind, g.start, g.end, g.offset, MIN_FILL, self.line_step, len(g.times), g.point_fill,
                g.point_pressure], [g.values, g.fills], device=dev)
        if g.sensors is not None:
            g.sensors.read(g.values, len(g.times))
        g.times.append(t)
        self.samples += 1
        if scheduled:
            k = g.next_index(t)
            g.skipped += max(0, k - max(g.next_k, 1) - 1)
            g.next_k = k
        else:
            g.next_k = g.next_index(t)

    def restart(self, t: float) -> None:
        """After a resume at time t [s]: the next samples are the ones after t."""
        for g in self.groups:
            g.times, g.host = [], []
            g.next_k = g.next_index(t)
        self._t_last = t

    # --- reading ------------------------------------------------------------------------------
    def collect(self) -> dict[str, list[tuple[float, float, float]]]:
        """The samples since the last call, per probe name: (time [s], value [unit], fill [-]); one host
        read per rate group."""
        out: dict[str, list] = {line.name: [] for line in self.lines}
        for g in self.groups:
            g.flush()
            for t, v, f in g.host:
                for q, line in enumerate(g.lines):
                    out[line.name].append((t, float(v[q]), float(f[q])))
            g.host = []
        return out

    def skipped(self) -> dict[str, int]:
        """Sample times stepped over per probe (substeps longer than 1 / rate)."""
        return {line.name: g.skipped for g in self.groups for line in g.lines}
