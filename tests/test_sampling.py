"""Initial particle sampling: lattice counts, wall gap, wall coverage, obstacles (NumPy oracles)."""
import math

import numpy as np
import pytest

from warp_sph.core.errors import SceneError
from warp_sph.scene.meshes import TriangleMesh, load_triangle_mesh, points_inside, sample_surface
from warp_sph.scene.sampling import PointGrid, box_surface, sample_scene
from warp_sph.scene import list_scenes, load_scene, scene_from_dict

CUBE_OBJ = """# unit cube, outward counter-clockwise faces
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
f 1 3 2
f 1 4 3
f 5 6 7
f 5 7 8
f 1 2 6
f 1 6 5
f 2 3 7
f 2 7 6
f 3 4 8
f 3 8 7
f 4 1 5
f 4 5 8
"""


def min_distance(a, b, chunk=256):
    """Brute-force distance from each point of a to its nearest point of b (oracle)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    out = np.empty(len(a))
    for s in range(0, len(a), chunk):
        out[s:s + chunk] = np.sqrt(((a[s:s + chunk, None, :] - b[None]) ** 2).sum(-1)).min(1)
    return out


def nearest_neighbour(a):
    """Distance from each point of a to the nearest other point of a (oracle)."""
    a = np.asarray(a, dtype=np.float64)
    d = np.sqrt(((a[:, None, :] - a[None]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    return d.min(1)


def test_box_count_and_positions_exact():
    s = scene_from_dict({"container": False, "fluid": [{"min": [0.1, 0.2, 0.3], "max": [0.6, 0.5, 0.5],
                                                        "velocity": [1.0, 2.0, 3.0]}]})
    ss = sample_scene(s)
    d, r = 0.05, 0.025
    assert ss.fluid_count == round(0.5 * 0.3 * 0.2 / d**3) == 240
    assert ss.fluid_x.dtype == np.float64 and ss.fluid_x.shape == (240, 3)
    axes = [lo + r + d * np.arange(n) for lo, n in zip((0.1, 0.2, 0.3), (10, 6, 4))]
    expected = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    got = ss.fluid_x[np.lexsort(ss.fluid_x.T[::-1])]
    np.testing.assert_allclose(got, expected, atol=1e-6)
    np.testing.assert_array_equal(ss.fluid_v, np.tile([1.0, 2.0, 3.0], (240, 1)).astype(np.float32))
    assert ss.boundary_count == 0 and ss.container_min is None


def tank(gap=None, width=0.6):
    """A 0.5 m deep block flush with the floor and the four side walls of a tank."""
    data = {"container": {"min": [0, 0, 0], "max": [width, width, 1.0]},
            "fluid": [{"min": [0, 0, 0], "max": [width, width, 0.5]}]}
    if gap is not None:
        data["boundary_gap"] = gap
    return scene_from_dict(data)


@pytest.mark.parametrize("gap", [1.0, 1.1, None])
def test_fluid_touching_walls_starts_one_gap_from_walls(gap):
    s = tank(gap)
    ss = sample_scene(s)
    d = s.spacing
    g = s.wall_gap
    if gap is not None:
        assert g == pytest.approx(gap * d)
    else:
        assert 1.05 * d < g < 1.15 * d  # physics notes section 7: ~1.1 d for the cubic kernel
    x = ss.fluid_x.astype(np.float64)
    # the floor gap is exactly the wall gap
    np.testing.assert_allclose(x[:, 2].min(), g, atol=1e-6)
    # between two opposite walls the lattice is centred: equal gaps, at least the wall gap
    assert np.all(x[:, :2].min(0) >= g - 1e-6)
    np.testing.assert_allclose(x[:, :2].max(0), 0.6 - x[:, :2].min(0), atol=1e-6)
    if gap == 1.0:  # 0.6 m is a multiple of d: exactly the gap on every side
        np.testing.assert_allclose(x[:, :2].min(0), [g] * 2, atol=1e-6)
    # the block is clipped to the container shrunk by g - r, then sampled on the lattice
    n_side = math.floor((0.6 - 2 * (g - 0.5 * d)) / d + 1e-6)
    n_up = math.floor((0.5 - (g - 0.5 * d)) / d + 1e-6)
    assert ss.fluid_count == n_side * n_side * n_up
    if gap == 1.0:
        assert ss.fluid_count == 11 * 11 * 9
    # still a lattice at spacing d
    np.testing.assert_allclose(nearest_neighbour(x), d, rtol=1e-5)


def test_hydrostatic_tank_fits_the_rest_gap_on_all_sides():
    s = load_scene("hydrostatic")
    x = sample_scene(s).fluid_x.astype(np.float64)
    g = s.wall_gap
    np.testing.assert_allclose(x.min(0), g, atol=0.01 * s.spacing)
    np.testing.assert_allclose(0.61 - x[:, :2].max(0), g, atol=0.01 * s.spacing)
    assert len(x) == 11 * 11 * 9


def test_sphere_count_close_to_volume():
    for radius in (0.3, 0.37, 0.5):
        s = scene_from_dict({"container": False, "fluid": [{"shape": "sphere", "center": [0.1, 0.2, 0.3],
                                                            "radius": radius}]})
        ss = sample_scene(s)
        expected = 4.0 / 3.0 * math.pi * radius**3 / s.spacing**3
        assert abs(ss.fluid_count / expected - 1.0) < 0.03
        assert np.all(np.linalg.norm(ss.fluid_x - np.array([0.1, 0.2, 0.3]), axis=1) <= radius + 1e-6)


@pytest.mark.parametrize("name", [n for n, _ in list_scenes()])
def test_no_fluid_within_gap_of_boundary(name):
    s = load_scene(name)
    ss = sample_scene(s)
    assert 0 < ss.fluid_count < 20000
    assert ss.fluid_x.dtype == np.float64 and ss.boundary_x.dtype == np.float64
    if ss.boundary_count == 0:
        return
    d = s.spacing
    lo, hi = ss.fluid_x.min(0) - 2 * d, ss.fluid_x.max(0) + 2 * d
    near = ss.boundary_x[np.all((ss.boundary_x >= lo) & (ss.boundary_x <= hi), axis=1)]
    if len(near) == 0:  # the fluid starts away from every wall (honey: a column in the air)
        return
    dist = min_distance(ss.fluid_x, near)
    assert dist.min() >= s.wall_gap * (1 - 1e-5)
    # and the first fluid layer is not much farther (the fluid lattice may be offset sideways from the wall lattice)
    assert dist.min() <= s.wall_gap + 0.5 * d


def test_builtin_counts():
    assert sample_scene(load_scene("dam_break")).fluid_count == 19**3  # flush with 3 walls
    assert sample_scene(load_scene("radial_expansion")).fluid_count == 11**3  # 0.5 / (0.9 d)


def test_container_walls_cover_six_faces_at_spacing_d():
    s = tank()
    ss = sample_scene(s)
    d = s.spacing
    b = ss.boundary_x.astype(np.float64)
    lo, hi = np.array(s.container.min), np.array(s.container.max)
    n = np.round((hi - lo) / d).astype(int)  # 12, 12, 20
    assert np.all(ss.boundary_object == -1)
    faces = 0
    for axis in range(3):
        a, c = [k for k in range(3) if k != axis]
        for plane in (lo[axis], hi[axis]):
            on = b[np.abs(b[:, axis] - plane) < 1e-6]
            expected = {(i, j) for i in range(n[a] + 1) for j in range(n[c] + 1)}
            got = {(int(round((p[a] - lo[a]) / d)), int(round((p[c] - lo[c]) / d))) for p in on}
            assert got == expected and len(on) == len(expected)
            faces += 1
    assert faces == 6
    # nothing off the walls, each point once, spacing d
    on_any = np.any((np.abs(b - lo) < 1e-6) | (np.abs(b - hi) < 1e-6), axis=1)
    assert on_any.all()
    assert len(b) == np.prod(n + 1) - np.prod(n - 1)
    np.testing.assert_allclose(nearest_neighbour(b), d, rtol=1e-5)
    # normals point into the container
    inward = (b + 0.1 * ss.boundary_normals)
    assert np.all((inward > lo) & (inward < hi))


def test_box_surface_nonmultiple_size_keeps_spacing_close_to_d():
    p, _ = box_surface((0, 0, 0), (1.02, 0.5, 0.33), 0.05, inward=False)
    nn = nearest_neighbour(p)
    assert np.all(np.abs(nn / 0.05 - 1.0) < 0.1)


@pytest.fixture
def cube_obj(tmp_path):
    path = tmp_path / "cube.obj"
    path.write_text(CUBE_OBJ)
    return path


def test_mesh_surface_sampling_of_unit_cube(cube_obj):
    mesh = load_triangle_mesh(cube_obj)
    assert mesh.triangles.shape == (12, 3)
    d = 0.05
    p, n = sample_surface(mesh, d)
    # on the surface: inside [0,1]^3 and on at least one face plane
    assert np.all((p > -1e-9) & (p < 1 + 1e-9))
    assert np.all(np.min(np.minimum(np.abs(p), np.abs(p - 1)), axis=1) < 1e-9)
    # a square lattice at spacing d on every face, each point once
    assert len(p) == 21**3 - 19**3
    np.testing.assert_allclose(nearest_neighbour(p), d, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)


def test_mesh_inside_test():
    rng = np.random.default_rng(1)
    tri_cube = unit_cube_mesh()
    q = rng.uniform(-0.5, 1.5, size=(2000, 3))
    inside = np.all((q > 0) & (q < 1), axis=1)
    assert np.array_equal(points_inside(tri_cube, q), inside)
    # orientation does not matter
    flipped = TriangleMesh(tri_cube.vertices, tri_cube.triangles[:, ::-1])
    assert np.array_equal(points_inside(flipped, q), inside)


def unit_cube_mesh():
    """The unit cube as 12 outward triangles; vertex index = x + 2 y + 4 z."""
    v = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float)
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (1, 3, 7, 5), (3, 2, 6, 7), (2, 0, 4, 6)]
    tris = [t for a, b, c, e in quads for t in ((a, b, c), (a, c, e))]
    return TriangleMesh(v, np.array(tris))


@pytest.mark.parametrize("translate,aligned", [([0.5, 0.5, 0.5], True), ([0.53, 0.47, 0.51], False)])
def test_mesh_obstacle_removes_fluid_inside(cube_obj, translate, aligned):
    r = 0.05
    d = 2 * r
    s = scene_from_dict({
        "particle_radius": r,
        "container": {"min": [0, 0, 0], "max": [2, 2, 2]},
        "fluid": [{"min": [0, 0, 0], "max": [2, 2, 2]}],
        "obstacles": [{"shape": "mesh", "file": str(cube_obj), "translate": translate}],
        "boundary_gap": 1.0,
    })
    ss = sample_scene(s)
    lo, hi = np.array(translate), np.array(translate) + 1.0
    ob = ss.boundary_x[ss.boundary_object == 0].astype(np.float64)
    # obstacle particles lie on the cube surface
    assert len(ob) > 0
    assert np.all((ob > lo - 1e-5) & (ob < hi + 1e-5))
    assert np.all(np.min(np.minimum(np.abs(ob - lo), np.abs(ob - hi)), axis=1) < 1e-5)
    # no fluid inside the cube, none within the gap of any boundary particle
    x = ss.fluid_x.astype(np.float64)
    assert not np.any(np.all((x > lo) & (x < hi), axis=1))
    assert min_distance(x, ss.boundary_x).min() >= s.wall_gap * (1 - 1e-5)
    if aligned:
        # oracle: the lattice 0.1 .. 1.9 minus the points closer than d to the solid cube
        k = d * np.arange(1, 20)
        g = np.stack(np.meshgrid(k, k, k, indexing="ij"), -1).reshape(-1, 3)
        dist_to_box = np.linalg.norm(np.maximum(np.maximum(lo - g, g - hi), 0.0), axis=1)
        assert ss.fluid_count == int(np.sum(dist_to_box >= d - 1e-9))
        assert len(ob) == 11**3 - 9**3


def test_spacing_scale_packs_tighter():
    s = scene_from_dict({"container": False, "fluid": [{"min": [0, 0, 0], "max": [0.45, 0.45, 0.45],
                                                        "spacing_scale": 0.9}]})
    ss = sample_scene(s)
    assert ss.fluid_count == 10**3  # 0.45 / (0.9 * 0.05)
    np.testing.assert_allclose(nearest_neighbour(ss.fluid_x), 0.9 * 0.05, rtol=1e-5)
    np.testing.assert_allclose(ss.fluid_x.min(0), 0.9 * 0.025, atol=1e-6)


def test_overlapping_blocks_have_no_duplicates():
    s = scene_from_dict({"container": False, "fluid": [
        {"min": [0, 0, 0], "max": [0.5, 0.5, 0.5]},
        {"min": [0.25, 0.25, 0.25], "max": [0.75, 0.75, 0.75], "velocity": [0, 0, -1]},
    ]})
    ss = sample_scene(s)
    assert nearest_neighbour(ss.fluid_x).min() >= 0.5 * s.spacing
    assert ss.fluid_count == 2 * 1000 - 125  # the shared 0.25^3 corner is sampled once
    assert np.all(ss.fluid_v[ss.fluid_block == 1] == [0, 0, -1])


def test_empty_fluid_is_an_error():
    s = scene_from_dict({"container": False, "fluid": [{"min": [0, 0, 0], "max": [0.03, 1, 1]}]}, source="tiny.toml")
    with pytest.raises(SceneError, match=r"^tiny\.toml: fluid: no fluid particle"):
        sample_scene(s)


def test_shipped_cylinder_obstacle():
    s = load_scene("obstacle")
    ss = sample_scene(s)
    cyl = ss.boundary_x[ss.boundary_object == 0].astype(np.float64) - np.array([1.6, 0.505, 0.0])
    rad = np.linalg.norm(cyl[:, :2], axis=1)
    on_side = np.abs(rad - 0.15) < 0.01  # the 16-gon's sides are within 1.2 mm of the circle
    on_cap = (np.abs(cyl[:, 2]) < 1e-6) | (np.abs(cyl[:, 2] - 0.6) < 1e-6)
    assert np.all(on_side | (on_cap & (rad <= 0.15 + 1e-6)))
    # where the bottom cap meets the floor's wall particles, no two boundary particles coincide
    near = ss.boundary_x[np.linalg.norm(ss.boundary_x[:, :2] - [1.6, 0.505], axis=1) < 0.3]
    assert nearest_neighbour(near).min() >= 0.5 * s.spacing - 1e-6
    nn = nearest_neighbour(cyl)
    assert nn.min() >= 0.8 * s.spacing - 1e-6 and np.median(nn) <= 1.2 * s.spacing
    x = ss.fluid_x.astype(np.float64) - np.array([1.6, 0.505, 0.0])
    assert not np.any((np.linalg.norm(x[:, :2], axis=1) < 0.15) & (x[:, 2] < 0.6))


def test_point_grid_matches_brute_force():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, size=(500, 3))
    q = rng.uniform(-1.2, 1.2, size=(300, 3))
    grid = PointGrid(pts, 0.2)
    got = grid.nearest_distance(q, 0.2)
    ref = min_distance(q, pts)
    ref[ref > 0.2] = np.inf
    np.testing.assert_allclose(got, ref)


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_usd_mesh_obstacle(tmp_path, suffix):
    from pxr import Gf, Usd, UsdGeom

    path = tmp_path / f"cube{suffix}"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)  # centimetres
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.Xform.Define(stage, "/root").AddTranslateOp().Set(Gf.Vec3d(10, 0, 0))
    mesh = UsdGeom.Mesh.Define(stage, "/root/cube")
    cube = unit_cube_mesh()
    mesh.CreatePointsAttr([Gf.Vec3f(*(100.0 * p)) for p in cube.vertices])
    # as quads, to exercise the triangulation
    quads = cube.triangles.reshape(6, 2, 3)
    mesh.CreateFaceVertexCountsAttr([4] * 6)
    mesh.CreateFaceVertexIndicesAttr([int(i) for q in quads for i in (q[0, 0], q[0, 1], q[0, 2], q[1, 2])])
    stage.GetRootLayer().Save()
    loaded = load_triangle_mesh(path)
    assert loaded.triangles.shape == (12, 3)
    lo, hi = loaded.bounds
    np.testing.assert_allclose(lo, [0.1, 0, 0], atol=1e-6)  # 10 cm translate, 100 cm cube
    np.testing.assert_allclose(hi, [1.1, 1, 1], atol=1e-6)
    q = np.random.default_rng(2).uniform(-0.5, 1.5, size=(500, 3))
    assert np.array_equal(points_inside(loaded, q), np.all((q > lo) & (q < hi), axis=1))
