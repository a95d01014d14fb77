"""The registry of methods by name: pressure solvers and boundary methods.

Every module in ``warp_sph/methods/solvers/`` and ``warp_sph/methods/boundaries/`` is imported on
first use, and its classes register themselves with ``@register_solver`` / ``@register_boundary``.
The scene's ``solver`` and ``boundary`` choices, the method sections of the parameter table (and so
validation and the scene-file reference), the watchdog's advice and the benchmark solver lists all read this
registry; nothing else lists methods. A solver defined elsewhere (a test, a user's script) registers
the same way and is then a valid ``solver`` value.
"""
from __future__ import annotations

import importlib
import pkgutil

from ..core.errors import SceneError

DEFAULT_SOLVER = "dfsph"
DEFAULT_BOUNDARY = "akinci2012"
#: table names a method section may not take
RESERVED_SECTIONS = frozenset({"material", "time", "container", "fluid", "obstacles", "output", "name",
                               "description", "solver", "boundary", "gravity", "duration", "fps"})

_solvers: dict = {}
_boundaries: dict = {}
_discovered = False


def _discover() -> None:
    global _discovered
    if _discovered:
        return
    _discovered = True
    for package in ("solvers", "boundaries"):
        pkg = importlib.import_module(f"{__package__}.{package}")
        for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
            importlib.import_module(f"{pkg.__name__}.{info.name}")


def _register(table: dict, other: dict, cls, kind: str):
    name = getattr(cls, "name", "")
    if not name or not name.isidentifier():
        raise ValueError(f"{kind} {cls.__name__}: class attribute 'name' must be an identifier, got {name!r}")
    if name in RESERVED_SECTIONS or name in other or (name in table and table[name] is not cls):
        raise ValueError(f"{kind} name {name!r} is already taken")
    for p in cls.parameters:
        if p.section != name:
            raise ValueError(f"{kind} {name!r}: parameter {p.path!r} must be in its own section {name!r}.")
    table[name] = cls
    return cls


def register_solver(cls):
    """Class decorator: make ``cls`` (a ``warp_sph.methods.solver.Solver``) the solver named ``cls.name``."""
    return _register(_solvers, _boundaries, cls, "solver")


def register_boundary(cls):
    """Class decorator: make ``cls`` (a ``warp_sph.methods.boundary.BoundaryMethod``) the boundary ``cls.name``."""
    return _register(_boundaries, _solvers, cls, "boundary method")


def unregister(name: str) -> None:
    """Remove a registered solver or boundary method (e.g. one a test defined)."""
    _solvers.pop(name, None)
    _boundaries.pop(name, None)


def solvers() -> dict:
    """{name: Solver class}: the built-in solvers in name order, then any registered later."""
    _discover()
    return dict(_solvers)


def boundaries() -> dict:
    """{name: BoundaryMethod class}."""
    _discover()
    return dict(_boundaries)


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


def methods_with_parameters() -> dict:
    """{section name: method class} of every registered method that has scene parameters."""
    return {name: cls for name, cls in list(solvers().items()) + list(boundaries().items()) if cls.parameters}
