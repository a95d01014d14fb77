"""Kinematic bodies: ``[[bodies]]`` with ``kinematic = true`` become animated obstacles (docs/colliders.md).

A kinematic body follows its path (``keyframes`` or ``animation``, as an animated obstacle's) whatever the
fluid does: x = R(t) x_local + T(t), with x_local the body's shape in its own frame, as a dynamic body's
(a box of ``size`` or a sphere of ``radius`` centred at the origin; a mesh scaled by ``scale`` and moved so
that the centroid of its enclosed volume is the origin), T(t) the key's ``translate`` (the centre) and R(t)
its ``rotation``. The keys give the pose outright, so ``position`` and ``rotation`` are refused, as are the
keys of the dynamics (density, mass, velocity, angular_velocity) and ``fluid_friction`` (an animated
obstacle's friction is material.boundary_friction). At validation each becomes an ``Obstacle`` (box min/max
= -/+ size/2, sphere of ``radius`` with center = the origin, or the mesh with translate = -centroid) with the
same path and the name ``body<index>`` unless named, appended to ``scene.obstacles`` and removed from
``scene.bodies``: it is sampled, stepped, written to /sph/bodies/<name> and counted in the work like an
animated obstacle, and it is not a Newton body.
"""
from __future__ import annotations

import numpy as np

#: keys refused alongside kinematic = true, with why
REFUSED = {
    "position": "its pose comes from its keyframes or animation (translate is the centre); remove position",
    "rotation": "its pose comes from its keyframes or animation (each key's rotation); remove rotation",
    "density": "it follows its path whatever the forces, so it has no mass; remove density",
    "mass": "it follows its path whatever the forces, so it has no mass; remove mass",
    "velocity": "its velocity comes from its path; remove velocity",
    "angular_velocity": "its angular velocity comes from its path; remove angular_velocity",
    "fluid_friction": "its fluid friction is material.boundary_friction, as an animated obstacle's; remove "
                      "fluid_friction",
}
PATH_KEYS = ("keyframes", "animation")


def kinematic_raw(v, raw: dict, kp: str) -> tuple[dict, dict]:
    """One raw ``[[bodies]]`` table checked for the kinematic rules (``v.fail`` names the key): the table to
    validate as a Body (path keys out, a placeholder position for a kinematic body) and its path keys."""
    kinematic = raw.get("kinematic", False)
    if not isinstance(kinematic, bool):
        v.fail(f"{kp}.kinematic", f"expected true or false, got {kinematic!r}")
    nested = {k: raw[k] for k in PATH_KEYS if k in raw}
    if not kinematic:
        for k in (*PATH_KEYS, "interpolation"):
            if k in raw:
                v.fail(f"{kp}.{k}", "only a kinematic body follows a path: add kinematic = true (the fluid then "
                       f"does not move it) or remove {k}")
        return raw, {}
    for k, why in REFUSED.items():
        if k in raw:
            v.fail(f"{kp}.{k}", f"not used by a kinematic body (kinematic = true): {why}")
    if not nested:
        v.fail(f"{kp}.kinematic", "a kinematic body needs a path: keyframes = [{time = ..., translate = [...]}, "
               "...] or animation = {file = ..., prim = ...}")
    out = {k: val for k, val in raw.items() if k not in nested}
    out["position"] = (0.0, 0.0, 0.0)  # placeholder for the required key; the path gives the pose
    out.setdefault("interpolation", "smooth")
    return out, nested


def kinematic_obstacles(obstacles: list, bodies: list, fail) -> tuple[list, list]:
    """(obstacles with the kinematic bodies appended as animated obstacles, the dynamic bodies). A dynamic
    body without a name gets body<its index as written>, so names do not shift when kinematic ones leave."""
    if not any(b.kinematic for b in bodies):
        return obstacles, bodies
    from .meshes import load_triangle_mesh
    from .mesh_volume import volume_and_centroid
    from .types import Obstacle

    out_ob, out_b = list(obstacles), []
    for i, b in enumerate(bodies):
        kp = f"bodies[{i}]"
        if not b.kinematic:
            b.name = b.name or f"body{i}"
            out_b.append(b)
            continue
        common = dict(name=b.name or f"body{i}", interpolation=b.interpolation,
                      keyframes=getattr(b, "keyframes", None), animation=getattr(b, "animation", None))
        if b.shape == "box":
            half = 0.5 * np.asarray(b.size, dtype=float)
            if not np.all(half > 0.0):
                fail(f"{kp}.size", f"expected every component > 0, got {list(b.size)}")
            ob = Obstacle(shape="box", min=tuple(map(float, -half)), max=tuple(map(float, half)), **common)
        elif b.shape == "sphere":
            ob = Obstacle(shape="sphere", center=(0.0, 0.0, 0.0), radius=float(b.radius), **common)
        else:
            mesh = load_triangle_mesh(b.file)
            volume, centroid = volume_and_centroid(mesh.vertices * float(b.scale), np.asarray(mesh.triangles))
            if not abs(volume) > 0.0:
                fail(f"{kp}.file", f"mesh {b.file!r} encloses no volume")
            ob = Obstacle(shape="mesh", file=b.file, scale=float(b.scale),
                          translate=tuple(map(float, -np.asarray(centroid))), **common)
        ob.path = b.path
        ob.origin = kp  # named in the cross checks' messages
        out_ob.append(ob)
    return out_ob, out_b
