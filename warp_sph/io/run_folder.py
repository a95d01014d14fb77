"""The run folder: run.json, recorded frames, checkpoints; atomic writes; never clobber a user's files.

Layout of DIR:
    run.json                      resolved scene, versions, device, counts, per-frame statistics
    <scene>.usdc                  particles + surface for Blender (saved after every frame)
    frames/frame_000001.npz       recorded frames: x [m] (world), v [m/s], density [kg/m^3], time [s]
    checkpoints/checkpoint_000010.npz   exact state to resume from (written atomically, after the
                                  frame's other outputs: checkpoint k implies frames 1..k are saved)
    mesh/surface_000001.obj       optional mesh sequence
    export/                       re-exports from the recorded frames (``warp-sph export``)
"""
from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path

import numpy as np

from ..core.errors import OutputError

RUN_JSON = "run.json"


def atomic_write_bytes(path: Path, data: bytes) -> None:
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def to_json(obj, indent: int | None = None) -> str:
    """JSON text of run data (NumPy scalars and arrays, Paths included)."""
    return json.dumps(obj, indent=indent, default=_json_default)


def atomic_write_json(path: Path, obj) -> None:
    atomic_write_bytes(path, to_json(obj, indent=1).encode())


def atomic_save_npz(path: Path, **arrays) -> None:
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp.npz", dir=path.parent)
    os.close(fd)
    try:
        np.savez(tmp, **arrays)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def is_run_folder(path: Path) -> bool:
    return (Path(path) / RUN_JSON).is_file()


def prepare_run_folder(out: Path | None, scene_name: str, overwrite: bool) -> Path:
    """Choose and create the output folder.

    Default (out None): runs/<scene>, or runs/<scene>-2, -3 ... when that holds a run already.
    An explicit folder must be new or empty; one holding a previous run is reused only with
    overwrite=True (its run files are replaced); a non-empty folder that is not a run is refused.
    """
    if out is None:
        base = Path("runs") / scene_name
        out = base
        k = 2
        while out.exists() and any(out.iterdir()):
            out = base.with_name(f"{scene_name}-{k}")
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
        _clear_run(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write_test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise OutputError(f"cannot write to output folder {out}: {e.strerror or e}") from None
    return out


def _clear_run(out: Path) -> None:
    """Remove the files a previous run wrote (and nothing else)."""
    for sub in ("frames", "checkpoints", "mesh", "preview"):
        d = out / sub
        if d.is_dir():
            for f in d.iterdir():
                if f.is_file() and (f.suffix in (".npz", ".obj", ".ply", ".vtk", ".png", ".gif", ".json")):
                    f.unlink()
    for f in out.iterdir():
        if f.is_file() and (f.name == RUN_JSON or f.suffix == ".usdc"):
            f.unlink()


def frame_path(out: Path, frame: int) -> Path:
    return Path(out) / "frames" / f"frame_{frame:06d}.npz"


def checkpoint_path(out: Path, frame: int) -> Path:
    return Path(out) / "checkpoints" / f"checkpoint_{frame:06d}.npz"


def latest_checkpoint(out: Path) -> Path | None:
    d = Path(out) / "checkpoints"
    cps = sorted(d.glob("checkpoint_*.npz")) if d.is_dir() else []
    return cps[-1] if cps else None


def _frame_number(path: Path) -> int | None:
    """N of ``<prefix>_NNNNNN.<ext>`` (frames, checkpoints, mesh files), None for other names."""
    m = re.fullmatch(r"[a-z]+_(\d+)", path.stem)
    return int(m.group(1)) if m else None


def truncate_run(out: Path, frame: int) -> list[Path]:
    """Remove recorded frames, checkpoints and mesh-sequence files after ``frame`` (before a resume
    from the checkpoint of ``frame``: what a run wrote beyond it is written again). Returns them."""
    removed = []
    for sub, suffixes in (("frames", (".npz",)), ("checkpoints", (".npz",)), ("mesh", (".obj", ".ply", ".vtk"))):
        d = Path(out) / sub
        for p in sorted(d.iterdir()) if d.is_dir() else []:
            n = _frame_number(p)
            if p.is_file() and p.suffix in suffixes and n is not None and n > frame:
                p.unlink()
                removed.append(p)
    return removed


def read_run_json(out: Path) -> dict:
    p = Path(out) / RUN_JSON
    if not p.is_file():
        raise OutputError(f"{out} is not a warp-sph run folder (no {RUN_JSON})")
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise OutputError(f"{p}: unreadable JSON ({e})") from None
