"""The advisor of ``warp-sph plan``: models fitted to the calibration, the candidates, the recommendation.

For each solver that calibrated, the models (``fit.py``) predict at any particle radius r (spacing d = 2r):
- particles N: fluid (a + b d)^3 / d^3 and walls (a + b d)^2 / d^2 through the sampled counts (``LatticeCount``);
- substeps S = (steps per simulated second)(d) * duration: a power law with exponent <= -1 above the floor of
  one step per frame or per time.dt_max (``StepRate``);
- wall time = load + setup(N) + S * step(N) + frames * frame_overhead(N), three lines fitted against N, and
  the time a fresh process spends loading the step's kernels (the largest first-step excess measured);
- mean density error over the run: the calibration's frames measured e_cal(d) = A d^p, the rest of the run at the
  calibration's last frame's error e_last(d) = B d^p' times the profile's ratio R: (F_c e_cal + (F - F_c) R e_last)
  / F over F frames, F_c of them calibrated. The profile is a run of the whole duration at the coarsest radius:
  R = its mean error over frames F_c+1..F / its error at frame F_c (a dam break's impact doubles the error after
  the release the short runs see); without one (no room in the budget) R = 1, the error held. The orders p, p'
  are measured and clamped to ORDER_RANGE (a clamped order is a bound, and the plan says so);
- an error against an experiment (``metrics.py``; calibrated over the whole duration): E(d) = C d^q;
- the solver's tolerance t (PBF, DFSPH: calibrated at the scene's t0 and at t0 / 4 at one radius): the cost per
  step, the steps per simulated second and each error times (t / t0)^k, each k measured from that pair;
  candidates only between the two calibrated tolerances (no extrapolation in t), and a candidate at t != t0
  counts its extrapolation from the pair's particle count (measured, hydrostatic 0.5 s: DFSPH at t0 / 4 with
  14x the pair's count took 3.8x its prediction: the iterations a tolerance costs grow with the resolution);
- memory: ``run.memory.estimate_memory`` at the predicted counts.
The candidates are the solvers x their tolerances x a geometric ladder of radii from the coarsest stable one
down to 64x finer than the finest calibrated; each says how far it extrapolates beyond the calibrated counts.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from .calibrate import Calibration, PlanError, coarsest_radius, scene_tolerance, variant
from .fit import (LatticeCount, Line, PowerLaw, StepRate, extrapolation, fit_lattice_count, fit_line, fit_power_law,
                  fit_step_rate, log_slope)
from .metrics import DENSITY

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
#: the order of the error fit is clipped to this range (an error that grows with refinement: p < 0). Measured
#: (hydrostatic, DFSPH, 0.5 s): the calibration's last frames give p' = -2.4 between d = 0.085 and 0.057 m,
#: the whole runs -1.4 between 0.057 and 0.030 m: the clamped -1 predicted 1.25x under, the fit 1.9x over
ORDER_RANGE = (-1.0, 4.0)
#: tolerance candidates of a solver with two calibrated tolerances: this many, geometric, between them
TOLERANCE_LADDER = 3


@dataclass
class SolverModel:
    """The fitted models of one solver (see the module docstring); ``calibrated``: the points' radii [m]."""

    solver: str
    steps_per_second: StepRate     # against d [m]
    error: PowerLaw                # against d [m]
    step_time: Line                # [s] against N
    setup_time: Line               # [s] against N
    frame_overhead: Line           # [s] against N
    fluid_count: LatticeCount      # against d [m]
    boundary_count: LatticeCount
    load_time: float               # [s] a fresh process spends loading the step's kernels (the largest first-step excess)
    calibrated_radii: list
    calibrated_particles: list
    error_last: PowerLaw | None = None       # the calibration's last frame's mean density error, against d [m]
    calibrated_frames: int = 0               # frames each calibration run advanced
    metric: str = DENSITY                    # the error a target names (``metrics.py``)
    metric_error: PowerLaw | None = None     # that error against d [m] (None: the density error)
    tolerance: float | None = None           # the scene's tolerance t0 [-] (None: the solver has none)
    tolerances: list = field(default_factory=list)      # the calibrated tolerances [-], t0 first
    tolerance_particles: int = 0                        # particles of the pair the tolerance's effect was measured on
    tolerance_exponents: dict = field(default_factory=dict)  # figure -> k: figure ~ (t / t0)^k
    profile: list = field(default_factory=list)  # [-] per-frame mean density error of a whole run at the coarsest radius

    def later_ratio(self, frames: int) -> float:
        """R: the profile's mean error over the frames after the calibrated ones / its error at the last calibrated
        frame (1 without a profile covering ``frames``)."""
        fc = self.calibrated_frames
        if len(self.profile) < frames or frames <= fc or fc < 1 or self.profile[fc - 1] <= 0:
            return 1.0
        later = self.profile[fc:frames]
        return float(sum(later) / len(later) / self.profile[fc - 1])

    def tolerance_factor(self, figure: str, tolerance: float | None) -> float:
        """(t / t0)^k of ``figure`` ("step_time", "steps_per_second", "error", "error_last", "metric")."""
        k = self.tolerance_exponents.get(figure, 0.0)
        if tolerance is None or self.tolerance is None or k == 0.0:
            return 1.0
        return (tolerance / self.tolerance) ** k

    def candidate_tolerances(self) -> list:
        """The tolerances a plan may choose: TOLERANCE_LADDER between the calibrated ones ([t0] or [None] else)."""
        if len(self.tolerances) < 2:
            return [self.tolerance]
        lo, hi = min(self.tolerances), max(self.tolerances)
        n = TOLERANCE_LADDER
        return sorted({float(f"{hi * (lo / hi) ** (i / (n - 1)):.4g}") for i in range(n)}, reverse=True)

    def to_dict(self) -> dict:
        """The models as plain JSON types."""
        return asdict(self)


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
        return {"scene": self.scene, "source": self.source, "budget_s": self.budget_s, "metric": self.metric,
                "notes": self.notes, "target_error": self.target_error, "duration": self.duration, "frames": self.frames,
                "chosen": self.chosen.to_dict(), "alternatives": [c.to_dict() for c in self.alternatives],
                "candidates": [c.to_dict() for c in self.candidates],
                "models": {k: m.to_dict() for k, m in self.models.items()},
                "calibration_seconds": self.calibration_seconds, "calibration_cached": self.calibration_cached,
                "cache_path": self.cache_path, "machine": self.machine, "failed_solvers": self.failed_solvers}


