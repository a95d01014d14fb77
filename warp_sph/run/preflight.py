"""Pre-flight checks: refuse a scene that cannot run well before any step kernel runs, warn about one
that runs but is probably not what the user meant.

``check_memory(scene, device)`` runs before sampling (``Simulation.__init__``): it estimates the
particle count from the scene's geometry and refuses a run that would not fit in memory.
``preflight_checks(scene, sim)`` runs once the Simulation is built (the runner calls it before
the first step):
- a fixed time step above the solver's stability bound (WCSPH: acoustic CFL
  cfl (H_s/2)/(c_s + v_ref); with viscosity also 0.0625 (H_s/2)^2/nu, Morris et al. 1997) is refused
  with the bound in the message; adaptive steps are clamped by it anyway, but a ``time.dt_min``
  above it is refused;
- fluid removed by sampling (inside obstacles, within the wall gap, overlapping an earlier block):
  a block left empty is refused, more than ``REMOVED_WARN`` of the lattice removed is reported;
- the rest-lattice density bias of the kernel and h/d before mass calibration (``model.lattice_bias``;
  the calibrated mass removes it in the bulk, but a large bias means a kernel used far from its
  intended h/d) and an over-dense initial state;
- the particle count and a memory estimate against what is available (``/proc/meminfo``
  MemAvailable and the cgroup limit; free device memory on CUDA);
- float32 resolution of local coordinates across the domain.
Warnings are issued as ``PreflightWarning`` (a UserWarning) and returned as a list of strings.
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import warp as wp

from ..core.errors import SceneError

#: Warn when the kernel's rest-lattice sum before calibration is off by more than this [-].
LATTICE_BIAS_WARN = 0.05
#: Warn when the initial state is this much over rest density anywhere (without spacing_scale < 1) [-].
INITIAL_DENSITY_WARN = 0.05
#: Warn when sampling removed more than this fraction of the fluid lattice [-].
REMOVED_WARN = 0.10
#: Warn when the run needs more than this fraction of the available memory; refuse above 1.
MEMORY_WARN = 0.5
#: Warn when float32 local coordinates resolve less than this fraction of the spacing d [-].
PRECISION_WARN = 1e-3

# Memory model [bytes], from the arrays a WCSPH run allocates (x, v, density, pressure, acceleration,
# boundary force, XSPH correction: 68 B), hash-grid indices (~32 B), the watchdog's frame-start copy
# (24 B) and up to three export snapshots in flight (96 B); host: sampling temporaries in float64 and
# the export copies. A rough but conservative model; the check refuses only what cannot fit.
DEVICE_BYTES_PER_FLUID = 256
DEVICE_BYTES_PER_BOUNDARY = 64
HOST_BYTES_PER_FLUID = 512
HOST_BYTES_PER_BOUNDARY = 128
HASH_GRID_BYTES = 2 * 128**3 * 4 * 2  # fluid and boundary grids: cell starts and ends
SURFACE_BYTES_PER_CELL = 32


class PreflightWarning(UserWarning):
    """A scene that runs but is probably not what was meant."""


# --------------------------------------------------------------------------------------------
# Time-step bounds
# --------------------------------------------------------------------------------------------
def time_step_bounds(sim, speed: float | None = None) -> dict[str, float]:
    """{name: seconds} of every time-step bound (``Simulation.time_step_bounds``) at flow speed ``speed``
    [m/s] (default: the model's reference speed, the largest speed the scene is expected to reach)."""
    v = sim.model.reference_speed if speed is None else float(speed)
    return {b.name: b.seconds for b in sim.time_step_bounds(v)}


def _step_estimate(scene, sim) -> tuple[float, float, object]:
    """(dt [s], substeps for the whole run (a float, may be huge), the tightest bound) at the reference
    speed; dt is what the run would take (fixed, or the bound clamped to dt_min..dt_max)."""
    t = scene.time
    bound = sim.time_step_bounds(sim.model.reference_speed)[0]
    dt = float(t.fixed_dt) if t.fixed_dt > 0 else min(max(bound.seconds, t.dt_min), t.dt_max)
    return dt, _substeps(scene, dt), bound


def _substeps(scene, dt: float) -> float:
    """Substeps of the whole run at step dt [s]: whole substeps per frame, times the frames."""
    frame_dt = 1.0 / float(scene.fps)
    per_frame = max(1.0, math.ceil(frame_dt / dt - 1e-9)) if dt > 0 else math.inf
    return per_frame * scene.duration * scene.fps


def time_step_summary(scene, sim) -> list[str]:
    """Lines for ``warp-sph check``: every bound at the reference speed and the estimated substep count."""
    v = sim.model.reference_speed
    lines = [f"time-step bound {b.name}: {b.seconds:.4g} s ({b.formula})" for b in sim.time_step_bounds(v)]
    dt, steps, _ = _step_estimate(scene, sim)
    frames = int(round(scene.duration * scene.fps)) + 1
    lines.append(f"{frames} frames at {scene.fps:g} fps; about {steps:,.0f} substeps of {dt:.4g} s at the reference "
                 f"speed {v:.3g} m/s (adaptive steps follow the flow)")
    return lines


def measured_step_cost(sim, steps: int = 2) -> float:
    """Wall seconds per particle-step of this simulation, measured on ``steps`` substeps after a first
    one (which loads the kernels); the state is put back afterwards."""
    import time

    wd = sim.watchdog
    dt = sim.time_step(sim.model.reference_speed)
    wd.save()
    try:
        sim.step(dt)
        wp.synchronize_device(sim.device)
        t0 = time.perf_counter()
        for _ in range(steps):
            sim.step(dt)
        wp.synchronize_device(sim.device)
        seconds = (time.perf_counter() - t0) / steps
    finally:
        wd.restore()
        sim.refresh_density()
    return seconds / max(sim.model.fluid_count, 1)


def _duration_text(seconds: float) -> str:
    if not math.isfinite(seconds) or seconds > 3.15e9:
        return "more than a century"
    for unit, size in (("days", 86400.0), ("hours", 3600.0), ("minutes", 60.0)):
        if seconds >= 2 * size:
            return f"about {seconds / size:.3g} {unit}"
    return f"about {seconds:.3g} s"


# --------------------------------------------------------------------------------------------
# Memory
# --------------------------------------------------------------------------------------------
def available_host_memory() -> int | None:
    """Bytes the process may still allocate: MemAvailable from /proc/meminfo, lowered by a cgroup
    limit when one is set; None where neither can be read."""
    avail = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = int(line.split()[1]) * 1024
                break
    except (OSError, ValueError, IndexError):
        pass
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            limit = Path(limit_file).read_text().strip()
            usage = int(Path(usage_file).read_text().strip())
        except (OSError, ValueError):
            continue
        if limit.isdigit() and int(limit) < 1 << 60:
            room = max(int(limit) - usage, 0)
            avail = room if avail is None else min(avail, room)
        break
    return avail


def available_device_memory(device) -> int | None:
    """Free memory [bytes] of a CUDA device; None on the CPU (host memory applies)."""
    d = wp.get_device(device)
    if not d.is_cuda:
        return None
    free = getattr(d, "free_memory", None)
    return int(free) if free else None


def particle_count_contributions(scene) -> list[tuple[str, str, int]]:
    """[(key path, "fluid" | "boundary", particles)] estimated from the scene's geometry without
    sampling: a block's volume / (s d)^3, a wall's or obstacle's area / d^2."""
    d = scene.spacing
    out = []
    for i, b in enumerate(scene.fluid):
        step = b.spacing_scale * d
        vol = 4.0 / 3.0 * math.pi * b.radius**3 if b.shape == "sphere" else float(np.prod(np.subtract(b.max, b.min)))
        out.append((f"fluid[{i}]", "fluid", int(min(vol / step**3, 2**62))))

    def box_area(lo, hi):
        e = np.subtract(hi, lo)
        return 2.0 * (e[0] * e[1] + e[1] * e[2] + e[0] * e[2])

    if scene.container is not None:
        out.append(("container", "boundary", int(min(box_area(scene.container.min, scene.container.max) / d**2, 2**62))))
    for i, ob in enumerate(scene.obstacles):
        if ob.shape == "box":
            area = box_area(ob.min, ob.max)
        else:
            try:
                from ..scene.meshes import load_triangle_mesh

                mesh = load_triangle_mesh(ob.file).transformed(ob.scale, ob.translate)
                a, b, c = mesh.triangle_corners()
                area = 0.5 * float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
            except Exception:
                area = 0.0
        out.append((f"obstacles[{i}]", "boundary", int(min(area / d**2, 2**62))))
    return out


def estimate_particle_counts(scene) -> tuple[int, int]:
    """(fluid, boundary) particle counts estimated from the scene's geometry, without sampling."""
    parts = particle_count_contributions(scene)
    return (sum(n for _, kind, n in parts if kind == "fluid"), sum(n for _, kind, n in parts if kind == "boundary"))


def _surface_bytes(scene, fluid_count: int) -> int:
    o = scene.output
    if not (o.surface and (o.usd or o.mesh_sequence)):
        return 0
    cell = o.surface_cell_per_radius * scene.particle_radius
    if scene.container is not None:
        volume = float(np.prod(np.subtract(scene.container.max, scene.container.min)))
    else:  # free fluid: its volume grown 8x (a block expanding to twice its size)
        volume = 8.0 * fluid_count * scene.spacing**3
    return int(min(SURFACE_BYTES_PER_CELL * volume / cell**3, 2**62))


def estimate_memory(scene, fluid_count: int, boundary_count: int) -> dict[str, int]:
    """{"device": bytes, "host": bytes} a run of ``scene`` needs at its peak (rough, conservative).
    On the CPU both live in host memory."""
    device = (DEVICE_BYTES_PER_FLUID * fluid_count + DEVICE_BYTES_PER_BOUNDARY * boundary_count
              + HASH_GRID_BYTES + _surface_bytes(scene, fluid_count))
    host = HOST_BYTES_PER_FLUID * fluid_count + HOST_BYTES_PER_BOUNDARY * boundary_count
    return {"device": int(device), "host": int(host)}


def _gib(n: float) -> str:
    return f"{n / 2**30:.3g} GiB" if n >= 2**28 else f"{n / 2**20:.3g} MiB"


def _largest_cost(scene, fluid: int, boundary: int) -> tuple[str, str]:
    """(key path, advice) of what needs the most memory: a fluid block, a wall, an obstacle or the surface grid."""
    per = {"fluid": DEVICE_BYTES_PER_FLUID + HOST_BYTES_PER_FLUID,
           "boundary": DEVICE_BYTES_PER_BOUNDARY + HOST_BYTES_PER_BOUNDARY}
    parts = [(n * per[kind], key, kind, n) for key, kind, n in particle_count_contributions(scene)]
    surface = _surface_bytes(scene, fluid)
    cost, key, kind, n = max(parts) if parts else (0, "particle_radius", "fluid", fluid)
    if surface > cost:
        return ("output.surface_cell_per_radius",
                f"the surface grid at {scene.output.surface_cell_per_radius:g} r cells needs {_gib(surface)}; "
                "raise output.surface_cell_per_radius")
    if key.startswith("obstacles"):
        return key, (f"{key} needs about {n:,} boundary particles at spacing d = {scene.spacing:g} m; check its "
                     "size (scale, min/max) or raise particle_radius")
    if key == "container":
        return key, (f"the container walls need about {n:,} boundary particles at spacing d = {scene.spacing:g} m; "
                     "shrink the container or raise particle_radius")
    return "particle_radius", f"{key} needs about {n:,} fluid particles; raise particle_radius or shrink the fluid blocks"


def _memory_verdict(scene, fluid: int, boundary: int, device, estimated: bool) -> tuple[str, str] | None:
    """("refuse" | "warn", message) or None."""
    need = estimate_memory(scene, fluid, boundary)
    host_avail = available_host_memory()
    dev_avail = available_device_memory(device)
    if dev_avail is None:
        pools = [("host", need["device"] + need["host"], host_avail)]
    else:
        pools = [("device", need["device"], dev_avail), ("host", need["host"], host_avail)]
    count = f"{'about ' if estimated else ''}{fluid:,} fluid and {boundary:,} boundary particles"
    worst = None
    for pool, n, avail in pools:
        if avail is None or avail <= 0:
            continue
        ratio = n / avail
        if worst is None or ratio > worst[0]:
            worst = (ratio, pool, n, avail)
    if worst is None:
        return None
    ratio, pool, n, avail = worst
    # memory scales as 1/r^3: the radius that would fit in half the available memory
    r_fit = scene.particle_radius * max(ratio / MEMORY_WARN, 1.0) ** (1.0 / 3.0)
    text = f"{count} need about {_gib(n)} of {pool} memory, {100 * ratio:.0f} % of the {_gib(avail)} available"
    if ratio > 1.0:
        key, advice = _largest_cost(scene, fluid, boundary)
        if key == "particle_radius":
            advice += f" (particle_radius about {r_fit:.3g} m would fit; memory scales as 1/r^3)"
        return "refuse", f"{scene.source}: {key}: {text}; {advice}"
    if ratio > MEMORY_WARN:
        return "warn", f"{text}; the run may swap or fail (particle_radius {r_fit:.3g} m would halve that)"
    return None


def check_memory(scene, device=None) -> None:
    """Refuse a scene whose estimated particle count cannot fit in memory, before sampling it."""
    fluid, boundary = estimate_particle_counts(scene)
    verdict = _memory_verdict(scene, fluid, boundary, device, estimated=True)
    if verdict is not None and verdict[0] == "refuse":
        raise SceneError(verdict[1])


# --------------------------------------------------------------------------------------------
# The checks
# --------------------------------------------------------------------------------------------
def _removed_fluid(scene, sim) -> tuple[list[int], list[int]]:
    """(lattice points per block before removal, particles per block after sampling)."""
    from ..scene.sampling import lattice_block

    d = scene.spacing
    c = scene.container
    before = []
    for block in scene.fluid:
        region = None
        if c is not None:
            shrink = scene.wall_gap - 0.5 * block.spacing_scale * d
            region = (np.asarray(c.min) + shrink, np.asarray(c.max) - shrink)
        before.append(len(lattice_block(block, d, region)))
    blocks = getattr(sim.sampled, "fluid_block", None)
    if blocks is None:
        after = before
    else:
        after = [int(np.count_nonzero(blocks == i)) for i in range(len(scene.fluid))]
    return before, after


def preflight_checks(scene, sim, warn: bool = True) -> list[str]:
    """Check a built Simulation before its first step. Raises SceneError for what cannot run;
    returns (and, with warn, issues as PreflightWarning) the warnings."""
    m = sim.model
    t = scene.time
    out: list[str] = []
    src = scene.source

    # time step ---------------------------------------------------------------------------------
    bounds = sim.time_step_bounds(m.reference_speed)
    tight = bounds[0]
    bound = tight.seconds
    uses_speed = "v = " in tight.formula
    source = (f"; the reference speed v_ref = {m.reference_speed:.3g} m/s comes from {m.reference_speed_source}"
              if uses_speed else "")
    keys = list(tight.keys) + ([m.reference_speed_source] if uses_speed and "velocity" in m.reference_speed_source
                               else [])
    set_by = f"; set by {', '.join(tight.keys)}" if tight.keys else ""
    at_bound = _substeps(scene, bound)
    if t.fixed_dt > 0 and t.fixed_dt > bound * (1.0 + 1e-6):
        raise SceneError(
            f"{src}: time.fixed_dt: {t.fixed_dt:.4g} s is {t.fixed_dt / bound:.3g}x the {tight.name} time-step bound "
            f"{bound:.4g} s ({tight.formula}, at the scene's reference speed{set_by}){source}; set time.fixed_dt <= "
            f"{bound:.4g} or 0 for adaptive steps, which that bound clamps")
    if t.fixed_dt == 0 and t.dt_min > bound * (1.0 + 1e-6):
        fix = (f"check {', '.join(keys) or 'those values'}: at that bound the run would need {at_bound:.3g} "
               f"substeps, more than time.max_steps = {t.max_steps:,}" if at_bound > t.max_steps
               else f"lower time.dt_min to {bound:.4g} or less")
        raise SceneError(
            f"{src}: the {tight.name} time-step bound {bound:.4g} s ({tight.formula}{set_by}) is below time.dt_min = "
            f"{t.dt_min:.4g} s{source}; {fix}")
    dt, steps, _ = _step_estimate(scene, sim)
    if steps > t.max_steps:
        cost = measured_step_cost(sim)
        wall = steps * cost * m.fluid_count
        why = (f"time.fixed_dt = {t.fixed_dt:.4g} s" if t.fixed_dt > 0 else
               f"dt = {dt:.4g} s from the {tight.name} bound ({tight.formula}{set_by})")
        raise SceneError(
            f"{src}: the run needs about {steps:.3g} substeps ({why}, duration {scene.duration:g} s), more than "
            f"time.max_steps = {t.max_steps:,}; at {1e9 * cost:.3g} ns per particle-step measured here that is "
            f"{_duration_text(wall)}{source if t.fixed_dt == 0 else ''}; check those values, or raise time.max_steps "
            "to run it anyway")

    # fluid removed by sampling -----------------------------------------------------------------
    before, after = _removed_fluid(scene, sim)
    for i, (b, a) in enumerate(zip(before, after)):
        if b == 0:
            out.append(f"fluid[{i}] is smaller than one particle spacing d = {scene.spacing:g} m (after the "
                       f"wall gap) and holds no particle")
        elif a == 0:
            raise SceneError(
                f"{src}: fluid[{i}]: all {b} of its particles lie inside obstacles, within the wall gap "
                f"{scene.wall_gap:.3g} m of boundary particles or inside an earlier fluid block; move or "
                f"resize the block")
    total_b, total_a = sum(before), sum(after)
    if total_b and (total_b - total_a) > REMOVED_WARN * total_b:
        out.append(f"sampling removed {total_b - total_a} of {total_b} fluid particles "
                   f"({100 * (total_b - total_a) / total_b:.0f} %): they lay inside obstacles, within the wall "
                   f"gap of boundary particles or inside an earlier fluid block")

    # rest density ------------------------------------------------------------------------------
    if abs(m.lattice_bias) > LATTICE_BIAS_WARN:
        out.append(f"the {m.smoothing.name} kernel at h/d = {m.smoothing_length / m.spacing:.3g} sums to "
                   f"{100 * m.lattice_bias:+.1f} % of rest density on a rest lattice before mass calibration; the "
                   f"calibrated mass removes it in the bulk, but surface and wall layers keep part of it: use the "
                   f"kernel's default h_per_spacing ({m.smoothing.default_h_per_spacing:.3g})")
    if all(b.spacing_scale >= 1.0 for b in scene.fluid):
        rho = sim.fields["particle_density"].numpy()
        err = float(rho.max()) / m.rest_density - 1.0 if len(rho) else 0.0
        if err > INITIAL_DENSITY_WARN:
            i = int(np.argmax(rho))
            x = sim.get_field("particle_x")[i]
            out.append(f"the initial state is {100 * err:.1f} % over rest density at particle {i} "
                       f"(x = [{', '.join(f'{c:.4g}' for c in x)}] m): fluid too close to a boundary or to "
                       f"another block; the first steps will push it apart")

    # memory ------------------------------------------------------------------------------------
    verdict = _memory_verdict(scene, m.fluid_count, m.boundary_count, sim.device, estimated=False)
    if verdict is not None:
        if verdict[0] == "refuse":
            raise SceneError(verdict[1])
        out.append(verdict[1])

    # float32 resolution of local coordinates -----------------------------------------------------
    if m.container_lo is not None:
        extent = float(max(np.abs(m.container_lo).max(), np.abs(m.container_hi).max()))
    else:
        x = sim.get_field("particle_x") - m.origin
        extent = 2.0 * float(np.abs(x).max()) if len(x) else 0.0
    ulp = float(np.spacing(np.float32(extent))) if extent > 0 else 0.0
    if ulp > PRECISION_WARN * m.spacing:
        out.append(f"the domain reaches {extent:.4g} m from its centre, where float32 positions resolve "
                   f"{ulp:.2g} m = {100 * ulp / m.spacing:.2g} % of the spacing; split the scene or raise "
                   f"particle_radius")

    if warn:
        for w in out:
            warnings.warn(w, PreflightWarning, stacklevel=2)
    return out
