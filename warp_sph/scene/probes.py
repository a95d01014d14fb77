"""Checks of ``[[probes]]`` before anything is sampled: names, probes inside the container, line lengths.

A pressure point and both ends of a height or front line must lie in the container (its faces
included: a wall probe sits on the face); a line without ``length`` runs to the container wall. The
rate against the time step is checked once the solver is known (``warp_sph.run.probes.Probes.check``).
"""
from __future__ import annotations

import math
import re

import numpy as np

_NAME = re.compile(r"[A-Za-z0-9_-]+")


def _wall_distance(start: np.ndarray, direction: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """Distance [m] from ``start`` (inside the box) along the unit ``direction`` to the box's faces."""
    s = math.inf
    for a in range(3):
        if direction[a] > 0.0:
            s = min(s, (hi[a] - start[a]) / direction[a])
        elif direction[a] < 0.0:
            s = min(s, (lo[a] - start[a]) / direction[a])
    return s


def check_probes(scene, fail) -> None:
    """Fill in names and line lengths; ``fail(keypath, message)`` on a bad name, a duplicate, a probe outside
    the container, a zero axis or a line without a length in a scene without a container."""
    c = scene.container
    lo = hi = None
    if c is not None:
        lo, hi = np.asarray(c.min, dtype=float), np.asarray(c.max, dtype=float)
        tol = 1e-9 * max(1.0, float(np.abs(np.concatenate([lo, hi])).max()))
    seen = {}
    for i, p in enumerate(scene.probes):
        kp = f"probes[{i}]"
        if p.name and not _NAME.fullmatch(p.name):
            fail(f"{kp}.name", f"expected letters, digits, '-' and '_' (it names probe_<name>.csv), got {p.name!r}")
        p.name = p.name or f"probe{i}"
        if p.name in seen:
            fail(f"{kp}.name", f"{p.name!r} is already the name of probes[{seen[p.name]}]; names must differ")
        seen[p.name] = i
        start = np.asarray(p.position, dtype=float)
        if lo is not None and (np.any(start < lo - tol) or np.any(start > hi + tol)):
            fail(f"{kp}.position", f"{list(p.position)} is outside the container {list(c.min)}..{list(c.max)}; "
                 "a probe reads the fluid inside it (a wall probe lies on the wall's face)")
        if p.kind == "pressure":
            continue
        if p.kind == "front":
            a = np.asarray(p.axis, dtype=float)
            if not np.linalg.norm(a) > 0.0:
                fail(f"{kp}.axis", f"expected a non-zero direction, got {list(p.axis)}")
            direction = a / np.linalg.norm(a)
        else:
            direction = np.array([0.0, 0.0, 1.0])
        if p.length is None:
            if lo is None:
                fail(f"{kp}.length", "missing; expected the line's length [m] (a scene without a container has no "
                     "wall for the line to run to)")
            p.length = float(_wall_distance(start, direction, lo, hi))
            if not p.length > 0.0:
                fail(f"{kp}.position", f"{list(p.position)} lies on the container wall the line runs to; "
                     "move it inside or give length")
        elif lo is not None:
            end = start + p.length * direction
            if np.any(end < lo - tol) or np.any(end > hi + tol):
                fail(f"{kp}.length", f"the line from {list(p.position)} ends at {np.round(end, 6).tolist()}, outside "
                     f"the container {list(c.min)}..{list(c.max)}; expected at most "
                     f"{_wall_distance(start, direction, lo, hi):.6g} m")
