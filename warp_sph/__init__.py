"""warp-sph: smoothed-particle hydrodynamics as NVIDIA Warp kernels, exported to USD for Blender.

Scripting entry points::

    import warp_sph as ws
    sim = ws.Simulation(ws.load_scene("dam_break"))
    sim.advance_frame()
"""
from .core.errors import OutputError, SceneError, SimulationError, StepGraphError, WarpSphError
from .scene import Scene, list_scenes, load_scene, parameter_table_markdown, scene_from_dict
from .run.simulation import FrameStatistics, Simulation
from .core.smoothing import SMOOTHING_KERNELS, SmoothingKernel, calibrated_mass, get_smoothing_kernel
from .core.step_graph import Stage, StepGraph

__version__ = "0.1.0"


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
    "run", "scene_from_dict",
]
