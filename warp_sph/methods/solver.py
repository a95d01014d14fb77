"""The pressure-solver interface: what a solver (WCSPH, PBF, DFSPH, ...) provides, and nothing more.

A solver is one host module in ``warp_sph/methods/solvers/`` with a ``Solver`` subclass decorated with
``@register_solver``, and one kernels module of the same name in ``kernels/``. The simulation, the
runner, the watchdog, pre-flight and the benchmarks use only what this class declares:

- class attributes: ``name`` (the scene's ``solver`` value and the name of its scene section),
  ``title``, ``parameters`` (the rows of its section: keys, units, defaults, valid ranges; the
  typed settings object is ``scene.section(name)``, also ``self.config``), ``iterative``;
- ``validate(scene, fail)``: cross-checks of its settings, before anything is built;
- ``refuses_boundary(boundary_cls)``: a reason to refuse a boundary method, or None;
- ``stages()``: the step graph's stages (``warp_sph.core.step_graph.Stage``), each declaring the
  fields it reads, writes and updates; per-particle arrays live in the workspace (``sim.allocate``);
- ``time_step_bounds(speed)``: the named bounds [s] of the adaptive step (``TimeStepBound``); ``step_floor()``:
  the smallest step it resolves, if any;
- ``step_statistics()`` (per substep, host values only) and ``finish_frame()`` (once per frame);
- ``carried_fields()``: workspace fields that outlive a substep; ``refresh_density()``;
- ``checkpoint_arrays()`` / ``restore_arrays(arrays)``: what a resume needs beyond x and v;
- ``instability_hint(rule, stage)``: the likely cause of a watchdog finding in its own terms;
- ``equation_of_state()``: the pressure law whose compression energy the energy watchdog counts;
- moving rigid bodies (``warp_sph.rigid``, two-way coupled as Akinci et al. 2012): ``body_coupling_after``
  and the workspace field ``boundary_pressure_term`` (below); ``refuses_bodies(boundary_cls)``.

Coupling moving bodies. When the scene has bodies (``sim.bodies`` is not None, a compile-time choice:
scenes without bodies keep their kernels), a solver that couples writes the workspace field
``boundary_pressure_term`` (one float per fluid particle, ``sim.allocate``): the scalar term_i such
that the pressure acceleration of fluid particle i due to boundary particle b is
``terms.pressure(params, grad_i W_ib, V_b, term_i)`` (Akinci: -rho0 V_b term_i grad_i W_ib [m/s^2];
term_i in m^5/(kg s^2), WCSPH's p/rho^2 of the wall). ``body_coupling_after`` names the stage after
which that term is final for the substep and particle_x, particle_v and particle_density hold the
values the boundary terms (pressure and force) were evaluated with (a solver whose velocities change
between its boundary force and that stage names, in ``body_coupling_velocity``, a workspace field
holding the velocities the force term read; DFSPH: a copy taken before its viscosity stage, since
its density solve follows); the simulation gathers the
fluid's force on each moving boundary particle right after it, as the exact negative of those terms
(``kernels/rigid.py``), and moves the bodies after the solver's last stage.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

from ..scene.parameters import Param


@dataclass(frozen=True)
class TimeStepBound:
    """One bound of the adaptive step: ``seconds`` [s], the ``formula`` with the numbers that went into
    it (for messages), and the scene keys that set it (``keys``, for advice)."""

    name: str
    seconds: float
    formula: str
    keys: tuple[str, ...] = ()


class MethodBase:
    """What solvers and boundary methods share: a name, a title, a scene section of parameters."""

    name: ClassVar[str] = ""
    title: ClassVar[str] = ""
    #: one line for the section's row of the parameter table (default: "<title> settings")
    section_doc: ClassVar[str] = ""
    parameters: ClassVar[tuple[Param, ...]] = ()
    _config_classes: ClassVar[dict] = {}

    @classmethod
    def config_class(cls):
        """The dataclass of this method's scene section, generated once from ``parameters``."""
        key = (cls, cls.parameters)
        made = MethodBase._config_classes.get(key)
        if made is None:
            from ..scene.types import section_class

            made = MethodBase._config_classes[key] = section_class(cls.name, cls.parameters, doc=cls.title)
        return made

    @classmethod
    def validate(cls, scene, fail) -> None:
        """Cross-checks of the method's settings in ``scene``; call ``fail(keypath, message)`` to refuse."""


