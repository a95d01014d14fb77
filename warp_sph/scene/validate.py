"""Scene validation: a TOML-shaped dict -> a typed ``Scene``, or a ``SceneError`` naming the file, the
key path (``fluid[1].min``) and what was expected, before any kernel runs.

Checks every value against its parameter row (type, range, choices), unknown keys, required keys,
shape-specific keys, and the cross-checks between values: boxes with max > min, fluid inside the
container, obstacles closed and not entirely outside the container, a mesh sequence only with a
surface, each method's own cross-checks (``Solver.validate``) and the solver x boundary pairing,
rigid bodies (``warp_sph.rigid.checks``: inside the container, no overlap, Newton installed); the checks
between values of the typed Scene are in ``cross_checks``.
"""
from __future__ import annotations

import copy
import importlib.resources
import math
from pathlib import Path
from typing import Any

from ..core.errors import SceneError
from ..core.smoothing import get_smoothing_kernel
from ..methods import registry
from .cross_checks import cross_checks
from .mesh_volume import closed_surface_problem, signed_volume
from .meshes import load_triangle_mesh, open_edge_count
from .parameters import REQUIRED, TABLE_KINDS, Param, all_parameters, by_section
from .types import CORE_SECTIONS, Container, Scene


def _short(value) -> str:
    text = " ".join(repr(value).split())
    return text if len(text) <= 60 else text[:57] + "..."


