"""benchmarks/hydrostatic_profile.py's "what moves" diagnostics (issue #31, the tank at rest): the lattice's column-slip
stiffness against the closed-form kernel Hessian, and the velocity-field measures against fields whose answer is
exact on a lattice."""
import numpy as np
import pytest

from benchmarks.hydrostatic_profile import _block_energy_share, _pair_correlations, lattice_slip_stiffness, motion
from warp_sph.core.smoothing import get_smoothing_kernel

D = 0.05


def _cubic_slip_oracle(h: float, d: float) -> float:
    """k d^2 / (P / rho0) = 2 V d^2 sum_j W_zz(x_j) over the cubic lattice's points j off the column through the
    origin, W the cubic spline (Monaghan & Lattanzio 1985, alpha = 3 / (2 pi h^3), physics notes 3) with its Hessian
    W_zz = alpha [f''(R) / h^2 (z/r)^2 + f'(R) / (h r) (1 - (z/r)^2)], V = 1 / sum_j W(x_j) (the calibrated volume)."""
    alpha = 3.0 / (2.0 * np.pi * h ** 3)
    n = int(np.ceil(2.0 * h / d)) + 1
    k = np.arange(-n, n + 1)
    x = np.stack(np.meshgrid(k, k, k, indexing="ij"), axis=-1).reshape(-1, 3) * d
    r = np.linalg.norm(x, axis=1)
    R = r / h
    f = np.where(R < 1, 2 / 3 - R ** 2 + R ** 3 / 2, np.where(R < 2, (2 - R) ** 3 / 6, 0.0))
    volume = 1.0 / np.sum(alpha * f)
    other = np.hypot(x[:, 0], x[:, 1]) > 0.5 * d
    x, r, R = x[other], r[other], R[other]
    fp = np.where(R < 1, -2 * R + 1.5 * R ** 2, np.where(R < 2, -(2 - R) ** 2 / 2, 0.0))
    fpp = np.where(R < 1, -2 + 3 * R, np.where(R < 2, 2 - R, 0.0))
    c2 = (x[:, 2] / r) ** 2
    wzz = alpha * (fpp / h ** 2 * c2 + fp / (h * r) * (1.0 - c2))
    return 2.0 * volume * d * d * float(np.sum(wzz))


@pytest.mark.parametrize("h_per_d", [1.0, 1.3])
def test_slip_stiffness_matches_the_kernel_hessian(h_per_d):
    """The finite-difference stiffness (the project's kernel on the lattice) equals the closed-form Hessian sum within
    2 % of the larger of the two and 2e-3, and its sign: the cubic lattice at the default h = d is (weakly) unstable to a
    column slipping along itself under pressure, at h = 1.3 d stable."""
    got = lattice_slip_stiffness("cubic", h_per_d * D, D)
    want = _cubic_slip_oracle(h_per_d * D, D)
    assert got == pytest.approx(want, rel=0.02, abs=2e-3)
    assert (got < 0.0) == (h_per_d == 1.0)


def test_slip_stiffness_of_the_default_kernels():
    """At each kernel's default h (all: support 2 d): cubic and quintic negative (a column slips), quadric positive."""
    k = {name: lattice_slip_stiffness(name, get_smoothing_kernel(name).default_smoothing_length(D), D)
         for name in ("cubic", "quintic", "quadric")}
    assert k["cubic"] < 0.0 and k["quintic"] < 0.0 < k["quadric"]


def _lattice(n: int = 6):
    i = np.stack(np.meshgrid(*(np.arange(n),) * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    return i, (i + 0.5) * D


def test_pair_correlations_of_exact_fields():
    """Uniform motion: every correlation 1. v_z alternating layer by layer: stacked pairs -1, pairs in one layer +1.
    Columns moving up and down alternately (a checkerboard in x, y, uniform along z: the slip): stacked +1, side by
    side -1."""
    i, x = _lattice()
    uniform = np.tile([0.1, -0.2, 0.3], (len(x), 1))
    c = _pair_correlations(x, uniform, D)
    assert c == pytest.approx({"all": 1.0, "vertical_vz": 1.0, "horizontal_vz": 1.0})
    layers = np.zeros_like(x)
    layers[:, 2] = (-1.0) ** i[:, 2]
    c = _pair_correlations(x, layers, D)
    assert c["vertical_vz"] == pytest.approx(-1.0) and c["horizontal_vz"] == pytest.approx(1.0)
    columns = np.zeros_like(x)
    columns[:, 2] = (-1.0) ** (i[:, 0] + i[:, 1])
    c = _pair_correlations(x, columns, D)
    assert c["vertical_vz"] == pytest.approx(1.0) and c["horizontal_vz"] == pytest.approx(-1.0)


def test_block_energy_share_of_exact_fields():
    """Blocks of 3 x 3 x 3 particles: a uniform field keeps all its energy in the block means (1); a checkerboard
    (-1)^(i+j+k) leaves each block a mean of +-1/27, so 27 (1/27)^2 / 27 = 1/729 of the energy."""
    i, x = _lattice()
    lo = np.zeros(3)
    assert _block_energy_share(x, np.ones_like(x), lo, 3 * D) == pytest.approx(1.0)
    v = np.zeros_like(x)
    v[:, 0] = (-1.0) ** i.sum(axis=1)
    assert _block_energy_share(x, v, lo, 3 * D) == pytest.approx(1.0 / 729.0)


def test_motion_record_of_two_frames():
    """The case's coarse tank (1440 particles, DFSPH) for two frames: one row per frame, the groups partition the
    fluid (400 wall-ring, 40 corner-column, 1000 interior particles; 144 in the top layer), the speed shares lie in
    [0, 1], a character sample per frame with one slip figure per layer, the walls' load per step near the weight."""
    r = motion("dfsph", 0.025, 2.0 / 24.0, [], every=1)
    assert r["counts"] == {"wall_ring": 400, "corner_columns": 40, "interior": 1000, "top_layer": 144}
    assert len(r["frames"]) == 2 and len(r["character"]) == 2
    for f in r["frames"]:
        assert len(f["layers"]) == 10
        assert 0.0 < f["share_top_layer"] < 1.0 and 0.0 < f["share_wall_ring_and_corners"] < 1.0
        assert 0.0 < f["mean"] < 0.1
    assert len(r["character"][-1]["slip_sd_dz_d"]) == 10
    # the walls carry the water's weight over the second frame, step by step (DFSPH's continuous stop: no bounce)
    load = r["load_second_half"]
    assert load["steps"] > 3 and load["mean"] == pytest.approx(1.0, abs=0.03) and load["iterations"]
    assert r["slosh_period"] == pytest.approx(2 * np.pi / np.sqrt(9.81 * np.pi / 0.6 * np.tanh(np.pi / 0.6 * 0.5)))
