"""One calibration run of ``warp-sph plan`` and the figures read from its run.json (``Point``).

A point is an ordinary run (``warp_sph.run.runner.run``, the scene's own outputs) of the scene with one solver at one
particle radius and tolerance, into a folder that is removed afterwards (``run_point``). From run.json come the
particle counts, the steps, the steady time per step, the time outside the steps, the density errors, the solver's
sweeps per step (``solver_sweeps``) and the share of the steady step time its sweeps take (``solve_share``): the step's
cost as a per-step part plus a per-sweep part times the sweeps (``models.SolverModel.sweep_factor``).
"""
from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path

from ..core.errors import WarpSphError

#: the stages whose work repeats with each solver sweep (the solvers' stage names: DFSPH's density solve "pressure"
#: and its divergence solve "divergence", PBF's constraint iterations "solve"); their steady time over the step's is
#: ``Point.solve_share``. Measured (hydrostatic DFSPH, 4 frames, load 3-6): 0.37, 0.42 and 0.38 of the step at 648,
#: 7,497 and 22,500 fluid particles
SOLVE_STAGES = ("pressure", "divergence", "solve")

@dataclass
class Point:
    """One calibration run: the scene with ``solver`` at ``particle_radius`` [m] for ``frames`` frames."""

    solver: str
    particle_radius: float
    tolerance: float | None = None      # the solver's density tolerance in this run (None: it has none)
    status: str = "completed"           # "completed" or "failed"
    error: str = ""                     # the one-line reason of a failed run
    fluid: int = 0
    boundary: int = 0
    estimated_fluid: int = 0            # the geometric estimate at this radius (``memory.estimate_particle_counts``)
    estimated_boundary: int = 0
    frames: int = 0                     # frames advanced (the initial one not counted)
    steps: int = 0
    simulated_time: float = 0.0         # [s]
    wall_time: float = 0.0              # [s] of run.json
    step_time: float = 0.0              # [s] steady wall time of one substep (first call excluded)
    export_wait: float = 0.0            # [s] the simulation thread spent on exports
    first_step_time: float = 0.0        # [s] the first step's stages, kernel loads included
    density_error_mean: float = 0.0     # [-] mean over the advanced frames of the frame's mean error
    density_error_max: float = 0.0      # [-] largest of any frame
    density_error_last: float = 0.0     # [-] the last frame's mean error
    density_errors: list = field(default_factory=list)  # [-] each advanced frame's mean error, in order
    frame_steps: list = field(default_factory=list)     # substeps of each advanced frame, in order
    frame_speeds: list = field(default_factory=list)    # [m/s] fastest particle (fluid or body) at each frame's end, initial first
    frame_cpu: list = field(default_factory=list)       # [s] process CPU time of each advanced frame (run.json ``frame_times``)
    sweeps: float = 0.0                 # solver sweeps per step: pressure + divergence iterations, mean over the steps (0: none)
    solve_share: float = 0.0            # [-] the sweeps' stages' share of the steady step time (``solve_share``)
    first_in_process: bool = False      # the process's first calibration run: its set-up loaded the shared kernels
    array_bytes: int = 0                # [bytes] what its steps read of its Warp arrays (run.json ``read_bytes``, else
    #                                     ``array_bytes`` for older runs; 0: not recorded)
    reference: dict = field(default_factory=dict)  # metric -> error against the experiment (None: not measurable)
    seconds: float = 0.0                # wall time the calibration run took, start-up included [s]

    @property
    def spacing(self) -> float:
        """Lattice spacing d = 2 r [m]."""
        return 2.0 * self.particle_radius

    @property
    def particles(self) -> int:
        """Fluid and boundary particles."""
        return self.fluid + self.boundary

    @property
    def steps_per_second(self) -> float:
        """Substeps per simulated second."""
        return self.steps / self.simulated_time if self.simulated_time > 0 else math.nan

    @property
    def load_time(self) -> float:
        """[s] the first step took beyond a steady one: loading (or compiling) the step's kernels."""
        return max(self.first_step_time - self.step_time, 0.0)

    @property
    def setup_time(self) -> float:
        """[s] of the run outside its steps, its per-frame exports and its kernel loads: sampling, model, files."""
        return max(self.wall_time - self.steps * self.step_time - self.export_wait - self.load_time, 0.0)

    @property
    def frame_overhead(self) -> float:
        """[s] per frame the simulation waited on exports."""
        return self.export_wait / self.frames if self.frames else 0.0




