"""Bytes a step moves, modelled: the array bytes its kernel launches are given (``warp-sph bench scaling``).

No hardware counter is readable on the VM this project runs on (``perf stat -e cache-misses true``: "not
supported", no PMU is exposed), so the memory traffic of a step is a model, counted while a few extra steps
run after the timed ones: every kernel launch (``wp.launch`` and replays of recorded launches,
``Launch.launch``) streams each distinct Warp array among its arguments once (arrays inside Warp struct
arguments, such as neighbour lists and pair caches, included), a row array at its rows' used entries as
run.json ``read_bytes`` counts them (``working_set.used_bytes``), any other at its allocation. It counts neither
the repeated gathers of neighbours' values a neighbour loop makes (the model takes them as cache hits) nor what
Warp's native helpers move (hash-grid builds, scans, sorts), nor a write separately from a read; so it is an
estimate of the step's streaming, not a measurement. Divided by ``read_bytes`` (one pass over the
step's arrays at their used entries, run.json) it reads as passes over the arrays per step.

The counted steps run with ``WARP_SPH_CPU_THREADS=1``, so that each launch is one range (a split launch gives
every range the whole arrays); results do not depend on the thread count, so these steps are the ones the run
would take.
"""
from __future__ import annotations

import os
from contextlib import contextmanager

import warp as wp

#: steps counted after the timed ones (``RunSpec.traffic_steps`` of ``bench scaling``)
TRAFFIC_STEPS = 2


def arrays_in(value, out: dict | None = None) -> dict:
    """{id: array} of the Warp arrays in a launch argument: the array itself, or the arrays among a Warp struct's
    fields (recursively)."""
    out = {} if out is None else out
    if isinstance(value, wp.array):
        out[id(value)] = value
    elif hasattr(getattr(value, "_cls", None), "vars"):  # a Warp struct instance
        for name in value._cls.vars:
            arrays_in(getattr(value, name, None), out)
    return out


def allocation_bytes(a: wp.array) -> int:
    """[bytes] of a Warp array's allocation: size x dtype size."""
    return int(a.size * wp.types.type_size_in_bytes(a.dtype))


def launch_bytes(args, sizes: dict | None = None) -> int:
    """[bytes] of the distinct Warp arrays among ``args``, each at ``sizes[id(array)]`` where given (the used entries
    of a row array: ``working_set.used_bytes``), else at its allocation."""
    found: dict = {}
    for a in args:
        arrays_in(a, found)
    sizes = sizes or {}
    return int(sum(sizes.get(k, allocation_bytes(a)) for k, a in found.items()))


class LaunchBytes:
    """The launches run while counting: ``launches``, and how many of them were given each array (``uses``)."""

    def __init__(self):
        self.launches = 0
        self.uses: dict[int, int] = {}
        self.arrays: dict[int, wp.array] = {}  # kept alive, so that no id is reused while counting

    def add(self, args) -> None:
        self.launches += 1
        found: dict = {}
        for a in args:
            arrays_in(a, found)
        for k, a in found.items():
            self.uses[k] = self.uses.get(k, 0) + 1
            self.arrays[k] = a

    def bytes(self, sizes: dict | None = None) -> int:
        """[bytes] of every launch's distinct arrays: each array's uses x ``sizes[id]`` (else its allocation)."""
        sizes = sizes or {}
        return int(sum(n * sizes.get(k, allocation_bytes(self.arrays[k])) for k, n in self.uses.items()))


@contextmanager
def counting_launches(threads: int | None = 1):
    """Count every kernel launch run inside the block (``LaunchBytes``): ``wp.launch`` calls (not those that only
    record a launch) and replays of recorded launches, which run through Warp's ``Launch.launch`` inside the block
    (``core.launch.PREPARED_REPLAY`` off: the prepared replays call the kernel without it). ``threads``:
    ``WARP_SPH_CPU_THREADS`` inside the block (None: unchanged), restored after it."""
    from warp._src.context import Launch

    from warp_sph.core import launch as core_launch

    counter = LaunchBytes()
    plain, replay = wp.launch, Launch.launch

    def counted_launch(kernel, dim, inputs=(), outputs=(), *args, **kwargs):
        if not kwargs.get("record_cmd"):
            counter.add([*(inputs or ()), *(outputs or ())])
        return plain(kernel, dim, inputs, outputs, *args, **kwargs)

    def counted_replay(self, *args, **kwargs):
        counter.add(self.fwd_args or ())
        return replay(self, *args, **kwargs)

    old_threads = os.environ.get("WARP_SPH_CPU_THREADS")
    wp.launch, Launch.launch = counted_launch, counted_replay
    prepared, core_launch.PREPARED_REPLAY = core_launch.PREPARED_REPLAY, False
    if threads is not None:
        os.environ["WARP_SPH_CPU_THREADS"] = str(int(threads))
    try:
        yield counter
    finally:
        wp.launch, Launch.launch = plain, replay
        core_launch.PREPARED_REPLAY = prepared
        if threads is not None:
            if old_threads is None:
                os.environ.pop("WARP_SPH_CPU_THREADS", None)
            else:
                os.environ["WARP_SPH_CPU_THREADS"] = old_threads


def step_traffic(sim, dt: float, steps: int = TRAFFIC_STEPS) -> dict:
    """Run ``steps`` more steps of ``sim`` at ``dt`` [s] counting their launches; metrics, modelled (module
    docstring): ``launches_per_step``, ``launch_bytes_per_step`` [bytes] (row arrays at the used entries of the
    lists after the counted steps, ``working_set.used_bytes``), ``launch_bytes_per_particle_step`` [bytes per fluid
    particle-step] and ``launch_allocation_bytes_per_particle_step`` (every array at its allocation)."""
    from warp_sph.run.working_set import used_bytes

    with sim.in_cell_order(), counting_launches() as c:
        for _ in range(steps):
            sim.step(dt)
        wp.synchronize_device(sim.device)
    used = c.bytes(used_bytes(sim)) / steps
    n = max(1, sim.model.fluid_count)
    return {"traffic_steps": steps, "launches_per_step": c.launches / steps, "launch_bytes_per_step": used,
            "launch_bytes_per_particle_step": used / n,
            "launch_allocation_bytes_per_particle_step": c.bytes() / (steps * n)}
