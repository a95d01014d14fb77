"""Smoothing kernels of Liu & Liu (2010) in 3D, as ``@wp.func`` value/gradient pairs.

Notation: r = |x_ij| [m], h = smoothing length [m], R = r/h, W(r, h) = alpha_3D f(R) [1/m^3],
grad_i W_ij = (alpha_3D/h) f'(R) x_ij / r [1/m^4] with x_ij = x_i - x_j, and grad W(0) = 0.

| kernel  | support | alpha_3D            |
|---------|---------|---------------------|
| cubic   | 2h      | 3 / (2 pi h^3)      |
| quintic | 3h      | 1 / (120 pi h^3)    |  (exact; the widely printed 3/(359 pi h^3) is +0.28 %)
| quadric | 2h      | 315 / (208 pi h^3)  |

Every f and f' is zero at the support edge, so W and grad W are continuous there.
"""
import functools
import math

import warp as wp

PI = wp.constant(math.pi)


@wp.func
def cubic_value(r: float, h: float) -> float:
    """Cubic spline (Monaghan & Lattanzio 1985), support 2h: W(r, h) [1/m^3]."""
    q = r / h
    a = 3.0 / (2.0 * PI * h * h * h)
    if q < 1.0:
        return a * (2.0 / 3.0 - q * q + 0.5 * q * q * q)
    if q < 2.0:
        t = 2.0 - q
        return a * t * t * t / 6.0
    return 0.0


@wp.func
def cubic_gradient(x_ij: wp.vec3, h: float) -> wp.vec3:
    """Gradient of the cubic spline with respect to x_i, x_ij = x_i - x_j [1/m^4]."""
    r = wp.length(x_ij)
    q = r / h
    if r <= 0.0 or q >= 2.0:
        return wp.vec3(0.0)
    a = 3.0 / (2.0 * PI * h * h * h * h)
    df = float(0.0)
    if q < 1.0:
        df = -2.0 * q + 1.5 * q * q
    else:
        t = 2.0 - q
        df = -0.5 * t * t
    return x_ij * (a * df / r)


@wp.func
def quintic_value(r: float, h: float) -> float:
    """Quintic spline (Morris 1997), support 3h: W(r, h) [1/m^3], alpha = 1/(120 pi h^3)."""
    q = r / h
    if q >= 3.0:
        return 0.0
    a = 1.0 / (120.0 * PI * h * h * h)
    t3 = 3.0 - q
    f = t3 * t3 * t3 * t3 * t3
    if q < 2.0:
        t2 = 2.0 - q
        f = f - 6.0 * t2 * t2 * t2 * t2 * t2
    if q < 1.0:
        t1 = 1.0 - q
        f = f + 15.0 * t1 * t1 * t1 * t1 * t1
    return a * f


@wp.func
def quintic_gradient(x_ij: wp.vec3, h: float) -> wp.vec3:
    """Gradient of the quintic spline with respect to x_i [1/m^4]."""
    r = wp.length(x_ij)
    q = r / h
    if r <= 0.0 or q >= 3.0:
        return wp.vec3(0.0)
    a = 1.0 / (120.0 * PI * h * h * h * h)
    t3 = 3.0 - q
    df = -5.0 * t3 * t3 * t3 * t3
    if q < 2.0:
        t2 = 2.0 - q
        df = df + 30.0 * t2 * t2 * t2 * t2
    if q < 1.0:
        t1 = 1.0 - q
        df = df - 75.0 * t1 * t1 * t1 * t1
    return x_ij * (a * df / r)


@wp.func
def quadric_value(r: float, h: float) -> float:
    """Quadric smoothing function (Liu, Liu & Lam 2003), support 2h: W(r, h) [1/m^3]."""
    q = r / h
    if q >= 2.0:
        return 0.0
    a = 315.0 / (208.0 * PI * h * h * h)
    return a * (2.0 / 3.0 - 9.0 / 8.0 * q * q + 19.0 / 24.0 * q * q * q - 5.0 / 32.0 * q * q * q * q)


@wp.func
def quadric_gradient(x_ij: wp.vec3, h: float) -> wp.vec3:
    """Gradient of the quadric smoothing function with respect to x_i [1/m^4]."""
    r = wp.length(x_ij)
    q = r / h
    if r <= 0.0 or q >= 2.0:
        return wp.vec3(0.0)
    a = 315.0 / (208.0 * PI * h * h * h * h)
    df = -9.0 / 4.0 * q + 19.0 / 8.0 * q * q - 5.0 / 8.0 * q * q * q
    return x_ij * (a * df / r)


# name -> (value, gradient); the host registry in warp_sph/smoothing.py adds support and defaults.
SMOOTHING_FUNCTIONS = {
    "cubic": (cubic_value, cubic_gradient),
    "quintic": (quintic_value, quintic_gradient),
    "quadric": (quadric_value, quadric_gradient),
}


@functools.cache
def evaluate_kernel(smoothing: str):
    """Kernel that evaluates W and grad W of one smoothing kernel at given offsets (host checks)."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.kernel(enable_backward=False, module="unique")
    def evaluate_smoothing(
        # In:
        offset_in: wp.array(dtype=wp.vec3),
        h: float,
        # Out:
        value_out: wp.array(dtype=float),
        gradient_out: wp.array(dtype=wp.vec3),
    ):
        tid = wp.tid()
        x = offset_in[tid]
        value_out[tid] = wp.static(value)(wp.length(x), h)
        gradient_out[tid] = wp.static(gradient)(x, h)

    return evaluate_smoothing
