"""Surface reconstruction: closed, outward, welded meshes of the right volume; field vs a NumPy oracle."""
import math

import numpy as np
import pytest
import warp as wp

from warp_sph.core.smoothing import calibrated_mass, evaluate, get_smoothing_kernel
from warp_sph.surface import DEFAULT_CELL_PER_RADIUS, DEFAULT_ISO_LEVEL, SurfaceReconstructor

REST_DENSITY = 1000.0
R_SPHERE = 0.3
RADIUS = 0.02
SPACING = 2.0 * RADIUS
METHODS = ["marching_cubes", "surface_nets"]


def lattice_sphere(center=(0.0, 0.0, 0.0), radius=R_SPHERE, spacing=SPACING):
    n = int(math.ceil(radius / spacing)) + 1
    k = np.arange(-n, n + 1)
    p = np.stack(np.meshgrid(k, k, k, indexing="ij"), axis=-1).reshape(-1, 3) * spacing
    p = p[np.linalg.norm(p, axis=1) < radius]
    return p + np.asarray(center, dtype=np.float64)


def reconstructor(method="marching_cubes", smoothing="cubic", **kw):
    kernel = get_smoothing_kernel(smoothing)
    h = kernel.default_smoothing_length(SPACING)
    mass = calibrated_mass(smoothing, h, SPACING, REST_DENSITY)
    return SurfaceReconstructor(smoothing, h, mass, RADIUS, DEFAULT_CELL_PER_RADIUS * RADIUS,
                                DEFAULT_ISO_LEVEL, device="cpu", method=method, **kw)


def extract(recon, points):
    x = wp.array(np.asarray(points, dtype=np.float32), dtype=wp.vec3, device="cpu")
    rho = wp.full(len(points), REST_DENSITY, dtype=float, device="cpu")
    return recon.extract(x, rho)


def edge_counts(tris):
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    _, counts = np.unique(np.sort(e, axis=1), axis=0, return_counts=True)
    return counts


def signed_volume(verts, tris, origin):
    v = verts.astype(np.float64) - origin
    return float(np.einsum("ij,ij->i", v[tris[:, 0]], np.cross(v[tris[:, 1]], v[tris[:, 2]])).sum() / 6.0)


def check_closed_outward(verts, tris, center):
    assert verts.dtype == np.float32 and verts.ndim == 2 and verts.shape[1] == 3
    assert tris.dtype == np.int32 and tris.ndim == 2 and tris.shape[1] == 3
    assert len(tris) > 100
    assert tris.min() >= 0 and tris.max() < len(verts)
    # no triangle repeats a vertex, none has zero area, every vertex is used
    assert np.all((tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2]))
    v = verts.astype(np.float64) - center
    normal = np.cross(v[tris[:, 1]] - v[tris[:, 0]], v[tris[:, 2]] - v[tris[:, 0]])
    assert np.all(np.linalg.norm(normal, axis=1) > 0.0)
    assert len(np.unique(tris)) == len(verts)
    # welded and watertight: every undirected edge in exactly two triangles
    counts = edge_counts(tris)
    assert np.all(counts == 2), f"{np.sum(counts != 2)} edges not shared by exactly two triangles"
    # and consistently oriented: every directed edge appears once
    directed = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    assert len(np.unique(directed, axis=0)) == len(directed)
    # outward: positive signed volume, triangle normals point away from the centre
    assert signed_volume(verts, tris, center) > 0.0
    centroid = v[tris].mean(axis=1)
    outward = np.einsum("ij,ij->i", normal, centroid) > 0.0
    assert outward.mean() > 0.99


@pytest.mark.parametrize("method", METHODS)
def test_sphere_closed_outward_volume(method):
    points = lattice_sphere()
    verts, tris = extract(reconstructor(method), points)
    check_closed_outward(verts, tris, np.zeros(3))
    exact = 4.0 / 3.0 * math.pi * R_SPHERE**3
    volume = signed_volume(verts, tris, np.zeros(3))
    assert abs(volume / exact - 1.0) < 0.05, f"volume {volume:.5f} vs {exact:.5f}"
    # the surface lies near the sphere: vertex radii within a particle spacing of R
    radius = np.linalg.norm(verts.astype(np.float64), axis=1)
    assert np.all(np.abs(radius - R_SPHERE) < SPACING)


