"""The run's progress bar on stderr: frames done, elapsed time, ETA and a status line."""
from __future__ import annotations

import math
import sys
import time


class Progress:
    """A one-line progress bar with ETA on stderr (plain lines every few seconds when not a TTY)."""

    def __init__(self, total: int, enabled: bool = True, stream=None, unit: str = "frames"):
        self.total = max(total, 1)
        self.unit = unit
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.perf_counter()
        self.last = 0.0
        self.done0 = None

    def update(self, done: int, info: str = "") -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.done0 is None:
            self.done0 = done
            self.t0 = now
        if not self.tty and now - self.last < 5.0 and done < self.total:
            return
        self.last = now
        elapsed = now - self.t0
        rate = (done - self.done0) / elapsed if elapsed > 0 and done > self.done0 else 0.0
        eta = (self.total - done) / rate if rate > 0 else float("nan")
        width = 28
        filled = int(width * done / self.total)
        bar = "#" * filled + "-" * (width - filled)
        eta_s = f"{eta:6.0f}s" if math.isfinite(eta) else "     ?s"
        line = f"[{bar}] {done}/{self.total} {self.unit}  {elapsed:6.1f}s elapsed  ETA {eta_s}  {info}"
        if self.tty:
            self.stream.write("\r" + line[:160].ljust(160))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()
