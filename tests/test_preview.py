"""Preview renderer: analytic silhouettes and highlights, a brute-force oracle, and run-folder output."""
import json
import math

import numpy as np
import pytest

from warp_sph.preview.render_run import (
    BACKGROUND,
    Camera,
    Light,
    PreviewError,
    auto_camera,
    preview_run,
    render_mesh,
    render_particles,
    save_png,
)

BACKGROUND_U8 = np.rint(np.asarray(BACKGROUND) * 255.0).astype(np.uint8)


def _foreground(image):
    return np.any(image != BACKGROUND_U8, axis=2)


def _pinhole(camera_position, target, up, fov_deg, size):
    """Independent pinhole model: returns project(p) -> (column, row) in pixel-index coordinates."""
    eye = np.asarray(camera_position, float)
    forward = np.asarray(target, float) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    width, height = size
    focal = (height / 2.0) / math.tan(math.radians(fov_deg) / 2.0)  # [px]

    def project(p):
        d = np.asarray(p, float) - eye
        z = d @ forward
        return width / 2.0 + focal * (d @ right) / z - 0.5, height / 2.0 - focal * (d @ cam_up) / z - 0.5

    return project, focal


def test_sphere_silhouette_and_highlight(device):
    radius, size, fov = 1.0, (160, 120), 40.0
    eye, up = np.array([3.0, -3.5, 1.5]), (0.0, 0.0, 1.0)
    light_dir = np.array([-0.3, -0.5, 0.8]) / np.linalg.norm([-0.3, -0.5, 0.8])
    light = Light(direction=tuple(light_dir), ambient=0.1, diffuse=0.4, specular=0.45, shininess=120.0)
    camera = Camera(position=tuple(eye), target=(0.0, 0.0, 0.0), up=up, fov_deg=fov)
    image = render_particles(np.zeros((1, 3)), radius, camera, size, colors=(0.5, 0.5, 0.5), device=device, light=light)
    assert image.shape == (120, 160, 3) and image.dtype == np.uint8

    # silhouette: the sphere seen from distance D subtends half-angle asin(R/D); on the optical axis
    # its image is a disc of radius focal * tan(asin(R/D)) pixels
    project, focal = _pinhole(eye, (0, 0, 0), up, fov, size)
    disc_radius = focal * math.tan(math.asin(radius / np.linalg.norm(eye)))
    expected_area = math.pi * disc_radius**2
    area = _foreground(image).sum()
    assert abs(area - expected_area) < 0.03 * expected_area, (area, expected_area)

    # highlight: the sphere point whose normal is the half vector of light and view directions
    normal = light_dir + eye / np.linalg.norm(eye)
    for _ in range(100):
        normal /= np.linalg.norm(normal)
        point = radius * normal
        view = (eye - point) / np.linalg.norm(eye - point)
        normal = light_dir + view
    expected = np.array(project(radius * normal / np.linalg.norm(normal)))
    luminance = np.where(_foreground(image), image.astype(int).sum(axis=2), -1)  # the sphere's pixels only
    rows, cols = np.nonzero(luminance == luminance.max())
    brightest = np.array([cols.mean(), rows.mean()])
    assert np.linalg.norm(brightest - expected) <= 2.0, (brightest, expected)
    # and the highlight is off the disc centre, so the check is not trivially met
    assert np.linalg.norm(expected - np.array(project((0, 0, 0)))) > 5.0


def test_square_mesh_covers_its_projection(device):
    # two triangles: the square [-1, 1]^2 at z = 0, seen straight from above from 5 m
    vertices = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float32)
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    size, fov = (120, 90), 40.0
    camera = Camera(position=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_deg=fov)
    light = Light(direction=(0.0, 0.6, 0.8), ambient=0.2, diffuse=0.5, specular=0.0)
    image = render_mesh(vertices, triangles, camera, size, device=device, color=(0.2, 0.4, 0.8), light=light)
    mask = _foreground(image)
    _, focal = _pinhole((0, 0, 5), (0, 0, 0), (0, 1, 0), fov, size)
    half = focal * 1.0 / 5.0  # half side of the square's image [px]
    cols = np.arange(size[0]) + 0.5 - size[0] / 2.0  # pixel centres relative to the image centre
    rows = np.arange(size[1]) + 0.5 - size[1] / 2.0
    expected = (np.abs(rows)[:, None] < half) & (np.abs(cols)[None, :] < half)
    assert expected.sum() > 1000
    assert (mask != expected).sum() <= 0.02 * expected.sum(), ((mask != expected).sum(), expected.sum())
    # without a highlight, a plane under a directional light is one flat colour: (ambient + diffuse n.l) C
    inside = expected & mask
    flat = np.rint((0.2 + 0.5 * 0.8) * np.array([0.2, 0.4, 0.8]) * 255.0)
    assert np.all(np.abs(image[inside].astype(int) - flat) <= 1)


