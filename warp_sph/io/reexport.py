"""Re-export a finished (or interrupted) run from its recorded frames, without simulating again.

    warp-sph export runs/dam_break --surface-cell 0.5             # finer surface, new USD
    warp-sph export runs/dam_break --format obj --frames 10:40    # OBJ sequence of frames 10..40

Inputs, all from the run folder (``run_folder`` describes the layout):
- ``frames/frame_NNNNNN.npz``: x (world) [m], v [m/s], density [kg/m^3], time [s] of each frame (and the
  particle ids ``id`` with emitters or sinks: the count changes from frame to frame);
- ``run.json``: the resolved scene (container, obstacles, output settings, fps) and the model
  constants the surface needs: smoothing kernel, smoothing length h, particle mass m, particle
  radius r, and the local origin (positions are meshed relative to it, as during the run, so
  float32 keeps its precision wherever the scene sits).

Outputs (default under ``DIR/export/``): ``<scene>.usdc`` (particles, surface, container and
obstacles, rigid bodies at the poses run.json recorded; the run's frame numbers are kept as time
codes) or ``<fmt>/surface_NNNNNN.<fmt>``.
An existing output is never replaced without ``overwrite``, and never by a part: the export is written
beside it (a hidden temporary file or folder) and moved into place once every frame is in. A damaged
or truncated frame file stops the export with one line naming it (as ``run --resume`` stops at a
damaged checkpoint); what was there before is left as it was. The frames' archives are checked
before any surface is made, so a truncated file stops it at once.
"""
from __future__ import annotations

import os
import re
import shutil
import tempfile
import warnings
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from . import atomic
from . import run_folder as rf
from ..core.errors import OutputError, SceneError, WarpSphError

#: export formats: "usd" (one stage) or a mesh sequence format of ``export_mesh``
EXPORT_FORMATS = ("usd", "obj", "ply", "vtk")


