"""Scene description: typed dataclasses in SI units, loaded from TOML and validated up front.

Every parameter is declared once, in ``PARAMETERS``: key path, type, unit, default, valid range
or choices and a one-line description. That table drives validation, defaults, ``--set``
overrides and the README table (``parameter_table_markdown``). A bad scene raises
``SceneError`` with the file, the key path (``fluid[1].min``) and what was expected, before any
kernel runs.

Key paths: ``particle_radius`` (top level), ``material.rest_density`` (a table),
``fluid[0].max`` (an element of an array of tables; in the table written ``fluid[].max``).
"""
from __future__ import annotations

import copy
import dataclasses
import importlib.resources
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..core.errors import SceneError
from .meshes import load_triangle_mesh
from ..core.smoothing import SMOOTHING_KERNELS, get_smoothing_kernel, wall_gap

Vec3 = tuple[float, float, float]

SOLVERS = ("wcsph", "pbf")
BOUNDARY_METHODS = ("akinci2012", "penalty")
EQUATIONS_OF_STATE = ("linear", "tait")
MESH_SEQUENCE_FORMATS = ("", "obj", "ply", "vtk")
PARTICLE_PRIMVARS = ("density", "pressure")
FLUID_SHAPES = ("box", "sphere")
OBSTACLE_SHAPES = ("box", "mesh")


# --------------------------------------------------------------------------------------------
# Parameter definitions
# --------------------------------------------------------------------------------------------
class _Required:
    def __repr__(self):
        return "required"


REQUIRED: Any = _Required()


@dataclass(frozen=True)
class Param:
    """Definition of one scene parameter.

    path: key path; ``a.b`` for a key of table ``a``, ``a[].b`` for a key of array of tables ``a``.
    kind: "float", "int", "bool", "str", "vec3", "str_list", "table", "tables" or "table_or_false".
    unit: SI unit, "-" for dimensionless.
    default: value when absent (REQUIRED: must be given; None: optional, meaning in ``doc``).
    gt/ge/lt/le: numeric bounds; choices: allowed strings.
    shapes: for fluid/obstacle keys, the shapes that use the key (None: every shape).
    """

    path: str
    kind: str
    unit: str
    default: Any
    doc: str
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[str, ...] | None = None
    shapes: tuple[str, ...] | None = None
    default_text: str | None = None

    @property
    def section(self) -> str:
        return self.path.rpartition(".")[0]

    @property
    def key(self) -> str:
        return self.path.rpartition(".")[2]

    def expected(self) -> str:
        """What a valid value looks like, in words (used in error messages and the README)."""
        if self.choices is not None:
            opts = ", ".join(repr(c) for c in self.choices)
            return f"a list of strings from {opts}" if self.kind == "str_list" else f"one of {opts}"
        base = {
            "float": "a finite number",
            "int": "an integer",
            "bool": "true or false",
            "str": "a string",
            "vec3": "a list of 3 finite numbers",
            "table": "a table",
            "tables": "an array of tables ([[...]])",
            "table_or_false": "a table or false",
        }[self.kind]
        bounds = self.range_text()
        return f"{base} {bounds}" if bounds else base

    def range_text(self) -> str:
        parts = []
        if self.gt is not None:
            parts.append(f"> {self.gt:g}")
        if self.ge is not None:
            parts.append(f">= {self.ge:g}")
        if self.lt is not None:
            parts.append(f"< {self.lt:g}")
        if self.le is not None:
            parts.append(f"<= {self.le:g}")
        return " and ".join(parts)


_P = Param
_KERNEL_NAMES = tuple(SMOOTHING_KERNELS)

