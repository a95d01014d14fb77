"""Typed scene values: a dataclass per table, generated from the parameter rows (defaults written once).

``section_class(section, rows)`` makes the dataclass of one table (``material``, ``time``, a method's
section ...); its docstring lists the keys with units. ``Scene`` holds the top-level values, the core
tables and one section object per registered method (``scene.pbf``, ``scene.section("pbf")``).
"""
from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from ..core.smoothing import get_smoothing_kernel, wall_gap
from ..methods.registry import DEFAULT_BOUNDARY, DEFAULT_SOLVER
from .parameters import REQUIRED, TABLE_KINDS, Param, by_section, core_parameters

Vec3 = tuple[float, float, float]


def _field_default(p: Param):
    if p.default is REQUIRED or p.shapes is not None:
        return field(default=None)
    d = p.default
    if isinstance(d, (list, tuple)) and p.kind == "str_list":
        return field(default_factory=lambda d=tuple(d): list(d))
    return field(default=copy.copy(d))


def section_class(section: str, rows, namespace: dict | None = None, doc: str = "", nested: tuple = ()):
    """The dataclass of table ``section`` from its parameter rows (one field per key, its default); the
    table-valued keys named in ``nested`` become fields too (default None: absent)."""
    fields = [(p.key, Any, _field_default(p)) for p in rows if p.kind not in TABLE_KINDS]
    fields += [(key, Any, field(default=None)) for key in nested]
    name = "".join(part.capitalize() for part in section.replace("[]", "").split("_")) or "Section"
    keys = "; ".join(f"{p.key} [{p.unit}]" for p in rows if p.kind not in TABLE_KINDS)
    cls = dataclasses.make_dataclass(name, fields, namespace=dict(namespace or {}))
    cls.__doc__ = (doc + "\n\n" if doc else "") + f"Table ``{section}``: {keys}."
    return cls


def _bounds(self) -> tuple[Vec3, Vec3]:
    """Axis-aligned bounding box (min, max) [m]."""
    if self.shape == "sphere":
        c, r = self.center, self.radius
        return tuple(x - r for x in c), tuple(x + r for x in c)
    if self.shape == "mesh":
        lo, hi = self.mesh().bounds
        return tuple(map(float, lo)), tuple(map(float, hi))
    return self.min, self.max


def _mesh(self):
    """The block's triangle mesh (shape "mesh") with its scale and translate applied [m]."""
    from .meshes import load_triangle_mesh_cached

    return load_triangle_mesh_cached(self.file).transformed(self.scale, self.translate)


def _volume(self) -> float:
    """Volume of the block [m^3]: box extent product, 4/3 pi R^3, or the mesh's enclosed volume."""
    if self.shape == "sphere":
        return 4.0 / 3.0 * math.pi * self.radius**3
    if self.shape == "mesh":
        from .mesh_volume import signed_volume

        return abs(signed_volume(self.mesh()))
    return float(math.prod(b - a for a, b in zip(self.min, self.max)))


_CORE = by_section(core_parameters())
Material = section_class("material", _CORE["material"].values(), doc="Fluid material.")
TimeParams = section_class("time", _CORE["time"].values(), doc="Time stepping.")
Container = section_class("container", _CORE["container"].values(),
                          doc="Axis-aligned box of walls [m]; its six faces are sampled as boundary particles.")
OutputParams = section_class("output", _CORE["output"].values(), doc="What a run writes.")
FluidBlock = section_class("fluid[]", _CORE["fluid[]"].values(), {"bounds": _bounds, "mesh": _mesh, "volume": _volume},
                           doc="A block of fluid sampled on a lattice; keys of the other shapes are None (file: the "
                               "absolute path after loading).")
Obstacle = section_class("obstacles[]", _CORE["obstacles[]"].values(), {"animated": property(lambda self: bool(
                             self.keyframes or self.animation))}, nested=("keyframes", "animation"),
                         doc="An obstacle sampled on its surface as boundary particles, static or (``animated``: "
                             "keyframes or animation given) moving along a path (``warp_sph.scene.paths``); keys of "
                             "the other shape are None (file: the absolute path after loading).")

Body = section_class("bodies[]", _CORE["bodies[]"].values(),
                     doc="A moving rigid body (``warp_sph.rigid``); keys of other shapes are None (file: the "
                         "absolute path after loading).")
Body.__name__ = Body.__qualname__ = "Body"
Probe = section_class("probes[]", _CORE["probes[]"].values(),
                      doc="A probe sampled during the run (``warp_sph.run.probes``); keys of other kinds are None.")
Probe.__name__ = Probe.__qualname__ = "Probe"
Emitter = section_class("emitters[]", _CORE["emitters[]"].values(),
                        doc="A nozzle emitting fluid (``warp_sph.run.emission``); keys of the other shape are None.")
Emitter.__name__ = Emitter.__qualname__ = "Emitter"
Sink = section_class("sinks[]", _CORE["sinks[]"].values(), doc="A box that removes fluid (``warp_sph.run.emission``).")
Sink.__name__ = Sink.__qualname__ = "Sink"
RigidParams = section_class("rigid", _CORE["rigid"].values(), doc="Contacts of the rigid bodies.")
WhitewaterParams = section_class("whitewater", _CORE["whitewater"].values(),
                                 doc="Spray, foam and air bubbles (``warp_sph.run.whitewater``).")
PlanParams = section_class("plan", _CORE["plan"].values(), doc="The prediction of warp-sph plan (docs/plan.md).")

