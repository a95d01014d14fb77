"""Where the cases of a sweep run: in this process one after the other, or on Dask.

    SerialExecutor()                      in-process, one case at a time (no extra needed)
    DaskExecutor(workers=N)               a distributed.LocalCluster on this machine: N processes
                                          (default: the cores), one thread each
    DaskExecutor(scheduler="tcp://HOST:8786")   an existing Dask cluster (``dask scheduler`` +
                                          ``dask worker``); its workers need warp-sph installed and
                                          the output folder on a shared file system

Every executor answers ``map(fn, tasks)`` with an ``Outcome`` per task as each finishes (in the
order they finish). ``fn`` is a module-level function (pickled by reference to Dask workers) that
returns a JSON-able dict; an exception it raises becomes the outcome's one-line ``error`` and does
not stop the other tasks. A task whose worker dies (killed, out of memory) is submitted once more;
a second death is recorded as its error. Ctrl-C (KeyboardInterrupt) cancels every task not yet
finished and closes the cluster before it propagates.

Warp's CPU threads: each Dask worker runs its cases with ``WARP_SPH_CPU_THREADS`` set (1 on a
LocalCluster of one process per core, set before the worker imports warp_sph), so N workers do not
oversubscribe the cores; a worker of an external cluster keeps its own setting if it has one,
else 1. Results do not depend on the thread count (``warp_sph.core.launch``).
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator

from ..core.errors import WarpSphError

INSTALL_HINT = "pip install -e '.[distributed]' in the warp-sph checkout (into the environment warp-sph runs in, e.g. .venv/bin/pip)"


class MissingExtraError(WarpSphError):
    """An option needs an optional extra that is not installed."""


@dataclass
class Outcome:
    """One finished task. result: fn's return value (None on error); error: one line;
    attempts: 1, or 2 when its worker died and it was submitted again; submitted/received:
    wall-clock times [s since the epoch] on the client."""

    key: str
    result: dict | None
    error: str | None = None
    attempts: int = 1
    submitted: float = 0.0
    received: float = 0.0


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0] if text else ''}".rstrip(": ")


def machine_cores() -> int:
    """Cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


class Pinned:
    """``fn(arg)`` with ``WARP_SPH_CPU_THREADS`` set in the process that runs it, unless that
    process's environment sets it already (picklable: sent to Dask workers)."""

    def __init__(self, fn: Callable, threads: int):
        self.fn = fn
        self.threads = int(threads)

    def __call__(self, arg):
        os.environ.setdefault("WARP_SPH_CPU_THREADS", str(self.threads))
        return self.fn(arg)


class SerialExecutor:
    """Runs the tasks in this process, one after the other."""

    name = "serial"

    def __init__(self, log: Callable = print):
        self.log = log
        self.workers = 1

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self) -> None:
        pass

    def describe(self) -> str:
        return "in-process, one case at a time"

    def map(self, fn: Callable, tasks: Iterable[tuple[str, object]]) -> Iterator[Outcome]:
        for key, arg in tasks:
            t0 = time.time()
            try:
                result, error = fn(arg), None
            except Exception as e:  # noqa: BLE001 - a failed task is an outcome, not the end of the sweep
                result, error = None, _one_line(e)
            yield Outcome(key, result, error, 1, t0, time.time())


def _import_distributed():
    try:
        import dask  # noqa: F401 - both halves of the extra
        import distributed
    except ImportError:
        raise MissingExtraError(f"--workers and --scheduler need Dask's distributed scheduler: {INSTALL_HINT}") from None
    return distributed