def _error_law(d, values) -> PowerLaw | None:
    """The error's power law in d with the order clamped to ORDER_RANGE (None: no point measured it)."""
    ok = [(a, max(v, 1e-9)) for a, v in zip(d, values) if v is not None]
    return fit_power_law([a for a, _ in ok], [v for _, v in ok], ORDER_RANGE) if ok else None


def tolerance_exponents(cal: Calibration, solver: str, t0: float | None, metric: str) -> tuple[list, dict, int]:
    """(calibrated tolerances, t0 first; {figure: k}; the pair's particles) of ``solver`` from a pair of points at
    one radius, one at t0 and one at another tolerance (the finest such radius); ([t0], {}, 0) without a pair."""
    if t0 is None:
        return [None], {}, 0
    base = cal.for_solver(solver, t0)
    others = [p for p in cal.for_solver(solver) if p.tolerance is not None and abs(p.tolerance / t0 - 1) > 1e-6]
    pairs = [(a, b) for b in others for a in base if abs(a.particle_radius / b.particle_radius - 1) <= 1e-6]
    if not pairs:
        return [t0], {}, 0
    a, b = min(pairs, key=lambda ab: ab[0].particle_radius)
    k = {"step_time": log_slope(a.tolerance, a.step_time, b.tolerance, b.step_time),
         "steps_per_second": log_slope(a.tolerance, a.steps_per_second, b.tolerance, b.steps_per_second),
         "error": log_slope(a.tolerance, a.density_error_mean, b.tolerance, b.density_error_mean),
         "error_last": log_slope(a.tolerance, a.density_error_last, b.tolerance, b.density_error_last)}
    if metric != DENSITY:
        k["metric"] = log_slope(a.tolerance, a.reference.get(metric) or 0.0, b.tolerance, b.reference.get(metric) or 0.0)
    return [t0, b.tolerance], k, a.particles


