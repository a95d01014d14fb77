"""Peak resident memory of one benchmark case, read inside the process that runs it (Linux /proc).

``MemoryWindow.open()`` takes the process's resident set size (VmRSS) right before a case builds its
simulation (the *baseline*: interpreter, libraries and the engine's loaded code) and resets the
high-water mark VmHWM to it (``/proc/self/clear_refs`` "5"); ``close(fluid_particles)`` reads VmHWM:
the most the process held while the case ran. Its increment over the baseline is the case's own
memory; divided by the fluid particle count it is the *peak RSS per fluid particle* that
``warp-sph bench splishsplash`` puts beside SPlisHSPlasH's (each engine's case in its own process).

Standard library only: SPlisHSPlasH's driver (``splishsplash_driver.py``, run as a script, no Warp)
imports it by its plain name (``warp_sph/sweep/runs.py`` makes the same two reads for a sweep's rows, but
importing it loads Warp).
"""
from __future__ import annotations

import os
import resource

#: where Linux reports this process's memory (VmRSS: resident now; VmHWM: its high-water mark)
STATUS = "/proc/self/status"


def status_bytes(field: str, path: str = STATUS) -> int | None:
    """A ``/proc/<pid>/status`` field given in kB (``VmRSS``, ``VmHWM``) [bytes]; None where unreadable."""
    try:
        with open(path) as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def reset_peak() -> bool:
    """Reset this process's VmHWM to its current RSS (``/proc/self/clear_refs`` "5", Linux >= 4.0); False
    where unsupported (the peak then is the process's lifetime peak)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def peak_bytes() -> int:
    """This process's resident high-water mark [bytes]: VmHWM, else getrusage's ru_maxrss (KiB on Linux)."""
    hwm = status_bytes("VmHWM")
    return hwm if hwm is not None else int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


class MemoryWindow:
    """The peak RSS of the code run between ``open()`` and ``close()`` against the RSS at ``open()``."""

    def __init__(self):
        self.baseline = 0        # [bytes] VmRSS at open()
        self.process_peak = 0    # [bytes] VmHWM at open(), before the reset: the process's peak so far
        self.scope = "process"   # "case": VmHWM was reset at open(); "process": it could not be

    def open(self) -> "MemoryWindow":
        self.process_peak = peak_bytes()
        self.baseline = status_bytes("VmRSS") or 0
        self.scope = "case" if reset_peak() else "process"
        return self

    def close(self, fluid_particles: int) -> dict:
        """Metrics [bytes]: ``rss_baseline_bytes``, ``rss_case_peak_bytes`` (the most the process held while the
        case ran, baseline included), ``rss_process_peak_bytes`` (the process's lifetime peak),
        ``rss_peak_increment_bytes`` = case peak - baseline, ``rss_peak_per_particle`` = that / fluid particles,
        and ``rss_peak_scope``."""
        peak = peak_bytes()
        inc = max(0, peak - self.baseline)
        return {"rss_baseline_bytes": self.baseline, "rss_case_peak_bytes": peak,
                "rss_process_peak_bytes": max(peak, self.process_peak), "rss_peak_increment_bytes": inc,
                "rss_peak_per_particle": inc / max(1, int(fluid_particles)), "rss_peak_scope": self.scope}


def rss_ratio(ours: dict, theirs: dict) -> float | None:
    """warp-sph's peak RSS per fluid particle over the other engine's (two records' ``metrics``); None when either
    lacks it (records from before these columns) or the other's is 0."""
    a, b = ours.get("rss_peak_per_particle"), theirs.get("rss_peak_per_particle")
    return a / b if a is not None and b else None