def run_point(scene, solver: str, radius: float, frames: int, device, folder: Path,
              tolerance: float | None = None) -> Point:
    """One calibration run into ``folder`` (removed afterwards); a run that fails gives a failed Point."""
    from ..run import runner
    from ..run.memory import estimate_particle_counts
    from .variants import scene_tolerance, variant
    from .metrics import evaluate_reference

    point = Point(solver=solver, particle_radius=radius,
                  tolerance=tolerance if tolerance is not None else scene_tolerance(scene, solver))
    try:
        s = variant(scene, solver, radius, tolerance)
        point.estimated_fluid, point.estimated_boundary = estimate_particle_counts(s)
        info = runner.run(s, out=folder, device=device, frames=frames, progress=False, log=lambda *a, **k: None)
        point.reference = evaluate_reference(s, folder, info)
    except WarpSphError as exc:
        point.status, point.error = "failed", str(exc).splitlines()[0]
        return point
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    advanced = [f for f in info["frames"] if f["frame"] > 1]
    point.fluid, point.boundary = int(info["fluid_particles"]), int(info["boundary_particles"])
    point.frames = len(advanced)
    point.steps = int(info["steps"])
    point.simulated_time = float(info["simulated_time"])
    point.wall_time = float(info["wall_time"])
    point.step_time = steady_step_time(info)
    # what its steps read (used pair and list entries), else the allocation (runs recorded before read_bytes)
    point.array_bytes = int(info.get("read_bytes", info.get("array_bytes", 0)))
    point.export_wait = float(info.get("export_wait_time", 0.0))
    point.first_step_time = float(info.get("first_step_time", 0.0))
    point.density_error_mean = sum(f["density_error_mean"] for f in advanced) / max(len(advanced), 1)
    point.density_error_max = max((f["density_error_max"] for f in advanced), default=0.0)
    point.density_error_last = advanced[-1]["density_error_mean"] if advanced else 0.0
    point.density_errors = [float(f["density_error_mean"]) for f in advanced]
    point.frame_steps = [int(f["steps"]) for f in advanced]
    point.sweeps = solver_sweeps(advanced)
    point.solve_share = solve_share(info.get("stage_times") or [])
    point.frame_speeds = [max(float(f.get("max_speed", 0.0)), float(f.get("body_speed", 0.0))) for f in info["frames"]]
    point.frame_cpu = [float(t.get("cpu_time", 0.0)) for t in info.get("frame_times") or []]
    return point


def cpu_per_step(steps, cpu) -> float | None:
    """[s] process CPU time per step over frames 2.. of per-frame ``steps`` and ``cpu`` [s] (the first frame loads the
    kernels); None without them."""
    if len(cpu) != len(steps) or len(cpu) < 2 or sum(steps[1:]) <= 0:
        return None
    return float(sum(cpu[1:]) / sum(steps[1:]))


def cpu_per_wall(point: Point) -> float | None:
    """[-] the process CPU seconds a point's frames took per wall second of its steps' stages (steps x steady step
    time + the first step's kernel loads): the cores the run got, about 1.9 on 2 quiet cores, under 1 on a loaded
    machine (a timing point's one frame too); None where its frames' CPU time was not recorded."""
    wall = point.steps * point.step_time + point.load_time
    return float(sum(point.frame_cpu) / wall) if point.frame_cpu and wall > 0 else None


def course_ratio(point: Point, window: int) -> tuple:
    """(C, the window's CPU seconds): one whole run's process CPU time per step over its advanced frames 2..F over that
    over frames 2..``window`` (the calibration window's), its first advanced frame left out (it loads the kernels):
    the course of the step's cost over the run, from one process and one set of particles (no cross-run noise). (None,
    0) where the run did not record ``frame_cpu`` or has no frame beyond the window."""
    cpu, steps = point.frame_cpu, point.frame_steps
    if len(cpu) != len(steps) or len(cpu) <= window or window < 2 or min(cpu[1:], default=0.0) <= 0:
        return None, 0.0
    first = sum(cpu[1:window]) / max(sum(steps[1:window]), 1)
    whole = sum(cpu[1:]) / max(sum(steps[1:]), 1)
    return (float(whole / first), float(sum(cpu[1:window]))) if first > 0 else (None, 0.0)


