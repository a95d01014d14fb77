"""The advisor of ``warp-sph plan``: the candidates and the recommendation, from the models (``models.py``).

Each candidate is a solver, one of its tolerances and a radius r: its particles, substeps, wall time and errors
predicted by the solver's models over the scene's duration, memory by ``run.memory.estimate_memory`` at the
predicted counts. A candidate at another tolerance than the scene's t0 counts its extrapolation from the
particle count the tolerance's effect was measured at (measured, hydrostatic 0.5 s: DFSPH at t0 / 4 with 14x
the pair's count took 3.8x its prediction: the iterations a tolerance costs grow with the resolution).
The candidates are the solvers x their tolerances x a geometric ladder of radii from the coarsest stable one
down to 64x finer than the finest calibrated; each says how far it extrapolates beyond the calibrated counts.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from .calibrate import Calibration, PlanError, coarsest_radius, variant
from .fit import extrapolation
from .metrics import DENSITY
from .models import (ORDER_RANGE, TOLERANCE_LADDER, SolverModel, fit_models, process_overhead,  # noqa: F401
                     run_density_error, tolerance_exponents)

#: a plan chooses settings whose predicted wall time is at most this fraction of the budget
BUDGET_SAFETY = 0.8
#: radii of the candidate ladder per halving of the radius
LADDER_PER_OCTAVE = 6
#: the finest candidate: this factor below the finest calibrated radius
LADDER_DEPTH = 64.0
#: a plan chooses no setting with more particles than this factor times the largest calibrated count; ``plan``
#: calibrates a finer point first when the budget allows (CALIBRATION_SHARE)
MAX_COUNT_EXTRAPOLATION = 4.0  # measured: a 5.7x extrapolation took 1.57x its prediction (bench plan, dam break)
#: a calibration round adds a point with at most this factor more particles than the largest calibrated one
STEP_UP = 4.0
#: the calibration may take at most this fraction of the budget (the points a plan adds to reach a budget)
CALIBRATION_SHARE = 0.1
#: the calibration's decisions keep within this fraction of CALIBRATION_SHARE, each run's predicted cost times what
#: the runs so far took over their prediction: room for the last run's own error (measured, 60 s budgets: the
#: calibration took 10.2 % and 10.4 % of the budget planned for 10 %, its last finer point's cost under-predicted)
CALIBRATION_MARGIN = 0.85


@dataclass
class Candidate:
    """One setting and its predicted figures (wall time [s], memory [bytes], mean density error [-])."""

    solver: str
    particle_radius: float
    tolerance: float | None
    fluid_particles: int
    boundary_particles: int
    steps: int
    wall_time: float
    memory: int
    density_error: float
    count_extrapolation: float     # N / the largest calibrated N (1: inside the calibrated range)
    spacing_extrapolation: float   # finest calibrated d / d (1: inside)
    pareto: bool = False
    metric: str = DENSITY          # the error the plan targets
    metric_error: float | None = None   # [-] that error against the experiment (None: the density error)
    tolerance_extrapolation: float = 1.0  # N / the particles the tolerance's effect was measured at (1: t0, or inside)

    @property
    def particles(self) -> int:
        """Fluid and boundary particles."""
        return self.fluid_particles + self.boundary_particles

    @property
    def error(self) -> float:
        """The targeted error [-]: the metric's, else the mean density error."""
        return self.density_error if self.metric_error is None else self.metric_error

    def extrapolated(self) -> str:
        """In words: which figures are extrapolated and how far ("" when inside the calibrated range)."""
        parts = []
        if self.count_extrapolation > 1.05:
            parts.append(f"{self.count_extrapolation:.3g}x the largest calibrated count (wall time)")
        if self.spacing_extrapolation > 1.05:
            parts.append(f"{self.spacing_extrapolation:.3g}x finer than calibrated (error, steps)")
        if self.tolerance_extrapolation > 1.05:
            parts.append(f"the tolerance's effect {self.tolerance_extrapolation:.3g}x beyond the count it was measured at")
        return "; ".join(parts)

    def to_dict(self) -> dict:
        """The candidate as plain JSON types, with ``extrapolated`` in words."""
        return {**asdict(self), "extrapolated": self.extrapolated()}


