"""Surface reconstruction: oracles for the particle statistics, the field and marching cubes, and
quality as numbers (notes/surface.md section 7) on a pool, a sphere, thin sheets and spray."""
import math

import numpy as np
import pytest
import warp as wp
import warp.geometry

from surface_metrics import (RADIUS, SPACING, components, distance_to_mesh, euler_characteristic, is_closed_manifold,
                             lattice_box, lattice_sphere, mean_curvature_radius, plane_fit_rms, volume)
from warp_sph.core.errors import SimulationError
from warp_sph.core.smoothing import get_smoothing_kernel
from warp_sph.surface import SurfaceReconstructor, surface_settings
from warp_sph.surface.band import classify
from warp_sph.surface.decimation import Decimator
from warp_sph.surface.field import compute_field
from warp_sph.surface.grid import lattice_weighted_count

H = get_smoothing_kernel("cubic").default_smoothing_length(SPACING)  # h = d: support R = 2h = 4 r
SUPPORT = 2.0 * H


def defaults(**overrides) -> dict:
    """The scene defaults (output.surface_*), as the run uses them."""
    from warp_sph.scene import OutputParams

    kw = surface_settings(OutputParams(), RADIUS)
    kw.update(overrides)
    return kw


def reconstructor(device="cpu", **overrides):
    kw = defaults(**overrides)
    return SurfaceReconstructor("cubic", H, RADIUS, device=device, **kw)


def reconstruct(rec, points):
    return rec.reconstruct(wp.array(np.asarray(points, dtype=np.float32), dtype=wp.vec3, device=rec.device))


def field_kernel(r2):
    return np.maximum(1.0 - r2 / SUPPORT**2, 0.0) ** 5


# -- oracles ------------------------------------------------------------------------------------
def blob_with_spray(seed=3):
    """A jittered ball, a pair and a lone particle (spray), a line of three (spray), a block of 27."""
    rng = np.random.default_rng(seed)
    ball = lattice_sphere(6.0, jitter=0.3, seed=seed)
    extra = [np.array([[14.0, 0, 0]]) * RADIUS,                                   # lone
             np.array([[0, 14.0, 0], [0, 16.0, 0]]) * RADIUS,                     # pair
             np.array([[0, 0, 14.0], [0, 0, 16.0], [0, 0, 18.0]]) * RADIUS,       # line of 3
             lattice_box(3, 3, 3, jitter=0.05) + np.array([-20.0, -20.0, -20.0]) * RADIUS]  # 27: meshed
    return np.concatenate([ball] + extra) + rng.uniform(-1e-3, 1e-3, 3)


