"""``container.inner``: the container's box as the tank's inner faces (the water's boundary), not its wall planes.

The fluid's first layer rests a wall gap g d (``scene.wall_gap``, about 1.1 d) from a wall's particles and each
particle fills r = d/2 around its centre, so the water starts the water offset o = g d - r (about 0.6 d) inside
each wall's particle plane. By default the container's min/max are the particle planes, and water given flush
with a wall loses o there (a 0.3 m column is 0.28 m high at r = 10 mm). With ``inner = true`` the loader moves
the six particle planes o outward, so the water fills the given box exactly at every resolution (an
experiment's tank and column keep their measured sizes), and a probe on a face of the box moves with its wall
plane; its other coordinates (a sensor's height above the tank's floor) stay as given. ``to_dict`` gives the
box and probes back as written (``inner = true``), so a scene changed and loaded again (``warp-sph plan`` at
another radius, run.json) places its walls for its own radius.
"""
from __future__ import annotations

import dataclasses


def water_offset(scene) -> float:
    """o = g d - r [m]: how far the water's boundary lies inside a container wall's particle plane."""
    return float(scene.wall_gap - scene.particle_radius)


def resolve_inner(scene):
    """``scene`` with ``container.inner`` applied: the container's min/max moved ``water_offset`` outward (``inner``
    false on the result: its min/max are the wall planes), every probe whose position lies on a face of the given
    box moved onto that face's new plane; what was written is kept in ``scene.inner_given`` for ``to_dict``. A
    scene without ``inner`` is returned as it is."""
    c = scene.container
    if c is None or not c.inner:
        return scene
    off = water_offset(scene)
    lo, hi = [float(v) for v in c.min], [float(v) for v in c.max]
    probes = []
    for p in scene.probes:
        pos = [float(v) for v in p.position]
        for a in range(3):
            if abs(pos[a] - lo[a]) <= 1e-9:
                pos[a] = lo[a] - off
            elif abs(pos[a] - hi[a]) <= 1e-9:
                pos[a] = hi[a] + off
        probes.append(dataclasses.replace(p, position=tuple(pos)))
    box = dataclasses.replace(c, min=tuple(v - off for v in lo), max=tuple(v + off for v in hi), inner=False)
    given = {"container": c, "positions": [p.position for p in scene.probes], "walls": box,
             "moved": [p.position for p in probes]}
    return dataclasses.replace(scene, container=box, probes=probes, inner_given=given)


def given_box(scene, out: dict) -> None:
    """In ``out`` (``scene.to_dict()``'s plain dict) the container and probe positions as written, where the scene
    still has the walls and probes ``resolve_inner`` made (a container or probe changed since keeps its own)."""
    g = scene.inner_given
    if scene.container == g["walls"]:
        out["container"] = {**out["container"], "min": list(g["container"].min), "max": list(g["container"].max),
                            "inner": True}
    plain = out.get("probes", [])
    for i, p in enumerate(scene.probes):
        if i < len(g["moved"]) and tuple(p.position) == tuple(g["moved"][i]):
            plain[i]["position"] = list(g["positions"][i])