#: The one table of scene parameters.
PARAMETERS: tuple[Param, ...] = (
    _P("name", "str", "-", "", "scene name (default: the file name without .toml)"),
    _P("description", "str", "-", "", "one-line description"),
    _P("particle_radius", "float", "m", 0.025, "particle radius r; the lattice spacing is d = 2r", gt=0.0),
    _P("smoothing_kernel", "str", "-", "cubic", "smoothing kernel W (Liu & Liu 2010)", choices=_KERNEL_NAMES),
    _P("h_per_spacing", "float", "-", None, "smoothing length h / d (absent: the kernel's default: "
       "1 for cubic and quadric, 2/3 for quintic, i.e. support 2d)", gt=0.0, le=4.0, default_text="kernel default"),
    _P("solver", "str", "-", "wcsph", "pressure solver: weakly compressible SPH (Becker & Teschner 2007) "
       "or position-based fluids (Macklin & Mueller 2013)", choices=SOLVERS),
    _P("boundary", "str", "-", "akinci2012", "boundary handling: Akinci et al. 2012 boundary particles or a "
       "penalty force", choices=BOUNDARY_METHODS),
    _P("boundary_gap", "float", "-", None, "initial distance from the boundary particles to the nearest fluid "
       "particle centres, in spacings d (absent: the gap at which the first layer next to one Akinci wall "
       "layer is at rest density, physics notes section 7: cubic 1.10, quadric 1.08, quintic 1.03)",
       ge=0.5, le=3.0, default_text="auto"),
    _P("gravity", "vec3", "m/s^2", (0.0, 0.0, -9.81), "gravitational acceleration (Z is up)"),
    _P("duration", "float", "s", 2.0, "simulated time", gt=0.0),
    _P("fps", "float", "1/s", 24.0, "output frames per second of simulated time", gt=0.0),
    # material
    _P("material", "table", "-", {}, "fluid material"),
    _P("material.rest_density", "float", "kg/m^3", 1000.0, "rest density rho0", gt=0.0),
    _P("material.viscosity", "float", "m^2/s", 0.0, "kinematic viscosity, explicit (SPlisHSPlasH "
       "'standard' form); needs dt <= 0.0625 (H_s/2)^2 / nu", ge=0.0),
    _P("material.xsph", "float", "-", 0.0, "XSPH velocity smoothing factor (report eq. 21)", ge=0.0, le=1.0),
    _P("material.boundary_friction", "float", "-", 0.0, "Akinci boundary friction sigma (report eq. 22-24)", ge=0.0),
    # wcsph
    _P("wcsph", "table", "-", {}, "weakly compressible SPH settings"),
    _P("wcsph.equation_of_state", "str", "-", "linear", "p = k (rho/rho0 - 1) (linear) or "
       "p = B ((rho/rho0)^7 - 1) (Tait, Becker & Teschner 2007)", choices=EQUATIONS_OF_STATE),
    _P("wcsph.speed_of_sound", "float", "m/s", 0.0, "speed of sound c_s (0: derived from "
       "speed_of_sound_factor)", ge=0.0),
    _P("wcsph.speed_of_sound_factor", "float", "-", 10.0, "c_s = factor * sqrt(2 g H_fluid) when "
       "speed_of_sound is 0 (factor 10 keeps the density error near 1 %)", gt=0.0),
    _P("wcsph.stiffness", "float", "Pa", 0.0, "stiffness k (linear) or B (Tait); 0: derived "
       "from c_s, k = rho0 c_s^2 or B = rho0 c_s^2 / 7; overrides c_s when > 0", ge=0.0),
    _P("wcsph.boundary_pressure", "str", "-", "eq16", "pressure term of Akinci boundary particles: "
       "'eq16' (report eq. 16, p_i/rho_i^2: energy-consistent, but layers near a wall read 15-70 % over "
       "rho0 g depth) or 'mirrored' (p_i/rho_i^2 + p_i/rho0^2, as SPlisHSPlasH: hydrostatic profile within "
       "4 %, but not energy-consistent: it can add energy in violent flows)", choices=("eq16", "mirrored")),
    # pbf
    _P("pbf", "table", "-", {}, "position-based fluids settings"),
    _P("pbf.target_density_error", "float", "-", 0.005, "stop iterating when the average density error "
       "(fraction of rho0) is below this", gt=0.0, lt=1.0),
    _P("pbf.max_iterations", "int", "-", 50, "most constraint iterations per substep", ge=1),
    _P("pbf.min_iterations", "int", "-", 2, "fewest constraint iterations per substep", ge=0),
    _P("pbf.relaxation", "float", "-", 1e-4, "constraint-force mixing epsilon, relative to the "
       "rest-lattice denominator sum_k (grad_k C)^2; about 5 under-relaxes the Jacobi solve so that fluid "
       "at rest settles (with viscosity 2e-3 m^2/s a resting block holds speeds below 1e-3 m/s); the "
       "small default applies each correction in full: fewer iterations in violent flows", ge=0.0),
    _P("pbf.tensile_correction", "bool", "-", False, "artificial pressure s_corr against clustering"),
    _P("pbf.tensile_k", "float", "-", 0.1, "s_corr strength k", ge=0.0),
    _P("pbf.tensile_n", "int", "-", 4, "s_corr exponent n", ge=1),
    _P("pbf.tensile_dq", "float", "-", 0.2, "s_corr reference distance dq in smoothing lengths h",
       gt=0.0, lt=2.0),
    _P("pbf.vorticity", "float", "-", 0.0, "vorticity confinement strength epsilon", ge=0.0),
    # time
    _P("time", "table", "-", {}, "time stepping"),
    _P("time.cfl", "float", "-", 0.4, "CFL number lambda of the adaptive step", gt=0.0, le=1.0),
    _P("time.dt_min", "float", "s", 1e-6, "smallest adaptive step", gt=0.0),
    _P("time.dt_max", "float", "s", 5e-3, "largest adaptive step", gt=0.0),
    _P("time.fixed_dt", "float", "s", 0.0, "fixed step (0: adaptive)", ge=0.0),
    _P("time.on_instability", "str", "-", "stop", "when the watchdog finds a non-finite value or an "
       "escaped particle: 'stop' with an error (frames so far are kept) or 'retry' the frame with "
       "half the time step", choices=("stop", "retry")),
    # container
    _P("container", "table_or_false", "-", {}, "box of boundary-particle walls (six faces); "
       "'container = false': no walls", default_text="box"),
    _P("container.min", "vec3", "m", (0.0, 0.0, 0.0), "lower corner of the container"),
    _P("container.max", "vec3", "m", (4.0, 1.5, 3.0), "upper corner of the container"),
    # fluid blocks
    _P("fluid", "tables", "-", REQUIRED, "fluid blocks ([[fluid]]), at least one"),
    _P("fluid[].shape", "str", "-", "box", "block shape", choices=FLUID_SHAPES),
    _P("fluid[].min", "vec3", "m", REQUIRED, "lower corner of a box block", shapes=("box",)),
    _P("fluid[].max", "vec3", "m", REQUIRED, "upper corner of a box block", shapes=("box",)),
    _P("fluid[].center", "vec3", "m", REQUIRED, "centre of a sphere block", shapes=("sphere",)),
    _P("fluid[].radius", "float", "m", REQUIRED, "radius of a sphere block", gt=0.0, shapes=("sphere",)),
    _P("fluid[].velocity", "vec3", "m/s", (0.0, 0.0, 0.0), "initial velocity"),
    _P("fluid[].spacing_scale", "float", "-", 1.0, "lattice spacing / d; < 1 starts the block "
       "over-dense (compressed)", ge=0.5, le=2.0),
    # obstacles
    _P("obstacles", "tables", "-", [], "static obstacles ([[obstacles]]), sampled as boundary particles",
       default_text="none"),
    _P("obstacles[].shape", "str", "-", "box", "obstacle shape", choices=OBSTACLE_SHAPES),
    _P("obstacles[].min", "vec3", "m", REQUIRED, "lower corner of a box obstacle", shapes=("box",)),
    _P("obstacles[].max", "vec3", "m", REQUIRED, "upper corner of a box obstacle", shapes=("box",)),
    _P("obstacles[].file", "str", "-", REQUIRED, "closed triangle mesh (.obj .stl .ply .usd .usda .usdc); "
       "relative to the scene file", shapes=("mesh",)),
    _P("obstacles[].scale", "float", "-", 1.0, "uniform scale of the mesh (x -> scale x + translate)",
       gt=0.0, shapes=("mesh",)),
    _P("obstacles[].translate", "vec3", "m", (0.0, 0.0, 0.0), "translation of the mesh", shapes=("mesh",)),
    # output. Surface (warp_sph/surface/reconstruction.py): Phi = sum_j f_j / rho~_j with
    # f = (1 - r^2/R^2)^5 and rho~ from the same f (mass, rest density and walls cancel, Phi ~ 1 in
    # the bulk); on a rest lattice the 0.6 level lies 1.0 r beyond the last particle layer (ripple
    # 0.002 r), splashsurf's default level. Cells of 0.5 r are splashsurf's usual cube size; the
    # cost grows with the surface area / cell^2 (sparse narrow band). Defaults: the default dam break's
    # USD at 25 MB instead of 104 MB, frame 13 as smooth as at 0.5 r (benchmarks/results/surface_*).
    _P("output", "table", "-", {}, "what a run writes"),
    _P("output.usd", "bool", "-", True, "write a USD stage (points, and the surface mesh if surface)"),
    _P("output.surface", "bool", "-", True, "reconstruct the fluid surface (marching cubes)"),
    _P("output.surface_cell_per_radius", "float", "-", 1.0, "surface grid cell size / r (1.0: once "
       "smoothed and decimated, no visible difference from 0.5 in a render, 4x cheaper)", gt=0.0, le=4.0),
    _P("output.surface_method", "str", "-", "marching_cubes", "iso-surface extraction: marching cubes "
       "on the sparse narrow band (Warp's case table)", choices=("marching_cubes",)),
    _P("output.surface_iso", "float", "-", 0.6, "iso level of Phi = sum_j f_j/rho~_j (1 inside the "
       "fluid; 0.6 lies 1.0 r beyond the last particle layer, splashsurf's default)", gt=0.0, lt=1.0),
    _P("output.surface_spray_neighbors", "int", "-", 5, "particles with fewer fluid neighbours than "
       "this within the kernel support are spray: written as points to /sph/spray, left out of the "
       "surface (0: no spray)", ge=0),
    _P("output.surface_smoothing_iterations", "int", "-", 15, "feature-weighted Laplacian smoothing "
       "steps of the surface, volume restored after them (removes the particle-scale ridges, keeps "
       "droplets and thin sheets; 0: raw marching cubes)", ge=0),
    _P("output.surface_decimation_error", "float", "-", 0.5, "decimate the smoothed surface by edge "
       "collapses (quadric error) that keep each merged vertex within this distance of the planes of "
       "all the faces it replaces, in particle radii (0: no decimation)", ge=0.0),
    _P("output.surface_triangle_budget", "int", "-", 0, "decimate until the surface has at most this "
       "many triangles per frame, within the error bound if one is set (0: no budget)", ge=0),
    _P("output.surface_normal_smoothing_iterations", "int", "-", 10, "one-ring averaging steps of "
       "the surface's vertex normals", ge=0),
    _P("output.surface_normals", "bool", "-", True, "write vertex normals (primvars:normals: smooth "
       "shading in Blender without modifiers)"),
    _P("output.mesh_sequence", "str", "-", "", "also write one surface mesh file per frame "
       "('' for none)", choices=MESH_SEQUENCE_FORMATS),
    _P("output.particle_primvars", "str_list", "-", ("density",), "per-particle fields written to USD",
       choices=PARTICLE_PRIMVARS),
    _P("output.checkpoint_every", "int", "-", 10, "write a checkpoint every this many frames "
       "(0: never)", ge=0),
    _P("output.record_frames", "bool", "-", True, "record per-frame diagnostics in run.json"),
)

