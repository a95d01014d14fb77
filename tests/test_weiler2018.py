"""Implicit viscosity (Weiler et al. 2018): the operator against a dense NumPy oracle built from
SPlisHSPlasH's equation, its symmetry and definiteness, and the CG solve against a dense solve."""
import numpy as np
import pytest
import warp as wp

from warp_sph.kernels import neighbors as _neighbors
from warp_sph.kernels import weiler2018_cg as _cg
from warp_sph.methods.forces.weiler2018 import Weiler2018Solve

from sph_oracle import grad_W

SPACING = 0.05
H = SPACING            # smoothing length (cubic: support 2H)
SUPPORT = 2.0 * H
REST = 1000.0
MASS = REST * SPACING**3


class _Model:
    particle_mass = MASS
    rest_density = REST
    smoothing_length = H
    support_radius = SUPPORT


def _packing(seed=1, n_side=(8, 7, 6)):
    """A jittered lattice of fluid particles above one layer of wall particles, with densities near
    rho0 and a moving wall (boundary velocities)."""
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(*[np.arange(k) for k in n_side], indexing="ij"), -1).reshape(-1, 3)
    x = (g + 0.5) * SPACING + rng.uniform(-0.15, 0.15, g.shape) * SPACING
    x[:, 2] += 0.6 * SPACING
    bg = np.stack(np.meshgrid(np.arange(-2, n_side[0] + 2), np.arange(-2, n_side[1] + 2), indexing="ij"), -1).reshape(-1, 2)
    bx = np.column_stack([(bg + 0.5) * SPACING, np.zeros(len(bg))])
    bvol = np.full(len(bx), 0.8 * SPACING**3) * rng.uniform(0.9, 1.1, len(bx))
    bv = np.zeros_like(bx)
    bv[:, 0] = 0.3  # the wall slides along x
    rho = REST * rng.uniform(0.9, 1.05, len(x))
    v = rng.normal(0.0, 0.5, x.shape)
    return x, rho, v, bx, bv, bvol


def _lists(query, points, exclude_self, device):
    """A brute-force ``NeighborList`` (index in order of j) within the support radius."""
    d = np.linalg.norm(query[:, None, :] - points[None, :, :], axis=-1)
    near = d < SUPPORT
    if exclude_self:
        np.fill_diagonal(near, False)
    counts = near.sum(1)
    cap = max(int(counts.max()) if len(counts) else 1, 1) + 3  # spare slots: never read
    index = np.zeros((len(query), cap), dtype=np.int32)
    for i in range(len(query)):
        js = np.nonzero(near[i])[0]
        index[i, : len(js)] = js
    nl = _neighbors.NeighborList()
    nl.count = wp.array(counts.astype(np.int32), dtype=wp.int32, device=device)
    nl.index = wp.array(index, dtype=wp.int32, device=device)
    nl.order = wp.array(np.arange(len(query), dtype=np.int32)[::-1].copy(), dtype=wp.int32, device=device)
    return nl


def _oracle(x, rho, bx, bv, bvol, nu, nu_b, dt):
    """Dense A (3n x 3n), c (b = v* + c) and the boundary blocks B_i (3x3 each) from SPlisHSPlasH's
    matrixVecProd / computeRHS (float64)."""
    n = len(x)
    A = np.eye(3 * n)
    c = np.zeros((n, 3))
    B = np.zeros((n, 3, 3))
    mu, mu_b = REST * nu, REST * nu_b
    eps = 0.01 * H**2  # SPlisHSPlasH: 0.01 H_s^2; here 0.01 h^2 as the explicit form (kernels/viscosity.py)
    for i in range(n):
        xij = x[i] - x
        r2 = (xij**2).sum(1)
        g = grad_W("cubic", xij, H)
        for j in np.nonzero((r2 < SUPPORT**2) & (np.arange(n) != i))[0]:
            blk = (dt / rho[i]) * 10 * mu * (MASS / rho[j]) / (r2[j] + eps) * np.outer(g[j], xij[j])
            A[3 * i:3 * i + 3, 3 * i:3 * i + 3] -= blk
            A[3 * i:3 * i + 3, 3 * j:3 * j + 3] += blk
        xib = x[i] - bx
        rb2 = (xib**2).sum(1)
        gb = grad_W("cubic", xib, H)
        for b in np.nonzero(rb2 < SUPPORT**2)[0]:
            w = (dt / rho[i]) * 10 * mu_b * (REST * bvol[b] / rho[i]) / (rb2[b] + eps)
            A[3 * i:3 * i + 3, 3 * i:3 * i + 3] -= w * np.outer(gb[b], xib[b])
            B[i] -= w * np.outer(gb[b], xib[b])
            c[i] -= w * np.dot(bv[b], xib[b]) * gb[b]
    return A, c, B