class Validator:
    """Validates one scene dict; ``fail`` raises SceneError("<source>: <keypath>: <message>")."""

    def __init__(self, source: str, base_dir: Path | None):
        self.source = source
        self.base_dir = base_dir
        self.params = by_section(all_parameters())

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
            v = tuple(self.number(param, x, keypath) for x in value)
            if not param.in_range(math.hypot(*v)):  # a vec3's bounds are those of its length
                self.fail(keypath, f"expected {param.expected()}, got {_short(value)} (length "
                                   f"{math.hypot(*v):.4g})")
            return v
        elif kind == "str_list":
            if not isinstance(value, (list, tuple)) or any(
                not isinstance(x, str) or x not in param.choices for x in value
            ):
                self.bad(param, keypath, value)
            return list(dict.fromkeys(value))
        else:  # pragma: no cover - tables are handled by the caller
            raise AssertionError(kind)
        if not param.in_range(v):
            self.bad(param, keypath, value)
        return v

    # one table -----------------------------------------------------------------------------
    def table(self, raw, section: str, keypath: str, shape_key: bool | str = False) -> dict:
        params = {k: p for k, p in self.params.get(section, {}).items() if p.kind not in TABLE_KINDS}
        if not isinstance(raw, dict):
            self.fail(keypath, f"expected a table, got {_short(raw)}")
        for k in raw:
            if k not in params:
                self.fail(f"{keypath}.{k}", f"unknown key; expected one of {', '.join(params)}")
        shape = None
        word = shape_key if isinstance(shape_key, str) else "shape"  # the key that selects the keys used
        if shape_key:
            if params[word].default is REQUIRED and word not in raw:
                self.fail(f"{keypath}.{word}", f"missing; expected {params[word].expected()}")
            shape = self.value(params[word], raw.get(word, params[word].default), f"{keypath}.{word}")
        out = {}
        for k, p in params.items():
            kp = f"{keypath}.{k}"
            if p.shapes is not None and shape not in p.shapes:
                if k in raw:
                    self.fail(kp, f"not used by {word} {shape!r} (used by {', '.join(map(repr, p.shapes))})")
                out[k] = None
            elif k in raw:
                out[k] = self.value(p, raw[k], kp)
            elif p.default is REQUIRED:
                self.fail(kp, f"missing; expected {p.expected()}" + (f" for {word} {shape!r}" if shape else ""))
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
        top = self.params[""]
        for k in data:
            if k in ("sweep", "case") and k not in top:  # a sweep file given where a scene is expected
                self.fail(k, "a sweep file ([sweep] / [[case]]), not a scene; run it with: "
                          f"warp-sph sweep {self.source}")
            if k not in top:
                self.fail(k, f"unknown key; expected one of {', '.join(top)}")
        values: dict[str, Any] = {}
        for k, p in top.items():
            if p.kind in TABLE_KINDS:
                continue
            values[k] = self.value(p, data[k], k) if k in data else p.default
        if not values["name"]:
            stem = Path(self.source).stem if self.source.endswith(".toml") else ""
            values["name"] = stem or "scene"
        try:
            get_smoothing_kernel(values["smoothing_kernel"])
        except SceneError as exc:
            self.fail("smoothing_kernel", str(exc))
        for section in ("material", "time", "output", "rigid"):
            values[section] = CORE_SECTIONS[section](**self.table(data.get(section, {}), section, section))
        if "plan" in data:  # warp-sph plan's prediction (absent: None, left out of to_dict)
            values["plan"] = CORE_SECTIONS["plan"](**self.table(data["plan"], "plan", "plan"))
        sections = {}
        for name, cls in registry.methods_with_parameters().items():
            sections[name] = cls.config_class()(**self.table(data.get(name, {}), name, name))
        values["sections"] = sections
        raw = data.get("container", {})
        if raw is False or raw is None:
            values["container"] = None
        elif not isinstance(raw, dict):
            self.fail("container", f"expected a table ([container] with min and max) or false, got "
                      f"{str(raw).lower() if isinstance(raw, bool) else _short(raw)}")
        else:
            c = Container(**self.table(raw, "container", "container"))
            self.box(c.min, c.max, "container")
            values["container"] = c
        values["fluid"] = self.blocks(data, "fluid", required=not data.get("emitters"))  # emitters may start empty
        values["obstacles"] = self.blocks(data, "obstacles", required=False)
        values["bodies"] = self.blocks(data, "bodies", required=False)
        from .kinematic import kinematic_obstacles  # kinematic bodies become animated obstacles

        values["obstacles"], values["bodies"] = kinematic_obstacles(values["obstacles"], values["bodies"], self.fail)
        values["forces"] = self.forces(data)
        values["probes"] = self.blocks(data, "probes", required=False, shape_key="kind")
        if "whitewater" in data:  # off unless present
            values["whitewater"] = CORE_SECTIONS["whitewater"](**self.table(data["whitewater"], "whitewater",
                                                                            "whitewater"))
        values["emitters"] = self.blocks(data, "emitters", required=False)
        values["sinks"] = self.blocks(data, "sinks", required=False, shape_key="")
        scene = Scene(**values, source=self.source)
        from .container import resolve_inner  # container.inner: the box is the water's, the walls go outside it

        scene = resolve_inner(scene)
        cross_checks(scene, self.fail)
        return scene

    def blocks(self, data, name: str, required: bool, shape_key: str = "shape") -> list:
        raw = data.get(name, [])
        if isinstance(raw, dict):
            self.fail(name, f"expected an array of tables: write [[{name}]] (double brackets) for each block, "
                            f"got a single table [{name}]")
        if not isinstance(raw, list) or any(not isinstance(b, dict) for b in raw):
            self.fail(name, f"expected an array of tables ([[{name}]]), got {_short(raw)}")
        if required and not raw:
            self.fail(name, f"expected at least one [[{name}]] block" + (" (or an [[emitters]] block)" if name == "fluid" else ""))
        cls = CORE_SECTIONS[f"{name}[]"]
        out = []
        for i, b in enumerate(raw):
            kp = f"{name}[{i}]"
            nested = {k: b[k] for k in ("keyframes", "animation") if name == "obstacles" and k in b}
            b = {k: v for k, v in b.items() if k not in nested}
            if name == "bodies":
                from .kinematic import kinematic_raw

                b, nested = kinematic_raw(self, b, kp)
            block = cls(**self.table(b, f"{name}[]", kp, shape_key=shape_key))
            if nested:
                self.collider_path(block, nested, kp)
            if getattr(block, "shape", None) == "box" and name != "bodies":
                self.box(block.min, block.max, kp)
            if name in ("obstacles", "bodies") and block.shape == "mesh":
                self.mesh_file(block, kp, name)
            if name == "fluid" and block.shape == "mesh":
                self.fluid_mesh(block, kp)
            out.append(block)
        return out

    def collider_path(self, block, nested: dict, kp: str) -> None:
        """An animated obstacle's ``keyframes`` or ``animation`` checked, its Path built (``block.path``)."""
        from .paths import keyframe_path, usd_path

        if "keyframes" in nested and "animation" in nested:
            self.fail(f"{kp}.animation", "give keyframes or animation, not both")
        if "keyframes" in nested:
            raw = nested["keyframes"]
            if not isinstance(raw, list) or any(not isinstance(k, dict) for k in raw):
                self.fail(f"{kp}.keyframes", f"expected an array of tables ({{time = ..., translate = [...], rotation = "
                          f"[...]}}), got {_short(raw)}")
            block.keyframes = [self.table(k, "obstacles[].keyframes[]", f"{kp}.keyframes[{j}]") for j, k in enumerate(raw)]
            block.path = keyframe_path(block.keyframes, block.interpolation, self.fail, kp)
        else:
            anim = self.table(nested["animation"], "obstacles[].animation", f"{kp}.animation")
            anim["file"] = str(self.mesh_path(anim["file"]))
            block.animation = anim
            block.path = usd_path(anim["file"], anim["prim"], block.interpolation, self.fail, kp)
        if block.name and not (block.name.replace("_", "a").isalnum() and block.name.isascii()
                               and not block.name[0].isdigit()):
            self.fail(f"{kp}.name", f"expected letters, digits and '_', not starting with a digit, got {block.name!r}")

    def forces(self, data) -> list:
        """The ``[[forces]]`` entries: each a ``method`` and that force's keys (``Force.config_class``)."""
        raw = data.get("forces", [])
        if isinstance(raw, dict):
            raw = [raw]
        if not isinstance(raw, list) or any(not isinstance(b, dict) for b in raw):
            self.fail("forces", f"expected an array of tables ([[forces]] with method = ...), got {_short(raw)}")
        out = []
        method_param = self.params["forces[]"]["method"]
        for i, b in enumerate(raw):
            kp = f"forces[{i}]"
            if "method" not in b:
                self.fail(f"{kp}.method", f"missing; expected {method_param.expected()}")
            name = self.value(method_param, b["method"], f"{kp}.method")
            cls = registry.force(name)
            values = self.table({k: v for k, v in b.items() if k != "method"}, f"forces[{name}]", kp)
            out.append(cls.config_class()(**values))
        return out

    def mesh_path(self, file: str) -> Path:
        """``file`` resolved: absolute, else relative to the scene file's folder, else (when not there)
        a mesh shipped in the built-in scenes' meshes/ folder."""
        path = Path(file).expanduser()
        if not path.is_absolute():
            local = (self.base_dir or Path.cwd()) / path
            shipped = Path(str(importlib.resources.files("warp_sph.scenes"))) / "meshes" / path
            path = local if local.is_file() or not shipped.is_file() else shipped
        return path.resolve()

    def read_mesh(self, block, kp: str):
        """(absolute path, TriangleMesh) of ``block.file``; a file that cannot be read fails as ``<kp>.file``."""
        path = self.mesh_path(block.file)
        try:
            return path, load_triangle_mesh(path)
        except SceneError as exc:
            self.fail(f"{kp}.file", str(exc))

    def fluid_mesh(self, block, kp: str) -> None:
        """A [[fluid]] mesh: readable, closed and consistently oriented, enclosing a volume; file made absolute."""
        path, mesh = self.read_mesh(block, kp)
        problem = closed_surface_problem(mesh)
        if problem:
            self.fail(f"{kp}.file", f"mesh {str(path)!r} cannot be filled with fluid: {problem}; a fluid mesh "
                      "needs a closed, consistently oriented surface (every edge shared by exactly two triangles)")
        volume = abs(signed_volume(mesh.transformed(block.scale, block.translate)))
        if not volume > 0.0:
            self.fail(f"{kp}.file", f"mesh {str(path)!r} encloses no volume")
        block.file = str(path)

    def mesh_file(self, block, kp: str, what: str = "obstacles") -> None:
        """An obstacle's or a body's mesh: readable and closed; file made absolute."""
        path, mesh = self.read_mesh(block, kp)
        holes = open_edge_count(mesh)
        if holes:
            self.fail(f"{kp}.file", f"mesh {str(path)!r} is not closed ({holes} edges belong to one triangle only); "
                      f"{what} need a closed surface (the inside test and the wall sampling assume one)")
        block.file = str(path)
