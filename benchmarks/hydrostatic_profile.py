"""The hydrostatic validation tank's settled state, taken apart: where its floor figure comes from.

    python -m benchmarks.hydrostatic_profile --solver dfsph --radius 0.0125 --duration 2
    python -m benchmarks.hydrostatic_profile --solver wcsph --radius 0.025 --set material.viscosity=0.2
    python -m benchmarks.hydrostatic_profile --motion --solver pbf --duration 5   # what moves (``motion``)

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
The case's tank is 0.6 m wide (its water fills it at every resolution); ``--case hydrostatic_fcc`` runs the fcc
start in its fitted tank. Wrap it in ``flock /tmp/warp_sph_bench.lock`` on a shared machine.
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


def lattice_slip_stiffness(name: str, h: float, spacing: float, shift: float = 1e-3) -> float:
    """k d^2 / (P / rho0), the restoring acceleration per unit displacement of one lattice column moved along its own
    axis (z) by delta against the still ones, under a uniform particle pressure P: a_z = -(2 P / rho0) sum_j V
    dW/dz(x_i + delta e_z - x_j) over the particles j of the OTHER columns (its own column moves with it), V the
    calibrated volume, by central differences in delta = +-shift d [-]. Positive: the cubic lattice is a stable
    rest state under pressure; negative: under any positive pressure a column slips along itself (the symmetric
    pressure force's pairs across columns repel it further than its diagonal pairs pull it back), a re-packing
    with no density change that the pressure solve cannot see (issue #31)."""
    from warp_sph.core.smoothing import evaluate, get_smoothing_kernel, lattice_offsets

    x = lattice_offsets(spacing, get_smoothing_kernel(name).support_radius(h) + spacing).astype(np.float64)
    w, _ = evaluate(name, -x, h)
    volume = 1.0 / float(np.sum(w.astype(np.float64)))
    other = np.hypot(x[:, 0], x[:, 1]) > 0.5 * spacing
    a = []
    for delta in (shift * spacing, -shift * spacing):
        _, g = evaluate(name, (np.array([0.0, 0.0, delta]) - x[other]).astype(np.float32), h)
        a.append(-2.0 * volume * float(np.sum(g[:, 2].astype(np.float64))))
    return -(a[0] - a[1]) / (2.0 * shift * spacing) * spacing * spacing


def _plane_spacing(scene, d: float) -> float:
    """Spacing of the start's horizontal planes [m]: d for the cubic lattice, d / sqrt 2 for fcc (its planes are
    the per-layer figures' layers)."""
    from warp_sph.core.model import fluid_lattice
    from warp_sph.core.smoothing import LATTICE_LAYER

    return LATTICE_LAYER[fluid_lattice(scene)] * d


def profile(solver: str, radius: float, duration: float, extra: list[str], case: str = "hydrostatic") -> dict:
    from warp_sph.run.simulation import Simulation
    from warp_sph.validation.cases import CASES, load_case_scene, water_offset

    scene = load_case_scene(CASES[case], solver, radius, extra)
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
    k = np.round((x[:, 2] - first) / _plane_spacing(scene, d)).astype(int)  # the start's planes (fcc: d / sqrt 2)
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


# --- issue #31's "at rest": what moves (``--motion``) -----------------------------------------------------------------

def _pair_correlations(x: np.ndarray, v: np.ndarray, d: float) -> dict:
    """Velocity correlations over the nearest-neighbour pairs (|x_ij| < 1.2 d) of one state [-]:
    ``all`` = sum_pairs v_i . v_j / sum_pairs (|v_i|^2 + |v_j|^2) / 2 (1: the pair moves together, 0: uncorrelated,
    -1: opposite), ``vertical_vz`` the same of v_z over the pairs stacked in z (|z_ij| > 0.8 d), ``horizontal_vz`` of
    v_z over the pairs side by side in one layer (|z_ij| < 0.2 d): a layer-by-layer alternation reads vertical < 0 <
    horizontal."""
    n = x.shape[0]
    num = {"all": 0.0, "vertical_vz": 0.0, "horizontal_vz": 0.0}
    den = dict.fromkeys(num, 0.0)
    for s in range(0, n, 1024):
        dx = x[s:s + 1024, None, :] - x[None, :, :]
        r = np.linalg.norm(dx, axis=2)
        i, j = np.nonzero((r < 1.2 * d) & (r > 0.0))
        i += s
        keep = i < j
        i, j = i[keep], j[keep]
        dz = np.abs(x[i, 2] - x[j, 2])
        num["all"] += float(np.sum(v[i] * v[j]))
        den["all"] += float(np.sum(v[i] ** 2 + v[j] ** 2)) / 2.0
        for key, sel in (("vertical_vz", dz > 0.8 * d), ("horizontal_vz", dz < 0.2 * d)):
            num[key] += float(np.sum(v[i[sel], 2] * v[j[sel], 2]))
            den[key] += float(np.sum(v[i[sel], 2] ** 2 + v[j[sel], 2] ** 2)) / 2.0
    return {k: num[k] / den[k] if den[k] > 0.0 else 0.0 for k in num}


def _block_energy_share(x: np.ndarray, v: np.ndarray, lo: np.ndarray, block: float) -> float:
    """Share of the kinetic energy in the block-mean velocities (blocks of side ``block`` [m]) [-]: 1 for a flow
    coherent over the blocks (sloshing, breathing), about 1/(particles per block) for uncorrelated noise."""
    k = np.floor((x - lo) / block).astype(int)
    key = (k[:, 0] * 1000 + k[:, 1]) * 1000 + k[:, 2]
    _, inv, count = np.unique(key, return_inverse=True, return_counts=True)
    mean = np.zeros((count.size, 3))
    for a in range(3):
        mean[:, a] = np.bincount(inv, v[:, a]) / count
    total = float(np.sum(v * v))
    return float(np.sum(count[:, None] * mean * mean)) / total if total > 0.0 else 0.0


def motion(solver: str, radius: float, duration: float, extra: list[str], every: int = 3, stagger: float = 0.0,
           case: str = "hydrostatic") -> dict:
    """What moves in the tank at rest (issue #31), frame by frame to ``duration``: per frame the mean |v| [m/s] of
    all particles, per lattice layer (the start's z index), of the columns at the side walls (the outer ring),
    of the corner columns and of the interior; every ``every`` frames the velocity field's character
    (``_pair_correlations``, ``_block_energy_share`` over 3 d blocks), the centre of mass's velocity and the
    surface's tilt (top layer's mean z at x > mid minus at x < mid) [m] for the sloshing mode, whose period
    2 pi / sqrt(g k tanh(k D)), k = pi / L, is reported beside (``slosh_period``); and the decay rate of the
    mean |v| fitted over each second, log(v) = a - t / tau; with the character, per layer the spread (standard
    deviation) and mean of the particles' vertical displacement from the start [d], whose spread is the columns'
    slip along themselves (``lattice_slip_stiffness``), and the mean horizontal displacement [d]; over the second
    half, per step, the walls' vertical load over the weight (mean, mean step-to-step change) and the solver's
    iteration counts (``load_second_half``). ``stagger`` > 0
    raises every other column (a checkerboard in x, y) by stagger d before the first step: at 0.5 the bulk's
    columns stand half a spacing apart, the arrangement the slip heads for (its slip stiffness positive)."""
    from warp_sph.run.simulation import Simulation
    from warp_sph.validation.cases import CASES, load_case_scene, water_offset

    scene = load_case_scene(CASES[case], solver, radius, extra)
    sim = Simulation(scene)
    m = sim.model
    d = float(m.spacing)
    c = scene.container
    off = water_offset(scene)
    lo = np.array([float(c.min[a]) + off for a in range(3)])
    hi = np.array([float(c.max[a]) - off for a in (0, 1)])
    x0 = sim.get_field("particle_x").astype(np.float64)[: m.fluid_count]
    layer = np.round((x0[:, 2] - lo[2] - 0.5 * d) / _plane_spacing(scene, d)).astype(int)
    if stagger:  # an experiment, not a start: every other column (a checkerboard in x, y) raised by stagger d
        ij = np.round((x0[:, :2] - lo[:2] - 0.5 * d) / d).astype(int)
        x = sim.get_field("particle_x")
        x[: m.fluid_count, 2] += np.where(ij.sum(axis=1) % 2 == 1, stagger * d, 0.0).astype(x.dtype)
        sim.set_field("particle_x", x)
        sim.refresh_density()
        x0 = x[: m.fluid_count].astype(np.float64)
    wall_dist = np.minimum(x0[:, :2] - lo[:2], hi - x0[:, :2]).min(axis=1)
    edge_count = ((x0[:, :2] - lo[:2] < d) | (hi - x0[:, :2] < d)).sum(axis=1)
    ring = wall_dist < d
    corner = edge_count == 2
    groups = {"wall_ring": ring & ~corner, "corner_columns": corner, "interior": ~ring}
    top = layer == layer.max()
    L = float(hi[0] - lo[0])
    depth = float(layer.max() + 1) * d
    k = np.pi / L
    frames, character, steps = [], [], []
    weight = m.fluid_count * m.particle_mass * G

    def record(sim, dt):  # per step: the walls' vertical load over the weight, the solver's iterations
        steps.append((float(sim.state.time), float(sim.get_field("boundary_force")[:, 2].astype(np.float64).sum())
                      / weight, int(getattr(sim.solver, "last_iterations", 0))))

    from warp_sph.core.step_graph import Stage

    sim.graph.insert(Stage("wall_load", record, reads=("boundary_force",)))
    c0 = time.process_time()
    f = 0
    while sim.state.time < duration - 1e-9:
        sim.advance_frame()
        f += 1
        x = sim.get_field("particle_x").astype(np.float64)[: m.fluid_count]
        v = sim.get_field("particle_v").astype(np.float64)[: m.fluid_count]
        s = np.linalg.norm(v, axis=1)
        row = {"t": round(float(sim.state.time), 5), "mean": float(s.mean()),
               "layers": [float(s[layer == j].mean()) for j in range(layer.max() + 1)]}
        row.update({g: float(s[sel].mean()) for g, sel in groups.items()})
        row["share_top_layer"] = float(s[top].sum() / s.sum())
        row["share_wall_ring_and_corners"] = float(s[ring].sum() / s.sum())
        frames.append(row)
        if f % every == 0:
            mid = 0.5 * (lo[0] + hi[0])
            t_sel = top & (x[:, 0] > mid), top & (x[:, 0] < mid)
            dz = (x[:, 2] - x0[:, 2]) / d
            character.append({"t": row["t"], **_pair_correlations(x, v, d),
                              "slip_sd_dz_d": [float(dz[layer == j].std()) for j in range(layer.max() + 1)],
                              "mean_dz_d": [float(dz[layer == j].mean()) for j in range(layer.max() + 1)],
                              "horizontal_dx_d": float(np.linalg.norm(x[:, :2] - x0[:, :2], axis=1).mean() / d),
                              "block_energy_share": _block_energy_share(x, v, lo, 3.0 * d),
                              "com_velocity": [float(a) for a in v.mean(axis=0)],
                              "surface_tilt_x": float(x[t_sel[0], 2].mean() - x[t_sel[1], 2].mean())})
    cpu = time.process_time() - c0
    t = np.array([r["t"] for r in frames])
    mv = np.array([r["mean"] for r in frames])
    decay = []
    for a in np.arange(0.0, duration, 1.0):
        sel = (t > a) & (t <= a + 1.0) & (mv > 0.0)
        if sel.sum() > 3:
            slope = float(np.polyfit(t[sel], np.log(mv[sel]), 1)[0])
            decay.append({"from": float(a), "to": float(a + 1.0), "rate_per_s": -slope,
                          "tau_s": -1.0 / slope if slope < 0.0 else None})
    S = np.array(steps)
    late = S[S[:, 0] >= 0.5 * duration - 1e-9] if len(S) else S
    load = {"steps": int(len(late)), "mean": float(late[:, 1].mean()),
            "step_to_step": float(np.abs(np.diff(late[:, 1])).mean()) if len(late) > 1 else 0.0,
            "iterations": sorted({int(k) for k in late[:, 2]})} if len(late) else {}
    counts = {g: int(sel.sum()) for g, sel in groups.items()}
    counts["top_layer"] = int(top.sum())
    return {"solver": solver, "radius": radius, "duration": duration, "overrides": extra, "cpu_s": cpu,
            "fluid_particles": int(m.fluid_count), "counts": counts,
            "slosh_period": 2.0 * np.pi / np.sqrt(G * k * np.tanh(k * depth)),
            "lattice_slip_stiffness": lattice_slip_stiffness(m.smoothing.name, float(m.smoothing_length), d),
            "decay": decay, "load_second_half": load, "frames": frames, "character": character}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--solver", default="dfsph")
    ap.add_argument("--radius", type=float, default=0.025, help="particle radius [m] (the case's: 0.025, 0.0125)")
    ap.add_argument("--duration", type=float, default=2.0, help="simulated seconds")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="scene override (repeatable)")
    ap.add_argument("--motion", action="store_true", help="what moves (issue #31): speeds per layer, wall ring, "
                    "corners and interior per frame, the field's correlations, the sloshing tilt, the decay rate")
    ap.add_argument("--every", type=int, default=3, help="--motion: frames between the field's character samples")
    ap.add_argument("--stagger", type=float, default=0.0, help="--motion: raise every other column by this many d "
                    "before the first step (an experiment: 0.5 starts the bulk on the packing the slip heads for)")
    ap.add_argument("--case", default="hydrostatic", choices=["hydrostatic", "hydrostatic_fcc"],
                    help="the bench's hydrostatic case (hydrostatic_fcc: the fcc start in its fitted tank)")
    a = ap.parse_args(argv)
    if a.motion:
        print(json.dumps(motion(a.solver, a.radius, a.duration, a.set, a.every, a.stagger, a.case)))
        return
    print(json.dumps(profile(a.solver, a.radius, a.duration, a.set, a.case), indent=1))


if __name__ == "__main__":
    main()
