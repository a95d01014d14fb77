"""DFSPH sweeps per step against depth, plain Jacobi beside Chebyshev weights (issue #32).

    python -m warp_sph.benchmarks.dfsph_sweeps [--radii 0.025:1.0,0.0125:0.125] [--chebyshev 0,0.8] [--set K=V] [--out FILE]

The default dam break (its own adaptive step) at each particle radius [m] for the given simulated
seconds, once per ``dfsph.chebyshev`` value (0: plain Jacobi), the cases of one radius run one after the
other in this process. Reported per case: fluid particles, steps, density and divergence sweeps per
step, the mean density error of the solves [%] and the process CPU time per step [ms], the fluid's
layers and the estimate the solver used (0 below ``dfsph.chebyshev_min_layers``) (wrap the run in
``flock /tmp/warp_sph_bench.lock`` on a shared machine; sweeps and errors do not depend on the load).
Writes one JSON line per case (to --out, default benchmarks/results/dfsph_sweeps.jsonl).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from .records import print_profile_record


def measure(radius: float, seconds: float, chebyshev: float, overrides=()) -> dict:
    """One run of the dam break (module docstring)."""
    from warp_sph.run.simulation import Simulation
    from warp_sph.scene import load_scene

    sc = load_scene("dam_break", ["solver=dfsph", f"particle_radius={radius}", f"dfsph.chebyshev={chebyshev}",
                                  "output.usd=false", "output.surface=false", *overrides])
    sim = Simulation(sc)
    steps = sweeps = div_sweeps = error = 0.0
    cpu0 = time.process_time()
    while sim.state.time < seconds - 1e-9:
        st = sim.advance_frame()
        if st.outside or st.non_finite:
            raise RuntimeError(f"r = {radius}, chebyshev = {chebyshev}: {st.outside} outside, {st.non_finite} non-finite")
        s = st.solver
        steps += st.steps
        sweeps += s["iterations"]["mean"] * st.steps
        div_sweeps += s["divergence_iterations"]["mean"] * st.steps
        error += s["density_error"]["mean"] * st.steps
    cpu = time.process_time() - cpu0
    return {"particle_radius": radius, "particles": sim.model.fluid_count, "seconds": seconds, "chebyshev": chebyshev,
            # what the solver used: plain Jacobi (0) for fluid shallower than dfsph.chebyshev_min_layers
            "fluid_layers": sim.solver.fluid_layers, "chebyshev_used": sim.solver.chebyshev,
            "steps": int(steps), "density_sweeps_per_step": sweeps / steps, "divergence_sweeps_per_step": div_sweeps / steps,
            "density_error_percent": 100.0 * error / steps, "cpu_ms_per_step": 1000.0 * cpu / steps,
            "overrides": list(overrides)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--radii", default="0.025:1.0,0.0125:0.125", help="radius [m]:simulated seconds, comma-separated")
    ap.add_argument("--chebyshev", default="0,0.8", help="dfsph.chebyshev values, comma-separated (0: plain Jacobi)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="scene override (repeatable)")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "dfsph_sweeps.jsonl"))
    a = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    for item in a.radii.split(","):
        radius, seconds = (float(v) for v in item.split(":"))
        for rho in (float(v) for v in a.chebyshev.split(",")):
            print_profile_record(measure(radius, seconds, rho, a.set), a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