def _reference_image(x, radius, colors, camera, size):
    """Brute force: every pixel's ray against every sphere; nearest hit's colour (unlit), else background."""
    width, height = size
    eye = np.asarray(camera.position, float)
    forward = np.asarray(camera.target, float) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, camera.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    tan_half = math.tan(math.radians(camera.fov_deg) / 2.0)
    sx = (2.0 * (np.arange(width) + 0.5) / width - 1.0) * tan_half * width / height
    sy = (1.0 - 2.0 * (np.arange(height) + 0.5) / height) * tan_half
    d = forward + sx[None, :, None] * right + sy[:, None, None] * up
    d /= np.linalg.norm(d, axis=2, keepdims=True)  # (H, W, 3)
    oc = eye[None, :] - x  # (N, 3)
    b = np.einsum("hwk,nk->hwn", d, oc)
    c = np.sum(oc * oc, axis=1) - radius**2
    disc = b * b - c
    t = np.where(disc >= 0.0, -b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
    t = np.where(t > 0.0, t, np.inf)
    nearest = np.argmin(t, axis=2)
    hit = np.isfinite(np.min(t, axis=2))
    image = np.where(hit[..., None], colors[nearest], np.asarray(BACKGROUND))
    return np.rint(image * 255.0).astype(np.uint8), t


def test_accelerated_spheres_match_brute_force(device):
    # a dense clump and loose spray of spheres with distinct colours, lit by ambient light only,
    # so every pixel must show exactly the colour of the nearest sphere along its ray
    rng = np.random.default_rng(3)
    radius = 0.07
    clump = rng.normal(0.0, 0.15, size=(300, 3))
    spray = rng.uniform(-1.0, 1.0, size=(100, 3))
    x = np.concatenate([clump, spray]).astype(np.float32)
    colors = rng.uniform(0.05, 0.95, size=(len(x), 3)).astype(np.float32)
    camera = Camera(position=(1.8, -2.6, 1.2), target=(0.0, 0.0, 0.0), fov_deg=45.0)
    size = (96, 72)
    flat = Light(direction=(0.0, 0.0, 1.0), ambient=1.0, diffuse=0.0, specular=0.0)
    image = render_particles(x, radius, camera, size, colors=colors, device=device, light=flat)
    reference, t = _reference_image(x.astype(float), radius, colors.astype(float), camera, size)
    # a pixel may differ only where two spheres are hit at (nearly) the same distance or at a silhouette
    differs = np.any(np.abs(image.astype(int) - reference.astype(int)) > 1, axis=2)
    t_sorted = np.sort(t, axis=2)
    second = np.where(np.isfinite(t_sorted[..., 1]), t_sorted[..., 1], 1.0e30)
    ambiguous = second - t_sorted[..., 0] < 1.0e-4  # two spheres at the same depth
    assert _foreground(reference).sum() > 1000
    assert (differs & ~ambiguous).sum() <= 3, (differs & ~ambiguous).sum()


def test_auto_camera_frames_the_box():
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([2.0, 1.0, 0.8])
    camera = auto_camera(lo, hi)
    size = (160, 90)
    project, _ = _pinhole(camera.position, camera.target, camera.up, camera.fov_deg, size)
    corners = [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    pixels = np.array([project(c) for c in corners])
    assert np.all(pixels >= 0.0) and np.all(pixels < size)  # the whole box is in view
    extent = pixels.max(axis=0) - pixels.min(axis=0)
    assert extent[1] > 0.6 * size[1]  # ... and fills it
    assert camera.position[2] > hi[2]  # seen from above, Z up


def _fake_run(tmp_path, frames=(0, 5)):
    """A run folder in the simulator's layout: run.json, frames/frame_*.npz and a USD with /sph/surface."""
    from pxr import Usd, UsdGeom

    run = tmp_path / "run"
    (run / "frames").mkdir(parents=True)
    rng = np.random.default_rng(0)
    scene = {"particle_radius": 0.02, "container": {"min": [0, 0, 0], "max": [1, 0.5, 0.5]}, "fps": 10.0}
    stage = Usd.Stage.CreateNew(str(run / "run.usdc"))
    mesh = UsdGeom.Mesh.Define(stage, "/sph/surface")
    for k, frame in enumerate(frames):
        x = rng.uniform([0.05, 0.05, 0.05], [0.4, 0.45, 0.3], size=(500, 3)).astype(np.float32)
        v = rng.normal(0.0, 1.0, size=(500, 3)).astype(np.float32)
        np.savez(run / "frames" / f"frame_{frame:06d}.npz", x=x, v=v, density=np.full(500, 1000.0, np.float32),
                 time=frame / 10.0)
        z = 0.2 + 0.05 * k
        points = [(0.0, 0.0, z), (1.0, 0.0, z), (1.0, 0.5, z), (0.0, 0.5, z + 0.1)]
        mesh.GetPointsAttr().Set(points, Usd.TimeCode(frame))
        mesh.GetFaceVertexCountsAttr().Set([4], Usd.TimeCode(frame))  # a quad: triangulated by the reader
        mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3], Usd.TimeCode(frame))
    stage.GetRootLayer().Save()
    meta = {"scene": scene, "frames": [{"frame": f, "time": f / 10.0} for f in frames]}
    (run / "run.json").write_text(json.dumps(meta))
    return run


