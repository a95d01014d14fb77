"""The fitted models of ``warp-sph plan``: power laws in log space and a line with non-negative coefficients.

Every figure of a plan comes from a fit to measured calibration points (``calibrate.py``):
- particles against the spacing d: fluid (a + b d)^3 / d^3, walls (a + b d)^2 / d^2 (``LatticeCount``);
- steps per simulated second against d: max(floor, a d^q) with q <= -1 (CFL: dt ~ h / v; ``StepRate``);
- mean density error against the spacing: e = A d^p, p the measured convergence order;
- wall time of one step against the fluid and wall particle counts: t = c0 + cf Nf + cb Nb (all >= 0: launch
  overhead, cost per fluid and per wall particle-step; ``StepCost``);
- wall time outside the steps (set-up, statistics, exports) against N: the same line.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PowerLaw:
    """y = coefficient * x^exponent, fitted by least squares on (log x, log y)."""

    coefficient: float
    exponent: float
    measured: float | None = None   # the least-squares exponent before clipping (None: not fitted, one point)

    def __call__(self, x: float) -> float:
        return self.coefficient * float(x) ** self.exponent

    @property
    def clipped(self) -> bool:
        """Whether the measured exponent lay outside the allowed range (the fit is then a bound, not a measurement)."""
        return self.measured is not None and abs(self.measured - self.exponent) > 1e-12


@dataclass(frozen=True)
class Line:
    """y = intercept + slope * x with intercept, slope >= 0."""

    intercept: float
    slope: float

    def __call__(self, x: float) -> float:
        return self.intercept + self.slope * float(x)


def fit_power_law(x, y, exponent_range: tuple[float, float] = (-6.0, 6.0)) -> PowerLaw:
    """The power law y = a x^p through positive points (x, y): least squares in log space; one point (or
    points at one x) gives p = 0 (a constant, the mean); p is clipped to ``exponent_range`` and a refitted for it.
    Points with a non-positive or non-finite value are left out; none left: ValueError."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    if not ok.any():
        raise ValueError("no positive finite point to fit")
    lx, ly = np.log(x[ok]), np.log(y[ok])
    if np.ptp(lx) == 0.0:
        return PowerLaw(float(np.exp(ly.mean())), 0.0)
    measured, _ = np.polyfit(lx, ly, 1)
    p = float(np.clip(measured, *exponent_range))
    return PowerLaw(float(np.exp(np.mean(ly - p * lx))), p, float(measured))