def _solver(x, rho, bx, bv, bvol, nu_b, device, tolerance=1e-5, max_iterations=200):
    wb = nu_b > 0.0
    s = Weiler2018Solve(len(x), "cubic", wb, tolerance, max_iterations, device)
    arrays = dict(
        fluid_neighbors=_lists(x, x, False, device), boundary_neighbors=_lists(x, bx, False, device),
        boundary_x=wp.array(bx, dtype=wp.vec3, device=device), boundary_v=wp.array(bv, dtype=wp.vec3, device=device),
        boundary_volume=wp.array(bvol, dtype=float, device=device),
        particle_x=wp.array(x, dtype=wp.vec3, device=device), particle_density=wp.array(rho, dtype=float, device=device))
    return s, arrays


def _apply(s, arrays, nu, nu_b, dt, u, device):
    """A u with the kernels (setup, then one matvec)."""
    fn = arrays["fluid_neighbors"]
    pairs = s._pairs_for(fn.index.shape[1])
    wp.launch(s._setup, len(u), inputs=[0, MASS, REST, H, SUPPORT, nu, nu_b, dt, arrays["boundary_neighbors"],
                                        arrays["boundary_x"], arrays["boundary_v"], arrays["boundary_volume"], fn,
                                        arrays["particle_x"], arrays["particle_density"]],
              outputs=[pairs, s.block_inverse, s.boundary_block, s.boundary_rhs], device=device)
    p = wp.array(u, dtype=wp.vec3, device=device)
    q = wp.zeros(len(u), dtype=wp.vec3, device=device)
    control = wp.zeros(_cg.CONTROL_COUNT, dtype=wp.float64, device=device)
    wp.launch(s._matvec, len(u), inputs=[0, fn, pairs, s.boundary_block, p, control], outputs=[q], device=device)
    return q.numpy().astype(np.float64)


