"""Loading scenes: built-in names or TOML files, ``--set`` overrides by key path, validation.

    load_scene("dam_break", ["particle_radius=0.02", "fluid[0].max=[1,1,1]"])
"""
from __future__ import annotations

import copy
import importlib.resources
import re
import tomllib
import warnings
from pathlib import Path

from ..core.errors import SceneError
from .types import Scene
from .unused import UnusedKeyWarning, unused_keys
from .validate import Validator

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


def _refuse_folder(path: Path, text: str):
    run = (path / "run.json").is_file()
    raise SceneError(f"{text}: is a folder; expected a scene file (.toml) or a built-in scene name"
                     + (f" (it holds a run: warp-sph run --resume {text} continues it)" if run else ""))


def _resolve(name_or_path: str) -> Path:
    text = str(name_or_path)
    path = Path(text).expanduser()
    if path.suffix.lower() == ".toml" or "/" in text or "\\" in text or path.is_file():
        if path.is_dir():  # e.g. a run folder given where a scene goes
            _refuse_folder(path, text)
        if not path.is_file():
            raise SceneError(f"{text}: scene file not found")
        return path
    builtin = _scenes_dir() / f"{text}.toml"
    if not builtin.is_file() and path.is_dir():  # a folder of that name here (a built-in scene's name wins)
        _refuse_folder(path, text)
    if not builtin.is_file():
        names = ", ".join(n for n, _ in list_scenes())
        raise SceneError(f"{text}: no such scene file or built-in scene; built-in scenes: {names}")
    return builtin


def read_toml(path: Path) -> dict:
    """The TOML table of a scene (or sweep) file; SceneError (one line) when it is not UTF-8 TOML text."""
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: malformed TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: not a UTF-8 text file (byte {exc.object[exc.start]:#04x} at offset {exc.start}); "
                         "a scene is TOML text in UTF-8") from None
    except OSError as exc:
        raise SceneError(f"{path}: cannot read: {exc.strerror}") from None


def load_scene(name_or_path: str, overrides: list[str] | dict | None = None) -> Scene:
    """Load, override and validate a scene.

    name_or_path: the name of a built-in scene (``dam_break``) or a path to a .toml file;
    relative mesh paths resolve against the file's folder.
    overrides: ``["particle_radius=0.02", "fluid[0].max=[1,1,1]", "output.usd=false"]``, one such string, or a
    dict.
    Raises SceneError naming the file, the key path and what was expected; warns (UnusedKeyWarning, one
    line per section) of keys set in another solver's or boundary's section, which change nothing.
    """
    path = _resolve(name_or_path)
    data = read_toml(path)
    if isinstance(overrides, str):  # one "KEY=VALUE" (it was read character by character: --set 'p')
        overrides = [overrides]
    data = apply_overrides(data, overrides, str(path))
    scene = scene_from_dict(data, source=str(path), base_dir=path.parent)
    # another solver's keys: one line each, the run goes on. A shipped scene (built-in or validation) carries each
    # solver's tuning on purpose (--set solver=pbf picks it up): there only the keys of --set are the user's
    only = _override_keys(overrides) if _scenes_dir().resolve() in path.resolve().parents else None
    for line in unused_keys(data, scene, only):
        warnings.warn(line, UnusedKeyWarning, stacklevel=2)
    return scene


def with_override(message: str, overrides) -> str:
    """A scene error about a key that an override set (or about the table holding it) says so, as
    ``warp-sph run`` and ``check`` print it: "FILE: particle_radius: expected ..., got -1 (from --set
    particle_radius)": the value is not in the file."""
    parts = message.split(": ")
    if len(parts) < 3:
        return message
    where = parts[1]  # "FILE: KEYPATH: what was expected"
    keys = overrides.keys() if isinstance(overrides, dict) else [str(o).partition("=")[0] for o in overrides or ()]
    for key in (str(k).strip() for k in keys):
        if key and any(a == b or a.startswith(b + ".") or a.startswith(b + "[") for a, b in ((key, where), (where, key))):
            return f"{message} (from --set {key})"
    return message


def _override_keys(overrides) -> set:
    """The (table, key) pairs that ``--set`` overrides name, indices left out (``pbf.max_iterations`` ->
    ("pbf", "max_iterations"), ``bodies[0].fluid_friction`` -> ("bodies", "fluid_friction"))."""
    keys = overrides.keys() if isinstance(overrides, dict) else [str(o).partition("=")[0] for o in overrides or ()]
    out = set()
    for key in keys:
        tokens = [t for t in _parse_key_path(str(key)) if isinstance(t, str)]  # parsed by apply_overrides: valid
        if len(tokens) == 2:
            out.add(tuple(tokens))
    return out


def scene_from_dict(data: dict, source: str = "<dict>", base_dir: str | Path | None = None) -> Scene:
    """Validate a scene given as nested dicts/lists (TOML structure) and build the Scene.

    base_dir: folder that relative mesh paths resolve against (default: the working directory).
    """
    return Validator(source, Path(base_dir) if base_dir is not None else None).scene(data)


