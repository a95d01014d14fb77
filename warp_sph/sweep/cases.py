"""Sweep cases: the cartesian product of ``--param`` lists, or the cases of a TOML sweep file.

A case is one ordinary run: a scene (built-in name or .toml path), scene overrides in ``--set``
syntax (``KEY=VALUE``, the value TOML value text), the frames to write and a folder name under the
sweep's output folder. The folder name is made from the swept values only, so the same sweep
finds its finished runs again (resume) and a sweep with one more value adds only new folders.

Sweep file (``warp-sph sweep SWEEP.toml``)::

    [sweep]
    scene = "dam_break"                      # built-in name, or a scene file relative to this file
    frames = 25                              # frames per run including the initial one (optional)
    set = { particle_radius = 0.05, "output.usd" = false }     # fixed overrides (optional)
    param = { solver = ["wcsph", "pbf"], "time.cfl" = [0.2, 0.4] }   # product of these (optional)

    [[case]]                                 # and/or cases listed one by one
    name = "pbf-fine"                        # optional: the folder name (default: from its values)
    scene = "hydrostatic"                    # optional: default sweep.scene
    set = { particle_radius = 0.0125, solver = "pbf" }
    frames = 10
"""
from __future__ import annotations

import hashlib
import itertools
import math
import re
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..core.errors import WarpSphError


class SweepError(WarpSphError):
    """A sweep's command line or sweep file is invalid (names the option or key and what was expected)."""


@dataclass
class Case:
    """One run of a sweep.

    scene: built-in scene name or absolute .toml path; overrides: ``KEY=VALUE`` (TOML value text),
    the fixed ones first, then the swept ones; params: the swept values only {key: value text};
    frames: frames to write including the initial one (None: the scene's duration * fps + 1).
    """

    name: str
    scene: str
    overrides: list[str] = field(default_factory=list)
    params: dict = field(default_factory=dict)
    frames: int | None = None

    def to_dict(self) -> dict:
        return asdict(self)


# --------------------------------------------------------------------------------------------
# --param KEY=V1,V2,...
# --------------------------------------------------------------------------------------------
def split_values(text: str) -> list[str]:
    """Split on commas outside brackets and quotes, so vectors survive: ``[0,0,-9.81],[0,0,-5]``."""
    out, depth, cur, quote = [], 0, "", ""
    for ch in text:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch == "[":
            depth += 1
        elif ch == "]":
            depth -= 1
        if ch == "," and depth == 0 and not quote:
            out.append(cur)
            cur = ""
        else:
            cur += ch
    out.append(cur)
    return [v.strip() for v in out if v.strip()]


def parse_param(text: str) -> tuple[str, list[str]]:
    """``key=v1,v2,...`` -> (key, [v1, v2, ...]); values stay TOML value text for load_scene."""
    key, sep, values = text.partition("=")
    if not sep or not key.strip() or not values.strip():
        raise SweepError(f"--param {text!r}: expected KEY=V1,V2,... e.g. solver=wcsph,pbf")
    return key.strip(), split_values(values)


def parse_params(texts: list[str], fixed: list[str] | None = None) -> dict[str, list[str]]:
    """The ``--param`` flags as {key: values}; a key given twice (the first list was dropped) or also fixed by a
    ``--set`` (every case overrides it) is a SweepError naming it."""
    params: dict[str, list[str]] = {}
    for text in texts:
        key, values = parse_param(text)
        if key in params:
            merged = ",".join(dict.fromkeys(params[key] + values))
            raise SweepError(f"--param {key} is given twice; give its values in one list: --param {key}={merged}")
        params[key] = values
    for item in fixed or []:
        key = str(item).partition("=")[0].strip()
        if key in params:
            raise SweepError(f"--set {item} has no effect: --param {key} sets {key} in every case; drop one of them")
    return params


def expand_product(params: dict[str, list[str]]) -> list[dict[str, str]]:
    """Cartesian product of the parameter lists, in the order given (the last key varies fastest)."""
    keys = list(params)
    return [dict(zip(keys, combo)) for combo in itertools.product(*(params[k] for k in keys))] if keys else [{}]


