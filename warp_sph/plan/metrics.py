"""The errors a plan can target: the mean density error of every scene and, for a validation scene, its errors
against the published experiment (``--target-error front:4%``).

A scene is a validation case when its ``name`` is that of a case's scene file in ``scenes/validation/`` and it
has the probes the case reads (``warp-sph bench validation``: ``benchmarks/validation.py``). The figures are
that bench's own (``validation.evaluate`` over the run's probe CSVs, with the experiments' data and the error
functions of ``warp_sph/validation/errors.py``), read from each calibration run before its folder is removed:

martin_moyce  front     relative RMS of the surge front Z = x/a against Martin & Moyce 1952 (best start shift)
              residual  RMS of the residual height over the initial height
lobovsky      sensor1, sensor3, sensor4   |relative error| of the filtered pressure peak (Lobovsky et al. 2014)
hydrostatic   floor, middle   |p / (rho0 g (h - z)) - 1| over the second half of the run (hydrostatic_probes)

An error against an experiment is defined over the experiment's span (a pressure peak comes with the impact),
so with a reference metric the calibration runs cover the scene's whole duration (``calibration_time``).
"""
from __future__ import annotations

import tomllib
from functools import lru_cache

from ..core.errors import PlanError

#: the metric every scene has: run.json's per-frame mean density error, averaged over the frames
DENSITY = "density"

#: case -> metric -> (the bench's figure, its probe, what it is)
CASE_METRICS = {
    "martin_moyce": {"front": ("front_rms", "front", "relative RMS of the surge front (Martin & Moyce 1952)"),
                     "residual": ("residual_rms", "residual", "RMS of the residual height / initial height")},
    "lobovsky": {s: (s, s, f"|error| of the pressure peak at {s} (Lobovsky et al. 2014)")
                 for s in ("sensor1", "sensor3", "sensor4")},
    "hydrostatic": {"floor": ("floor_error", "floor", "|error| of the floor pressure against rho0 g (h - z)"),
                    "middle": ("middle_error", "middle", "|error| of the mid-depth pressure against rho0 g (h - z)")},
}


@lru_cache(maxsize=None)
def _case_scene_names() -> dict:
    """{scene name in the case's file: case} of the validation cases; a file two cases share is the first's (the
    hydrostatic tank's, not hydrostatic_fcc's, which starts the same file on another lattice)."""
    from ..validation.cases import CASES, _scene_dir

    out = {}
    for name, case in CASES.items():
        try:
            out.setdefault(tomllib.loads((_scene_dir() / case.scene).read_text())["name"], name)
        except (OSError, KeyError, tomllib.TOMLDecodeError):
            continue
    return out


def reference_case(scene) -> str | None:
    """The validation case ``scene`` is (by its name, with at least one of the probes the case reads), or None."""
    case = _case_scene_names().get(scene.name)
    if case is None or case not in CASE_METRICS:
        return None
    probes = {p.name for p in scene.probes}
    return case if any(probe in probes for _, probe, _ in CASE_METRICS[case].values()) else None


def metric_names(scene) -> list[str]:
    """The metrics ``scene`` can target: "density", then its validation case's whose probe it has."""
    case = reference_case(scene)
    if case is None:
        return [DENSITY]
    probes = {p.name for p in scene.probes}
    return [DENSITY] + [m for m, (_, probe, _) in CASE_METRICS[case].items() if probe in probes]


def check_metric(scene, metric: str) -> str:
    """``metric`` when ``scene`` has it; PlanError (one line listing the metrics it has) otherwise."""
    names = metric_names(scene)
    if metric in names:
        return metric
    known = sorted({m for c in CASE_METRICS.values() for m in c})
    why = ("it is not a validation case (no experiment to compare with: scenes/validation/, docs/validation.md)"
           if reference_case(scene) is None else f"it is validation case {reference_case(scene)!r}")
    what = "an error against an experiment" if metric in known else "an unknown metric"
    raise PlanError(f"--target-error {metric}:...: {what} for scene {scene.name!r}: {why}; its metrics: "
                    f"{', '.join(names)}")


def case_overrides(scene, radius: float) -> list[str]:
    """The per-radius overrides ``warp-sph bench validation`` gives the case's scene at ``radius`` [m] (the
    surge-front line 1.25 d above the floor's particles), none for another scene."""
    case = reference_case(scene)
    if case is None:
        return []
    from ..validation.cases import CASES

    return [f(2.0 * radius) for f in CASES[case].overrides.values()]


def calibration_time(scene, metric: str, default: float) -> float:
    """Simulated seconds of a calibration run for ``metric``: ``default`` for the density error, the scene's
    duration for an error against an experiment."""
    return default if metric == DENSITY else max(default, float(scene.duration))


def evaluate_reference(scene, folder, info: dict) -> dict:
    """{metric: error} of a finished run of a validation scene in ``folder`` (None where the run's span holds no
    experimental point), {} for another scene or a run without its probe files."""
    case = reference_case(scene)
    if case is None or not info.get("probes"):
        return {}
    from ..validation.cases import evaluate

    try:
        figures, _, _ = evaluate(case, folder, info)
    except (OSError, ValueError, KeyError, IndexError):
        return {}
    out = {}
    for metric, (figure, probe, _) in CASE_METRICS[case].items():
        v = figures.get(figure)
        if isinstance(v, dict):  # a pressure sensor: its peak
            v = v.get("peak_error")
        out[metric] = None if v is None else abs(float(v))
    return out
