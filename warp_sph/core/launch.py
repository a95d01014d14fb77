"""The one place host code launches kernels (returns early on empty ranges).

Kernels whose first parameter is ``tid_offset: int`` are particle-parallel over disjoint indices
``wp.tid() + tid_offset``. On the CPU, ``launch`` splits such a launch into one contiguous range
per worker thread (a CPU ``wp.launch`` releases the GIL, so the ranges run on separate cores) and
waits for all of them; elsewhere it launches once with offset 0. The caller never passes the
offset. Each thread writes only its own indices, so results do not depend on the thread count
or timing as long as the kernel does not accumulate across indices with atomics.

Other kernels (atomics across indices, ray tracing over pixels, 2-D and 3-D launches: ``dim`` a
tuple) run as one ``wp.launch``, unchanged.

Worker count: ``WARP_SPH_CPU_THREADS`` if set, else the number of cores this process may use.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import warp as wp

MIN_RANGE = 1024  # fewest indices worth a thread of their own
#: the same for light kernels (a few loads and flops per index: integrators, gathers, the equation
#: of state), for which a split costs more than it saves below this many indices
LIGHT_MIN_RANGE = 32768

_pool: ThreadPoolExecutor | None = None
_loaded: set = set()


def cpu_threads() -> int:
    """Worker threads for split CPU launches."""
    env = os.environ.get("WARP_SPH_CPU_THREADS")
    if env:
        return max(1, int(env))
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _takes_offset(kernel) -> bool:
    args = kernel.adj.args
    return bool(args) and args[0].label == "tid_offset"


def launch(kernel, dim: int | tuple[int, ...], inputs, outputs=(), device=None, min_range: int = MIN_RANGE) -> None:
    """wp.launch over ``dim`` threads (an int, or a tuple for a 2-D/3-D launch); nothing happens when
    a dimension is 0. Kernels taking ``tid_offset`` first (1-D only) run in disjoint ranges on all CPU
    cores (see the module docstring), each of at least ``min_range`` indices (``LIGHT_MIN_RANGE`` for
    light kernels)."""
    if isinstance(dim, tuple):
        if _takes_offset(kernel):
            raise ValueError(f"kernel {kernel.key} takes tid_offset: launch it over an int dim, got {dim}")
        if min(dim, default=0) <= 0:
            return
        wp.launch(kernel, dim=dim, inputs=list(inputs), outputs=list(outputs), device=device)
        return
    if dim <= 0:
        return
    if not _takes_offset(kernel):
        wp.launch(kernel, dim=dim, inputs=list(inputs), outputs=list(outputs), device=device)
        return
    device = wp.get_device(device)
    threads = _thread_count(dim, device, min_range)
    key = (kernel, device.alias)
    if getattr(kernel, "is_generic", False):  # one overload per argument type: each is loaded once
        key += tuple(getattr(a, "dtype", type(a)) for a in (*inputs, *outputs))
    if threads <= 1 or key not in _loaded:
        # the first launch also loads the module, from this thread only
        wp.launch(kernel, dim=dim, inputs=[0, *inputs], outputs=list(outputs), device=device)
        _loaded.add(key)
        return
    bounds = [dim * k // threads for k in range(threads + 1)]
    ins = list(inputs)
    outs = list(outputs)
    _run_split([partial(wp.launch, kernel, dim=bounds[k + 1] - bounds[k], inputs=[bounds[k], *ins], outputs=outs,
                        device=device) for k in range(threads)])


def _thread_count(dim: int, device, min_range: int) -> int:
    """Ranges a 1-D CPU launch of ``dim`` threads splits into: at most the CPU threads, each >= ``min_range``."""
    return max(min(cpu_threads(), dim // max(min_range, 1)), 1) if device.is_cpu else 1


def _run_split(calls) -> None:
    """Run ``calls[1:]`` on the thread pool and ``calls[0]`` on this thread; return when all have finished."""
    global _pool
    rest = calls[1:]
    if rest and (_pool is None or _pool._max_workers < len(rest)):
        _pool = ThreadPoolExecutor(max_workers=len(rest), thread_name_prefix="warp_sph_launch")
    futures = [_pool.submit(c) for c in rest]
    calls[0]()
    for f in futures:
        f.result()

class Recorded:
    """A launch recorded once and replayed (``record``): Warp packs the arguments at recording only,
    so a replay costs a few microseconds of Python instead of a full ``wp.launch``. The same split
    into thread ranges as ``launch``; ``set(index, value)`` replaces input/output ``index`` (counted
    without ``tid_offset``) in every range."""

    def __init__(self, kernel, dim: int, inputs, outputs=(), device=None, min_range: int = MIN_RANGE):
        device = wp.get_device(device)
        offset = 1 if _takes_offset(kernel) else 0
        threads = _thread_count(dim, device, min_range) if offset else 1
        bounds = [dim * k // threads for k in range(threads + 1)]
        ins, outs = list(inputs), list(outputs)
        self.offset = offset
        self.dim = dim
        self.threads = threads
        # recording loads the module from this thread (as launch's first call does)
        self.cmds = [wp.launch(kernel, dim=bounds[k + 1] - bounds[k], inputs=[bounds[k], *ins][1 - offset:],
                               outputs=outs, device=device, record_cmd=True)
                     for k in range(threads) if bounds[k + 1] > bounds[k]]

    def resize(self, dim: int) -> None:
        """Launch over ``dim`` threads from now on, in as many ranges as recorded (each non-empty:
        dim >= the number of ranges)."""
        if dim == self.dim:
            return
        n = len(self.cmds)
        for k, cmd in enumerate(self.cmds):
            lo, hi = dim * k // n, dim * (k + 1) // n
            cmd.set_dim(hi - lo)
            if self.offset:
                cmd.set_param_at_index(0, lo)
        self.dim = dim

    def set(self, index: int, value) -> None:
        for cmd in self.cmds:
            cmd.set_param_at_index(index + self.offset, value)

    def launch(self) -> None:
        """Run the recorded launch (every range; waits for all of them)."""
        if self.cmds:
            _run_split([cmd.launch for cmd in self.cmds])

def record(kernel, dim: int, inputs, outputs=(), device=None, min_range: int = MIN_RANGE) -> Recorded:
    """A :class:`Recorded` launch of ``kernel`` over ``dim`` threads (1-D; split into ranges like
    ``launch``), for a kernel launched many times with the same or few changed arguments (an
    iteration loop). ``dim`` must be > 0."""
    if dim <= 0:
        raise ValueError(f"record: kernel {kernel.key} needs dim > 0, got {dim}")
    return Recorded(kernel, dim, inputs, outputs, device=device, min_range=min_range)
