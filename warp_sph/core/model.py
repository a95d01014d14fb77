"""Model (constant during a run) and State (what a checkpoint needs), built from a scene.

Positions on the device are relative to a local origin (the centre of the container, or of the
fluid when there is none), so float32 keeps its precision wherever the scene sits; exports add
the origin back (float64 on the host).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from .errors import SceneError
from ..kernels import density as _density_dev
from ..neighbors import NeighborGrid
from .launch import launch
from .smoothing import LATTICE_LAYER, SmoothingKernel, calibrated_mass, get_smoothing_kernel, lattice_sum


@dataclass
class Model:
    """Everything constant during a run. Lengths [m], densities [kg/m^3], times [s]."""

    device: object
    smoothing: SmoothingKernel
    rest_density: float           # rho0 [kg/m^3]
    particle_radius: float        # r [m]
    spacing: float                # d = 2r [m]
    smoothing_length: float       # h [m]
    support_radius: float         # H_s = kappa h [m], also the neighbour search radius
    particle_mass: float          # m [kg], calibrated: m sum_lattice W = rho0
    lattice_bias: float           # d^3 sum_lattice W - 1 before calibration [-]
    gravity: np.ndarray           # g [m/s^2], shape (3,)
    origin: np.ndarray            # local origin [m], float64 shape (3,)
    reference_speed: float        # expected max speed max(sqrt(2 |g| H), |v0|) [m/s]
    reference_speed_source: str   # what set it: the fall height or a block's initial velocity
    speed_of_sound: float         # c_s [m/s]: WCSPH's stiffness, the Akinci friction and the penalty force
    boundary_friction: float      # Akinci sigma [-]
    boundary_method: str          # the scene's boundary method, "none" without boundary particles
    boundary_x: wp.array          # boundary particle positions (local) [m], shape (boundary_count,)
    boundary_v: wp.array          # boundary particle velocities [m/s] (0: static walls), shape (boundary_count,)
    boundary_volume: wp.array     # Akinci V_b = 1/sum_k W_bk [m^3], shape (boundary_count,)
    boundary_grid: NeighborGrid | None  # hash grid over the static boundary particles
    container_lo: np.ndarray | None  # container box in local coordinates [m]
    container_hi: np.ndarray | None
    fluid_count: int
    boundary_count: int
    #: boundary particles [0, static_boundary_count) are walls and obstacles (they never move); the rest,
    #: [static_boundary_count, boundary_count), belong to moving rigid bodies, body after body
    static_boundary_count: int = 0
    boundary_body: wp.array | None = None  # per boundary particle: -1 static, else the body index [-]
    #: Akinci sigma per boundary particle [-] when a body has its own ``fluid_friction`` (else None: every
    #: particle has ``boundary_friction``)
    boundary_particle_friction: wp.array | None = None
    max_boundary_friction: float = -1.0  # the largest sigma of any boundary particle [-] (< 0: boundary_friction)
    #: particles the per-particle arrays hold (``warp_sph.run.emission``): fluid_count, the active particles,
    #: changes with emitters and sinks and is at most this; 0: fluid_count
    capacity: int = 0

    def __post_init__(self):
        self.capacity = max(int(self.capacity), int(self.fluid_count))
        if self.max_boundary_friction < 0.0:
            self.max_boundary_friction = self.boundary_friction

    @property
    def boundary_grid_id(self):
        return self.boundary_grid.id if self.boundary_grid is not None else wp.uint64(0)

    def to_local(self, x: np.ndarray) -> np.ndarray:
        return (np.asarray(x, dtype=np.float64) - self.origin).astype(np.float32)

    def to_world(self, x: np.ndarray) -> np.ndarray:
        return (np.asarray(x, dtype=np.float64) + self.origin)

    def summary(self) -> dict:
        return {
            "smoothing_kernel": self.smoothing.name,
            "rest_density": self.rest_density,
            "particle_radius": self.particle_radius,
            "spacing": self.spacing,
            "smoothing_length": self.smoothing_length,
            "support_radius": self.support_radius,
            "particle_mass": self.particle_mass,
            "lattice_bias_before_calibration": self.lattice_bias,
            "speed_of_sound": self.speed_of_sound,
            "reference_speed": self.reference_speed,
            "boundary_method": self.boundary_method,
            "origin": [float(v) for v in self.origin],
            "fluid_count": self.fluid_count,
            "boundary_count": self.boundary_count,
        }


@dataclass
class State:
    """What changes during a run: positions (local) [m], velocities [m/s], time [s], step count."""

    particle_x: wp.array
    particle_v: wp.array
    time: float = 0.0
    step: int = 0
    frame: int = 0


def _body_speeds(scene, body_x: np.ndarray) -> tuple[np.ndarray, float, int]:
    """(the body particles' world positions (K, 3) [m], the largest initial speed of a body particle
    bound |v| + |omega| max|x - x_com| [m/s], the index of that body)."""
    if not len(body_x) or not scene.bodies:
        return np.zeros((0, 3)), 0.0, -1
    speeds = []
    for body in scene.bodies:
        v = np.asarray(body.velocity, dtype=np.float64)
        w = np.asarray(body.angular_velocity, dtype=np.float64)
        c = np.asarray(body.position, dtype=np.float64)
        reach = float(np.max(np.linalg.norm(body_x - c, axis=1)))  # generous: every particle's distance
        speeds.append(float(np.linalg.norm(v)) + float(np.linalg.norm(w)) * reach)
    return body_x, max(speeds), int(np.argmax(speeds))


def _speed_of_sound(scene, fluid_x: np.ndarray, fluid_v: np.ndarray, container_lo,
                    fluid_block: np.ndarray | None = None, body_x: np.ndarray | None = None,
                    driven_speed: float = 0.0) -> tuple[float, float, str]:
    """(reference speed, c_s, what set v_ref): v_ref = max(sqrt(2 |g| H), max|v0|), H the height of the fluid above the
    container floor (or the fluid's own height). c_s, the fluid's (artificial) speed of sound, comes from
    the ``wcsph`` section: sqrt(k / rho0) (linear) or sqrt(7 B / rho0) (Tait) when ``wcsph.stiffness`` is
    set, else ``wcsph.speed_of_sound``, else factor * v_ref (Becker & Teschner 2007: |drho|/rho0 ~
    v^2/c^2, so factor 10 keeps density errors near 1 %). WCSPH's pressure, the Akinci friction
    (report eq. 24) and the penalty force scale with it. Moving bodies (``body_x``: their particles at
    t = 0 [m]) count as fluid for H (a body falls into the pool) and with their initial speeds; animated
    obstacles with ``driven_speed``, their top speed over the run [m/s]."""
    body_x, body_speed, fastest = _body_speeds(scene, np.zeros((0, 3)) if body_x is None else body_x)
    g = np.asarray(scene.gravity, dtype=np.float64)
    gnorm = float(np.linalg.norm(g))
    if gnorm > 0 and len(fluid_x):
        up = -g / gnorm
        heights = np.concatenate([fluid_x.astype(np.float64), body_x]) @ up
        floor = heights.min()
        if container_lo is not None:
            corners = np.array([[a, b, c] for a in (container_lo[0], scene.container.max[0])
                                for b in (container_lo[1], scene.container.max[1])
                                for c in (container_lo[2], scene.container.max[2])])
            floor = min(floor, (corners @ up).min())
        height = heights.max() - floor + scene.particle_radius
    else:
        height = float(np.ptp(fluid_x[:, 2])) + 2 * scene.particle_radius if len(fluid_x) else 1.0
    g_ref = gnorm if gnorm > 0 else 9.81
    fall = math.sqrt(2.0 * g_ref * height)
    speeds = np.linalg.norm(fluid_v.astype(np.float64), axis=1) if len(fluid_v) else np.zeros(1)
    v_ref = max(fall, float(speeds.max()), body_speed, driven_speed)
    if driven_speed > max(fall, float(speeds.max()), body_speed):
        source = "the animated obstacles' top speed"
    elif body_speed > max(fall, float(speeds.max())):
        source = f"bodies[{fastest}].velocity"
    elif v_ref > fall:
        k = int(np.argmax(speeds))
        block = int(fluid_block[k]) if fluid_block is not None and len(fluid_block) > k else 0
        source = f"fluid[{block}].velocity"
    else:
        source = f"the fall height H = {height:.3g} m (sqrt(2 g H))"
    w = scene.sections.get("wcsph")
    rho0 = float(scene.material.rest_density)
    if w is not None and w.stiffness > 0:
        c_s = math.sqrt((7.0 if w.equation_of_state == "tait" else 1.0) * float(w.stiffness) / rho0)
    elif w is not None and w.speed_of_sound > 0:
        c_s = float(w.speed_of_sound)
    else:
        c_s = (w.speed_of_sound_factor if w is not None else 10.0) * v_ref
    return v_ref, c_s, source


def fluid_lattice(scene) -> str:
    """The fluid's start lattice: the blocks' ``fluid[].lattice`` (sampling refuses a mix), "cubic" without blocks."""
    names = sorted({str(b.lattice) for b in scene.fluid})
    return names[0] if names else "cubic"


def build_model(scene, sampled, device) -> tuple[Model, State]:
    """Model and initial State from a validated Scene and its SampledScene."""
    kernel = get_smoothing_kernel(scene.smoothing_kernel)
    r = float(scene.particle_radius)
    d = 2.0 * r
    h = scene.smoothing_length
    support = scene.support_radius
    rho0 = float(scene.material.rest_density)
    lattice = fluid_lattice(scene)  # the fluid's start lattice (one per scene): its calibrated mass
    mass = calibrated_mass(kernel.name, h, d, rho0, lattice)
    bias = lattice_sum(kernel.name, h, d, lattice) * LATTICE_LAYER[lattice] * d**3 - 1.0

    fluid_x = np.asarray(sampled.fluid_x, dtype=np.float64).reshape(-1, 3)
    fluid_v = np.asarray(sampled.fluid_v, dtype=np.float32).reshape(-1, 3)
    boundary_x = np.asarray(sampled.boundary_x, dtype=np.float64).reshape(-1, 3)
    if len(fluid_x) == 0 and not getattr(scene, "emitters", None):
        raise SceneError(f"{scene.name}: the scene holds no fluid particles after sampling")
    if len(fluid_x) == 0 and scene.container is None:
        raise SceneError(f"{scene.name}: container: a scene whose fluid all comes from emitters needs a [container]")

    if scene.container is not None:
        lo = np.asarray(scene.container.min, dtype=np.float64)
        hi = np.asarray(scene.container.max, dtype=np.float64)
        origin = 0.5 * (lo + hi)
    else:
        lo = hi = None
        origin = 0.5 * (fluid_x.min(axis=0) + fluid_x.max(axis=0))

    body_x = np.asarray(getattr(sampled, "body_x", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    capacity = 0
    fx_ref, fv_ref = fluid_x, fluid_v
    if getattr(scene, "emitters", None) or getattr(scene, "sinks", None):
        from ..scene.emitters import emission_capacity, nozzle_reference

        capacity = emission_capacity(scene, len(fluid_x))
        fx_ref, fv_ref = nozzle_reference(scene, fluid_x, fluid_v)  # the nozzles count as fluid for v_ref
    v_ref, c_s, v_source = _speed_of_sound(scene, fx_ref, fv_ref, lo, getattr(sampled, "fluid_block", None),
                                           body_x)
    colliders = list(getattr(sampled, "colliders", []))
    if colliders:  # animated obstacles: moving particles after the bodies'; their top speed counts in v_ref
        from ..rigid.colliders import max_path_speed

        v_col = max_path_speed(colliders, 0.0, float(scene.duration))
        if v_col > v_ref:
            v_ref, c_s, v_source = _speed_of_sound(scene, fluid_x, fluid_v, lo, None, body_x, driven_speed=v_col)
        body_x = np.concatenate([body_x, np.asarray(sampled.collider_x, np.float64).reshape(-1, 3)])

    static_count = len(boundary_x)
    boundary_method = scene.boundary if static_count + len(body_x) else "none"
    bx = wp.array((boundary_x - origin).astype(np.float32), dtype=wp.vec3, device=device)
    bv = wp.zeros(len(boundary_x), dtype=wp.vec3, device=device)
    bvol = wp.zeros(len(boundary_x), dtype=float, device=device)
    bgrid = None
    if len(boundary_x):
        bgrid = NeighborGrid(support, device=device)
        bgrid.build(bx)
        launch(_density_dev.boundary_volume_kernel(kernel.name), len(boundary_x),
               [float(h), float(support), bgrid.id, bx], [bvol], device=device)
    body_of = None
    particle_friction = None
    max_friction = -1.0
    if len(body_x):  # moving bodies after the static particles; their volumes from their own samples
        samples = list(sampled.body_samples) + [c.samples for c in colliders]
        bx = wp.array(np.concatenate([bx.numpy(), (body_x - origin).astype(np.float32)]), dtype=wp.vec3, device=device)
        bvol = wp.array(np.concatenate([bvol.numpy()] + [s.volume for s in samples]).astype(np.float32), dtype=float,
                        device=device)
        bv = wp.zeros(bx.shape[0], dtype=wp.vec3, device=device)
        body_of = wp.array(np.concatenate([np.full(static_count, -1, np.int32)]
                                          + [np.full(s.count, k, np.int32) for k, s in enumerate(samples)]),
                           dtype=wp.int32, device=device)
        boundary_x = np.concatenate([boundary_x, body_x])
        sigma0 = float(scene.material.boundary_friction)
        sigmas = [sigma0 if b.fluid_friction is None else float(b.fluid_friction) for b in scene.bodies]
        sigmas += [sigma0] * len(colliders)
        max_friction = max([sigma0] + sigmas)
        if any(s != sigma0 for s in sigmas):  # a body with its own friction: sigma per particle
            particle_friction = wp.array(np.concatenate([np.full(static_count, sigma0, np.float32)] + [
                np.full(s.count, sig, np.float32) for s, sig in zip(samples, sigmas)]), dtype=float, device=device)

    model = Model(
        device=device, smoothing=kernel, rest_density=rho0, particle_radius=r, spacing=d,
        smoothing_length=h, support_radius=support, particle_mass=mass, lattice_bias=bias,
        gravity=np.asarray(scene.gravity, dtype=np.float32), origin=origin,
        reference_speed=v_ref, reference_speed_source=v_source, speed_of_sound=c_s,
        boundary_friction=float(scene.material.boundary_friction), boundary_method=boundary_method,
        boundary_x=bx, boundary_v=bv, boundary_volume=bvol, boundary_grid=bgrid,
        container_lo=None if lo is None else (lo - origin), container_hi=None if hi is None else (hi - origin),
        fluid_count=len(fluid_x), boundary_count=len(boundary_x), static_boundary_count=static_count,
        boundary_body=body_of, boundary_particle_friction=particle_friction, max_boundary_friction=max_friction,
        capacity=capacity,
    )
    state = State(
        particle_x=wp.array((fluid_x - origin).astype(np.float32), dtype=wp.vec3, device=device),
        particle_v=wp.array(fluid_v, dtype=wp.vec3, device=device),
    )
    return model, state