_BY_PATH: dict[str, Param] = {p.path: p for p in PARAMETERS}
_BY_SECTION: dict[str, dict[str, Param]] = {}
for _p in PARAMETERS:
    _BY_SECTION.setdefault(_p.section, {})[_p.key] = _p


# --------------------------------------------------------------------------------------------
# Dataclasses
# --------------------------------------------------------------------------------------------
@dataclass
class Material:
    """Fluid material. rest_density [kg/m^3]; viscosity: kinematic [m^2/s]; xsph [-];
    boundary_friction: Akinci sigma [-]."""

    rest_density: float = 1000.0
    viscosity: float = 0.0
    xsph: float = 0.0
    boundary_friction: float = 0.0


@dataclass
class WcsphParams:
    """WCSPH settings. speed_of_sound [m/s] (0: derived), speed_of_sound_factor [-],
    stiffness [Pa] (0: derived from c_s)."""

    equation_of_state: str = "linear"
    speed_of_sound: float = 0.0
    speed_of_sound_factor: float = 10.0
    stiffness: float = 0.0
    boundary_pressure: str = "eq16"


@dataclass
class PbfParams:
    """PBF settings. target_density_error [-] (average, fraction of rho0), relaxation [-] (CFM
    epsilon relative to the rest-lattice denominator), tensile_dq [h], vorticity [-]."""

    target_density_error: float = 0.005
    max_iterations: int = 50
    min_iterations: int = 2
    relaxation: float = 1e-4
    tensile_correction: bool = False
    tensile_k: float = 0.1
    tensile_n: int = 4
    tensile_dq: float = 0.2
    vorticity: float = 0.0


