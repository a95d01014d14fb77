"""Keeping a crate (.usdc) file intact across a Save that fails part-way (a full disk).

A crate Save of an existing file writes the new values *over* the file's structural sections and
table of contents (its last ~1 kB: the smallest section start to the end) and on past the end, then
rewrites the table-of-contents offset in the header (measured with a byte diff before and after
``Save()``, usd-core 26.11). A Save that fails part-way leaves a header pointing past the end ("crate
file corrupt"). ``crate_tail`` reads the header and those last bytes before a Save;
``restore_crate_tail`` writes them back and truncates, which needs no free space: the file is then
as of its last good Save.
"""
from __future__ import annotations

import os
import struct

_CRATE_MAGIC = b"PXR-USDC"
_CRATE_HEADER = 88  # bootstrap: magic, version, table-of-contents offset, reserved


def crate_tail(path: str) -> tuple[bytes, int, bytes] | None:
    """(header, offset, bytes from offset to the end) of a crate file: what its next Save
    overwrites (the structural sections and the table of contents); None if not crate."""
    try:
        with open(path, "rb") as f:
            header = f.read(_CRATE_HEADER)
            if len(header) < 24 or header[:8] != _CRATE_MAGIC:
                return None
            toc = struct.unpack_from("<q", header, 16)[0]
            f.seek(toc)
            (count,) = struct.unpack("<Q", f.read(8))
            if not 0 < count < 64:
                return None
            table = f.read(32 * count)
            starts = [struct.unpack_from("<q", table, 32 * i + 16)[0] for i in range(count)]
            offset = min(starts + [toc])
            f.seek(offset)
            return header, offset, f.read()
    except (OSError, struct.error, ValueError):
        return None


def restore_crate_tail(path: str, saved: tuple[bytes, int, bytes]) -> bool:
    """Write back what ``crate_tail`` read: the file is again as of its last good Save. Writes
    only over bytes the file already has, then truncates, so it needs no free space."""
    header, offset, tail = saved
    try:
        with open(path, "r+b") as f:
            f.seek(offset)
            f.write(tail)
            f.truncate(offset + len(tail))
            f.seek(0)
            f.write(header)
            f.flush()
            os.fsync(f.fileno())
        return True
    except OSError:
        return False
