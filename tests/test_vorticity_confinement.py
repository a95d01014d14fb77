"""Vorticity confinement (``[[forces]] method = "vorticity_confinement"``) for every solver: the vorticity
against a NumPy oracle, the confinement spins a vortex up (never down), and leaves uniform motion alone."""
import numpy as np
import pytest
import warp as wp

from small_scenes import small_tank, stage
from sph_oracle import grad_W
from warp_sph.run.simulation import Simulation

SOLVERS = ["dfsph", "wcsph", "pbf"]


def vortex_block(solver, strength=0.05, n=8, device=None):
    """An n^3 block (r = 0.025 m) without walls or gravity, spinning as a Gaussian vortex about the vertical
    axis through its centre: v = Omega x (x - c) exp(-rho^2 / s^2), Omega = 4 rad/s, s = half the side."""
    d = 0.05
    forces = [{"method": "vorticity_confinement", "strength": strength}] if strength else []
    sim = Simulation(small_tank("vortex", solver, particle_radius=0.025, container=False, gravity=[0.0, 0.0, 0.0],
                                fluid=[{"min": [0, 0, 0], "max": [n * d] * 3}], forces=forces), device=device)
    x = sim.get_field("particle_x").astype(np.float64)
    c = x.mean(axis=0)
    rel = x - c
    s = 0.5 * n * d
    v = np.cross([0.0, 0.0, 4.0], rel) * np.exp(-(rel[:, 0] ** 2 + rel[:, 1] ** 2) / s**2)[:, None]
    sim.set_field("particle_v", v)
    sim.refresh_density()
    return sim, v


@pytest.mark.parametrize("solver", SOLVERS)
def test_vorticity_matches_the_oracle_and_confinement_feeds_the_vortex(solver, device):
    sim, v = vortex_block(solver, device=device)
    m = sim.model
    sim.fields["force_acceleration"].zero_()
    stage(sim, "vorticity").run(sim, 1e-3)
    x = sim.fields["particle_x"].numpy().astype(np.float64)
    rho = sim.fields["particle_density"].numpy().astype(np.float64)
    g = grad_W(m.smoothing.name, x[:, None] - x[None], m.smoothing_length)
    omega = ((m.particle_mass / rho)[None, :, None] * np.cross(g, v[None] - v[:, None])).sum(1)
    got = sim.fields["particle_vorticity"].numpy()
    np.testing.assert_allclose(got, omega, rtol=1e-3, atol=1e-4 * np.abs(omega).max())
    # the curl of the vortex, Omega (2 - 2 rho^2/s^2) exp(-rho^2/s^2) along +z, where the kernel sees no face
    rho2 = ((x[:, :2] - x[:, :2].mean(axis=0)) ** 2).sum(axis=1)
    exact = 4.0 * (2.0 - 2.0 * rho2 / 0.2**2) * np.exp(-rho2 / 0.2**2)
    inner = np.all(np.abs(x - x.mean(axis=0)) < 0.2 - m.support_radius, axis=1)
    assert inner.sum() >= 8
    np.testing.assert_allclose(omega[inner, 2], exact[inner], atol=0.1 * 8.0)
    a = sim.fields["force_acceleration"].numpy().astype(np.float64)
    power = (a * v).sum(axis=1)
    assert power.sum() > 0 and np.abs(a).max() > 0  # a = eps v_ref (N x omega) along the flow: it spins it up


@pytest.mark.parametrize("solver", SOLVERS)
def test_confinement_keeps_a_vortex_spinning_longer(solver, device):
    """After 0.08 s (steps within the solver's bounds at 1 m/s) the vortex with confinement holds more angular
    momentum about its axis than the same vortex without (confinement puts back what numerical dissipation
    removes)."""
    spins = []
    for strength in (0.0, 0.05):
        sim, _ = vortex_block(solver, strength, device=device)
        dt = min(2e-3, min(b.seconds for b in sim.time_step_bounds(1.0)))
        for _ in range(int(round(0.08 / dt))):
            sim.step(dt)
        x = sim.get_field("particle_x").astype(np.float64)
        v = sim.get_field("particle_v").astype(np.float64)
        spins.append(float(np.cross(x - x.mean(axis=0), v)[:, 2].sum()))
    assert spins[0] > 0 and spins[1] > 1.01 * spins[0], spins


def test_uniform_motion_feels_no_confinement(device):
    sim, _ = vortex_block("dfsph", device=device)
    sim.set_field("particle_v", np.tile([0.3, -0.1, 0.2], (sim.model.fluid_count, 1)))
    sim.fields["force_acceleration"].zero_()
    stage(sim, "vorticity").run(sim, 1e-3)
    assert np.abs(sim.fields["force_acceleration"].numpy()).max() < 1e-6
