"""Issue #31: a fluid start that is a stable rest state under load. ``benchmarks.lattice_stability``'s dynamical
matrix against a brute-force force sum (finite differences of the SPH pressure force), the cubic and fcc starts'
stiffness signs, and the ``fluid[].lattice = "fcc"`` start: its geometry, calibrated mass and wall gap."""
import math

import numpy as np
import pytest

from benchmarks.lattice_stability import STARTS, Lattice, lattice_points
from warp_sph.core.errors import SceneError
from warp_sph.core.smoothing import calibrated_mass, evaluate, first_layer_density, wall_gap
from tests.small_scenes import small_tank

D = 0.05


def _pressure_acceleration(name, h, x, volume):
    """a_0 / (P / rho0) = -2 V sum_j grad W(x_0 - x_j) [1/m] of the first point of ``x`` under a uniform particle
    pressure P: the symmetric pressure force's sum over every point, by brute force."""
    _, g = evaluate(name, x[0] - x[1:], h)
    return -2.0 * volume * g.astype(np.float64).sum(axis=0)


@pytest.mark.parametrize("start,q_frac,u", [
    ("cubic", (0.5, 0.5, 0.0), (0.0, 0.0, 1.0)),      # the columns' checkerboard slip: the cubic lattice's weakest
    ("cubic", (0.25, 0.0, 0.125), (0.6, 0.0, 0.8)),
    ("fcc", (0.5, 0.0, 0.25), (0.0, 1.0, 0.0)),
    ("fcc", (0.125, 0.375, -0.25), (0.48, 0.6, 0.64)),
    ("bcc", (0.0, 0.5, -0.5), (1.0, 0.0, 0.0)),
])
def test_dynamical_matrix_against_the_force_sum(start, q_frac, u):
    """Displace every point of a lattice patch by eps u cos(q . x_j) (eps = +-1e-3 d) and sum the pressure force on
    the origin's point directly: its change over the displacement, -(a(+eps) - a(-eps)) / (2 eps), is
    (2 V / rho0)... D(q) u, the tool's stiffness matrix times u (within 2 % of |D u| and 1e-3 d^-2 scaled)."""
    layer, shift = STARTS[start]
    L = Lattice("cubic", D, D, layer, shift)
    x = lattice_points(D, layer, shift, 2.0 * 2.0 * D + 2.0 * D)       # the origin first; reaches past the support
    q = np.asarray(q_frac) @ L.b
    u = np.asarray(u, dtype=np.float64)
    eps = 1e-3 * D
    a = []
    for s in (eps, -eps):
        y = x + s * np.cos(x @ q)[:, None] * u
        a.append(_pressure_acceleration("cubic", D, y, L.volume))
    k_force = -(a[0] - a[1]) / (2.0 * eps) * D * D                 # k d^2 / (P / rho0) per unit u
    Dm, _ = L.dynamical(q)
    k_tool = 2.0 * L.volume * D * D * (Dm @ u)
    assert k_force == pytest.approx(k_tool, abs=0.02 * np.linalg.norm(k_tool) + 1e-3)


def test_the_cubic_lattice_slips_and_the_fcc_lattice_holds():
    """Cubic spline, h = d: the cubic lattice's column checkerboard has a negative stiffness under pressure (-0.27),
    the whole Brillouin zone of the fcc lattice (nearest neighbours d) a positive one (its smallest, at the longest
    wave of the grid, +0.009); the calibrated volumes are the lattices' own, d^3 and d^3 / sqrt 2, within 1 %."""
    cubic = Lattice("cubic", D, D, *STARTS["cubic"])
    assert cubic.column_slip() == pytest.approx(-0.27, abs=0.01)
    assert cubic.scan(8)["hidden"]["k"] < -0.2
    fcc = Lattice("cubic", D, D, *STARTS["fcc"])
    low = fcc.scan(8)
    assert low["all"]["k"] > 0.005 and low["hidden"]["k"] > 0.005
    assert fcc.volume / D ** 3 == pytest.approx(1.0 / math.sqrt(2.0), rel=0.01)
    assert cubic.volume / D ** 3 == pytest.approx(1.0, rel=0.01)


def _fcc_tank(width_cells: int, **kw):
    w = D + (width_cells - 1) * D / math.sqrt(2.0) + 1e-9          # a tank the fcc start fits exactly
    return small_tank("fcc", particle_radius=D / 2, container={"min": [0.0, 0.0, 0.0], "max": [w, w, 0.5],
                                                                 "inner": True},
                      fluid=[{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [w, w, 0.25], "lattice": "fcc"}], **kw)