def test_particle_statistics_and_field_match_numpy():
    points = blob_with_spray()
    rec = reconstructor(narrow_band=False)
    grid = rec.grid
    grid.build(wp.array(points.astype(np.float32), dtype=wp.vec3))
    n = len(points)
    order = grid.sorted_index.numpy()[:n]
    d2 = ((points[:, None, :] - points[None, :, :]) ** 2).sum(-1)
    inside = d2 < SUPPORT**2
    count = inside.sum(1) - 1
    wnn = np.where(inside, 1.0 - d2 / SUPPORT**2, 0.0).sum(1) - 1.0
    rho = np.where(inside, field_kernel(d2), 0.0).sum(1)
    sure = np.all(np.abs(np.sqrt(d2) - SUPPORT) > 1e-5 * SUPPORT, axis=1)  # no pair at R within float32 rounding
    assert sure.mean() > 0.9
    np.testing.assert_array_equal(grid.neighbor_count.numpy()[:n][sure[order]], count[order][sure[order]])
    np.testing.assert_allclose(grid.weighted_count.numpy()[:n], wnn[order], rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(grid.kernel_sum.numpy()[:n], rho[order], rtol=1e-4)
    spray = count < 5
    assert spray.sum() == 6  # the lone particle, the pair, the line of three
    np.testing.assert_array_equal(grid.spray_mask(), spray)
    # Phi = sum_j f_j / rho~_j over the non-spray particles, at every node of every band block
    classify(grid, exact=True)
    field = compute_field(grid).numpy()
    b = grid.block_nodes
    meshed = grid.meshed_block.numpy()[: grid.meshed_count]
    band = grid.meshed_band.numpy()[: grid.meshed_count].astype(bool)
    coords = grid.block_coord.numpy()[meshed[band]]
    local = np.stack(np.meshgrid(*[np.arange(b)] * 3, indexing="ij"), -1).reshape(-1, 3)
    nodes = (coords[:, None, :] * b + local[None]).reshape(-1, 3)
    values = field.reshape(-1, b**3)[: grid.meshed_count][band].reshape(-1)
    pick = np.random.default_rng(0).choice(len(nodes), min(3000, len(nodes)), replace=False)
    x = grid.grid_origin + nodes[pick] * grid.cell_size
    keep = ~spray
    oracle = (field_kernel(((x[:, None, :] - points[None, keep]) ** 2).sum(-1)) / rho[keep][None, :]).sum(1)
    assert oracle.max() > 0.9 and oracle.min() == 0.0
    np.testing.assert_allclose(values[pick], oracle, rtol=2e-4, atol=2e-5)


def test_marching_cubes_matches_warp_on_the_same_field():
    """The sparse marching cubes gives exactly the triangles of Warp's dense IsoSurfaceMarchingCubes."""
    points = blob_with_spray()
    rec = reconstructor(narrow_band=False)
    grid, mc = rec.grid, rec.marching
    grid.build(wp.array(points.astype(np.float32), dtype=wp.vec3))
    classify(grid, exact=True)
    compute_field(grid)
    assert mc.count(grid, rec.iso_level) == 0
    vx, _, tris = mc.extract(grid, rec.iso_level)
    # the same nodes as one dense array (nodes of unmeshed blocks: Phi = 0, no particle within R)
    b = grid.block_nodes
    meshed = grid.meshed_block.numpy()[: grid.meshed_count]
    coords = grid.block_coord.numpy()[meshed]
    lo, hi = coords.min(0) * b, (coords.max(0) + 1) * b
    dense = np.zeros(tuple(hi - lo + 1), np.float32)
    field = grid.field.numpy()[: grid.meshed_count * b**3].reshape(-1, b, b, b)
    for c, block in zip(coords, field):
        o = c * b - lo
        dense[o[0]:o[0] + b, o[1]:o[1] + b, o[2]:o[2] + b] = block
    wv, wi = warp.geometry.IsoSurfaceMarchingCubes.extract(wp.array(dense, dtype=float), rec.iso_level)
    ours_g = (vx.numpy().astype(np.float64) - grid.grid_origin) / grid.cell_size - lo  # grid units
    warp_g = wv.numpy().astype(np.float64)
    assert len(ours_g) == len(warp_g)
    # match every vertex to Warp's nearest (ours went through float32 metres: ~1e-6 grid units off)
    nearest = np.empty(len(ours_g), np.int64)
    for s in range(0, len(ours_g), 512):
        d = np.linalg.norm(ours_g[s:s + 512, None, :] - warp_g[None, :, :], axis=-1)
        nearest[s:s + 512] = d.argmin(axis=1)
        assert d.min(axis=1).max() < 1e-4
    assert len(np.unique(nearest)) == len(nearest)  # a one-to-one map
    ours_t = nearest[tris.numpy().reshape(-1, 3)]
    warp_t = wi.numpy().reshape(-1, 3)[:, ::-1]  # Warp winds for "inside below the level"

    def canon(t):  # each triangle rotated to start at its smallest index (keeps the winding)
        t = np.asarray(t)
        k = t.argmin(axis=1)
        r = np.stack([t[np.arange(len(t)), (k + i) % 3] for i in range(3)], axis=1)
        return r[np.lexsort(r.T[::-1])]

    np.testing.assert_array_equal(canon(ours_t), canon(warp_t))


def test_narrow_band_gives_the_exact_mesh(device):
    """Phi on the narrow band only: the same mesh as Phi on every block a particle's support reaches,
    with fewer blocks evaluated; the slab split of the GPU gives the same field on the CPU too."""
    points = np.concatenate([lattice_box(20, 16, 12, jitter=0.3, seed=5),
                             lattice_sphere(4.0, 0.2, center=(16 * RADIUS, 10 * RADIUS, 40 * RADIUS))])
    raw = dict(smoothing_iterations=0, decimation=None, normals=False, cell_size=0.5 * RADIUS)
    band = reconstruct(reconstructor(device, **raw), points)
    exact = reconstruct(reconstructor(device, narrow_band=False, **raw), points)
    assert band.stats["band_fallback"] == 0
    assert band.stats["band_blocks"] < exact.stats["band_blocks"]
    np.testing.assert_array_equal(np.sort(band.vertices.view("f4,f4,f4"), axis=0),
                                  np.sort(exact.vertices.view("f4,f4,f4"), axis=0))
    assert len(band.triangles) == len(exact.triangles) and is_closed_manifold(band.triangles)
    if device == "cpu":
        rec = reconstructor(device, **raw)
        rec.grid.slabs = rec.grid.block_nodes  # a thread per node layer of a block, as on a GPU
        slabbed = reconstruct(rec, points)
        np.testing.assert_array_equal(slabbed.vertices, band.vertices)
        np.testing.assert_array_equal(slabbed.triangles, band.triangles)


# -- quality as numbers -----------------------------------------------------------------------------
def test_sphere_watertight_outward_volume_curvature(device):
    points = lattice_sphere(15.0, jitter=0.1)
    frame = reconstruct(reconstructor(device), points)  # the run's defaults: cells of 2 r, smoothed
    v, t = frame.vertices, frame.triangles
    assert not frame.spray.any()
    assert is_closed_manifold(t) and len(np.unique(components(t, len(v)))) == 1
    fluid = len(points) * SPACING**3
    radius = (3.0 * fluid / (4.0 * math.pi)) ** (1.0 / 3.0)
    assert volume(v, t) > 0.0 and abs(volume(v, t) / fluid - 1.0) < 0.01  # measured +0.7 %
    assert abs(mean_curvature_radius(v, t) / radius - 1.0) < 0.03  # measured -0.6 % (raw mesh: -51 %)
    center = v.astype(np.float64).mean(0)
    radial = np.linalg.norm(v - center, axis=1)
    assert radial.std() < 0.3 * RADIUS  # the decimation bound (0.3 r); measured 0.26 r (0.13 r undecimated)
    outward = np.einsum("ij,ij->i", frame.normals, (v - center) / radial[:, None])
    assert np.all(outward > 0.9)


@pytest.mark.parametrize("jitter", [0.1, 0.2])
def test_pool_at_rest_is_flat_after_smoothing(jitter):
    """Top of a pool (24 x 24 x 6 particles, lattice jittered by up to `jitter` r): rms from a plane
    below 0.05 r after smoothing, smaller than before, and no vertex farther than r from the raw surface."""
    points = lattice_box(24, 24, 6, jitter=jitter)
    raw = reconstruct(reconstructor(smoothing_iterations=0, decimation=None), points)
    smooth = reconstruct(reconstructor(decimation=None), points)
    final = reconstruct(reconstructor(), points)
    top_z = points[:, 2].max()

    def top_rms(frame, least=100):
        v = frame.vertices.astype(np.float64)
        margin = 4 * SPACING  # 4 spacings from the pool's edges
        sel = (v[:, 2] > top_z) & np.all(v[:, :2] > margin, axis=1) & np.all(v[:, :2] < 23 * SPACING - margin, axis=1)
        assert sel.sum() > least
        return plane_fit_rms(v[sel])[0] / RADIUS

    before, after, decimated = top_rms(raw), top_rms(smooth), top_rms(final, least=10)
    assert after < 0.05 and after < 0.6 * before  # measured 0.050 -> 0.020 r (jitter 0.1), 0.10 -> 0.035 r (0.2)
    assert decimated < 0.05
    dist = distance_to_mesh(smooth.vertices, raw.vertices, raw.triangles, reach=2.0 * RADIUS)
    assert dist.max() < RADIUS  # measured 0.78 r, at the pool's edges


def test_perfect_lattice_gives_a_flat_raw_surface():
    """No lattice ridges from the field: the raw top of a perfect lattice is flat to 0.02 r."""
    points = lattice_box(24, 24, 4)
    raw = reconstruct(reconstructor(smoothing_iterations=0, decimation=None), points)
    v = raw.vertices.astype(np.float64)
    sel = (v[:, 2] > points[:, 2].max()) & np.all(v[:, :2] > 8 * SPACING, axis=1) & np.all(v[:, :2] < 15 * SPACING, axis=1)
    rms, _ = plane_fit_rms(v[sel])
    assert rms < 0.02 * RADIUS  # measured 0.012 r
    assert abs(v[sel, 2].mean() - points[:, 2].max() - RADIUS) < 0.1 * RADIUS  # the level lies r above the top layer


@pytest.mark.parametrize("spacing_in_r", [2.0, 2.6])
def test_two_layer_sheet_survives(spacing_in_r):
    points = lattice_box(20, 20, 2) * spacing_in_r / 2.0
    frame = reconstruct(reconstructor(), points)
    v, t = frame.vertices, frame.triangles
    assert not frame.spray.any()
    assert is_closed_manifold(t) and euler_characteristic(v, t) == 2  # one closed sheet, no hole
    assert len(np.unique(components(t, len(v)))) == 1
    area = np.ptp(points[:, 0]) * np.ptp(points[:, 1])
    assert 1.5 * SPACING < volume(v, t) / area < 3.0 * SPACING  # thickness: measured 4.3 r / 5.1 r


def test_lone_particle_becomes_spray_not_mesh():
    block = lattice_box(8, 8, 8, jitter=0.1)
    lone = np.array([[30.0, 30.0, 30.0]]) * RADIUS
    with_spray = reconstruct(reconstructor(), np.concatenate([block, lone]))
    alone = reconstruct(reconstructor(), block)
    np.testing.assert_array_equal(np.flatnonzero(with_spray.spray), [len(block)])
    assert len(np.unique(components(with_spray.triangles, len(with_spray.vertices)))) == 1
    np.testing.assert_array_equal(with_spray.vertices, alone.vertices)  # spray leaves the mesh untouched
    every = reconstruct(reconstructor(spray_neighbors=0), np.concatenate([block, lone]))
    assert not every.spray.any() and len(np.unique(components(every.triangles, len(every.vertices)))) == 2


def test_decimation_budget_and_error_bound():
    points = lattice_sphere(12.0, jitter=0.1)
    cell = dict(cell_size=RADIUS)  # fine cells: many edges far below the 0.1 r bound
    full = reconstruct(reconstructor(decimation=None, **cell), points)
    budget = len(full.triangles) // 4
    cut = reconstruct(reconstructor(decimation=Decimator(triangle_budget=budget, length_scale=RADIUS), **cell), points)
    assert 0.7 * budget < len(cut.triangles) <= budget and is_closed_manifold(cut.triangles)
    bound = reconstruct(reconstructor(decimation=Decimator(max_error=0.1 * RADIUS), **cell), points)
    assert len(bound.triangles) < 0.6 * len(full.triangles) and is_closed_manifold(bound.triangles)
    # merged vertices stay within the bound of the planes they replace, so near the smoothed surface
    dist = distance_to_mesh(bound.vertices, full.vertices, full.triangles, reach=2.0 * RADIUS)
    assert dist.max() < 0.1 * RADIUS
    assert abs(volume(bound.vertices, bound.triangles) / volume(full.vertices, full.triangles) - 1.0) < 0.005


# -- bookkeeping -----------------------------------------------------------------------------------
def test_surface_moves_with_the_particles():
    """A ball far from the origin: the grid follows the particles; the same mesh, shifted."""
    ball = lattice_sphere(6.0, jitter=0.2)
    shift = np.array([50.0, -20.0, 3.0])
    a = reconstruct(reconstructor(decimation=None), ball)
    b = reconstruct(reconstructor(decimation=None), ball + shift)
    assert len(a.triangles) == pytest.approx(len(b.triangles), rel=0.05)
    assert volume(b.vertices, b.triangles) == pytest.approx(volume(a.vertices, a.triangles), rel=0.01)
    np.testing.assert_allclose(b.vertices.astype(np.float64).mean(0) - shift, a.vertices.mean(0), atol=1e-3)


def test_bitwise_the_same_mesh_on_any_thread_count(monkeypatch):
    """Surface kernels split over CPU threads write only their own indices: 1 or 3 threads (every
    split launch cut into ranges of 16 indices, so that this small scene splits everywhere) give
    bitwise the same mesh, normals and spray, with and without decimation."""
    import warp_sph.surface.grid as grid_module

    original = grid_module._launch_module.launch
    points = np.concatenate([blob_with_spray(), lattice_sphere(12.0, 0.3, center=(40 * RADIUS, 0.0, 0.0))])
    res = {}
    for threads in ("1", "3"):
        monkeypatch.setenv("WARP_SPH_CPU_THREADS", threads)
        monkeypatch.setattr(grid_module._launch_module, "launch",
                            lambda k, dim, inputs, outputs=(), device=None, min_range=0:
                            original(k, dim, inputs, outputs, device=device, min_range=16))
        for name, kw in (("smoothed", {}), ("decimated", {"decimation": Decimator(0.3 * RADIUS, length_scale=RADIUS)})):
            rec = reconstructor(**kw)
            reconstruct(rec, points)  # first launch of each kernel: one range (it loads the module)
            f = reconstruct(rec, points)
            res[threads, name] = (f.vertices.copy(), f.triangles.copy(), f.normals.copy(), f.spray.copy())
    for name in ("smoothed", "decimated"):
        assert len(res["1", name][1]) > 500
        for a, b in zip(res["1", name], res["3", name]):
            assert np.array_equal(a, b)


def test_empty_all_spray_and_non_finite():
    rec = reconstructor()
    empty = reconstruct(rec, np.zeros((0, 3)))
    assert empty.vertices.shape == (0, 3) and empty.triangles.shape == (0, 3) and empty.spray.shape == (0,)
    pair = reconstruct(rec, np.array([[0.0, 0.0, 0.0], [SPACING, 0.0, 0.0]]))
    assert pair.spray.all() and len(pair.triangles) == 0
    points = lattice_sphere(4.0)
    points[3] = np.nan
    with pytest.raises(SimulationError, match="not finite"):
        reconstruct(rec, points)


def test_surface_particles_threshold_sits_between_the_layers():
    """The surface class (weighted count below 0.85 of a full lattice's) catches the outer layer of a
    flat free surface and not the second one."""
    full = lattice_weighted_count(SUPPORT, SPACING)
    assert full == pytest.approx(12.5)
    points = lattice_box(12, 12, 6)
    rec = reconstructor()
    rec.grid.build(wp.array(points.astype(np.float32), dtype=wp.vec3))
    n = len(points)
    order = rec.grid.sorted_index.numpy()[:n]
    flag = np.empty(n, np.int32)
    flag[order] = rec.grid.particle_flag.numpy()[:n]
    top = points[:, 2] == points[:, 2].max()
    second = np.isclose(points[:, 2], points[:, 2].max() - SPACING)
    inner = np.all((points[:, :2] > 3 * SPACING) & (points[:, :2] < 8 * SPACING), axis=1)
    assert np.all(flag[top & inner] == 2) and np.all(flag[second & inner] == 1)


def test_array_pool_reuses_and_grows_by_half():
    """The one growable scratch array of the surface passes (core/buffers.py): the same array while it
    is large enough, else max(n, 1.5 x) rows; a width gives (rows, width)."""
    from warp_sph.core.buffers import ArrayPool

    pool = ArrayPool("cpu")
    a = pool.get("a", 10, wp.int32)
    assert a.shape == (10,) and pool.get("a", 7, wp.int32) is a
    assert pool.get("a", 11, wp.int32).shape == (15,)  # 1.5 x 10
    assert pool.get("a", 40, wp.int32).shape == (40,)  # more than 1.5 x 15: n itself
    assert pool.get("b", 0, wp.vec3, width=27).shape == (1, 27)