@dataclass
class TimeParams:
    """Time stepping. cfl [-]; dt_min, dt_max, fixed_dt [s] (fixed_dt 0: adaptive)."""

    cfl: float = 0.4
    dt_min: float = 1e-6
    dt_max: float = 5e-3
    fixed_dt: float = 0.0
    on_instability: str = "stop"


@dataclass
class Container:
    """Axis-aligned box of walls [m]; its six faces are sampled as boundary particles."""

    min: Vec3 = (0.0, 0.0, 0.0)
    max: Vec3 = (4.0, 1.5, 3.0)


@dataclass
class FluidBlock:
    """A block of fluid sampled on a lattice.

    shape: "box" (min, max [m]) or "sphere" (center [m], radius [m]); the other shape's fields are None.
    velocity: initial velocity [m/s]. spacing_scale: lattice spacing / d [-] (< 1: over-dense start).
    """

    shape: str = "box"
    min: Vec3 | None = None
    max: Vec3 | None = None
    center: Vec3 | None = None
    radius: float | None = None
    velocity: Vec3 = (0.0, 0.0, 0.0)
    spacing_scale: float = 1.0

    def bounds(self) -> tuple[Vec3, Vec3]:
        """Axis-aligned bounding box (min, max) [m]."""
        if self.shape == "sphere":
            c, r = self.center, self.radius
            return tuple(x - r for x in c), tuple(x + r for x in c)
        return self.min, self.max


