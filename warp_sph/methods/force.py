"""The non-pressure force interface: viscosity, surface tension, vorticity, velocity filters.

A force is one host module in ``warp_sph/methods/forces/`` with a ``Force`` subclass decorated with
``@register_force``, one kernels module of the same name in ``kernels/`` and one test. A scene lists
its forces as an array of tables, each naming its method and the method's parameters::

    [[forces]]
    method = "explicit_viscosity"
    viscosity = 0.01

Only the forces a scene names exist in the run: a force it does not name (or one whose coefficient is
0, ``Force.is_active``) has no stage, no workspace array, no time-step bound and costs nothing. At
most one force of each ``kind`` (viscosity, surface tension, vorticity, filter), as SPlisHSPlasH's
one-method-per-family rule.

Where forces act is the solver's choice, never the force's: each solver calls the family's stages at
its named slot (``ForceSlot``). Within a slot the phases run in this order (SPlisHSPlasH's
``computeNonPressureForces`` semantics, research note forces.md 1.1):

1. ``explicit`` forces each *add* their acceleration [m/s^2] into the workspace field
   ``force_acceleration`` (cleared by the family before the first of them), all from the same v;
2. ``apply`` (a shared stage, not a force): v += dt force_acceleration plus the boundary method's own
   non-pressure term (Akinci friction, a penalty force). WCSPH has no apply stage: its force kernel
   adds ``force_acceleration`` to the pressure acceleration and integrates once;
3. ``implicit`` forces change ``particle_v`` in place, on v* (after the explicit kick; with
   ``slot.gravity_in_velocity`` False the solver adds this step's dt g later, so an implicit solve
   that must damp gravity's kick adds and removes it itself);
4. ``filter`` forces (XSPH) smooth ``particle_v`` last.

Slots of the built-in solvers: DFSPH ``before_pressure`` (after the divergence solve, before the
density source: the density solve projects whatever the forces did), WCSPH ``before_pressure``
(explicit forces read the state the pressure forces read; filters before them, as XSPH always ran
there; implicit ones between the velocity kick and the position drift), PBF ``after_update`` (on the
new velocity after the projection, as Macklin & Mueller 2013 and SPlisHSPlasH).

A force provides: ``name``, ``title``, ``kind``, ``mode``, ``parameters`` (rows ``<name>.<key>``, shown
in the parameter table as ``forces[<name>].<key>``), ``legacy_keys`` (old scene keys that still set
it), ``is_active(config)``, ``validate_config(scene, config, keypath, fail)`` (cross-checks, before any
kernel), ``refuses_solver(solver_cls)``, ``stages(slot)``, ``time_step_bounds(speed)``,
``carried_fields()`` (workspace fields that outlive a substep: allocate them with ``sim.allocate`` and
they follow the particle-order permutation), ``checkpoint_arrays()`` / ``restore_arrays(arrays)``,
``step_statistics()``, ``instability_hint(rule, stage)``, ``summary()``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, ClassVar, Mapping

import numpy as np
import warp as wp

from ..core.step_graph import Stage
from . import registry
from .density import neighbor_args
from .force_apply import FORCE_ACCELERATION, apply_stage as _apply_stage
from .registry import FORCE_KINDS, FORCE_MODES
from .solver import MethodBase, TimeStepBound

#: (FORCE_ACCELERATION, the workspace field the explicit forces add into, lives in force_apply.py)


@dataclass(frozen=True)
class ForceSlot:
    """Where a solver hosts the non-pressure forces.

    name: "before_pressure" (DFSPH, WCSPH) or "after_update" (PBF); neighbors: "list" (the step's
    ``neighbor_lists``) or "grid" (``fluid_grid`` queries); positions: the positions field the
    neighbours were found for; gravity_in_velocity: True when particle_v already holds this step's
    dt g (PBF, WCSPH after its kick), False when the solver adds it after the slot (DFSPH).
    """

    name: str
    neighbors: str = "list"
    positions: str = "particle_x"
    gravity_in_velocity: bool = True
    acceleration: str = FORCE_ACCELERATION

    @property
    def lists(self) -> bool:
        return self.neighbors == "list"

    @property
    def neighbor_field(self) -> str:
        """The workspace field a stage reads for its neighbours."""
        return "neighbor_lists" if self.lists else "fluid_grid"

    def neighbor_arg(self, sim):
        """The neighbour argument of a kernel launch (``kernels.density.NEIGHBOR_TYPES``)."""
        return neighbor_args(sim, self.lists)[1]

    def boundary_neighbor_arg(self, sim):
        """The boundary-neighbour argument of a kernel launch (the lists' boundary part, or the boundary hash
        grid); a stage that reads it declares ``boundary_x`` and ``boundary_volume`` (and ``boundary_grid``
        without lists; ``boundary_v`` with moving bodies)."""
        return neighbor_args(sim, self.lists)[0]


class Force(MethodBase):
    """Base class of the non-pressure forces (see the module docstring). ``sim`` is the Simulation,
    ``config`` the scene's settings of this force (``config_class``), ``keypath`` where the scene set
    it (``forces[0]`` or a legacy key such as ``material.viscosity``), for messages."""

    #: the family: one of FORCE_KINDS
    kind: ClassVar[str] = ""
    #: "explicit" (adds to force_acceleration), "implicit" (changes v on v*) or "filter" (smooths v)
    mode: ClassVar[str] = "explicit"
    #: old scene keys that set this force: {"material.viscosity": "viscosity"} (old key -> this force's
    #: key); active when the old key is not its default (a key of a solver's section only with that solver)
    legacy_keys: ClassVar[dict[str, str]] = {}
    #: True for a force that stores energy the energy watchdog does not count (surface tension: surface
    #: energy) or puts energy in by design (vorticity confinement): with it in a scene the watchdog's
    #: energy rule is off (``warp_sph.run.energy``); the energies are still measured and recorded
    stores_energy: ClassVar[bool] = False

    def __init__(self, sim, config, keypath: str):
        self.sim = sim
        self.model = sim.model
        self.config = config
        self.keypath = keypath

    @classmethod
    def config_class(cls):
        """The dataclass of one ``[[forces]]`` entry of this method (``method`` is a class attribute)."""
        key = (cls, cls.parameters, "force")
        made = MethodBase._config_classes.get(key)
        if made is None:
            from ..scene.types import section_class

            made = MethodBase._config_classes[key] = section_class(cls.name, cls.parameters, {"method": cls.name},
                                                                   doc=cls.title)
        return made

    @classmethod
    def key_path(cls, keypath: str, key: str) -> str:
        """The scene key of parameter ``key`` of the entry at ``keypath`` (``forces[0].viscosity``, or the
        legacy key itself)."""
        if keypath.startswith("forces["):
            return f"{keypath}.{key}"
        return keypath

    @classmethod
    def is_active(cls, config) -> bool:
        """False when these settings make the force do nothing (e.g. a coefficient of 0): no stage."""
        return True

    @classmethod
    def validate_config(cls, scene, config, keypath: str, fail) -> None:
        """Cross-checks of one entry, before anything is built; ``fail(keypath, message)`` refuses."""

    @classmethod
    def refuses_solver(cls, solver_cls) -> str | None:
        """A reason why ``solver_cls`` cannot host this force, or None (it can)."""
        return None

    def stages(self, slot: ForceSlot) -> list[Stage]:
        """The force's stages at ``slot`` (explicit: they add to ``slot.acceleration``, declared in
        ``updates``; implicit and filter: they update ``particle_v``)."""
        raise NotImplementedError

    def time_step_bounds(self, speed: float) -> list[TimeStepBound]:
        """Bounds of the step this force needs at flow speed ``speed`` [m/s]."""
        return []

    def carried_fields(self) -> tuple[str, ...]:
        """Workspace fields that outlive a substep (inputs of the step graph), e.g. a warm start. Allocate
        them with ``sim.allocate`` (one value per fluid particle) when the force is built: they then follow
        the particle-order permutation, and the default ``checkpoint_arrays`` / ``restore_arrays`` save and
        restore them (name them after the force, e.g. ``weiler2018_dv``)."""
        return ()

    def checkpoint_arrays(self) -> dict[str, Any]:
        """Arrays a resume needs, by name (default: the carried fields)."""
        return {name: self.sim.fields[name] for name in self.carried_fields()}

    def restore_arrays(self, arrays: Mapping[str, Any]) -> None:
        """Restore what ``checkpoint_arrays`` saved (default: the carried fields; zero when absent)."""
        for name in self.carried_fields():
            field = self.sim.fields[name]
            if name in arrays:
                a = arrays[name]
                field.assign(a if isinstance(a, wp.array) else wp.array(np.asarray(a), dtype=field.dtype,
                                                                         device=field.device))
            else:
                field.zero_()

    def step_statistics(self) -> dict[str, float]:
        """Host-side figures of the last substep (e.g. iterations), merged into the solver's per-frame
        statistics (mean and max per frame in run.json); names must not clash with the solver's."""
        return {}

    def instability_hint(self, rule: str, stage: str | None) -> str | None:
        """The likely cause of a watchdog finding in this force's terms, or None."""
        return None

    def summary(self) -> dict:
        """Constants of this force for run.json and ``warp-sph check``."""
        return {}


