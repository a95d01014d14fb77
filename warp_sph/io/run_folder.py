"""The run folder: run.json, recorded frames, checkpoints; never clobber a user's files (the writes are
atomic: ``warp_sph.io.atomic``).

Layout of DIR:
    run.json                      resolved scene, versions, device, counts, per-frame statistics
    <scene>.usdc                  particles + surface for Blender (saved after every frame)
    frames/frame_000001.npz       recorded frames: x [m] (world), v [m/s], density [kg/m^3], time [s]
    checkpoints/checkpoint_000010.npz   exact state to resume from (written atomically, after the
                                  frame's other outputs: checkpoint k implies frames 1..k are saved)
    mesh/surface_000001.obj       optional mesh sequence
    probe_<name>.csv              probe samples (``[[probes]]``, ``warp_sph.io.probe_files``)
    plots/probe_<name>.png        probe plots (``warp-sph plot``)
    export/                       re-exports from the recorded frames (``warp-sph export``)
"""
from __future__ import annotations

import json
import re
import zipfile
from pathlib import Path

import numpy as np

from ..core.errors import OutputError

RUN_JSON = "run.json"

#: file names a run (or ``warp-sph preview``) writes inside its folder; ``--overwrite`` removes
#: only these (plus the USD named in the previous run.json), never anything else
RUN_FILE_PATTERNS = {
    "frames": re.compile(r"frame_\d{6}\.npz"),
    "checkpoints": re.compile(r"checkpoint_\d{6}\.npz"),
    "mesh": re.compile(r"surface_\d{6}\.(obj|ply|vtk)"),
    "preview": re.compile(r"(particles|surface)(_\d{6}\.png|\.gif)"),
    "plots": re.compile(r"probe_[A-Za-z0-9_-]+\.png"),
}
#: the probes' CSV files beside run.json (``warp_sph.io.probe_files``)
PROBE_CSV_PATTERN = re.compile(r"probe_[A-Za-z0-9_-]+\.csv")
#: temporary files of the atomic writes (``warp_sph.io.atomic``; left behind only by a crash during a write)
_TEMP_PATTERN = re.compile(r"\.(frame|checkpoint|surface|particles|run|probe)[A-Za-z0-9_.-]*\.tmp(\.npz)?")


def safe_name(name: str) -> str:
    """A file name made from a scene name: letters, digits, '.', '_' and '-' kept, every other
    character (path separators included) replaced by '_', no leading dot; "scene" if nothing is
    left. ``"../precious"`` -> ``"precious"``, ``"my tank/v2"`` -> ``"my_tank_v2"``."""
    text = re.sub(r"[^A-Za-z0-9._-]", "_", str(name)).lstrip("._")
    return text[:120] or "scene"


def is_run_folder(path: Path) -> bool:
    return (Path(path) / RUN_JSON).is_file()


def choose_run_folder(out: Path | None, scene_name: str, overwrite: bool) -> Path:
    """Choose the output folder and check it can be used; changes nothing on disk.

    Default (out None): runs/<name>, or runs/<name>-2, -3 ... when that holds something already,
    where <name> is ``safe_name(scene_name)``: a scene name never places a run outside runs/.
    An explicit folder must be new or empty; one holding a previous run is reused only with
    overwrite=True (``clear_run`` then removes that run's files and nothing else); a non-empty
    folder that is not a run is refused.
    """
    if out is None:
        name = safe_name(scene_name)
        base = Path("runs") / name
        out = base
        k = 2
        while out.exists() and (not out.is_dir() or any(out.iterdir())):
            out = base.with_name(f"{name}-{k}")
            k += 1
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"output path {out} exists and is not a folder")
    if out.exists() and any(out.iterdir()):
        if not is_run_folder(out):
            raise OutputError(f"output folder {out} is not empty and holds no warp-sph run; choose another --out")
        if not overwrite:
            raise OutputError(f"output folder {out} holds a previous run; pass --overwrite to replace it "
                              f"or --resume {out} to continue it")
    return out