#: core section name -> class (method sections come from the registry)
CORE_SECTIONS = {"material": Material, "time": TimeParams, "container": Container, "output": OutputParams,
                 "fluid[]": FluidBlock, "obstacles[]": Obstacle, "bodies[]": Body, "rigid": RigidParams,
                 "probes[]": Probe, "whitewater": WhitewaterParams, "emitters[]": Emitter, "sinks[]": Sink,
                 "plan": PlanParams}


@dataclass
class Scene:
    """A validated scene, SI units. Build with ``load_scene`` or ``scene_from_dict``.

    particle_radius r [m] (spacing d = 2r); boundary_gap [d] (None: auto, see ``wall_gap``);
    gravity [m/s^2]; duration [s]; fps [1/s]; container None means no walls; forces: the ``[[forces]]``
    entries as written (each a ``Force.config_class()`` object with its ``method``; the forces legacy keys
    set are added by ``warp_sph.methods.force.scene_forces``). ``sections`` holds one
    settings object per registered method (solvers and boundaries with parameters), also reachable as
    attributes (``scene.pbf.max_iterations``). ``source`` (the file it came from) is not part of the
    scene's value and is left out of ``to_dict`` and comparisons.
    """

    name: str = ""
    description: str = ""
    particle_radius: float = 0.025
    smoothing_kernel: str = "cubic"
    h_per_spacing: float | None = None
    solver: str = DEFAULT_SOLVER
    boundary: str = DEFAULT_BOUNDARY
    boundary_gap: float | None = None
    gravity: Vec3 = (0.0, 0.0, -9.81)
    duration: float = 2.0
    fps: float = 24.0
    material: Any = field(default_factory=Material)
    time: Any = field(default_factory=TimeParams)
    container: Any = field(default_factory=Container)
    fluid: list = field(default_factory=list)
    obstacles: list = field(default_factory=list)
    bodies: list = field(default_factory=list)
    forces: list = field(default_factory=list)
    probes: list = field(default_factory=list)
    max_particles: int = 0
    emitters: list = field(default_factory=list)
    sinks: list = field(default_factory=list)
    rigid: Any = field(default_factory=RigidParams)
    whitewater: Any = None  # WhitewaterParams when the scene has [whitewater]
    output: Any = field(default_factory=OutputParams)
    plan: Any = None  # PlanParams when the scene has a [plan] table (``warp-sph plan --apply``)
    sections: dict = field(default_factory=dict)
    source: str = field(default="<dict>", compare=False, repr=False)
    #: container.inner as written (``scene.container.given_box``): what ``to_dict`` gives back, so that a scene
    #: changed and loaded again (another radius) places its walls anew; not part of the scene's value
    inner_given: Any = field(default=None, compare=False, repr=False)

    def __getattr__(self, name: str):
        sections = self.__dict__.get("sections")
        if sections is not None and name in sections:
            return sections[name]
        raise AttributeError(f"Scene has no attribute or method section {name!r}")

    def section(self, name: str):
        """The settings of method ``name`` (its scene table), e.g. ``scene.section("pbf")``."""
        return self.sections[name]

    @property
    def spacing(self) -> float:
        """Rest particle spacing d = 2 r [m]."""
        return 2.0 * self.particle_radius

    @property
    def smoothing_length(self) -> float:
        """Smoothing length h [m]: h_per_spacing * d, or the kernel's default."""
        kernel = get_smoothing_kernel(self.smoothing_kernel)
        if self.h_per_spacing is None:
            return kernel.default_smoothing_length(self.spacing)
        return self.h_per_spacing * self.spacing

    @property
    def support_radius(self) -> float:
        """Support radius H_s of the smoothing kernel [m]: the neighbour-search radius."""
        return get_smoothing_kernel(self.smoothing_kernel).support_radius(self.smoothing_length)

    @property
    def wall_gap(self) -> float:
        """Initial distance [m] from boundary particles to the nearest fluid centres: boundary_gap * d,
        or (boundary_gap absent) the distance at which the first fluid layer over one Akinci wall
        layer sits at rest density with this kernel and h (``smoothing.wall_gap``)."""
        if self.boundary_gap is not None:
            return self.boundary_gap * self.spacing
        lattice = "fcc" if any(b.lattice == "fcc" for b in self.fluid) else "cubic"
        return wall_gap(self.smoothing_kernel, self.smoothing_length, self.spacing, lattice)

    def to_dict(self) -> dict:
        """The scene with every default filled in, as plain TOML/JSON types.

        None-valued optional keys are left out (TOML has no null); no container is
        ``container = false``; method sections are top-level tables.
        ``scene_from_dict(scene.to_dict()) == scene``.
        """
        out = _plain(self)
        if self.inner_given is not None:  # container.inner: the box and probes as written, not the wall planes
            from .container import given_box

            given_box(self, out)
        out["forces"] = [{"method": f.method, **_plain(f)} for f in self.forces]
        if not out["forces"]:
            del out["forces"]  # as written: a scene without forces has no [[forces]]
        sections = out.pop("sections", {})
        for name, values in sections.items():
            out[name] = values
        return out


def _plain(obj):
    if dataclasses.is_dataclass(obj):
        out = {}
        for f in dataclasses.fields(obj):
            if f.name in ("source", "inner_given"):
                continue
            value = getattr(obj, f.name)
            if f.name == "container" and value is None:
                out[f.name] = False
            elif value is not None:
                out[f.name] = _plain(value)
        return out
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    return obj
