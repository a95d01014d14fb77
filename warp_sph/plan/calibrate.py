"""Calibration runs of ``warp-sph plan``: the user's own scene, a fraction of a second, at coarse radii.

Each calibration point is an ordinary run (``warp_sph.run.runner.run``, the scene's own outputs: USD,
surface, checkpoints) of the scene with one candidate solver and one coarse particle radius, into a
temporary folder under the cache directory that is removed afterwards. From its run.json come the
figures the models are fitted to (``fit.py``): particle counts, substeps per simulated second, the
steady wall time per step, the wall time outside the steps (set-up, statistics, exports), the mean
density error (over the run's frames and of its last frame) and, for a validation scene, the errors
against the experiment (``metrics.py``). A solver with a density tolerance (``tolerance_key``) is run at
the scene's tolerance and, at one radius, at TOLERANCE_STEP times tighter.

The points are cached per scene content, machine and calibration settings (``cache_key``) as one JSON
file in the cache directory: ``$WARP_SPH_CACHE_DIR``, else ``$XDG_CACHE_HOME/warp-sph/plan``, else
``~/.cache/warp-sph/plan``. A second plan of the same scene on the same machine runs nothing.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..core.device import cpu_model
from ..core.errors import PlanError  # noqa: F401 (plan's error, re-exported)
from .fit import step_floor
from .points import Point, run_point, solver_sweeps  # noqa: F401 (re-exported)
from .variants import scene_tolerance, tolerance_key, variant, variant_dict  # noqa: F401 (re-exported)

#: simulated time of a calibration run [s] (rounded up to whole frames, at least two frames)
CALIBRATION_TIME = 0.1
#: fluid particle counts the calibration radii are chosen for (from the scene's geometry)
CALIBRATION_COUNTS = (300, 1000)
#: the coarsest radius keeps at least this many particle layers across the thinnest fluid block
MIN_LAYERS = 3
#: the keys a plan changes: left out of the scene's content hash
PLANNED_KEYS = ("particle_radius", "solver", "plan", "name", "description")
#: the second calibrated tolerance of a solver with one: the scene's divided by this
TOLERANCE_STEP = 4.0
#: the version of the cached points' fields (older cache files are not read)
CACHE_SCHEMA = 4
#: calibration runs made by this process so far (the first one's set-up includes loading the shared kernels)
_RUNS_IN_PROCESS = [0]


@dataclass
class Calibration:
    """The calibration points of one scene on one machine, and where they are cached."""

    key: str
    machine: str
    points: list = field(default_factory=list)
    seconds: float = 0.0                # wall time the calibration took when it ran [s]
    cached: bool = False                # loaded from the cache (nothing ran)
    path: str = ""                      # the cache file
    step_floor: float = 0.0             # [1/s] fewest substeps per simulated second (``fit.step_floor``)
    step_quantum: float = 0.0           # [1/s] the frame rate: frames are split into whole steps (0: unknown)
    split_particles: int = 0            # particles from which a CPU launch splits over the threads (0: never)
    cache_bytes: int = 0                # [bytes] the CPU's last-level cache (0: a GPU, or not listed)

    def for_solver(self, solver: str, tolerance: float | None | str = "any") -> list[Point]:
        """The completed points of ``solver`` (at ``tolerance`` only, unless "any")."""
        return [p for p in self.points if p.solver == solver and p.status == "completed"
                and (tolerance == "any" or _same_tolerance(p.tolerance, tolerance))]

    def failures(self) -> list[Point]:
        """The points whose run failed."""
        return [p for p in self.points if p.status != "completed"]


def cache_dir(path: str | Path | None = None) -> Path:
    """Where calibrations are cached: ``path``, ``$WARP_SPH_CACHE_DIR``, ``$XDG_CACHE_HOME/warp-sph/plan`` or
    ``~/.cache/warp-sph/plan``."""
    if path:
        return Path(path).expanduser()
    if os.environ.get("WARP_SPH_CACHE_DIR"):
        return Path(os.environ["WARP_SPH_CACHE_DIR"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "warp-sph" / "plan"


def machine_text(device) -> str:
    """The machine a timing holds for: host name, CPU model, cores, CPU threads of Warp, the device."""
    model = cpu_model()
    threads = os.environ.get("WARP_SPH_CPU_THREADS", "")
    return f"{platform.node()} | {model} | {os.cpu_count()} cores | threads {threads or 'all'} | {device}"


def scene_content(scene) -> dict:
    """The scene as a dict without the keys a plan chooses (radius, solver, the [plan] table, names)."""
    d = scene.to_dict()
    for k in PLANNED_KEYS:
        d.pop(k, None)
    return d


def cache_key(scene, device, frames) -> tuple[str, str]:
    """(sha256 hex, machine text) of a scene's calibrations: scene content, machine, frames, versions. The points
    of every solver and radius calibrated so far share the key (a later plan adds the points it lacks)."""
    from ..run.checkpoints import scene_hash
    from ..core.version import __version__

    import warp as wp

    machine = machine_text(device)
    text = json.dumps({"scene": scene_hash(scene_content(scene)), "machine": machine, "frames": frames,
                       "versions": [__version__, wp.config.version], "schema": CACHE_SCHEMA}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest(), machine


def cached_points(path: Path) -> list[Point]:
    """The points of a cache file ([] where there is none, or it is damaged or of another schema: calibrate again)."""
    if not path.is_file():
        return []
    try:
        return [Point(**p) for p in json.loads(path.read_text())["points"]]
    except (OSError, ValueError, KeyError, TypeError):
        return []


def is_cached(scene, solvers, radius: float, frames: int, cache, device) -> bool:
    """Whether every solver of ``solvers`` has a point of ``scene`` at ``radius`` [m] over ``frames`` frames in the
    cache (at the scene's tolerance): a calibration of them runs nothing."""
    key, _ = cache_key(scene, device, frames)
    pts = cached_points(cache_dir(cache) / f"calibration-{key[:20]}.json")
    return all(any(p.solver == s and _same_radius(p.particle_radius, radius)
                   and _same_tolerance(p.tolerance, scene_tolerance(scene, s)) for p in pts) for s in solvers)


def machine_floor(cache: str | Path | None, device) -> dict | None:
    """The least costs any cached calibration run measured on this machine (``machine_text``), over every scene's cache
    file in the cache directory: ``start`` [s], a fresh process's least time outside its steady steps (the process's
    first runs: set-up, shared and solver kernel loads; without one, any run's set-up), ``step`` [s] the least steady
    step and ``particle_step`` [s] the least cost per particle-step. None where nothing of this machine is cached (no
    honest floor without measuring)."""
    machine = machine_text(device)
    pts = []
    for path in sorted(cache_dir(cache).glob("calibration-*.json")):
        try:
            data = json.loads(path.read_text())
            if data.get("machine") == machine:
                pts += [Point(**p) for p in data["points"]]
        except (OSError, ValueError, KeyError, TypeError):
            continue  # a damaged or older file: not a measurement
    pts = [p for p in pts if p.status == "completed" and p.step_time > 0 and p.particles > 0]
    if not pts:
        return None
    first = [p.wall_time - p.steps * p.step_time - p.export_wait for p in pts if p.first_in_process]
    return {"start": max(min(first) if first else min(p.setup_time for p in pts), 0.0),
            "step": min(p.step_time for p in pts), "particle_step": min(p.step_time / p.particles for p in pts),
            "points": len(pts)}


def thinnest_fluid(scene) -> float:
    """The smallest extent [m] of any fluid block's bounding box."""
    ext = []
    for b in scene.fluid:
        lo, hi = b.bounds()
        ext.append(min(h - l for l, h in zip(lo, hi)))
    return min(ext)


def radius_for_count(scene, count: float) -> float:
    """The particle radius [m] at which the fluid blocks hold about ``count`` particles (from their volume)."""
    volume = sum(b.volume() / b.spacing_scale**3 for b in scene.fluid)
    return 0.5 * (volume / count) ** (1.0 / 3.0)


def coarsest_radius(scene) -> float:
    """The coarsest radius [m] a plan considers: MIN_LAYERS particle layers across the thinnest fluid block."""
    return thinnest_fluid(scene) / (2.0 * MIN_LAYERS)


def calibration_radii(scene, counts=CALIBRATION_COUNTS) -> list[float]:
    """The calibration radii [m]: one per count of ``counts``, none coarser than ``coarsest_radius``, distinct."""
    r_max = coarsest_radius(scene)
    radii = []
    for c in sorted(counts):
        r = float(f"{min(radius_for_count(scene, c), r_max):.4g}")
        if all(abs(r - q) > 1e-3 * q for q in radii):
            radii.append(r)
    return sorted(radii, reverse=True)  # coarse first


def calibration_frames(scene, seconds: float = CALIBRATION_TIME) -> int:
    """Frames of a calibration run including the initial one: ``seconds`` of simulated time, at least 2 advanced."""
    return max(2, math.ceil(seconds * scene.fps - 1e-9)) + 1


def _same_radius(a: float, b: float) -> bool:
    return abs(a - b) <= 1e-6 * max(a, b)


def _same_tolerance(a: float | None, b: float | None) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and _same_radius(a, b))