def fit_models(cal: Calibration, solver: str, scene=None, metric: str = DENSITY,
               profile: Calibration | None = None) -> SolverModel | None:
    """The models of ``solver`` from its completed calibration points at the scene's tolerance (None: it has
    none); ``metric``: the error a target names (its law from the points' ``reference``); ``profile``: the
    whole-duration calibration whose per-frame errors give R (module docstring)."""
    t0 = scene_tolerance(scene, solver) if scene is not None else None
    pts = sorted(cal.for_solver(solver, t0) if scene is not None else cal.for_solver(solver),
                 key=lambda p: p.particle_radius)
    if not pts:
        return None
    d = [p.spacing for p in pts]
    n = [p.particles for p in pts]
    steady = [p for p in pts if not p.first_in_process] or pts
    setup = fit_line([p.particles for p in steady], [p.setup_time for p in steady])
    metric_law = None
    if metric != DENSITY:
        metric_law = _error_law(d, [p.reference.get(metric) for p in pts])
        if metric_law is None:  # no calibration run's span held a point of the experiment
            return None
    tolerances, exponents, pair_particles = tolerance_exponents(cal, solver, t0, metric)
    return SolverModel(
        solver=solver,
        steps_per_second=fit_step_rate(d, [p.steps_per_second for p in pts], cal.step_floor),
        error=fit_power_law(d, [max(p.density_error_mean, 1e-9) for p in pts], ORDER_RANGE),
        step_time=fit_line(n, [p.step_time for p in pts]),
        setup_time=setup,
        frame_overhead=fit_line(n, [p.frame_overhead for p in pts]),
        fluid_count=fit_lattice_count(d, [p.fluid for p in pts], 3),
        boundary_count=fit_lattice_count(d, [max(p.boundary, 0) for p in pts], 2),
        # a fresh process loads the step's kernels as the solver's first calibration run did, and the shared ones
        # as the process's first calibration run did
        load_time=max(p.load_time for p in pts) + process_overhead(cal, scene),
        calibrated_radii=[p.particle_radius for p in pts], calibrated_particles=n,
        error_last=_error_law(d, [p.density_error_last or p.density_error_mean for p in pts]),
        calibrated_frames=min(p.frames for p in pts), metric=metric, metric_error=metric_law,
        tolerance=t0, tolerances=tolerances, tolerance_exponents=exponents, tolerance_particles=pair_particles,
        profile=_profile(profile, solver, t0) if profile is not None else [])


def _profile(profile: Calibration, solver: str, t0) -> list:
    pts = profile.for_solver(solver, t0)
    return list(max(pts, key=lambda p: p.particle_radius).density_errors) if pts else []


def process_overhead(cal: Calibration, scene=None) -> float:
    """[s] a fresh process spends loading the kernels every run shares (sampling, grid, exports): the set-up of the
    process's first calibration run beyond its solver's set-up line fitted to the other points (0 where no point
    of the calibration was a process's first, or its solver has no other point)."""
    out = 0.0
    for q in (p for p in cal.points if p.first_in_process and p.status == "completed"):
        t0 = scene_tolerance(scene, q.solver) if scene is not None else "any"
        others = [p for p in cal.for_solver(q.solver, t0) if p is not q and not p.first_in_process]
        if others:
            line = fit_line([p.particles for p in others], [p.setup_time for p in others])
            out = max(out, q.setup_time - line(q.particles))
    return out


def run_density_error(model: SolverModel, d: float, frames: int, tolerance: float | None = None) -> float:
    """The predicted mean density error [-] over a run of ``frames`` frames at spacing ``d`` [m]: the calibrated
    frames at the calibration's mean, the rest at its last frame's error times the profile's R (module docstring)."""
    first = model.error(d) * model.tolerance_factor("error", tolerance)
    if model.error_last is None or frames <= 0:
        return first
    last = model.error_last(d) * model.tolerance_factor("error_last", tolerance) * model.later_ratio(frames)
    fc = min(model.calibrated_frames, frames)
    return (fc * first + (frames - fc) * last) / frames


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
    rate = model.steps_per_second(d) * model.tolerance_factor("steps_per_second", tolerance)
    steps = max(int(math.ceil(rate * scene.duration)), frames)
    step = model.step_time(n) * model.tolerance_factor("step_time", tolerance)
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


def next_point(cal: Calibration, free: Candidate) -> tuple[float, float, float]:
    """(radius [m], predicted cost [s], largest calibrated radius [m]) of the next calibration point of
    ``free``'s solver: a quarter of its particle count, but at most STEP_UP x the largest calibrated count (the
    fit is least sure beyond it); the cost scaled from the largest point run: its time outside the steps as it
    was, its steps' time times particles x steps (steps ~ 1/d)."""
    largest = max(cal.for_solver(free.solver), key=lambda q: q.particles)
    target = min(free.particles / 4.0, STEP_UP * largest.particles)
    r_new = float(f"{largest.particle_radius * (largest.particles / target) ** (1.0 / 3.0):.4g}")
    steps = largest.steps * largest.step_time
    cost = (max(largest.seconds - steps, 0.0)
            + steps * (target / largest.particles) * (largest.particle_radius / r_new))
    return r_new, cost, largest.particle_radius
