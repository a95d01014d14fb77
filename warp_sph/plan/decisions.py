"""Hysteresis of ``warp-sph plan``'s timing-dependent decisions: the previous plan of the same request (scene,
machine, budget, target, metric, solvers) is kept in the cache directory, and a plan made again on fresh timings
(``--refresh``, or after another plan added points) keeps its decisions where the new timings move them by less than
DECISION_MARGIN: the chosen setting (``keep_previous``) and the solver that leads the calibration
(``share.rank_solvers``). Without it a 5 % timing change near the budget's threshold moved the chosen radius one rung
of the ladder (12 % in r, about 1.4x the wall time): a plan made twice gave two answers for one question.
"""
from __future__ import annotations

import json
from pathlib import Path

#: a previous decision stands while the new timings move it by at most this fraction past a threshold, and a new one
#: replaces it only when it clears the threshold by as much: two calibrations' timings of one point on 2 shared cores
#: differ by up to 10 % (PBF's whole run over its window: 0.96-1.07 over four plans at load <= 2, ``models.COST_RATIO_NOISE``)
DECISION_MARGIN = 0.1


def request_key(budget_s, target_error, metric: str, solvers) -> str:
    """The plan request a decision belongs to (the scene and the machine are in the file's name)."""
    return json.dumps({"budget": budget_s, "target": target_error, "metric": metric, "solvers": sorted(solvers)},
                      sort_keys=True)


def decisions_path(cache, key: str) -> Path:
    """The decisions file of a scene's calibration key ``key`` (``calibrate.cache_key``) in the cache directory."""
    from .calibrate import cache_dir

    return cache_dir(cache) / f"plan-{key[:20]}.json"


def read_previous(path: Path, request: str) -> dict:
    """The previous plan's decisions for ``request`` ({} where none, or the file is damaged)."""
    try:
        return dict(json.loads(path.read_text()).get(request) or {})
    except (OSError, ValueError, AttributeError, TypeError):
        return {}


def write_decision(path: Path, request: str, chosen, lead: str | None) -> None:
    """Record the plan's decisions for ``request`` (atomically; the other requests' kept)."""
    from ..io.atomic import atomic_write_json

    try:
        data = json.loads(path.read_text()) if path.is_file() else {}
        data = data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        data = {}
    data[request] = {"solver": chosen.solver, "particle_radius": chosen.particle_radius, "tolerance": chosen.tolerance,
                     "lead": lead}
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, data)


def _same(c, previous: dict) -> bool:
    t = previous.get("tolerance")
    return (c.solver == previous.get("solver") and abs(c.particle_radius / previous["particle_radius"] - 1.0) <= 1e-6
            and ((c.tolerance is None and t is None) or (c.tolerance is not None and t is not None
                                                         and abs(c.tolerance / t - 1.0) <= 1e-6)))


def keep_previous(chosen, candidates, previous: dict, budget_s, target_error, memory_limit,
                  margin: float = DECISION_MARGIN):
    """``chosen`` or, where the previous plan of the request chose another setting of the same solver that still
    qualifies within ``margin``, that one: with a budget alone, the previous setting stands while its predicted wall
    time is within BUDGET_SAFETY x the budget x (1 + margin) (its count extrapolation and memory within the limits),
    unless ``chosen`` is finer and clears BUDGET_SAFETY x the budget x (1 - margin); with a target error, while it
    reaches the target and its wall time is within (1 + margin) of ``chosen``'s (and of the budget's share, if any)."""
    from .advisor import BUDGET_SAFETY, MAX_COUNT_EXTRAPOLATION

    if not previous.get("particle_radius") or previous.get("solver") != chosen.solver or _same(chosen, previous):
        return chosen
    prev = next((c for c in candidates if _same(c, previous)), None)
    if prev is None or prev.count_extrapolation > MAX_COUNT_EXTRAPOLATION or (
            memory_limit is not None and prev.memory > memory_limit):
        return chosen
    limit = BUDGET_SAFETY * budget_s if budget_s is not None else None
    if limit is not None and prev.wall_time > limit * (1.0 + margin):
        return chosen
    if target_error is not None:
        return prev if prev.error <= target_error and prev.wall_time <= chosen.wall_time * (1.0 + margin) else chosen
    if chosen.particle_radius < prev.particle_radius and chosen.wall_time <= limit * (1.0 - margin):
        return chosen
    return prev
