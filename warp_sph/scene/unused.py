"""Valid scene keys that change nothing in this scene: one warning line each, the run goes on.

A scene may carry the tables of several methods (``[pbf]`` tuning kept for a ``--set solver=pbf`` run), so a
key of a method not chosen is not an error (a key no table knows is, in ``validate``); but one that differs
from its default is named, with the method in use and the setting that would make it count:

    mine.toml: pbf.max_iterations: no effect with solver 'dfsph' (the [pbf] keys apply with solver = 'pbf',
    e.g. --set solver=pbf)

Keys at their defaults are not named: a scene written out whole (``Scene.to_dict``: every table, as
``plan --apply`` writes it) loads without a warning. ``load_scene`` warns (``UnusedKeyWarning``); for a
built-in scene only of the keys given with ``--set`` (the built-in scenes carry each solver's tuning on purpose).
"""
from __future__ import annotations

from ..methods import registry
from .parameters import all_parameters, by_section

#: keys of a method's table that every method reads: the fluid's speed of sound c_s comes from these whatever
#: the solver (``warp_sph.core.model._speed_of_sound``: the Akinci friction and the penalty force scale with it)
SHARED_KEYS = {"wcsph": ("equation_of_state", "speed_of_sound", "speed_of_sound_factor", "stiffness")}
#: the boundary method whose friction term alone reads material.boundary_friction and bodies[].fluid_friction
FRICTION_BOUNDARY = "akinci2012"

class UnusedKeyWarning(UserWarning):
    """A scene key that is valid but changes nothing in this scene (another method's key)."""


def unused_keys(data: dict, scene, only: set | None = None) -> list[str]:
    """The warning lines (module docstring) for the scene dict ``data`` as written (overrides applied) and its
    validated ``scene``. only: the (table, key) pairs to consider (None: every key)."""
    if not isinstance(data, dict):
        return []
    in_use = {**{n: ("solver", scene.solver) for n in registry.solvers()},
              **{n: ("boundary", scene.boundary) for n in registry.boundaries()}}
    params = by_section(all_parameters())
    lines = []
    for name in registry.methods_with_parameters():
        raw = data.get(name)
        what, used = in_use[name]
        if not isinstance(raw, dict) or name == used:
            continue
        values = scene.sections[name]
        changed = [k for k in raw if k in params[name] and getattr(values, k) != params[name][k].default
                   and k not in SHARED_KEYS.get(name, ()) and (only is None or (name, k) in only)]
        if changed:
            keys = ", ".join(f"{name}.{k}" for k in changed)
            lines.append(f"{scene.source}: {keys}: no effect with {what} {used!r} (the [{name}] keys apply with "
                         f"{what} = {name!r}, e.g. --set {what}={name})")
    if scene.boundary != FRICTION_BOUNDARY:
        material = data.get("material") if isinstance(data.get("material"), dict) else {}
        bodies = data.get("bodies") if isinstance(data.get("bodies"), list) else []
        keys = (["material.boundary_friction"] if "boundary_friction" in material and scene.material.boundary_friction
                != 0.0 and (only is None or ("material", "boundary_friction") in only) else [])
        if only is None or ("bodies", "fluid_friction") in only:
            keys += [f"bodies[{i}].fluid_friction" for i, b in enumerate(bodies) if isinstance(b, dict)
                     and "fluid_friction" in b]
        if keys:
            lines.append(f"{scene.source}: {', '.join(keys)}: no effect with boundary {scene.boundary!r} (the "
                         f"friction of the {FRICTION_BOUNDARY} boundary: boundary = {FRICTION_BOUNDARY!r}, e.g. --set "
                         f"boundary={FRICTION_BOUNDARY})")
    return lines
