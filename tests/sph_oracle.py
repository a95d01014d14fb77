"""NumPy float64 reference implementations (oracles) of the smoothing kernels: Liu & Liu 2010."""
import numpy as np

SUPPORT = {"cubic": 2.0, "quintic": 3.0, "quadric": 2.0}


def f_and_df(name, R):
    R = np.asarray(R, dtype=np.float64)
    if name == "cubic":
        f = np.where(R < 1, 2 / 3 - R**2 + 0.5 * R**3, np.where(R < 2, (2 - R) ** 3 / 6, 0.0))
        df = np.where(R < 1, -2 * R + 1.5 * R**2, np.where(R < 2, -0.5 * (2 - R) ** 2, 0.0))
        return f, df
    if name == "quadric":
        f = np.where(R < 2, 2 / 3 - 9 / 8 * R**2 + 19 / 24 * R**3 - 5 / 32 * R**4, 0.0)
        df = np.where(R < 2, -9 / 4 * R + 19 / 8 * R**2 - 5 / 8 * R**3, 0.0)
        return f, df
    if name == "quintic":
        t3 = np.clip(3 - R, 0, None)
        t2 = np.clip(2 - R, 0, None)
        t1 = np.clip(1 - R, 0, None)
        f = t3**5 - 6 * t2**5 + 15 * t1**5
        df = -5 * t3**4 + 30 * t2**4 - 75 * t1**4
        return f, df
    raise KeyError(name)


def alpha(name, h):
    return {"cubic": 3 / (2 * np.pi), "quadric": 315 / (208 * np.pi), "quintic": 1 / (120 * np.pi)}[name] / h**3


def W(name, r, h):
    f, _ = f_and_df(name, np.asarray(r) / h)
    return alpha(name, h) * f


def grad_W(name, x, h):
    x = np.asarray(x, dtype=np.float64)
    r = np.linalg.norm(x, axis=-1, keepdims=True)
    _, df = f_and_df(name, r / h)
    with np.errstate(invalid="ignore", divide="ignore"):
        g = alpha(name, h) / h * df * x / r
    return np.where(r > 0, g, 0.0)


def fluid_sums(name, h, H, xf, vf, p):
    """(sum_j W v_j, sum_j W, #{j : |p - x_j| < H}) at each point p: what a whitewater particle reads of the
    fluid (kernels/whitewater_sample.py), by brute force; shape (len(p), 5)."""
    p = np.atleast_2d(np.asarray(p, dtype=np.float64))
    r = np.linalg.norm(p[:, None, :] - np.asarray(xf, np.float64)[None, :, :], axis=2)
    near = r < H
    w = np.where(near, W(name, r, h), 0.0)
    return np.concatenate([w @ np.asarray(vf, np.float64), w.sum(axis=1, keepdims=True),
                           near.sum(axis=1, keepdims=True)], axis=1)


def grid_sample(name, h, H, xf, vf, p, lo, s):
    """fluid_sums at the nodes lo + s (a, b, c) of each point's cell, interpolated trilinearly (the
    whitewater's ``fluid_sampling = "grid"``)."""
    p = np.atleast_2d(np.asarray(p, dtype=np.float64))
    q = (p - lo) / s
    a = np.floor(q)
    f = q - a
    out = np.zeros((len(p), 5))
    for corner in np.ndindex(2, 2, 2):
        c = np.array(corner)
        lam = np.prod(np.where(c == 1, f, 1.0 - f), axis=1)
        out += lam[:, None] * fluid_sums(name, h, H, xf, vf, lo + (a + c) * s)
    return out