def calibrate(scene, solvers, device=None, radii=None, frames: int | None = None, cache: str | Path | None = None,
              refresh: bool = False, progress: bool = True, log=print, tolerance_factor: float = 1.0) -> Calibration:
    """Calibrate ``scene`` for every solver of ``solvers`` at ``radii`` (default ``calibration_radii``), each
    solver with a tolerance at the scene's tolerance times ``tolerance_factor`` (a solver without one: once at
    factor 1, not at all otherwise): the points the cache lacks are run, the others loaded (``refresh``: all run
    again). The Calibration holds every cached point of the scene (other solvers, radii and tolerances included).
    Raises PlanError when no run of these completes."""
    from ..core.device import resolve_device
    from ..io.atomic import atomic_write_json
    from ..run.progress import Progress

    dev = resolve_device(device)
    radii = list(radii) if radii else calibration_radii(scene)
    frames = frames or calibration_frames(scene)
    key, machine = cache_key(scene, dev, frames)
    folder = cache_dir(cache)
    path = folder / f"calibration-{key[:20]}.json"
    points = [] if refresh else cached_points(path)
    tol = {s: (None if t is None else t * tolerance_factor) for s in solvers
           for t in [scene_tolerance(scene, s)] if t is not None or tolerance_factor == 1.0}
    todo = [(s, r) for s in tol for r in radii
            if not any(p.solver == s and _same_radius(p.particle_radius, r) and _same_tolerance(p.tolerance, tol[s])
                       for p in points)]
    if todo:
        folder.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix="calibration-", dir=folder))
        log(f"calibrating {scene.name}: {len(todo)} run{'s' if len(todo) != 1 else ''} ({', '.join(sorted({s for s, _ in todo}))} at "
            f"{', '.join(f'{r:.4g}' for r in sorted({r for _, r in todo}, reverse=True))} m), {frames - 1} frames each "
            f"({(frames - 1) / scene.fps:.3g} s simulated)"
            + (f", tolerance {tolerance_factor:g} x the scene's" if tolerance_factor != 1.0 else ""))
        bar = Progress(len(todo), enabled=progress, unit="runs")
        try:
            for i, (solver, r) in enumerate(todo):
                t0 = time.perf_counter()
                point = run_point(scene, solver, r, frames, dev, work / f"{solver}-{i}", tol[solver])
                point.seconds = time.perf_counter() - t0
                point.first_in_process = _RUNS_IN_PROCESS[0] == 0
                _RUNS_IN_PROCESS[0] += 1
                points.append(point)
                bar.update(i + 1, f"{solver} r = {r:.4g} m: {point.status}")
        finally:
            bar.close()
            shutil.rmtree(work, ignore_errors=True)
        atomic_write_json(path, {"key": key, "machine": machine, "points": [asdict(p) for p in points]})
    asked = [p for p in points if p.solver in tol and _same_tolerance(p.tolerance, tol[p.solver])
             and any(_same_radius(p.particle_radius, r) for r in radii)]
    if not asked:
        raise PlanError(f"{scene.source}: none of {', '.join(solvers)} has a density tolerance to calibrate")
    if not any(p.status == "completed" for p in asked):
        first = asked[0]
        raise PlanError(f"{scene.source}: the scene cannot be calibrated: every calibration run failed; the first "
                        f"({first.solver}, particle_radius {first.particle_radius:g} m): {first.error}")
    ran = points[len(points) - len(todo):] if todo else []
    t = scene.time
    floor = step_floor(scene.fps, t.dt_max, t.fixed_dt)
    from ..run.working_set import last_level_cache_bytes

    return Calibration(key=key, machine=machine, points=points, step_floor=floor, split_particles=split_particles(dev),
                       step_quantum=float(scene.fps), seconds=sum(p.seconds for p in ran), cached=not todo, path=str(path),
                       cache_bytes=last_level_cache_bytes() if dev.is_cpu else 0)


def split_particles(device) -> int:
    """[particles] on a CPU, the count from which a launch splits over 2 threads (``core.launch``: ranges of at least
    MIN_RANGE indices); 0 on a GPU. The step's cost per particle differs either side of it and a plan's target lies
    above it: there the cost is fitted to the points above it alone (``models.SolverModel.step_time_split``).
    Measured (hydrostatic DFSPH, 4 frames, load 7.8, ``WARP_SPH_CPU_THREADS`` 1 / 2): 20.3 / 21.2, 10.4 / 7.6, 3.8 /
    5.8 and 3.4 / 4.9 us per fluid particle-step at 561, 1,684, 4,530 and 9,516 particles: the fall below ~4.5k
    particles comes with one thread too (the per-step overhead and the solver's sweeps, 3.7 / 5.7 / 4.2 / 3.7), so
    the boundary holds on one thread as well."""
    from ..core.launch import MIN_RANGE

    return 2 * MIN_RANGE if device.is_cpu else 0
