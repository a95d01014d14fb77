"""Smoothing kernels: normalisation, symmetry, support, gradients, calibrated rest density."""
import numpy as np
import pytest
import warp as wp

from warp_sph.kernels.neighbors import NoBoundaryParams

from sph_oracle import W as W_ref, grad_W as grad_ref
from warp_sph.core import smoothing
from warp_sph.kernels import density as density_dev
from warp_sph.neighbors import NeighborGrid

NAMES = list(smoothing.SMOOTHING_KERNELS)
H = 0.1


@pytest.mark.parametrize("name", NAMES)
def test_matches_oracle(name):
    rng = np.random.default_rng(1)
    k = smoothing.get_smoothing_kernel(name)
    x = rng.uniform(-1, 1, (2000, 3)) * k.support_radius(H) * 0.8
    w, g = smoothing.evaluate(name, x, H)
    r = np.linalg.norm(x, axis=1)
    np.testing.assert_allclose(w, W_ref(name, r, H), rtol=2e-5, atol=1e-5 * W_ref(name, 0.0, H))
    gref = grad_ref(name, x, H)
    scale = np.abs(gref).max()
    np.testing.assert_allclose(g, gref, rtol=1e-4, atol=1e-5 * scale)


@pytest.mark.parametrize("name", NAMES)
def test_normalisation(name):
    """4 pi int_0^Hs r^2 W(r) dr = 1 within 1e-3 (Simpson on the device values)."""
    k = smoothing.get_smoothing_kernel(name)
    hs = k.support_radius(H)
    r = np.linspace(0.0, hs, 4001)
    w, _ = smoothing.evaluate(name, np.stack([r, 0 * r, 0 * r], axis=1), H)
    y = 4 * np.pi * r**2 * w.astype(np.float64)
    dr = r[1] - r[0]
    integral = dr / 3 * (y[0] + y[-1] + 4 * y[1:-1:2].sum() + 2 * y[2:-1:2].sum())
    assert abs(integral - 1.0) < 1e-3, integral


def test_quintic_uses_exact_constant():
    """alpha_3D = 1/(120 pi h^3), not the printed 3/(359 pi h^3) (0.28 % too large)."""
    w, _ = smoothing.evaluate("quintic", np.zeros((1, 3)), H)
    f0 = 3**5 - 6 * 2**5 + 15
    assert w[0] == pytest.approx(f0 / (120 * np.pi * H**3), rel=1e-6)
    assert abs(w[0] / (3 * f0 / (359 * np.pi * H**3)) - 1) > 2e-3


@pytest.mark.parametrize("name", NAMES)
def test_symmetry_and_nonnegativity(name):
    rng = np.random.default_rng(2)
    k = smoothing.get_smoothing_kernel(name)
    x = rng.uniform(-1, 1, (1000, 3)) * k.support_radius(H)
    w1, g1 = smoothing.evaluate(name, x, H)
    w2, g2 = smoothing.evaluate(name, -x, H)
    np.testing.assert_array_equal(w1, w2)
    np.testing.assert_allclose(g1, -g2, rtol=0, atol=0)
    w0 = smoothing.evaluate(name, np.zeros((1, 3)), H)[0][0]
    if name == "quadric":
        # The published quadric (Liu, Liu & Lam 2003) has a shallow negative lobe for
        # 1.6957 h < r < 2h: f = -5/32 (R-2)^2 (R^2 - 16/15 R - 16/15), min f(1.8) = -0.00158
        # (-0.24 % of W(0)). We keep the published, exactly normalised formula and bound the lobe.
        r = np.linalg.norm(x, axis=1)
        assert (w1[r < 1.69 * H] >= 0).all()
        assert w1.min() >= -0.0024 * w0
        assert w1.min() < 0  # the lobe is real: this documents it rather than hiding it
    else:
        assert (w1 >= 0).all()


