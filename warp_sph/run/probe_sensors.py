"""Transducer probes (``[[probes]]`` of kind pressure on a container wall with ``sensor_diameter`` > 0): what a
pressure transducer flush with the wall measures, the fluid's normal force on the wall over the sensor's face
divided by the face's area, averaged over each sample interval (an integral of the force, not a filter).

The face is the disc of the sensor's diameter on the wall around the probe's position; the wall is the lattice
of container particles (``scene.meshes.box_surface``: L / round(L / d) apart, edges included), each particle b
standing for its cell of the face (half or quarter cells at the face's edges), of area A_b. w_b is the share
of the disc's area inside b's cell (quadrature on a 256 x 256 grid over the disc); with a sensor smaller than
one cell (4.2 mm against d = 5-10 mm) that is the one particle the sensor's centre lies on: the finest area
the wall resolves. Device code and the force split: ``kernels/probe_sensors.py``.

Every substep (after the solver's stages, with the probes) adds p dt to each sensor's accumulator; a sample
at t_k reads the accumulated impulse divided by the time since the previous sample (or since a rewind: a
frame redone from its start drops what was accumulated). The force F_i is the one of the substep just taken,
split among the wall particles at the substep's end positions (one step's motion, v dt, apart).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ..core.launch import launch
from ..kernels import probe_sensors as _dev

#: quadrature points per side of the square around a sensor's disc (face shares w_b)
QUADRATURE = 256


def face_cells(lo, hi, axis: int, spacing: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """For the two in-plane axes of the container face normal to ``axis``: the wall lattice coordinates [m]
    (``box_surface``'s) and each lattice point's cell edges (clipped to the face), as (points, edges)."""
    pts, edges = [], []
    for a in [x for x in range(3) if x != axis]:
        n = max(1, int(np.round((hi[a] - lo[a]) / spacing)))
        u = lo[a] + np.arange(n + 1) * ((hi[a] - lo[a]) / n)
        mid = 0.5 * (u[1:] + u[:-1])
        pts.append(u)
        edges.append(np.concatenate([[lo[a]], mid, [hi[a]]]))
    return pts, edges


def face_weights(center, diameter: float, lo, hi, axis: int, spacing: float) -> list[tuple[tuple[int, int], float, float]]:
    """The wall cells a sensor's disc (``center`` on the face normal to ``axis``, ``diameter`` [m]) overlaps:
    [((i, j) lattice indices, w = share of the disc's area in the cell [-], A = the cell's area [m^2])],
    shares summing to 1 over the disc's part on the face."""
    (ua, ub), (ea, eb) = face_cells(lo, hi, axis, spacing)
    a, b = [x for x in range(3) if x != axis]
    r = 0.5 * diameter
    g = (np.arange(QUADRATURE) + 0.5) / QUADRATURE * 2.0 - 1.0
    qa, qb = np.meshgrid(center[a] + r * g, center[b] + r * g, indexing="ij")
    inside = (np.hypot(qa - center[a], qb - center[b]) <= r) & (qa >= lo[a]) & (qa <= hi[a]) & \
        (qb >= lo[b]) & (qb <= hi[b])
    ia = np.clip(np.searchsorted(ea, qa[inside], side="right") - 1, 0, len(ua) - 1)
    ib = np.clip(np.searchsorted(eb, qb[inside], side="right") - 1, 0, len(ub) - 1)
    keys, counts = np.unique(np.stack([ia, ib], axis=1), axis=0, return_counts=True)
    total = counts.sum()
    return [((int(i), int(j)), float(c / total), float((ea[i + 1] - ea[i]) * (eb[j + 1] - eb[j])))
            for (i, j), c in zip(keys, counts)]


class SensorFaces:
    """The transducer probes of one rate group: their face particles, weights and impulse accumulators.

    Args: sim; ``sensors``: [(column of the probe in the group's sample rows, ProbeLine, (axis, side))]."""

    def __init__(self, sim, sensors):
        m, dev = sim.model, sim.device
        c = sim.scene.container
        lo, hi = np.asarray(c.min, dtype=np.float64), np.asarray(c.max, dtype=np.float64)
        bx = m.to_local(np.zeros((1, 3)))  # the local origin's offset, to match wall points
        boundary = m.boundary_x.numpy().astype(np.float64) - bx
        self.count = len(sensors)
        self.columns, normals, start, end, entry_b, entry_w = [], [], [], [], [], []
        for column, line, (axis, side) in sensors:
            (ua, ub), _ = face_cells(lo, hi, axis, m.spacing)
            a, b = [x for x in range(3) if x != axis]
            nrm = np.zeros(3)
            nrm[axis] = -side
            start.append(len(entry_b))
            for (i, j), w, area in face_weights(line.start, line.sensor_diameter, lo, hi, axis, m.spacing):
                x = np.zeros(3)
                x[axis] = lo[axis] if side < 0 else hi[axis]
                x[a], x[b] = ua[i], ub[j]
                k = int(np.argmin(np.sum((boundary - x) ** 2, axis=1)))
                if np.linalg.norm(boundary[k] - x) > 0.05 * m.spacing:
                    raise RuntimeError(f"probe {line.name!r}: no wall particle at {x.tolist()} (the container's "
                                       "lattice); the sensor needs its wall's particles")
                entry_b.append(k)
                entry_w.append(w / area)
            end.append(len(entry_b))
            self.columns.append(column)
            normals.append(nrm)
        self.normal = wp.array(np.array(normals), dtype=wp.vec3, device=dev)
        self.start = wp.array(start, dtype=int, device=dev)
        self.end = wp.array(end, dtype=int, device=dev)
        self.entry_b = wp.array(entry_b, dtype=int, device=dev)
        self.entry_weight = wp.array(entry_w, dtype=float, device=dev)
        self.column = wp.array(self.columns, dtype=int, device=dev)
        self.impulse = wp.zeros(self.count, dtype=float, device=dev)
        self.elapsed = 0.0

    def accumulate(self, sim, fluid_grid, boundary_grid, dt: float) -> None:
        """Add the substep's p dt to each sensor (``fluid_grid`` and ``boundary_grid``: hash grids of the fluid
        and the wall particles at the substep's end)."""
        m, f = sim.model, sim.fields
        launch(_dev.sensor_impulse_kernel(m.smoothing.name), self.count,
               [m.smoothing_length, m.support_radius, m.boundary_x, m.boundary_volume, self.normal, self.start,
                self.end, self.entry_b, self.entry_weight, float(dt), fluid_grid, boundary_grid,
                f["particle_x"], f["boundary_force"]], [self.impulse], device=m.device)
        self.elapsed += float(dt)

    def read(self, values: wp.array, row: int) -> None:
        """Write the mean pressure since the last read into ``values[row, column]`` and restart the interval."""
        inv = 1.0 / self.elapsed if self.elapsed > 0.0 else 0.0
        launch(_dev.sensor_readings, self.count, [self.column, int(row), inv], [self.impulse, values],
               device=self.impulse.device)
        self.elapsed = 0.0

    def rewind(self) -> None:
        """A frame redone from its start: drop the partial interval."""
        self.impulse.zero_()
        self.elapsed = 0.0
