"""The edge sheet of a liquid block hitting the floor (issue #36 finding 3; docs/stability.md "Impacts").

    python -m warp_sph.benchmarks.impact_edge [--radius 0.05] [--solver dfsph] [--speed 14] [--out FILE]

A 1 m cube starts one particle diameter above the floor of a 5 m x 5 m box with the velocity -V
(V = 14 m/s is a drop from 10 m) and runs 0.05 s at the solver's own adaptive step (gravity on), before
the sheet reaches the side walls. Reported: the fastest particle over V and the 99.9th percentile of the
speeds over V, each the largest over the run, and the particle count. Incompressible pressure-impulse
theory puts a logarithmic singularity of the velocity at the line where the free surface meets the
wall (Cooker & Peregrine 1995; Philippi, Antkowiak & Lagree 2018), so the fastest particles are set by
the spacing and grow as it is refined. Writes one JSON line (to --out, default
benchmarks/results/impact_edge.jsonl).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from .records import print_profile_record

#: the simulated time [s]: the sheet at about 2.5 V reaches the side walls (2 m away) after about 0.06 s
DURATION = 0.05


def impact_scene(radius: float, solver: str, speed: float):
    """The 1 m cube at -speed [m/s] just above the floor of a 5 m x 5 m x 3 m box, particle radius [m]."""
    from warp_sph.scene import scene_from_dict

    return scene_from_dict({
        "name": "impact_edge", "particle_radius": radius, "solver": solver, "gravity": [0.0, 0.0, -9.81],
        "container": {"min": [-2.5, -2.5, 0.0], "max": [2.5, 2.5, 3.0]},
        "fluid": [{"min": [-0.5, -0.5, 2 * radius], "max": [0.5, 0.5, 1.0 + 2 * radius],
                   "velocity": [0.0, 0.0, -speed]}],
        "output": {"usd": False, "surface": False}})


def measure(radius: float = 0.05, solver: str = "dfsph", speed: float = 14.0, duration: float = DURATION) -> dict:
    """One run (module docstring)."""
    from warp_sph.run.simulation import Simulation

    sim = Simulation(impact_scene(radius, solver, speed))
    t, steps, fastest, p999 = 0.0, 0, 0.0, 0.0
    cpu0 = time.process_time()
    while t < duration:
        dt = sim.time_step(sim.current_speed())
        sim.step(dt)
        t += dt
        steps += 1
        s = np.linalg.norm(sim.get_field("particle_v").astype(np.float64), axis=1)
        fastest, p999 = max(fastest, float(s.max())), max(p999, float(np.percentile(s, 99.9)))
    return {"solver": solver, "particle_radius": radius, "particles": sim.model.fluid_count, "speed": speed,
            "time": t, "steps": steps, "fastest_over_speed": fastest / speed, "p999_over_speed": p999 / speed,
            "cpu_s": time.process_time() - cpu0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--radius", type=float, default=0.05, help="particle radius [m]")
    ap.add_argument("--solver", default="dfsph")
    ap.add_argument("--speed", type=float, default=14.0, help="impact speed V [m/s]")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "impact_edge.jsonl"))
    a = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    print_profile_record(measure(a.radius, a.solver, a.speed), a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
