"""warp-sph: smoothed-particle hydrodynamics as NVIDIA Warp kernels, exported to USD for Blender."""
from .errors import OutputError, SceneError, SimulationError, StepGraphError, WarpSphError
from .smoothing import SMOOTHING_KERNELS, SmoothingKernel, calibrated_mass, get_smoothing_kernel

__version__ = "0.1.0"