@dataclass
class Obstacle:
    """A static obstacle sampled on its surface as boundary particles.

    shape: "box" (min, max [m]) or "mesh" (file: absolute path after loading, scale [-],
    translate [m]); the other shape's fields are None.
    """

    shape: str = "box"
    min: Vec3 | None = None
    max: Vec3 | None = None
    file: str | None = None
    scale: float | None = None
    translate: Vec3 | None = None


@dataclass
class OutputParams:
    """Output settings. surface_cell_per_radius [-] (marching-cubes cell = factor * r [m]),
    surface_iso [-] (iso level of Phi = sum f/rho~), surface_spray_neighbors [-] (spray below this
    neighbour count), smoothing iterations [-], checkpoint_every [frames]."""

    usd: bool = True
    surface: bool = True
    surface_cell_per_radius: float = 1.0
    surface_method: str = "marching_cubes"
    surface_iso: float = 0.6
    surface_spray_neighbors: int = 5
    surface_smoothing_iterations: int = 15
    surface_decimation_error: float = 0.5
    surface_triangle_budget: int = 0
    surface_normal_smoothing_iterations: int = 10
    surface_normals: bool = True
    mesh_sequence: str = ""
    particle_primvars: list[str] = field(default_factory=lambda: ["density"])
    checkpoint_every: int = 10
    record_frames: bool = True


@dataclass
class Scene:
    """A validated scene, SI units. Build with ``load_scene`` or ``scene_from_dict``.

    particle_radius r [m] (spacing d = 2r); boundary_gap [d] (None: auto, see ``wall_gap``);
    gravity [m/s^2]; duration [s]; fps [1/s]; container None means no walls. ``source`` (the file it came from) is not part of the
    scene's value and is left out of ``to_dict`` and comparisons.
    """

    name: str = ""
    description: str = ""
    particle_radius: float = 0.025
    smoothing_kernel: str = "cubic"
    h_per_spacing: float | None = None
    solver: str = "wcsph"
    boundary: str = "akinci2012"
    boundary_gap: float | None = None
    gravity: Vec3 = (0.0, 0.0, -9.81)
    duration: float = 2.0
    fps: float = 24.0
    material: Material = field(default_factory=Material)
    wcsph: WcsphParams = field(default_factory=WcsphParams)
    pbf: PbfParams = field(default_factory=PbfParams)
    time: TimeParams = field(default_factory=TimeParams)
    container: Container | None = field(default_factory=Container)
    fluid: list[FluidBlock] = field(default_factory=list)
    obstacles: list[Obstacle] = field(default_factory=list)
    output: OutputParams = field(default_factory=OutputParams)
    source: str = field(default="<dict>", compare=False, repr=False)

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
        return wall_gap(self.smoothing_kernel, self.smoothing_length, self.spacing)

    @property
    def frame_count(self) -> int:
        """Number of output frames after the initial one: round(duration * fps)."""
        return int(round(self.duration * self.fps))

    def to_dict(self) -> dict:
        """The scene with every default filled in, as plain TOML/JSON types.

        None-valued optional keys are left out (TOML has no null); no container is
        ``container = false``. ``scene_from_dict(scene.to_dict()) == scene``.
        """
        return _plain(self)


def _plain(obj):
    if dataclasses.is_dataclass(obj):
        out = {}
        for f in dataclasses.fields(obj):
            if f.name == "source":
                continue
            value = getattr(obj, f.name)
            if f.name == "container" and value is None:
                out[f.name] = False
            elif value is not None:
                out[f.name] = _plain(value)
        return out
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    return obj


_SECTION_CLASSES = {
    "material": Material,
    "wcsph": WcsphParams,
    "pbf": PbfParams,
    "time": TimeParams,
    "container": Container,
    "output": OutputParams,
    "fluid[]": FluidBlock,
    "obstacles[]": Obstacle,
}


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------
def _short(value) -> str:
    text = " ".join(repr(value).split())
    return text if len(text) <= 60 else text[:57] + "..."


