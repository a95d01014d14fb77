"""The registry of methods by name: pressure solvers, boundary methods and non-pressure forces.

Every module in ``warp_sph/methods/solvers/``, ``warp_sph/methods/boundaries/`` and
``warp_sph/methods/forces/`` is imported on first use, and its classes register themselves with
``@register_solver`` / ``@register_boundary`` / ``@register_force``. The scene's ``solver`` and
``boundary`` choices and its ``[[forces]]`` methods, the method sections of the parameter table (and so
validation and the scene-file reference), the watchdog's advice and the benchmark solver lists all read this
registry; nothing else lists methods. A solver defined elsewhere (a test, a user's script) registers
the same way and is then a valid ``solver`` value.
"""
from __future__ import annotations

import importlib
import pkgutil

from ..core.errors import SceneError

DEFAULT_SOLVER = "dfsph"
#: the families a force belongs to; a scene has at most one force of each
FORCE_KINDS = ("vorticity", "surface_tension", "viscosity", "drag", "filter")
#: the phases of a slot, in the order they run (warp_sph.methods.force)
FORCE_MODES = ("explicit", "implicit", "filter")
DEFAULT_BOUNDARY = "akinci2012"
#: table names a method section may not take
RESERVED_SECTIONS = frozenset({"material", "time", "container", "fluid", "obstacles", "output", "name",
                               "description", "solver", "boundary", "gravity", "duration", "fps", "forces",
                               "method"})

_solvers: dict = {}
_boundaries: dict = {}
_forces: dict = {}
_discovered = False


def _discover() -> None:
    global _discovered
    if _discovered:
        return
    _discovered = True
    for package in ("solvers", "boundaries", "forces"):
        pkg = importlib.import_module(f"{__package__}.{package}")
        for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
            importlib.import_module(f"{pkg.__name__}.{info.name}")
    # a built-in whose module was imported before this discovery (a script, a test file) keeps its place: the
    # built-ins in module-name order, then the methods registered from elsewhere in their order
    for table in (_solvers, _boundaries, _forces):
        items = list(table.items())
        builtin = sorted((kv for kv in items if kv[1].__module__.startswith(f"{__package__}.")),
                         key=lambda kv: kv[1].__module__)
        table.clear()
        table.update(builtin + [kv for kv in items if not kv[1].__module__.startswith(f"{__package__}.")])


def _register(table: dict, others: tuple, cls, kind: str):
    name = getattr(cls, "name", "")
    if not name or not name.isidentifier():
        raise ValueError(f"{kind} {cls.__name__}: class attribute 'name' must be an identifier, got {name!r}")
    if name in RESERVED_SECTIONS or any(name in o for o in others) or (name in table and table[name] is not cls):
        raise ValueError(f"{kind} name {name!r} is already taken")
    for p in cls.parameters:
        if p.section != name:
            raise ValueError(f"{kind} {name!r}: parameter {p.path!r} must be in its own section {name!r}.")
    table[name] = cls
    return cls


def register_solver(cls):
    """Class decorator: make ``cls`` (a ``warp_sph.methods.solver.Solver``) the solver named ``cls.name``."""
    return _register(_solvers, (_boundaries, _forces), cls, "solver")


def register_boundary(cls):
    """Class decorator: make ``cls`` (a ``warp_sph.methods.boundary.BoundaryMethod``) the boundary ``cls.name``."""
    return _register(_boundaries, (_solvers, _forces), cls, "boundary method")


def register_force(cls):
    """Class decorator: make ``cls`` (a ``warp_sph.methods.force.Force``) the force ``cls.name`` (a scene's
    ``[[forces]] method``)."""

    if cls.kind not in FORCE_KINDS:
        raise ValueError(f"force {cls.__name__}: kind must be one of {', '.join(FORCE_KINDS)}, got {cls.kind!r}")
    if cls.mode not in FORCE_MODES:
        raise ValueError(f"force {cls.__name__}: mode must be one of {', '.join(FORCE_MODES)}, got {cls.mode!r}")
    return _register(_forces, (_solvers, _boundaries), cls, "force")


def unregister(name: str) -> None:
    """Remove a registered solver, boundary method or force (e.g. one a test defined)."""
    _solvers.pop(name, None)
    _boundaries.pop(name, None)
    _forces.pop(name, None)


def solvers() -> dict:
    """{name: Solver class}: the built-in solvers in name order, then any registered later."""
    _discover()
    return dict(_solvers)


def boundaries() -> dict:
    """{name: BoundaryMethod class}."""
    _discover()
    return dict(_boundaries)


def forces() -> dict:
    """{name: Force class}."""
    _discover()
    return dict(_forces)


def force_names() -> tuple[str, ...]:
    return tuple(forces())


def solver_names() -> tuple[str, ...]:
    return tuple(solvers())


def boundary_names() -> tuple[str, ...]:
    return tuple(boundaries())


def solver(name: str):
    """The Solver class registered as ``name``; SceneError listing the valid names otherwise."""
    table = solvers()
    if name not in table:
        raise SceneError(f"unknown solver {name!r}; expected one of {', '.join(table)}")
    return table[name]


def boundary(name: str):
    """The BoundaryMethod class registered as ``name``; SceneError listing the valid names otherwise."""
    table = boundaries()
    if name not in table:
        raise SceneError(f"unknown boundary method {name!r}; expected one of {', '.join(table)}")
    return table[name]


def force(name: str):
    """The Force class registered as ``name``; SceneError listing the valid names otherwise."""
    table = forces()
    if name not in table:
        raise SceneError(f"unknown force method {name!r}; expected one of {', '.join(table)}")
    return table[name]


def methods_with_parameters() -> dict:
    """{section name: method class} of every registered solver and boundary method that has scene parameters
    (forces have theirs in ``[[forces]]`` entries, ``forces()``)."""
    return {name: cls for name, cls in list(solvers().items()) + list(boundaries().items()) if cls.parameters}
