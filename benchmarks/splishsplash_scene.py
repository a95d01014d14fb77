"""The SPlisHSPlasH side of a comparison case as a scene file: warp-sph's Z-up dam break translated
into SPlisHSPlasH's Y-up scene JSON (fluid block, Akinci 2012 box walls as an OBJ, its method codes
and TimeStep parameters). Used by ``splishsplash.py``; imports no Warp.
"""
from __future__ import annotations

import numpy as np

#: SPlisHSPlasH scene-file codes (its scene-file documentation).
SIMULATION_METHODS = {"wcsph": 0, "pbf": 2, "iisph": 3, "dfsph": 4}
#: its TimeStep class per method (the driver records the class it got, the report checks it)
TIME_STEP_CLASSES = {"wcsph": "TimeStepWCSPH", "pbf": "TimeStepPBF", "iisph": "TimeStepIISPH", "dfsph": "TimeStepDFSPH"}
#: SPlisHSPlasH's CFL settings in the adaptive comparison: cflMethod 1 (the velocity CFL step), the
#: cflFactor 1 and 5 ms cap of its example scenes, 1 ms initial step
ADAPTIVE_CFL = {"cflMethod": 1, "cflFactor": 1.0, "cflMaxTimeStepSize": 0.005, "cflMinTimeStepSize": 1e-4,
                "timeStepSize": 0.001}
BOUNDARY_AKINCI2012 = 0
KERNEL_CUBIC = 0


def to_y_up(v) -> list[float]:
    """(x, y, z) Z-up -> (x, z, y) Y-up."""
    return [float(v[0]), float(v[2]), float(v[1])]


def from_y_up(a: np.ndarray) -> np.ndarray:
    """(n, 3) Y-up -> Z-up."""
    return np.asarray(a)[:, [0, 2, 1]]


def box_obj_text(lo, hi) -> str:
    """A closed box lo..hi as OBJ text (8 vertices, 12 triangles)."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    verts = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
             (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
    faces = [(1, 3, 2), (1, 4, 3), (5, 6, 7), (5, 7, 8), (1, 2, 6), (1, 6, 5),
             (2, 3, 7), (2, 7, 6), (3, 4, 8), (3, 8, 7), (4, 1, 5), (4, 5, 8)]
    lines = [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in verts] + [f"f {a} {b} {c}" for a, b, c in faces]
    return "\n".join(lines) + "\n"


_JSON_KEYS = {"STIFFNESS": "stiffness", "EXPONENT": "exponent", "MAX_ITERATIONS": "maxIterations",
              "MIN_ITERATIONS": "minIterations", "MAX_ERROR": "maxError", "MAX_ITERATIONS_V": "maxIterationsV",
              "MAX_ERROR_V": "maxErrorV", "USE_DIVERGENCE_SOLVER": "enableDivergenceSolver",
              "VELOCITY_UPDATE_METHOD": "velocityUpdateMethod"}


def time_step_values(scene: dict, model: dict, solver: str) -> dict:
    """Pressure-solver parameters for SPlisHSPlasH's TimeStep class, by its parameter name.

    WCSPH: p = stiffness ((rho/rho0)^exponent - 1) with warp-sph's K and exponent 1 (linear) or 7
    (Tait). PBF: warp-sph's iteration limits and target average density error (SPlisHSPlasH's
    maxError is in percent). DFSPH: SPlisHSPlasH's defaults (0.01 % density, 0.1 % divergence).
    """
    if solver == "wcsph":
        return {"STIFFNESS": float(model["stiffness"]),
                "EXPONENT": 7.0 if model.get("equation_of_state") == "tait" else 1.0}
    if solver == "pbf":
        pbf = scene.get("pbf", {})
        return {"MAX_ITERATIONS": int(pbf.get("max_iterations", 50)), "MIN_ITERATIONS": int(pbf.get("min_iterations", 2)),
                "MAX_ERROR": 100.0 * float(pbf.get("target_density_error", 0.005)), "VELOCITY_UPDATE_METHOD": 0}
    if solver == "dfsph":
        return {"MAX_ITERATIONS": 100, "MIN_ITERATIONS": 2, "MAX_ERROR": 0.01, "MAX_ITERATIONS_V": 100,
                "MAX_ERROR_V": 0.1, "USE_DIVERGENCE_SOLVER": True}
    raise ValueError(f"unknown solver {solver!r}")


def scene_json(scene: dict, model: dict, fluid_min, fluid_max, solver: str, dt: float, box_obj: str,
               adaptive: bool = False, time_step: dict | None = None) -> dict:
    """SPlisHSPlasH scene (JSON structure) for a warp-sph scene dict with a box container and box fluid.

    model: warp-sph ``Model.summary()`` (stiffness, equation of state); fluid_min/max: corners of
    warp-sph's sampled fluid lattice (particle centres) [m], Z-up. SPlisHSPlasH fills a block
    start..end with particles at start + d, ..., end - d, so start/end are the lattice corners -/+ d.
    adaptive: its CFL step (``ADAPTIVE_CFL``) instead of the fixed step dt; time_step: the method's
    parameters by TimeStep name (default: ``time_step_values``, warp-sph's settings).
    """
    d = 2.0 * float(scene["particle_radius"])
    g = to_y_up(scene["gravity"])
    conf = {
        "particleRadius": float(scene["particle_radius"]),
        "simulationMethod": SIMULATION_METHODS[solver],
        "boundaryHandlingMethod": BOUNDARY_AKINCI2012,
        "kernel": KERNEL_CUBIC, "gradKernel": KERNEL_CUBIC,
        "gravitation": g,
        "timeStepSize": float(dt), "cflMethod": 0,
        "numberOfStepsPerRenderUpdate": 1,
        "enableVTKExport": False, "enablePartioExport": False,
    }
    if adaptive:
        conf.update(ADAPTIVE_CFL)
    ts = time_step_values(scene, model, solver) if time_step is None else time_step
    block = {"wcsph": "WCSPH", "pbf": "PBF", "dfsph": "DFSPH", "iisph": "IISPH"}[solver]
    conf[block] = {_JSON_KEYS[k]: (bool(v) if isinstance(v, bool) else v) for k, v in ts.items()}
    lo = np.minimum(to_y_up(np.asarray(fluid_min) - d), to_y_up(np.asarray(fluid_max) + d))
    hi = np.maximum(to_y_up(np.asarray(fluid_min) - d), to_y_up(np.asarray(fluid_max) + d))
    return {
        "Configuration": conf,
        "Materials": [{"id": "Fluid", "density0": float(scene["material"]["rest_density"]),
                       "viscosityMethod": 0, "surfaceTensionMethod": 0, "vorticityMethod": 0,
                       "dragMethod": 0, "elasticityMethod": 0}],
        "RigidBodies": [{"geometryFile": box_obj, "translation": [0.0, 0.0, 0.0], "scale": [1.0, 1.0, 1.0],
                         "rotationAxis": [1.0, 0.0, 0.0], "rotationAngle": 0.0,
                         "isDynamic": False, "isWall": True, "mapInvert": True, "mapThickness": 0.0,
                         "mapResolution": [20, 20, 20]}],
        "FluidBlocks": [{"denseMode": 0, "start": [float(v) for v in lo], "end": [float(v) for v in hi],
                         "translation": [0.0, 0.0, 0.0], "scale": [1.0, 1.0, 1.0], "initialVelocity": [0.0, 0.0, 0.0]}],
    }