def scene_static_meshes(scene: dict) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Static meshes of a scene (``Scene.to_dict()`` form) for the USD stage, in world metres.

    ``container``: the container box without its top (an open tank); ``obstacle_<i>``: box
    obstacles as closed boxes, mesh obstacles loaded and placed as the sampler places them
    (x -> scale x + translate) and wound outward (a closed mesh with negative signed volume is
    flipped). A mesh file that no longer loads is left out with a warning: the particles and
    surface are what an export is for.
    """
    from .export_usd import container_box_mesh
    from ..scene.meshes import load_triangle_mesh

    out = []
    c = scene.get("container")
    if isinstance(c, dict):  # ``container = false`` (radial_expansion): no walls, no mesh
        out.append(("container", *container_box_mesh(c["min"], c["max"], open_top=True)))
    for i, ob in enumerate(scene.get("obstacles") or []):
        name = f"obstacle_{i}"
        if ob.get("keyframes") or ob.get("animation"):  # animated: a moving prim under /sph/bodies
            continue
        if ob.get("shape", "box") == "box":
            out.append((name, *container_box_mesh(ob["min"], ob["max"], open_top=False)))
            continue
        try:
            scale = ob.get("scale")
            translate = ob.get("translate")
            mesh = load_triangle_mesh(ob["file"]).transformed(1.0 if scale is None else scale,
                                                              (0.0, 0.0, 0.0) if translate is None else translate)
        except (SceneError, OSError, KeyError) as exc:
            warnings.warn(f"obstacle {i} left out of the USD: {exc}", RuntimeWarning, stacklevel=2)
            continue
        verts = np.asarray(mesh.vertices, dtype=np.float64)
        tris = np.asarray(mesh.triangles, dtype=np.int64)
        a, b, cc = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
        if np.einsum("ij,ij->i", a, np.cross(b, cc)).sum() < 0.0:  # 6 x signed volume
            tris = tris[:, ::-1]
        out.append((name, verts.astype(np.float32), np.ascontiguousarray(tris, dtype=np.int32)))
    return out


def _body_shapes(scene: dict, info: dict, frames: list[int]) -> tuple[list, dict]:
    """([(name, vertices, triangles)] in the body frames, {frame: {name: (position, quaternion)}}) of the
    run's rigid bodies, from run.json's scene and per-frame poses; empty when it has none. A body whose
    mesh file no longer loads, or a frame without poses, leaves the bodies out with a warning."""
    entries = scene.get("bodies") or []
    if not entries:
        return [], {}
    from ..rigid.spec import Body, body_geometry, body_name

    try:
        shapes = []
        for i, entry in enumerate(entries):
            body = Body(**entry)
            geo = body_geometry(body)
            shapes.append((body_name(body, i), geo.vertices, geo.triangles))
    except (SceneError, OSError, TypeError) as exc:
        warnings.warn(f"rigid bodies left out of the USD: {exc}", RuntimeWarning, stacklevel=3)
        return [], {}
    records = {int(r["frame"]): r.get("bodies") or {} for r in info.get("frames") or []}
    poses = {}
    for frame in frames:
        rec = records.get(frame, {})
        if any(name not in rec for name, _, _ in shapes):
            warnings.warn(f"rigid bodies left out of the USD: run.json has no body poses for frame {frame}",
                          RuntimeWarning, stacklevel=3)
            return [], {}
        poses[frame] = {name: (np.asarray(rec[name]["position"]), np.asarray(rec[name]["orientation"]))
                        for name, _, _ in shapes}
    return shapes, poses


def _far_from_origin(frame_file: Path) -> bool:
    """A run recorded far from (0, 0, 0) stores x in float64 (``runner.world_float32_error``):
    its USD re-export is then written relative to the origin too."""
    try:
        with np.load(frame_file) as data:
            return data["x"].dtype == np.float64
    except (OSError, KeyError, ValueError):
        return False


def recorded_frames(run_dir: Path) -> dict[int, Path]:
    """Frame number -> recorded frame file of a run folder."""
    d = Path(run_dir) / "frames"
    found = {}
    for p in d.glob("frame_*.npz") if d.is_dir() else []:
        m = re.fullmatch(r"frame_(\d+)", p.stem)
        if m:
            found[int(m.group(1))] = p
    return dict(sorted(found.items()))


def parse_frame_range(frames, available: Iterable[int]) -> list[int]:
    """Frames to export: None (all recorded), "A:B" (inclusive; A or B may be left out), "A", or ints.

    Raises WarpSphError when the range is malformed, empty, or asks for frames not recorded.
    """
    available = sorted(available)
    if not available:
        raise OutputError("the run recorded no frames (frames/ is empty; output.record_frames = false?)")
    if frames is None:
        wanted = available
    elif isinstance(frames, str):
        text = frames.strip()
        a, sep, b = text.partition(":")
        try:
            lo = int(a) if a.strip() else available[0]
            hi = (int(b) if b.strip() else available[-1]) if sep else lo
        except ValueError:
            raise WarpSphError(f"--frames {frames!r}: expected A:B (integers, inclusive), A: , :B or A") from None
        if lo > hi:
            raise WarpSphError(f"--frames {frames!r}: first frame {lo} is after last frame {hi}")
        wanted = list(range(lo, hi + 1))
    else:
        wanted = sorted(int(f) for f in frames)
    if not wanted:
        raise WarpSphError("no frame to export")
    missing = sorted(set(wanted) - set(available))
    if missing:
        shown = ", ".join(str(f) for f in missing[:8]) + (" ..." if len(missing) > 8 else "")
        raise OutputError(f"frame(s) {shown} not recorded; the run holds frames "
                          f"{available[0]}..{available[-1]} ({len(available)} files)")
    return wanted


def _surface_reconstructor(info: dict, cell_per_radius: float | None, iso: float | None, device):
    """The run's surface settings (``scene.output.surface_*``; a run made before a setting existed
    gets its current default), with ``--surface-cell`` / ``--surface-iso`` applied."""
    from ..scene.parameters import parameter
    from ..surface.reconstruction import SurfaceReconstructor, surface_settings

    model = info.get("model") or {}
    out_cfg = dict((info.get("scene") or {}).get("output") or {})
    try:
        kernel = model["smoothing_kernel"]
        h = float(model["smoothing_length"])
        r = float(model["particle_radius"])
    except (KeyError, TypeError, ValueError):
        raise OutputError("run.json lacks the model constants of the surface (model.smoothing_kernel, "
                          "smoothing_length, particle_radius)") from None
    for flag, key, value in (("--surface-cell", "surface_cell_per_radius", cell_per_radius),
                             ("--surface-iso", "surface_iso", iso)):
        if value is not None:  # the scene key's range (parameter registry), so no flag writes an empty surface
            p = parameter(f"output.{key}")
            if not p.in_range(value):
                raise WarpSphError(f"{flag} {value:g}: expected {p.expected()}, as the scene key output.{key}")
            out_cfg[key] = float(value)
    return SurfaceReconstructor(kernel, h, r, device=device, **surface_settings(out_cfg, r))


def export_run(run_dir, fmt: str = "usd", out=None, cell_per_radius: float | None = None,
               iso: float | None = None, frames=None, overwrite: bool = False, device=None) -> Path:
    """Re-export the recorded frames of ``run_dir`` and return the file (usd) or folder written.

    Args:
        run_dir: a run folder (holds run.json and frames/).
        fmt: "usd" (particles + surface + static meshes in one .usdc) or "obj" / "ply" / "vtk"
            (one surface file per frame).
        out: output file (usd; an existing folder gets ``<scene>.usdc`` inside) or folder
            (meshes); default ``run_dir/export/<scene>.usdc`` or ``run_dir/export/<fmt>/``.
        cell_per_radius: surface grid cell / particle radius (default: the run's output setting).
        iso: iso level of the colour field, 0 < iso < 1 (default: the run's).
        frames: None (all recorded), "A:B" (inclusive), or an iterable of frame numbers.
        overwrite: replace existing output files (otherwise OutputError before anything is written).
        device: Warp device of the surface reconstruction (default: Warp's default device).
    """
    import warp as wp

    run_dir = Path(run_dir)
    if fmt not in EXPORT_FORMATS:
        raise WarpSphError(f"unknown export format {fmt!r}; expected one of {', '.join(EXPORT_FORMATS)}")
    info = rf.read_run_json(run_dir)
    scene = info.get("scene") or {}
    name = rf.safe_name(scene.get("name") or "run")  # a file name inside the output folder, whatever the scene says
    files = recorded_frames(run_dir)
    wanted = parse_frame_range(frames, files)
    if fmt == "usd" and wanted != list(range(wanted[0], wanted[-1] + 1)):
        raise WarpSphError("a USD export needs consecutive frames")
    for frame in wanted:  # a truncated or damaged archive: one line before anything is made or written
        try:
            rf.check_frame_file(files[frame], keys=("x", "v", "density"))
        except OutputError as exc:
            raise OutputError(_damaged(exc, frame, wanted)) from None
    origin = np.asarray((info.get("model") or {}).get("origin", (0.0, 0.0, 0.0)), dtype=np.float64)
    device = wp.get_device(device)
    surface = _surface_reconstructor(info, cell_per_radius, iso, device)
    radius = surface.particle_radius

    # choose and check the output before any work
    if fmt == "usd":
        target = Path(out) if out is not None else run_dir / "export" / f"{name}.usdc"
        if target.is_dir():
            target = target / f"{name}.usdc"
        if target.suffix.lower() not in (".usdc", ".usd", ".usda"):
            raise OutputError(f"--out {target}: a USD export is written to a .usdc file (or .usd, .usda); "
                              "name it so, or give a folder")
        if target.exists() and not overwrite:
            raise OutputError(f"{target} exists; pass --overwrite to replace it or choose another --out")
        target.parent.mkdir(parents=True, exist_ok=True)
    else:
        target = Path(out) if out is not None else run_dir / "export" / fmt
        if target.exists() and not target.is_dir():
            raise OutputError(f"--out {target} exists and is not a folder")
        pattern = re.compile(rf"surface_\d{{6}}\.{fmt}")
        existing = sorted(p for p in target.glob(f"surface_*.{fmt}") if pattern.fullmatch(p.name)) \
            if target.is_dir() else []
        if existing and not overwrite:
            raise OutputError(f"{target} already holds {len(existing)} surface_*.{fmt} files; pass --overwrite "
                              "to replace them or choose another --out")
        target.mkdir(parents=True, exist_ok=True)

    # written beside the target and moved into place at the end: a failed export leaves the old one
    usd = mesh_writer = None
    body_poses: dict = {}
    existed = target.exists() if fmt == "usd" else any(target.glob(f"surface_*.{fmt}"))
    partial = _partial_path(target, fmt)
    done = False
    try:
        if fmt == "usd":
            from .export_usd import UsdWriter

            primvars = tuple(n for n in (scene.get("output") or {}).get("particle_primvars", ("density",))
                             if n == "density")  # pressure is not recorded
            far = float(np.abs(origin).max()) > 0.0 and _far_from_origin(files[wanted[0]])
            usd = UsdWriter(partial, fps=float(info.get("fps") or scene.get("fps") or 24.0), particle_radius=radius,
                            static_meshes=scene_static_meshes(scene), primvars=primvars, with_surface=True,
                            with_normals=surface.with_normals, with_spray=surface.grid.spray_neighbors > 0,
                            overwrite=True, first_frame=wanted[0], origin=origin if far else None)
            shapes, body_poses = _body_shapes(scene, info, wanted)
            for body, vertices, triangles in shapes:  # moving rigid bodies at the poses run.json recorded
                usd.add_body(body, vertices, triangles)
        else:
            from .export_mesh import MeshSequenceWriter

            mesh_writer = MeshSequenceWriter(partial, fmt)
        _write_frames(wanted, files, origin, surface, device, usd, mesh_writer, body_poses)
        if usd is not None:
            usd.close()
        _move_into_place(partial, target, fmt, overwrite)
        done = True
    except OutputError as exc:
        frame = getattr(exc, "frame", None)
        raise OutputError(_damaged(exc, frame, wanted, target if existed else None) if frame is not None
                          else str(exc)) from None
    finally:
        if usd is not None:
            usd.close()
        if not done:
            _remove_partial(partial)
    return target


def _damaged(exc: OutputError, frame: int, wanted: list[int], target: Path | None = None) -> str:
    """The one line of a damaged frame file: the reader's, what the export left (``target``: an earlier export
    there, kept), and the frames it can export."""
    left = "wrote nothing" if target is None else f"left {target} as it was"
    hint = f"; --frames {wanted[0]}:{frame - 1} exports the frames before it" if frame > wanted[0] else ""
    return f"{exc}; the export stopped and {left}{hint}"


def _partial_path(target: Path, fmt: str) -> Path:
    """A new hidden file (usd, same suffix: the same file format) or folder beside ``target``."""
    if fmt == "usd":
        fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".export-tmp{target.suffix or '.usdc'}",
                                   dir=target.parent)
        os.close(fd)
        os.unlink(tmp)  # the USD writer creates it
        return Path(tmp)
    return Path(tempfile.mkdtemp(prefix=".export-tmp-", dir=target))


def _remove_partial(partial: Path) -> None:
    try:
        if partial.is_dir():
            shutil.rmtree(partial)
        else:
            partial.unlink(missing_ok=True)
    except OSError:
        pass


def _move_into_place(partial: Path, target: Path, fmt: str, overwrite: bool) -> None:
    """The finished export moved onto ``target`` (os.replace: atomic per file); a mesh sequence's
    earlier surface_* files not in the new one removed (a shorter export leaves no stale frames)."""
    try:
        if fmt == "usd":
            if target.exists() and not overwrite:  # appeared while exporting
                raise OutputError(f"{target} appeared while exporting; the export is left in {partial}")
            os.replace(partial, target)
            from pxr import Sdf

            layer = Sdf.Layer.Find(str(target))
            if layer is not None:  # a stage of the old file open in this process reads the new one
                layer.Reload(force=True)
            return
        pattern = re.compile(rf"surface_\d{{6}}\.{fmt}")
        new = sorted(p.name for p in partial.iterdir() if pattern.fullmatch(p.name))
        for p in target.iterdir():
            if p.is_file() and pattern.fullmatch(p.name) and p.name not in new:
                p.unlink()
        for name in new:
            os.replace(partial / name, target / name)
        partial.rmdir()
    except OSError as exc:
        raise atomic.write_error(target, exc) from None


def _write_frames(wanted, files, origin, surface, device, usd, mesh_writer, body_poses) -> None:
    """Every wanted frame read, meshed and written; an unreadable frame file raises the reader's
    OutputError with ``frame`` set."""
    import warp as wp

    for frame in wanted:
        try:
            data = rf.read_frame(files[frame], keys=("x", "v", "density", "id?"))
        except OutputError as exc:
            exc.frame = frame
            raise
        x_dtype = data["x"].dtype  # float64 where the run lies far from (0, 0, 0)
        x_world = np.asarray(data["x"], dtype=np.float64).reshape(-1, 3)
        v = np.asarray(data["v"], dtype=np.float32).reshape(-1, 3)
        rho = np.asarray(data["density"], dtype=np.float32).reshape(-1)
        x_local = wp.array((x_world - origin).astype(np.float32), dtype=wp.vec3, device=device)
        mesh = surface.reconstruct(x_local)
        verts = mesh.vertices.astype(np.float64) + origin  # world [m]; float32 on writing unless far
        data_far = x_dtype == np.float64
        if usd is not None:
            usd.write_frame(frame, x_world, v, primvars={n: rho for n in usd.primvar_names},
                            surface=(verts, mesh.triangles, mesh.normals), spray=(x_world[mesh.spray], v[mesh.spray]),
                            bodies=body_poses.get(frame), ids=data["id"] if "id" in data else None)
        else:
            mesh_writer.write_frame(frame, verts if data_far else verts.astype(np.float32), mesh.triangles)
