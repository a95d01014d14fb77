"""The fitted models of one solver (``SolverModel``), from its calibration points (``calibrate.py``).

For each solver that calibrated, the models (``fit.py``) predict at any particle radius r (spacing d = 2r):
- particles N: fluid (a + b d)^3 / d^3 and walls (a + b d)^2 / d^2 through the sampled counts (``LatticeCount``);
- substeps S: each frame split into ceil(rate(d) / fps) whole steps, the bound's rate per simulated second a power
  law with exponent <= -1 above the floor of the steps a frame takes at time.dt_max (``StepRate``);
- wall time = load + setup(N) + S * step(Nf, Nb) + frames * frame_overhead(N): the step's cost fitted against the
  fluid and the wall counts (``StepCost``: the fluid's share of N grows as d shrinks), the others lines in N; load: the
  time a fresh process spends loading the step's kernels (the largest first-step excess measured) and the kernels
  every run shares (the process's first calibration run's set-up beyond the others': ``process_overhead``); on a CPU
  whose launches split over the threads from 2 x 1,024 indices (``core.launch``), a target at or above that count
  takes the step's cost fitted to the calibration points there alone, once two counts or more lie there
  (``step_time_split``: a line across both regimes need not hold beyond them); beyond the largest calibrated count
  (CPU, two fluid counts or more at or above the split) the cost is at least that count's measured cost times
  (Nf / Nf_max)^b, b measured over the largest counts and clipped to COUNT_EXPONENT_RANGE (``fit.fit_count_law``:
  the per-particle cost stops falling beyond the calibrated counts); and the step's cost over the whole run is the
  calibration window's times the whole-run profile's cost ratio C (its steady step time over the same radius's
  calibration point's; ``whole_run_cost_ratio``); on a CPU a point that stepped slower than a larger count on
  its side of the split is left out (the load only adds time, ``points.slowed_points``), and where no count law
  holds, a fitted cost growing slower than Nf^MIN_COUNT_EXPONENT beyond the largest count at the split holds that
  count's cost per fluid particle-step (``SolverModel.flat_growth``);
- mean density error over the run: the calibration's frames measured e_cal(d) = A d^p (fitted to the finest
  ERROR_FIT_POINTS radii), the rest of the run at
  R e_cal(d): (F_c + (F - F_c) R) e_cal / F over F frames, F_c of them calibrated. The profile is a run of the whole
  duration at the coarsest radius: R = its mean error over frames F_c+1..F / its mean over frames 1..F_c (a dam
  break's impact doubles the error after the release the short runs see); without one (no room in the budget) the
  later frames are held at the calibration's last frame's error e_last(d) = B d^p'. The orders p, p' are measured
  and clamped to ORDER_RANGE (a clamped order is a bound, and the plan says so);
- an error against an experiment (``metrics.py``; calibrated over the whole duration): E(d) = C d^q;
- the solver's tolerance t (PBF, DFSPH: calibrated at the scene's t0 and at t0 / 4 at one radius): the cost per
  step, the steps per simulated second and each error times (t / t0)^k, each k measured from that pair;
  candidates only between the two calibrated tolerances (no extrapolation in t).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

from .calibrate import Calibration, scene_tolerance
from .fit import (LatticeCount, Line, PowerLaw, StepCost, StepRate, fit_count_law, fit_lattice_count, fit_line,
                  fit_power_law, fit_speed_exponent, fit_step_cost, fit_step_rate, fit_sweeps, log_slope,
                  scene_bound_rate)
from .metrics import DENSITY
from .points import course_ratio, slowed_points

#: the order of the error fit is clipped to this range (an error that grows with refinement: p < 0). Measured
#: (hydrostatic, DFSPH, 0.5 s): the calibration's last frames give p' = -2.4 between d = 0.085 and 0.057 m,
#: the whole runs -1.4 between 0.057 and 0.030 m: the clamped -1 predicted 1.25x under, the fit 1.9x over. The dam
#: break's PBF: -2.55 between r = 0.0747 and 0.05 m, the calibrated frames 0.146 % at r = 0.0315 m; clamped to -1,
#: 0.054 % predicted at r = 0.0296 m (the 60 s plan's error came out 2.34x its prediction), at -2: 0.112 %
ORDER_RANGE = (-2.0, 4.0)
#: the error's laws are fitted to this many of the finest calibrated radii: the order near the settings a plan
#: chooses, not the coarse points' (measured, dam break PBF: 0.0158, 0.0439, 0.146, 0.241, 0.272 % at r = 0.0747 to
#: 0.014 m: order -2.5 between the two coarsest, clamped to -1 and extrapolated to r = 0.0296 m, predicted 0.054 %
#: in the calibrated frames where r = 0.0315 m measured 0.146 %: the 60 s plan's error came out 2.34x its prediction;
#: the finest three give -0.77)
ERROR_FIT_POINTS = 3
#: tolerance candidates of a solver with two calibrated tolerances: this many, geometric, between them
TOLERANCE_LADDER = 3
#: the exponent b of the step's cost ~ Nf^b beyond the largest calibrated count is clipped to this range, fitted to the
#: COUNT_FIT_POINTS largest counts above the thread split (``fit.fit_count_law``). Measured: 0.72-0.91 over the
#: calibrated counts, 0.93-1.09 from the largest calibrated count to the whole run's 3-5x that count (dam break PBF,
#: hydrostatic DFSPH; the runs' wall time less set-up per step); 1.19 once from a calibration point slowed by the
#: machine's load (hydrostatic, load 3-6)
COUNT_EXPONENT_RANGE = (1.0, 1.1)
COUNT_FIT_POINTS = 3
#: the whole run's step cost over the calibration window's (C, ``whole_run_cost_ratio``): within COST_RATIO_NOISE of 1
#: it is taken as 1, and it is clipped to COST_RATIO_RANGE. Measured at the coarsest radius (2.2k particles, 2 shared
#: cores, eight plans): PBF 0.96-1.07, DFSPH 0.76-1.46 where its window point was the process's first run (then not
#: used, ``whole_run_cost_ratio``): at that count the launches' overhead dominates and the ratio is mostly noise
COST_RATIO_NOISE = 0.1
COST_RATIO_RANGE = (0.8, 1.5)
#: C is applied only where the calibration point's steps took at least this long [s]: a shorter window is a sample of
#: the machine's load, not a timing (measured, load 4.3-5.3: PBF's C 0.59 and 1.22 from windows of 27 steps, 0.06-0.08
#: s; the whole runs' wall time then 1.93x and 0.88x the prediction with C, 1.55x and 1.07x without)
COST_RATIO_MIN_WINDOW = 0.5
#: on a CPU (a thread split), beyond the largest calibrated fluid count a fitted step cost that grows slower than
#: Nf^MIN_COUNT_EXPONENT there (a line whose slope came out 0: the mean of the points) is not a cost law but the
#: points' noise: the plan then holds that count's measured cost per fluid particle-step (b = 1). Measured (hydrostatic
#: DFSPH, load 10.8): two points above the split, 36.4 ms per step at 1,440 fluid (slowed by the load) and 13.7 ms at
#: 2,352, gave a constant 25 ms per step: 1.97 us per fluid particle-step predicted at 11,767 where the largest count
#: measured 5.84 and the run took 14.8
MIN_COUNT_EXPONENT = 0.5

@dataclass
class SolverModel:
    """The fitted models of one solver (see the module docstring); ``calibrated``: the points' radii [m]."""

    solver: str
    steps_per_second: StepRate     # against d [m]
    error: PowerLaw                # against d [m]
    step_time: StepCost            # [s] against the fluid and wall counts
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
    split_particles: int = 0                     # particles from which the CPU launches split over the threads (0: never)
    step_time_split: StepCost | None = None      # [s] the step's cost fitted to the points at or above that count only
    count_law: PowerLaw | None = None            # [s] the step's least cost against Nf beyond ``count_fluid``
    count_fluid: int = 0                         # the largest calibrated fluid count above the split
    count_anchor: tuple = ()                     # (Nf, Nb, step time [s]) of the largest fluid count kept where its
                                                 # fluid alone reaches the thread split (CPU only; () else)
    slowed: list = field(default_factory=list)   # points left out of the step's cost (``slowed_points``): [(r [m], Nf,
                                                 # step [s], the larger count's r [m], Nf, step [s])]
    cost_ratio: float = 1.0                      # C applied: the whole run's step cost over the calibration window's
    cost_ratio_measured: float | None = None     # C as measured (None: no whole run of this solver)
    cost_ratio_window: float = 0.0               # [s] the steps' time of the calibration point C was measured against
    sweeps: PowerLaw | None = None               # the solver's sweeps per step against d [m] (None: it has none)
    sweeps_bounds: tuple = (0.0, 0.0)            # the fewest and most sweeps per step the scene allows (most 0: none)
    sweeps_fluid: int = 0                        # the largest calibrated fluid count: the reference of the sweeps' part
    sweeps_reference: float = 0.0                # that point's sweeps per step
    solve_share: float = 0.0                     # [-] that point's steady step time share of the sweeps' stages
    array_bytes: StepCost | None = None          # [bytes] the run's arrays against Nf, Nb (None: no point recorded them)
    array_bytes_calibrated: int = 0              # [bytes] the most any calibration point's arrays took
    cache_bytes: int = 0                         # [bytes] the CPU's last-level cache (0: a GPU, or not listed)
    timing_radii: list = field(default_factory=list)  # [m] timing-only points in the step's cost (``past_cache.py``)

    def past_cache(self, fluid: int, boundary: int) -> float | None:
        """[bytes] the run's arrays at ``fluid`` and ``boundary`` particles where they pass the CPU's last-level cache
        and no calibration point's did (its step cost is then carried past the cache unmeasured:
        docs/plan-model.md, item 12); None otherwise."""
        if self.array_bytes is None or not self.cache_bytes or self.array_bytes_calibrated >= self.cache_bytes:
            return None
        need = self.array_bytes(fluid, boundary)
        return need if need > self.cache_bytes else None

    def sweeps_grow(self) -> bool:
        """Whether the calibration window's sweeps per step grew with refinement (the law's measured exponent below
        its clipped one, 0): the growth is not extrapolated, and beyond the largest calibrated count the step then
        takes that count's sweeps (``sweeps_at``), not the law's constant (the points' mean, below the reference)."""
        law = self.sweeps
        return law is not None and law.measured is not None and law.measured < law.exponent - 1e-9 and \
            self.sweeps_reference > 0  # (PBF's constant 2 fits to +-1e-16)

    def sweeps_at(self, d: float) -> float:
        """Sweeps per step at spacing ``d`` [m] at the scene's tolerance: ``sweeps`` within ``sweeps_bounds`` (0 for a
        solver without sweeps); where they grew with refinement (``sweeps_grow``), the largest count's
        (``sweeps_reference``), held: measured, dam break DFSPH, whole 0.5 s runs at r = 0.0315, 0.0198 and 0.0132 m:
        the first frames' sweeps 5.4, 10.3 and 18.5 per step (growth, the law clipped to a constant, their mean) while
        the runs' steps cost 1.14, 0.93 and 0.90x their first frames' (process CPU time; the sweeps fall to 4-5 after
        the impact, each frame's steps cost more: docs/plan-model.md, item 8)."""
        if self.sweeps is None:
            return 0.0
        lo, hi = self.sweeps_bounds
        s = max(self.sweeps_reference if self.sweeps_grow() else self.sweeps(d), lo)
        return float(min(s, hi) if hi > 0 else s)

    def sweep_factor(self, fluid: int, d: float) -> float:
        """The step's cost beyond the largest calibrated fluid count as a per-step part plus a per-sweep part times the
        sweeps, a + b s, over that count's own, a + b s_ref: (1 - f) + f s(d) / s_ref, f the reference point's
        ``solve_share`` (its sweeps' stages' share of its step; their time taken as proportional to the sweeps, an
        upper bound on the sweeps' effect: those stages also hold a fixed part); 1 within the calibrated counts,
        where the fit carries the points' own sweeps, and for a solver without sweeps."""
        if self.sweeps is None or fluid <= self.sweeps_fluid or self.sweeps_reference <= 0 or self.solve_share <= 0:
            return 1.0
        f = self.solve_share
        return float((1.0 - f) + f * self.sweeps_at(d) / self.sweeps_reference)

    def step_cost(self, fluid: int, boundary: int, d: float | None = None) -> float:
        """[s] one step at the scene's tolerance over the whole run: above the thread split from the points above it
        where two or more counts were calibrated there, else from every point; beyond the largest calibrated count at
        least ``count_law``'s; times the whole-run cost ratio C and, at spacing ``d`` [m] (None: not), the sweeps'
        factor (``sweep_factor``; module docstring)."""
        if self.step_time_split is not None and fluid + boundary >= self.split_particles:
            base = self.step_time_split(fluid, boundary)
        else:
            base = self.step_time(fluid, boundary)
        if self.count_law is not None and fluid > self.count_fluid:
            base = max(base, self.count_law(fluid))
        elif self.flat_growth(fluid, boundary) is not None:
            nf, _, t = self.count_anchor
            base = t * fluid / nf
        return base * self.cost_ratio * (self.sweep_factor(fluid, d) if d is not None else 1.0)

    def flat_growth(self, fluid: int, boundary: int) -> float | None:
        """The exponent k of the fitted step cost ~ Nf^k from the largest calibrated fluid count (``count_anchor``) to
        ``fluid`` where it is under MIN_COUNT_EXPONENT and no count law holds (``step_cost`` then holds that count's
        measured cost per fluid particle-step); None otherwise (within the calibrated counts, on a GPU)."""
        if not self.count_anchor or self.count_law is not None or fluid <= self.count_anchor[0]:
            return None
        nf, nb, _ = self.count_anchor
        fit = self.step_time_split if self.step_time_split is not None and nf + nb >= self.split_particles \
            else self.step_time
        fit_t = self.step_time_split if self.step_time_split is not None and fluid + boundary >= self.split_particles \
            else self.step_time
        k = log_slope(nf, fit(nf, nb), fluid, fit_t(fluid, boundary))
        return k if k < MIN_COUNT_EXPONENT else None

    def later_ratio(self, frames: int) -> float:
        """R: the profile's mean error over the frames after the calibrated ones / its mean over the calibrated
        frames (1 without a profile covering ``frames``). Over the calibrated frames' mean, not their last frame's:
        one frame of an oscillating error is a sample of the oscillation (measured, hydrostatic WCSPH: 0.26, 0.19
        and 0.35 % in frames 3-5 of the whole run, the calibration's last frame being frame 4; the last frames' order came out +2.4 and the 180 s plan's error
        3.1x its prediction)."""
        fc = self.calibrated_frames
        if len(self.profile) < frames or frames <= fc or fc < 1:
            return 1.0
        first = sum(self.profile[:fc]) / fc
        if first <= 0:
            return 1.0
        later = self.profile[fc:frames]
        return float(sum(later) / len(later) / first)

    def has_profile(self, frames: int) -> bool:
        """Whether a whole-run profile covers ``frames`` frames beyond the calibrated ones."""
        return len(self.profile) >= frames > self.calibrated_frames >= 1

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
               profile: Calibration | None = None, timing: Calibration | None = None) -> SolverModel | None:
    """The models of ``solver`` from its completed calibration points at the scene's tolerance (None: it has
    none); ``metric``: the error a target names (its law from the points' ``reference``); ``profile``: the
    whole-duration calibration whose per-frame errors give R (module docstring); ``timing``: timing-only points
    (``past_cache.py``: past the CPU's last-level cache), fitted into the step's cost and the arrays' bytes only."""
    t0 = scene_tolerance(scene, solver) if scene is not None else None
    pts = sorted(cal.for_solver(solver, t0) if scene is not None else cal.for_solver(solver),
                 key=lambda p: p.particle_radius)
    if not pts:
        return None
    timed = pts + (timing.for_solver(solver, t0) if timing is not None and scene is not None else [])
    split = int(getattr(cal, "split_particles", 0) or 0)
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
    rate = fit_step_rate(d, [p.steps_per_second for p in pts], cal.step_floor, cal.step_quantum,
                         scene_bound_rate(scene) if scene is not None else None)
    speeds = _profile(profile, solver, t0, "frame_speeds") if profile is not None else []
    if speeds and scene is not None and scene.time.fixed_dt <= 0:  # the steps' course over the run (``StepRate``)
        g = sum(x * x for x in scene.gravity) ** 0.5
        from ..methods.registry import solver as solver_class

        per_substep = bool(solver_class(solver).time_step_per_substep and not scene.bodies and not scene.obstacles)
        rate = replace(rate, speeds=tuple(speeds), cfl=float(scene.time.cfl), gravity=float(g), per_substep=per_substep,
                       speed_spacing=2.0 * _profile_radius(profile, solver, t0),
                       speed_exponent=fit_speed_exponent(d, [p.frame_speeds[1:] for p in pts]))
    # the error's laws from the finest ERROR_FIT_POINTS radii: the order near the settings a plan extrapolates to
    fine = pts[:ERROR_FIT_POINTS]
    d_fine = [p.spacing for p in fine]
    measured_ratio, window = whole_run_cost_ratio(pts, profile, solver, t0) if profile is not None else (None, 0.0)
    # the sweeps per step against d (the finest radii), and the largest count's split of its step into the sweeps' part
    # and the rest: the step's cost beyond that count as a + b x sweeps (``SolverModel.sweep_factor``); a timing point
    # in both (the reference and the law from the same points: measured, dam break 60 s, DFSPH: the timing point's 12.2
    # sweeps at 24,389 fluid against a law over the calibration points alone, 5.26 at 50,239, gave x 0.542; the run took
    # 7.1 per step)
    ref = max(timed, key=lambda p: (p.fluid, -p.particle_radius))
    from .points import sweep_bounds
    return SolverModel(
        solver=solver,
        steps_per_second=rate,
        error=fit_power_law(d_fine, [max(p.density_error_mean, 1e-9) for p in fine], ORDER_RANGE),
        setup_time=setup,
        frame_overhead=fit_line(n, [p.frame_overhead for p in pts]),
        fluid_count=fit_lattice_count(d, [p.fluid for p in pts], 3),
        boundary_count=fit_lattice_count(d, [max(p.boundary, 0) for p in pts], 2),
        # a fresh process loads the step's kernels as the solver's first calibration run did, and the shared ones
        # as the process's first calibration run did
        load_time=max(p.load_time for p in pts) + process_overhead(cal, scene),
        calibrated_radii=[p.particle_radius for p in pts], calibrated_particles=n,
        error_last=_error_law(d_fine, [p.density_error_last or p.density_error_mean for p in fine]),
        calibrated_frames=min(p.frames for p in pts), metric=metric, metric_error=metric_law,
        tolerance=t0, tolerances=tolerances, tolerance_exponents=exponents, tolerance_particles=pair_particles,
        profile=_profile(profile, solver, t0) if profile is not None else [],
        **step_cost_fields(timed, split),
        cost_ratio=applied_cost_ratio(measured_ratio, window), cost_ratio_measured=measured_ratio,
        cost_ratio_window=window,
        sweeps=fit_sweeps([p.spacing for p in timed], [p.sweeps for p in timed], ERROR_FIT_POINTS),
        sweeps_bounds=sweep_bounds(scene, solver) if scene is not None else (0.0, 0.0), sweeps_fluid=ref.fluid,
        sweeps_reference=ref.sweeps, solve_share=ref.solve_share, **array_fields(timed, cal),
        timing_radii=[p.particle_radius for p in timed[len(pts):]])


