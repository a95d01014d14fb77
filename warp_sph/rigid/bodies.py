"""The rigid bodies of a running simulation (``sim.bodies``): Newton world, moving boundary particles,
and the two stages that couple them to the fluid every substep (Akinci et al. 2012, weak coupling as
SPlisHSPlasH does it):

1. ``body_forces``, right after the solver's ``body_coupling_after`` stage: the fluid's force on each
   moving boundary particle, F_b = -sum_i m [pressure(grad W_ib, V_b, term_i) + force(x_ib, v_ib, ...)]
   (``kernels/rigid.py``), the exact negative of what the boundary terms gave the fluid for each pair.
2. ``bodies``, after the solver's last stage: the forces summed on the device into one wrench per
   body (force, torque about the centre of mass), Newton's step under that wrench, gravity and
   contacts (``RigidWorld``; collision detection at a cadence, ``plan_frame``), the particles placed
   at the new poses with their rigid velocities, and the moving particles' cell grid and mask
   rebuilt (``NeighborLists.update_moving``).

The fluid of the next substep sees the bodies where this substep left them (weak coupling).
Workspace fields: ``body_q`` (poses, Newton's layout), ``body_qd`` (COM velocity, angular velocity),
``body_f`` (the fluid's wrench of the last substep [N, N m]), ``body_particle_force`` [N],
``boundary_v`` [m/s] and ``moving_boundary_grid``.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ..core.errors import SceneError
from ..core.step_graph import Stage
from .coupling import BodyParticles, boundary_force_stage, insert_coupling_stages
from .spec import body_name
from .world import RigidWorld, contact_frequency_for, static_colliders

#: detection gap of Newton's contacts in particle spacings d: covers the motion of one substep (the CFL
#: bounds v dt <= cfl d with the body speeds included)
CONTACT_GAP_SPACINGS = 2.0


class SimulationBodies:
    """Rigid bodies of ``sim`` (built by the Simulation when the scene has ``[[bodies]]``)."""

    def __init__(self, sim):
        scene, m = sim.scene, sim.model
        sampled = sim.sampled
        self.sim = sim
        self.names = [body_name(b, i) for i, b in enumerate(scene.bodies)]
        self.geometries = list(sampled.body_geometries)
        w = float(scene.rigid.contact_frequency) or contact_frequency_for(m.particle_radius, m.gravity)
        container = None if scene.container is None else (scene.container.min, scene.container.max)
        self.world = RigidWorld(scene.bodies, self.geometries, gravity=tuple(float(g) for g in m.gravity),
                                container=container, obstacles=static_colliders(scene), origin=m.origin,
                                contact_frequency=w, contact_gap=CONTACT_GAP_SPACINGS * m.spacing,
                                contact_friction=float(scene.rigid.contact_friction), device=m.device)
        self.particles = BodyParticles(sampled.body_samples, start=m.static_boundary_count, device=m.device)
        self.count = self.particles.count
        # farthest particle from each centre of mass [m] (for the speed bound |v| + |omega| reach)
        self.reach = np.array([float(np.max(np.linalg.norm(s.local_x, axis=1))) if s.count else 0.0
                               for s in sampled.body_samples])
        self.force = wp.zeros(max(self.count, 1), dtype=wp.vec3, device=m.device)
        self.wrench = wp.zeros(self.world.body_count, dtype=wp.spatial_vector, device=m.device)
        sim.fields.update(body_q=self.world.body_q, body_qd=self.world.body_qd, body_f=self.wrench,
                          body_particle_force=self.force, boundary_v=m.boundary_v)
        self.inputs = {"body_q", "body_qd", "boundary_v", "moving_boundary_grid"}
        #: Newton's collision detection runs every this many substeps (``plan_frame``; 1 outside frames)
        self.detect_every = 1
        self._since = 1
        #: fields that are not one value per fluid particle (never sorted into cell order)
        self.unsorted = {"body_particle_force", "boundary_v"}
        self.place()

    # --- graph ---------------------------------------------------------------------------------
    def check_solver(self, solver) -> None:
        """Refuse a solver variant that cannot move bodies (SceneError, one line)."""
        if solver.body_coupling_after is None:
            raise SceneError(solver.refuses_bodies(type(self.sim.boundary)))
        if not getattr(solver, "lists", True):
            raise SceneError(f"bodies: the {solver.name} solver's hash-grid variant (lists=False) cannot move bodies; "
                             "use its neighbour-list variant (the default)")

    def insert_stages(self, stages: list[Stage], solver) -> list[Stage]:
        """The solver's stages with ``body_forces`` after its coupling stage and ``bodies`` at the end."""
        self.check_solver(solver)
        return insert_coupling_stages(stages, solver, self.force_stage, self.motion_stage, "bodies")

    def force_stage(self, velocity: str = "particle_v") -> Stage:
        """The gather stage; ``velocity``: the workspace field of the fluid velocities the boundary force
        term was evaluated with (``Solver.body_coupling_velocity``)."""
        m = self.sim.model
        return boundary_force_stage(self.sim, "body_forces", m.static_boundary_count, self.count, self.force,
                                    "body_particle_force", velocity=velocity,
                                    doc=f"the fluid's force on {self.count} moving boundary particles: the negative "
                                        f"of the {self.sim.boundary_terms.name} boundary terms, pair by pair "
                                        "(Akinci et al. 2012)")

    def motion_stage(self) -> Stage:
        def run(sim, dt):
            self.step(dt)

        return Stage("bodies", run, reads=("body_particle_force",),
                     writes=("body_f",), updates=("body_q", "body_qd", "boundary_x", "boundary_v", "moving_boundary_grid"),
                     doc=f"{len(self.names)} bodies: wrench (force, torque about the centre of mass) summed in a fixed "
                         f"order -> Newton SolverSemiImplicit (contacts at w = {self.world.contact_frequency:.4g} rad/s, "
                         f"steps <= {self.world.max_substep:.3g} s; detected while no body can have moved half the gap "
                         f"{self.world.contact_gap:.3g} m) -> boundary particles placed -> their cells rebuilt")

    # --- stepping --------------------------------------------------------------------------------
    def plan_frame(self, dt: float, speed: float) -> None:
        """Collision detection for a frame of substeps dt [s] that starts at the largest speed ``speed``
        [m/s] (fluid or body): at the frame's first substep, then every ``detect_every`` substeps, so that
        no body moves more than half the detection gap between two detections: detect_every =
        floor(gap / 2 / (v dt)) with the speed bound v = 2 speed + |g| frame_dt (a body at most doubles
        the frame's top speed, or falls for a frame). WCSPH (dt ~ 0.04 d / v at c_s = 10 v) detects about
        every 12 substeps, PBF about every substep. Every frame starts with a detection, so a resume or a
        retried frame replays bit for bit."""
        g = float(np.linalg.norm(self.sim.model.gravity))
        v = 2.0 * float(speed) + g * self.sim.frame_dt
        self.detect_every = max(1, int(0.5 * self.world.contact_gap / max(v * float(dt), 1e-30)))
        self._since = self.detect_every

    def step(self, dt: float) -> None:
        """Wrench from ``body_particle_force``, Newton step of dt [s], particles placed at the new poses."""
        m = self.sim.model
        self.particles.wrench(self.world.body_q, self.world.body_com, m.boundary_x, self.force, self.wrench)
        detect = self._since >= self.detect_every
        self._since = 1 if detect else self._since + 1
        self.world.step(dt, self.wrench, detect=detect)
        self.place()

    def place(self) -> None:
        """Moving boundary particles (x, v) from the bodies' current poses; their cell grid rebuilt."""
        m = self.sim.model
        self.particles.place(self.world.body_q, self.world.body_qd, self.world.body_com, m.boundary_x, m.boundary_v)
        lists = self.sim.fields.get("neighbor_lists")
        if lists is not None:
            lists.update_moving(m.boundary_x)
            self.sim.fields["moving_boundary_grid"] = lists.moving_cells
        else:
            self.sim.fields.setdefault("moving_boundary_grid", None)

    # --- host reads (once per frame) -------------------------------------------------------------
    def max_speed(self, qd: np.ndarray | None = None) -> float:
        """Largest speed of a body's boundary particle bound, max_k |v_k| + |omega_k| reach_k [m/s]."""
        qd = self.world.body_qd.numpy().astype(np.float64) if qd is None else qd
        if not len(qd):
            return 0.0
        return float(np.max(np.linalg.norm(qd[:, :3], axis=1) + np.linalg.norm(qd[:, 3:], axis=1) * self.reach))

    def frame_record(self) -> tuple[dict, float]:
        """({name: pose, velocities and the fluid's last wrench}, max speed) for run.json: position of
        the centre of mass [m] (world), orientation quaternion (x, y, z, w), velocity [m/s], angular
        velocity [rad/s] (world axes), fluid_force [N] and fluid_torque [N m] (about the centre of mass)
        of the frame's last substep."""
        poses = self.world.poses()
        f = self.wrench.numpy().astype(np.float64)
        out = {}
        for k, name in enumerate(self.names):
            out[name] = {"position": poses["position"][k].tolist(), "orientation": poses["orientation"][k].tolist(),
                         "velocity": poses["velocity"][k].tolist(),
                         "angular_velocity": poses["angular_velocity"][k].tolist(),
                         "fluid_force": f[k, :3].tolist(), "fluid_torque": f[k, 3:].tolist()}
        qd = np.concatenate([poses["velocity"], poses["angular_velocity"]], axis=1)
        return out, self.max_speed(qd)

    def energy(self) -> tuple[np.ndarray, np.ndarray]:
        """Per body (kinetic, potential) energy [J] in the simulation's local frame (``RigidWorld.energy``), for
        the energy watchdog."""
        return self.world.energy(self.sim.model.gravity)

    def export_poses(self) -> dict:
        """{name: (centre of mass [m] world (3,), quaternion (x, y, z, w))} for the USD writer."""
        poses = self.world.poses()
        return {name: (poses["position"][k], poses["orientation"][k]) for k, name in enumerate(self.names)}

    # --- checkpoints, frame retries ----------------------------------------------------------------
    def checkpoint_arrays(self) -> dict[str, np.ndarray]:
        """Newton's state arrays (``RigidWorld.state_arrays``) under keys ``rigid_<name>``."""
        return {f"rigid_{k}": v for k, v in self.world.state_arrays().items()}

    def restore_arrays(self, arrays) -> None:
        """Restore ``checkpoint_arrays`` and place the particles (bitwise the saved state)."""
        state = {k[len("rigid_"):]: np.asarray(arrays[k]) for k in arrays if str(k).startswith("rigid_")}
        if not state:
            raise SceneError("bodies: the checkpoint holds no rigid-body state (written by a run without bodies?)")
        self.world.load_state_arrays(state)
        self._since = self.detect_every
        self.place()

    def save(self) -> dict:
        """Device copies of the world state at a frame start (the watchdog's retry)."""
        return {name: wp.clone(a) for name, a in vars(self.world.state).items() if isinstance(a, wp.array)} | {
            "_counters": (self.world.steps, self.world.substeps)}

    def restore(self, saved: dict) -> None:
        for name, a in vars(self.world.state).items():
            if isinstance(a, wp.array):
                wp.copy(a, saved[name])
        self.world.steps, self.world.substeps = saved["_counters"]
        self._since = self.detect_every  # the next substep detects contacts again
        self.place()

    def summary(self) -> dict:
        """Constants for run.json (``model.bodies``)."""
        return {"count": len(self.names), "names": self.names, "boundary_particles": self.count,
                "masses": [float(g.mass) for g in self.geometries], "volumes": [float(g.volume) for g in self.geometries],
                "contact_frequency": self.world.contact_frequency, "contact_gap": self.world.contact_gap,
                "contact_friction": self.world.contact_friction, "max_newton_step": self.world.max_substep}