# --------------------------------------------------------------------------------------------
# The scene's forces
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ForceEntry:
    """One force of a scene: its class, its settings and the key path that set it."""

    cls: type
    config: Any
    keypath: str


def scene_forces(scene) -> list[ForceEntry]:
    """The forces of ``scene``: its ``[[forces]]`` entries and the forces set by legacy keys
    (``material.viscosity``, ``material.xsph``, ``pbf.vorticity``), in scene order then legacy order."""

    out = [ForceEntry(registry.force(c.method), c, f"forces[{i}]") for i, c in enumerate(scene.forces)]
    for name, cls in registry.forces().items():
        for old, key in cls.legacy_keys.items():
            value = _legacy_value(scene, old)
            if value is None:
                continue
            config = replace(cls.config_class()(), **{key: value})
            out.append(ForceEntry(cls, config, old))
    return out


def _legacy_value(scene, path: str):
    """The value of legacy key ``path`` when it is set to something other than its default, else None."""
    from ..scene.parameters import all_parameters

    section, _, key = path.rpartition(".")
    if section in registry.solvers() and scene.solver != section:
        return None
    table = getattr(scene, section, None) if section in ("material",) else scene.sections.get(section)
    if table is None:
        return None
    value = getattr(table, key)
    default = next((p.default for p in all_parameters() if p.path == path), None)
    return None if value == default else value


