"""A calibration point's scene: the user's scene with one candidate solver, particle radius and density
tolerance (``variant``), and the solver's tolerance key and the scene's value of it. Used by the calibration runs
(``points.py``), the calibration (``calibrate.py``) and the plan's output (``report.py``).
"""
from __future__ import annotations

from pathlib import Path


def tolerance_key(solver: str) -> str | None:
    """The scene key of ``solver``'s density tolerance (``<solver>.target_density_error`` where the parameter
    registry declares it: PBF, DFSPH), None for a solver without one (WCSPH: its compressibility follows from
    the speed of sound)."""
    from ..methods.registry import solver as solver_class

    key = f"{solver}.target_density_error"
    return key if any(p.path == key for p in solver_class(solver).parameters) else None


def scene_tolerance(scene, solver: str) -> float | None:
    """The scene's value of ``solver``'s density tolerance (None: the solver has none)."""
    key = tolerance_key(solver)
    if key is None:
        return None
    section, name = key.split(".")
    return float(scene.to_dict().get(section, {}).get(name, _default(key)))


def _default(key: str) -> float:
    from ..methods.registry import solver as solver_class

    return next(p.default for p in solver_class(key.split(".")[0]).parameters if p.path == key)


def variant_dict(scene, solver: str, radius: float, tolerance: float | None = None) -> dict:
    """The scene dict with ``solver``, ``particle_radius`` [m] and the solver's tolerance (None: the scene's),
    without a [plan] table; a validation scene's probes placed for the radius (``metrics.case_overrides``)."""
    from ..scene.load import apply_overrides
    from .metrics import case_overrides

    d = scene.to_dict()
    d["solver"] = solver
    d["particle_radius"] = float(radius)
    d.pop("plan", None)
    key = tolerance_key(solver)
    if key is not None and tolerance is not None:
        section, name = key.split(".")
        d.setdefault(section, {})[name] = float(tolerance)
    extra = case_overrides(scene, radius)
    return apply_overrides(d, extra) if extra else d


def variant(scene, solver: str, radius: float, tolerance: float | None = None):
    """The scene with ``solver``, ``particle_radius`` and tolerance (``variant_dict``; validated again: a refusal is
    a SceneError)."""
    from ..scene import scene_from_dict

    base = Path(scene.source).parent if str(scene.source).endswith(".toml") else None
    return scene_from_dict(variant_dict(scene, solver, radius, tolerance), source=scene.source, base_dir=base)
