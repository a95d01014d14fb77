"""Surface reconstruction speed (``warp-sph bench surface``): field + extraction + host clean-up per
frame, on dam-break particles at a given time, for cell sizes and extraction methods.

Reference (issue text, measured on this machine kind): splashsurf at cube size 0.5 r takes 81 ms
(1 thread) / 43 ms (2 threads) for 6,859 particles and 592 / 310 ms for 59,319.
"""
from __future__ import annotations

import time

import numpy as np

SPLASHSURF_MS = {6859: (81.0, 43.0), 59319: (592.0, 310.0)}


def particles_at(radius: float, t: float, device=None):
    """Dam-break particles (local positions, densities as wp arrays) and the Simulation at time t [s]."""
    from warp_sph.scene import load_scene
    from warp_sph.run.simulation import Simulation

    scene = load_scene("dam_break", [f"particle_radius={radius}", "output.usd=false", "output.surface=false"])
    sim = Simulation(scene, device=device)
    while sim.state.time < t - 1e-9:
        sim.advance_frame()
    return sim


def time_surface(sim, cell_per_radius: float, method: str, repeats: int = 3) -> dict:
    """Median wall time [ms] of SurfaceReconstructor.extract and the mesh size."""
    import warp as wp

    from warp_sph.surface import SurfaceReconstructor

    m = sim.model
    rec = SurfaceReconstructor(m.smoothing.name, m.smoothing_length, m.particle_mass, m.particle_radius,
                               cell_size=cell_per_radius * m.particle_radius, iso_level=0.5,
                               device=sim.device, method=method)
    x, rho = sim.fields["particle_x"], sim.fields["particle_density"]
    rec.extract(x, rho)  # compile and warm up
    times = []
    for _ in range(repeats):
        wp.synchronize_device(sim.device)
        t0 = time.perf_counter()
        verts, tris = rec.extract(x, rho)
        wp.synchronize_device(sim.device)
        times.append(1e3 * (time.perf_counter() - t0))
    return {"ms": float(np.median(times)), "ms_all": times, "vertices": int(len(verts)), "triangles": int(len(tris))}


def run_surface_bench(radii=(0.025,), times=(0.3,), cells=(0.5, 0.75), methods=("marching_cubes", "surface_nets"),
                      device=None, log=print) -> list[dict]:
    records = []
    for radius, t in zip(radii, times):
        sim = particles_at(radius, t, device=device)
        n = sim.model.fluid_count
        for cell in cells:
            for method in methods:
                r = time_surface(sim, cell, method)
                ref = SPLASHSURF_MS.get(n)
                rec = {"kind": "surface", "status": "ok", "particle_radius": radius, "time": t, "fluid_particles": n,
                       "cell_per_radius": cell, "method": method, "device": str(sim.device), **r,
                       "splashsurf_ms_1_thread": ref[0] if ref else None, "splashsurf_ms_2_threads": ref[1] if ref else None}
                log(f"surface r={radius} t={t} N={n} cell={cell}r {method}: {r['ms']:.1f} ms, {r['triangles']} triangles")
                records.append(rec)
    return records