@dataclass
class Plan:
    """A recommendation: the chosen candidate, the alternatives, every candidate, the models and the
    calibration. ``budget_s`` [s] and ``target_error`` [-] as asked (None: not asked)."""

    scene: str
    source: str
    chosen: Candidate
    alternatives: list = field(default_factory=list)   # the best candidate of each other solver
    candidates: list = field(default_factory=list)
    models: dict = field(default_factory=dict)          # solver -> SolverModel
    budget_s: float | None = None
    target_error: float | None = None
    duration: float = 0.0
    frames: int = 0
    calibration_seconds: float = 0.0
    calibration_cached: bool = False
    cache_path: str = ""
    machine: str = ""
    failed_solvers: dict = field(default_factory=dict)  # solver -> one-line reason
    metric: str = DENSITY                               # the error targeted (``metrics.py``)
    notes: list = field(default_factory=list)           # what the calibration left out and why
    points: list = field(default_factory=list)          # the calibration runs the plan used (``point_summary``)

    @property
    def budget_used(self) -> float | None:
        """[-] the chosen setting's predicted wall time over the budget (None without a budget)."""
        return self.chosen.wall_time / self.budget_s if self.budget_s else None

    def prediction(self) -> dict:
        """The chosen setting's predicted figures, as the scene's [plan] table stores them."""
        c = self.chosen
        out = {"wall_time": float(c.wall_time), "density_error": float(c.density_error), "steps": int(c.steps),
               "fluid_particles": int(c.fluid_particles), "memory": float(c.memory),
               "budget": float(self.budget_s or 0.0), "target_error": float(self.target_error or 0.0)}
        if c.metric_error is not None:
            out.update(metric=c.metric, metric_error=float(c.metric_error))
        return out

    def to_dict(self) -> dict:
        """The plan as plain JSON types (``warp-sph bench plan`` records it)."""
        return {"scene": self.scene, "source": self.source, "budget_s": self.budget_s, "budget_used": self.budget_used,
                "metric": self.metric,
                "notes": self.notes, "target_error": self.target_error, "duration": self.duration, "frames": self.frames,
                "chosen": self.chosen.to_dict(), "alternatives": [c.to_dict() for c in self.alternatives],
                "candidates": [c.to_dict() for c in self.candidates],
                "models": {k: m.to_dict() for k, m in self.models.items()},
                "calibration_seconds": self.calibration_seconds, "calibration_cached": self.calibration_cached,
                "cache_path": self.cache_path, "machine": self.machine, "failed_solvers": self.failed_solvers,
                "points": self.points}


def point_summary(p, whole: bool = False, timing: bool = False) -> dict:
    """A calibration run's figures as the plan's record keeps them: solver, radius [m], tolerance, counts, frames,
    steps, steady step time [s], solver sweeps per step, wall time [s] of the run and of the whole calibration
    point, process CPU seconds per wall second of its steps (``points.cpu_per_wall``), mean and last density error; ``whole``: a whole-duration run (the error profile), with its frames' steps
    and process CPU time [s] (the course C, ``points.course_ratio``); ``timing``: a timing-only point past the CPU's
    last-level cache (``past_cache.py``: in the step's cost only)."""
    from .points import cpu_per_wall

    course = {"frame_steps": p.frame_steps, "frame_cpu": p.frame_cpu} if whole else {}
    return {**course, "solver": p.solver, "particle_radius": p.particle_radius, "tolerance": p.tolerance, "status": p.status,
            "fluid": p.fluid, "boundary": p.boundary, "frames": p.frames, "steps": p.steps, "step_time": p.step_time,
            "sweeps": p.sweeps, "wall_time": p.wall_time, "seconds": p.seconds, "first_in_process": p.first_in_process,
            "array_bytes": p.array_bytes, "cpu_per_wall": cpu_per_wall(p),
            "density_error_mean": p.density_error_mean, "density_error_last": p.density_error_last, "whole_run": whole,
            "timing_only": timing}


