"""Watchdog: per-frame health rules checked on the device, retry with a smaller step, diagnosis by replay.

Rules (counted by ``kernels/diagnostics.accumulate_statistics`` in the frame's one statistics pass):
- **non-finite**: a position, velocity, density or acceleration is NaN or infinite.
- **outside**: a particle is outside the container grown by one spacing d (it went through a wall), unless it
  is past the plane of an open face (``container.open``): it left through that face, or flies above an open
  top (over the rim it may also be past a side wall's plane, above the wall).
- **too fast**: |v| > SPEED_LIMIT_FACTOR * (v_ref + |g| t_free), v_ref = ``model.reference_speed``
  = max(sqrt(2 |g| H), max |v0|), H the height of the fluid top above the container floor. In a
  container energy bounds every particle's speed by about sqrt(2 |g| H + |v0|^2) <= sqrt(2) v_ref, so
  a particle 10x faster holds 50x more kinetic energy than the whole scene can release: only a
  blow-up produces it. Without a container the fluid may fall freely; t_free = t then (the ballistic
  speed |v0| + |g| t bounds it), 0 in a container.
- **over-dense**: rho/rho0 - 1 > DENSITY_LIMIT_FACTOR * max(1, rho_max(0)/rho0) - 1, i.e. the density
  doubled beyond rest (or beyond an intentionally compressed start). WCSPH aims at ~1 % compression
  (c_s = 10 v_ref, Becker & Teschner 2007); 100 % means particles at 0.8 d and a broken boundary or
  stiffness, never a valid state of a liquid.
- **energy**: the total energy (fluid kinetic + potential, and the rigid bodies') rose more than 1 % of the
  scene's energy above its initial value (``warp_sph.run.energy``): the
  rule every solver shares, since a bad step, solve, viscosity or coupling creates energy long before it
  throws a particle out. Checked on the host once per frame; no replay (the rise has no single stage).

On a violation the frame is either retried from its start with half the time step
(``time.on_instability = "retry"``, up to MAX_RETRIES halvings; the reduction relaxes again,
doubling per clean frame) or the run stops with a SimulationError. Before it stops, the frame is
replayed from its start stage by stage, checking after each stage the fields it wrote and the rules
above, so the error names the first stage, step, time and particle(s) that went wrong, with the
likely cause. The frame start is kept as device copies of x and v (2 copies per frame, 24 bytes per
particle; negligible next to the substeps; measured in the issue note), and of the rigid bodies'
Newton state when the scene has bodies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.errors import SimulationError
from ..kernels import diagnostics as _diag
from ..core.launch import launch
from .energy import ENERGY_GROWTH_LIMIT, EnergyWatch

SPEED_LIMIT_FACTOR = 10.0
DENSITY_LIMIT_FACTOR = 2.0
MAX_RETRIES = 5

RULE_TEXT = {
    "non_finite": "a non-finite value",
    "outside": "a particle outside the container",
    "fast": "a particle faster than the speed limit",
    "dense": "a density beyond the limit",
    "energy": "a rise of the total energy",
}
#: the rules the device's statistics pass counts (the stage-by-stage replay checks these only)
DEVICE_RULES = ("non_finite", "outside", "fast", "dense")


@dataclass
class Finding:
    """The first stage (in replay order) after which a rule broke."""

    rule: str           # "non_finite" | "outside" | "fast" | "dense"
    stage: str
    field: str          # the field that broke the rule
    step: int           # global step number of the failing substep (1-based count of steps taken)
    substep: int        # 1-based within the frame
    time: float         # [s] at the start of that substep
    count: int
    first: int          # smallest particle index breaking it


def _kept_copy(kept, a: wp.array) -> wp.array:
    """``a`` copied into ``kept`` where that array has its shape, dtype and device (the last frame's copy: no
    allocation per frame), else into a new clone."""
    if isinstance(kept, wp.array) and kept.shape == a.shape and kept.dtype == a.dtype and kept.device == a.device:
        wp.copy(kept, a)
        return kept
    return wp.clone(a)


class Watchdog:
    """Health rules, frame-start snapshot and retry state of one Simulation."""

    def __init__(self, sim):
        self.sim = sim
        m = sim.model
        self.mode = getattr(sim.scene.time, "on_instability", "stop")
        self.watch = wp.zeros(_diag.WATCH_COUNT, dtype=int, device=sim.device)
        self._count = wp.zeros(2, dtype=int, device=sim.device)
        self.free_fall = m.container_lo is None
        self.gravity = float(np.linalg.norm(m.gravity))
        rho = sim.fields["particle_density"].numpy()
        start = float(np.max(rho)) / m.rest_density if len(rho) and np.all(np.isfinite(rho)) else 1.0
        self.density_limit = DENSITY_LIMIT_FACTOR * max(1.0, start) - 1.0
        self.dt_scale = 1.0
        self.replay = True
        self._x0 = None
        self._v0 = None
        self._start = None      # (time, step, frame) at the frame start
        self._extra = None
        self._bodies = None
        self._parts = ()        # (part, its saved state) of the optional parts with a frame-start state
        #: the energy rule's reference and measurements (``warp_sph.run.energy``)
        self.energy = EnergyWatch(sim)

    # --- limits ------------------------------------------------------------------------------
    def speed_limit(self, t: float) -> float:
        """Speed limit [m/s] at time t [s]."""
        v = self.sim.model.reference_speed
        if self.free_fall:
            v += self.gravity * max(t, 0.0)
        return SPEED_LIMIT_FACTOR * v

    # --- frame-start snapshot ----------------------------------------------------------------
    def save(self) -> None:
        s = self.sim.state
        if self._x0 is None:  # the capacity: emitters change the active count (``warp_sph.run.emission``)
            self._x0 = wp.empty(self.sim.model.capacity, dtype=s.particle_x.dtype, device=self.sim.device)
            self._v0 = wp.empty(self.sim.model.capacity, dtype=s.particle_v.dtype, device=self.sim.device)
        wp.copy(self._x0, s.particle_x, count=s.particle_x.shape[0])
        wp.copy(self._v0, s.particle_v, count=s.particle_v.shape[0])
        self._start = (s.time, s.step, s.frame)
        self._bodies = self.sim.bodies.save() if self.sim.bodies is not None else None
        # animated obstacles (pose, work so far) and whitewater (a redone frame generates the same particles)
        self._parts = tuple((p, p.save()) for p in self.sim.parts if hasattr(p, "save"))
        # the carried fields (e.g. DFSPH's warm start) too, in every mode: a frame redone after a neighbour list
        # overflowed (``frame_loop``) must start from the same values to be bitwise the run with longer rows
        arrays = {**self.sim.solver.checkpoint_arrays(), **self.sim.forces.checkpoint_arrays()}
        kept = self._extra or {}
        self._extra = {k: _kept_copy(kept.get(k), a) if isinstance(a, wp.array) else a for k, a in arrays.items()}

    def restore(self) -> None:
        s = self.sim.state
        wp.copy(s.particle_x, self._x0, count=s.particle_x.shape[0])
        wp.copy(s.particle_v, self._v0, count=s.particle_v.shape[0])
        s.time, s.step, s.frame = self._start
        if self._extra:
            self.sim.solver.restore_arrays(self._extra)
            self.sim.forces.restore_arrays(self._extra)
        if self._bodies is not None:  # the bodies' Newton state and their boundary particles
            self.sim.bodies.restore(self._bodies)
        for part, saved in self._parts:
            part.restore(saved)

    # --- rules -------------------------------------------------------------------------------
    def read(self) -> dict:
        """The watch counters of the last statistics pass, as a dict (first index -1 when none)."""
        w = self.watch.numpy()
        out = {}
        for rule, k in (("non_finite", _diag.WATCH_NON_FINITE), ("outside", _diag.WATCH_OUTSIDE),
                        ("fast", _diag.WATCH_FAST), ("dense", _diag.WATCH_DENSE)):
            first = int(w[k + 1])
            out[rule] = int(w[k])
            out[f"first_{rule}"] = -1 if first == _diag.INDEX_NONE else first
        return out

    @staticmethod
    def broken(watch: dict, rules: tuple[str, ...] = DEVICE_RULES + ("energy",)) -> str | None:
        """The first rule of ``rules`` the watch counts say is broken, or None."""
        for rule in rules:
            if watch.get(rule, 0):
                return rule
        return None

    # --- diagnosis ---------------------------------------------------------------------------
    def _non_finite(self, a) -> tuple[int, int]:
        kernel = {float: _diag.count_non_finite_float, wp.float32: _diag.count_non_finite_float,
                  wp.vec3: _diag.count_non_finite_vec3}.get(a.dtype)
        if kernel is None:
            return 0, -1
        launch(_diag.reset_count, 1, [], [self._count], device=self.sim.device)
        launch(kernel, a.shape[0], [a], [self._count], device=self.sim.device)
        c = self._count.numpy()
        return int(c[0]), (int(c[1]) if c[0] else -1)

    def diagnose(self, n: int, dt: float) -> Finding | None:
        """Replay the frame from its start (n substeps of dt) stage by stage; the first stage
        after which a field turns non-finite or a rule breaks. Leaves the state where it stopped."""
        sim = self.sim
        if self._start is None:
            return None
        self.restore()
        sim.refresh_density()
        acc = sim.fields.get("particle_acceleration")
        if acc is not None:
            acc.zero_()
        t0, step0, _ = self._start
        for k in range(n):
            t = t0 + k * dt
            for stage in sim.graph.stages:
                stage.run(sim, dt)
                for name in tuple(stage.writes) + tuple(stage.updates):
                    a = sim.fields.get(name)
                    if isinstance(a, wp.array) and a.ndim == 1 and a.shape[0] == sim.model.fluid_count:
                        count, first = self._non_finite(a)
                        if count:
                            return Finding("non_finite", stage.name, name, step0 + k + 1, k + 1, t, count, first)
                sim.statistics(at_time=t + dt)
                w = self.read()
                rule = self.broken(w, DEVICE_RULES)
                if rule is not None:
                    field = {"non_finite": "particle state", "outside": "particle_x", "fast": "particle_v",
                             "dense": "particle_density"}[rule]
                    return Finding(rule, stage.name, field, step0 + k + 1, k + 1, t, w[rule], w[f"first_{rule}"])
            sim.state.step += 1
            sim.state.time += dt
        return None

    # --- messages ----------------------------------------------------------------------------
    def _particle_text(self, i: int) -> str:
        if i < 0:
            return ""
        sim = self.sim
        parts = []
        try:
            x = sim.get_field("particle_x")[i]
            v = sim.fields["particle_v"].numpy()[i]
            parts.append("x = [" + ", ".join(f"{c:.4g}" for c in x) + "] m")
            parts.append(f"|v| = {float(np.linalg.norm(v)):.3g} m/s")
            rho = sim.fields.get("particle_density")
            if rho is not None:
                parts.append(f"density = {float(rho.numpy()[i]):.5g} kg/m^3")
        except Exception:  # pragma: no cover - a description must never hide the error
            pass
        return " (" + ", ".join(parts) + ")" if parts else ""

    def likely_cause(self, rule: str, stage: str | None, dt: float, speed: float) -> str:
        """A sentence naming the likely cause and what to change. ``speed`` [m/s] is the flow speed the
        frame's step was sized for, so the quoted bound is the one the step was checked against."""
        sim = self.sim
        m = sim.model
        t = sim.scene.time
        if stage is not None and stage not in sim.solver_stage_names:
            return f"stage {stage!r} is not one of the {sim.scene.solver} solver's own stages: check that stage"
        tight = sim.time_step_bounds(speed)[0]
        if dt > 1.01 * tight.seconds:
            fix = ("lower time.fixed_dt, or set it to 0 for adaptive steps" if t.fixed_dt > 0 else
                   f"lower time.dt_min below {tight.seconds:.3g} s")
            return (f"time step too large: dt = {dt:.3g} s is {dt / tight.seconds:.2g}x the {tight.name} bound "
                    f"{tight.seconds:.3g} s ({tight.formula}); {fix}")
        hint = sim.solver.instability_hint(rule, stage) or sim.forces.instability_hint(rule, stage)
        if hint:
            return hint
        if rule == "energy":
            return self.energy.cause(self.energy.last, dt, tight)
        if rule == "outside":
            return ("particles passed through a wall: the boundary is too soft or the step too large for the "
                    "impact speed; lower time.cfl" + (", or use boundary = 'akinci2012'" if m.boundary_method == "penalty" else ""))
        if rule == "dense":
            return "the fluid compressed to twice its rest density: the pressure solve is too weak for the scene"
        return (f"a value left its valid range with dt = {dt:.3g} s within the {tight.name} bound {tight.seconds:.3g} s: "
                f"check the values of {', '.join(tight.keys) or 'the scene'} and the fluid's initial state; "
                f"lower time.cfl or set time.on_instability = 'retry'")

    def error(self, stats, n: int, dt: float, retries: int, start_speed: float) -> SimulationError:
        """Diagnose the failed frame (replay) and build the error."""
        rule = self.broken(stats.watch)
        tail = f" after {retries} retries with halved time steps" if retries else ""
        if rule == "energy":
            return SimulationError(
                f"{self.energy.account(self.energy.last)} by frame {stats.frame} (t = {stats.time:.5g} s, step "
                f"{self.sim.state.step}, dt = {dt:.3g} s){tail}; likely cause: "
                f"{self.likely_cause(rule, None, dt, start_speed)}")
        finding = self.diagnose(n, dt) if self.replay else None
        if finding is not None:
            where = (f"stage {finding.stage!r} produced {RULE_TEXT[finding.rule]} in {finding.field} at step "
                     f"{finding.step} (t = {finding.time:.5g} s, substep {finding.substep} of {n} in frame "
                     f"{stats.frame}, dt = {dt:.3g} s){tail}")
            who = f"particle {finding.first}" + (f" and {finding.count - 1} more" if finding.count > 1 else "")
            cause = self.likely_cause(finding.rule, finding.stage, dt, start_speed)
            return SimulationError(f"{where}: {who}{self._particle_text(finding.first)}; likely cause: {cause}")
        first = stats.watch.get(f"first_{rule}", -1)
        count = stats.watch.get(rule, 0)
        who = f"particle {first}" + (f" and {count - 1} more" if count > 1 else "")
        cause = self.likely_cause(rule, None, dt, start_speed)
        return SimulationError(
            f"{RULE_TEXT[rule]} by frame {stats.frame} (t = {stats.time:.5g} s, step {self.sim.state.step}, "
            f"dt = {dt:.3g} s){tail}: {who}{self._particle_text(first)}; likely cause: {cause}")

    def initial_error(self, stats) -> SimulationError:
        rule = self.broken(stats.watch)
        if rule == "energy" and self.sim.state.step == 0:  # an unintended compression energy at the start
            en = self.energy
            tight = self.sim.time_step_bounds(stats.max_speed)[0]
            return SimulationError(
                f"the initial state holds {en.unintended:.3g} J of compression energy = "
                f"{100 * en.unintended / en.scale:.3g} % of the scene's energy {en.scale:.4g} J (limit "
                f"{100 * ENERGY_GROWTH_LIMIT:g} %), which a run releases as motion; likely cause: "
                f"{en.cause(en.last, tight.seconds, tight)}")
        if rule == "energy":  # the caller stepped the state (Simulation.step): judge the steps it took
            dt = float(getattr(stats, "dt_max", 0.0) or 0.0) or float(self.sim.scene.time.fixed_dt)
            cause = self.likely_cause(rule, None, dt, stats.max_speed) if dt > 0 else "check the steps taken"
            return SimulationError(f"{self.energy.account(self.energy.last)} by step {self.sim.state.step} "
                                   f"(t = {stats.time:.5g} s); likely cause: {cause}")
        first = stats.watch.get(f"first_{rule}", -1)
        count = stats.watch.get(rule, 0)
        who = f"particle {first}" + (f" and {count - 1} more" if count > 1 else "")
        where = (f"the state at frame {stats.frame} (t = {stats.time:.5g} s, step {self.sim.state.step}) holds "
                 f"{RULE_TEXT[rule]}: {who}{self._particle_text(first)}")
        dt = float(getattr(stats, "dt_max", 0.0) or 0.0)
        if self.sim.state.step > 0 and dt > 0:
            # the caller stepped the state (e.g. Simulation.step at a fixed dt): judge the step it used
            # against the bounds at the flow's speed now, which the step did not follow
            tight = self.sim.time_step_bounds(stats.max_speed)[0]
            if dt > 1.01 * tight.seconds:
                cause = (f"the steps taken, dt = {dt:.3g} s, are {dt / tight.seconds:.2g}x the {tight.name} bound "
                         f"{tight.seconds:.3g} s at the flow's speed now ({tight.formula}): size each step for the "
                         f"current speed (Simulation.time_step(max speed), as advance_frame does every frame)")
            else:
                cause = self.likely_cause(rule, None, dt, stats.max_speed)
            return SimulationError(f"{where}; likely cause: {cause}")
        return SimulationError(f"{where}; check the scene's fluid blocks, velocities and container, or the values "
                               f"written with set_field")


def frame_substeps(frame_dt: float, bound: float) -> int:
    """Equal substeps no larger than ``bound`` covering one frame."""
    return max(1, math.ceil(frame_dt / bound - 1e-9))
