"""The energy watchdog: the scene's total energy may not grow (issue 36), whatever the solver.

Total energy E [J], summed in float64 once per frame (``kernels/diagnostics.energy_chunks``, one small read):
- fluid: kinetic sum m |v|^2 / 2 and potential sum -m g.x;
- rigid bodies: M |v|^2 / 2 + w.I w / 2 - M g.x_com (``RigidWorld.energy``).
The compression energy sum m e(rho/rho0) of the solver's equation of state (``Solver.equation_of_state``:
WCSPH; e = int p / rho^2 drho, clamped at 0 below rho0) is measured and recorded but is not part of E: an
impact stores kinetic energy there for a moment (E falls, and returns no higher than it was), and
counting it would add the integrator's bounded oscillation of a stiff spring (a WCSPH block landing from
0.1 m read 1.05 % with it, 0.11 % without). It enters the start instead (below). PBF and DFSPH, an
incompressible projection, store nothing in compression. Animated obstacles (``rigid.colliders``) drive the
fluid: the work they do on it, W = -sum over substeps dt sum_b F_b . v_b (F_b the fluid's force on their
particle b, the exact negative of the boundary terms), is subtracted (E - W is what the rule watches).
Emitters and sinks (``warp_sph.run.emission``) add and remove particles: the kinetic + potential energy they
brought in minus what the removed ones took out (``ParticleFlow.exchanged``) is added to E(0), and the emitted
energy above the floor to the scale.
Any other source that puts energy in must add its work to the reference before it can run under this rule.

Rule: E(t) - E(0) - W(t) > allowance + ENERGY_GROWTH_LIMIT * scale at the end of a frame stops the run (or retries
the frame with ``time.on_instability = "retry"``), with one line naming the likely cause and the key to change.
- ``scale`` [J] does not depend on the origin: the initial total with the potential energy counted from the
  floor (the lowest container corner along gravity; without a container the lowest particle or body at
  t = 0), i.e. what the scene can release, but at least 1 % of M v_ref^2 / 2 (v_ref =
  ``model.reference_speed``), so that a scene at rest in zero gravity is not judged on rounding.
  The dam break: M g h_com, the centre of mass above the floor.
- The start: the compression energy of an *unintended* over-density under the solver's equation of state
  (the first layers of a lattice sampled at rest spacing read up to ~1 % over rest at walls) becomes a
  rise when released, so a start holding more than 1 % of the scale there is stopped before the first
  step (WCSPH with c_s = 1000 m/s stores 6 % of the small dam break's energy there).
  A block packed tighter on purpose (``fluid[].spacing_scale`` < 1, ``radial_expansion``) keeps it.
- ``allowance`` [J]: for a start compressed on purpose (or a state set by hand), the energy that
  compression can return: sum m e(rho/rho0) under the solver's equation of state, or for a solver without
  one (PBF, DFSPH) a linear law at the model's speed of sound c_s; 0 otherwise.
- ENERGY_GROWTH_LIMIT = 1 %: on every shipped scene at r = 0.05 m (floating_bodies at 0.015 m), 24 frames,
  every solver, the largest rise above E(0) was +0.18 % (drop_into_pool, WCSPH); every other run lost
  energy (numerical dissipation). radial_expansion (time.cfl = 0.2) stays 0.25 % beyond its allowance at
  its r = 0.025 m (WCSPH; 0.69 % at r = 0.05 m). A solver instability grows fast and crosses 1 % within a frame or two,
  long before the speed or escape rules see it (docs/extremes.md).

A user change of the state (``Simulation.set_field``) or of the solver (``set_solver``) starts a new reference.
A boundary method whose wall force is a spring (``BoundaryMethod.stores_energy``: penalty) exchanges energy
with the fluid that E does not hold (up to 16 % of a resting tank's), so the rule is off with it; so is it
with a force that stores or adds energy E does not hold (``Force.stores_energy``: surface tension's surface
energy, vorticity confinement's injected rotation).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.launch import launch
from ..kernels import diagnostics as _diag
from ..kernels import reduction as _reduce

#: largest rise of the total energy above its initial value, as a fraction of ``EnergyWatch.scale``
ENERGY_GROWTH_LIMIT = 0.01
#: the floor of the scale: this fraction of M v_ref^2 / 2 (a scene at rest without gravity)
SCALE_FLOOR = 0.01

_EOS = {"linear": _diag.EOS_LINEAR, "tait": _diag.EOS_TAIT}


@dataclass
class Energy:
    """The scene's energies at one instant [J] (potentials in the simulation's local frame)."""

    kinetic: float
    potential: float
    compression: float            # the solver's equation of state (0 without one)
    body_kinetic: np.ndarray      # per body
    body_potential: np.ndarray    # per body
    work: float = 0.0             # done on the fluid by animated obstacles since the reference (``rigid.colliders``)

    @property
    def bodies(self) -> float:
        return float(np.sum(self.body_kinetic) + np.sum(self.body_potential))

    @property
    def fluid(self) -> float:
        """Kinetic + potential [J]: the compression energy is not part of the total (module docstring)."""
        return self.kinetic + self.potential

    @property
    def total(self) -> float:
        return self.fluid + self.bodies


class EnergyWatch:
    """Total energy of ``sim`` against its value at the reference state (see the module docstring)."""

    def __init__(self, sim):
        self.sim = sim
        m = sim.model
        chunks = max(1, -(-m.capacity // _reduce.REDUCE_CHUNK))
        self._partial = wp.zeros((chunks, _diag.ENERGY_COUNT), dtype=wp.float64, device=sim.device)
        #: a user changed the state or the solver: the next check starts a new reference
        self.stale = False
        self.reference: Energy | None = None
        self.scale = 0.0
        self.allowance = 0.0
        self.last: Energy | None = None
        #: False when the boundary method's wall force (penalty) or a force of the scene (surface tension,
        #: vorticity confinement) stores or adds energy the rule does not count: the energies are still
        #: measured and recorded, the rule is off
        self.enabled = not ((sim.boundary is not None and type(sim.boundary).stores_energy)
                            or any(type(f).stores_energy for f in sim.forces))
        self.rebase()

    # --- measuring -------------------------------------------------------------------------
    def _sums(self, law) -> np.ndarray:
        sim, m = self.sim, self.sim.model
        eos, k = (_EOS[law[0]], float(law[1])) if law else (_diag.EOS_NONE, 0.0)
        f = sim.fields
        launch(_diag.energy_chunks, self._partial.shape[0],
               [_reduce.REDUCE_CHUNK, m.particle_mass, m.rest_density, wp.vec3(*m.gravity), eos,
                wp.float64(k / m.rest_density), f["particle_x"], f["particle_v"], f["particle_density"]],
               [self._partial], device=sim.device)
        return self._partial.numpy().sum(axis=0)

    def measure(self) -> Energy:
        """The energies now (one reduction and one small read; the bodies' state is read too)."""
        ke, pe, u = self._sums(self.sim.solver.equation_of_state())
        if self.sim.bodies is not None:
            bk, bp = self.sim.bodies.energy()
        else:
            bk = bp = np.zeros(0)
        colliders = getattr(self.sim, "colliders", None)
        work = colliders.work_done() if colliders is not None else 0.0
        self.last = Energy(float(ke), float(pe), float(u), bk, bp, work)
        return self.last

    def rebase(self, intended: bool | None = None) -> None:
        """Take the current state as the reference: E(0), the scale and the allowance. ``intended``: the state's
        compression is meant (default: a fluid block has ``spacing_scale`` < 1; a state set by hand is)."""
        sim, m = self.sim, self.sim.model
        if getattr(sim, "colliders", None) is not None:
            sim.colliders.reset_work()  # the driven work counts from the reference on
        e = self.measure()
        self.reference = e
        self.stale = False
        # a block packed tighter than rest on purpose (spacing_scale < 1) may release its compression; the
        # residual over-density of a lattice sampled at rest spacing (first layers at walls) may not
        if intended is None:
            intended = any(float(getattr(b, "spacing_scale", 1.0)) < 1.0 for b in sim.scene.fluid)
        self.unintended = 0.0 if intended else e.compression
        rho = sim.fields["particle_density"].numpy()
        self.start_compression = float(np.max(rho)) / m.rest_density - 1.0 if len(rho) else 0.0
        if intended:
            law = sim.solver.equation_of_state() or ("linear", m.rest_density * m.speed_of_sound ** 2)
            self.allowance = float(self._sums(law)[2])
        else:
            self.allowance = 0.0
        #: E(0) the rule measures from [J]
        self.reference_total = e.total
        flow = getattr(sim, "flow", None)
        #: the emitters' and sinks' exchanged energy at the reference [J] (``warp_sph.run.emission``)
        self.exchanged_base = flow.exchanged if flow is not None else 0.0
        self.exchanged_scale_base = flow.exchanged_scale if flow is not None else 0.0
        g = np.asarray(m.gravity, dtype=np.float64)
        gn = float(np.linalg.norm(g))
        masses = np.asarray(sim.bodies.world.masses if sim.bodies is not None else [], dtype=np.float64)
        total_mass = m.fluid_count * m.particle_mass + float(masses.sum())
        floor = 0.0
        if gn > 0:
            up = -g / gn
            if m.container_lo is not None:
                lo, hi = np.asarray(m.container_lo, float), np.asarray(m.container_hi, float)
                floor = min(float(np.array([a, b, c]) @ up) for a in (lo[0], hi[0]) for b in (lo[1], hi[1])
                            for c in (lo[2], hi[2]))
            else:
                heights = self.sim.fields["particle_x"].numpy().astype(np.float64) @ up
                if sim.bodies is not None and len(masses):
                    q = sim.bodies.world.body_q.numpy().astype(np.float64)
                    heights = np.concatenate([heights, q[:, :3] @ up])
                floor = float(heights.min())
        #: the floor's height along -g in the local frame [m] (the potential energy's zero for the scale)
        self.floor = floor
        # potential energy counted from the floor: sum m g.(h - floor) = PE_local - M |g| floor
        above = self.reference_total - total_mass * gn * floor + self.allowance
        # (at least one particle's worth: a scene whose fluid all comes from emitters starts with none)
        self.scale = max(above, SCALE_FLOOR * 0.5 * max(total_mass, m.particle_mass) * m.reference_speed ** 2)

    # --- the rule ----------------------------------------------------------------------------
    def growth(self, e: Energy) -> float:
        """(E - E(0) - W - exchanged) / (scale + emitted) [-] (E(0): ``reference_total``; W: the work animated
        obstacles did on the fluid since then; exchanged: the energy emitters brought in minus what sinks took
        out since the reference, emitted: its part above the floor)."""
        flow = getattr(self.sim, "flow", None)
        if flow is None:
            return (e.total - e.work - self.reference_total) / self.scale
        return ((e.total - e.work - self.reference_total - (flow.exchanged - self.exchanged_base))
                / (self.scale + flow.exchanged_scale - self.exchanged_scale_base))

    def limit(self) -> float:
        """The largest allowed (E - E(0)) / scale [-]: allowance / scale + ENERGY_GROWTH_LIMIT."""
        return self.allowance / self.scale + ENERGY_GROWTH_LIMIT

    def check(self) -> tuple[Energy, float, bool]:
        """(energies now, growth, True when the growth is beyond the limit)."""
        if self.stale:
            self.rebase(intended=True)
        e = self.measure()
        g = self.growth(e)
        start = self.unintended > ENERGY_GROWTH_LIMIT * self.scale  # the start holds more than the limit
        return e, g, self.enabled and (start or not g <= self.limit())  # NaN breaks it too

    # --- messages ----------------------------------------------------------------------------
    def account(self, e: Energy) -> str:
        """How much the total rose and where: fluid kinetic, potential and bodies; the rise and the scale as the
        rule counts them (``growth``: the flow's exchanged energy subtracted)."""
        r = self.reference
        parts = [f"kinetic {e.kinetic - r.kinetic:+.3g} J", f"potential {e.potential - r.potential:+.3g} J"]
        if len(e.body_kinetic):
            parts.append(f"bodies {e.bodies - r.bodies:+.3g} J")
        if e.work:
            parts.append(f"work of the animated obstacles {e.work:+.3g} J (subtracted)")
        rise = e.total - e.work - self.reference_total
        scale = self.scale
        flow = getattr(self.sim, "flow", None)
        if flow is not None:  # what the emitters brought in minus what the sinks took out is not a rise
            exchanged = flow.exchanged - self.exchanged_base
            rise -= exchanged
            scale += flow.exchanged_scale - self.exchanged_scale_base
            parts.append(f"exchanged by emitters and sinks {exchanged:+.3g} J (subtracted)")
        text = (f"the total energy rose by {rise:.3g} J = {100 * rise / scale:.3g} % of the scene's energy "
                f"{scale:.4g} J (limit {100 * ENERGY_GROWTH_LIMIT:g} %")
        if self.allowance > 1e-6 * self.scale:
            text += f" beyond the {self.allowance:.3g} J its initial compression can release"
        return text + f"; {', '.join(parts)})"

    def cause(self, e: Energy, dt: float, tight) -> str:
        """The likely cause of an energy rise that the step bound does not explain, with the key to change.
        ``tight``: the tightest ``TimeStepBound`` at the frame's speed."""
        sim, m = self.sim, self.sim.model
        scene, solver = sim.scene, sim.solver
        r = self.reference
        rise = e.total - e.work - self.reference_total
        flow = getattr(sim, "flow", None)
        if flow is not None:  # what the emitters brought in minus what the sinks took out is not a rise (``growth``)
            rise -= flow.exchanged - self.exchanged_base
        # a stage inserted by hand that changes a field (one that only reads cannot add energy)
        added = [s.name for s in sim.graph.stages if s.name not in sim.solver_stage_names and (s.writes or s.updates)]
        if added:
            return (f"stage(s) {', '.join(map(repr, added))} inserted into the step graph by hand may add energy: check "
                    "them first (a stage that puts energy in by design: sim.watchdog.energy.enabled = False)")
        if self.unintended > 0.5 * rise:
            law = solver.equation_of_state()
            keys = [k for k in tight.keys if k != "time.cfl"] or [f"{solver.name}.stiffness"]
            return (f"the fluid starts up to {100 * self.start_compression:.2g} % over its rest density (the sampled "
                    f"lattice's first layers at the walls), and the {law[0] if law else ''} equation of state at "
                    f"c_s = {m.speed_of_sound:.4g} m/s stores {self.unintended:.3g} J = "
                    f"{100 * self.unintended / self.scale:.3g} % of the scene's energy in it, which the run turns into "
                    f"motion; lower {' or '.join(keys)}")
        if len(e.body_kinetic):
            gain = (e.body_kinetic + e.body_potential) - (r.body_kinetic + r.body_potential)
            k = int(np.argmax(gain))
            if gain[k] > 0.5 * rise:
                geo = sim.bodies.geometries[k]
                ratio = geo.density / m.rest_density
                return (f"bodies[{k}] ({sim.bodies.names[k]!r}, {geo.density:.4g} kg/m^3 = {ratio:.3g}x the fluid's "
                        f"density) gained {gain[k]:.3g} J: the fluid-body coupling is explicit, and a body that is light "
                        "against the fluid it moves (added mass) gains energy at every bounce; raise "
                        f"bodies[{k}].density, or lower time.cfl")
        viscous = [b for b in sim.time_step_bounds(0.0) if b.name == "viscous" and math.isfinite(b.seconds)]
        if viscous and dt > 0.5 * viscous[0].seconds:
            b = viscous[0]
            key = b.keys[0] if b.keys else "the viscosity"
            return (f"explicit viscosity ({key}) at dt = {dt:.3g} s, {dt / b.seconds:.2g}x its stable step "
                    f"{b.seconds:.3g} s ({b.formula}): lower {key} or time.cfl, or use "
                    '[[forces]] method = "weiler2018" (implicit viscosity)')
        t = scene.time
        if t.fixed_dt > 0 and dt < 0.1 * tight.seconds:
            return (f"the fixed step time.fixed_dt = {t.fixed_dt:.3g} s is {tight.seconds / dt:.3g}x below the "
                    f"{tight.name} bound {tight.seconds:.3g} s, and the {solver.name} pressure turns each step's "
                    "density error into velocity over that step; set time.fixed_dt = 0 for adaptive steps, or raise "
                    f"it toward {tight.seconds:.3g} s")
        # equal substeps no larger than dt_max fill the frame: dt in (dt_max / 2, dt_max] when it clamps
        if t.fixed_dt == 0 and dt < 0.1 * tight.seconds and dt > 0.5 * t.dt_max * sim.watchdog.dt_scale:
            return (f"time.dt_max = {t.dt_max:.3g} s holds the step {tight.seconds / dt:.3g}x below the {tight.name} bound "
                    f"{tight.seconds:.3g} s, and the {solver.name} pressure turns each step's density error into "
                    f"velocity over that step; raise time.dt_max toward {tight.seconds:.3g} s")
        tolerance = [p.path for p in solver.parameters if p.path.endswith(".target_density_error")]
        cfl = f"time.cfl (now {t.cfl:g})"
        if tolerance:
            key = tolerance[0]
            now = getattr(solver.config, key.split(".", 1)[1])
            return (f"the {solver.name} pressure solve added energy: lower {key} (now {now:g}) or {cfl}")
        keys = [k for k in tight.keys if k != "time.cfl"]
        return (f"the {solver.name} pressure added energy at dt = {dt:.3g} s: lower {cfl}"
                + (f", or check {', '.join(keys)}" if keys else ""))

