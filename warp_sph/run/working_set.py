"""What a run's step reads against what the CPU caches: the bytes of the simulation's arrays (run.json ``array_bytes``)
and the size of the CPU's last-level cache.

``warp-sph plan`` compares the two (docs/plan.md, item 12): the dam break's DFSPH calibrated with its arrays inside this
CPU's 32 MiB L3 (20.4 MiB at 10,648 fluid particles) ran at 50,653 (90.7 MiB) 1.47x its largest calibrated count's cost
per fluid particle-step, while the dam break's PBF and the hydrostatic tank's DFSPH crossed the L3 at no cost. So the
plan measures the cost past the cache (a timing point) rather than scale it. What it compares with the cache is
``read_bytes``, the arrays at the rows' used entries: DFSPH's pair rows use about 40 % of their slots and, packed on the
CPU, stream only those, so the allocation (``array_bytes``) put a point past the L3 whose steps read half of it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import warp as wp

#: where Linux lists the CPU's caches (``index*/level`` and ``index*/size``, e.g. "32768K")
CPU_CACHE_DIR = Path("/sys/devices/system/cpu/cpu0/cache")


def array_bytes(sim) -> int:
    """[bytes] of every Warp array the simulation ``sim`` holds (its fields, model, state, solver and forces, and the
    objects of this package they hold: neighbour lists, pair caches), each array counted once."""
    seen: set[int] = set()
    total = 0
    stack = [sim]
    while stack:
        obj = stack.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        if isinstance(obj, wp.array):
            total += obj.size * wp.types.type_size_in_bytes(obj.dtype)
        elif isinstance(obj, dict):
            stack.extend(obj.values())
        elif isinstance(obj, (list, tuple)):
            stack.extend(obj)
        elif isinstance(obj, type):
            continue
        elif hasattr(getattr(obj, "_cls", None), "vars"):  # a Warp struct (a pair cache, a list's rows)
            stack.extend(getattr(obj, name) for name in obj._cls.vars)
        elif type(obj).__module__.startswith("warp_sph") and hasattr(obj, "__dict__"):
            stack.extend(vars(obj).values())
    return int(total)


def _rows(holder):
    """(per-row counts as NumPy, the row arrays) of a holder of row-structured arrays: a ``count`` int32 array of n
    rows and arrays of n x capacity entries (2-D (n, capacity), or 1-D of n x capacity: DFSPH's pair rows); (None,
    ()) for anything else."""
    count = getattr(holder, "count", None)
    if not isinstance(count, wp.array) or count.dtype != wp.int32 or count.ndim != 1 or count.shape[0] < 1:
        return None, ()
    n = count.shape[0]
    names = holder._cls.vars if hasattr(getattr(holder, "_cls", None), "vars") else vars(holder)  # fields, no properties
    rows = []
    for name in names:
        a = getattr(holder, name, None)
        if isinstance(a, wp.array) and a is not count and a.size > n and a.shape[0] in (n, a.size) and a.size % n == 0:
            rows.append(a)
    return count.numpy(), rows


def read_bytes(sim) -> int:
    """[bytes] a step reads of the simulation's arrays: ``array_bytes``, with each row-structured array (neighbour
    lists, pair caches: a ``count`` per row and rows of a fixed capacity) counted at its rows' used entries,
    sum_i min(count_i, capacity) entries, not at its allocation (DFSPH's pair rows use about 40 % of their 64 slots, and
    on the CPU they are packed: what the passes stream, docs/plan.md item 12)."""
    total = array_bytes(sim)
    seen: set[int] = set()
    stack = [sim]
    while stack:
        obj = stack.pop()
        if id(obj) in seen or isinstance(obj, (wp.array, type)):
            continue
        seen.add(id(obj))
        counts, rows = _rows(obj)
        for a in rows:
            if id(a) in seen:
                continue
            seen.add(id(a))
            capacity = a.size // counts.shape[0]
            used = int(np.minimum(np.maximum(counts, 0), capacity).sum())
            total -= (a.size - used) * wp.types.type_size_in_bytes(a.dtype)
        if isinstance(obj, dict):
            stack.extend(obj.values())
        elif isinstance(obj, (list, tuple)):
            stack.extend(obj)
        elif hasattr(getattr(obj, "_cls", None), "vars"):
            stack.extend(getattr(obj, name) for name in obj._cls.vars)
        elif type(obj).__module__.startswith("warp_sph") and hasattr(obj, "__dict__"):
            stack.extend(vars(obj).values())
    return int(total)


def last_level_cache_bytes(root: Path | None = None) -> int:
    """[bytes] of the CPU's largest-level cache (Linux sysfs under ``root``, default CPU_CACHE_DIR; 0 where it is not
    listed)."""
    best = (0, 0)
    for index in sorted(Path(root or CPU_CACHE_DIR).glob("index*")):
        try:
            level = int((index / "level").read_text().strip())
            size = (index / "size").read_text().strip().upper()
        except (OSError, ValueError):
            continue
        scale = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}.get(size[-1:], 1)
        try:
            value = int(size.rstrip("KMG")) * scale
        except ValueError:
            continue
        best = max(best, (level, value))
    return best[1]