class _Validator:
    def __init__(self, source: str, base_dir: Path | None):
        self.source = source
        self.base_dir = base_dir

    def fail(self, keypath: str, message: str):
        raise SceneError(f"{self.source}: {keypath}: {message}")

    def bad(self, param: Param, keypath: str, value):
        self.fail(keypath, f"expected {param.expected()}, got {_short(value)}")

    # one value -----------------------------------------------------------------------------
    def number(self, param: Param, value, keypath: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.bad(param, keypath, value)
        value = float(value)
        if not math.isfinite(value):
            self.bad(param, keypath, value)
        return value

    def value(self, param: Param, value, keypath: str):
        kind = param.kind
        if value is None and param.default is None:
            return None
        if kind == "float":
            v = self.number(param, value, keypath)
        elif kind == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                self.bad(param, keypath, value)
            v = value
        elif kind == "bool":
            if not isinstance(value, bool):
                self.bad(param, keypath, value)
            return value
        elif kind == "str":
            if not isinstance(value, str) or (param.choices is not None and value not in param.choices):
                self.bad(param, keypath, value)
            return value
        elif kind == "vec3":
            if not isinstance(value, (list, tuple)) or len(value) != 3:
                self.bad(param, keypath, value)
            return tuple(self.number(param, x, keypath) for x in value)
        elif kind == "str_list":
            if not isinstance(value, (list, tuple)) or any(
                not isinstance(x, str) or x not in param.choices for x in value
            ):
                self.bad(param, keypath, value)
            return list(dict.fromkeys(value))
        else:  # pragma: no cover - tables are handled by the caller
            raise AssertionError(kind)
        if ((param.gt is not None and not v > param.gt) or (param.ge is not None and not v >= param.ge)
                or (param.lt is not None and not v < param.lt) or (param.le is not None and not v <= param.le)):
            self.bad(param, keypath, value)
        return v

    # one table -----------------------------------------------------------------------------
    def table(self, raw, section: str, keypath: str, shape_key: bool = False) -> dict:
        params = {k: p for k, p in _BY_SECTION[section].items() if p.kind not in ("table", "tables", "table_or_false")}
        if not isinstance(raw, dict):
            self.fail(keypath, f"expected a table, got {_short(raw)}")
        for k in raw:
            if k not in params:
                self.fail(f"{keypath}.{k}", f"unknown key; expected one of {', '.join(params)}")
        shape = None
        if shape_key:
            shape = self.value(params["shape"], raw.get("shape", params["shape"].default), f"{keypath}.shape")
        out = {}
        for k, p in params.items():
            kp = f"{keypath}.{k}"
            if p.shapes is not None and shape not in p.shapes:
                if k in raw:
                    self.fail(kp, f"not used by shape {shape!r} (used by {', '.join(map(repr, p.shapes))})")
                out[k] = None
            elif k in raw:
                out[k] = self.value(p, raw[k], kp)
            elif p.default is REQUIRED:
                self.fail(kp, f"missing; expected {p.expected()}" + (f" for shape {shape!r}" if shape else ""))
            else:
                out[k] = copy.copy(list(p.default) if isinstance(p.default, (list, tuple)) and p.kind == "str_list"
                                   else p.default)
        return out

    def box(self, lo, hi, keypath: str):
        if not all(a < b for a, b in zip(lo, hi)):
            self.fail(f"{keypath}.max", f"expected every component > {keypath}.min {list(lo)}, got {list(hi)}")

    # the scene -----------------------------------------------------------------------------
    def scene(self, data) -> Scene:
        if not isinstance(data, dict):
            raise SceneError(f"{self.source}: expected a table of scene parameters, got {_short(data)}")
        top = _BY_SECTION[""]
        for k in data:
            if k not in top:
                self.fail(k, f"unknown key; expected one of {', '.join(top)}")
        values: dict[str, Any] = {}
        for k, p in top.items():
            if p.kind in ("table", "tables", "table_or_false"):
                continue
            if k in data:
                values[k] = self.value(p, data[k], k)
            else:
                values[k] = p.default
        if not values["name"]:
            stem = Path(self.source).stem if self.source.endswith(".toml") else ""
            values["name"] = stem or "scene"
        try:
            get_smoothing_kernel(values["smoothing_kernel"])
        except SceneError as exc:
            self.fail("smoothing_kernel", str(exc))
        for section in ("material", "wcsph", "pbf", "time", "output"):
            values[section] = _SECTION_CLASSES[section](**self.table(data.get(section, {}), section, section))
        # container: table or false
        raw = data.get("container", {})
        if raw is False or raw is None:
            values["container"] = None
        elif raw is True:
            values["container"] = Container()
        else:
            c = Container(**self.table(raw, "container", "container"))
            self.box(c.min, c.max, "container")
            values["container"] = c
        values["fluid"] = self.blocks(data, "fluid", required=True)
        values["obstacles"] = self.blocks(data, "obstacles", required=False)
        self.cross_checks(values)
        return Scene(**values, source=self.source)

    def blocks(self, data, name: str, required: bool) -> list:
        raw = data.get(name, [])
        if isinstance(raw, dict):
            raw = [raw]
        if not isinstance(raw, list) or any(not isinstance(b, dict) for b in raw):
            self.fail(name, f"expected an array of tables ([[{name}]]), got {_short(raw)}")
        if required and not raw:
            self.fail(name, f"expected at least one [[{name}]] block")
        cls = _SECTION_CLASSES[f"{name}[]"]
        out = []
        for i, b in enumerate(raw):
            kp = f"{name}[{i}]"
            block = cls(**self.table(b, f"{name}[]", kp, shape_key=True))
            if block.shape == "box":
                self.box(block.min, block.max, kp)
            if name == "obstacles" and block.shape == "mesh":
                path = Path(block.file).expanduser()
                if not path.is_absolute():
                    path = (self.base_dir or Path.cwd()) / path
                path = path.resolve()
                try:
                    load_triangle_mesh(path)
                except SceneError as exc:
                    self.fail(f"{kp}.file", str(exc))
                block.file = str(path)
            out.append(block)
        return out

    def cross_checks(self, v: dict):
        pbf, time = v["pbf"], v["time"]
        if pbf.min_iterations > pbf.max_iterations:
            self.fail("pbf.min_iterations", f"expected <= pbf.max_iterations ({pbf.max_iterations}), "
                      f"got {pbf.min_iterations}")
        if time.dt_min > time.dt_max:
            self.fail("time.dt_min", f"expected <= time.dt_max ({time.dt_max:g}), got {time.dt_min:g}")
        c = v["container"]
        if c is not None:
            tol = 1e-9 * max(1.0, *map(abs, c.min + c.max))
            for i, block in enumerate(v["fluid"]):
                lo, hi = block.bounds()
                if any(a < cl - tol for a, cl in zip(lo, c.min)) or any(b > ch + tol for b, ch in zip(hi, c.max)):
                    what = "sphere" if block.shape == "sphere" else "box"
                    self.fail(f"fluid[{i}]", f"{what} {list(lo)}..{list(hi)} is not inside the container "
                              f"{list(c.min)}..{list(c.max)}")


# --------------------------------------------------------------------------------------------
# Overrides
# --------------------------------------------------------------------------------------------
_TOKEN = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]")