@pytest.mark.parametrize("name", NAMES)
def test_compact_support_and_continuity(name):
    k = smoothing.get_smoothing_kernel(name)
    hs = k.support_radius(H)
    d = np.array([[hs, 0, 0], [0, hs * 1.0001, 0], [0, 0, 2 * hs], [hs * 1.0001 / np.sqrt(3)] * 3])
    w, g = smoothing.evaluate(name, d, H)
    assert np.all(w == 0) and np.all(g == 0)
    # approaching the edge, value and gradient go to zero continuously
    w0, g0 = smoothing.evaluate(name, np.zeros((1, 3)) + [[1e-6, 0, 0]], H)
    near, gnear = smoothing.evaluate(name, np.array([[hs * (1 - 1e-3), 0, 0], [hs * (1 - 1e-4), 0, 0]]), H)
    gmax = np.abs(smoothing.evaluate(name, np.linspace(0, hs, 200)[:, None] * [[1, 0, 0]], H)[1]).max()
    assert np.abs(near).max() < 1e-6 * w0[0]
    gn = np.linalg.norm(gnear, axis=1)
    assert gn[0] < 2e-3 * gmax and gn[1] < 0.2 * gn[0] + 1e-7 * gmax


@pytest.mark.parametrize("name", NAMES)
def test_gradient_against_central_differences(name):
    """Report eq. 1, in float64 on the oracle W, compared with the device gradient (rel < 1e-3)."""
    rng = np.random.default_rng(3)
    k = smoothing.get_smoothing_kernel(name)
    hs = k.support_radius(H)
    dirs = rng.normal(size=(500, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    radii = rng.uniform(0.05 * H, hs * 0.98, 500)
    x = dirs * radii[:, None]
    _, g = smoothing.evaluate(name, x, H)
    eps = 1e-6 * H
    fd = np.zeros_like(x)
    for a in range(3):
        e = np.zeros(3)
        e[a] = eps
        fd[:, a] = (W_ref(name, np.linalg.norm(x + e, axis=1), H) - W_ref(name, np.linalg.norm(x - e, axis=1), H)) / (2 * eps)
    err = np.linalg.norm(g - fd, axis=1) / np.maximum(np.linalg.norm(fd, axis=1), 1e-12)
    big = np.linalg.norm(fd, axis=1) > 1e-3 * np.linalg.norm(fd, axis=1).max()
    assert err[big].max() < 1e-3


@pytest.mark.parametrize("name", NAMES)
def test_gradient_zero_at_origin(name):
    _, g = smoothing.evaluate(name, np.zeros((1, 3)), H)
    assert np.all(g == 0) and np.all(np.isfinite(g))


@pytest.mark.parametrize("name", NAMES)
def test_support_is_search_radius_and_default_h(name):
    k = smoothing.get_smoothing_kernel(name)
    d = 0.05
    h = k.default_smoothing_length(d)
    # same support (2d) for every kernel: comparable neighbour counts
    assert k.support_radius(h) == pytest.approx(2 * d)
    assert len(smoothing.lattice_offsets(d, k.support_radius(h))) == 27


def test_unknown_kernel_name():
    from warp_sph.core.errors import SceneError

    with pytest.raises(SceneError, match="cubic"):
        smoothing.get_smoothing_kernel("gaussian")


@pytest.mark.parametrize("name", NAMES)
def test_rest_lattice_density(name, device):
    """The density stage kernel gives rho0 within 0.1 % for an interior particle of a perfect lattice
    with the calibrated mass (report 7.3), for every kernel."""
    d = 0.04
    k = smoothing.get_smoothing_kernel(name)
    h = k.default_smoothing_length(d)
    rho0 = 1000.0
    m = smoothing.calibrated_mass(name, h, d, rho0)
    n = 9
    g = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3) * d - 3.3
    x = wp.array(g.astype(np.float32), dtype=wp.vec3, device=device)
    grid = NeighborGrid(k.support_radius(h), device=device)
    grid.build(x)
    rho = wp.zeros(len(g), dtype=float, device=device)
    empty = wp.zeros(0, dtype=wp.vec3, device=device)
    wp.launch(density_dev.density_kernel(name, None), dim=len(g),
              inputs=[0, m, h, k.support_radius(h), rho0, NoBoundaryParams(), wp.uint64(0), empty,
                      wp.zeros(0, dtype=float, device=device), grid.id, x],
              outputs=[rho], device=device)
    centre = np.argmin(np.linalg.norm(g - g.mean(0), axis=1))
    assert rho.numpy()[centre] == pytest.approx(rho0, rel=1e-3)
    # and the calibration is not a no-op: mass differs from rho0 d^3 by the lattice bias
    assert m * smoothing.lattice_sum(name, h, d) == pytest.approx(rho0, rel=1e-12)