def toml_value(value) -> str:
    """A TOML value as override text: ``0.2``, ``true``, ``"wcsph"``, ``[0.0, 0.0, -9.81]``."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise SweepError(f"sweep value {value!r}: not a finite number")
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise SweepError(f"sweep value {value!r}: expected a number, boolean, string or list")


def _value_label(text: str) -> str:
    """Override text as it reads in a folder name: quotes dropped (``"wcsph"`` -> ``wcsph``)."""
    t = text.strip()
    if len(t) >= 2 and t[0] == t[-1] and t[0] in "\"'":
        t = t[1:-1]
    return t


def _safe(text: str, signed: bool = False) -> str:
    """``text`` in a folder name: each run of characters other than letters, digits, ``.`` ``_`` ``+``
    and ``-`` becomes one ``-``, and those at either end go. ``signed`` (a value): a minus sign is kept,
    also the first one (``-9.81``, ``[-1, 0]`` -> ``-1-0``), so a value and its negative get two folders."""
    sep = "\0" if signed else "-"
    out = re.sub(r"[^A-Za-z0-9._+-]+", sep, text).strip(sep)
    return (out.replace(sep, "-") if signed else out) or "x"


def case_name(params: dict[str, str], scene: str | None = None) -> str:
    """Folder name of a case: ``solver=pbf,time.cfl=0.2`` (in keys and values, characters other than
    letters, digits, ``.`` ``_`` ``+`` and ``-`` become ``-``; a value keeps its minus sign,
    ``gravity=-9.81``; names over 120 characters are shortened with a hash); ``default`` for a sweep
    of one case without parameters. The name never starts with ``-`` (shell tools would read it as an
    option): it starts with a key or the scene's name."""
    parts = ([_safe(Path(scene).stem).lstrip("-.") or "scene"] if scene else []) + \
        [f"{_safe(k).lstrip('-') or 'x'}={_safe(_value_label(v), signed=True)}" for k, v in params.items()]
    name = ",".join(parts) or "default"
    if len(name) > 120:
        digest = hashlib.sha1(name.encode()).hexdigest()[:10]
        name = name[:100].rstrip("-_.") + "_" + digest
    return name


def _scene_ref(scene: str, base: Path | None) -> str:
    """A built-in name stays a name; a path becomes absolute (relative to ``base``), so workers on
    other machines find it on the shared file system."""
    from ..scene.load import _resolve, read_toml

    text = str(scene)
    if text.endswith(".toml") or "/" in text or "\\" in text:
        p = Path(text).expanduser()
        if not p.is_absolute():
            p = (base or Path.cwd()) / p
        text = str(p.resolve())
    # SceneError (exit status 2) for a scene that is neither a file nor built in, and for a file that
    # is not TOML text (a malformed or binary sweep file is not run as a scene, case after case)
    read_toml(_resolve(text))
    return text


def build_cases(scene: str, params: dict[str, list[str]], fixed: list[str] | None = None,
                frames: int | None = None) -> list[Case]:
    """The product of ``params`` on one scene, each with the fixed overrides first."""
    ref = _scene_ref(scene, None)
    cases = [Case(name=case_name(combo), scene=ref,
                  overrides=list(fixed or []) + [f"{k}={v}" for k, v in combo.items()],
                  params=dict(combo), frames=frames)
             for combo in expand_product(params)]
    return _unique(cases)


def _unique(cases: list[Case]) -> list[Case]:
    seen: dict[str, Case] = {}
    for c in cases:
        if c.name in seen:
            if seen[c.name].to_dict() == c.to_dict():
                raise SweepError(f"case {c.name!r} is listed twice")
            raise SweepError(f"two cases share the folder name {c.name!r}; give them distinct names")
        seen[c.name] = c
    return cases


def _overrides_from_table(table, where: str) -> list[str]:
    if table is None:
        return []
    if not isinstance(table, dict):
        raise SweepError(f"{where}: expected a table of KEY = VALUE overrides, e.g. {{ particle_radius = 0.05 }}")
    return [f"{k}={toml_value(v)}" for k, v in _flatten(table).items()]


def _flatten(table: dict, prefix: str = "") -> dict:
    """{"time": {"cfl": 0.2}} and {"time.cfl": 0.2} both -> {"time.cfl": 0.2}."""
    out = {}
    for k, v in table.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def _frames(value, where: str) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise SweepError(f"{where}: frames = {value!r}: expected an integer >= 1")
    return value


