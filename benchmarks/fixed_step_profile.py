"""Where a fixed step of WCSPH and PBF goes on the CPU (issue #32): per stage, per kernel, list rebuilds.

    python -m benchmarks.fixed_step_profile                         # both, dam break r = 0.025 m, 1 thread
    python -m benchmarks.fixed_step_profile --solvers wcsph --start 0.5 --frames 4 --set wcsph.search_skin=0.3

The dam break of ``warp-sph bench splishsplash`` (the same fixed steps: WCSPH at the CFL-0.4 bound of the
scene's c_s, ``benchmarks.splishsplash.default_dt``; PBF at 2 ms, both a whole number per frame;
``wcsph.speed_of_sound_factor=11`` as the bench's goal command) runs to ``--start`` seconds (the splash),
then ``--frames`` frames are measured twice:
- stages: each stage of the step graph timed in process CPU time (``time.process_time``: run it with
  ``--threads 1``, so that it is the CPU of that stage alone); WCSPH's "neighbors" and "density" stages
  split by whether the step searched (``wcsph.search_skin``: a search step, a kept-lists step); the
  per-frame work outside the steps ("frame": sort into cell order, PBF's density pass at x, the watchdog);
- kernels: each kernel run timed on its thread (``dfsph_step_profile._instrumented``), per step;
and the solver's figures: WCSPH's searches per step and the drift that triggered them; PBF's iterations,
stabilisation iterations and density passes per step; both the fluid and boundary neighbours per particle
(the lists' counts). One JSON object on stdout; wrap it in ``flock /tmp/warp_sph_bench.lock``.
"""
from __future__ import annotations

import argparse
import collections
import json
import math
import os
import sys
import time

SOLVERS = ("wcsph", "pbf")
#: the bench's warp-sph-only overrides of the goal command (``warp-sph bench splishsplash --warp-sph-set``)
GOAL_SET = ("wcsph.speed_of_sound_factor=11",)


def fixed_dt(solver: str, radius: float) -> float:
    """The bench's fixed step [s] (``splishsplash.run_comparison``): the default step rounded down to a whole
    number per frame, from the scene without the warp-sph-only overrides."""
    import warp as wp

    from warp_sph.core.model import build_model
    from warp_sph.scene import load_scene
    from warp_sph.scene.sampling import sample_scene

    from .splishsplash import default_dt

    sc = load_scene("dam_break", overrides=[f"particle_radius={radius}"])
    model, _ = build_model(sc, sample_scene(sc), wp.get_device("cpu"))
    target = default_dt(model.summary(), solver, radius)
    frame_dt = 1.0 / float(sc.fps)
    return frame_dt / math.ceil(frame_dt / target - 1e-9)


def simulation(solver: str, radius: float, dt: float, overrides=()):
    from warp_sph.run.simulation import Simulation
    from warp_sph.scene import load_scene

    own = [o for o in overrides if o.split("=", 1)[0].split(".", 1)[0] not in set(SOLVERS) - {solver}]
    sc = load_scene("dam_break", overrides=[f"particle_radius={radius}", f"solver={solver}", f"time.fixed_dt={dt}",
                                            "output.usd=false", "output.surface=false", *own])
    return Simulation(sc)


class StageClock:
    """Process CPU time per stage (``StepGraph.run`` replaced on one simulation), WCSPH's neighbour stages split
    by whether the step searched; ``outside``: the CPU of the frames minus that of the stages."""

    def __init__(self, sim):
        self.sim = sim
        self.cpu = collections.defaultdict(float)
        self.calls = collections.defaultdict(int)
        self.steps = 0
        graph = sim.graph
        self._plain = graph.run

        def run(sim_, dt):
            kept = getattr(sim_.solver, "kept_lists", None)
            self.steps += 1
            for s in graph.stages:
                c = time.process_time()
                s.run(sim_, dt)
                c = time.process_time() - c
                name = s.name
                if kept is not None and name in ("neighbors", "density"):
                    name += " (search)" if kept._search else " (kept lists)"
                self.cpu[name] += c
                self.calls[name] += 1

        graph.run = run

    def restore(self) -> None:
        self.sim.graph.run = self._plain

    def table(self, frames_cpu: float) -> dict:
        n = max(self.steps, 1)
        staged = sum(self.cpu.values())
        out = {name: {"calls_per_step": self.calls[name] / n, "cpu_ms_per_step": 1e3 * c / n,
                      "cpu_ms_per_call": 1e3 * c / max(self.calls[name], 1), "share": c / frames_cpu}
               for name, c in self.cpu.items()}
        out["outside the steps"] = {"cpu_ms_per_step": 1e3 * (frames_cpu - staged) / n,
                                    "share": (frames_cpu - staged) / frames_cpu}
        return out