def check_scene_forces(scene, fail) -> None:
    """Validation of the scene's forces (``scene.validate``): one of each kind, hosted by the solver, each
    force's own cross-checks. ``fail(keypath, message)`` raises."""

    solver_cls = registry.solver(scene.solver)
    seen: dict[str, ForceEntry] = {}
    for entry in scene_forces(scene):
        cls = entry.cls
        other = seen.get(cls.kind)
        if other is not None:
            fail(entry.keypath, f"a second {cls.kind.replace('_', ' ')} force ({cls.name!r}); {other.keypath} already "
                 f"sets {other.cls.name!r}: a scene has at most one force of each kind, remove one")
        seen[cls.kind] = entry
        refusal = cls.refuses_solver(solver_cls)
        if refusal:
            fail(entry.keypath, f"force {cls.name!r} does not work with solver {scene.solver!r}: {refusal}")
        cls.validate_config(scene, entry.config, entry.keypath, fail)


class SimulationForces:
    """The active forces of a simulation and the stages of each phase at a solver's slot."""

    def __init__(self, sim):
        self.sim = sim
        order = {mode: k for k, mode in enumerate(FORCE_MODES)}
        kinds = {kind: k for k, kind in enumerate(FORCE_KINDS)}
        entries = [e for e in scene_forces(sim.scene) if e.cls.is_active(e.config)]
        entries.sort(key=lambda e: (order[e.cls.mode], kinds.get(e.cls.kind, len(kinds))))
        self.forces: list[Force] = [e.cls(sim, e.config, e.keypath) for e in entries]

    def __iter__(self):
        return iter(self.forces)

    def __len__(self) -> int:
        return len(self.forces)

    def of_mode(self, mode: str) -> list[Force]:
        return [f for f in self.forces if f.mode == mode]

    @property
    def has_explicit(self) -> bool:
        """True when an explicit force adds to ``force_acceleration`` (a solver that integrates the
        accelerations itself, as WCSPH, then reads it)."""
        return bool(self.of_mode("explicit"))

    def explicit_stages(self, slot: ForceSlot) -> list[Stage]:
        """The explicit forces' stages; the first one also clears ``force_acceleration`` (written)."""
        stages: list[Stage] = []
        for force in self.of_mode("explicit"):
            stages += force.stages(slot)
        if stages:
            field = slot.acceleration
            self.sim.allocate(field, wp.vec3)
            first = stages[0]
            run = first.run

            def clear_then_run(sim, dt, run=run):
                sim.fields[field].zero_()
                run(sim, dt)

            stages[0] = replace(first, run=clear_then_run, writes=tuple(first.writes) + (field,),
                                updates=tuple(u for u in first.updates if u != field))
        return stages

    def apply_stage(self, slot: ForceSlot, name: str = "apply_forces") -> Stage | None:
        """v += dt force_acceleration + the boundary method's non-pressure velocity change (None when the
        scene has neither). The boundary term's force on the walls (m a_boundary [N]) is added to
        ``boundary_force``."""
        return _apply_stage(self.sim, slot, self.has_explicit, name)

    def implicit_stages(self, slot: ForceSlot) -> list[Stage]:
        return [s for f in self.of_mode("implicit") for s in f.stages(slot)]

    def filter_stages(self, slot: ForceSlot) -> list[Stage]:
        return [s for f in self.of_mode("filter") for s in f.stages(slot)]

    def stages(self, slot: ForceSlot) -> list[Stage]:
        """Every phase at ``slot`` in order: explicit, apply, implicit, filter (DFSPH and PBF)."""
        apply = self.apply_stage(slot)
        return (self.explicit_stages(slot) + ([apply] if apply is not None else []) + self.implicit_stages(slot)
                + self.filter_stages(slot))

    # --- what the simulation collects ----------------------------------------------------------
    def time_step_bounds(self, speed: float) -> list[TimeStepBound]:
        return [b for f in self.forces for b in f.time_step_bounds(speed)]

    def carried_fields(self) -> tuple[str, ...]:
        return tuple(name for f in self.forces for name in f.carried_fields())

    def checkpoint_arrays(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in self.forces:
            out.update(f.checkpoint_arrays())
        return out

    def restore_arrays(self, arrays: Mapping[str, Any]) -> None:
        for f in self.forces:
            f.restore_arrays(arrays)

    def step_statistics(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for f in self.forces:
            out.update(f.step_statistics())
        return out

    def instability_hint(self, rule: str, stage: str | None) -> str | None:
        for f in self.forces:
            hint = f.instability_hint(rule, stage)
            if hint:
                return hint
        return None

    def summary(self) -> list[dict]:
        return [{"method": f.name, "kind": f.kind, "set_by": f.keypath, **f.summary()} for f in self.forces]

