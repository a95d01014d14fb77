"""Atomic writes: a file holds its old or its new content, never a part (a temporary file beside it, then a
rename), made with the mode a plain ``open()`` gives; the free space on a disk; one-line OutputErrors for a
failed write (a full disk says how much is free and that --resume continues). The run folder
(``warp_sph.io.run_folder``), the exporters, probes, sweeps and plans write through these.
"""
from __future__ import annotations

import errno
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from ..core.errors import OutputError


def _umask() -> int:
    """The process umask, read without changing it (Linux /proc); else set and restored."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _mkstemp(path: Path, suffix: str) -> tuple[int, str]:
    """A temporary file beside ``path`` with the mode a plain ``open()`` would give (0666 & ~umask;
    mkstemp alone gives 0600)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_umask())
    except (OSError, AttributeError):
        pass
    return fd, tmp


def nearest_existing(path: Path) -> Path:
    """``path`` when it exists, else its nearest parent that does (the file system's root at the last)."""
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def not_a_folder(folder: Path) -> str | None:
    """Why ``folder`` cannot be a folder to write into: "is a file", or "lies under the file P" (its nearest
    existing parent is a file); None when it is a folder or can be made one."""
    p = nearest_existing(folder)
    if p.exists() and not p.is_dir():
        return "is a file" if p == Path(folder) else f"lies under the file {p}"
    return None


def free_bytes(path: Path) -> int | None:
    """Bytes free to this user on the file system holding ``path`` (its nearest existing folder)."""
    try:
        st = os.statvfs(nearest_existing(path))
    except (OSError, AttributeError):
        return None
    return st.f_bavail * st.f_frsize


def format_bytes(n: float | None) -> str:
    if n is None:
        return "unknown"
    for unit in ("B", "kB", "MB", "GB"):
        if abs(n) < 1000.0 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} TB"


def write_error(path: Path, exc: OSError) -> OutputError:
    """A one-line OutputError for a failed write: the path and, for a full disk, the free space."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return OutputError(f"no space left on device writing {path} ({format_bytes(free_bytes(path))} free); "
                           "free some space, then continue with --resume")
    return OutputError(f"cannot write {path}: {exc.strerror or exc}")


def check_free_space(path: Path, needed: int, what: str) -> None:
    """Raise OutputError before writing ``needed`` bytes at ``path`` when the disk has fewer free."""
    free = free_bytes(path)
    if free is not None and free < needed:
        raise OutputError(f"no space left on device for {what} in {Path(path).parent}: needs about "
                          f"{format_bytes(needed)}, {format_bytes(free)} free; free some space, then "
                          "continue with --resume")


def atomic_write_with(path: Path, write, suffix: str = ".tmp") -> None:
    """Call ``write(tmp)`` on a temporary file beside ``path`` (a name ending in ``suffix``), then rename it
    to ``path``: ``path`` holds either its old or its new content, never a part; the temporary file is
    removed when ``write`` fails. Raises OutputError (one line) when the write fails with an OSError."""
    path = Path(path)
    try:
        fd, tmp = _mkstemp(path, suffix)
        os.close(fd)
    except OSError as exc:
        raise write_error(path, exc) from None
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise write_error(path, exc) from None
        raise


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename (``atomic_write_with``)."""
    atomic_write_with(path, lambda tmp: Path(tmp).write_bytes(data))


def to_json(obj, indent: int | None = None) -> str:
    """JSON text of run data (NumPy scalars and arrays, Paths included)."""
    return json.dumps(obj, indent=indent, default=_json_default)


def atomic_write_json(path: Path, obj) -> None:
    atomic_write_bytes(path, to_json(obj, indent=1).encode())


def atomic_save_npz(path: Path, **arrays) -> None:
    """``np.savez`` through a temporary file and a rename (``atomic_write_with``)."""
    atomic_write_with(path, lambda tmp: np.savez(tmp, **arrays), ".tmp.npz")


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
