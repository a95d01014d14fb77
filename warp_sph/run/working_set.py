"""What a run's step reads against what the CPU caches: the bytes of the simulation's arrays (run.json ``array_bytes``)
and the size of the CPU's last-level cache.

``warp-sph plan`` compares the two (docs/plan-model.md, item 12): the dam break's DFSPH calibrated with its arrays
inside this CPU's 32 MiB L3 (20.4 MiB at 10,648 fluid particles) ran at 50,653 (90.7 MiB) 1.47x its largest calibrated
count's cost per fluid particle-step, while the dam break's PBF and the hydrostatic tank's DFSPH crossed the L3 at no
cost. So the plan measures the cost past the cache (a timing point) rather than scale it. What it compares with the
cache is ``read_bytes``, the arrays at the rows' used entries: DFSPH's pair rows use about 40 % of their slots and,
packed on the CPU, stream only those, so the allocation (``array_bytes``) put a point past the L3 whose steps read half
of it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import warp as wp

#: where Linux lists the CPU's caches (``index*/level`` and ``index*/size``, e.g. "32768K")
CPU_CACHE_DIR = Path("/sys/devices/system/cpu/cpu0/cache")


def _fields(obj) -> list:
    """The values ``obj`` holds that the walk follows: a dict's values, a list's items, a Warp struct's fields, the
    attributes of an object of this package (never its properties); nothing for anything else."""
    if isinstance(obj, dict):
        return list(obj.values())
    if isinstance(obj, (list, tuple)):
        return list(obj)
    if isinstance(obj, type):
        return []
    if hasattr(getattr(obj, "_cls", None), "vars"):  # a Warp struct (a pair cache, a list's rows)
        return [getattr(obj, name, None) for name in obj._cls.vars]
    if type(obj).__module__.startswith("warp_sph") and hasattr(obj, "__dict__"):
        return list(vars(obj).values())
    return []


def _holders(sim):
    """Every object the simulation ``sim`` holds (its fields, model, state, solver and forces, and the objects of this
    package they hold: neighbour lists, pair caches), each once, Warp arrays included."""
    seen: set[int] = set()
    stack = [sim]
    while stack:
        obj = stack.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        yield obj
        if not isinstance(obj, wp.array):
            stack.extend(_fields(obj))


def _bytes(a: wp.array) -> int:
    return a.size * wp.types.type_size_in_bytes(a.dtype)


def array_bytes(sim) -> int:
    """[bytes] of every Warp array the simulation ``sim`` holds, each array counted once (their allocation)."""
    return int(sum(_bytes(obj) for obj in _holders(sim) if isinstance(obj, wp.array)))


def _unused_row_bytes_each(holder, counted: set[int]) -> list[tuple]:
    """(array, [bytes] of its unused entries) of each of a holder's row arrays: a ``count`` int32 array of n rows and
    arrays of n x capacity entries (2-D (n, capacity), or 1-D of n x capacity: DFSPH's pair rows), row i using
    min(count_i, capacity) of them; [] for anything else. Arrays already in ``counted`` are skipped, the others added
    to it."""
    count = getattr(holder, "count", None)
    if not isinstance(count, wp.array) or count.dtype != wp.int32 or count.ndim != 1 or count.shape[0] < 1:
        return []
    n, counts, out = count.shape[0], None, []
    for a in _fields(holder):
        if (not isinstance(a, wp.array) or a is count or id(a) in counted or a.size <= n
                or a.shape[0] not in (n, a.size) or a.size % n):
            continue
        counted.add(id(a))
        counts = count.numpy() if counts is None else counts
        used = int(np.minimum(np.maximum(counts, 0), a.size // n).sum())
        out.append((a, (a.size - used) * wp.types.type_size_in_bytes(a.dtype)))
    return out


def read_bytes(sim) -> int:
    """[bytes] a step reads of the simulation's arrays: ``array_bytes``, with each row-structured array (neighbour
    lists, pair caches: a ``count`` per row and rows of a fixed capacity) counted at its rows' used entries,
    sum_i min(count_i, capacity) entries, not at its allocation (DFSPH's pair rows use about 40 % of their 64 slots, and
    on the CPU they are packed: what the passes stream, docs/plan-model.md item 12)."""
    return int(sum(used_bytes(sim).values()))


def used_bytes(sim) -> dict[int, int]:
    """{id(array): [bytes]} of every Warp array the simulation ``sim`` holds, as ``read_bytes`` counts it: a row
    array at its rows' used entries, any other at its allocation (``bench scaling``'s launch-bytes model reads it)."""
    sizes, counted = {}, set()
    for obj in _holders(sim):
        if isinstance(obj, wp.array):
            sizes.setdefault(id(obj), _bytes(obj))
        else:
            for a, unused in _unused_row_bytes_each(obj, counted):
                sizes[id(a)] = sizes.get(id(a), _bytes(a)) - unused
    return sizes


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
