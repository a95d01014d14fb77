"""Rigid-body dynamics by Newton (NVIDIA's Warp-based physics engine): the bodies of a scene, the
container and static obstacles as colliders, one call per SPH step with the fluid's wrench.

Solver: ``newton.solvers.SolverSemiImplicit`` (angular_damping = 0) with penalty contacts.
XPBD was rejected: its ``apply_body_deltas`` sets every |v| < 1e-4 m/s and |omega| < 1e-4 rad/s to
zero after each correction of a body with a joint or contact (every ``add_body`` body), so a body
whose net acceleration times the SPH step is below 1e-4 m/s never starts to move (at dt = 2e-4 s:
any a < 0.5 m/s^2, e.g. a near-neutral body or a slow current; notes/rigid_newton.md section 3).
Featherstone has no clamp either but costs more per step and integrates joint coordinates.

Contacts (penalty springs): after each collision detection ``kernels/rigid.py``
``pair_contact_properties`` writes every contact point's stiffness k = mu w^2 [N/m] and damping
c = mu w [N s/m] from the reduced mass mu = 1/(1/m_a + 1/m_b) of the two bodies (a static shape adds
nothing), w = ``contact_frequency`` [rad/s], into Newton's per-contact arrays (``Contacts.
rigid_contact_stiffness/damping``, which SolverSemiImplicit prefers over the shapes' averaged ke, kd):
each pair vibrates at w with damping ratio 0.5 per contact point whatever the masses, and a body
resting on a wall sinks in by about g / w^2. The shapes' own ke, kd (used only if a contact were
left without a value) are mass-scaled likewise; the friction gain kf = m_min w on every contact
(m_min the lightest body: the viscous friction regime stays stable for it), and mu is one value for
every shape (``contact_friction``), so Newton's average gives exactly it.

Sub-steps: explicit penalty contacts are stable while the damping rate times the step stays below
2; with up to n = 4 contact points per pair the rate is n w, so the rigid step is at most
1 / (4 w) (a factor 2 of margin). ``step(dt)`` runs ceil(dt / max_substep) equal Newton steps with
the same wrench; collision detection runs once per call, with a detection gap ``contact_gap`` [m]
that must cover how far bodies move during one call (contact points are stored in body frames, so
the penalty depth is re-evaluated at every sub-step).

Frames: the world works in the coordinates it is given (the simulation passes local ones, the
Model's origin subtracted, so float32 keeps its precision); ``origin`` is added back by the
readouts that say so. Newton is Z-up; gravity is any vector.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.errors import SceneError
from ..core.launch import launch
from ..kernels import rigid as _rigid
from ..scene.meshes import TriangleMesh, load_triangle_mesh
from .spec import Body, BodyGeometry, body_geometry, body_name, quat_to_matrix, rotation_quaternion

#: the verified Newton release (pyproject's [rigid] extra pins it)
NEWTON_VERSION = "1.8.0"
INSTALL_HINT = "pip install 'warp-sph[rigid]' (in a source checkout: pip install -e '.[rigid]')"
#: contact points per body pair assumed by the sub-step bound
CONTACT_POINTS = 4
#: mesh-triangle candidate pairs per collision pass (Newton's own estimate is at least 10^6: with the
#: shipped cylinder obstacle 467 MB peak memory against 399 MB with this cap)
MAX_TRIANGLE_PAIRS = 8192


def require_newton():
    """The ``newton`` module, or a one-line SceneError naming ``bodies`` and the install command."""
    try:
        import newton
    except ImportError:
        raise SceneError(f"bodies: moving rigid bodies need the Newton physics engine, which is not "
                         f"installed; install it with: {INSTALL_HINT}") from None
    except Exception as exc:  # noqa: BLE001 - a broken install (e.g. a warp-lang it does not support)
        reason = " ".join(str(exc).split())[:120]
        raise SceneError(f"bodies: the Newton physics engine does not load ({reason}); reinstall it with: "
                         f"{INSTALL_HINT}") from None
    return newton


def contact_frequency_for(particle_radius: float, gravity=(0.0, 0.0, -9.81)) -> float:
    """Default contact frequency w [rad/s]: a body resting on a wall sinks into it by g / w^2 =
    1 % of the particle radius r (w = sqrt(|g| / (0.01 r)); |g| = 9.81 m/s^2 without gravity):
    r = 0.01 m gives 313 rad/s."""
    g = float(np.linalg.norm(gravity)) or 9.81
    return math.sqrt(g / (0.01 * float(particle_radius)))


@dataclass(frozen=True)
class StaticCollider:
    """A static shape bodies collide with: ``kind`` "box" (lo, hi [m]) or "mesh" (a TriangleMesh [m]),
    in world coordinates."""

    kind: str
    lo: tuple | None = None
    hi: tuple | None = None
    mesh: TriangleMesh | None = None


def static_colliders(scene) -> list[StaticCollider]:
    """The scene's obstacles as colliders (the container is passed separately, as planes)."""
    out = []
    for ob in scene.obstacles:
        if ob.shape == "box":
            out.append(StaticCollider("box", tuple(ob.min), tuple(ob.max)))
        elif ob.shape == "sphere":
            from ..scene.sphere_obstacle import sphere_triangle_mesh

            out.append(StaticCollider("mesh", mesh=sphere_triangle_mesh(ob)))
        else:
            mesh = load_triangle_mesh(ob.file).transformed(ob.scale, ob.translate)
            out.append(StaticCollider("mesh", mesh=mesh))
    return out


