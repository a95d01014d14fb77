"""Warp start-up without noise, and device names checked before anything is created.

``import warp_sph`` sets Warp's log level to warnings (no banner, no "Module ... load on device"
lines); real warnings still print. Warp's native library prints "Could not find or load the
NVIDIA CUDA driver" on every start on a machine without a GPU; ``init_warp`` drops that one line
(and only it) while Warp initialises. Ask for everything with ``WARP_SPH_VERBOSE=1`` or
``warp-sph --verbose`` (``set_verbose(True)`` from a script, before the first simulation).
"""
from __future__ import annotations

import os
import sys
import tempfile
import threading

import warp as wp

from .errors import WarpSphError

#: native start-up lines of Warp that only say "no GPU here"; dropped unless verbose
_NO_GPU_LINES = ("Could not find or load the NVIDIA CUDA driver",)

_verbose = os.environ.get("WARP_SPH_VERBOSE", "") not in ("", "0")
_lock = threading.Lock()


def is_verbose() -> bool:
    return _verbose


def set_verbose(verbose: bool) -> None:
    """Show (True) or hide (False) Warp's banner, module-load lines and native start-up notes."""
    global _verbose
    _verbose = bool(verbose)
    apply_log_level()


def apply_log_level() -> None:
    """Warp logs warnings and errors only, unless verbose (info: banner and module loads)."""
    info, warning = getattr(wp, "LOG_INFO", 20), getattr(wp, "LOG_WARNING", 30)
    wp.config.quiet = not _verbose
    if hasattr(wp.config, "log_level"):  # warp >= 1.19 reads this instead of quiet
        wp.config.log_level = info if _verbose else warning


def _warp_initialized() -> bool:
    import importlib

    for module in ("warp._src.context", "warp.context"):  # warp >= 1.10 / older
        try:
            return importlib.import_module(module).runtime is not None
        except (ImportError, AttributeError):
            continue
    return False


def init_warp() -> None:
    """Initialise Warp once; unless verbose, its native "no CUDA driver" line is not printed."""
    with _lock:
        if _warp_initialized():
            return
        apply_log_level()
        if _verbose:
            wp.init()
            return
        init_filtering_stderr()


def init_filtering_stderr() -> None:
    """wp.init() with file descriptor 2 sent to a temporary file; lines other than the known
    no-GPU note are written back to stderr afterwards (nothing else is hidden). ``init_warp`` runs
    this when not verbose and Warp is not initialised yet."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):
        wp.init()
        return
    with tempfile.TemporaryFile() as capture:
        os.dup2(capture.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        capture.seek(0)
        text = capture.read().decode("utf-8", "replace")
    kept = [ln for ln in text.splitlines(keepends=True) if not any(s in ln for s in _NO_GPU_LINES)]
    if kept:
        sys.stderr.write("".join(kept))
        sys.stderr.flush()


def resolve_device(name: str | None = None):
    """The Warp device for ``name`` ("cpu", "cuda", "cuda:0", ...; None: Warp's default).

    Raises WarpSphError (one line, before anything is created) for a name Warp does not know or a
    CUDA device on a machine without one, listing the devices there are.
    """
    init_warp()
    if name is None:
        return wp.get_device()
    if not isinstance(name, str):  # a wp.context.Device already
        return wp.get_device(name)
    available = [d.alias for d in wp.get_devices()]
    text = name.strip()
    if text.startswith("cuda") and wp.get_cuda_device_count() == 0:
        raise WarpSphError(f"--device {name}: no CUDA device on this machine (Warp found no usable CUDA driver); "
                           f"available: {', '.join(available)}")
    if text not in available and text != "cuda":
        raise WarpSphError(f"--device {name}: unknown device; available: {', '.join(available)}"
                           + ("" if wp.get_cuda_device_count() else " (no CUDA device on this machine)"))
    try:
        return wp.get_device(text)
    except (ValueError, RuntimeError) as exc:
        raise WarpSphError(f"--device {name}: {exc}; available: {', '.join(available)}") from None


def cpu_model() -> str:
    """The host CPU's model name (Linux: /proc/cpuinfo; elsewhere ``platform.processor()``), for the
    records that say which machine a timing holds for (benchmarks, plan calibrations)."""
    import platform

    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or ""
