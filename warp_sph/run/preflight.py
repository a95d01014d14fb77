"""Pre-flight checks: refuse a scene that cannot run well before any step kernel runs, warn about one
that runs but is probably not what the user meant.

``check_memory(scene, device)`` (``memory.py``, re-exported here) runs before sampling
(``Simulation.__init__``): it estimates the particle count from the scene's geometry and refuses a
run that would not fit in memory.
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

import numpy as np
import warp as wp

from ..core.errors import SceneError
from .memory import MEMORY_WARN, check_memory, estimate_memory, estimate_particle_counts, memory_verdict

#: Warn when the kernel's rest-lattice sum before calibration is off by more than this [-].
LATTICE_BIAS_WARN = 0.05
#: Warn when the initial state is this much over rest density anywhere (without spacing_scale < 1) [-].
INITIAL_DENSITY_WARN = 0.05
#: Warn when sampling removed more than this fraction of the fluid lattice [-].
REMOVED_WARN = 0.10
#: Warn when float32 local coordinates resolve less than this fraction of the spacing d [-].
PRECISION_WARN = 1e-3


#: memory.py's names re-exported (check_memory has always been imported from here)
__all__ = ["INITIAL_DENSITY_WARN", "LATTICE_BIAS_WARN", "MEMORY_WARN", "PRECISION_WARN", "REMOVED_WARN",
           "PreflightWarning", "check_memory", "estimate_memory", "estimate_particle_counts", "measured_step_cost",
           "memory_verdict", "preflight_checks", "time_step_bounds", "time_step_summary"]


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


def _step_estimate(scene, sim, frames: int | None = None) -> tuple[float, float, object]:
    """(dt [s], substeps for the whole run (a float, may be huge), the tightest bound) at the reference
    speed; dt is what the run would take (fixed, or the bound clamped to dt_min..dt_max)."""
    t = scene.time
    bound = sim.time_step_bounds(sim.model.reference_speed)[0]
    dt = float(t.fixed_dt) if t.fixed_dt > 0 else min(max(bound.seconds, t.dt_min), t.dt_max)
    return dt, _substeps(scene, dt, frames), bound


def _substeps(scene, dt: float, frames: int | None = None) -> float:
    """Substeps of the whole run at step dt [s]: whole substeps per frame, times the frames after the
    first (``frames`` written, as ``--frames``; default: duration * fps of them)."""
    frame_dt = 1.0 / float(scene.fps)
    per_frame = max(1.0, math.ceil(frame_dt / dt - 1e-9)) if dt > 0 else math.inf
    intervals = scene.duration * scene.fps if frames is None else max(int(frames) - 1, 0)
    return per_frame * intervals if intervals else 0.0


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


def preflight_checks(scene, sim, warn: bool = True, frames: int | None = None) -> list[str]:
    """Check a built Simulation before its first step. Raises SceneError for what cannot run;
    returns (and, with warn, issues as PreflightWarning) the warnings. ``frames``: the frames the run
    writes (``--frames``) when not the scene's duration * fps + 1."""
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
    at_bound = _substeps(scene, bound, frames)
    if t.fixed_dt > 0 and t.fixed_dt > bound * (1.0 + 1e-6):
        raise SceneError(
            f"{src}: time.fixed_dt: {t.fixed_dt:.4g} s is {t.fixed_dt / bound:.3g}x the {tight.name} time-step bound "
            f"{bound:.4g} s ({tight.formula}, at the scene's reference speed{set_by}){source}; set time.fixed_dt <= "
            f"{bound:.4g} or 0 for adaptive steps, which that bound clamps")
    floor = sim.solver.step_floor()
    if floor is not None and 0 < t.fixed_dt < floor.seconds:
        raise SceneError(
            f"{src}: time.fixed_dt: {t.fixed_dt:.4g} s is below the {scene.solver} solver's smallest step "
            f"{floor.seconds:.4g} s ({floor.name}: {floor.formula}); set time.fixed_dt >= {floor.seconds:.4g}, 0 for "
            f"adaptive steps, or use solver = \"dfsph\"")
    if t.fixed_dt == 0 and t.dt_min > bound * (1.0 + 1e-6):
        fix = (f"check {', '.join(keys) or 'those values'}: at that bound the run would need {at_bound:.3g} "
               f"substeps, more than time.max_steps = {t.max_steps:,}" if at_bound > t.max_steps
               else f"lower time.dt_min to {bound:.4g} or less")
        raise SceneError(
            f"{src}: the {tight.name} time-step bound {bound:.4g} s ({tight.formula}{set_by}) is below time.dt_min = "
            f"{t.dt_min:.4g} s{source}; {fix}")
    dt, steps, _ = _step_estimate(scene, sim, frames)
    if steps > t.max_steps:
        cost = measured_step_cost(sim)
        wall = steps * cost * m.fluid_count
        why = (f"time.fixed_dt = {t.fixed_dt:.4g} s" if t.fixed_dt > 0 else
               f"dt = {dt:.4g} s from the {tight.name} bound ({tight.formula}{set_by})")
        span = f"duration {scene.duration:g} s" if frames is None else f"--frames {frames:,} at {scene.fps:g} fps"
        raise SceneError(
            f"{src}: the run needs about {steps:.3g} substeps ({why}, {span}), more than "
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
    # the arrays' capacity (emitters: max_particles or what they emit), not just the particles at t = 0
    verdict = memory_verdict(scene, max(m.capacity, m.fluid_count), m.boundary_count, sim.device, estimated=False,
                             frames=frames)
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
