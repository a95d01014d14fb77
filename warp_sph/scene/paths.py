"""Paths of animated colliders: a rigid pose that changes with time, from TOML keyframes or a USD file.

A path maps the collider's local points (its geometry as written in the scene: a box's min/max, a
mesh after its scale and translate) to the world at time t [s]:

    x(t) = R(t) x_local + T(t),    v(t) = dT/dt + omega(t) x (x(t) - T(t))

Keys are (time [s], translate T [m], rotation [deg]) with the rotation as Euler angles about X, then
Y, then Z (extrinsic, R = Rz Ry Rx: Blender's XYZ rotation mode, the convention of ``bodies[].rotation``).
Each of the six channels is interpolated on its own, as Blender's F-curves do, so a key at 0 deg and
one at 360 deg make a full turn:

- ``linear``: straight lines between keys (velocity jumps at every key);
- ``smooth``: cubic Hermite with Catmull-Rom tangents m_k = (p_{k+1} - p_{k-1}) / (t_{k+1} - t_{k-1})
  inside, and zero tangents at the first and last key (the path starts and ends at rest, like
  Blender's default auto-clamped Bezier keys): continuous velocity.

Before the first key and after the last the end pose is held (velocity 0). The angular velocity is the
exact derivative of R(t): omega = c' e_z + b' Rz(c) e_y + a' Rz(c) Ry(b) e_x for angles (a, b, c)
about (X, Y, Z).

USD (``usd_path``): the prim's local-to-world matrix (``UsdGeom.Xformable.ComputeLocalToWorldTransform``,
ancestors included) at every authored time sample of the prim or an ancestor, split into translate and
Euler angles (unwrapped so consecutive samples differ by less than 180 deg per channel), at time
t = (time code - startTimeCode) / timeCodesPerSecond; translations times the stage's metersPerUnit; a
Y-up stage is turned Z-up by +90 deg about X, as Blender's importer does. Blender's USD exporter writes
Z-up, metersPerUnit 1, timeCodesPerSecond = the scene's fps and one sample per frame, startTimeCode =
the first frame: that frame is t = 0.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path as _FsPath

import numpy as np

from ..core.errors import SceneError

INTERPOLATIONS = ("linear", "smooth")


def euler_matrix(deg) -> np.ndarray:
    """R = Rz(c) Ry(b) Rx(a) of Euler angles (a, b, c) [deg] about X, Y, Z; shape (..., 3, 3)."""
    a, b, c = (np.radians(np.asarray(deg, dtype=np.float64)[..., k]) for k in range(3))
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    R = np.empty(np.shape(a) + (3, 3))
    R[..., 0, 0] = cc * cb
    R[..., 0, 1] = cc * sb * sa - sc * ca
    R[..., 0, 2] = cc * sb * ca + sc * sa
    R[..., 1, 0] = sc * cb
    R[..., 1, 1] = sc * sb * sa + cc * ca
    R[..., 1, 2] = sc * sb * ca - cc * sa
    R[..., 2, 0] = -sb
    R[..., 2, 1] = cb * sa
    R[..., 2, 2] = cb * ca
    return R


def matrix_euler(R) -> np.ndarray:
    """Euler angles (a, b, c) [deg] about X, Y, Z with R = Rz(c) Ry(b) Rx(a) (b in [-90, 90])."""
    R = np.asarray(R, dtype=np.float64)
    b = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    a = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    c = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.degrees(np.stack([a, b, c], axis=-1))


def matrix_quaternion(R) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    else:
        i = int(np.argmax([R[0, 0], R[1, 1], R[2, 2]]))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-300))
        q = [0.0, 0.0, 0.0, (R[k, j] - R[j, k]) / s]
        q[i] = 0.25 * s
        q[j] = (R[j, i] + R[i, j]) / s
        q[k] = (R[k, i] + R[i, k]) / s
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def _hermite(s):
    """Cubic Hermite basis (h00, h10, h01, h11) and its derivative in s."""
    s2, s3 = s * s, s * s * s
    return ((2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2),
            (6 * s2 - 6 * s, 3 * s2 - 4 * s + 1, -6 * s2 + 6 * s, 3 * s2 - 2 * s))


@dataclass
class Path:
    """Keys (times [s] (K,), channels (K, 6) = translate [m] and Euler XYZ angles [deg]) and the
    interpolation ("linear" or "smooth"). Evaluate with ``pose`` and ``velocity``."""

    times: np.ndarray
    channels: np.ndarray
    interpolation: str = "linear"
    source: str = "keyframes"

    def __post_init__(self):
        self.times = np.asarray(self.times, dtype=np.float64).reshape(-1)
        self.channels = np.asarray(self.channels, dtype=np.float64).reshape(-1, 6)
        k = len(self.times)
        self.tangents = np.zeros_like(self.channels)
        if self.interpolation == "smooth" and k > 2:
            self.tangents[1:-1] = ((self.channels[2:] - self.channels[:-2])
                                   / (self.times[2:] - self.times[:-2])[:, None])

    def channels_at(self, t) -> tuple[np.ndarray, np.ndarray]:
        """(channels (..., 6), their time derivatives (..., 6)) at times ``t`` [s]."""
        t = np.asarray(t, dtype=np.float64)
        T, P = self.times, self.channels
        if len(T) == 1:
            return np.broadcast_to(P[0], t.shape + (6,)).copy(), np.zeros(t.shape + (6,))
        tc = np.clip(t, T[0], T[-1])
        i = np.clip(np.searchsorted(T, tc, side="right") - 1, 0, len(T) - 2)
        dt = T[i + 1] - T[i]
        s = ((tc - T[i]) / dt)[..., None]
        p0, p1 = P[i], P[i + 1]
        if self.interpolation == "smooth":
            (h00, h10, h01, h11), (d00, d10, d01, d11) = _hermite(s)
            m0, m1 = self.tangents[i] * dt[..., None], self.tangents[i + 1] * dt[..., None]
            value = h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1
            rate = (d00 * p0 + d10 * m0 + d01 * p1 + d11 * m1) / dt[..., None]
        else:
            value = p0 + s * (p1 - p0)
            rate = np.broadcast_to((p1 - p0) / dt[..., None], value.shape).copy()
        outside = ((t < T[0]) | (t > T[-1]))[..., None]
        return value, np.where(outside, 0.0, rate)

    def pose(self, t) -> tuple[np.ndarray, np.ndarray]:
        """(R (..., 3, 3), T [m] (..., 3)) at times ``t`` [s]."""
        c, _ = self.channels_at(t)
        return euler_matrix(c[..., 3:]), c[..., :3]

    def velocity(self, t) -> tuple[np.ndarray, np.ndarray]:
        """(dT/dt [m/s] (..., 3), omega [rad/s] (..., 3), world axes) at times ``t`` [s]."""
        c, r = self.channels_at(t)
        a, b, cz = (np.radians(c[..., 3 + k]) for k in range(3))
        da, db, dc = (np.radians(r[..., 3 + k]) for k in range(3))
        ex = np.stack([np.cos(cz) * np.cos(b), np.sin(cz) * np.cos(b), -np.sin(b)], axis=-1)  # Rz Ry e_x
        ey = np.stack([-np.sin(cz), np.cos(cz), np.zeros_like(cz)], axis=-1)                 # Rz e_y
        ez = np.broadcast_to(np.array([0.0, 0.0, 1.0]), ex.shape)
        omega = dc[..., None] * ez + db[..., None] * ey + da[..., None] * ex
        return r[..., :3], omega

    def max_speed(self, reach: float, t0: float, t1: float, samples: int = 64) -> float:
        """Largest |dT/dt| + |omega| reach [m/s] over [t0, t1] (every key inside, plus ``samples`` times,
        plus 7 times inside every key interval shorter than 8 sample spacings: a smooth segment's speed peaks
        between its keys however short it is; ``reach`` [m]: the farthest local point from the local origin)."""
        a, b = self.times[:-1], self.times[1:]
        short = (b - a) < 8.0 * (t1 - t0) / max(samples - 1, 1)
        a, b = a[short], b[short]
        inner = (a[:, None] + np.linspace(0.0, 1.0, 9)[None, 1:-1] * (b - a)[:, None]).reshape(-1)
        t = np.concatenate([np.linspace(t0, t1, samples), self.times[(self.times >= t0) & (self.times <= t1)],
                            inner[(inner >= t0) & (inner <= t1)]])
        t = np.concatenate([t, np.nextafter(t, -np.inf)])
        v, w = self.velocity(t)
        return float(np.max(np.linalg.norm(v, axis=-1) + np.linalg.norm(w, axis=-1) * reach))


def keyframe_path(keys: list, interpolation: str, fail, keypath: str) -> Path:
    """A Path from validated ``keyframes`` entries (dicts with time, translate, rotation); ``fail(keypath,
    message)`` raises for fewer than one key or times not strictly increasing."""
    if not keys:
        fail(f"{keypath}.keyframes", "expected at least one keyframe ({time = ..., translate = [...]})")
    times = [float(k["time"]) for k in keys]
    for i in range(1, len(times)):
        if not times[i] > times[i - 1]:
            what = "duplicated" if times[i] == times[i - 1] else "out of order"
            fail(f"{keypath}.keyframes[{i}].time", f"keyframe times must increase strictly; {times[i]:g} s is {what} "
                 f"after keyframes[{i - 1}].time = {times[i - 1]:g} s")
    channels = [list(k["translate"]) + list(k["rotation"]) for k in keys]
    return Path(np.array(times), np.array(channels), interpolation, "keyframes")


_Y_TO_Z = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # +90 deg about X


def usd_path(file, prim_path: str, interpolation: str, fail, keypath: str) -> Path:
    """A Path from the animated transform of prim ``prim_path`` in the USD file ``file`` (module docstring).
    ``fail(keypath, message)`` raises for a missing file or prim, a prim that is not an Xformable or has no
    time samples, a scale other than 1 or a shear."""
    file = _FsPath(file)
    if not file.is_file():
        fail(f"{keypath}.animation.file", f"USD file {str(file)!r} does not exist")
    from pxr import Usd, UsdGeom

    try:
        stage = Usd.Stage.Open(str(file))
    except Exception as exc:  # noqa: BLE001 - pxr raises its own Tf errors
        fail(f"{keypath}.animation.file", f"cannot open USD file {str(file)!r}: {' '.join(str(exc).split())[:120]}")
    prim = stage.GetPrimAtPath(prim_path) if prim_path.startswith("/") else Usd.Prim()
    if not prim or not prim.IsValid():
        fail(f"{keypath}.animation.prim", f"prim {prim_path!r} does not exist in {file.name!r} (expected an absolute "
             "prim path such as '/paddle')")
    if not prim.IsA(UsdGeom.Xformable):
        fail(f"{keypath}.animation.prim", f"prim {prim_path!r} in {file.name!r} is a {prim.GetTypeName() or 'typeless'} "
             "prim, not an Xformable (Xform or a geometry prim) with a transform")
    codes: set[float] = set()
    p = prim
    while p and p.IsValid() and not p.IsPseudoRoot():
        if p.IsA(UsdGeom.Xformable):
            codes.update(UsdGeom.Xformable(p).GetTimeSamples())
        p = p.GetParent()
    if not codes:
        fail(f"{keypath}.animation.prim", f"prim {prim_path!r} in {file.name!r} is not animated: its transform has no "
             "time samples (export with Blender's USD exporter with Animation ticked)")
    codes = sorted(codes)
    tcps = float(stage.GetTimeCodesPerSecond())
    start = float(stage.GetStartTimeCode()) if stage.HasAuthoredMetadata("startTimeCode") else codes[0]
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    up = _Y_TO_Z if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y else np.eye(3)
    xf = UsdGeom.Xformable(prim)
    times, translate, rot = [], [], []
    for code in codes:
        M = np.array(xf.ComputeLocalToWorldTransform(Usd.TimeCode(code)), dtype=np.float64)
        R = M[:3, :3].T  # USD: row vectors, x' = x M
        sv = np.linalg.svd(R, compute_uv=False)
        if np.max(np.abs(sv - 1.0)) > 1e-4 or np.linalg.det(R) < 0:
            fail(f"{keypath}.animation.prim", f"prim {prim_path!r} has a scale or shear at time code {code:g} (singular "
                 f"values {np.round(sv, 6).tolist()}); a collider moves rigidly: apply the scale to the mesh")
        times.append((code - start) / tcps)
        translate.append(up @ M[3, :3] * mpu)
        rot.append(up @ R)
    euler = np.degrees(np.unwrap(np.radians(matrix_euler(np.array(rot))), axis=0))
    return Path(np.array(times), np.concatenate([np.array(translate), euler], axis=1), interpolation,
                f"{file.name}:{prim_path}")


def check_inside(path: Path, lo, hi, container, duration: float, keypath: str, fail, samples: int = 200) -> None:
    """``fail`` unless the 8 corners of the local box lo..hi [m], moved along ``path``, stay inside the
    ``container`` at every key and at ``samples`` times over [0, duration] [s]."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], float)
    t = np.concatenate([np.linspace(0.0, duration, samples), path.times[(path.times >= 0) & (path.times <= duration)]])
    t = np.sort(t)
    R, T = path.pose(t)
    world = np.einsum("kij,cj->kci", R, corners) + T[:, None, :]
    cmin, cmax = np.asarray(container.min, float), np.asarray(container.max, float)
    tol = 1e-9 * max(1.0, float(np.max(np.abs(np.concatenate([cmin, cmax])))))
    out = np.any((world < cmin - tol) | (world > cmax + tol), axis=2)
    if out.any():
        k, c = np.argwhere(out)[0]
        fail(keypath, f"its path leaves the container {cmin.tolist()}..{cmax.tolist()} at t = {t[k]:.4g} s (a corner "
             f"of its box reaches {np.round(world[k, c], 6).tolist()}); keep every pose inside the container")
