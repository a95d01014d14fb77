"""Animated colliders: ``[[obstacles]]`` with ``keyframes`` or ``animation`` (a path,
``warp_sph.scene.paths``) whose boundary particles follow the path every substep.

Sampling (``sample_colliders``): the obstacle's surface as written (its local frame) is sampled like a
static obstacle's (``box_surface``, ``sphere_obstacle.sphere_surface``, ``sample_surface``, about d apart, on the true surface) and gets
Akinci volumes from its own samples (``rigid.sampling.akinci_volumes``), since it moves away from the
walls. Its particles follow the moving bodies' in the Model's boundary arrays (``build_model``), so the
solvers, the neighbour lists (``moving_boundary_grid``) and the boundary methods treat them as moving
boundary particles.

Stepping (``SimulationColliders``), two stages, as the bodies':
1. ``collider_forces`` right after the solver's ``body_coupling_after`` stage: the fluid's force F_b on
   each collider particle (the negative of the boundary terms, ``kernels/rigid.py``);
2. ``colliders`` after the solver's last stage: the work done on the fluid over the substep,
   W += -dt sum_b F_b . v_b (``kernels/colliders.py``; the energy watchdog subtracts it), then every
   particle placed at the pose of the substep's end time, x = R(t) x_local + T(t), with the path's velocity
   v = dT/dt + omega x (x - T) (Akinci's divergence and pressure terms, viscosity and friction read it;
   the penalty force reads the relative velocity), and the moving cell grid rebuilt.
The pose is a function of time only, so a resumed or retried frame replays bit for bit; at every frame's
end the particles are placed again at the exact frame time.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.launch import LIGHT_MIN_RANGE, launch
from ..core.step_graph import Stage
from ..kernels import colliders as _colliders_dev
from ..scene.meshes import box_surface, load_triangle_mesh, points_inside, sample_surface
from ..scene.paths import Path, matrix_quaternion
from ..scene.sphere_obstacle import sphere_inside, sphere_surface, sphere_triangle_mesh
from .coupling import BodyParticles, boundary_force_stage, insert_coupling_stages
from .sampling import BodySamples, akinci_volumes
from .spec import box_mesh


@dataclass
class Collider:
    """One animated obstacle: ``name``; ``index`` in ``scene.obstacles``; its ``path``; ``samples`` (boundary
    particles in the local frame [m], Akinci volumes); the local surface (``vertices``, ``triangles``) for
    the USD file; ``reach`` [m], the farthest sample from the local origin."""

    name: str
    index: int
    path: Path
    samples: BodySamples
    vertices: np.ndarray
    triangles: np.ndarray
    reach: float

    def inside(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Mask of world points [m] inside the collider at time t [s]."""
        R, T = self.path.pose(t)
        local = (np.asarray(x, dtype=np.float64) - T) @ R
        if self.triangles.shape[0] == 12 and self._box is not None:
            lo, hi = self._box
            return np.all((local >= lo) & (local <= hi), axis=1)
        if self._sphere is not None:
            return sphere_inside(self._sphere, local)
        from ..scene.meshes import TriangleMesh

        return points_inside(TriangleMesh(self.vertices, self.triangles), local)

    _box = None
    _sphere = None


def collider_name(ob, index: int) -> str:
    return ob.name or f"obstacle{index}"


def sample_colliders(scene, device=None) -> tuple[list[Collider], np.ndarray]:
    """The scene's animated obstacles sampled (module docstring) and their particles' world positions at
    t = 0 [m] (K, 3), collider after collider."""
    out, world = [], []
    d = scene.spacing
    for i, ob in enumerate(scene.obstacles):
        if not ob.animated:
            continue
        if ob.shape == "box":
            lo, hi = np.asarray(ob.min, float), np.asarray(ob.max, float)
            p, n = box_surface(lo, hi, d, inward=False)
            verts, tris = box_mesh(0.5 * (hi - lo))
            verts = verts + 0.5 * (lo + hi)
        elif ob.shape == "sphere":
            p, n = sphere_surface(ob, d)
            mesh = sphere_triangle_mesh(ob)
            verts, tris = mesh.vertices, mesh.triangles
        else:
            mesh = load_triangle_mesh(ob.file).transformed(ob.scale, ob.translate)
            p, n = sample_surface(mesh, d)
            verts, tris = mesh.vertices, mesh.triangles
        vol = akinci_volumes(p, scene.smoothing_kernel, scene.smoothing_length, device=device)
        samples = BodySamples(np.ascontiguousarray(p, np.float64), np.ascontiguousarray(n, np.float32),
                              vol.astype(np.float32))
        c = Collider(collider_name(ob, i), i, ob.path, samples, np.asarray(verts, float),
                     np.asarray(tris, np.int64), float(np.max(np.linalg.norm(p, axis=1))) if len(p) else 0.0)
        if ob.shape == "box":
            c._box = (lo, hi)
        elif ob.shape == "sphere":
            c._sphere = ob
        R, T = ob.path.pose(0.0)
        out.append(c)
        world.append(p @ R.T + T)
    return out, (np.concatenate(world) if world else np.zeros((0, 3)))