def _parse_key_path(path: str) -> list:
    tokens, pos = [], 0
    path = path.strip()
    while pos < len(path):
        if path[pos] == "." and tokens and pos + 1 < len(path):
            pos += 1
        m = _TOKEN.match(path, pos)
        if not m:
            raise ValueError(f"malformed key path {path!r}")
        tokens.append(m.group(1) if m.group(1) is not None else int(m.group(2)))
        pos = m.end()
    if not tokens or not isinstance(tokens[0], str):
        raise ValueError(f"malformed key path {path!r}")
    return tokens


def parse_override_value(text: str):
    """A ``--set`` value in TOML value syntax (``0.02``, ``[1, 1, 1]``, ``false``); a bare word is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text.strip()


def apply_overrides(data: dict, overrides: list[str] | dict | None, source: str = "<dict>") -> dict:
    """A deep copy of ``data`` with overrides applied by key path.

    overrides: ``["particle_radius=0.02", "fluid[0].max=[1,1,1]"]`` (values in TOML syntax) or a
    dict ``{"particle_radius": 0.02}`` (values taken as they are).
    """
    data = copy.deepcopy(data)
    if not overrides:
        return data
    if isinstance(overrides, dict):
        items = list(overrides.items())
    else:
        items = []
        for item in overrides:
            key, sep, text = str(item).partition("=")
            if not sep or not key.strip():
                raise SceneError(f"{source}: --set {item!r}: expected KEY=VALUE, e.g. particle_radius=0.02")
            items.append((key.strip(), parse_override_value(text)))
    for key, value in items:
        try:
            tokens = _parse_key_path(key)
        except ValueError as exc:
            raise SceneError(f"{source}: --set {key}: {exc}; expected e.g. material.rest_density or fluid[0].max") from None
        node = data
        for depth, tok in enumerate(tokens[:-1]):
            here = "".join(f"[{t}]" if isinstance(t, int) else ("." if j else "") + t for j, t in enumerate(tokens[:depth + 1]))
            nxt = tokens[depth + 1]
            if isinstance(tok, int):
                if not isinstance(node, list) or tok >= len(node):
                    n = len(node) if isinstance(node, list) else 0
                    raise SceneError(f"{source}: --set {key}: {here}: index out of range (the scene has {n})")
                if not isinstance(node[tok], dict):
                    node[tok] = {}
                node = node[tok]
                continue
            if not isinstance(node, dict):
                raise SceneError(f"{source}: --set {key}: {here}: not a table")
            child = node.get(tok)
            if isinstance(nxt, int):
                if isinstance(child, dict):
                    child = [child]
                if not isinstance(child, list):
                    child = []
            elif not isinstance(child, dict):
                child = {}
            node[tok] = child
            node = child
        last = tokens[-1]
        if isinstance(last, int):
            if not isinstance(node, list) or last >= len(node):
                raise SceneError(f"{source}: --set {key}: index out of range")
        node[last] = value
    return data


# --------------------------------------------------------------------------------------------
# Public entry points
# --------------------------------------------------------------------------------------------
def _scenes_dir() -> Path:
    return Path(str(importlib.resources.files("warp_sph.scenes")))


def list_scenes() -> list[tuple[str, str]]:
    """(name, description) of every built-in scene, sorted by name."""
    out = []
    for path in sorted(_scenes_dir().glob("*.toml")):
        try:
            with open(path, "rb") as f:
                desc = tomllib.load(f).get("description", "")
        except (OSError, tomllib.TOMLDecodeError):
            desc = "(unreadable)"
        out.append((path.stem, str(desc)))
    return out


def _resolve(name_or_path: str) -> Path:
    text = str(name_or_path)
    path = Path(text).expanduser()
    if path.suffix.lower() == ".toml" or "/" in text or "\\" in text or path.is_file():
        if not path.is_file():
            raise SceneError(f"{text}: scene file not found")
        return path
    builtin = _scenes_dir() / f"{text}.toml"
    if not builtin.is_file():
        names = ", ".join(n for n, _ in list_scenes())
        raise SceneError(f"{text}: no such scene file or built-in scene; built-in scenes: {names}")
    return builtin


def load_scene(name_or_path: str, overrides: list[str] | dict | None = None) -> Scene:
    """Load, override and validate a scene.

    name_or_path: the name of a built-in scene (``dam_break``) or a path to a .toml file;
    relative mesh paths resolve against the file's folder.
    overrides: ``["particle_radius=0.02", "fluid[0].max=[1,1,1]", "output.usd=false"]`` or a dict.
    Raises SceneError naming the file, the key path and what was expected.
    """
    path = _resolve(name_or_path)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: malformed TOML: {exc}") from None
    except OSError as exc:
        raise SceneError(f"{path}: cannot read: {exc.strerror}") from None
    data = apply_overrides(data, overrides, str(path))
    return scene_from_dict(data, source=str(path), base_dir=path.parent)


def scene_from_dict(data: dict, source: str = "<dict>", base_dir: str | Path | None = None) -> Scene:
    """Validate a scene given as nested dicts/lists (TOML structure) and build the Scene.

    base_dir: folder that relative mesh paths resolve against (default: the working directory).
    """
    return _Validator(source, Path(base_dir) if base_dir is not None else None).scene(data)


def _default_text(p: Param) -> str:
    if p.default_text is not None:
        return p.default_text
    if p.default is REQUIRED:
        return "required"
    if p.kind in ("table", "tables"):
        return ""
    d = p.default
    if isinstance(d, bool):
        return "true" if d else "false"
    if isinstance(d, str):
        return f'"{d}"'
    if isinstance(d, (list, tuple)):
        return "[" + ", ".join(f'"{x}"' if isinstance(x, str) else f"{x:g}" for x in d) + "]"
    if isinstance(d, float):
        return f"{d:g}"
    return str(d)


def parameter_table_markdown() -> str:
    """The scene parameters as a Markdown table: key, type, unit, default, valid values, meaning."""
    kinds = {"float": "float", "int": "int", "bool": "bool", "str": "string", "vec3": "[x, y, z]",
             "str_list": "list of strings", "table": "table", "tables": "array of tables",
             "table_or_false": "table or false"}
    lines = ["| key | type | unit | default | valid | description |", "|---|---|---|---|---|---|"]
    for p in PARAMETERS:
        if p.choices is not None:
            valid = ", ".join(f'"{c}"' for c in p.choices)
        else:
            valid = p.range_text()
        if p.shapes is not None:
            valid = (valid + "; " if valid else "") + f"shape {', '.join(p.shapes)}"
        doc = p.doc.replace("|", "\\|")
        lines.append(f"| `{p.path}` | {kinds[p.kind]} | {p.unit} | {_default_text(p)} | {valid} | {doc} |")
    return "\n".join(lines) + "\n"