def array_fields(pts, cal) -> dict:
    """The SolverModel fields of the run's arrays: their bytes fitted against the fluid and wall counts of the points
    that recorded them (``fit_step_cost``'s non-negative line), the most any point took and the CPU's last-level
    cache (``Calibration.cache_bytes``)."""
    sized = [p for p in pts if getattr(p, "array_bytes", 0) > 0]
    return dict(array_bytes=fit_step_cost([p.fluid for p in sized], [max(p.boundary, 0) for p in sized],
                                          [p.array_bytes for p in sized]) if sized else None,
                array_bytes_calibrated=max((p.array_bytes for p in sized), default=0),
                cache_bytes=int(getattr(cal, "cache_bytes", 0) or 0))


def step_cost_fields(pts, split: int) -> dict:
    """The SolverModel fields of the step's cost fitted to the calibration points ``pts`` (``points.Point``: fluid,
    boundary, step_time, particle_radius) with the CPU's thread split at ``split`` particles (0: a GPU): ``step_time``,
    ``step_time_split`` and ``split_particles``, ``count_law`` and ``count_fluid``, ``count_anchor`` and ``slowed``
    (module docstring). Apart from ``fit_models`` so that a recorded plan's points can be fitted again
    (``benchmarks/plan_replay.py``)."""
    slowed = slowed_points(pts, split)
    timed = [p for p in pts if all(p is not a for a, _ in slowed)]  # the points the step's cost is fitted to
    # the step's cost above the thread split from the points there alone, where two counts or more were calibrated
    above = [p for p in timed if split and p.particles >= split]
    split_cost = (fit_step_cost([p.fluid for p in above], [max(p.boundary, 0) for p in above],
                                [p.step_time for p in above])
                  if len({p.particles for p in above}) >= 2 and len(above) < len(timed) else None)
    # the count law from the points whose fluid alone splits (a dam break's coarse points pass the split on their walls)
    split_fluid = [p for p in timed if split and p.fluid >= split]
    count_law = fit_count_law([p.fluid for p in split_fluid], [p.step_time for p in split_fluid], COUNT_EXPONENT_RANGE,
                              COUNT_FIT_POINTS) if split_fluid else None
    top = max(timed, key=lambda p: (p.fluid, -p.particle_radius))
    return dict(
        step_time=fit_step_cost([p.fluid for p in timed], [max(p.boundary, 0) for p in timed],
                                [p.step_time for p in timed]),
        split_particles=split if split_cost is not None else 0, step_time_split=split_cost,
        count_law=count_law, count_fluid=max(p.fluid for p in split_fluid) if count_law is not None else 0,
        count_anchor=(top.fluid, max(top.boundary, 0), top.step_time) if split and top.fluid >= split else (),
        slowed=[(p.particle_radius, p.fluid, p.step_time, q.particle_radius, q.fluid, q.step_time) for p, q in slowed])