def steady_step_time(info: dict) -> float:
    """[s] the steady wall time of one step of a run (run.json ``info``): the median over its advanced frames of each
    frame's steps' stage time per step (``frame_times``; in the frame that holds the process's first step, its kernel
    loads, ``first_step_time``, and that step left out), robust to a load spike that slows one frame; without
    ``frame_times`` (a run.json from before they were kept) the mean over the steps, ``sim_time_per_step_ms``."""
    per_frame, first = [], float(info.get("first_step_time", 0.0))
    for t in info.get("frame_times") or []:
        steps, seconds = int(t["steps"]), float(t["step_seconds"])
        if t.get("first_step"):  # the first step loads the kernels
            steps, seconds = steps - 1, seconds - first
        if steps > 0 and seconds > 0:
            per_frame.append(seconds / steps)
    if not per_frame:
        return float(info["sim_time_per_step_ms"]) * 1e-3
    per_frame.sort()
    m = len(per_frame) // 2
    return per_frame[m] if len(per_frame) % 2 else 0.5 * (per_frame[m - 1] + per_frame[m])


def slowed_points(pts, split: int) -> list:
    """[(p, q)]: on a CPU (``split`` > 0 particles, the thread split), each point p whose steady step took longer than
    that of a point q on the same side of the split with at least as many fluid and wall particles (and more of one):
    a larger count cannot cost less per step, and the machine's load only adds time, so q's is the nearer to what p's
    step costs and p's was slowed (left out of the step's cost, the plan's notes name it). Not across the split (one
    thread against two: a count just above it may step as fast as one below) and not on a GPU (its step is launch
    overhead up to many thousand particles: equal costs, noise either way). Measured (hydrostatic DFSPH, load 10.8):
    648 / 1,440 / 2,352 fluid particles at 23.7 / 25.3 / 5.84 us per fluid particle-step, 15.4 / 36.4 / 13.7 ms per step
    (quiet, load 1.5-3.3: 4.58 and 4.22 us at 648 and 2,156 fluid)."""
    if not split:
        return []
    out = []
    for p in pts:
        side = p.particles >= split
        by = [q for q in pts if (q.particles >= split) == side and q.fluid >= p.fluid and q.boundary >= p.boundary
              and (q.fluid, q.boundary) != (p.fluid, p.boundary) and q.step_time < p.step_time]
        if by:
            out.append((p, min(by, key=lambda q: q.step_time)))
    return out


def solver_sweeps(frames) -> float:
    """Solver sweeps per step over run.json ``frames``: each frame's mean pressure (``iterations``) and divergence
    iterations, weighted by its steps (0 for a solver that reports none, WCSPH)."""
    steps = sweeps = 0.0
    for f in frames:
        solver = f.get("solver") or {}
        n = float(f.get("steps", 0))
        steps += n
        sweeps += n * sum(float((solver.get(k) or {}).get("mean", 0.0)) for k in ("iterations", "divergence_iterations"))
    return sweeps / steps if steps > 0 else 0.0


def solve_share(stage_times) -> float:
    """[-] the share of the steady stage time (each stage's seconds less its first call's, which loads the kernels) that
    the SOLVE_STAGES took, over run.json's ``stage_times`` (0 where none ran or nothing was timed)."""
    steady = {s["stage"]: max(float(s.get("seconds", 0.0)) - float(s.get("first_call_seconds", 0.0)), 0.0)
              for s in stage_times}
    total = sum(steady.values())
    return sum(v for k, v in steady.items() if k in SOLVE_STAGES) / total if total > 0 else 0.0


def sweep_bounds(scene, solver: str) -> tuple[float, float]:
    """(fewest, most) solver sweeps per step the scene allows ``solver``: its ``min_iterations`` / ``max_iterations``
    plus, where it has a divergence solve that is on, ``divergence_min_iterations`` / ``divergence_max_iterations``
    (the registry's keys, the scene's values; (0, 0) for a solver without them, WCSPH: a most of 0 is no cap, and the
    figures stay JSON numbers)."""
    from ..methods.registry import solver as solver_class

    default = {p.path.split(".", 1)[1]: p.default for p in solver_class(solver).parameters
               if p.path.startswith(solver + ".")}
    own = scene.to_dict().get(solver, {}) if scene is not None else {}

    def value(key):
        return own.get(key, default.get(key))

    pairs = [("min_iterations", "max_iterations")]
    if value("divergence_solve") is not False:
        pairs.append(("divergence_min_iterations", "divergence_max_iterations"))
    lo = sum(float(value(a)) for a, b in pairs if a in default and b in default)
    hi = sum(float(value(b)) for a, b in pairs if a in default and b in default)
    return float(lo), float(hi)
