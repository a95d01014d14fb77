"""Checkpoints: what a resume needs, and what it belongs to.

A checkpoint ``checkpoints/checkpoint_NNNNNN.npz`` holds the state of frame N (positions relative to
the model origin, velocities, step, time, the max speed that sizes the next substep, the solver's
own arrays, the forces' carried arrays, the rigid bodies' Newton state (``rigid_*``), the per-frame statistics so far) and what it belongs to: the layout version, the hash
of run.json's scene, the particle counts, the solver and the software versions. ``check_checkpoint``
refuses one that belongs to another scene, particle count, solver or a newer layout.
"""
from __future__ import annotations

import hashlib
import json
import platform
from pathlib import Path

import numpy as np
import warp as wp

from ..core.errors import OutputError
from ..core.version import __version__
from ..io import atomic

#: version of the checkpoint layout (``checkpoint_info``); a newer one is refused on resume
CHECKPOINT_FORMAT = 2


def versions() -> dict:
    """Versions of warp-sph, Warp, NumPy, Python, the platform and usd-core (run.json, checkpoints)."""
    import numpy

    out = {"warp_sph": __version__, "warp": wp.__version__, "numpy": numpy.__version__,
           "python": platform.python_version(), "platform": platform.platform()}
    try:
        from pxr import Usd

        out["usd"] = ".".join(str(v) for v in Usd.GetVersion())
    except Exception:
        pass
    return out


def scene_hash(scene_dict: dict) -> str:
    """sha256 of a scene (``Scene.to_dict()`` or run.json's ``scene``), independent of key order."""
    canonical = json.dumps(json.loads(atomic.to_json(scene_dict)), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode()).hexdigest()


def checkpoint_info(sim, frame: int, frame_log: list[dict], digest: str = "") -> dict:
    """Host part of a checkpoint of ``frame`` (positions and velocities come from the frame's snapshot).

    Holds the step count, frame, time, the max speed that sizes the next substep, any arrays the
    solver carries between steps, and the per-frame statistics so far (run.json may lag behind);
    and what it belongs to (``check_checkpoint``): the layout version, ``digest`` (scene_hash of
    run.json's scene), the particle counts, the solver and the software versions.
    """
    s = sim.state
    last = sim.last_frame.max_speed if sim.last_frame else 0.0
    extra = dict(sim.solver.checkpoint_arrays())
    extra.update(sim.forces.checkpoint_arrays())  # e.g. a warm start or a carried angular velocity
    if sim.bodies is not None:  # Newton's state: a resume continues bit for bit
        extra.update(sim.bodies.checkpoint_arrays())
    for part in sim.parts:  # animated obstacles' work, whitewater particles, emitters' and sinks' state
        extra.update(part.checkpoint_arrays())
    # copies: on the CPU ``numpy()`` is a view of the live array, and a checkpoint is written on the
    # export thread while the next frame already runs (a solver's carried warm-start values change)
    extra = {k: np.array(a.numpy() if isinstance(a, wp.array) else a, copy=True) for k, a in extra.items()}
    v = versions()
    return dict(step=np.int64(s.step), frame=np.int64(frame), state_frame=np.int64(s.frame),
                time=np.float64(s.time), last_max_speed=np.float64(last),
                frame_log=np.array(atomic.to_json(frame_log)),
                checkpoint_format=np.int64(CHECKPOINT_FORMAT), scene_hash=np.array(digest or scene_hash(sim.scene.to_dict())),
                fluid_count=np.int64(sim.model.fluid_count), boundary_count=np.int64(sim.model.boundary_count),
                solver=np.array(sim.scene.solver), warp_sph_version=np.array(v["warp_sph"]),
                warp_version=np.array(v["warp"]), **extra)


def check_checkpoint(cp: dict, path: Path, run_scene: dict, sim, log=print) -> None:
    """Refuse (OutputError, one line) a checkpoint that belongs to another scene, particle count,
    solver, checkpoint layout or warp-sph / Warp version than the run it is in."""
    m = sim.model
    n = len(cp["particle_x_local"])
    if sim.flow is not None:  # emitters and sinks: the count changes; the capacity bounds it
        if n > m.capacity or "flow_ids" not in cp:
            raise OutputError(f"{path}: holds {n} fluid particles without the emitters' state, or more than the "
                              f"capacity {m.capacity}; the checkpoint belongs to another scene")
    elif n != m.fluid_count:
        raise OutputError(f"{path}: holds {n} fluid particles, the scene of run.json has {m.fluid_count}; "
                          "the checkpoint belongs to another scene")
    fmt = int(cp["checkpoint_format"]) if "checkpoint_format" in cp else 1
    if fmt > CHECKPOINT_FORMAT:
        raise OutputError(f"{path}: checkpoint layout {fmt} is newer than this warp-sph reads "
                          f"({CHECKPOINT_FORMAT}); resume with the version that wrote it")
    if "scene_hash" in cp and str(cp["scene_hash"]) != scene_hash(run_scene):
        raise OutputError(f"{path}: written for another scene than the one in run.json (scene hash "
                          f"{str(cp['scene_hash'])[:12]} vs {scene_hash(run_scene)[:12]}); was run.json edited?")
    for key, want in ((("fluid_count", m.fluid_count),) if sim.flow is None else ()) + (("boundary_count", m.boundary_count),):
        if key in cp and int(cp[key]) != want:
            raise OutputError(f"{path}: {key.replace('_', ' ')} {int(cp[key])}, the scene of run.json has {want}")
    if "solver" in cp and str(cp["solver"]) != sim.scene.solver:
        raise OutputError(f"{path}: written by the {str(cp['solver'])} solver, the scene uses {sim.scene.solver}")
    now = versions()
    for key, name in (("warp_sph_version", "warp_sph"), ("warp_version", "warp")):
        if key in cp and str(cp[key]) != now[name]:
            raise OutputError(f"{path}: written with {name} {str(cp[key])}, this is {now[name]}; a resume continues "
                              f"bit for bit only with the versions that started the run: install {name}=="
                              f"{str(cp[key])} to resume it, or run the scene again from the start")