def create_run_folder(out: Path) -> list[Path]:
    """Create ``out`` (and missing parents) and check it is writable. Returns the folders created,
    outermost first, so that a start that fails can remove them again (``remove_new_folders``)."""
    out = Path(out)
    created = []
    p = out
    while not p.exists() and p != p.parent:
        created.append(p)
        p = p.parent
    created.reverse()
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write_test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        remove_new_folders(created)
        raise OutputError(f"cannot write to output folder {out}: {e.strerror or e}") from None
    return created


def remove_new_folders(created: list[Path]) -> None:
    """Remove the folders ``create_run_folder`` made, innermost first, where they are empty."""
    for d in reversed(created):
        try:
            d.rmdir()
        except OSError:
            return


def prepare_run_folder(out: Path | None, scene_name: str, overwrite: bool) -> Path:
    """choose_run_folder + clear_run (with overwrite) + create_run_folder, in one call."""
    out = choose_run_folder(out, scene_name, overwrite)
    if is_run_folder(out):
        clear_run(out)
    create_run_folder(out)
    return out


def run_files(out: Path) -> list[Path]:
    """The files of the run in ``out`` that a run writes: run.json, the USD named after the scene
    of its run.json, frames, checkpoints, mesh files, previews and temporary files of
    interrupted writes. Anything else in the folder is the user's."""
    out = Path(out)
    found = []
    if (out / RUN_JSON).is_file():
        found.append(out / RUN_JSON)
        try:
            info = json.loads((out / RUN_JSON).read_text())
            name = info["scene"]["name"]
        except (OSError, ValueError, KeyError, TypeError):
            name = None
        if isinstance(name, str):
            usd = out / f"{safe_name(name)}.usdc"
            if usd.is_file():
                found.append(usd)
    found += [p for p in sorted(out.iterdir()) if p.is_file() and (_TEMP_PATTERN.fullmatch(p.name)
                                                                   or PROBE_CSV_PATTERN.fullmatch(p.name))]
    for sub, pattern in RUN_FILE_PATTERNS.items():
        d = out / sub
        if d.is_dir():
            found += [p for p in sorted(d.iterdir())
                      if p.is_file() and (pattern.fullmatch(p.name) or _TEMP_PATTERN.fullmatch(p.name))]
    return found


def clear_run(out: Path) -> list[Path]:
    """Remove the files a previous run wrote (``run_files``) and nothing else; returns them."""
    removed = run_files(out)
    for p in removed:
        p.unlink()
    for sub in RUN_FILE_PATTERNS:
        d = Path(out) / sub
        if d.is_dir() and not any(d.iterdir()):
            d.rmdir()
    return removed


def remove_files(paths) -> None:
    for p in paths:
        try:
            Path(p).unlink()
        except FileNotFoundError:
            pass


def frame_path(out: Path, frame: int) -> Path:
    return Path(out) / "frames" / f"frame_{frame:06d}.npz"


def checkpoint_path(out: Path, frame: int) -> Path:
    return Path(out) / "checkpoints" / f"checkpoint_{frame:06d}.npz"


def latest_checkpoint(out: Path) -> Path | None:
    d = Path(out) / "checkpoints"
    cps = sorted(p for p in d.glob("checkpoint_*.npz") if RUN_FILE_PATTERNS["checkpoints"].fullmatch(p.name)) \
        if d.is_dir() else []
    return cps[-1] if cps else None


def _frame_number(path: Path) -> int | None:
    """N of ``<prefix>_NNNNNN.<ext>`` (frames, checkpoints, mesh files), None for other names."""
    m = re.fullmatch(r"[a-z]+_(\d+)", path.stem)
    return int(m.group(1)) if m else None


def files_after(out: Path, frame: int) -> list[Path]:
    """Recorded frames, checkpoints and mesh-sequence files of frames after ``frame``: what a resume
    from the checkpoint of ``frame`` writes again."""
    found = []
    for sub in ("frames", "checkpoints", "mesh"):
        d = Path(out) / sub
        for p in sorted(d.iterdir()) if d.is_dir() else []:
            n = _frame_number(p)
            if p.is_file() and RUN_FILE_PATTERNS[sub].fullmatch(p.name) and n is not None and n > frame:
                found.append(p)
    return found


def truncate_run(out: Path, frame: int) -> list[Path]:
    """Remove ``files_after(out, frame)`` (before a resume from the checkpoint of ``frame``).
    Returns them."""
    removed = files_after(out, frame)
    remove_files(removed)
    return removed