def test_fcc_start_geometry_mass_and_gap():
    """The sampled fcc block: every interior particle has 12 nearest neighbours at d (face-centred cubic), the
    first layer stands the fcc wall gap over the floor's wall particles, and the model's mass is rho0 over the fcc
    lattice's kernel sum, so a particle deep inside reads rho0 (within 1e-3) where the cubic mass would read
    sqrt 2 more."""
    from warp_sph.run.simulation import Simulation
    from warp_sph.scene.sampling import sample_scene

    scene = _fcc_tank(9)
    sim = Simulation(scene)
    m = sim.model
    x = sim.get_field("particle_x")[: m.fluid_count].astype(np.float64)
    r = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=2)
    centre = np.argmin(np.linalg.norm(x - x.mean(axis=0), axis=1))
    near = np.sort(r[centre])[1:14]
    assert near[:12] == pytest.approx(D, rel=1e-5) and near[12] > 1.3 * D
    gap = wall_gap("cubic", D, D, "fcc")
    assert 0.9 * D < gap < 1.0 * D < wall_gap("cubic", D, D)
    assert first_layer_density("cubic", D, D, gap, 1.0, "fcc") == pytest.approx(1.0, abs=1e-3)
    sampled = sample_scene(scene)
    floor = float(sampled.boundary_x[:, 2].min())
    assert float(sampled.fluid_x[:, 2].min()) - floor == pytest.approx(gap, rel=1e-4)
    side = float(sampled.boundary_x[:, 0].min())
    assert float(sampled.fluid_x[:, 0].min()) - side == pytest.approx(gap, rel=1e-4)
    assert m.particle_mass == pytest.approx(calibrated_mass("cubic", D, D, 1000.0, "fcc"), rel=1e-6)
    assert m.particle_mass / calibrated_mass("cubic", D, D, 1000.0) == pytest.approx(1.0 / math.sqrt(2.0), rel=0.01)
    sim.refresh_density()
    rho = sim.get_field("particle_density")[: m.fluid_count]
    assert rho[centre] / 1000.0 == pytest.approx(1.0, abs=1e-3)


def test_mixed_lattices_are_refused():
    """Two blocks on different lattices: one clear line naming the key, before any kernel runs."""
    from warp_sph.scene.sampling import sample_scene

    scene = small_tank("mixed", fluid=[{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.3, 0.5, 0.5]},
                                       {"shape": "box", "min": [0.4, 0.0, 0.0], "max": [0.7, 0.5, 0.5],
                                        "lattice": "fcc"}])
    with pytest.raises(SceneError, match=r"fluid\[\]\.lattice: cubic and fcc"):
        sample_scene(scene)


def test_fcc_walls_register_with_the_fluid():
    """With an fcc start the container's faces are (100) nets of the fluid's grid: every floor particle under the
    fluid's footprint stands in a hollow of the bottom plane (horizontally d / sqrt 2 from its nearest four), every
    side-wall particle level with the fluid likewise in a hollow of the outermost plane, and a face carries one
    particle per d^2 as the square wall layer does (within 5 %)."""
    from warp_sph.scene.sampling import sample_scene

    scene = _fcc_tank(9)
    s = sample_scene(scene)
    x, b = s.fluid_x, s.boundary_x
    c = D / math.sqrt(2.0)
    for axis in (2, 0):
        a1, a2 = [k for k in range(3) if k != axis]
        plane = x[np.isclose(x[:, axis], x[:, axis].min())]
        wall = b[np.isclose(b[:, axis], b[:, axis].min())]
        inner = wall[(wall[:, a1] > x[:, a1].min() + D) & (wall[:, a1] < x[:, a1].max() - D)
                     & (wall[:, a2] > x[:, a2].min() + D) & (wall[:, a2] < x[:, a2].max() - D)]
        assert len(inner) >= 4
        dist = np.linalg.norm(inner[:, None, [a1, a2]] - plane[None, :, [a1, a2]], axis=2)
        near = np.sort(dist, axis=1)[:, :5]
        assert near[:, :4] == pytest.approx(c, rel=1e-6) and np.all(near[:, 4] > 1.4 * c)
        extent = [len(np.unique(np.round(wall[:, k] / c, 6))) * c for k in (a1, a2)]  # its rows, c apart
        assert len(wall) / (extent[0] * extent[1]) == pytest.approx(1.0 / D ** 2, rel=0.05)


@pytest.mark.parametrize("width_cells", [9, 10])
def test_fcc_tank_edges_start_no_denser_than_the_flat_walls_depart(width_cells):
    """Where two faces meet, their nets share one lattice row; it lies on the edge (``_fcc_walls``), so no particle
    of the fcc tank starts further over rho0 than the flat walls' own layers depart from it (first -0.18 %, second
    -1.1 %: one Akinci layer for two missing lattice planes), within 0.05 %, at the corners and edges of a tank with
    corner particles (9 columns: +0.67 %) and without (10: +1.13 %). Kept in one net at its own plane, 0.34 d from
    the other's, the row left the corner particle 5.9 % over rho0 and the edges 2.3 %. The top planes (the free
    surface) are left out."""
    from warp_sph.run.simulation import Simulation

    sim = Simulation(_fcc_tank(width_cells))
    m = sim.model
    sim.refresh_density()
    x = sim.get_field("particle_x")[: m.fluid_count].astype(np.float64)
    dev = sim.get_field("particle_density")[: m.fluid_count].astype(np.float64) / 1000.0 - 1.0
    below_top = x[:, 2] < x[:, 2].max() - 2.5 * D / math.sqrt(2.0)
    lo, hi = x.min(axis=0), x.max(axis=0)
    side = np.minimum(x[:, :2] - lo[:2], hi[:2] - x[:, :2]).min(axis=1)
    flat = below_top & (side > 1.4 * D)          # the floor's layers, out of the side walls' reach
    band = float(np.abs(dev[flat]).max())
    assert 0.005 < band < 0.015
    assert float(dev[below_top].max()) <= band + 5e-4


