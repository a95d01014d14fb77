"""XSPH (``[[forces]] method = "xsph"``): the filter against a NumPy oracle for every solver; uniform
motion passes through unchanged."""
import numpy as np
import pytest

from small_scenes import small_tank, stage
from sph_oracle import W
from warp_sph.run.simulation import Simulation

EPS = 0.1


def block(solver, device=None):
    d = 0.05
    sim = Simulation(small_tank("xsph", solver, particle_radius=0.025, container=False, gravity=[0.0, 0.0, 0.0],
                                fluid=[{"min": [0, 0, 0], "max": [6 * d] * 3}], forces=[{"method": "xsph", "factor": EPS}]), device=device)
    x = sim.model.to_local(sim.get_field("particle_x")).astype(np.float64)
    x += np.random.default_rng(1).uniform(-0.15, 0.15, x.shape) * d
    sim.set_field("particle_x", sim.model.to_world(x))
    sim.refresh_density()
    return sim


@pytest.mark.parametrize("solver", ["dfsph", "wcsph", "pbf"])
def test_filter_matches_the_oracle(solver, device):
    sim = block(solver, device=device)
    m = sim.model
    v = np.random.default_rng(2).normal(0.0, 0.5, (m.fluid_count, 3))
    sim.set_field("particle_v", v)
    x = sim.fields["particle_x"].numpy().astype(np.float64)
    rho = sim.fields["particle_density"].numpy().astype(np.float64)
    stage(sim, "xsph").run(sim, 1e-3)
    w = W(m.smoothing.name, np.linalg.norm(x[:, None] - x[None], axis=2), m.smoothing_length) * (m.particle_mass / rho)[None]
    ref = v + EPS * (w[:, :, None] * (v[None] - v[:, None])).sum(1)
    np.testing.assert_allclose(sim.get_field("particle_v"), ref, rtol=1e-4, atol=1e-5)
    assert np.abs(ref - v).max() > 1e-2


def test_uniform_motion_is_unchanged(device):
    sim = block("dfsph", device=device)
    v = np.tile([0.3, -0.1, 0.2], (sim.model.fluid_count, 1))
    sim.set_field("particle_v", v)
    stage(sim, "xsph").run(sim, 1e-3)
    np.testing.assert_allclose(sim.get_field("particle_v"), v, atol=1e-7)