def max_path_speed(colliders, t0: float, t1: float) -> float:
    """Largest speed of a collider particle over [t0, t1] [m/s] (|dT/dt| + |omega| reach, 0 without colliders)."""
    return max((c.path.max_speed(c.reach, t0, t1) for c in colliders), default=0.0)


class SimulationColliders:
    """The animated colliders of ``sim`` (built by the Simulation when an obstacle has a path)."""

    #: key of this part in run.json's summary (``Simulation.parts``)
    name = "colliders"

    def __init__(self, sim):
        m = sim.model
        self.sim = sim
        self.colliders: list[Collider] = list(sim.sampled.colliders)
        self.names = [c.name for c in self.colliders]
        body_count = sum(s.count for s in getattr(sim.sampled, "body_samples", []))
        self.start = m.static_boundary_count + body_count
        self.particles = BodyParticles([c.samples for c in self.colliders], start=self.start, device=m.device)
        self.count = self.particles.count
        n = len(self.colliders)
        self.q = wp.zeros(n, dtype=wp.transform, device=m.device)
        self.qd = wp.zeros(n, dtype=wp.spatial_vector, device=m.device)
        self.com = wp.zeros(n, dtype=wp.vec3, device=m.device)
        self.force = wp.zeros(max(self.count, 1), dtype=wp.vec3, device=m.device)
        self.work = wp.zeros(1, dtype=wp.float64, device=m.device)
        sim.fields.update(boundary_v=m.boundary_v, collider_particle_force=self.force)
        self.inputs = {"boundary_v", "moving_boundary_grid"}
        self.unsorted = {"boundary_v", "collider_particle_force"}
        self.time = 0.0
        self.place(0.0)

    # --- poses ---------------------------------------------------------------------------------
    def poses(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(R (n, 3, 3), T world [m] (n, 3), dT/dt [m/s] (n, 3), omega [rad/s] (n, 3)) at time t [s]."""
        R = np.array([c.path.pose(t)[0] for c in self.colliders]).reshape(-1, 3, 3)
        T = np.array([c.path.pose(t)[1] for c in self.colliders]).reshape(-1, 3)
        vel = [c.path.velocity(t) for c in self.colliders]
        return R, T, np.array([v for v, _ in vel]).reshape(-1, 3), np.array([w for _, w in vel]).reshape(-1, 3)

    def place(self, t: float) -> None:
        """Collider particles (x, v) at the poses of time t [s]; the moving cell grid rebuilt."""
        m = self.sim.model
        R, T, v, w = self.poses(t)
        T = T - m.origin
        q = np.array([np.concatenate([T[k], matrix_quaternion(R[k])]) for k in range(len(R))], dtype=np.float32)
        qd = np.concatenate([v, w], axis=1).astype(np.float32)
        self.q.assign(q.reshape(-1, 7))
        self.qd.assign(qd.reshape(-1, 6))
        self.particles.place(self.q, self.qd, self.com, m.boundary_x, m.boundary_v)
        self.time = float(t)
        lists = self.sim.fields.get("neighbor_lists")
        if lists is not None:
            lists.update_moving(m.boundary_x)
            self.sim.fields["moving_boundary_grid"] = lists.moving_cells
        else:
            self.sim.fields.setdefault("moving_boundary_grid", None)

    def max_speed(self, t0: float, t1: float) -> float:
        """Largest speed of a collider particle over [t0, t1] [m/s] (the path's look-ahead, for the step bound)."""
        return max_path_speed(self.colliders, t0, t1)

    # --- graph ---------------------------------------------------------------------------------
    def insert_stages(self, stages: list[Stage], solver) -> list[Stage]:
        """``collider_forces`` after the solver's coupling stage, ``colliders`` at the end."""
        from ..core.errors import SceneError

        if solver.body_coupling_after is None:
            raise SceneError(solver.refuses_bodies(type(self.sim.boundary)).replace("bodies need", "animated obstacles need"))
        if not getattr(solver, "lists", True):
            raise SceneError(f"obstacles: the {solver.name} solver's hash-grid variant (lists=False) cannot move "
                             "animated obstacles; use its neighbour-list variant (the default)")
        return insert_coupling_stages(stages, solver, self.force_stage, self.motion_stage, "obstacles")

    def force_stage(self, velocity: str = "particle_v") -> Stage:
        return boundary_force_stage(self.sim, "collider_forces", self.start, self.count, self.force,
                                    "collider_particle_force", velocity=velocity,
                                    doc=f"the fluid's force on {self.count} animated-obstacle particles (the "
                                        f"negative of the {self.sim.boundary_terms.name} boundary terms), for the "
                                        "work they do on the fluid")

    def motion_stage(self) -> Stage:
        def run(sim, dt):
            m = sim.model
            launch(_colliders_dev.collider_work, 1, [float(dt), self.start, self.count, m.boundary_v, self.force],
                   [self.work], device=m.device, min_range=LIGHT_MIN_RANGE)
            self.place(sim.state.time + dt)

        return Stage("colliders", run, reads=("collider_particle_force",),
                     updates=("boundary_x", "boundary_v", "moving_boundary_grid"),
                     doc=f"{len(self.names)} animated obstacles: work on the fluid summed, particles placed at the "
                         "path's pose of the substep's end, their cells rebuilt")

    # --- host reads ----------------------------------------------------------------------------
    def work_done(self) -> float:
        """Work the colliders did on the fluid since the last ``reset_work`` [J] (one read)."""
        return float(self.work.numpy()[0])

    def reset_work(self) -> None:
        self.work.zero_()

    def frame_record(self) -> dict:
        """{name: position of the local origin [m], orientation (x, y, z, w), velocity [m/s], angular velocity
        [rad/s], fluid_force [N] (last substep)} for run.json."""
        R, T, v, w = self.poses(self.time)
        f = self.force.numpy().astype(np.float64)
        out = {}
        for k, name in enumerate(self.names):
            lo, hi = int(self.particles.offsets[k]), int(self.particles.offsets[k + 1])
            out[name] = {"position": T[k].tolist(), "orientation": matrix_quaternion(R[k]).tolist(),
                         "velocity": v[k].tolist(), "angular_velocity": w[k].tolist(),
                         "fluid_force": f[lo:hi].sum(axis=0).tolist()}
        return out

    def export_poses(self) -> dict:
        """{name: (local origin [m] world (3,), quaternion (x, y, z, w))} for the USD writer."""
        R, T, _, _ = self.poses(self.time)
        return {name: (T[k], matrix_quaternion(R[k])) for k, name in enumerate(self.names)}

    def checkpoint_arrays(self) -> dict:
        """What a resume needs beyond the time: the work done so far [J]."""
        return {"collider_work": self.work.numpy().copy()}

    def restore_arrays(self, arrays) -> None:
        """Restore ``checkpoint_arrays`` and place the particles at the state's time."""
        if "collider_work" in arrays:
            self.work.assign(np.asarray(arrays["collider_work"], dtype=np.float64).reshape(1))
        self.place(self.sim.state.time)

    def save(self) -> tuple:
        return (self.time, self.work_done())

    def restore(self, saved: tuple) -> None:
        self.work.assign(np.array([saved[1]], dtype=np.float64))
        self.place(saved[0])

    def summary(self) -> dict:
        return {"count": len(self.names), "names": self.names, "boundary_particles": self.count,
                "paths": [c.path.source for c in self.colliders],
                "interpolation": [c.path.interpolation for c in self.colliders]}
