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
import threading
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


# --- loops of recorded launches on persistent threads (CPU) ----------------------------------------

#: argument types compared by value when re-binding a replayed launch
_SCALARS = (int, float, bool)


def _binding(value):
    """What decides how ``value`` is packed into a launch: arrays by pointer, shape and strides, Warp
    structs by their packed bytes (a struct whose array member was replaced differs), scalars by type
    and value; None (always re-bind) for anything else."""
    if isinstance(value, wp.array):
        return ("array", value.ptr, value.shape, value.strides, value.dtype)
    if type(value) in _SCALARS:
        return (type(value), value)
    ctype = getattr(value, "_ctype", None)
    if ctype is not None:
        return ("struct", type(value), bytes(ctype))
    return None


class Replays:
    """Recorded launches kept per call site (kernel, tag) and re-bound only where an argument's binding
    (``_binding``) changed since the last call: a loop that launches the same kernels with the same
    arrays many times (a solver's sweeps) pays Warp's argument packing once. ``get`` returns the
    :class:`Recorded` for ``run_loop``."""

    def __init__(self):
        self._cache: dict = {}

    def get(self, kernel, dim: int, inputs, outputs=(), device=None, min_range: int = MIN_RANGE, tag=None) -> Recorded:
        device = wp.get_device(device)
        args = [*inputs, *outputs]
        threads = _thread_count(dim, device, min_range) if _takes_offset(kernel) else 1
        key = (kernel, tag, device.alias)
        entry = self._cache.get(key)
        if entry is None or entry[0].threads != threads or len(entry[1]) != len(args):
            rec = record(kernel, dim, inputs, outputs, device=device, min_range=min_range)
            self._cache[key] = (rec, [_binding(a) for a in args])
            return rec
        rec, bound = entry
        for i, value in enumerate(args):
            b = _binding(value)
            if b is None or b != bound[i]:
                rec.set(i, value)
                bound[i] = b
        rec.resize(dim)
        return rec


class _Barrier:
    """A reusable barrier for ``parties`` threads: a counter under a lock and two semaphores used in
    alternate rounds (a thread already waiting in the next round cannot take a release meant for
    this one); about half the cost of ``threading.Barrier``'s condition variable."""

    def __init__(self, parties: int):
        self.parties = parties
        self._lock = threading.Lock()
        self._count = 0
        self._round = 0
        self._gates = (threading.Semaphore(0), threading.Semaphore(0))

    def wait(self) -> None:
        with self._lock:
            gate = self._gates[self._round]
            self._count += 1
            last = self._count == self.parties
            if last:
                self._count = 0
                self._round ^= 1
        if last:
            gate.release(self.parties - 1)
        else:
            gate.acquire()


class _LoopWorkers:
    """Persistent daemon threads 1..count of ``run_loop`` (thread 0 is the caller)."""

    def __init__(self, count: int):
        self.count = count
        self.barrier = _Barrier(count + 1)
        self.job = None
        self._start = [threading.Semaphore(0) for _ in range(count)]
        for k in range(count):
            threading.Thread(target=self._work, args=(k,), daemon=True, name=f"warp_sph_loop_{k + 1}").start()

    def _work(self, k: int) -> None:
        while True:
            self._start[k].acquire()
            self.job(k + 1)

    def start(self, job) -> None:
        self.job = job
        for s in self._start:
            s.release()


_loop_workers: _LoopWorkers | None = None
_loop_lock = threading.Lock()


def _ranges(item) -> list:
    """The callables of a ``run_loop`` item: one per recorded range, or the item itself (thread 0)."""
    return [cmd.launch for cmd in item.cmds] if isinstance(item, Recorded) else [item]


def run_loop(groups, sweeps: int, stop=None) -> int:
    """Run up to ``sweeps`` sweeps of ``groups`` (a list of lists of :class:`Recorded` launches, or of
    callables that run on thread 0, e.g. ``wp.utils.array_scan`` between two passes) with one
    hand-off for the whole loop: on the CPU each range k of a recorded launch runs on thread k
    (thread 0: the caller; the others: persistent threads) and all threads meet at a barrier after
    each group, so a group sees everything the groups before it wrote. A launch recorded in fewer
    ranges (a serial kernel: a reduction, a one-thread control kernel) runs its ranges on the first
    threads while the rest wait at the barrier. After each sweep thread 0 calls ``stop(sweep)``
    (sweep: 1-based; a host read such as a solve's stop test) and all threads end the loop when it
    returns True. The same launches in the same order as launching each range of each group in turn,
    sweep after sweep: results are bitwise those of ``launch``. Returns the sweeps run."""
    global _loop_workers
    ranges = [[_ranges(r) for r in g] for g in groups]
    threads = max((len(r) for g in ranges for r in g), default=1)
    if threads <= 1 or sweeps <= 0:
        for s in range(1, sweeps + 1):
            for g in ranges:
                for r in g:
                    for run in r:
                        run()
            if s < sweeps and stop is not None and stop(s):
                return s
        return max(sweeps, 0)
    with _loop_lock:  # one loop at a time on the shared workers
        if _loop_workers is None or _loop_workers.count != threads - 1:
            _loop_workers = _LoopWorkers(threads - 1)
        workers = _loop_workers
        barrier = workers.barrier
        state = {"done": 0, "error": None}
        plan = [[[r[k] for r in g if k < len(r)] for g in ranges] for k in range(threads)]

        def job(k: int) -> None:
            mine = plan[k]
            s = 0
            while True:
                s += 1
                for cmds in mine:
                    if state["error"] is None:
                        try:
                            for run in cmds:
                                run()
                        except BaseException as e:  # keep meeting the barriers; thread 0 raises it
                            state["error"] = e
                    barrier.wait()
                if k == 0:
                    end = s >= sweeps or state["error"] is not None
                    if not end and stop is not None:
                        try:
                            end = bool(stop(s))
                        except BaseException as e:
                            state["error"], end = e, True
                    state["done"] = s if end else 0
                barrier.wait()
                if state["done"]:
                    return

        workers.start(job)
        job(0)  # returns after the last barrier: every worker has run its last launch
        if state["error"] is not None:
            raise state["error"]
        return state["done"]
