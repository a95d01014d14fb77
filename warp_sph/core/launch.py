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

import ctypes
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
    """Run ``calls[k]`` on thread k (0: this thread; the others: ``run_loop``'s persistent threads, woken by a
    semaphore and met at its barrier, about 10 us of hand-off against a thread pool's 17-180 us); return when
    all have finished. While those threads are taken (a split launch from inside a ``run_loop`` callable, or
    from a second Python thread) the others run on a thread pool instead."""
    global _pool
    if len(calls) > 1 and _loop_lock.acquire(blocking=False):
        try:
            errors = []
            workers = _workers(len(calls) - 1)
            barrier = workers.barrier_of(len(calls))

            def job(k: int) -> None:
                try:
                    calls[k]()
                except BaseException as e:  # still meet the barrier; this thread raises it
                    errors.append(e)
                barrier.wait()

            workers.start(job, len(calls))
            job(0)
        finally:
            _loop_lock.release()
        if errors:
            raise errors[0]
        return
    rest = calls[1:]
    if rest and (_pool is None or _pool._max_workers < len(rest)):
        _pool = ThreadPoolExecutor(max_workers=len(rest), thread_name_prefix="warp_sph_launch")
    futures = [_pool.submit(c) for c in rest]
    calls[0]()
    for f in futures:
        f.result()

#: replay recorded CPU launches through ``_prepared`` (their packed argument struct built once per change, not per
#: launch); False: through ``warp.Launch.launch`` (benchmarks/dfsph_step_profile.py times kernels there)
PREPARED_REPLAY = True
#: the Warp releases whose CPU launch ABI ``_prepared`` copies (an argument struct of (label, type(param)) fields passed
#: by reference to the kernel's forward entry, its type cached in ``Kernel._invoke_cache``): verified on 1.19.0; any
#: other version replays through Warp's own launch, which is always correct, only slower
PREPARED_WARP_VERSIONS = ("1.19.",)


def _prepared(cmd):
    """(callable, (struct, fields) or None): a callable that runs the recorded launch ``cmd`` (a ``warp`` Launch) as ``cmd.launch()`` does on the CPU, with
    its argument struct packed now, once: Warp's CPU ``invoke`` builds a ctypes struct of every argument on each
    launch (~0.3 us per argument, with the GIL held, on every thread of a split launch); here a replay is one call of
    the kernel's entry point with the same struct contents, so the kernel computes bitwise the same. ``cmd.launch``
    itself where that does not apply (a device, tile blocks, an adjoint, an active Warp graph capture)."""
    if not PREPARED_REPLAY or not wp.__version__.startswith(PREPARED_WARP_VERSIONS) or not cmd.device.is_cpu \
            or cmd.block_dim > 1 or cmd.adjoint:
        return cmd.launch, None
    try:
        from warp._src import context as _ctx
    except ImportError:  # (guarded by the version above; kept for a patched Warp)
        return cmd.launch, None
    kernel, params = cmd.kernel, cmd.params
    runtime = _ctx.runtime
    if not (hasattr(kernel, "_invoke_cache") and hasattr(runtime, "_apic_capture")
            and getattr(cmd.hooks, "forward", None) is not None):  # another Warp than 1.19's internals: its launch
        return cmd.launch, None
    key = (tuple(type(p) for p in params[1:]), False)
    cached = kernel._invoke_cache.get(key)
    if cached is None:  # as Warp's invoke builds and caches it on a first launch
        fields = [(a.label, type(params[1 + i])) for i, a in enumerate(kernel.adj.args)]
        cached = kernel._invoke_cache[key] = (type("ArgsStruct", (ctypes.Structure,), {"_fields_": fields}), fields)
    struct_type, fields = cached
    args = struct_type()
    for i, field in enumerate(fields):
        setattr(args, field[0], params[1 + i])
    forward, bounds_ref, args_ref = cmd.hooks.forward, ctypes.byref(params[0]), ctypes.byref(args)

    def run(args=args) -> None:  # (args: keeps the struct alive)
        if runtime._apic_capture is None:
            forward(bounds_ref, args_ref)
        else:
            cmd.launch()

    return run, (args, fields)