@pytest.mark.parametrize("mode", ["particles", "surface"])
def test_preview_run_writes_pngs_of_the_requested_size(tmp_path, mode):
    image_module = pytest.importorskip("PIL.Image")
    run = _fake_run(tmp_path)
    written = preview_run(run, frames=[0, 5], mode=mode, size=(96, 64), gif=True)
    pngs = [run / "preview" / f"{mode}_000000.png", run / "preview" / f"{mode}_000005.png"]
    assert written == pngs + [run / "preview" / f"{mode}.gif"]
    for path in pngs:
        with image_module.open(path) as im:
            assert im.size == (96, 64) and im.mode == "RGB"
            pixels = np.asarray(im)
        assert _foreground(pixels).sum() > 0.05 * 96 * 64  # the fluid (or surface) is in the picture
    with image_module.open(run / "preview" / f"{mode}.gif") as im:
        assert im.n_frames == 2
    assert not list((run / "preview").glob("*.tmp"))


def test_preview_run_defaults_and_errors(tmp_path):
    pytest.importorskip("PIL")
    run = _fake_run(tmp_path)
    out = tmp_path / "pictures"
    assert preview_run(run, size=(32, 24), out=out) == [out / "particles_000005.png"]  # the last frame
    with pytest.raises(PreviewError, match="not recorded"):
        preview_run(run, frames=[3], size=(32, 24))
    with pytest.raises(PreviewError, match="mode"):
        preview_run(run, mode="voxels")