class Solver(MethodBase):
    """Base class of the pressure solvers (see the module docstring). ``sim`` is the Simulation."""

    #: True when the solver iterates and reports ``iterations`` in ``step_statistics``
    iterative: ClassVar[bool] = False
    #: True: ``advance_frame`` sizes every substep for the flow's speed at its start (one read of the
    #: fastest particle per substep, as SPlisHSPlasH's CFL step), and ``time_step_bounds`` reads
    #: ``sim.per_substep_step``; False: one step size per frame, for the frame's speed plus |g| frame_dt
    #: (no read between substeps). Scenes with moving bodies always use one step per frame.
    time_step_per_substep: ClassVar[bool] = False
    #: True: the solver needs a start at rest density (a boundary method that can, relaxes the sampled fluid
    #: next to its walls before the first step: ``boundaries/akinci2012_start.py``). A weakly compressible
    #: solver stores an over-dense start as elastic energy ~ c_s^2 delta^2 / 2 per kg and releases it as
    #: motion; DFSPH and PBF spread its correction over the adaptive step (``error_share``)
    relaxed_start: ClassVar[bool] = False
    #: the stage after which the fluid's force on moving bodies is gathered (module docstring); None:
    #: the solver does not write ``boundary_pressure_term`` and scenes with bodies are refused
    body_coupling_after: ClassVar[str | None] = None
    #: the workspace field holding, after ``body_coupling_after``, the fluid velocities [m/s] the boundary
    #: method's force term (friction, penalty) was evaluated with (module docstring)
    body_coupling_velocity: str = "particle_v"

    def __init__(self, sim, **options: Any):
        if options:
            raise TypeError(f"solver {self.name!r} takes no options, got {', '.join(options)}")
        self.sim = sim
        self.model = sim.model
        self.config = sim.scene.sections.get(self.name)

    @classmethod
    def refuses_boundary(cls, boundary_cls) -> str | None:
        """A reason why this solver cannot work with ``boundary_cls``, or None (it can)."""
        return None

    @classmethod
    def refuses_bodies(cls, boundary_cls) -> str | None:
        """A reason why this solver with ``boundary_cls`` cannot move rigid bodies, or None (it can).
        Default: refused when ``body_coupling_after`` is None or the boundary method refuses."""
        if cls.body_coupling_after is None:
            from .registry import solvers

            able = sorted(name for name, other in solvers().items() if other.body_coupling_after is not None)
            return (f"the {cls.name} solver does not provide the wall pressure term bodies need "
                    f"(Solver.body_coupling_after); use solver = {' or '.join(repr(n) for n in able)}")
        return boundary_cls.refuses_bodies()

    @property
    def with_bodies(self) -> bool:
        """True when the scene has moving boundary particles (rigid bodies or animated obstacles): write
        ``boundary_pressure_term`` and walk the moving cell grid."""
        return getattr(self.sim, "bodies", None) is not None or getattr(self.sim, "colliders", None) is not None

    def stages(self) -> list:
        """The stages of one substep, in order."""
        raise NotImplementedError

    def time_step_bounds(self, speed: float) -> list[TimeStepBound]:
        """The solver's bounds of the step at flow speed ``speed`` [m/s]."""
        raise NotImplementedError

    def step_floor(self) -> TimeStepBound | None:
        """The smallest step [s] the solver resolves (pre-flight refuses a ``time.fixed_dt`` below it), or
        None (no floor)."""
        return None

    def error_share(self, dt: float) -> float:
        """Share s of the density error present at a step's start that an incompressible solver corrects
        within a step of dt [s] (Baumgarte stabilisation): s = min(1, dt / tau) with tau half the adaptive
        step (``Simulation.step_bound``). Correcting an over-density e in one step moves particles by
        about e d, i.e. a velocity e d / dt: a start-up error or an impact's leftover would become a
        kick that grows as 1/dt (issue #36: 29 m/s at a fixed 1e-5 s). With s it becomes e d / tau at
        any smaller step. tau is the pressure's own adaptive step (the solver's and the boundary's bounds:
        a force's viscous or capillary bound does not count), so a step made small by a fixed dt or by a
        force's bound spreads the correction too. Every adaptive step the pressure bounds is at least
        tau / 2 (a frame's equal substeps are between half the bound and the bound), so s = 1 there; 1 also
        when no bound is known (steps run by hand)."""
        bound = getattr(self.sim, "step_bound", 0.0)
        if not bound > 0.0:
            return 1.0
        return min(1.0, 2.0 * dt / bound)

    def carried_fields(self) -> tuple[str, ...]:
        """Workspace fields that outlive a substep (inputs of the step graph besides x and v), e.g. the
        last density pass a solver's next step reads."""
        return ()

    def refresh_density(self) -> None:
        """Recompute the density (and the solver's per-particle values of it) at the current positions:
        after construction, a resume or a change of positions from outside."""
        for stage in self.sim.graph.stages:
            if stage.name in ("neighbors", "density"):
                stage.run(self.sim, 0.0)

    def step_statistics(self) -> dict[str, float]:
        """Host-side figures of the last substep (iterations, errors); mean and max per frame go to run.json."""
        return {}

    def finish_frame(self) -> None:
        """Called once after a frame's substeps (e.g. a density pass at the frame's positions)."""

    def checkpoint_arrays(self) -> dict[str, Any]:
        """Arrays (wp.array or NumPy) a resume needs besides positions and velocities, by name."""
        return {}

    def restore_arrays(self, arrays: Mapping[str, Any]) -> None:
        """Restore what ``checkpoint_arrays`` saved (after the state's x and v were restored)."""

    def instability_hint(self, rule: str, stage: str | None) -> str | None:
        """The likely cause of a watchdog finding (rule: "non_finite", "outside", "fast", "dense", "energy";
        stage None for "energy") in this solver's terms, with the scene key to change; None when the generic
        advice applies."""
        return None

    def equation_of_state(self) -> tuple[str, float] | None:
        """("linear" | "tait", K [Pa]) when the pressure is a clamped equation of state of the density
        (p = K (rho/rho0 - 1) or K ((rho/rho0)^7 - 1), >= 0), whose compression energy the energy watchdog
        then counts in the total (``warp_sph.run.watchdog``); None for a solver that stores no energy in
        compression (an incompressible projection: PBF, DFSPH). Default: the section's
        ``equation_of_state`` with the solver's ``stiffness`` attribute when it has both (WCSPH), else None."""
        eos = getattr(self.config, "equation_of_state", None)
        k = getattr(self, "stiffness", None)
        return (eos, float(k)) if eos in ("linear", "tait") and k else None

    def summary(self) -> dict:
        """Constants of this solver for run.json (``model.solver``) and ``warp-sph check``."""
        return {}
