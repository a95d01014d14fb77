"""Emitters and sinks on the host: a nozzle's lattice, its layer times and speed, and the checks of
``[[emitters]]``, ``[[sinks]]`` and ``max_particles`` before anything is sampled.

A nozzle is a disc (radius R) or a rectangle (width W x height H) in the plane normal to the unit
direction n through ``position``; its particles sit on a square lattice of spacing d in that plane
(``nozzle_points``, N points). The fluid enters in layers: layer k enters at t_k = start + k d / v,
so consecutive layers are one spacing apart along n and the inlet is at the rest lattice density.
With a flow rate Q the speed is v = Q / (N d^2) (the nozzle's lattice area), so the emitted volume
N d^3 per layer over d / v seconds is Q exactly; with a speed, Q = N d^2 v.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def nozzle_basis(direction) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, u, w): the unit flow direction and two unit vectors spanning the nozzle plane (u horizontal
    when n is not vertical; the rectangle's width runs along u, its height along w)."""
    n = np.asarray(direction, dtype=np.float64)
    n = n / np.linalg.norm(n)
    helper = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(helper, n)
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    return n, u, w


def _axis(extent: float, spacing: float) -> np.ndarray:
    count = max(1, int(round(extent / spacing)))
    return (np.arange(count) - 0.5 * (count - 1)) * spacing


def nozzle_points(emitter, spacing: float) -> np.ndarray:
    """The nozzle's lattice points [m], shape (N, 3), world coordinates (see the module docstring)."""
    _, u, w = nozzle_basis(emitter.direction)
    if emitter.shape == "circle":
        a = _axis(2.0 * emitter.radius, spacing)
        gu, gw = np.meshgrid(a, a, indexing="ij")
        keep = gu ** 2 + gw ** 2 <= emitter.radius ** 2 + 1e-9 * spacing ** 2
        gu, gw = gu[keep], gw[keep]
        if not len(gu):
            gu, gw = np.zeros(1), np.zeros(1)
    else:
        gu, gw = np.meshgrid(_axis(emitter.width, spacing), _axis(emitter.height, spacing), indexing="ij")
        gu, gw = gu.ravel(), gw.ravel()
    return np.asarray(emitter.position, dtype=np.float64) + np.outer(gu, u) + np.outer(gw, w)


@dataclass
class EmitterPlan:
    """One emitter's schedule: nozzle points (world, [m]), direction, speed v [m/s], start/end [s],
    the layer period d / v [s] and the layer count."""

    points: np.ndarray
    direction: np.ndarray
    speed: float
    start: float
    end: float
    period: float
    layers: int

    @property
    def flow_rate(self) -> float:
        """Emitted volume per second [m^3/s]: N d^3 / period."""
        return len(self.points) * (self.period * self.speed) ** 3 / self.period

    def layers_by(self, t: float) -> int:
        """Layers that have entered by time t [s] (t_k <= t, k < layers)."""
        if t < self.start:
            return 0
        return min(self.layers, int(math.floor((t - self.start) / self.period + 1e-9)) + 1)


def emitter_plan(emitter, spacing: float, duration: float) -> EmitterPlan:
    """The schedule of ``emitter`` on the lattice of spacing d [m] in a scene of ``duration`` [s]."""
    points = nozzle_points(emitter, spacing)
    n, _, _ = nozzle_basis(emitter.direction)
    speed = emitter.speed if emitter.speed is not None else emitter.flow_rate / (len(points) * spacing ** 2)
    end = duration if emitter.end is None else min(emitter.end, duration)
    period = spacing / speed
    layers = max(0, int(math.ceil((end - emitter.start) / period - 1e-9))) if end > emitter.start else 0
    return EmitterPlan(points, n, float(speed), float(emitter.start), float(end), period, layers)


def emitted_total(scene) -> int:
    """Particles every emitter of ``scene`` emits over the run."""
    return sum(len(p.points) * p.layers for p in (emitter_plan(e, scene.spacing, scene.duration)
                                                 for e in scene.emitters))


def _obstacle_inside(ob, points: np.ndarray) -> np.ndarray:
    """Mask of ``points`` [m] inside obstacle ``ob`` (a box, a sphere, or a closed mesh by its winding number)."""
    if ob.shape == "box":
        return np.all((points >= np.asarray(ob.min)) & (points <= np.asarray(ob.max)), axis=1)
    if ob.shape == "sphere":
        from .sphere_obstacle import sphere_inside

        return sphere_inside(ob, points)
    from .meshes import load_triangle_mesh_cached, points_inside

    return points_inside(load_triangle_mesh_cached(ob.file).transformed(ob.scale, ob.translate), points)