def test_missing_pillow_names_the_extra(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "PIL", None)  # makes `from PIL import Image` raise ImportError
    with pytest.raises(PreviewError, match=r"warp-sph\[preview\].*pip install -e '\.\[preview\]'"):
        save_png(np.zeros((4, 4, 3), np.uint8), tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("mode", ["surface", "particles"])
def test_preview_shows_obstacles(tmp_path, mode):
    """The obstacle scene's cylinder (in the USD and the scene) is drawn, in stone grey."""
    image_module = pytest.importorskip("PIL.Image")
    from warp_sph.preview.render_run import SurfaceReader, load_frame, speed_colors
    from warp_sph.run import runner
    from warp_sph.scene import load_scene

    out = tmp_path / "obstacle"
    runner.run(load_scene("obstacle", ["particle_radius=0.05", "output.checkpoint_every=0"]), out=out,
               device="cpu", frames=2, progress=False, log=lambda *a: None)
    scene = json.loads((out / "run.json").read_text())["scene"]
    box = scene["container"]
    size = (160, 90)
    camera = auto_camera(np.asarray(box["min"]), np.asarray(box["max"]), aspect=size[0] / size[1])
    (png,) = preview_run(out, frames=[2], mode=mode, camera=camera, size=size)
    with image_module.open(png) as im:
        picture = np.asarray(im)
    if mode == "surface":
        vertices, triangles = SurfaceReader(out).frame(2)
        without = render_mesh(vertices, triangles, camera, size, (box["min"], box["max"]))
    else:
        x, v = load_frame(out, 2)
        speed = float(np.percentile(np.linalg.norm(v, axis=1), 99.0))
        without = render_particles(x, scene["particle_radius"], camera, size, (box["min"], box["max"]),
                                   speed_colors(v, speed, len(x)))
    changed = np.any(picture != without, axis=2)
    assert changed.sum() > 0.01 * size[0] * size[1], changed.sum()
    pixels = picture[changed].astype(float)
    assert np.median(pixels[:, 0] - pixels[:, 2]) > 0  # red over blue: stone, not water


def _cli_error(args, capsys) -> tuple[int, str]:
    """(exit status, the one error line) of ``warp-sph ARGS``; no traceback, nothing else on stderr."""
    from warp_sph.cli import main

    code = main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("warp-sph: error: "), err
    return code, err[0]


def test_preview_out_that_is_a_file_is_refused(tmp_path, capsys):
    """``preview RUN --out FILE`` with FILE existing ended in a FileExistsError traceback."""
    pytest.importorskip("PIL")
    run = _fake_run(tmp_path)
    picture = tmp_path / "picture.png"
    picture.write_bytes(b"my own picture")
    for out in (picture, picture / "sub"):
        code, line = _cli_error(["preview", str(run), "--out", str(out)], capsys)
        assert code == 2
        assert line.startswith(f"warp-sph: error: --out {out} ") and "not a folder" in line, line
    assert picture.read_bytes() == b"my own picture"
    assert not (run / "preview").exists()


@pytest.mark.parametrize("damage", ["text", "truncated", "empty"])
def test_preview_of_a_damaged_frame_is_one_line(tmp_path, capsys, damage):
    """A damaged frames/*.npz ended in a NumPy ValueError (or BadZipFile) traceback; ``export`` said it in
    one line, and now both say it the same way (``run_folder.read_frame``)."""
    run = _fake_run(tmp_path)
    frame = run / "frames" / "frame_000005.npz"
    data = frame.read_bytes()
    frame.write_bytes({"text": b"garbage\n", "truncated": data[: len(data) // 2], "empty": b""}[damage])
    code, line = _cli_error(["preview", str(run), "--frame", "5"], capsys)
    assert code == 2
    assert line == f"warp-sph: error: {frame}: unreadable recorded frame (not an npz archive: damaged or truncated)"


def test_preview_never_replaces_a_users_picture(tmp_path, capsys):
    """``preview --out ~/Pictures`` replaced a particles_000005.png the user kept there without a word. Now a
    folder other than the run's own preview/ is checked before rendering: a file of a name preview would write
    is refused (one line, exit 2, the file as it was) unless --overwrite; the run's preview/ is rewritten."""
    pytest.importorskip("PIL")
    from warp_sph.cli import main

    run = _fake_run(tmp_path, frames=(4, 5))
    pictures = tmp_path / "pictures"
    pictures.mkdir()
    mine = pictures / "particles_000005.png"
    mine.write_bytes(b"my own picture")
    args = ["preview", str(run), "--frames", "4:5", "--gif", "--size", "32x24", "--out", str(pictures)]
    code, line = _cli_error(args, capsys)
    assert code == 2 and line.startswith(f"warp-sph: error: --out {pictures} already holds particles_000005.png; "
                                         "pass --overwrite"), line
    assert "(and" not in line  # particles_000004.png and particles.gif are not there
    assert mine.read_bytes() == b"my own picture" and sorted(p.name for p in pictures.iterdir()) == [mine.name]
    assert main(args + ["--overwrite"]) == 0
    assert mine.read_bytes().startswith(b"\x89PNG")
    for _ in range(2):  # the run's own preview folder: its pictures are the run's files, replaced each time
        assert main(["preview", str(run), "--frame", "5", "--size", "32x24"]) == 0
    assert (run / "preview" / "particles_000005.png").read_bytes().startswith(b"\x89PNG")


@pytest.mark.parametrize("content, expected", [(None, "is not a warp-sph run folder (no run.json)"),
                                               (b"\xff\xfe{", "run.json: unreadable JSON"),
                                               (b"{", "run.json: unreadable JSON"),
                                               (b"[]", "not a warp-sph run.json"),
                                               (b'{"scene": {}, "frames": "abc"}', "'frames' is not a list of frame"),
                                               (b'{"scene": {}, "frames": [{"x": 1}]}', "'frames' is not a list")])
def test_a_missing_or_damaged_run_json_is_one_line_as_in_export(tmp_path, capsys, content, expected):
    """preview read run.json its own way: a file that is not UTF-8 ended in a UnicodeDecodeError traceback
    (exit 1). Now the run folder's one reader (``run_folder.read_run_json``), the lines of export and plot."""
    from warp_sph.cli import main

    run = tmp_path / "run"
    run.mkdir()
    if content is not None:
        (run / "run.json").write_bytes(content)
    assert main(["preview", str(run)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expected in err[0], err
