"""warp-sph: smoothed-particle hydrodynamics as NVIDIA Warp kernels, exported to USD for Blender.

Scripting entry points::

    import warp_sph as ws
    sim = ws.Simulation(ws.load_scene("dam_break"))
    sim.advance_frame()

Warp runs quietly (warnings only, no banner or module-load lines); ``WARP_SPH_VERBOSE=1`` or
``warp_sph.set_verbose(True)`` shows everything.
"""
import os as _os
import signal as _signal
import sys as _sys

# The warp-sph command: a Ctrl-C while it starts (importing Warp, about a second) ends it quietly with status
# 130, as one during a run does (warp_sph.cli.main), instead of a traceback; nothing is written yet.
# (Only in the main thread of the command's own process: a sweep's Dask workers inherit its argv and keep their
# handlers.)
_command = bool(_sys.argv) and _os.path.basename(_sys.argv[0]) == "warp-sph" \
    and __import__("multiprocessing").parent_process() is None \
    and __import__("threading").current_thread() is __import__("threading").main_thread()
if _command:
    _previous_sigint = _signal.signal(_signal.SIGINT, lambda *_: (_sys.stderr.write("\nwarp-sph: interrupted\n"),
                                                                 _os._exit(130)))

# A source checkout keeps the device code, scenes and benchmarks beside this folder (kernels/,
# scenes/, benchmarks/; pyproject.toml maps them to warp_sph.kernels, ...). When Python imports
# warp_sph from a checkout (a script or ``python -m pytest`` run there, with warp-sph installed
# elsewhere or not at all), look for those subpackages in the checkout too.
_here = _os.path.dirname(_os.path.abspath(__file__))
_root = _os.path.dirname(_here)
if not _os.path.isdir(_os.path.join(_here, "kernels")) and _os.path.isfile(_os.path.join(_root, "kernels", "__init__.py")) \
        and _os.path.isfile(_os.path.join(_root, "pyproject.toml")):
    __path__.append(_root)  # noqa: F821 (the package's own search path)

from .core.device import apply_log_level as _apply_log_level, set_verbose  # noqa: E402
from .core.errors import OutputError, SceneError, SimulationError, StepGraphError, WarpSphError
from .scene import Scene, list_scenes, load_scene, parameter_table_markdown, scene_from_dict
from .run.simulation import FrameStatistics, Simulation
from .plan import Plan, PlanError, plan  # the function, not the subpackage: ws.plan(scene, budget_s=...)
from .core.smoothing import SMOOTHING_KERNELS, SmoothingKernel, calibrated_mass, get_smoothing_kernel
from .core.step_graph import Stage, StepGraph

from .core.version import __version__  # noqa: E402

_apply_log_level()
if _command:
    _signal.signal(_signal.SIGINT, _previous_sigint)  # KeyboardInterrupt again: main() handles it


def run(scene, out=None, **kwargs):
    """Simulate a scene (a Scene, a built-in name or a .toml path) into a run folder; see runner.run."""
    from .run.runner import run as _run

    if isinstance(scene, str):
        scene = load_scene(scene)
    return _run(scene, out=out, **kwargs)


__all__ = [
    "FrameStatistics", "OutputError", "Scene", "SceneError", "SimulationError", "Simulation",
    "SMOOTHING_KERNELS", "SmoothingKernel", "Stage", "StepGraph", "StepGraphError", "WarpSphError",
    "calibrated_mass", "get_smoothing_kernel", "list_scenes", "load_scene", "parameter_table_markdown",
    "Plan", "PlanError", "plan", "run", "scene_from_dict", "set_verbose",
]
