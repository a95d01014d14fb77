"""A first run on a machine compiles every kernel module from scratch: the C++ compiler must print
nothing (issue 30: clang warned about the edge-hash constants of ``surface_decimation``).

The compiler writes to the process's file descriptors 1 and 2, not to Python's streams, so the
compile runs in a subprocess with an empty Warp kernel cache (``WARP_CACHE_PATH``), initialised the way
warp-sph does it (``warp_sph.core.device.init_warp``). It builds every module-level kernel module of
``kernels/`` (surface, solvers, neighbours, diagnostics) rather than a whole ``warp-sph run``: the
same C++ for the module-level kernels at a fraction of the time (the run also compiles the
factory-made solver kernels and takes about a minute from an empty cache).
"""
import os
import pathlib
import subprocess
import sys

_COMPILE_ALL = """
import importlib, pkgutil
import warp as wp
import warp_sph.kernels as kernels
from warp_sph.core.device import init_warp
init_warp()
for info in pkgutil.iter_modules(kernels.__path__):
    importlib.import_module("warp_sph.kernels." + info.name)
wp.load_module(kernels, device="cpu", recursive=True)
"""


def test_first_compile_prints_no_compiler_output(tmp_path):
    env = dict(os.environ, WARP_CACHE_PATH=str(tmp_path))
    env.pop("WARP_SPH_VERBOSE", None)
    r = subprocess.run([sys.executable, "-c", _COMPILE_ALL], capture_output=True, text=True, env=env,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    # the cache was empty: the modules were compiled here, not loaded (else the test proves nothing)
    built = {p.name for p in pathlib.Path(tmp_path).glob("*/wp_warp_sph.kernels.*")}
    for name in ("surface_decimation", "surface_grid", "surface_marching", "surface_smoothing", "dfsph"):
        assert any(b.startswith(f"wp_warp_sph.kernels.{name}_") for b in built), (name, sorted(built))
    assert r.stdout == "" and r.stderr == "", r.stdout + r.stderr
