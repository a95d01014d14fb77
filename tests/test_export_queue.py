"""The export thread's snapshot queue: the simulation never waits while the queued snapshots fit in
the byte budget, waits for a slot beyond it, and the frames are written in order."""
import threading
import time

import numpy as np
import warp as wp

from warp_sph.run.exporter import ExportThread, snapshot_bytes


class SlowExporter:
    """Writes nothing until ``release`` is set; records the order of the frames and whether each was
    written on every core (``Exporter.use_all_cores``)."""

    def __init__(self):
        self.release = threading.Event()
        self.frames = []
        self.all_cores = True
        self.frame_all_cores = []

    def use_all_cores(self, enabled):
        self.all_cores = enabled

    def write(self, frame, t, snap):
        self.release.wait(timeout=30)
        self.frames.append(frame)
        self.frame_all_cores.append(self.all_cores)


def snap(n=1000):
    return {"x": wp.zeros(n, dtype=wp.vec3, device="cpu"), "checkpoint": {"step": 1}}


def test_frames_queue_within_the_budget_and_the_simulation_never_waits():
    ex = SlowExporter()
    worker = ExportThread(ex, depth=2, max_bytes=64 * snapshot_bytes(snap()))
    t0 = time.perf_counter()
    for f in range(1, 41):  # 40 frames behind a writer that has not written one
        worker.submit(f, 0.1 * f, snap())
    assert time.perf_counter() - t0 < 5.0 and worker.queued == 40 and worker.blocked_seconds == 0.0
    ex.release.set()
    worker.finish()
    assert ex.frames == list(range(1, 41)) and worker.queued == 0 and worker.queued_bytes == 0


def test_the_export_uses_every_core_only_after_the_last_step():
    """Beside the simulation the surface runs on one core; the frames still queued when the
    simulation has finished (``finish``) are written on every core."""
    ex = SlowExporter()
    worker = ExportThread(ex, depth=2, max_bytes=64 * snapshot_bytes(snap()))
    worker.submit(1, 0.0, snap())
    ex.release.set()
    while not ex.frames:
        time.sleep(0.01)
    ex.release.clear()
    for f in range(2, 5):
        worker.submit(f, 0.0, snap())
    threading.Timer(0.2, ex.release.set).start()
    worker.finish()
    assert ex.frames == [1, 2, 3, 4] and ex.frame_all_cores[0] is False and ex.frame_all_cores[-1] is True


def test_submit_waits_for_a_slot_beyond_the_budget():
    ex = SlowExporter()
    assert snapshot_bytes(snap()) == 1000 * 12
    worker = ExportThread(ex, depth=2, max_bytes=2 * snapshot_bytes(snap()))
    worker.submit(1, 0.0, snap())
    worker.submit(2, 0.0, snap())
    done = threading.Event()
    threading.Thread(target=lambda: (worker.submit(3, 0.0, snap()), done.set()), daemon=True).start()
    assert not done.wait(0.5)  # the third frame would exceed the budget: it waits
    ex.release.set()
    assert done.wait(10.0)
    worker.finish()
    assert ex.frames == [1, 2, 3] and worker.blocked_seconds >= 0.5


def test_an_export_error_reaches_the_simulation_thread():
    class Failing(SlowExporter):
        def write(self, frame, t, snap):
            raise OSError("disk full")

    worker = ExportThread(Failing(), depth=1, max_bytes=1)
    worker.submit(1, 0.0, snap())
    try:
        for f in range(2, 50):  # a waiting submit wakes up and raises instead of hanging
            worker.submit(f, 0.0, snap())
            time.sleep(0.01)
        worker.finish()
    except OSError as e:
        assert "disk full" in str(e)
    else:
        raise AssertionError("the export error was not raised")


def test_whitewater_copies_count_toward_the_budget():
    """A snapshot's whitewater is host copies (up to whitewater.max_particles of them); the budget counted the
    device arrays only, so frames with a large whitewater queued without bound."""
    n = 500
    ww = {"spray": (np.zeros((n, 3)), np.zeros((n, 3), np.float32), np.zeros(n, np.float32))}
    assert snapshot_bytes({**snap(), "whitewater": ww}) == 1000 * 12 + n * (24 + 12 + 4)