def open_faces(scene) -> list[tuple[int, int]]:
    """The container's open faces (``container.open``, an outflow) as (axis, side): side 0 at container.min,
    1 at container.max; none without a container."""
    c = scene.container
    return [("xyz".index(f[1]), int(f[0] == "+")) for f in (getattr(c, "open", None) or ())] if c is not None else []


def has_flow(scene) -> bool:
    """True when the particle count can change: emitters, sinks or open container faces."""
    return bool(scene.emitters or scene.sinks or open_faces(scene))


def check_emission(scene, fail) -> None:
    """``fail(keypath, message)`` on an emitter with speed and flow_rate (or neither), a zero direction, a
    start at or after the scene's duration, an end before its start, a nozzle outside the container or
    inside an obstacle, a sink box that is empty or outside the container, or rigid bodies together with
    emitters, sinks or open container faces."""
    c = scene.container
    d = scene.spacing
    where = "emitters" if scene.emitters else "sinks" if scene.sinks else "container.open"
    if scene.bodies and has_flow(scene):
        fail(where, "emitters, sinks and open container faces do not work with [[bodies]] yet; remove the bodies "
             "or the flow")
    for i, f in enumerate(scene.forces):
        if getattr(f, "method", "") == "weiler2018" and has_flow(scene):
            fail(f"forces[{i}].method", "weiler2018 keeps arrays of the initial particle count and does not work "
                 "with emitters, sinks or open container faces yet; use explicit_viscosity")
    for i, e in enumerate(scene.emitters):
        kp = f"emitters[{i}]"
        if (e.speed is None) == (e.flow_rate is None):
            fail(kp, "expected exactly one of speed [m/s] or flow_rate [m^3/s], got "
                 + ("both" if e.speed is not None else "neither"))
        if not np.linalg.norm(np.asarray(e.direction, dtype=float)) > 0.0:
            fail(f"{kp}.direction", f"expected a non-zero vector, got {list(e.direction)}")
        if not e.start < scene.duration:  # layers enter up to the duration only (``emitter_plan``)
            fail(f"{kp}.start", f"expected a time before the scene's duration = {scene.duration} s (it would emit "
                 f"nothing), got {e.start}")
        if e.end is not None and not e.end > e.start:
            fail(f"{kp}.end", f"expected a time after start = {e.start} s, got {e.end}")
        points = nozzle_points(e, d)
        if c is not None:
            lo, hi = np.asarray(c.min, dtype=float), np.asarray(c.max, dtype=float)
            if np.any(points < lo + 0.5 * d) or np.any(points > hi - 0.5 * d):
                fail(kp, f"the nozzle ({len(points)} lattice points around {list(e.position)}) is not inside "
                     f"the container {list(c.min)}..{list(c.max)} (half a spacing from its walls)")
        for j, ob in enumerate(scene.obstacles):
            inside = _obstacle_inside(ob, points)
            if np.any(inside):
                fail(kp, f"the nozzle lies inside obstacles[{j}] ({int(inside.sum())} of its {len(points)} points)")
    for i, s in enumerate(scene.sinks):
        kp = f"sinks[{i}]"
        if not all(a < b for a, b in zip(s.min, s.max)):
            fail(f"{kp}.max", f"expected every component > {kp}.min {list(s.min)}, got {list(s.max)}")
        if c is not None and (np.any(np.asarray(s.max) <= np.asarray(c.min)) or np.any(np.asarray(s.min) >= np.asarray(c.max))):
            fail(kp, f"the box {list(s.min)}..{list(s.max)} lies outside the container {list(c.min)}..{list(c.max)}")


def emission_capacity(scene, initial: int) -> int:
    """Particle capacity: ``max_particles``, or the initial fluid plus every emitter's particles, plus 5 %.
    Raises SceneError when ``max_particles`` is smaller than the initial fluid."""
    from ..core.errors import SceneError

    if scene.max_particles:
        if scene.max_particles < initial:
            raise SceneError(f"{scene.source}: max_particles: expected at least the initial fluid's {initial} "
                             f"particles, got {scene.max_particles}")
        return int(scene.max_particles)
    total = emitted_total(scene)
    return initial + int(math.ceil(1.05 * total)) if total else initial


def nozzle_reference(scene, fluid_x: np.ndarray, fluid_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(fluid positions, velocities) with every nozzle's points and emission velocity appended: the reference
    speed (time-step bound, speed of sound, watchdog speed limit) counts the emitted fluid's height and speed."""
    xs, vs = [fluid_x], [fluid_v]
    for e in scene.emitters:
        plan = emitter_plan(e, scene.spacing, scene.duration)
        xs.append(plan.points)
        vs.append(np.broadcast_to((plan.speed * plan.direction).astype(np.float32), plan.points.shape))
    return np.concatenate(xs), np.concatenate(vs).astype(np.float32)
