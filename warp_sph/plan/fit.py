"""The fitted models of ``warp-sph plan``: power laws in log space and a line with non-negative coefficients.

Every figure of a plan comes from a fit to measured calibration points (``calibrate.py``):
- particles against the spacing d: fluid (a + b d)^3 / d^3, walls (a + b d)^2 / d^2 (``LatticeCount``);
- steps per simulated second against d: max(floor, a d^q) with q <= -1 (CFL: dt ~ h / v; ``StepRate``);
- mean density error against the spacing: e = A d^p, p the measured convergence order;
- wall time of one step against the particle count N: t = c0 + c1 N (c0, c1 >= 0: launch overhead and
  cost per particle-step);
- wall time outside the steps (set-up, statistics, exports) against N: the same line.
"""
from __future__ import annotations

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

    def __call__(self, d: float) -> int:
        return int(round((max(self.a + self.b * float(d), 0.0) / float(d)) ** self.k))


def fit_lattice_count(d, n, k: int) -> LatticeCount:
    """The LatticeCount through the measured counts ``n`` at spacings ``d`` (least squares on N^(1/k) d against
    d; one spacing: b = 0)."""
    d = np.asarray(d, dtype=np.float64)
    y = d * np.asarray(n, dtype=np.float64) ** (1.0 / k)
    if len(d) >= 2 and np.ptp(d) > 0:
        b, a = np.polyfit(d, y, 1)
        return LatticeCount(float(a), float(b), k)
    return LatticeCount(float(y.mean()), 0.0, k)


@dataclass(frozen=True)
class StepRate:
    """Substeps per simulated second against the spacing d: max(floor, coefficient d^exponent). The floor is
    one step per frame or per ``time.dt_max``; above it the CFL-type bounds make dt shrink at least as fast as
    d (exponent <= -1: a viscous bound gives -2)."""

    floor: float
    law: PowerLaw

    def __call__(self, d: float) -> float:
        return max(self.floor, self.law(d))


def fit_step_rate(d, rate, floor: float) -> StepRate:
    """The StepRate of measured rates: a power law (exponent in [-3, -1]) through the points above the floor;
    with one such point, exponent -1 through it; with none, exponent -1 through the largest rate x d (an upper
    bound: the points sit at the floor)."""
    d = np.asarray(d, dtype=np.float64)
    rate = np.asarray(rate, dtype=np.float64)
    free = rate > 1.05 * floor
    if free.sum() >= 2 and np.ptp(d[free]) > 0:
        return StepRate(floor, fit_power_law(d[free], rate[free], (-3.0, -1.0)))
    i = int(np.argmax(np.where(free, rate * d, -np.inf))) if free.any() else int(np.argmax(rate * d))
    return StepRate(floor, PowerLaw(float(rate[i] * d[i]), -1.0))
