"""Replayed launches of the surface kernels: each (kernel, call site) is recorded once per thread
(``core.launch.Replays``, over Warp's ``record_cmd``) and replayed on later calls and frames with only
the arguments that changed re-packed. A plain ``wp.launch`` costs ~30 us of Python; a replay with a
new size and a few new arguments costs a few microseconds per change, and the surface makes ~45
launches per frame (``grid.launch`` routes them here).
"""
from __future__ import annotations

import threading

from ..core.launch import Replays

_local = threading.local()


def replay(kernel, dim: int, inputs, outputs, device, min_range: int, tag=None) -> None:
    """Launch ``kernel`` over ``dim`` (> 0, 1-D) threads like ``core.launch.launch``, through the
    calling thread's recording for (kernel, tag); ``tag`` tells apart the call sites of a kernel
    launched from several places in a frame."""
    replays = getattr(_local, "replays", None)
    if replays is None:
        replays = _local.replays = Replays()
    replays.get(kernel, dim, inputs, outputs, device=device, min_range=min_range, tag=tag).launch()