def read_run_json(out: Path) -> dict:
    """run.json of a run folder; OutputError (one line) when it is missing, unreadable or holds no scene."""
    p = Path(out) / RUN_JSON
    if not p.is_file():
        raise OutputError(f"{out} is not a warp-sph run folder (no {RUN_JSON})")
    try:
        info = json.loads(p.read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise OutputError(f"{p}: unreadable JSON ({e})") from None
    if not isinstance(info, dict) or not isinstance(info.get("scene"), dict):
        raise OutputError(f"{p}: not a warp-sph run.json (it holds no 'scene' table)")
    return info


def check_frame_file(path: Path, keys=("x", "v", "density")) -> None:
    """OutputError (the line ``read_frame`` gives) unless ``path`` opens as an npz archive holding the
    arrays ``keys`` ("v?" optional): reads the archive's directory only, not the arrays, so a long run's
    frames are checked before an export writes anything (a damaged array's data still fails in
    ``read_frame``)."""
    path = Path(path)
    try:
        if not zipfile.is_zipfile(path):
            raise ValueError("not an npz archive: damaged or truncated")
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist())
        for k in keys:
            if not k.endswith("?") and f"{k}.npy" not in names:
                raise KeyError(f"{k} is not a file in the archive")
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError, RuntimeError) as exc:
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__  # as read_frame says it
        raise OutputError(f"{path}: unreadable recorded frame ({text})") from None


def read_frame(path: Path, keys=("x", "v", "density")) -> dict[str, np.ndarray]:
    """The arrays ``keys`` of a recorded frame file (``frames/frame_NNNNNN.npz``); OutputError (one
    line, naming the file) when it is missing, truncated, not an npz or lacks one of them. A key
    written as ``"v?"`` is optional (left out of the result when the frame has none)."""
    path = Path(path)
    try:
        if not zipfile.is_zipfile(path):  # (np.load would take it for a pickle and say so)
            raise ValueError("not an npz archive: damaged or truncated")
        with np.load(path, allow_pickle=False) as data:
            return {k.rstrip("?"): np.asarray(data[k.rstrip("?")]) for k in keys
                    if not k.endswith("?") or k.rstrip("?") in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError, RuntimeError) as exc:
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise OutputError(f"{path}: unreadable recorded frame ({text})") from None


#: arrays every checkpoint holds: name -> (dtype kind, trailing shape)
CHECKPOINT_ARRAYS = {"particle_x_local": ("f", (3,)), "particle_v": ("f", (3,)), "step": ("i", ()),
                     "frame": ("i", ()), "state_frame": ("i", ()), "time": ("f", ()), "last_max_speed": ("f", ())}


def load_checkpoint(path: Path) -> dict:
    """Every array of a checkpoint file, checked for the keys, shapes and finite values a resume
    needs; OutputError (one line, naming the file) otherwise. Nothing is pickled or executed."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            cp = {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError, RuntimeError) as exc:
        raise OutputError(f"{path}: unreadable checkpoint ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else 'truncated?'}); "
                          "remove it to resume from an earlier one") from None
    for key, (kind, shape) in CHECKPOINT_ARRAYS.items():
        a = cp.get(key)
        if a is None:
            raise OutputError(f"{path}: not a warp-sph checkpoint (no {key!r}); remove it to resume from an earlier one")
        ok = a.dtype.kind in (kind, "i", "u") if kind == "f" else a.dtype.kind in ("i", "u")
        if not ok or (a.shape[1:] != shape if shape else a.shape != ()):
            raise OutputError(f"{path}: checkpoint array {key!r} has dtype {a.dtype} and shape {a.shape}, "
                              f"expected {'float' if kind == 'f' else 'integer'} of shape {('N',) + shape if shape else ()}")
        if kind == "f" and not np.all(np.isfinite(a)):
            raise OutputError(f"{path}: checkpoint array {key!r} holds non-finite values")
    if len(cp["particle_x_local"]) != len(cp["particle_v"]):
        raise OutputError(f"{path}: {len(cp['particle_x_local'])} positions but {len(cp['particle_v'])} velocities")
    return cp
