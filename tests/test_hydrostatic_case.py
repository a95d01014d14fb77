"""The hydrostatic validation case (warp_sph/validation/cases.py, scenes/validation/hydrostatic_probes.toml): its
water fills its tank at both of the bench's radii, so the lattice starts in the tank at rest (issue #31: the fine
tank's 0.22 d of slack made its floor read +1.9 %)."""
import numpy as np
import pytest

from warp_sph.run.simulation import Simulation
from warp_sph.scene.sampling import sample_scene
from warp_sph.validation.cases import CASES, load_case_scene, water_offset

G, RHO0 = 9.81, 1000.0


@pytest.mark.parametrize("radius", [0.025, 0.0125])
def test_water_fills_the_tank_at_both_radii(radius):
    """At r = 0.025 and 0.0125 m the sampled water spans the scene's 0.6 x 0.6 x 0.5 m box (each particle filling
    r around its centre) and every outer fluid layer rests one wall gap from its wall's particle plane on all
    five walls, so nothing can spread sideways (before: 0.61 m walls, the water from gap - r = 0.015-0.030 m,
    and at r = 0.0125 m 0.22 d of slack at one side of each axis)."""
    scene = load_case_scene(CASES["hydrostatic"], "dfsph", radius)
    x = sample_scene(scene).fluid_x.astype(np.float64)
    r, d, g = radius, 2.0 * radius, scene.wall_gap
    np.testing.assert_allclose(x.min(axis=0) - r, 0.0, atol=1e-6)
    np.testing.assert_allclose(x.max(axis=0)[:2] + r, 0.6, atol=1e-6)
    assert x.max(axis=0)[2] + r == pytest.approx(0.5, abs=1e-6)
    c = scene.container
    np.testing.assert_allclose(x.min(axis=0) - np.asarray(c.min), g, atol=0.01 * d)
    np.testing.assert_allclose(np.asarray(c.max)[:2] - x.max(axis=0)[:2], g, atol=0.01 * d)
    assert water_offset(scene) == pytest.approx(g - r)
    assert len(x) == round(0.6 / d) ** 2 * round(0.5 / d)


def test_fine_tank_stays_at_rest_in_its_first_frame():
    """The fine tank (r = 0.0125 m, 11,520 particles, DFSPH at its defaults) over its first frame (1/24 s): a
    lattice at rest density that fills its tank stays nearly at rest, mean |v| < 1e-2 m/s (the first steps'
    g dt of the uncompressed start), and the walls carry the water's weight, sum_i F_i,z = M g within 3 %.
    Before, the water spread into the 0.22 d of slack: mean |v| 0.14 m/s and the walls' load 2.4 M g at 0.04 s."""
    scene = load_case_scene(CASES["hydrostatic"], "dfsph", 0.0125)
    sim = Simulation(scene)
    sim.advance_frame()
    m = sim.model
    v = np.linalg.norm(sim.get_field("particle_v"), axis=1)
    load = float(sim.get_field("boundary_force")[:, 2].sum()) / (m.fluid_count * m.particle_mass * G)
    assert v.mean() < 1e-2, v.mean()
    assert load == pytest.approx(1.0, abs=3e-2)


def test_bench_reads_the_mean_speed_of_the_last_frame(tmp_path):
    """The case's run keeps its last frame's state (a checkpoint at the first and last frame) and ``evaluate``
    reports its mean |v| (the issue's at-rest figure), equal to that of the same scene stepped frame by frame with
    ``Simulation.advance_frame`` to the same time (coarse tank, 3 frames)."""
    from warp_sph.io import run_folder as rf
    from warp_sph.run import runner
    from warp_sph.validation.cases import evaluate

    scene = load_case_scene(CASES["hydrostatic"], "dfsph", 0.025, ["duration=0.125"])
    info = runner.run(scene, out=tmp_path / "run", progress=False, log=lambda *a: None)
    fig, met, _ = evaluate("hydrostatic", tmp_path / "run", info)
    frames = sorted(p.name for p in (tmp_path / "run" / "checkpoints").glob("checkpoint_*.npz"))
    assert frames == ["checkpoint_000001.npz", "checkpoint_000004.npz"]  # frame 1 is t = 0
    sim = Simulation(scene)
    for _ in range(3):
        sim.advance_frame()
    expect = float(np.linalg.norm(sim.get_field("particle_v"), axis=1).mean())
    assert expect > 1e-4 and fig["mean_speed_final"] == pytest.approx(expect, rel=1e-3)
    assert met["settled"] is (expect < 1e-3)
    assert rf.latest_checkpoint(tmp_path / "run").name == frames[-1]


@pytest.mark.parametrize("radius", [0.025, 0.0125])
def test_fcc_tank_fills_its_width_at_both_radii(radius):
    """The hydrostatic_fcc case's tank is the fcc block's own width, d + (n - 1) d / sqrt(2) nearest 0.6 m (n = 17
    columns at d = 0.05 m, 34 at 0.025 m): the outer fcc columns rest one wall gap from their walls' particle
    planes on all four sides (as the cubic case's water fills its 0.6 m tank), and the probes stand at its centre.
    A width rounded below the exact one drops a column (1,664 instead of 1,879 particles at r = 0.025 m, floor
    -2.05 % against -0.94 %)."""
    from warp_sph.validation.cases import fcc_tank_width

    scene = load_case_scene(CASES["hydrostatic_fcc"], "dfsph", radius)
    x = sample_scene(scene).fluid_x.astype(np.float64)
    d, g, c = 2.0 * radius, scene.wall_gap, scene.container
    w = fcc_tank_width(d)
    n = round((w - d) / (d / np.sqrt(2.0))) + 1
    assert abs(w - 0.6) <= d / np.sqrt(2.0) / 2
    assert len(np.unique(np.round(x[:, 0] / (d / np.sqrt(2.0))))) == n
    np.testing.assert_allclose(x.min(axis=0)[:2] - np.asarray(c.min)[:2], g, atol=0.01 * d)
    np.testing.assert_allclose(np.asarray(c.max)[:2] - x.max(axis=0)[:2], g, atol=0.01 * d)
    for p in scene.to_dict()["probes"]:
        assert p["position"][:2] == pytest.approx([w / 2, w / 2], abs=1e-9)
