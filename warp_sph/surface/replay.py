"""Replayed launches of the surface kernels: each (kernel, call site) is recorded once per thread
(``core.launch.Recorded``, Warp's ``record_cmd``) and replayed on later calls and frames with only
the arguments that changed re-packed. A plain ``wp.launch`` costs ~30 us of Python; a replay with a
new size and a few new arguments costs a few microseconds per change, and the surface makes ~45
launches per frame (``grid.launch`` routes them here).
"""
from __future__ import annotations

import threading

import warp as wp

from ..core import launch as _launch_module

_local = threading.local()

#: argument types compared by value (others, e.g. arrays and Warp vectors, by identity)
_BY_VALUE = (int, float, bool)


def _same(old, new) -> bool:
    return old is new or (type(new) in _BY_VALUE and type(old) is type(new) and old == new)


def replay(kernel, dim: int, inputs, outputs, device, min_range: int, tag=None) -> None:
    """Launch ``kernel`` over ``dim`` (> 0, 1-D) threads like ``core.launch.launch``, through the
    calling thread's recording for (kernel, tag); ``tag`` tells apart the call sites of a kernel
    launched from several places in a frame."""
    cache = getattr(_local, "cache", None)
    if cache is None:
        cache = _local.cache = {}
    device = wp.get_device(device)
    args = [*inputs, *outputs]
    threads = 1
    if device.is_cpu and _launch_module._takes_offset(kernel):
        threads = max(1, min(_launch_module.cpu_threads(), dim // max(min_range, 1)))
    key = (kernel, tag, device.alias)
    entry = cache.get(key)
    if entry is None or entry[0].threads != threads or len(entry[1]) != len(args):
        rec = _launch_module.record(kernel, dim, inputs, outputs, device=device, min_range=min_range)
        if rec.threads != threads:  # (record() computes the same split; guard against drift)
            raise RuntimeError(f"replay: {kernel.key} recorded in {rec.threads} ranges, expected {threads}")
        cache[key] = (rec, args)
        rec.launch()
        return
    rec, old = entry
    for i, value in enumerate(args):
        if not _same(old[i], value):
            rec.set(i, value)
            old[i] = value
    rec.resize(dim)
    rec.launch()