class Recorded:
    """A launch recorded once and replayed (``record``): Warp packs the arguments at recording only,
    and on the CPU each range's argument struct is built once (``_prepared``), so a replay is one call of
    the kernel (0.2-0.4 us of Python) instead of a full ``wp.launch``. The same split
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
        self._runs = None  # ``_prepared`` callables of the ranges (made on first use, again after a change)
        self._runs_mode = PREPARED_REPLAY
        self._structs: list = []

    def runs(self) -> list:
        """One callable per range (``_prepared``): what ``launch`` and ``run_loop`` call."""
        if self._runs is None or self._runs_mode != PREPARED_REPLAY:
            prepared = [_prepared(cmd) for cmd in self.cmds]
            self._runs = [run for run, _ in prepared]
            self._structs = [struct for _, struct in prepared]
            self._runs_mode = PREPARED_REPLAY
        return self._runs

    def resize(self, dim: int) -> None:
        """Launch over ``dim`` threads from now on, in as many ranges as recorded (each non-empty:
        dim >= the number of ranges)."""
        if dim == self.dim:
            return
        n = len(self.cmds)
        self._runs = None
        for k, cmd in enumerate(self.cmds):
            lo, hi = dim * k // n, dim * (k + 1) // n
            cmd.set_dim(hi - lo)
            if self.offset:
                cmd.set_param_at_index(0, lo)
        self.dim = dim

    def set(self, index: int, value) -> None:
        at = index + self.offset
        for k, cmd in enumerate(self.cmds):
            cmd.set_param_at_index(at, value)
            struct = self._structs[k] if self._runs is not None else None
            if struct is not None:  # the prepared struct's field, packed as Warp packed the parameter
                args, fields = struct
                name, ctype = fields[at]
                if type(cmd.params[1 + at]) is ctype:
                    setattr(args, name, cmd.params[1 + at])
                else:
                    self._runs = None

    def launch(self) -> None:
        """Run the recorded launch (every range; waits for all of them)."""
        if self.cmds:
            _run_split(self.runs())

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
    structs by their packed bytes (a struct whose array member was replaced differs), scalars, vectors
    and matrices by type and value; None (always re-bind) for anything else."""
    if isinstance(value, wp.array):
        return ("array", value.ptr, value.shape, value.strides, value.dtype)
    if type(value) in _SCALARS:
        return (type(value), value)
    ctype = getattr(value, "_ctype", None)
    if ctype is not None:
        return ("struct", type(value), bytes(ctype))
    if isinstance(value, ctypes.Array):  # Warp vectors and matrices (wp.vec3, ...): by type and bytes
        return ("values", type(value), bytes(value))
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
            self._cache[key] = (rec, [_binding(a) for a in args], args)
            return rec
        rec, bound, last = entry
        for i, value in enumerate(args):
            if value is last[i] and type(value) is wp.array:  # the same array object: the same binding
                continue
            b = _binding(value)
            if b is None or b != bound[i]:
                rec.set(i, value)
                bound[i] = b
        entry[2][:] = args
        rec.resize(dim)
        return rec


def replaying_launch(device):
    """A ``launch(kernel, dim, inputs, outputs=(), min_range=MIN_RANGE, tag=None)`` on ``device``: on the CPU a
    replay of the launch recorded at that call site (``core.launch.Replays``: Warp packs the arguments once, ~50 us
    less per launch; the same ranges, so bitwise ``launch``; ``tag`` tells apart two call sites of one kernel),
    elsewhere ``launch``."""
    if not wp.get_device(device).is_cpu:
        def run(kernel, dim, inputs, outputs=(), min_range=MIN_RANGE, tag=None):
            launch(kernel, dim, inputs, outputs, device=device, min_range=min_range)
        return run
    replays = Replays()

    def replay(kernel, dim, inputs, outputs=(), min_range=MIN_RANGE, tag=None):
        if dim > 0:
            replays.get(kernel, dim, inputs, outputs, device=device, min_range=min_range, tag=tag).launch()
    return replay


_gate = threading.local()


def _own_gate():
    """This thread's gate for ``_Barrier``: a plain lock held while the thread does not wait (the cheapest
    sleep and wake CPython has: no condition variable, no Python-level semaphore)."""
    gate = getattr(_gate, "lock", None)
    if gate is None:
        gate = _gate.lock = threading.Lock()
        gate.acquire()
    return gate


class _Barrier:
    """A reusable barrier for ``parties`` threads: a counter under a lock; each thread that is not the last
    to arrive sleeps on its own gate (``_own_gate``) and the last one opens them. A thread opened in this
    round takes its gate again only in a later round, so it cannot take a release meant for another.
    About half the cost of a barrier over semaphores (``threading.Semaphore`` is a condition variable
    in Python) on a loaded machine."""

    def __init__(self, parties: int):
        self.parties = parties
        self._lock = threading.Lock()
        self._waiting: list = []

    def wait(self) -> None:
        gate = _own_gate()
        with self._lock:
            waiting = self._waiting
            last = len(waiting) + 1 == self.parties
            if last:
                self._waiting = []
            else:
                waiting.append(gate)
        if last:
            for g in waiting:
                g.release()
        else:
            gate.acquire()