@pytest.mark.parametrize("method", METHODS)
def test_grid_follows_particles(method):
    """A blob far from the origin: the grid hugs the particles and the mesh is unchanged."""
    center = np.array([50.0, -20.0, 3.0])
    recon = reconstructor(method)
    verts0, tris0 = extract(recon, lattice_sphere(radius=0.15))
    shape0 = recon.grid_shape
    verts, tris = extract(recon, lattice_sphere(center, radius=0.15))
    margin = recon.support_radius + recon.grid_cell_size
    assert recon.grid_shape == shape0
    assert np.all(np.abs(recon.grid_origin - (center - 0.14 - margin)) < 2 * SPACING)
    assert np.prod(recon.grid_shape) < 100**3
    check_closed_outward(verts, tris, center)
    assert len(tris) == pytest.approx(len(tris0), rel=0.02)
    assert signed_volume(verts, tris, center) == pytest.approx(signed_volume(verts0, tris0, np.zeros(3)), rel=0.01)
    # same mesh up to the shift (grid placed relative to the particles, so equally aligned)
    shift = verts.astype(np.float64).mean(axis=0) - verts0.astype(np.float64).mean(axis=0)
    assert np.allclose(shift, center, atol=1e-3)


def numpy_cubic(r, h):
    q = r / h
    a = 3.0 / (2.0 * math.pi * h**3)
    return a * np.where(q < 1.0, 2.0 / 3.0 - q * q + 0.5 * q**3, np.where(q < 2.0, (2.0 - np.minimum(q, 2.0)) ** 3 / 6.0, 0.0))


@pytest.mark.parametrize("smoothing", ["cubic", "quintic", "quadric"])
def test_field_matches_bruteforce(smoothing):
    rng = np.random.default_rng(7)
    points = rng.uniform(-0.1, 0.1, size=(300, 3)) + np.array([0.3, -0.2, 0.5])
    density = rng.uniform(800.0, 1200.0, size=300)
    recon = reconstructor(smoothing=smoothing)
    x = wp.array(points.astype(np.float32), dtype=wp.vec3, device="cpu")
    rho = wp.array(density.astype(np.float32), dtype=float, device="cpu")
    field = recon.compute_field(x, rho).numpy()
    assert field.shape == recon.grid_shape
    # every node of the outer layer is beyond the support of every particle
    for axis in range(3):
        assert np.all(np.take(field, [0, -1], axis=axis) == 0.0)
    idx = np.argwhere(field >= 0.0)
    picks = np.concatenate([idx[rng.choice(len(idx), 40, replace=False)], [np.unravel_index(field.argmax(), field.shape)]])
    nodes = recon.grid_origin + picks * recon.grid_cell_size
    dist = np.linalg.norm(nodes[:, None, :] - points[None, :, :], axis=-1)
    if smoothing == "cubic":
        w = numpy_cubic(dist, recon.h)
    else:  # the smoothing functions have their own tests; this checks the splat loop
        w = evaluate(smoothing, np.stack([dist.ravel(), 0 * dist.ravel(), 0 * dist.ravel()], 1), recon.h)[0]
        w = w.reshape(dist.shape).astype(np.float64)
    oracle = (recon.particle_mass / density[None, :] * w).sum(axis=1)
    got = field[tuple(picks.T)]
    assert oracle.max() > 0.5
    np.testing.assert_allclose(got, oracle, rtol=1e-4, atol=1e-5)


def test_empty_and_coarsened_grid():
    recon = reconstructor()
    verts, tris = extract(recon, np.zeros((0, 3)))
    assert verts.shape == (0, 3) and tris.shape == (0, 3)
    small = reconstructor(max_grid_nodes=20**3)
    with pytest.warns(RuntimeWarning, match="coarsened"):
        verts, tris = extract(small, lattice_sphere(radius=0.2))
    assert np.prod(small.grid_shape) <= 20**3
    assert small.grid_cell_size > small.cell_size
    assert len(tris) > 0 and signed_volume(verts, tris, np.zeros(3)) > 0.0


@pytest.mark.parametrize("method", METHODS)
def test_ties_at_nodes_are_welded(method):
    """A field that equals the iso level exactly on whole layers of nodes (ties the extractors turn
    into coincident vertices and zero-area triangles) still gives a closed, clean, outward mesh."""
    field = np.zeros((12, 12, 12), np.float32)
    field[3:9, 3:9, 3:9] = DEFAULT_ISO_LEVEL
    field[4:8, 4:8, 4:8] = 1.0
    field[5, 2, 5] = DEFAULT_ISO_LEVEL
    recon = reconstructor(method)
    recon.grid_shape, recon.grid_origin, recon.grid_cell_size = field.shape, np.zeros(3), 1.0
    import warp.geometry

    extractor = {"marching_cubes": warp.geometry.IsoSurfaceMarchingCubes, "surface_nets": warp.geometry.IsoSurfaceNets}[method]
    raw_verts, raw_indices = extractor.extract(wp.array(field, dtype=float, device="cpu"), DEFAULT_ISO_LEVEL)
    verts, tris = recon._finish(raw_verts.numpy(), raw_indices.numpy())
    check_closed_outward(verts, tris, np.full(3, 5.5))


def test_non_finite_positions_raise():
    from warp_sph.core.errors import SimulationError

    points = lattice_sphere(radius=0.1)
    points[3] = np.nan
    with pytest.raises(SimulationError, match="not finite"):
        extract(reconstructor(), points)