def whole_run_cost_ratio(pts, profile: Calibration, solver: str, t0) -> tuple:
    """(C, the window's steps' time [s]): what each step of ``solver``'s whole run (``profile``) costs over the run
    against the calibration window (the steps' number is modelled apart, ``StepRate``). Where the whole run recorded
    its frames' CPU time, from that run alone (``points.course_ratio``: its CPU per step over frames 2..F over frames
    2..F_c, F_c the calibration's frames; measured, dam break DFSPH, whole 0.5 s runs, load 1-2: 0.79, 0.88 and 1.01
    at r = 0.0747 m in three runs of the same setting, 1.15, 1.14, 0.93 and 0.90 at r = 0.05, 0.0315, 0.0198 and
    0.0132 m; hydrostatic DFSPH 1.01 twice, dam break PBF 1.08 and 1.11 at the coarsest radii: the coarsest radius's
    is the timing noise of ms steps, not the finer radii's course); else the whole run's steady step time over its
    calibration point's at the same radius, not against the process's first calibration run (its steady steps
    measured 0.76-1.46x the whole run's, DFSPH, six plans). (None, 0) without both."""
    whole = profile.for_solver(solver, t0)
    if not whole:
        return None, 0.0
    w = max(whole, key=lambda p: p.particle_radius)
    if w.frame_cpu and pts:  # within the one run: its later frames' CPU per step over its window frames'
        ratio, window = course_ratio(w, min(p.frames for p in pts))
        if ratio is not None:
            return ratio, window
    same = [p for p in pts if abs(p.particle_radius / w.particle_radius - 1.0) <= 1e-6 and p.step_time > 0
            and not p.first_in_process]
    if not same or w.step_time <= 0:
        return None, 0.0
    return float(w.step_time / same[0].step_time), float(same[0].steps * same[0].step_time)