class _LoopWorkers:
    """Persistent daemon threads 1..count of ``run_loop`` and ``_run_split`` (thread 0 is the caller); a job
    may take the first ``parties - 1`` of them, meeting at that many parties' barrier."""

    def __init__(self, count: int):
        self.count = count
        self._barriers: dict[int, _Barrier] = {}
        self.job = None
        self._start = [threading.Lock() for _ in range(count)]  # held: released to start thread k + 1
        for s in self._start:
            s.acquire()
        for k in range(count):
            threading.Thread(target=self._work, args=(k,), daemon=True, name=f"warp_sph_loop_{k + 1}").start()

    def _work(self, k: int) -> None:
        while True:
            self._start[k].acquire()
            self.job(k + 1)

    def barrier_of(self, parties: int) -> _Barrier:
        """The barrier of ``parties`` threads (the caller's thread 0 included), made on first use."""
        barrier = self._barriers.get(parties)
        if barrier is None:
            barrier = self._barriers[parties] = _Barrier(parties)
        return barrier

    def start(self, job, parties: int | None = None) -> None:
        """Run ``job(k)`` on threads k = 1..parties - 1 (default: all of them); the job meets at
        ``barrier_of(parties)``."""
        self.job = job
        for s in self._start[: (self.count + 1 if parties is None else parties) - 1]:
            s.release()


_loop_workers: _LoopWorkers | None = None
_loop_lock = threading.Lock()


def _workers(count: int) -> _LoopWorkers:
    """Persistent threads, at least ``count`` of them (made on first use, anew only for a larger count, so
    their number stays bounded by the largest split); hold ``_loop_lock``."""
    global _loop_workers
    if _loop_workers is None or _loop_workers.count < count:
        _loop_workers = _LoopWorkers(count)
    return _loop_workers


def _ranges(item) -> list:
    """The callables of a ``run_loop`` item: one per recorded range, or the item itself (thread 0)."""
    return item.runs() if isinstance(item, Recorded) else [item]


def _run_serial(groups) -> None:
    """Every range of every group of ``groups`` (``_ranges`` lists) in turn, on this thread."""
    for g in groups:
        for r in g:
            for run in r:
                run()


def run_loop(groups, sweeps: int, stop=None, before=(), after=()) -> int:
    """Run up to ``sweeps`` sweeps of ``groups`` (a list of lists of :class:`Recorded` launches, or of
    callables that run on thread 0, e.g. ``wp.utils.array_scan`` between two passes) with one
    hand-off for the whole loop: on the CPU each range k of a recorded launch runs on thread k
    (thread 0: the caller; the others: persistent threads) and all threads meet at a barrier after
    each group, so a group sees everything the groups before it wrote. A launch recorded in fewer
    ranges (a serial kernel: a reduction, a one-thread control kernel) runs its ranges on the first
    threads while the rest wait at the barrier. After each sweep thread 0 calls ``stop(sweep)``
    (sweep: 1-based; a host read such as a solve's stop test) and all threads end the loop when it
    returns True. ``before`` and ``after``: groups run once before the first sweep and once after the
    last (e.g. a solve's reset and its final update), in the same hand-off. The same launches in the
    same order as launching each range of each group in turn, sweep after sweep: results are bitwise
    those of ``launch``. Returns the sweeps run."""
    pre, ranges, post = ([[_ranges(r) for r in g] for g in gs] for gs in (before, groups, after))
    threads = max((len(r) for gs in (pre, ranges, post) for g in gs for r in g), default=1)
    # groups before the first (after the last) that only thread 0 runs: run on this thread before the other
    # threads start (after they stopped), with no barrier
    lead = next((i for i, g in enumerate(pre) if any(len(r) > 1 for r in g)), len(pre))
    trail = next((i for i in range(len(post), 0, -1) if any(len(r) > 1 for r in post[i - 1])), 0)
    if threads <= 1:
        lead, trail = len(pre), 0
    _run_serial(pre[:lead])
    pre = pre[lead:]
    post, solo_post = post[:trail], post[trail:]
    if threads <= 1:
        done = max(sweeps, 0)
        for s in range(1, sweeps + 1):
            _run_serial(ranges)
            if s < sweeps and stop is not None and stop(s):
                done = s
                break
        _run_serial(solo_post)
        return done
    with _loop_lock:  # one loop at a time on the shared workers
        workers = _workers(threads - 1)
        barrier = workers.barrier_of(threads)
        state = {"done": 0, "error": None}
        plans = [[[[r[k] for r in g if k < len(r)] for g in gs] for k in range(threads)] for gs in (pre, ranges, post)]
        # the last group of a sweep needs no barrier of its own when the stop test reads nothing the other
        # threads wrote in it (no stop test, or a group only thread 0 runs): the sweep's end barrier follows
        solo_last = stop is None or (bool(ranges) and all(len(r) <= 1 for r in ranges[-1]))

        def run_groups(mine, skip_last: bool = False) -> None:
            for g, cmds in enumerate(mine):
                if state["error"] is None:
                    try:
                        for run in cmds:
                            run()
                    except BaseException as e:  # keep meeting the barriers; thread 0 raises it
                        state["error"] = e
                if not (skip_last and g == len(mine) - 1):
                    barrier.wait()

        def job(k: int) -> None:
            run_groups(plans[0][k])
            s = 0
            while s < sweeps:
                s += 1
                run_groups(plans[1][k], solo_last)
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
                    break
            run_groups(plans[2][k])

        workers.start(job, threads)
        job(0)  # returns after the last barrier: every worker has run its last launch
        if state["error"] is not None:
            raise state["error"]
    _run_serial(solo_post)
    return state["done"]