@pytest.mark.parametrize("nu_b", [0.0, 0.7])
def test_operator_matches_oracle(device, nu_b):
    x, rho, _, bx, bv, bvol = _packing()
    nu, dt = 0.5, 0.004
    A, c, B = _oracle(x, rho, bx, bv, bvol, nu, nu_b, dt)
    s, arrays = _solver(x, rho, bx, bv, bvol, nu_b, device)
    rng = np.random.default_rng(3)
    u = rng.normal(size=x.shape)
    q = _apply(s, arrays, nu, nu_b, dt, u, device)
    ref = (A @ u.reshape(-1)).reshape(-1, 3)
    assert np.abs(A - np.eye(len(A))).max() > 0.1  # the viscous part is not negligible at this dt nu / H^2
    np.testing.assert_allclose(q, ref, rtol=0, atol=2e-5 * np.abs(ref).max())
    if nu_b > 0.0:
        np.testing.assert_allclose(s.boundary_rhs.numpy(), c, rtol=0, atol=1e-5 * np.abs(c).max())
        assert np.abs(c).max() > 1e-3
    # the block-Jacobi preconditioner is the inverse of A's diagonal blocks
    blocks = np.stack([A[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(len(x))])
    np.testing.assert_allclose(np.einsum("nij,njk->nik", s.block_inverse.numpy(), blocks),
                               np.broadcast_to(np.eye(3), blocks.shape), atol=1e-4)


def test_operator_symmetric_positive_definite(device):
    x, rho, _, bx, bv, bvol = _packing(seed=7)
    nu, nu_b, dt = 2.0, 1.0, 0.005
    s, arrays = _solver(x, rho, bx, bv, bvol, nu_b, device)
    rng = np.random.default_rng(11)
    for _ in range(3):
        v, w = rng.normal(size=x.shape), rng.normal(size=x.shape)
        Av, Aw = _apply(s, arrays, nu, nu_b, dt, v, device), _apply(s, arrays, nu, nu_b, dt, w, device)
        assert abs(np.sum(v * Aw) - np.sum(w * Av)) <= 1e-5 * np.sqrt(np.sum(Av**2) * np.sum(w**2))
        assert np.sum(v * Av) > np.sum(v * v)  # A = I + PSD, and the PSD part is not zero here
    # a uniform translation is not damped by the fluid part (Galilean invariance): A u = u without walls
    s0, arrays0 = _solver(x, rho, bx, bv, bvol, 0.0, device)
    u = np.tile([0.3, -1.0, 2.0], (len(x), 1))
    np.testing.assert_allclose(_apply(s0, arrays0, nu, 0.0, dt, u, device), u, atol=1e-5)


@pytest.mark.parametrize("nu_b", [0.0, 0.7])
def test_solve_matches_dense_solve_and_warm_start(device, nu_b):
    x, rho, v, bx, bv, bvol = _packing(seed=5)
    nu, dt = 5.0, 0.004  # dt nu / H^2 = 8: far past the explicit bound
    A, c, B = _oracle(x, rho, bx, bv, bvol, nu, nu_b, dt)
    ref = np.linalg.solve(A, (v + c).reshape(-1)).reshape(-1, 3)
    tol = 1e-5
    s, arrays = _solver(x, rho, bx, bv, bvol, nu_b, device, tolerance=tol)
    vel = wp.array(v, dtype=wp.vec3, device=device)
    warm = wp.zeros(len(x), dtype=wp.vec3, device=device)
    force = wp.zeros(len(x), dtype=wp.vec3, device=device)
    it, res = s.solve(
        dt, _Model, nu, nu_b, arrays["fluid_neighbors"], arrays["boundary_neighbors"], arrays["boundary_x"],
        arrays["boundary_v"], arrays["boundary_volume"], arrays["particle_x"], arrays["particle_density"], vel, warm,
        force)
    assert 1 <= it < 200 and res <= tol
    r0 = np.linalg.norm(v + c - (A @ v.reshape(-1)).reshape(-1, 3))
    out = vel.numpy().astype(np.float64)
    # |A dv - r0| <= tol |r0| bounds the error by cond(A) tol |r0| / |A|; check it against the dense answer
    assert np.linalg.norm(out - ref) <= 20 * tol * r0 + 1e-5 * np.linalg.norm(ref)
    np.testing.assert_allclose(warm.numpy(), out - v, atol=1e-5)
    if nu_b > 0.0:  # the walls' force on the fluid: m (c - B v_new) / dt
        fb = MASS * (c - np.einsum("nij,nj->ni", B, out)) / dt
        np.testing.assert_allclose(force.numpy(), fb, rtol=1e-4, atol=1e-6 * np.abs(fb).max())
    # warm start: the same system again from the last dv converges without an iteration
    vel.assign(wp.array(v, dtype=wp.vec3, device=device))
    it2, res2 = s.solve(dt, _Model, nu, nu_b, arrays["fluid_neighbors"], arrays["boundary_neighbors"],
                        arrays["boundary_x"], arrays["boundary_v"], arrays["boundary_volume"], arrays["particle_x"],
                        arrays["particle_density"], vel, warm, force)
    assert it2 <= 1 and res2 <= tol
    np.testing.assert_allclose(vel.numpy(), out, atol=1e-5 * np.abs(out).max())


def _lattice_lists(shape, support, device):
    """Neighbour lists of a perfect lattice (spacing SPACING, ``shape`` particles per axis) from the
    lattice offsets within ``support`` (no distance matrix)."""
    shape = np.asarray(shape)
    g = np.stack(np.meshgrid(*[np.arange(k) for k in shape], indexing="ij"), -1).reshape(-1, 3)
    r = int(np.ceil(support / SPACING))
    off = np.stack(np.meshgrid(*[np.arange(-r, r + 1)] * 3, indexing="ij"), -1).reshape(-1, 3)
    off = off[np.linalg.norm(off, axis=1) * SPACING < support]
    cand = g[:, None, :] + off[None, :, :]
    inside = np.all((cand >= 0) & (cand < shape), axis=-1)
    flat = (cand[..., 0] * shape[1] + cand[..., 1]) * shape[2] + cand[..., 2]
    order = np.argsort(~inside, axis=1, kind="stable")  # neighbours inside first
    index = np.take_along_axis(np.where(inside, flat, 0), order, 1).astype(np.int32)
    nl = _neighbors.NeighborList()
    nl.count = wp.array(inside.sum(1).astype(np.int32), dtype=wp.int32, device=device)
    nl.index = wp.array(index, dtype=wp.int32, device=device)
    nl.order = wp.array(np.arange(len(g), dtype=np.int32), dtype=wp.int32, device=device)
    return (g + 0.5) * SPACING, nl


def test_rotating_blob_spreads_at_the_analytic_rate(device):
    """A rotating Gaussian blob u = (Omega x r) f(|r|, t) in a cube of fluid: an exact solution of the
    unsteady Stokes equations (U -> 0: the centrifugal pressure is O(U^2)), divergence-free, with
    vector Laplacian (Omega x r)(f'' + 4 f' / r): f obeys the 5-D radial heat equation, so f stays a
    Gaussian of variance s^2 = sigma^2 + 2 nu t. The angular momentum density j = (r x u) . Omega /
    |Omega| is then conserved in total and its second moment sum(j r^2) / sum(j) = 5 s^2 grows as
    10 nu t, exactly also under backward Euler (as the heat equation's variance). The blob is ~0 at the
    cube's free faces. Default kernel (cubic, h = d); positions held, densities the SPH sums.
    Eight steps at 2.3x the explicit bound."""
    from sph_oracle import W

    d = SPACING
    h = d
    support = 2.0 * h
    n = 24
    x, nl = _lattice_lists((n, n, n), support, device)
    r = np.arange(-3, 4)
    off = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3) * d
    mass = REST / W("cubic", np.linalg.norm(off, axis=1), h).sum()
    idx, cnt = nl.index.numpy(), nl.count.numpy()
    used = np.arange(idx.shape[1])[None, :] < cnt[:, None]
    rho = mass * np.where(used, W("cubic", np.linalg.norm(x[:, None, :] - x[idx], axis=-1), h), 0.0).sum(1)

    class Model:
        particle_mass, rest_density, smoothing_length, support_radius = mass, REST, h, support

    nu, sigma = 0.01, 2.75 * d
    t_end = 0.15 * sigma**2 / nu  # s^2 grows by 30 %
    steps = 8
    dt = t_end / steps
    assert nu * dt / h**2 > 2 * 0.0625  # past the explicit bound 0.0625 h^2 / nu
    rel = x - x.mean(0)
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    omega = 0.01 / sigma * axis  # peak speed ~ 0.006 m/s
    v0 = np.cross(omega, rel) * np.exp(-(rel**2).sum(1) / (2 * sigma**2))[:, None]
    vel = wp.array(v0, dtype=wp.vec3, device=device)
    warm = wp.zeros(len(x), dtype=wp.vec3, device=device)
    one = wp.zeros(1, dtype=wp.vec3, device=device)
    s = Weiler2018Solve(len(x), "cubic", False, 1e-4, 100, device)
    xs = wp.array(x, dtype=wp.vec3, device=device)
    dens = wp.array(rho, dtype=float, device=device)
    iterations = [s.solve(dt, Model, nu, 0.0, nl, nl, one, one, wp.zeros(1, dtype=float, device=device), xs, dens,
                          vel, warm, one)[0] for _ in range(steps)]
    v = vel.numpy().astype(np.float64)
    j0, j = np.cross(rel, v0) @ axis, np.cross(rel, v) @ axis
    r2 = (rel**2).sum(1)
    assert abs(j.sum() / j0.sum() - 1.0) < 1e-4  # angular momentum
    assert abs(np.sum(j0 * r2) / np.sum(j0) / (5 * sigma**2) - 1.0) < 0.01  # the lattice resolves the blob
    growth = (np.sum(j * r2) / np.sum(j) - np.sum(j0 * r2) / np.sum(j0)) / 5.0
    assert abs(growth / (2 * nu * t_end) - 1.0) < 0.05, (growth / (2 * nu * t_end), iterations)
    assert max(iterations) < 100 and iterations[-1] <= iterations[0]  # converged; the warm start helps


