"""The step graph: an ordered list of stages that declare the fields they read and write.

A stage *writes* a field it produces from scratch (one writer per field), *updates* a field that
already exists (read-modify-write, e.g. the integrator on positions), and *reads* fields that must
exist before it runs: state fields (positions, velocities) or fields an earlier stage wrote.
The graph checks this when it is built or changed, and times each stage; work a frame does outside the
substeps (emitters and sinks) is timed with the same timers under its own names (``timed``).
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable

import warp as wp

from .errors import StepGraphError


@dataclass
class Stage:
    """One step of the pipeline. ``run(sim, dt)`` launches its kernels; dt in seconds."""

    name: str
    run: Callable[..., None]
    reads: tuple[str, ...] = ()
    writes: tuple[str, ...] = ()
    updates: tuple[str, ...] = ()
    doc: str = ""


@dataclass
class StageTiming:
    calls: int = 0
    seconds: float = 0.0              # all calls [s]
    first_call_seconds: float = 0.0   # the first call alone [s]: it loads (or compiles) the kernels
    cpu_seconds: float = 0.0          # process CPU time of all calls [s] (``StepGraph.timed`` only)
    first_call_cpu_seconds: float = 0.0


class StepGraph:
    """Ordered stages with checked data flow and per-stage wall-clock timing.

    ``inputs`` are the fields available before the first stage (the state and the model).
    """

    def __init__(self, stages: list[Stage], inputs: set[str], device=None, synchronize_timing: bool = False):
        self.inputs = set(inputs)
        self.stages: list[Stage] = []
        self.device = device
        self.synchronize_timing = synchronize_timing
        self.timings: dict[str, StageTiming] = {}
        #: per-frame work outside the stages, by name (``timed``)
        self.frame_timings: dict[str, StageTiming] = {}
        for s in stages:
            self.stages.append(s)
        self.validate()

    # --- structure -------------------------------------------------------------------------
    def names(self) -> list[str]:
        """The stage names in the order they run."""
        return [s.name for s in self.stages]

    def index(self, name: str) -> int:
        """The position of the stage ``name``; StepGraphError listing the stages when there is none."""
        for k, s in enumerate(self.stages):
            if s.name == name:
                return k
        raise StepGraphError(f"no stage named {name!r}; stages are: {', '.join(self.names())}")

    def insert(self, stage: Stage, *, before: str | None = None, after: str | None = None) -> None:
        """Insert a stage before or after a named stage (or at the end) and re-validate."""
        if (before is None) == (after is None) and not (before is None and after is None):
            raise StepGraphError("give exactly one of before= or after=")
        if before is not None:
            k = self.index(before)
        elif after is not None:
            k = self.index(after) + 1
        else:
            k = len(self.stages)
        self._edit(lambda stages: stages.insert(k, stage))

    def remove(self, name: str) -> Stage:
        """Remove the stage ``name`` and return it; the graph is re-validated (StepGraphError, and
        the graph unchanged, when a later stage reads a field only that stage wrote)."""
        return self._edit(lambda stages: stages.pop(self.index(name)))

    def _edit(self, change):
        """``change(self.stages)`` (in place), then re-validate; on a StepGraphError the stages as they were
        before, and the error raised. Returns what ``change`` returned."""
        old = list(self.stages)
        result = change(self.stages)
        try:
            self.validate()
        except StepGraphError:
            self.stages = old
            raise
        return result

    def validate(self) -> None:
        """Every read/update is produced before; no field has two writers; names unique."""
        available = set(self.inputs)
        writers: dict[str, str] = {}
        seen = set()
        for s in self.stages:
            if s.name in seen:
                raise StepGraphError(f"two stages are named {s.name!r}")
            seen.add(s.name)
            if not callable(s.run):
                raise StepGraphError(f"stage {s.name!r}: run must be callable")
            for f in tuple(s.reads) + tuple(s.updates):
                if f not in available:
                    raise StepGraphError(
                        f"stage {s.name!r} reads {f!r} before any stage writes it "
                        f"(available here: {', '.join(sorted(available))})"
                    )
            for f in s.writes:
                if f in writers:
                    raise StepGraphError(f"field {f!r} is written by both {writers[f]!r} and {s.name!r}")
                if f in self.inputs:
                    raise StepGraphError(f"stage {s.name!r} writes the input field {f!r}; declare it in updates")
                writers[f] = s.name
                available.add(f)

    # --- execution -------------------------------------------------------------------------
    def run(self, sim, dt: float) -> None:
        """Run every stage once, in order, for one substep of ``dt`` seconds, timing each."""
        for s in self.stages:
            t0 = time.perf_counter()
            s.run(sim, dt)
            if self.synchronize_timing:
                wp.synchronize_device(self.device)
            t = self.timings.get(s.name)
            if t is None:
                t = self.timings[s.name] = StageTiming()
            elapsed = time.perf_counter() - t0
            if t.calls == 0:
                t.first_call_seconds = elapsed
            t.calls += 1
            t.seconds += elapsed

    @contextmanager
    def timed(self, name: str):
        """Context: time the block as the per-frame stage ``name`` (wall and process CPU time; the device
        synchronised at its end when stages are), e.g. a frame's sinks and emitters before its substeps.
        Rows in ``frame_timing_table``, not in ``timing_table`` (the substep's stages)."""
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            if self.synchronize_timing:
                wp.synchronize_device(self.device)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            t = self.frame_timings.get(name)
            if t is None:
                t = self.frame_timings[name] = StageTiming(first_call_seconds=wall, first_call_cpu_seconds=cpu)
            t.calls += 1
            t.seconds += wall
            t.cpu_seconds += cpu

    def frame_timing_table(self) -> list[dict]:
        """[{stage, calls, seconds, first_call_seconds, cpu_seconds, first_call_cpu_seconds, ms_per_call,
        cpu_ms_per_call}] of the ``timed`` blocks in the order they first ran (per-call means without the
        first call, as ``timing_table``)."""
        out = []
        for name, t in self.frame_timings.items():
            row = {"stage": name, "calls": t.calls, "seconds": t.seconds, "first_call_seconds": t.first_call_seconds,
                   "cpu_seconds": t.cpu_seconds, "first_call_cpu_seconds": t.first_call_cpu_seconds}
            for key, total, first in (("ms_per_call", t.seconds, t.first_call_seconds),
                                      ("cpu_ms_per_call", t.cpu_seconds, t.first_call_cpu_seconds)):
                row[key] = 1e3 * ((total - first) / (t.calls - 1) if t.calls > 1 else total)
            out.append(row)
        return out

    def timing_table(self) -> list[dict]:
        """[{stage, calls, seconds, first_call_seconds, ms_per_call}] in graph order.

        seconds: all calls [s]; first_call_seconds: the first call [s], which loads or compiles the
        stage's Warp modules (seconds on a cold kernel cache); ms_per_call: the mean of the other
        calls [ms] (the first one alone while there is no other), so a compile is never averaged in.
        """
        out = []
        for s in self.stages:
            t = self.timings.get(s.name, StageTiming())
            if t.calls > 1:
                per_call = 1e3 * (t.seconds - t.first_call_seconds) / (t.calls - 1)
            else:
                per_call = 1e3 * t.seconds if t.calls else 0.0
            out.append({
                "stage": s.name,
                "calls": t.calls,
                "seconds": t.seconds,
                "first_call_seconds": t.first_call_seconds,
                "ms_per_call": per_call,
            })
        return out