def fit_line(x, y) -> Line:
    """The line y = c0 + c1 x with c0, c1 >= 0 closest to the points in least squares (the unconstrained fit,
    else the best through the origin, else the best constant); points at one x > 0: through the origin.
    Non-finite points are left out."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if len(x) == 0:
        raise ValueError("no finite point to fit")
    if np.ptp(x) == 0 and x[0] > 0:  # one count: proportional to it (an upper bound for larger counts)
        return Line(0.0, max(float(y.mean() / x[0]), 0.0))
    candidates = []
    if len(x) >= 2 and np.ptp(x) > 0:
        c1, c0 = np.polyfit(x, y, 1)
        if c0 >= 0 and c1 >= 0:
            candidates.append(Line(float(c0), float(c1)))
    sxx = float(np.dot(x, x))
    if sxx > 0:
        candidates.append(Line(0.0, max(float(np.dot(x, y)) / sxx, 0.0)))
    candidates.append(Line(max(float(y.mean()), 0.0), 0.0))
    return min(candidates, key=lambda f: float(np.sum((f.intercept + f.slope * x - y) ** 2)))


@dataclass(frozen=True)
class StepCost:
    """Wall time of one step [s]: intercept + fluid * Nf + boundary * Nb (all >= 0): launch overhead, cost per
    fluid particle-step and per wall particle-step."""

    intercept: float
    fluid: float
    boundary: float = 0.0

    def __call__(self, fluid: float, boundary: float = 0.0) -> float:
        return self.intercept + self.fluid * float(fluid) + self.boundary * float(boundary)


def fit_step_cost(fluid, boundary, t) -> StepCost:
    """The StepCost closest to the measured step times ``t`` [s] in least squares with every coefficient >= 0:
    the best of the column sets {1, Nf, Nb}, {1, Nf}, {Nf, Nb}, {Nf}, {1} whose unconstrained fit is non-negative;
    a set with the wall column only with more points than coefficients (two points cannot tell a wall's cost from
    a fluid particle's), none the points cannot determine (one count: proportional to it, an upper bound for
    larger counts), and between equal fits the one listed first. Measured (dam break, PBF, 3.4k / 13.8k /
    68.9k fluid with 11.4k / 28.8k / 80.8k wall particles): 5.0 / 4.95 / 5.4 us per fluid particle-step, 1.15 /
    1.6 / 2.5 us per particle (fluid and walls): the walls cost next to nothing, the fluid's share grows as d
    shrinks (d^-3 against d^-2), so a line in the total count under-predicts a finer run (-36 % at 3.5x)."""
    nf = np.asarray(fluid, dtype=np.float64)
    nb = np.asarray(boundary, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    ok = np.isfinite(nf) & np.isfinite(nb) & np.isfinite(t)
    nf, nb, t = nf[ok], nb[ok], t[ok]
    if len(t) == 0:
        raise ValueError("no finite point to fit")
    columns = {"intercept": np.ones_like(t), "fluid": nf, "boundary": nb}
    sets = [("intercept", "fluid", "boundary"), ("intercept", "fluid"), ("fluid", "boundary"), ("fluid",),
            ("intercept",)]
    best, best_rss = None, np.inf
    for names in sets:
        if "boundary" in names and len(t) <= len(names):
            continue
        a = np.stack([columns[k] for k in names], axis=1)
        if np.linalg.matrix_rank(a) < len(names):  # e.g. one count: the intercept and the slope not separable
            continue
        coef, *_ = np.linalg.lstsq(a, t, rcond=None)
        if np.any(coef < 0):
            continue
        rss = float(np.sum((a @ coef - t) ** 2))
        if rss < best_rss * (1.0 - 1e-9) - 1e-30:
            best, best_rss = dict(zip(names, coef.tolist())), rss
    if best is None:  # nothing non-negative: the mean per step
        return StepCost(max(float(t.mean()), 0.0), 0.0)
    return StepCost(best.get("intercept", 0.0), best.get("fluid", 0.0), best.get("boundary", 0.0))


def fit_count_law(fluid, t, exponent_range=(1.0, 1.1), points: int = 3) -> PowerLaw | None:
    """The step's cost beyond the largest calibrated count: t = c Nf^b through the point of the largest fluid count
    ``fluid`` [particles] (its measured step time ``t`` [s]), b the least-squares exponent of log t against log Nf
    over the ``points`` largest counts, clipped to ``exponent_range`` (None with fewer than two counts). Anchored at
    the largest count, not at the points' mean: the per-particle cost falls with the count over the calibrated range
    (the launches' overhead spread over more particles), and the largest count's is the nearest the target's.
    Measured (CPU, 2 cores, per fluid particle-step at the largest calibrated count -> at 3-5x that count in the
    plan's whole run): dam break PBF 1.93 -> 2.08 us and 1.94 -> 2.22 us, hydrostatic DFSPH 2.83 -> 2.57 us, where
    the exponents over the calibrated counts were 0.72-0.91 (a law with those, or a line with an intercept, predicted
    1.3-1.7 us): the per-particle cost stops falling beyond the calibrated counts, hence b >= 1. With one count at
    the thread split no law is fitted (the line through the points stands). Holding that count's per-particle cost
    beyond it (b = 1) was tried and not kept: no measurement separates the two rules on this VM (the quiet
    hydrostatic 60 s plan predicted 27.3 s with it and 29.5 s with the line for the same setting, DFSPH at 7,938
    fluid particles, which ran 13.8 s and 24.5 s fifteen minutes apart, load 0.8-2.1)."""
    pairs = sorted({(float(n), float(v)) for n, v in zip(fluid, t) if n > 0 and v > 0})
    counts = sorted({n for n, _ in pairs})
    if len(counts) < 2:
        return None
    top = [(n, v) for n, v in pairs if n >= counts[-min(points, len(counts))]]
    measured = float(np.polyfit(np.log([n for n, _ in top]), np.log([v for _, v in top]), 1)[0])
    b = float(np.clip(measured, *exponent_range))
    n_max = counts[-1]
    t_max = float(np.exp(np.mean([np.log(v) for n, v in top if n == n_max])))
    return PowerLaw(t_max / n_max ** b, b, measured)


#: the solver's sweeps per step against the spacing: the measured exponent is clipped to this range. Not below 0: sweeps
#: that grow with refinement were measured between the coarsest points only (hydrostatic DFSPH, the first 0.125 s: 3.74
#: and 5.70 at 125 and 648 fluid particles, then 4.31 to 3.58 from 2,925 to 7,497), and a plan calibrated at those alone
#: (load 5) extrapolated them as d^-1: 7.87 sweeps per step predicted at r = 0.0239 m, where r = 0.0285 m had measured
#: 5.70; so growth is not extrapolated (the largest count's sweeps held), a fall is
SWEEPS_EXPONENT_RANGE = (0.0, 1.0)


def fit_sweeps(d, sweeps, points: int = 3, exponent_range=SWEEPS_EXPONENT_RANGE) -> PowerLaw | None:
    """The solver's sweeps per step s = a d^k through the ``points`` finest spacings ``d`` [m] that measured sweeps
    (> 0), k least squares in log space clipped to ``exponent_range`` (one spacing: a constant); None where no point
    measured any (WCSPH). Measured (hydrostatic DFSPH, the first 0.125 s): 4.31, 3.97 and 3.58 sweeps at r = 0.018,
    0.0155 and 0.0136 m, k = 0.65, 3.00 at r = 0.0095 m where the whole run took 3.01 (its fewest: 2 + 1); the
    largest count's 3.58, held, is 19 % high."""
    pairs = sorted((float(x), float(s)) for x, s in zip(d, sweeps) if x > 0 and s > 0)[:points]
    if not pairs:
        return None
    return fit_power_law([x for x, _ in pairs], [s for _, s in pairs], exponent_range)


def log_slope(x0: float, y0: float, x1: float, y1: float) -> float:
    """The exponent k of y ~ x^k through two positive points (0 when either is not positive or x0 == x1)."""
    if min(x0, y0, x1, y1) <= 0 or x0 == x1:
        return 0.0
    return float(np.log(y1 / y0) / np.log(x1 / x0))


def extrapolation(value: float, lo: float, hi: float) -> float:
    """How far ``value`` lies outside [lo, hi] as a factor (1: inside; 8: 8x the largest; 0.5 -> 2)."""
    if value > hi:
        return value / hi
    if value < lo:
        return lo / value
    return 1.0


@dataclass(frozen=True)
class LatticeCount:
    """Particles on a lattice of spacing d: N(d) = (max(a + b d, 0) / d)^k, k = 3 for a volume (fluid), 2 for
    a surface (walls); b < 0 is the layer the walls' gap takes from each block (N^(1/k) d = a + b d is a line)."""

    a: float
    b: float
    k: int
    measured: tuple = ()  # ((d [m], N), ...): the counts sampled at the calibrated spacings, returned as they are

    def __call__(self, d: float) -> int:
        for dm, n in self.measured:  # a calibrated spacing: its count was measured, not predicted
            if abs(float(d) / float(dm) - 1.0) <= 1e-9:
                return int(n)
        return int(round((max(self.a + self.b * float(d), 0.0) / float(d)) ** self.k))


def fit_lattice_count(d, n, k: int) -> LatticeCount:
    """The LatticeCount through the measured counts ``n`` at spacings ``d`` (least squares on N^(1/k) d against
    d; one spacing: b = 0); at a measured spacing it gives the measured count (a fit through the others may miss a
    small lattice's count by a particle, and which radii were calibrated depends on the calibration's timing)."""
    d = np.asarray(d, dtype=np.float64)
    y = d * np.asarray(n, dtype=np.float64) ** (1.0 / k)
    measured = tuple(sorted({(float(di), int(ni)) for di, ni in zip(d, n)}))
    if len(d) >= 2 and np.ptp(d) > 0:
        b, a = np.polyfit(d, y, 1)
        return LatticeCount(float(a), float(b), k, measured)
    return LatticeCount(float(y.mean()), 0.0, k, measured)


@dataclass(frozen=True)
class StepRate:
    """Substeps per simulated second against the spacing d: max(floor, coefficient d^exponent, known(d)). The
    floor is the fewest steps a frame takes (``step_floor``); above it the CFL-type bounds make dt shrink at least
    as fast as d (exponent <= -1: a viscous bound gives -2). ``known``: the rate of the scene's own speed-independent
    bounds (the explicit viscous bound 0.0625 (H_s/2)^2 / nu ~ d^-2, ``scene_bound_rate``), None without one.
    ``quantum`` [1/s]: the frame rate where a frame is split into whole steps (0: none); the law is then the bound's
    own rate, and ``steps`` rounds each frame up. ``speeds`` [m/s]: the fastest particle at the end of each frame of
    a whole run (the profile, the initial frame first), ``cfl`` the scene's time.cfl and ``gravity`` |g| [m/s^2]:
    each frame then takes at least the velocity CFL's steps at its measured speed (``frame_rates``: the steps'
    course over the run; measured, dam break DFSPH: every calibration frame at dt_max, the fastest particle at
    7-8.5 m/s after the impact at 0.25 s, 19-23 steps per frame at r = 0.0198 m)."""

    floor: float
    law: PowerLaw
    quantum: float = 0.0
    known: PowerLaw | None = None
    speeds: tuple = ()
    cfl: float = 0.0
    gravity: float = 0.0
    speed_spacing: float = 0.0   # [m] the spacing ``speeds`` were measured at
    speed_exponent: float = 0.0  # the fastest speed ~ d^k (measured on the calibration's frames, ``fit_speed_exponent``)
    per_substep: bool = False  # the solver sizes each substep for the speed at its start (``Solver.time_step_per_substep``)
    at_floor: bool = False  # every point sat at the floor: ``law`` is a placeholder (d^-1 from the finest point)

    def __call__(self, d: float) -> float:
        return max(self.floor, self.law(d), self.known(d) if self.known is not None else 0.0)

    def frame_rates(self, d: float, frames: int, factor: float = 1.0) -> list:
        """[1/s] the bound's rate in each of ``frames`` frames at spacing ``d`` [m]: with ``speeds`` covering them,
        at least the velocity CFL's at the faster of the frame's start and end speeds v (per frame: (v + |g|
        frame_dt) / (cfl d); ``per_substep``, each substep sized at its start: dt (v + |g| dt) = cfl d); else the
        calibration's rate in every frame."""
        base = max(self.law(d) * factor, self.known(d) if self.known is not None else 0.0)
        if not (self.cfl > 0 and self.quantum > 0 and len(self.speeds) > frames):
            return [base] * frames
        if self.at_floor:  # the speeds' CFL replaces the placeholder
            base = self.known(d) if self.known is not None else 0.0
        reach, g = self.cfl * float(d), self.gravity
        scale = (float(d) / self.speed_spacing) ** self.speed_exponent if self.speed_spacing > 0 else 1.0
        out = []
        for start, end in zip(self.speeds[:frames], self.speeds[1:frames + 1]):
            v = max(start, end) * scale
            cfl = ((v + math.sqrt(v * v + 4.0 * g * reach)) / (2.0 * reach) if self.per_substep
                   else (v + g / self.quantum) / reach)
            out.append(max(base, cfl * factor))
        return out

    def steps(self, d: float, duration: float, factor: float = 1.0) -> int:
        """Substeps of ``duration`` [s] at spacing ``d`` [m], the rate times ``factor``: whole steps per frame
        (each frame n = ceil(rate / fps) equal steps, at least the floor's) where ``quantum`` is set, else
        ceil(rate x duration)."""
        if self.quantum > 0:
            frames = max(int(round(duration * self.quantum)), 1)
            least = max(math.ceil(self.floor / self.quantum - 1e-9), 1)
            return sum(max(math.ceil(r / self.quantum - 1e-9), least) for r in self.frame_rates(d, frames, factor))
        rate = max(self.floor, self.law(d) * factor, self.known(d) if self.known is not None else 0.0)
        return max(math.ceil(rate * duration - 1e-9), 1)


def step_floor(fps: float, dt_max: float, fixed_dt: float = 0.0) -> float:
    """[1/s] the fewest substeps per simulated second: fps x ceil(frame_dt / dt_max), with fixed_dt (> 0) in place
    of dt_max (a frame is split into whole equal steps, ``watchdog.frame_substeps``: dt_max = 5 ms at 24 fps gives
    9 steps per frame, 216 per second, not 200)."""
    bound = fixed_dt if fixed_dt > 0 else dt_max
    return float(fps) * max(math.ceil(1.0 / (float(fps) * bound) - 1e-9), 1)


def fit_step_rate(d, rate, floor: float, quantum: float = 0.0, known: PowerLaw | None = None) -> StepRate:
    """The StepRate of measured rates: a power law (exponent in [-3, -1]) through the points above the floor that
    ``known`` (the scene's speed-independent bound rate, ``scene_bound_rate``) does not explain; with one such point,
    exponent -1 through it; with none, exponent -1 through the finest point (the points sit at the floor: the bound
    lies beyond them). A point is the known bound's where that bound alone takes at least its steps less one and a
    half per frame (measured, hydrostatic DFSPH: 9 / 11 / 26 / 59 steps per frame at r = 0.0426 / 0.0285 / 0.018 /
    0.012 m, the viscous bound's 0.0625 (H_s/2)^2 / nu gives 8.7 / 10.3 / 25.7 / 57.9: with only the 11 above the
    floor the fit fell back to d^-1 and predicted 192 steps where the run took 288). ``quantum``: the frame rate where
    frames are split into whole steps: a measured n steps per frame says only that the bound's rate lies in
    ((n - 1) fps, n fps], so the fit takes its middle, (n - 1/2) fps (a floor point read 216/s, above a 200/s floor,
    flattened the fitted order to -1.24; the free points give -1.9, the viscous bound's d^-2)."""
    d = np.asarray(d, dtype=np.float64)
    rate = np.asarray(rate, dtype=np.float64)
    free = rate > floor + (0.5 * quantum if quantum > 0 else 0.05 * floor)  # a whole step per frame above it
    if known is not None:
        slack = 1.5 * quantum if quantum > 0 else 0.1 * rate
        free &= ~(np.array([known(x) for x in d]) >= rate - slack)
    bound = np.maximum(rate - 0.5 * quantum, 1e-300) if quantum > 0 else rate
    if free.sum() >= 2 and np.ptp(d[free]) > 0:
        return StepRate(floor, fit_power_law(d[free], bound[free], (-3.0, -1.0)), quantum, known)
    if free.any():
        i = int(np.argmax(np.where(free, rate * d, -np.inf)))
        return StepRate(floor, PowerLaw(float(bound[i] * d[i]), -1.0), quantum, known)
    # every point at the floor (or the known bound's): the bound's rate is at most the floor at the finest of
    # them, d^-1 from there (the coarsest point instead: the dam break's DFSPH, every point at dt_max, predicted
    # 276 steps where the run took 135; from the finest: 192)
    i = int(np.argmin(d))
    return StepRate(floor, PowerLaw(float(min(rate[i], floor) * d[i]), -1.0), quantum, known, at_floor=True)


#: the fastest particle's speed against the spacing: the measured exponent is clipped to this range
SPEED_EXPONENT_RANGE = (-0.5, 0.5)


def fit_speed_exponent(d, speeds) -> float:
    """k of the fastest particle's speed ~ d^k: a power law through each point's mean speed over its frames
    (``speeds``: per point, the speeds of its advanced frames), clipped to SPEED_EXPONENT_RANGE; 0 with fewer than
    two spacings. Measured (dam break DFSPH, the first 0.125 s): 1.78 m/s mean at d = 0.063 m, 1.92 at 0.040: k =
    -0.17 (the finer splash is faster; the whole runs' later frames: 7-8.2 and 7.3-8.5 m/s)."""
    pairs = [(float(x), float(np.mean(v))) for x, v in zip(d, speeds) if len(v) and np.mean(v) > 0]
    if len({x for x, _ in pairs}) < 2:
        return 0.0
    return fit_power_law([x for x, _ in pairs], [v for _, v in pairs], SPEED_EXPONENT_RANGE).exponent


def scene_bound_rate(scene) -> PowerLaw | None:
    """[1/s] against d [m]: the rate of the scene's speed-independent step bounds, from the scene itself: each
    active explicit viscosity's 1 / (0.0625 (H_s/2)^2 / nu) with H_s proportional to d (``viscous_step``), so
    coefficient x d^-2; None where the scene has none."""
    from ..methods.force import scene_forces
    from ..methods.forces.explicit_viscosity import ExplicitViscosity, viscous_step

    ratio = float(scene.support_radius) / float(scene.spacing)  # H_s / d
    coefficients = [1.0 / viscous_step(ratio, float(e.config.viscosity)) for e in scene_forces(scene)
                    if issubclass(e.cls, ExplicitViscosity) and e.cls.is_active(e.config)]
    return PowerLaw(max(coefficients), -2.0) if coefficients else None