def _list_counts(sim) -> dict:
    """Mean fluid and boundary neighbours per fluid particle in the current lists (within the search radius)."""
    import numpy as np

    nl = getattr(sim.solver, "nl", None) or getattr(getattr(sim.solver, "kept_lists", None), "nl", None)
    if nl is None:
        return {}
    n = sim.model.fluid_count
    out = {"search_radius": nl.search_radius}
    for name, lst in (("fluid", nl.fluid), ("boundary", nl.boundary)):
        count = getattr(lst, "count", None)
        if count is not None:
            out[f"{name}_per_particle"] = float(np.asarray(count.numpy()[:n], dtype=np.float64).mean())
    return out


def profile_solver(solver: str, radius: float, start: float, frames: int, overrides=(), kernels: bool = True) -> dict:
    from .dfsph_step_profile import _frames, _instrumented

    dt = fixed_dt(solver, radius)
    sim = simulation(solver, radius, dt, overrides)
    while sim.state.time < start - 1e-9:
        sim.advance_frame()
    s = sim.solver
    kept = getattr(s, "kept_lists", None)
    before = (kept.builds, kept.steps) if kept is not None else None
    its = collections.Counter()
    stab = collections.Counter()
    passes = [0]
    plain_pass = getattr(s, "density_pass", None)
    if solver == "pbf":
        def counted_pass(*a, **kw):
            passes[0] += 1
            return plain_pass(*a, **kw)
        s.density_pass = counted_pass
        plain_solve = s.run_solve

        def counted_solve(sim_, dt_):
            plain_solve(sim_, dt_)
            its[s.last_iterations] += 1
            stab[s.last_stabilization] += 1
        # the graph holds the bound method: replace it in the stage
        for st in sim.graph.stages:
            if st.name == "solve":
                st.run = counted_solve
    clock = StageClock(sim)
    c0, t0 = time.process_time(), time.perf_counter()
    steps = _frames(sim, frames)
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    clock.restore()
    out = {"solver": solver, "dt": dt, "overrides": list(overrides), "fluid": sim.model.fluid_count,
           "boundary": sim.model.boundary_count, "start_time": start, "frames": frames, "steps": steps,
           "cpu_ms_per_step": 1e3 * cpu / steps, "wall_ms_per_step": 1e3 * wall / steps,
           "stages": clock.table(cpu), "lists": _list_counts(sim)}
    if kept is not None:
        builds, kept_steps = kept.builds - before[0], kept.steps - before[1]
        out["searches_per_step"] = builds / max(kept_steps, 1)
        out["skin_d"] = kept.skin / sim.model.spacing
    if solver == "pbf":
        out["iterations"] = dict(sorted(its.items()))
        out["stabilization_iterations"] = dict(sorted(stab.items()))
        out["density_passes_per_step"] = passes[0] / steps  # besides the fused one of the "density" stage
        out["statistics_last"] = s.step_statistics()
    if kernels:
        out["kernels"] = _instrumented(sim, frames)
    return out


def profile(solvers=SOLVERS, radius: float = 0.025, start: float = 0.3, frames: int = 3, overrides=GOAL_SET) -> dict:
    from warp_sph.core.launch import cpu_threads

    out = {"radius": radius, "cpu_threads": cpu_threads(), "load_before": os.getloadavg(), "solvers": {}}
    for solver in solvers:
        out["solvers"][solver] = profile_solver(solver, radius, start, frames, overrides)
    out["load_after"] = os.getloadavg()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--solvers", default=",".join(SOLVERS), help="comma-separated: wcsph, pbf (default both)")
    ap.add_argument("--radius", type=float, default=0.025, help="particle radius [m] (default 0.025: 6,859 particles)")
    ap.add_argument("--start", type=float, default=0.3, help="simulated seconds run before measuring (default 0.3)")
    ap.add_argument("--frames", type=int, default=3, help="frames measured (default 3)")
    ap.add_argument("--set", action="append", default=None, metavar="KEY=VALUE",
                    help="scene override (repeatable; wcsph.* / pbf.* keys only for that solver; default: "
                         + " ".join(GOAL_SET) + ")")
    ap.add_argument("--threads", type=int, default=1, help="WARP_SPH_CPU_THREADS (default 1)")
    a = ap.parse_args(argv)
    os.environ["WARP_SPH_CPU_THREADS"] = str(a.threads)
    solvers = [s for s in a.solvers.split(",") if s]
    for s in solvers:
        if s not in SOLVERS:
            ap.error(f"--solvers: {s!r} is not one of {', '.join(SOLVERS)}")
    overrides = tuple(a.set) if a.set is not None else GOAL_SET
    out = {"command": " ".join(["python -m benchmarks.fixed_step_profile", *(argv if argv is not None else sys.argv[1:])])}
    out.update(profile(solvers, a.radius, a.start, a.frames, overrides))
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