def _frames(scene, frames, device=None):
    from warp_sph.run.simulation import Simulation

    sim = Simulation(scene, device=device)
    start = sim.statistics()
    stats = [sim.advance_frame() for _ in range(frames)]
    return sim, start, stats


def test_high_viscosity_runs_at_the_step_of_no_viscosity_and_stays_stable(device):
    """The small tank's block (a dam break in a box, DFSPH) at nu = 10 m^2/s with sticking walls: the same
    time-step bounds as nu = 0 (the explicit bound would be 6e-5 s), no more substeps,
    total energy never above the start, no particle faster than free fall from the top of the box, the
    fluid slower than without viscosity, and every CG solve converged to its tolerance."""
    from small_scenes import small_tank

    tol = 1e-3
    viscous = small_tank("honey_tank", forces=[{"method": "weiler2018", "viscosity": 10.0, "boundary_viscosity": 10.0,
                                                 "tolerance": tol, "max_iterations": 200}])
    sim0, start0, plain = _frames(small_tank("water_tank"), 4, device=device)
    sim, start, honey = _frames(viscous, 4, device=device)
    assert [b.name for b in sim.time_step_bounds(1.0)] == [b.name for b in sim0.time_step_bounds(1.0)]
    assert "implicit_viscosity" in sim.graph.names()
    assert sum(s.steps for s in honey) <= sum(s.steps for s in plain)
    e0 = start.kinetic_energy + start.potential_energy
    g, top = 9.81, 0.8
    for s in honey:
        assert s.kinetic_energy + s.potential_energy <= e0 + 1e-6 * abs(e0)
        assert s.max_speed <= np.sqrt(2 * g * top)
        assert s.non_finite == 0 and s.outside == 0
        assert s.solver["viscosity_residual"]["max"] <= tol
        assert 1 <= s.solver["viscosity_iterations"]["max"] < 200
    assert honey[-1].kinetic_energy < 0.5 * plain[-1].kinetic_energy


