"""The tank at rest's flow as a field (issue #31, DFSPH coarse): is it steady, and where does it go.

    python -m benchmarks.hydrostatic_flow --solver dfsph --duration 2
    python -m benchmarks.hydrostatic_flow --solver wcsph --set material.xsph=0.0848

Steps the bench's case scene (``--case``, default ``hydrostatic_fcc``; ``warp_sph.validation.cases``) frame by
frame with ``Simulation.advance_frame`` and reports, as one JSON object on stdout:
- ``frames``: per frame the mean |v| [m/s] and the two top start planes' mean radial velocity about the tank's
  vertical axis [m/s] (> 0: outward), and the mean vertical velocity of the columns within d of a side wall;
- over the frames after ``--window`` [s] (``field``): the correlation of the velocity field of frame k with frame
  k + lag (1: a steady flow; about 0: noise), the mean magnitude of the particles' time-mean velocity and of the
  fluctuation about it [m/s];
- per start plane (``planes``: the start's horizontal planes, d / sqrt 2 apart on the fcc lattice): the time
  mean's radial velocity, the time-mean vertical velocity of the wall columns and of the interior [m/s], and at
  the end the planes' mean particle pressure over rho0 [m^2/s^2] against g (h - z), h the top plane + half a
  plane spacing.
Wrap it in ``flock /tmp/warp_sph_bench.lock`` on a shared machine.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from .hydrostatic_profile import G, _plane_spacing


def lag_correlations(velocities: np.ndarray, lags) -> dict:
    """{lag: mean over k of <V_k, V_(k+lag)> / (|V_k| |V_(k+lag)|)} for the frames' velocity fields ``velocities``
    (frames, particles, 3) [-]; lags as long as the record or longer are left out."""
    f = velocities.reshape(len(velocities), -1)
    out = {}
    for lag in lags:
        if lag >= len(f):
            continue
        a, b = f[:-lag], f[lag:]
        out[int(lag)] = float(np.mean((a * b).sum(1) / np.sqrt((a * a).sum(1) * (b * b).sum(1))))
    return out


def radial_velocity(x: np.ndarray, v: np.ndarray, axis_xy) -> np.ndarray:
    """Each particle's velocity along the horizontal direction from the vertical axis through ``axis_xy`` [m/s]."""
    r = x[:, :2] - np.asarray(axis_xy, dtype=np.float64)
    return (v[:, :2] * r).sum(1) / np.maximum(np.linalg.norm(r, axis=1), 1e-12)


def flow(solver: str, radius: float, duration: float, extra: list[str], case: str = "hydrostatic_fcc",
         window: float = 1.0) -> dict:
    from warp_sph.run.simulation import Simulation
    from warp_sph.validation.cases import CASES, load_case_scene, water_offset

    scene = load_case_scene(CASES[case], solver, radius, extra)
    sim = Simulation(scene)
    m = sim.model
    n, d, rho0 = m.fluid_count, float(m.spacing), float(m.rest_density)
    c, off = scene.container, water_offset(scene)
    lo = np.array([float(c.min[a]) + off for a in range(3)])
    hi = np.array([float(c.max[a]) - off for a in (0, 1)])
    axis = 0.5 * (lo[:2] + hi)
    plane = _plane_spacing(scene, d)
    x0 = sim.get_field("particle_x").astype(np.float64)[:n]
    layer = np.round((x0[:, 2] - lo[2] - 0.5 * d) / plane).astype(int)
    wall = np.minimum(x0[:, :2] - lo[:2], hi - x0[:, :2]).min(axis=1) < d
    top = layer >= layer.max() - 1
    frames, kept = [], []
    c0 = time.process_time()
    while sim.state.time < duration - 1e-9:
        sim.advance_frame()
        x = sim.get_field("particle_x").astype(np.float64)[:n]
        v = sim.get_field("particle_v").astype(np.float64)[:n]
        frames.append({"t": round(float(sim.state.time), 5), "mean": float(np.linalg.norm(v, axis=1).mean()),
                       "top_radial": float(radial_velocity(x[top], v[top], axis).mean()),
                       "wall_vz": float(v[wall, 2].mean())})
        if sim.state.time > window:
            kept.append(v)
    cpu = time.process_time() - c0
    out = {"solver": solver, "radius": radius, "duration": duration, "overrides": extra, "case": case,
           "fluid_particles": int(n), "cpu_s": cpu, "frames": frames}
    if kept:
        V = np.array(kept)
        mean = V.mean(axis=0)
        out["field"] = {"from": window, "frames": len(V), "lag_correlation": lag_correlations(V, (1, 2, 6, 12, 24)),
                        "time_mean_speed": float(np.linalg.norm(mean, axis=1).mean()),
                        "fluctuation_speed": float(np.linalg.norm(V - mean, axis=2).mean())}
        vr = radial_velocity(x, mean, axis)
        p = sim.get_field("particle_pressure")[:n] / rho0 if "particle_pressure" in sim.fields else None
        h = float(x[layer == layer.max(), 2].mean()) + 0.5 * plane
        rows = []
        for j in range(layer.max() + 1):
            s = layer == j
            row = {"plane": j, "radial": float(vr[s].mean()), "vz_wall": float(mean[s & wall, 2].mean()),
                   "vz_interior": float(mean[s & ~wall, 2].mean())}
            if p is not None:
                row["p_over_rho0"] = float(p[s].mean())
                row["g_depth"] = G * (h - float(x[s, 2].mean()))
            rows.append(row)
        out["planes"] = rows
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--solver", default="dfsph")
    ap.add_argument("--radius", type=float, default=0.025, help="particle radius [m] (the case's: 0.025, 0.0125)")
    ap.add_argument("--duration", type=float, default=2.0, help="simulated seconds")
    ap.add_argument("--window", type=float, default=1.0, help="the field's statistics over the frames after this [s]")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="scene override (repeatable)")
    ap.add_argument("--case", default="hydrostatic_fcc", choices=["hydrostatic", "hydrostatic_fcc"])
    a = ap.parse_args(argv)
    print(json.dumps(flow(a.solver, a.radius, a.duration, a.set, a.case, a.window)))


if __name__ == "__main__":
    main()
