"""The scripting entry point: a Simulation built from a scene, advanced step by step or frame by frame.

    sim = Simulation(load_scene("dam_break"))
    sim.advance_frame()                 # CFL-bounded substeps up to the next frame time
    x = sim.get_field("particle_x")     # NumPy copy, world coordinates [m]
    sim.fields["particle_v"]            # the wp.array itself (device, local coordinates for positions)
    sim.graph.insert(Stage(...), before="integrate")

Every frame ends with the watchdog's rules (``warp_sph.run.watchdog``): a non-finite value, a particle
outside the container, too fast or too compressed, or a rise of the total energy stops the run with a
SimulationError naming the stage, step, time and particle (or the rise and its cause), or retries the frame
with half the step
(``time.on_instability = "retry"``). Pre-flight checks: ``warp_sph.run.preflight``.
"""
from __future__ import annotations

import math
import numbers
from contextlib import contextmanager

import numpy as np
import warp as wp

from ..core.errors import SceneError
from ..kernels import neighbors as _neighbors_dev
from ..kernels import reduction as _reduce
from ..core.launch import launch, replaying_launch
from ..core.model import build_model
from ..neighbors import NeighborGrid, fluid_grid_dim
from ..core.step_graph import StepGraph
from ..methods.force import SimulationForces
from .diagnostics import FrameDiagnostics, FrameStatistics
from . import frame_loop
from .watchdog import Watchdog