@pytest.mark.parametrize("start", ["cubic", "fcc"])
def test_pbf_jacobi_symbol_against_a_brute_force_correction(start):
    """``Lattice.pbf_jacobi``'s symbol A(q) of J J^T against PBF's correction applied by brute force: every particle
    within 2 H_s of the origin moved by dx_k = sum_j V (lambda_k + lambda_j) grad W_kj with lambda_j = cos(q . x_j),
    the origin's density re-summed at +-t dx (central differences): dC_0 / dt = A(q) lambda_0, at the lattice's worst
    wave and at a long one. That worst wave grows under the old default pbf.relaxation (1e-4 D0): factor 1 - A / D below
    -1 (cubic -1.8, fcc -2.3; docs/validation-notes.md, "PBF at rest"); the default (``pbf_lattice.auto_epsilon``,
    D + eps = 3/4 A_max) damps it, factor in [-1/3, 0) (-1/3 at A_max; the grid's worst wave is at most A_max)."""
    layer, shift = STARTS[start]
    L = Lattice("cubic", D, D, layer, shift)
    jac = L.pbf_jacobi(8)
    support = 2.0 * D
    x = lattice_points(D, layer, shift, 2.0 * support + 1e-9)
    inner = np.linalg.norm(x, axis=1) < support + 1e-9          # the origin and its neighbours: the ones that move
    for q in (np.array(jac["q_pi_over_d"]) * np.pi / D, np.array([0.2, 0.1, 0.05]) * np.pi / D):
        lam = np.cos(x @ q)
        dx = np.zeros_like(x)
        for k in np.nonzero(inner)[0]:
            r = x[k] - x
            near = (np.linalg.norm(r, axis=1) < support) & (np.linalg.norm(r, axis=1) > 0)
            _, g = evaluate("cubic", r[near], D)
            dx[k] = L.volume * ((lam[k] + lam[near])[:, None] * g.astype(np.float64)).sum(axis=0)

        def c0(t):
            y = x + t * dx
            w, _ = evaluate("cubic", y[0] - y, D)
            return L.volume * float(np.sum(w.astype(np.float64)))

        t = 1e-4 * D / float(np.abs(dx).max())
        brute = (c0(t) - c0(-t)) / (2.0 * t)
        g = L.volume * L.grad
        A = float(np.sum((np.sin(L.x @ q) @ g) ** 2))
        assert brute == pytest.approx(A, rel=2e-3, abs=1e-6 * A + 1e-12)
    assert 1.0 - jac["A_over_D"] / (1.0 + 1e-4 / jac["D_over_D0"]) < -1.0      # the old default, eps = 1e-4 D0
    assert -1.0 / 3.0 - 1e-9 <= jac["factor_at_default"] < -0.2
    assert jac["relaxation_convergent"] < jac["epsilon_default"] < jac["relaxation_monotone"]
    assert jac["relaxation_convergent"] < jac["relaxation_smoother"] < jac["relaxation_monotone"]


@pytest.mark.parametrize("start", ["cubic", "fcc"])
def test_pbf_jacobi_default_is_the_solvers(start):
    """``Lattice.pbf_jacobi``'s default eps and D0 are the ones PBF computes for a scene of that start (its
    ``epsilon`` and ``rest_denominator``, ``pbf.relaxation`` absent), so ``relaxation_*`` read as pbf.relaxation
    values; a start no scene samples (bcc) has no default."""
    from warp_sph.run.simulation import Simulation

    sim = Simulation(small_tank("pbf_default", solver="pbf", fluid=[{"shape": "box", "min": [0.0, 0.0, 0.0],
                                                                    "max": [0.3, 0.3, 0.3], "lattice": start}]))
    m, solver = sim.model, sim.solver
    jac = Lattice(m.smoothing.name, m.smoothing_length, m.spacing, *STARTS[start]).pbf_jacobi(4)
    assert jac["epsilon_default"] == pytest.approx(solver.epsilon / solver.rest_denominator, rel=1e-9)
    assert jac["D_over_D0"] == pytest.approx(1.0, rel=1e-9)       # the start's own lattice: D = D0
    assert Lattice("cubic", D, D, *STARTS["bcc"]).pbf_jacobi(4)["factor_at_default"] is None