def predict(scene, model: SolverModel, radius: float, tolerance: float | None = None) -> Candidate:
    """The predicted figures of ``scene`` with the model's solver at ``radius`` [m] and ``tolerance`` [-] (None:
    the scene's) over the scene's duration."""
    from ..run.memory import estimate_memory

    tolerance = model.tolerance if tolerance is None else tolerance
    s = variant(scene, model.solver, radius, tolerance)  # a radius the scene refuses raises here
    d = 2.0 * radius
    fluid, boundary = model.fluid_count(d), model.boundary_count(d)
    n = fluid + boundary
    frames = int(round(scene.duration * scene.fps))
    steps = max(model.steps_per_second.steps(d, scene.duration, model.tolerance_factor("steps_per_second", tolerance)),
                frames)
    step = model.step_cost(fluid, boundary, d) * model.tolerance_factor("step_time", tolerance)
    wall = model.load_time + model.setup_time(n) + steps * step + frames * model.frame_overhead(n)
    mem = estimate_memory(s, fluid, boundary)
    # another tolerance than the scene's: its effect was measured at one particle count (iterations grow with the
    # resolution), so its extrapolation counts from there
    tol_ext = 1.0
    if model.tolerance_particles and abs(tolerance / model.tolerance - 1.0) > 1e-6:
        tol_ext = max(n / model.tolerance_particles, 1.0)
    metric_error = None
    if model.metric_error is not None:
        metric_error = float(model.metric_error(d) * model.tolerance_factor("metric", tolerance))
    return Candidate(solver=model.solver, particle_radius=radius, tolerance=tolerance,
                     fluid_particles=fluid, boundary_particles=boundary, steps=steps, wall_time=float(wall),
                     memory=int(mem["device"] + mem["host"]),
                     density_error=float(run_density_error(model, d, frames, tolerance)),
                     count_extrapolation=max(extrapolation(n, min(model.calibrated_particles),
                                                           max(model.calibrated_particles)), tol_ext),
                     tolerance_extrapolation=tol_ext,
                     spacing_extrapolation=max(min(model.calibrated_radii) / radius, 1.0),
                     metric=model.metric, metric_error=metric_error)


def ladder(scene, models: dict) -> list[float]:
    """The candidate radii [m]: from the coarsest calibrated radius (the coarsest setting known to run) down to
    LADDER_DEPTH below the finest calibrated, LADDER_PER_OCTAVE per halving."""
    r_max = min(coarsest_radius(scene), max(max(m.calibrated_radii) for m in models.values()))
    r_min = min(min(m.calibrated_radii) for m in models.values()) / LADDER_DEPTH
    out, k = [], 0
    while True:
        r = r_max * 2.0 ** (-k / LADDER_PER_OCTAVE)
        if r < r_min:
            return out
        out.append(float(f"{r:.4g}"))
        k += 1


def mark_pareto(candidates: list) -> None:
    """Set ``pareto`` on the candidates no other beats in both wall time and error."""
    from ..sweep.runs import pareto_front

    for c, p in zip(candidates, pareto_front([c.wall_time for c in candidates], [c.error for c in candidates])):
        c.pareto = p


def choose(candidates: list, budget_s: float | None, target_error: float | None, memory_limit: float | None,
           source: str, max_extrapolation: float | None = MAX_COUNT_EXTRAPOLATION) -> Candidate:
    """The recommendation. With a budget only: the finest resolution whose predicted wall time is within
    BUDGET_SAFETY of the budget (what a budget buys; between solvers at the same radius the smaller predicted
    error, then the shorter time). With a target error: the cheapest setting that reaches it (within the budget
    when both are given). PlanError (one line, with the closest feasible setting) when none qualifies."""
    fits = [c for c in candidates if (memory_limit is None or c.memory <= memory_limit)
            and (max_extrapolation is None or c.count_extrapolation <= max_extrapolation)]
    if not fits:
        raise PlanError(f"{source}: no candidate setting fits in memory ({memory_limit / 2**30:.3g} GiB available)")
    in_budget = [c for c in fits if budget_s is None or c.wall_time <= BUDGET_SAFETY * budget_s]
    if budget_s is not None and not in_budget:
        best = min(fits, key=lambda c: c.wall_time)
        raise PlanError(f"{source}: --budget {budget_s:g} s is too small: the cheapest stable setting ({describe(best)}) "
                        f"is predicted to take {best.wall_time:.3g} s (plans keep {100 * BUDGET_SAFETY:.0f} % of the "
                        f"budget); give --budget {math.ceil(best.wall_time / BUDGET_SAFETY)}s or more")
    if target_error is not None:
        ok = [c for c in in_budget if c.error <= target_error]
        if not ok:
            best = min(in_budget, key=lambda c: (c.error, c.wall_time))
            within = f" within --budget {budget_s:g} s" if budget_s is not None else " that fits in memory"
            name = "" if best.metric == DENSITY else f"{best.metric}:"
            raise PlanError(f"{source}: --target-error {name}{100 * target_error:.3g}% is below what the finest "
                            f"affordable setting{within} reaches: {describe(best)} gives {100 * best.error:.3g} % in "
                            f"{best.wall_time:.3g} s")
        return min(ok, key=lambda c: (c.wall_time, c.error))
    return min(in_budget, key=lambda c: (c.particle_radius, c.error, c.wall_time))