def test_warm_start_follows_the_particles_and_resume_is_bitwise(tmp_path):
    """The warm start (weiler2018_dv) is a carried field: sorted with the particles each frame, in the
    checkpoint, restored on resume: the resumed run equals the uninterrupted one, bit for bit."""
    from test_run_outputs import assert_same_run, quiet

    from warp_sph.io import run_folder as rf
    from warp_sph.run import runner
    from warp_sph.scene import load_scene

    extra = ["particle_radius=0.05", "output.checkpoint_every=1", "output.surface=false",
             'forces=[{method = "weiler2018", viscosity = 1.0, boundary_viscosity = 1.0}]']

    def run(out, frames, **kw):
        return runner.run(load_scene("dam_break", extra), out=out, device="cpu", frames=frames, progress=False,
                          log=quiet, **kw)

    reference, resumed = tmp_path / "reference", tmp_path / "resumed"
    run(reference, 4)
    run(resumed, 3, threaded_export=False)
    rf.checkpoint_path(resumed, 3).unlink()  # frames 3, 4 are recomputed from the checkpoint of frame 2
    with np.load(rf.latest_checkpoint(resumed)) as cp:
        assert np.abs(cp["weiler2018_dv"]).max() > 0.0
    runner.run(None, frames=4, resume=resumed, progress=False, device="cpu", log=quiet)
    assert_same_run(reference, resumed)