class Simulation:
    """A scene turned into Model + State + step graph. ``device`` is a Warp device name or None."""

    def __init__(self, scene, device: str | None = None, solver_options: dict | None = None):
        from ..methods import registry
        from .preflight import check_memory

        from ..core.device import resolve_device

        self.scene = scene
        self.device = resolve_device(device)  # quiet Warp start-up; a bad name is a one-line error
        solver_cls = registry.solver(scene.solver)
        boundary_cls = registry.boundary(scene.boundary)
        check_memory(scene, self.device)
        self.sampled = boundary_cls.sample(scene)
        self.model, self.state = build_model(scene, self.sampled, self.device)
        self.fields: dict[str, object] = {
            "particle_x": self.state.particle_x,
            "particle_v": self.state.particle_v,
        }
        self._inputs = {"particle_x", "particle_v"}
        #: emitters and sinks (``warp_sph.run.emission.ParticleFlow``); None without: the count never changes
        self.flow = None
        from ..scene.emitters import has_flow

        if has_flow(scene):  # emitters, sinks or open container faces
            from .emission import ParticleFlow

            self.flow = ParticleFlow(self)
        if self.model.boundary_count:
            self.fields.update(boundary_x=self.model.boundary_x, boundary_volume=self.model.boundary_volume,
                               boundary_grid=self.model.boundary_grid)
            self._inputs |= {"boundary_x", "boundary_volume", "boundary_grid"}
            #: the boundary method (``warp_sph.methods.boundary.BoundaryMethod``); None without boundary particles
            self.boundary = boundary_cls(self)
            self.boundary_terms = self.boundary.terms()
            self.boundary_params = self.boundary.params()
        else:
            self.boundary = None
            self.boundary_terms = None
            self.boundary_params = _neighbors_dev.NoBoundaryParams()
        self.fluid_grid = NeighborGrid(self.model.support_radius, device=self.device,
                                       dim=fluid_grid_dim(self.model, self.sampled.fluid_x))
        self.fields["fluid_grid"] = self.fluid_grid
        #: fields that are not one value per fluid particle (never sorted into cell order)
        self.unsorted_fields = {"boundary_x", "boundary_volume"}
        #: the moving rigid bodies (``warp_sph.rigid.bodies.SimulationBodies``); None without [[bodies]]
        self.bodies = None
        if scene.bodies:
            from ..rigid.bodies import SimulationBodies

            self.bodies = SimulationBodies(self)
            self._inputs |= self.bodies.inputs
            self.unsorted_fields |= self.bodies.unsorted
        #: the animated obstacles (``warp_sph.rigid.colliders.SimulationColliders``); None without any
        self.colliders = None
        if self.sampled.colliders:
            from ..rigid.colliders import SimulationColliders

            self.colliders = SimulationColliders(self)
            self._inputs |= self.colliders.inputs
            self.unsorted_fields |= self.colliders.unsorted
        self._diagnostics = FrameDiagnostics(self.device)
        #: per-chunk largest |v|^2 of ``current_speed``
        self._speed_partial = wp.zeros(max(1, -(-self.model.capacity // _reduce.REDUCE_CHUNK)), dtype=float,
                                       device=self.device)
        self._speed_launch = replaying_launch(self.device)  # current_speed's launch (replayed on the CPU)
        self.frame_dt = 1.0 / float(scene.fps)
        self.step_bound = 0.0  # set by ``time_step``
        self.last_frame: FrameStatistics | None = None
        self.solver = None
        self.graph = None
        #: the scene's non-pressure forces (``warp_sph.methods.force.SimulationForces``); solvers place their
        #: stages at their slots
        self.forces = SimulationForces(self)
        #: the scene's probes (``warp_sph.run.probes.Probes``); None without [[probes]]
        self.probes = None
        if scene.probes:
            from .probes import Probes

            self.probes = Probes(self)
        #: the scene's whitewater (``warp_sph.run.whitewater.Whitewater``); None without [whitewater]
        self.whitewater = None
        if scene.whitewater is not None and scene.whitewater.enabled:
            from .whitewater import Whitewater

            self.whitewater = Whitewater(self)
            self.fields["whitewater"] = self.whitewater
            self._inputs.add("whitewater")
        self.set_solver(solver_cls.name, **(solver_options or {}))
        self.watchdog = Watchdog(self)
        #: sort the per-particle fields into cell order for each frame (``warp_sph.neighbors.particle_order``)
        self.cell_order = True
        self._cell_order = None

    def set_solver(self, name: str | None = None, **options) -> None:
        """Use solver ``name`` (default: the scene's) with constructor ``options`` (e.g. ``lists=False``
        for the hash-grid variant): a new step graph (stages inserted by hand are dropped) and the
        density refreshed. The scene's section of that solver holds its settings."""
        from ..methods import registry

        cls = registry.solver(name or self.scene.solver)
        if getattr(self, "watchdog", None) is not None:
            self.watchdog.energy.stale = True  # another solver: another equation of state, a new reference
        if self.boundary is not None:
            refusal = cls.refuses_boundary(type(self.boundary))
            if refusal:
                raise SceneError(f"solver {cls.name!r} does not work with boundary {self.boundary.name!r}: {refusal}")
        solver = cls(self, **options)
        if self.bodies is not None:
            self.bodies.check_solver(solver)
        stages = solver.stages()
        if self.bodies is not None:
            stages = self.bodies.insert_stages(stages, solver)
            self.bodies.place()  # the neighbour lists exist now: their moving grid is the workspace's
        if self.colliders is not None:
            stages = self.colliders.insert_stages(stages, solver)
            self.colliders.place(self.colliders.time)
        self.solver = solver
        if self.whitewater is not None:  # after the solver's and the bodies' stages: the step's end state
            self.whitewater.check_solver(solver)
            stages = stages + [self.whitewater.stage()]
        if self.probes is not None:  # after every other stage: they read the substep's end state
            stages = stages + [self.probes.stage(stages)]
        self.graph = StepGraph(stages, self._inputs | set(solver.carried_fields()) | set(self.forces.carried_fields()),
                               device=self.device,
                               synchronize_timing=self.device.is_cuda)
        #: names of the solver's own stages (the watchdog tells them apart from stages a user inserted)
        self.solver_stage_names = set(self.graph.names())
        self.refresh_density()

    def summary(self) -> dict:
        """The model's constants, the solver's (``solver``), the forces' (``forces``, when the scene has any),
        the boundary method's (``boundary``) and the rigid bodies' (``bodies``)."""
        out = self.model.summary()
        out["solver"] = {"name": self.solver.name, **self.solver.summary()}
        if len(self.forces):
            out["forces"] = self.forces.summary()
        if self.boundary is not None:
            out["boundary"] = {"name": self.boundary.name, **self.boundary.summary()}
        if self.bodies is not None:
            out["bodies"] = self.bodies.summary()
        for part in self.parts:
            out[part.name] = part.summary()
        return out

    @property
    def parts(self) -> tuple:
        """The optional parts the scene turned on, emitters and sinks first (their restore sets the active
        count the other arrays follow): each has ``name``, ``summary()``, ``checkpoint_arrays()`` and
        ``restore_arrays(cp)``; those with state inside a frame also ``save()`` / ``restore(saved)`` (the
        watchdog's frame retry)."""
        return tuple(p for p in (getattr(self, "flow", None), getattr(self, "colliders", None),
                                 getattr(self, "whitewater", None)) if p is not None)

    # --- fields ----------------------------------------------------------------------------
    def allocate(self, name: str, dtype) -> wp.array:
        """Workspace array of one value per fluid particle (allocated once)."""
        if name not in self.fields:
            if self.flow is not None:  # the capacity, the active particles a prefix view (``ParticleFlow``)
                self.fields[name] = self.flow.adopt(name, wp.zeros(self.model.capacity, dtype=dtype, device=self.device))
            else:
                self.fields[name] = wp.zeros(self.model.fluid_count, dtype=dtype, device=self.device)
        return self.fields[name]

    def get_field(self, name: str) -> np.ndarray:
        """NumPy copy of a field; positions come back in world coordinates [m]."""
        a = self.fields.get(name)
        if not isinstance(a, wp.array):
            arrays = sorted(k for k, v in self.fields.items() if isinstance(v, wp.array))
            raise KeyError(f"field {name!r} is not an array of this simulation; its arrays: {', '.join(arrays)}")
        out = a.numpy().copy()
        if name in ("particle_x", "boundary_x"):
            out = self.model.to_world(out)
        return out

    def set_field(self, name: str, values: np.ndarray) -> None:
        """Overwrite a field from NumPy (positions in world coordinates [m])."""
        a = self.fields[name]
        values = np.asarray(values)
        if name in ("particle_x", "boundary_x"):
            values = self.model.to_local(values)
        if values.shape[0] != a.shape[0]:
            raise ValueError(f"field {name!r} holds {a.shape[0]} values, got {values.shape[0]}")
        a.assign(wp.array(values.astype(np.float32), dtype=a.dtype, device=self.device))
        self.watchdog.energy.stale = True  # the energy rule measures from the changed state

    # --- stepping --------------------------------------------------------------------------
    def refresh_density(self) -> None:
        """Recompute the density (and the solver's values of it) at the current positions, e.g. after
        ``set_field("particle_x", ...)``; the statistics and the next step read it."""
        self.solver.refresh_density()

    def step(self, dt: float) -> None:
        """One substep of dt seconds (> 0) through every stage of the graph."""
        if not (isinstance(dt, numbers.Real) and math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"Simulation.step: dt must be a finite number of seconds > 0, got {dt!r}")
        self.graph.run(self, dt)
        self.state.step += 1
        self.state.time += dt

    def time_step_bounds(self, speed: float) -> list:
        """Every bound of the step [s] at flow speed ``speed`` [m/s] (fluid and moving bodies): the solver's
        the forces' and the boundary method's (``warp_sph.methods.solver.TimeStepBound``), tightest first."""
        bounds = list(self.solver.time_step_bounds(speed)) + self.forces.time_step_bounds(speed)
        if self.boundary is not None:
            bounds += self.boundary.time_step_bounds(speed)
        return sorted(bounds, key=lambda b: b.seconds)

    def time_step(self, max_speed: float) -> float:
        """Substep bound [s] for the next frame: the tightest of ``time_step_bounds`` clamped to
        [dt_min, dt_max], or the scene's fixed_dt; times the watchdog's retry factor (1 unless a frame
        was retried)."""
        t = self.scene.time
        bound = min(b.seconds for b in self.time_step_bounds(max_speed))
        # the pressure's own step: the solver's and the boundary's bounds, not the forces' (a viscous or
        # capillary bound can be far smaller and says nothing about how fast a density error may go)
        pressure = list(self.solver.time_step_bounds(max_speed))
        if self.boundary is not None:
            pressure += self.boundary.time_step_bounds(max_speed)
        pressure_bound = min((b.seconds for b in pressure), default=math.inf)
        #: the pressure's adaptive step at this speed [s] (also with a fixed_dt, or a force's smaller bound):
        #: the time over which the solvers spread the correction of a density error present at a step's
        #: start (``Solver.error_share``); measured: with the viscous bound in it (nu = 100 m^2/s, 6.25e-6 s)
        #: a resting block's 0.8 % start over-density became a 3.5 m/s kick in one step (issue #36)
        self.step_bound = float(min(max(pressure_bound, t.dt_min), t.dt_max))
        dt = float(t.fixed_dt) if t.fixed_dt > 0 else float(min(max(bound, t.dt_min), t.dt_max))
        return dt * self.watchdog.dt_scale

    def advance_frame(self) -> FrameStatistics:
        """Advance to the next frame time in substeps no larger than the time-step bound, in cell order; the
        watchdog checks the frame's end state and retries it with half the step or raises SimulationError
        (``warp_sph.run.frame_loop.advance_frame``)."""
        return frame_loop.advance_frame(self)

    @property
    def per_substep_step(self) -> bool:
        """True when ``advance_frame`` sizes each substep for the speed at its start: the solver asks for
        it (``Solver.time_step_per_substep``), the scene has no fixed_dt and no moving bodies (their
        coupling plans its substeps once per frame)."""
        return (self.solver.time_step_per_substep and self.bodies is None and self.colliders is None
                and not self.scene.time.fixed_dt > 0)

    def current_speed(self) -> float:
        """The fastest fluid particle's speed now [m/s] (a chunked maximum on the device, one read)."""
        partial = self._speed_partial
        self._speed_launch(_reduce.max_speed_chunks, partial.shape[0], [_reduce.REDUCE_CHUNK, self.fields["particle_v"]],
                           [partial])
        return math.sqrt(float(partial.numpy().max()))

    @contextmanager
    def in_cell_order(self):
        """Context: the per-particle fields in cell order inside it (``cell_order``; see
        ``warp_sph.neighbors.particle_order``), at their stable indices again after it, also on an error."""
        sorted_ = False
        if self.cell_order:
            if self._cell_order is None:
                from ..neighbors.particle_order import CellOrder

                self._cell_order = CellOrder(self)
            sorted_ = self._cell_order.sort()
        try:
            yield
        finally:
            if sorted_:
                self._cell_order.unsort()

    def statistics(self, steps: int = 0, dt_min: float = 0.0, dt_max: float = 0.0,
                   at_time: float | None = None) -> FrameStatistics:
        """Reduce diagnostics and the watchdog's rules on the device and read them once, and the energies
        (float64, one more small read) with the energy rule. at_time: the time [s] the free-fall speed limit is
        taken at (default: the state's time); given by the watchdog's stage-by-stage replay, which checks
        the device rules only (a state between stages has no meaningful energy), so energy is skipped."""
        return self._diagnostics.read(self, steps, dt_min, dt_max, at_time)

    def check_health(self, stats: FrameStatistics) -> None:
        """Watchdog on a frame's statistics: raise SimulationError on a non-finite value, a particle
        outside the container, too fast or too compressed (rules in ``warp_sph.run.watchdog``).
        ``advance_frame`` already checks every frame it simulates; this checks the initial state or
        a state the caller changed."""
        wd = self.watchdog
        if wd.broken(stats.watch) is None:
            return
        raise wd.initial_error(stats)