def describe(c: Candidate) -> str:
    """A candidate in words: solver, radius, tolerance, fluid particles."""
    tol = "" if c.tolerance is None else f", tolerance {c.tolerance:.3g}"
    return f"{c.solver}, particle_radius {c.particle_radius:.4g} m{tol}, {c.fluid_particles:,} fluid particles"


def candidates_for(scene, models: dict) -> list:
    """Every solver's prediction at every tolerance of its ladder and every radius of the ladder."""
    from ..core.errors import WarpSphError

    out = []
    for m in models.values():
        for r in ladder(scene, models):
            for t in m.candidate_tolerances():
                try:
                    out.append(predict(scene, m, r, t))
                except WarpSphError:  # the scene refuses this radius (e.g. too many substeps): not a candidate
                    continue
    mark_pareto(out)
    return out


#: a finer calibration point smaller than the STEP_UP one (to fit in what is left of the share) has at least this
#: factor more particles than the largest calibrated one, or is not run
LEAST_STEP_UP = 1.5


def next_point(cal: Calibration, free: Candidate, room: float | None = None) -> tuple[float, float, float]:
    """(radius [m], predicted cost [s], largest calibrated radius [m]) of the next calibration point of
    ``free``'s solver: a quarter of its particle count, at least LEAST_STEP_UP x and at most STEP_UP x the largest
    calibrated count (the fit is least sure beyond it), and where its cost exceeds ``room`` [s] (what is left of the share) the count
    whose cost fits, when that is at least LEAST_STEP_UP x the largest (a finer point than none: the plan may then
    extrapolate further). The cost scaled from the largest point run: its time outside the steps (``fixed_time``),
    its steps' time times particles x steps (steps ~ 1/d, so ~ N^(4/3))."""
    largest = max(cal.for_solver(free.solver), key=lambda q: q.particles)
    steps = largest.steps * largest.step_time
    fixed = fixed_time(largest, cal.points)
    target = min(max(free.particles / 4.0, LEAST_STEP_UP * largest.particles), STEP_UP * largest.particles)
    if room is not None and steps > 0 and fixed + steps * (target / largest.particles) ** (4.0 / 3.0) > room:
        fits = largest.particles * (max(room - fixed, 0.0) / steps) ** 0.75
        if fits >= LEAST_STEP_UP * largest.particles:
            target = fits
    r_new = float(f"{largest.particle_radius * (largest.particles / target) ** (1.0 / 3.0):.4g}")
    cost = fixed + steps * (target / largest.particles) * (largest.particle_radius / r_new)
    return r_new, cost, largest.particle_radius


def fixed_time(p, others=()) -> float:
    """[s] a calibration run's time outside its steady steps, without the kernel loads a later run of the process
    does not pay: less its first step's excess (``load_time``), and for the process's first run (which also loaded
    the kernels every run shares) at most the least of ``others``' (completed, not a process's first). Measured,
    hydrostatic 60 s at load 5: DFSPH's first run, 1.67 s, scaled as it was, put its second radius (0.44 s when run
    in another plan) beyond the share."""
    def own(q):
        return max(q.seconds - q.steps * q.step_time - q.load_time, 0.0)

    rest = [own(q) for q in others if not q.first_in_process and q.status == "completed"]
    return min([own(p), *rest]) if p.first_in_process else own(p)
