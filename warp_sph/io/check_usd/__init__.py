"""Validate a USD file exported by the SPH simulator for import into Blender.

Needs only usd-core and numpy (shipped with warp-sph; the tests run it on every USD they write):

    python -m warp_sph.io.check_usd run.usdc                    # human-readable report
    python -m warp_sph.io.check_usd run.usdc --min-frames 100   # also require >= 100 frames
    python -m warp_sph.io.check_usd run.usdc --json             # machine-readable report on stdout
    python -m warp_sph.io.check_usd run.usdc --strict           # warnings count as failures too

Exit status: 0 = no errors (warnings allowed), 1 = validation errors, 2 = cannot open / bad usage.

What it checks (why each one matters in Blender: the project's USD/Blender notes, summarised in
``warp_sph/io/export_usd.py``):
- stage: upAxis, metersPerUnit, timeCodesPerSecond, framesPerSecond, start/end time codes are
  authored. Unauthored upAxis is an error (fallback Y: Blender would tip a Z-up scene on its side),
  so is unauthored metersPerUnit (fallback 0.01: Blender's default "Apply Unit Conversion Scale"
  shrinks the scene 100x) and an unauthored start/end time code range;
- every UsdGeomPoints and UsdGeomMesh (and UsdGeomPointInstancer): the number of `points` time
  samples equals the stage frame range, samples sit on integer frames inside the range, points
  are finite at every sample, Points `widths` exist, are finite and positive and match their
  interpolation, Mesh faceVertexCounts/faceVertexIndices are consistent and in range at every
  sample, `extent` is authored and contains the points at every sample, optional per-point
  arrays (velocities, ids, normals, vertex primvars) have the right length; warnings for a
  closed surface with inward-facing winding, triangles repeating a vertex, subdivisionScheme not
  'none', and PointInstancer prims (static in Blender 4.2).
Self-test (good and deliberately broken files): tests/test_check_usd.py.

Layout: a package split along the validator's own sections, one module per kind of prim. Its modules
hold the shared validator ``/work/shared/tools/check_usd.py`` (the file the task and its reviewers
run) line for line, in its order: after each module's docstring and imports, ``common.py``,
``stage.py``, ``points.py``, ``mesh.py``, ``instancer.py``, ``driver.py`` concatenated are that file's
body after its imports, so a fix in either ports by diff. The package differs only in this docstring,
the ``python -m`` usage lines and ``--strict`` printing FAILED (``print_human(strict=)``). Change the
shared copy and this one together.
"""
from __future__ import annotations

import sys

try:
    import numpy  # noqa: F401
    from pxr import Usd  # noqa: F401
except ImportError as exc:  # pragma: no cover - environment problem
    print(f"check_usd: needs usd-core and numpy ({exc}); pip install usd-core numpy", file=sys.stderr)
    sys.exit(2)

from .common import MAX_TIMES_LISTED, Report, TimeIssues  # noqa: E402
from .driver import main, print_human, run  # noqa: E402
from .mesh import check_mesh_prim, mesh_winding  # noqa: E402
from .instancer import check_instancer_prim  # noqa: E402
from .points import check_extent, check_per_point_array, check_points_prim, check_primvars, check_samples  # noqa: E402
from .stage import check_stage  # noqa: E402

__all__ = ["MAX_TIMES_LISTED", "Report", "TimeIssues", "check_extent", "check_instancer_prim", "check_mesh_prim",
           "check_per_point_array", "check_points_prim", "check_primvars", "check_samples", "check_stage", "main",
           "mesh_winding", "print_human", "run"]