def applied_cost_ratio(measured: float | None, window: float = math.inf) -> float:
    """C as the wall prediction applies it: 1 without a measurement, within COST_RATIO_NOISE of 1 (the timing noise of
    two runs: a plan made again on fresh timings then takes the same) or measured against a window of steps shorter
    than COST_RATIO_MIN_WINDOW [s]; else clipped to COST_RATIO_RANGE."""
    if measured is None or abs(measured - 1.0) <= COST_RATIO_NOISE or window < COST_RATIO_MIN_WINDOW:
        return 1.0
    lo, hi = COST_RATIO_RANGE
    return float(min(max(measured, lo), hi))


def _profile_radius(profile: Calibration, solver: str, t0) -> float:
    return max(p.particle_radius for p in profile.for_solver(solver, t0))


def _profile(profile: Calibration, solver: str, t0, figure: str = "density_errors") -> list:
    pts = profile.for_solver(solver, t0)
    return list(getattr(max(pts, key=lambda p: p.particle_radius), figure)) if pts else []


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
    frames at the calibration's mean e_cal(d); the rest, with a whole-run profile, at e_cal(d) times the profile's
    R (its later frames' mean over its calibrated frames' mean), without one at the calibration's last frame's
    error e_last(d), held (module docstring)."""
    first = model.error(d) * model.tolerance_factor("error", tolerance)
    if frames <= 0:
        return first
    if model.has_profile(frames):
        last = first * model.later_ratio(frames)
    elif model.error_last is None:
        return first
    else:
        last = model.error_last(d) * model.tolerance_factor("error_last", tolerance)
    fc = min(model.calibrated_frames, frames)
    return (fc * first + (frames - fc) * last) / frames
