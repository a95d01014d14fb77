"""The hydrostatic validation tank's settled state, taken apart: where its floor figure comes from.

    python -m benchmarks.hydrostatic_profile --solver dfsph --radius 0.0125 --duration 2
    python -m benchmarks.hydrostatic_profile --solver wcsph --radius 0.025 --set material.viscosity=0.2

Steps the case's scene (``warp_sph.validation.cases``, as ``bench validation`` loads it) frame by frame with
``Simulation.advance_frame`` and reports, as one JSON object on stdout:
- ``load``: the walls' vertical force on the fluid, sum_i F_i,z, over the weight M g, per frame (its mean, min and
  max over the second half): whether the boundary carries the water;
- ``speed``: mean and rms |v| at the end [m/s] (the issue's "at rest" figure is the mean);
- ``probes``: the floor and mid-depth probes' means over the second half against rho0 g (h - z) with h the
  height probe's surface and with h the level of the water's volume over the tank's floor (z = 0, the case's
  water floor), and the surface's drop below that level [d];
- ``layers``: per horizontal layer of the last state (z rounded to the lattice): mean z, count, rho/rho0 and
  the particles' pressure against rho0 g (h - z): is the water compressed at the floor, and by how much;
- ``lattice_gradient_factor``: C, the SPH gradient of a linear field on the calibrated cubic lattice over the true
  one (1.0201 for the cubic spline at h = d): the bulk's particle pressures balance gravity at rho0 g / C;
- ``columns``: the floor's load per fluid column (the bottom layers' F_z by nearest lattice column, over the
  column's share of the floor) against the mean, along the centre row: how the weight is spread.
The case's tank is 0.6 m wide (its water fills it at every resolution). Wrap it in
``flock /tmp/warp_sph_bench.lock`` on a shared machine.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

G = 9.81


def lattice_gradient_factor(name: str, h: float, spacing: float) -> float:
    """C = sum_j V (z_j - z_i) dW_ij/dz_i (the SPH gradient of f = z) over an interior particle of the cubic lattice, V = 1 / sum_j W_ij (the
    calibrated mass over rho0): the SPH gradient of a linear field over the true one [-]. A particle at rest balances
    gravity with a particle-pressure gradient rho0 g / C, so the pressure field reads 1/C of rho0 g depth inside."""
    from warp_sph.core.smoothing import evaluate, get_smoothing_kernel, lattice_offsets

    x = lattice_offsets(spacing, get_smoothing_kernel(name).support_radius(h)).astype(np.float64)
    w, g = evaluate(name, -x, h)               # x_i - x_j = -x_j with x_i at the origin
    volume = 1.0 / float(np.sum(w.astype(np.float64)))
    return float(np.sum(volume * x[:, 2] * g[:, 2].astype(np.float64)))


def profile(solver: str, radius: float, duration: float, extra: list[str]) -> dict:
    from warp_sph.run.simulation import Simulation
    from warp_sph.validation.cases import CASES, load_case_scene, water_offset

    scene = load_case_scene(CASES["hydrostatic"], solver, radius, extra)
    sim = Simulation(scene)
    m = sim.model
    rho0, d = float(m.rest_density), float(m.spacing)
    c = scene.container
    off = water_offset(scene)
    floor = float(c.min[2]) + off                       # the water's floor
    width = [float(c.max[a] - c.min[a]) - 2.0 * off for a in (0, 1)]
    level = floor + m.fluid_count * m.particle_mass / rho0 / (width[0] * width[1])
    weight = m.fluid_count * m.particle_mass * G
    samples: dict[str, list] = {}
    loads = []
    c0 = time.process_time()
    while sim.state.time < duration - 1e-9:
        sim.advance_frame()
        for k, rows in sim.probes.collect().items():
            samples.setdefault(k, []).extend((t, v) for t, v, _ in rows)
        loads.append((sim.state.time, float(sim.get_field("boundary_force")[:, 2].sum()) / weight))
    cpu = time.process_time() - c0
    late = lambda a: a[:, 0] >= 0.5 * duration  # noqa: E731
    L = np.array(loads)
    t, h = np.array(samples["surface"]).T
    h_probe = float(h[t >= 0.5 * duration].mean())
    out = {"solver": solver, "radius": radius, "duration": duration, "overrides": extra, "fluid_particles": m.fluid_count,
           "cpu_s": cpu, "water_floor": floor, "volume_level": level, "surface_probe": h_probe,
           "surface_drop_d": (level - h_probe) / d,
           "lattice_gradient_factor": lattice_gradient_factor(m.smoothing.name, float(m.smoothing_length), d),
           "load": {"mean": float(L[late(L), 1].mean()), "min": float(L[late(L), 1].min()),
                    "max": float(L[late(L), 1].max()), "first_frame": float(L[0, 1])}}
    v = np.linalg.norm(sim.get_field("particle_v"), axis=1)
    out["speed"] = {"mean": float(v.mean()), "rms": float(np.sqrt((v * v).mean()))}
    probes = {"floor": floor, "middle": None}
    for name in probes:
        if name not in samples:
            continue
        S = np.array(samples[name])
        z = floor if name == "floor" else float(scene.probes[[p.name for p in scene.probes].index(name)].position[2])
        p = float(S[late(S), 1].mean())
        out.setdefault("probes", {})[name] = {"z": z, "p": p, "error_vs_probe_surface": p / (rho0 * G * (h_probe - z)) - 1.0,
                                             "error_vs_volume_level": p / (rho0 * G * (level - z)) - 1.0}
    x = sim.get_field("particle_x").astype(np.float64)
    fields = sim.fields
    rho = sim.get_field("particle_density") if "particle_density" in fields else None
    pr = sim.get_field("particle_pressure") if "particle_pressure" in fields else None
    first = floor + 0.5 * d
    k = np.round((x[:, 2] - first) / d).astype(int)
    layers = []
    for j in range(k.min(), k.max() + 1):
        s = k == j
        if not s.any():
            continue
        zj = float(x[s, 2].mean())
        row = {"layer": j, "z": zj, "count": int(s.sum())}
        if rho is not None:
            row["rho_rel"] = float(rho[s].mean() / rho0)
        if pr is not None:
            row["p_over_hydrostatic"] = float(pr[s].mean() / (rho0 * G * (h_probe - zj)))
        layers.append(row)
    out["layers"] = layers
    F = sim.get_field("boundary_force")
    n = [int(round(w / d)) for w in width]
    lo = [float(c.min[a]) + off + 0.5 * d for a in (0, 1)]
    bottom = x[:, 2] < floor + 0.5 * d + float(m.support_radius) + 0.5 * d
    ij = [np.clip(np.round((x[bottom, a] - lo[a]) / d).astype(int), 0, n[a] - 1) for a in (0, 1)]
    P = np.zeros(n)
    np.add.at(P, (ij[0], ij[1]), F[bottom, 2])
    P /= (width[0] / n[0]) * (width[1] / n[1])
    mean = weight / (width[0] * width[1])
    out["columns"] = {"centre_row_over_mean": [round(float(v), 4) for v in P[n[0] // 2] / mean],
                      "centre_over_mean": float(P[n[0] // 2, n[1] // 2] / mean)}
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--solver", default="dfsph")
    ap.add_argument("--radius", type=float, default=0.025, help="particle radius [m] (the case's: 0.025, 0.0125)")
    ap.add_argument("--duration", type=float, default=2.0, help="simulated seconds")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="scene override (repeatable)")
    a = ap.parse_args(argv)
    print(json.dumps(profile(a.solver, a.radius, a.duration, a.set), indent=1))


if __name__ == "__main__":
    main()