def _check_scheduler_address(address: str) -> None:
    """A ``--scheduler`` address Dask can parse (``tcp://HOST:PORT``, ``HOST:PORT``, ``tls://...``),
    checked before anything starts: WarpSphError (one line) otherwise."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(address)
        if scheme in ("tcp", "tls"):
            parse_host_port(location)
    except (ValueError, TypeError) as e:
        raise WarpSphError(f"--scheduler {address!r}: not a Dask scheduler address ({_one_line(e)}); expected "
                           "tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786") from None


class DaskExecutor:
    """Runs the tasks on a Dask cluster: a LocalCluster of ``workers`` processes (one thread
    each; None or 0: one per core) or the existing cluster at ``scheduler``."""

    name = "dask"

    def __init__(self, workers: int | None = None, scheduler: str | None = None, log: Callable = print,
                 quiet: bool = True):
        self.distributed = _import_distributed()
        if scheduler is not None:
            _check_scheduler_address(scheduler)
        self.scheduler = scheduler
        self.workers = (workers or machine_cores()) if scheduler is None else None
        self.log = log
        self.quiet = quiet
        self.cluster = None
        self.client = None
        self.threads = 1
        self._started_here: list[bool] = []  # per open ``with``: whether it started the cluster

    # --- life cycle --------------------------------------------------------------------------
    def __enter__(self):
        """Starts the cluster (or connects) unless started already; the ``with`` block that
        started it closes it, so one started executor can serve several sweeps."""
        self._started_here.append(self.client is None)
        if self._started_here[-1]:
            self.start()
        return self

    def __exit__(self, *exc):
        if self._started_here.pop():
            self.close()
        return False

    def start(self) -> None:
        import logging

        d = self.distributed
        level = logging.ERROR if self.quiet else logging.WARNING
        if self.scheduler is None:
            threads = max(1, machine_cores() // self.workers)
            self.threads = threads
            # processes, one thread each, Warp pinned before the worker imports warp_sph; a task
            # whose worker dies is handed back at once (allowed_failures=0) and submitted again
            # here, once; no memory limit (a case's arrays are not Dask data to spill or pause on);
            # a worker gets its next case only when it is free (saturation 1.0), so a long case
            # never waits in one worker's queue while another worker idles
            import dask

            with dask.config.set({"distributed.scheduler.worker-saturation": 1.0}):
                self.cluster = d.LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                              dashboard_address=":0", silence_logs=level, memory_limit=0,
                                              env={"WARP_SPH_CPU_THREADS": str(threads)},
                                              preload=["warp_sph.sweep.local_worker"],
                                              scheduler_kwargs={"allowed_failures": 0})
            self.client = d.Client(self.cluster)
        else:
            self.threads = 1
            try:
                self.client = d.Client(self.scheduler, timeout="30s")
            except (OSError, TimeoutError) as e:
                raise WarpSphError(f"--scheduler {self.scheduler}: cannot connect ({_one_line(e)}); "
                                   f"start it with 'dask scheduler' and workers with 'dask worker {self.scheduler}'") from None
            for name in ("distributed", "distributed.client"):
                logging.getLogger(name).setLevel(level)
            n = len(self.client.scheduler_info().get("workers", {}))
            self.workers = n
            if n == 0:
                self.log(f"{self.scheduler}: no workers yet; tasks wait until one joins")

    def close(self) -> None:
        for obj in (self.client, self.cluster):
            if obj is not None:
                try:
                    obj.close()
                except Exception:  # noqa: BLE001 - closing after Ctrl-C or a lost scheduler
                    pass
        self.client = self.cluster = None

    def describe(self) -> str:
        if self.scheduler is None:
            return f"Dask LocalCluster: {self.workers} worker processes, {self.threads} Warp CPU thread(s) each"
        return f"Dask cluster at {self.scheduler}: {self.workers} worker(s) now"

    # --- tasks -------------------------------------------------------------------------------
    def map(self, fn: Callable, tasks: Iterable[tuple[str, object]]) -> Iterator[Outcome]:
        d = self.distributed
        task = Pinned(fn, self.threads)
        futures = {}
        info: dict[str, dict] = {}

        tasks = list(tasks)

        def submit(key: str, arg, attempt: int, priority: int):
            # Dask runs the highest priority first: the tasks in the order given, a retry before the rest
            f = self.client.submit(task, arg, key=f"{key}#{attempt}", pure=False, priority=priority)
            futures[f] = key
            info[key] = {"arg": arg, "attempt": attempt, "submitted": info.get(key, {}).get("submitted", time.time())}
            return f

        pending = d.as_completed([submit(k, a, 1, len(tasks) - n) for n, (k, a) in enumerate(tasks)])
        try:
            for f in pending:
                key = futures.pop(f)
                i = info[key]
                if f.status == "finished":
                    result, error = f.result(), None
                elif f.status == "cancelled":
                    result, error = None, "cancelled"
                else:
                    exc = f.exception()
                    if isinstance(exc, d.KilledWorker) and i["attempt"] == 1:
                        self.log(f"{key}: its worker died; running it once more")
                        pending.add(submit(key, i["arg"], 2, len(tasks) + 1))
                        f.release()
                        continue
                    result = None
                    error = ("its worker died twice (killed, or out of memory)" if isinstance(exc, d.KilledWorker)
                             else _one_line(exc))
                f.release()
                yield Outcome(key, result, error, i["attempt"], i["submitted"], time.time())
        except BaseException as e:
            # Ctrl-C, or the consumer stopped: cancel what is left before the cluster closes
            try:
                self.client.cancel(list(futures), force=True)
            except Exception:  # noqa: BLE001
                pass
            if isinstance(e, KeyboardInterrupt):
                _quiet_dask_logs()
                self._stop_local_workers()
            raise

    def _stop_local_workers(self) -> None:
        """Kill the LocalCluster's worker processes (a running case stops at once instead of the
        cluster's close waiting for it; its run folder stays consistent: every file of a run is
        written atomically, and a re-run continues it from its latest checkpoint). Dask cannot stop
        a task running on an external cluster's worker: that case finishes there, unrecorded."""
        import signal

        for nanny in (self.cluster.workers.values() if self.cluster is not None else ()):
            proc = getattr(getattr(nanny, "process", None), "process", None)
            try:
                nanny.auto_restart = False
                if proc is not None and proc.pid:
                    os.kill(proc.pid, signal.SIGKILL)
            except (OSError, AttributeError):
                pass


def _quiet_dask_logs() -> None:
    """After a Ctrl-C: the scheduler and nannies of this process log the comms the killed workers
    leave behind (``distributed.batched - INFO - Batched Comm Closed`` with a traceback) while the
    cluster closes; the user asked to stop, so those go unsaid (loggers of ``distributed`` and
    ``tornado`` raised to CRITICAL, children with a level of their own included)."""
    import logging

    for name in list(logging.root.manager.loggerDict):
        if name.split(".")[0] in ("distributed", "tornado"):
            logging.getLogger(name).setLevel(logging.CRITICAL)
    for name in ("distributed", "tornado"):
        logging.getLogger(name).setLevel(logging.CRITICAL)


def make_executor(workers: int | None = None, scheduler: str | None = None, log: Callable = print):
    """SerialExecutor when neither is given; else a DaskExecutor (MissingExtraError without Dask).
    workers: None for serial, 0 for one worker per core."""
    if workers is not None and scheduler is not None:
        raise WarpSphError("--workers starts a cluster on this machine and --scheduler uses an existing one: "
                           "give one of them")
    if workers is not None and workers < 0:
        raise WarpSphError(f"--workers {workers}: expected a number of worker processes >= 1")
    if scheduler is not None:
        return DaskExecutor(scheduler=scheduler, log=log)
    if workers is not None:
        return DaskExecutor(workers=workers or None, log=log)
    return SerialExecutor(log=log)