def is_sweep_file(path: str) -> bool:
    """True for a .toml file with a top-level ``sweep`` table or ``case`` array (never a scene)."""
    p = Path(path)
    if p.suffix.lower() != ".toml" or not p.is_file():
        return False
    try:
        data = tomllib.loads(p.read_text())
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return False
    return "sweep" in data or "case" in data


def load_sweep_file(path: str, frames: int | None = None, fixed: list[str] | None = None) -> list[Case]:
    """The cases of a sweep file (module docstring). ``frames`` and ``fixed`` (``--frames``,
    ``--set`` on the command line) apply to every case, after the file's own."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as e:
        raise SweepError(f"{p}: malformed TOML: {e}") from None
    except OSError as e:
        raise SweepError(f"{p}: cannot read: {e.strerror}") from None
    unknown = sorted(set(data) - {"sweep", "case"})
    if unknown:
        raise SweepError(f"{p}: unknown top-level key(s) {', '.join(unknown)}; a sweep file has [sweep] and [[case]]")
    sw = data.get("sweep", {})
    if not isinstance(sw, dict):
        raise SweepError(f"{p}: sweep: expected a table")
    bad = sorted(set(sw) - {"scene", "frames", "set", "param"})
    if bad:
        raise SweepError(f"{p}: sweep.{bad[0]}: unknown key; expected scene, frames, set, param")
    base = p.resolve().parent
    default_scene = sw.get("scene", "dam_break")
    sweep_frames = frames if frames is not None else _frames(sw.get("frames"), f"{p}: sweep")
    sweep_fixed = _overrides_from_table(sw.get("set"), f"{p}: sweep.set") + list(fixed or [])
    scenes = {str(c.get("scene", default_scene)) for c in data.get("case", []) if isinstance(c, dict)}
    scenes.add(str(default_scene))
    cases: list[Case] = []
    param = sw.get("param")
    if param is not None:
        if not isinstance(param, dict) or not param:
            raise SweepError(f"{p}: sweep.param: expected a table of KEY = [V1, V2, ...]")
        lists = {}
        for k, vals in _flatten(param).items():
            if not isinstance(vals, list) or not vals:
                raise SweepError(f"{p}: sweep.param.{k}: expected a non-empty list of values")
            lists[k] = [toml_value(v) for v in vals]
        for combo in expand_product(lists):
            cases.append(Case(name=case_name(combo, default_scene if len(scenes) > 1 else None),
                              scene=_scene_ref(default_scene, base),
                              overrides=sweep_fixed + [f"{k}={v}" for k, v in combo.items()],
                              params={k: _value_label(v) for k, v in combo.items()}, frames=sweep_frames))
    listed = data.get("case", [])
    if not isinstance(listed, list):
        raise SweepError(f"{p}: case: expected an array of tables ([[case]])")
    for k, c in enumerate(listed):
        where = f"{p}: case[{k}]"
        if not isinstance(c, dict):
            raise SweepError(f"{where}: expected a table")
        bad = sorted(set(c) - {"name", "scene", "set", "frames"})
        if bad:
            raise SweepError(f"{where}.{bad[0]}: unknown key; expected name, scene, set, frames")
        own = _overrides_from_table(c.get("set"), f"{where}.set")
        scene = str(c.get("scene", default_scene))
        params = {o.split("=", 1)[0]: _value_label(o.split("=", 1)[1]) for o in own}
        name = c.get("name") or case_name(params, scene if len(scenes) > 1 else None)
        if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_+=,][A-Za-z0-9._+=,-]*", name):
            raise SweepError(f"{where}.name = {name!r}: expected letters, digits and . _ + - = , not starting with "
                             "'-' or '.' (a folder name that shell tools would read as an option, or a hidden one)")
        f = frames if frames is not None else (_frames(c.get("frames"), where) or sweep_frames)
        cases.append(Case(name=name, scene=_scene_ref(scene, base), overrides=sweep_fixed + own,
                          params=({"scene": Path(scene).stem} if len(scenes) > 1 else {}) | params, frames=f))
    if not cases:
        raise SweepError(f"{p}: no cases: add sweep.param or [[case]] tables")
    return _unique(cases)