def _quat_from_z(normal) -> wp.quat:
    """Rotation taking +z to the unit axis ``normal`` (exact for the six axis directions)."""
    n = np.asarray(normal, dtype=np.float64)
    if n[2] < -0.5:
        return wp.quat(1.0, 0.0, 0.0, 0.0)  # 180 degrees about x (quat_between_vectors is degenerate here)
    return wp.quat_between_vectors(wp.vec3(0.0, 0.0, 1.0), wp.vec3(*n))


class RigidWorld:
    """Newton model, solver and states for a scene's bodies.

    Args:
        bodies: the scene's ``Body`` entries, in order (body k is Newton body k).
        geometries: their ``BodyGeometry`` (default: ``body_geometry(body)``).
        gravity: [m/s^2].
        container: (lo, hi) corners [m] of the closed container box (six static planes, inward), or None.
        obstacles: static colliders (boxes and meshes) [m].
        origin: the simulation's local origin [m]; every position given here is world and is
            stepped as world - origin.
        contact_frequency: w [rad/s] of the penalty contacts (see the module docstring).
        contact_gap: contact detection distance [m] (>= the distance a body moves in one ``step``).
        contact_friction: Coulomb friction mu [-] of every contact.
        device: Warp device.
    """

    def __init__(self, bodies: Sequence[Body], geometries: Sequence[BodyGeometry] | None = None, *,
                 gravity=(0.0, 0.0, -9.81), container=None, obstacles: Sequence[StaticCollider] = (),
                 origin=(0.0, 0.0, 0.0), contact_frequency: float = 300.0, contact_gap: float = 0.02,
                 contact_friction: float = 0.5, device=None):
        newton = require_newton()
        if not contact_frequency > 0.0 or not contact_gap > 0.0 or not contact_friction >= 0.0:
            raise ValueError(f"contact_frequency and contact_gap must be > 0 and contact_friction >= 0; got "
                             f"{contact_frequency}, {contact_gap}, {contact_friction}")
        self.device = wp.get_device(device)
        self.origin = np.asarray(origin, dtype=np.float64).reshape(3)
        self.names = [body_name(b, i) for i, b in enumerate(bodies)]
        self.geometries = list(geometries) if geometries is not None else [body_geometry(b) for b in bodies]
        self.contact_frequency = float(contact_frequency)
        self.contact_gap = float(contact_gap)
        self.contact_friction = float(contact_friction)
        w = self.contact_frequency
        builder = newton.ModelBuilder(gravity=tuple(float(g) for g in gravity))
        builder.rigid_gap = self.contact_gap
        Cfg = newton.ModelBuilder.ShapeConfig
        static = Cfg(density=0.0, ke=0.0, kd=0.0, kf=0.0, mu=self.contact_friction, gap=self.contact_gap)
        if container is not None:
            lo = np.asarray(container[0], dtype=np.float64) - self.origin
            hi = np.asarray(container[1], dtype=np.float64) - self.origin
            for axis in range(3):
                for sign, corner in ((1.0, lo), (-1.0, hi)):
                    n = np.zeros(3)
                    n[axis] = sign
                    p = np.zeros(3)
                    p[axis] = corner[axis]
                    builder.add_shape_plane(xform=wp.transform(wp.vec3(*p), _quat_from_z(n)), width=0.0,
                                            length=0.0, cfg=static)
        for ob in obstacles:
            if ob.kind == "box":
                lo = np.asarray(ob.lo, dtype=np.float64) - self.origin
                hi = np.asarray(ob.hi, dtype=np.float64) - self.origin
                c, h = 0.5 * (lo + hi), 0.5 * (hi - lo)
                builder.add_shape_box(-1, xform=wp.transform(wp.vec3(*c), wp.quat_identity()),
                                      hx=float(h[0]), hy=float(h[1]), hz=float(h[2]), cfg=static)
            elif ob.kind == "mesh":
                verts = (ob.mesh.vertices - self.origin).astype(np.float32)
                mesh = newton.Mesh(verts, ob.mesh.triangles.astype(np.int32).reshape(-1), compute_inertia=False)
                builder.add_shape_mesh(-1, mesh=mesh, cfg=static)
            else:
                raise ValueError(f"static collider kind {ob.kind!r}: expected 'box' or 'mesh'")
        self.masses = np.array([g.mass for g in self.geometries], dtype=np.float64)
        kf = float(self.masses.min()) * w if len(self.masses) else 0.0
        for body, geo, name in zip(bodies, self.geometries, self.names):
            p = np.asarray(body.position, dtype=np.float64) - self.origin
            q = rotation_quaternion(body.rotation)
            k = builder.add_body(xform=wp.transform(wp.vec3(*p), wp.quat(*q)), label=name)
            m = geo.mass
            cfg = Cfg(density=geo.density, ke=2.0 * m * w * w, kd=2.0 * m * w, kf=2.0 * kf,
                      mu=self.contact_friction, gap=self.contact_gap)
            if geo.shape == "box":
                h = geo.half_extents
                builder.add_shape_box(k, hx=float(h[0]), hy=float(h[1]), hz=float(h[2]), cfg=cfg)
            elif geo.shape == "sphere":
                builder.add_shape_sphere(k, radius=float(geo.radius), cfg=cfg)
            else:
                mesh = newton.Mesh(geo.vertices.astype(np.float32), geo.triangles.astype(np.int32).reshape(-1))
                builder.add_shape_convex_hull(k, mesh=mesh, cfg=cfg)
        self.model = builder.finalize(device=self.device)
        self.body_count = len(self.names)
        self.solver = newton.solvers.SolverSemiImplicit(self.model, angular_damping=0.0)
        self.pipeline = newton.CollisionPipeline(self.model, deterministic=not self.device.is_cpu,
                                                 max_triangle_pairs=MAX_TRIANGLE_PAIRS)
        self.contacts = self.pipeline.contacts()
        if self.contacts.rigid_contact_stiffness is None:  # per-contact values (see the module docstring)
            n_max = self.contacts.rigid_contact_max
            self.contacts.rigid_contact_stiffness = wp.zeros(n_max, dtype=float, device=self.device)
            self.contacts.rigid_contact_damping = wp.zeros(n_max, dtype=float, device=self.device)
            self.contacts.rigid_contact_friction = wp.zeros(n_max, dtype=float, device=self.device)  # 0: shape mu
        self.control = self.model.control()
        self.state = self.model.state()
        self._next = self.model.state()
        self._primary = self.state  # after every step the current state is this object again
        qd = np.zeros((self.body_count, 6), dtype=np.float32)
        for k, body in enumerate(bodies):
            qd[k, :3] = body.velocity
            qd[k, 3:] = body.angular_velocity
        self.state.body_qd.assign(qd)
        self._zero_wrench = wp.zeros(self.body_count, dtype=wp.spatial_vector, device=self.device)
        self.max_substep = self._max_substep()
        self.steps = 0
        self.substeps = 0
        self.detections = 0  # collision detections so far

    def _max_substep(self) -> float:
        """Largest stable Newton step [s] (module docstring): 1 / (CONTACT_POINTS w)."""
        return 1.0 / (CONTACT_POINTS * self.contact_frequency)

    # --- the arrays coupling kernels read (the same objects after every ``step``) -------------------
    @property
    def body_q(self) -> wp.array:
        """Poses of the body origins (= centres of mass), (p [m], q xyzw), local frame."""
        return self.state.body_q

    @property
    def body_qd(self) -> wp.array:
        """(v of the centre of mass [m/s], omega [rad/s]), world axes."""
        return self.state.body_qd

    @property
    def body_com(self) -> wp.array:
        """Centres of mass in the body frames [m] (0 for every shape built here)."""
        return self.model.body_com

    # --- stepping ---------------------------------------------------------------------------
    def substeps_for(self, dt: float) -> int:
        """Newton steps per ``step(dt)``."""
        return max(1, math.ceil(dt / self.max_substep - 1e-9))

    def step(self, dt: float, body_f: wp.array | None = None, detect: bool = True) -> None:
        """Advance dt [s] under gravity, contacts and the external wrench ``body_f`` (per body
        (F [N], tau [N m]), world frame, torque about the centre of mass; None: no wrench), held
        constant over ``substeps_for(dt)`` equal Newton steps; contacts are detected once, or (``detect``
        False) the last detection's contacts are kept: their points live in the body frames, so their
        depths follow the bodies, and they hold every pair that was within ``contact_gap`` then (the
        caller keeps the motion since that detection below the gap)."""
        if self.body_count == 0:
            return
        wrench = self._zero_wrench if body_f is None else body_f
        n = self.substeps_for(dt)
        h = dt / n
        if detect or not self.detections:
            self.pipeline.collide(self.state, self.contacts)
            c = self.contacts
            launch(_rigid.pair_contact_properties, c.rigid_contact_max,
                   [self.contact_frequency, self.model.shape_body, self.model.body_inv_mass, c.rigid_contact_count,
                    c.rigid_contact_shape0, c.rigid_contact_shape1], [c.rigid_contact_stiffness, c.rigid_contact_damping],
                   device=self.device)
            self.detections += 1
        for _ in range(n):
            wp.copy(self.state.body_f, wrench)
            self.solver.step(self.state, self._next, self.control, self.contacts, h)
            self.state, self._next = self._next, self.state
        if self.state is not self._primary:  # keep the arrays a caller holds (``body_q`` ...) current
            self._primary.assign(self.state)
            self.state, self._next = self._primary, self.state
        self.steps += 1
        self.substeps += n

    # --- readouts (host copies; once per frame) -----------------------------------------------
    def poses(self) -> dict[str, np.ndarray]:
        """World-frame state per body: ``position`` of the centre of mass [m] (float64), ``orientation``
        quaternion (x, y, z, w), ``velocity`` [m/s], ``angular_velocity`` [rad/s]."""
        q = self.state.body_q.numpy().astype(np.float64)
        qd = self.state.body_qd.numpy().astype(np.float64)
        com = self.model.body_com.numpy().astype(np.float64)
        pos = np.array([q[k, :3] + quat_to_matrix(q[k, 3:]) @ com[k] for k in range(self.body_count)]).reshape(-1, 3)
        return {"position": pos + self.origin, "orientation": q[:, 3:7], "velocity": qd[:, :3],
                "angular_velocity": qd[:, 3:6]}

    def energy(self, gravity) -> tuple[np.ndarray, np.ndarray]:
        """Per body (kinetic, potential) energy [J], float64: M |v|^2 / 2 + w.(R I R^T w) / 2 (I the inertia
        about the centre of mass in the body frame) and -M g.x_com, x_com in the coordinates the world steps
        (local: ``origin`` not added)."""
        q = self.state.body_q.numpy().astype(np.float64)
        qd = self.state.body_qd.numpy().astype(np.float64)
        com = self.model.body_com.numpy().astype(np.float64)
        inertia = self.model.body_inertia.numpy().astype(np.float64).reshape(-1, 3, 3)
        g = np.asarray(gravity, dtype=np.float64)
        kinetic, potential = np.zeros(self.body_count), np.zeros(self.body_count)
        for k in range(self.body_count):
            R = quat_to_matrix(q[k, 3:7])
            w = qd[k, 3:6]
            kinetic[k] = 0.5 * self.masses[k] * float(qd[k, :3] @ qd[k, :3]) + 0.5 * float(w @ (R @ inertia[k] @ R.T) @ w)
            potential[k] = -self.masses[k] * float(g @ (q[k, :3] + R @ com[k]))
        return kinetic, potential

    def momentum(self) -> np.ndarray:
        """Total linear momentum of the bodies sum m v [kg m/s] (float64)."""
        qd = self.state.body_qd.numpy().astype(np.float64)
        return (self.masses[:, None] * qd[:, :3]).sum(axis=0)

    # --- checkpoints --------------------------------------------------------------------------
    def state_arrays(self) -> dict[str, np.ndarray]:
        """Every array of the current Newton state (body_q, body_qd, body_f, joint_q, joint_qd, ...) as
        NumPy copies, plus the step counters: what a checkpoint stores for a bitwise resume."""
        out = {name: a.numpy().copy() for name, a in vars(self.state).items() if isinstance(a, wp.array)}
        out["counters"] = np.array([self.steps, self.substeps], dtype=np.int64)
        return out

    def load_state_arrays(self, arrays: dict[str, np.ndarray]) -> None:
        """Restore ``state_arrays()`` output (shapes checked); the next ``step`` continues bitwise as the
        saved run did (on the CPU)."""
        for name, a in vars(self.state).items():
            if not isinstance(a, wp.array):
                continue
            if name not in arrays or arrays[name].shape != a.numpy().shape:
                raise ValueError(f"rigid-body checkpoint: array {name!r} missing or of another shape")
            a.assign(np.ascontiguousarray(arrays[name]))
        if "counters" in arrays:
            self.steps, self.substeps = (int(v) for v in arrays["counters"])
