"""Whitewater ([whitewater], warp_sph/run/whitewater.py): off costs nothing, the potentials against a NumPy
oracle, generation at an impact and decay with the lifetimes, none in a tank at rest, each kind's motion
against its analytic law, a resume bit for bit, bad input refused in one line."""
from __future__ import annotations

import numpy as np
import pytest

from warp_sph.cli import main
from warp_sph.core.errors import SceneError
from warp_sph.run import runner
from warp_sph.run.simulation import Simulation
from warp_sph.run.whitewater import KINDS
from warp_sph.scene import scene_from_dict

from small_scenes import small_tank, stage
from sph_oracle import fluid_sums, grad_W, grid_sample

G = 9.81


def quiet(*a, **k):
    pass


def drop_scene(**ww):
    """A 0.3 x 0.2 x 0.3 m block (r = 0.02 m, 245 particles) 0.3 m above the floor: impact at t = 0.25 s at
    2.4 m/s; generation only above 2.24 m/s (kinetic_energy_min 2.5 J/kg), i.e. from t = 0.23 s on."""
    w = {"kinetic_energy_min": 2.5, "kinetic_energy_max": 5.0, "trapped_air_min": 1.0, "trapped_air_max": 8.0,
         "lifetime_min": 0.05, "lifetime_max": 0.1, **ww}
    return {"name": "ww_drop", "particle_radius": 0.02, "duration": 0.6, "fps": 25.0,
            "container": {"min": [0.0, 0.0, 0.0], "max": [0.6, 0.3, 1.0]},
            "fluid": [{"min": [0.05, 0.05, 0.3], "max": [0.35, 0.25, 0.6]}],
            "output": {"usd": False, "surface": False}, "whitewater": w}


def inject(sim, x_world, v, kind=2, life=10.0):
    """Put secondary particles into the simulation (through the checkpoint path)."""
    x = np.atleast_2d(np.asarray(x_world, float))
    n = len(x)
    sim.whitewater.restore_arrays({
        "whitewater_x": sim.model.to_local(x).astype(np.float32),
        "whitewater_v": np.broadcast_to(np.asarray(v, np.float32), (n, 3)).copy(),
        "whitewater_age": np.zeros(n, np.float32), "whitewater_life": np.full(n, life, np.float32),
        "whitewater_kind": np.full(n, kind, np.int32), "whitewater_counters": np.zeros(3, np.int64)})


def state(sim):
    a = sim.whitewater.host_arrays()
    return sim.model.to_world(a["x"]), a["v"], a["kind"]


def test_off_has_no_stage_and_on_runs_last():
    plain = Simulation(small_tank("plain"))
    assert plain.whitewater is None and "whitewater" not in plain.graph.names()
    assert "whitewater" not in plain.fields
    off = Simulation(small_tank("off", whitewater={"enabled": False}))
    assert off.whitewater is None and "whitewater" not in off.graph.names()
    on = Simulation(small_tank("on", whitewater={}))
    assert on.graph.names()[-1] == "whitewater"
    assert on.summary()["whitewater"]["max_particles"] == 200_000


def oracle_potentials(x, v, rho, m, H, kernel_grad, c):
    """Ihmsen et al. 2012 potentials by brute force over all pairs (float64)."""
    d = x[:, None, :] - x[None, :, :]                      # x_ij
    r = np.linalg.norm(d, axis=2)
    near = (r < H) & (r > 0)
    w = np.where(near, 1.0 - r / H, 0.0)
    grad = kernel_grad(d, r)                                # grad_i W_ij
    normal = -np.einsum("ij,ijk->ik", np.where(near, m / rho[None, :], 0.0), grad)
    surface = np.linalg.norm(normal, axis=1) * H >= 0.25
    nhat = normal / np.maximum(np.linalg.norm(normal, axis=1), 1e-30)[:, None]
    vij = v[:, None, :] - v[None, :, :]
    s = np.linalg.norm(vij, axis=2)
    cos = np.einsum("ijk,ijk->ij", vij / np.maximum(s, 1e-30)[..., None], d / np.maximum(r, 1e-30)[..., None])
    trapped = (np.where(s > 0, s * (1 - cos), 0.0) * w).sum(axis=1)
    convex = np.einsum("ijk,ik->ij", -d, nhat) < 0
    pair = surface[:, None] & surface[None, :] & convex
    curv = (np.where(pair, 1 - nhat @ nhat.T, 0.0) * w).sum(axis=1)
    speed = np.linalg.norm(v, axis=1)
    crest = surface & (np.einsum("ik,ik->i", v / np.maximum(speed, 1e-30)[:, None], nhat) >= 0.6)
    curv = np.where(crest, curv, 0.0)

    def clamp(i, lo, hi):
        return (np.minimum(i, hi) - np.minimum(i, lo)) / (hi - lo)

    ik = clamp(0.5 * speed**2, c.kinetic_energy_min, c.kinetic_energy_max)
    return np.stack([np.where(ik > 0, clamp(trapped, c.trapped_air_min, c.trapped_air_max), 0),
                     np.where(ik > 0, clamp(curv, c.wave_crest_min, c.wave_crest_max), 0), ik], axis=1)


def test_potentials_match_numpy_oracle(device):
    """A block with a random velocity field: (I_ta, I_wc, I_k) of every particle as the brute-force oracle."""
    scene = small_tank("pot", container=False, gravity=[0.0, 0.0, 0.0],
                       fluid=[{"min": [0.0, 0.0, 0.0], "max": [0.4, 0.3, 0.3]}],
                       whitewater={"kinetic_energy_min": 0.5, "kinetic_energy_max": 8.0, "trapped_air_min": 0.5,
                                   "trapped_air_max": 6.0, "wave_crest_min": 0.2, "wave_crest_max": 2.0})
    sim = Simulation(scene, device=device)
    sim.cell_order = False
    rng = np.random.default_rng(1)
    x = sim.get_field("particle_x") + rng.normal(0, 0.1 * scene.spacing, (sim.model.fluid_count, 3))
    v = rng.normal(0, 2.0, (sim.model.fluid_count, 3)) + [0.0, 0.0, 1.5]
    sim.set_field("particle_x", x)
    sim.set_field("particle_v", v)
    for name in ("neighbors", "density"):
        stage(sim, name).run(sim, 1e-3)
    sim.whitewater.step(1e-3)
    got = sim.whitewater.potential.numpy()
    m = sim.model

    def kernel_grad(d, r):
        return grad_W(scene.smoothing_kernel, d, m.smoothing_length)

    want = oracle_potentials(x - m.origin, v, sim.get_field("particle_density").astype(np.float64), m.particle_mass,
                             m.support_radius, kernel_grad, scene.whitewater)
    assert np.count_nonzero(want[:, 0] > 0) > 10 and np.count_nonzero(want[:, 1] > 0) > 5
    np.testing.assert_allclose(got, want, atol=2e-4)


def test_counts_grow_at_impact_and_decay_with_lifetimes(device):
    sim = Simulation(scene_from_dict(drop_scene()), device=device)
    counts, times = [], []
    for _ in range(15):
        sim.advance_frame()
        counts.append(sim.whitewater.count)
        times.append(sim.state.time)
    counts, times = np.array(counts), np.array(times)
    assert np.all(counts[times < 0.2] == 0)                 # falling slower than the threshold: nothing
    peak = int(np.argmax(counts))
    assert 0.24 <= times[peak] <= 0.45 and counts[peak] > 200  # the impact
    assert sim.whitewater.generated >= counts[peak]
    assert counts[-1] < 0.5 * counts[peak]                  # foam dies within 0.1 s, nothing new
    assert sim.whitewater.dropped == 0


def test_none_generated_in_a_tank_at_rest(device):
    """A pool filling its tank (settling: the coarse lattice moves at up to ~0.9 m/s in its first frames).
    Default thresholds: nothing (slower than sqrt(2 kinetic_energy_min) = 3.2 m/s). With the kinetic gate
    open (kinetic_energy_min = 0) its relative speeds still give no trapped air (0 below 5 m/s)."""
    pool = [{"min": [0.0, 0.0, 0.0], "max": [0.8, 0.6, 0.3]}]
    sim = Simulation(small_tank("rest", fluid=pool, whitewater={}), device=device)
    for _ in range(3):
        sim.advance_frame()
    assert sim.last_frame.max_speed < 3.16
    assert sim.whitewater.generated == 0 and sim.whitewater.count == 0
    gate_open = Simulation(small_tank("rest", fluid=pool, whitewater={"kinetic_energy_min": 0.0}), device=device)
    for _ in range(3):
        gate_open.advance_frame()
        assert gate_open.whitewater.potential.numpy()[:, 0].max() == 0.0


def test_spray_follows_the_ballistic_parabola(device):
    sim = Simulation(small_tank("spray", whitewater={}, output={"usd": False, "surface": False}), device=device)
    x0, v0 = np.array([0.4, 0.3, 0.7]), np.array([0.5, -0.2, 1.0])
    inject(sim, x0, v0, kind=1)
    dt, n = 1e-3, 100
    for _ in range(n):
        sim.step(dt)
    x, v, kind = state(sim)
    t = n * dt
    g = np.array([0.0, 0.0, -G])
    assert kind.tolist() == [1]
    np.testing.assert_allclose(v[0], v0 + g * t, atol=1e-5)
    # symplectic Euler: x_n = x0 + v0 t + g dt^2 n (n + 1) / 2, within dt g t / 2 of the parabola
    np.testing.assert_allclose(x[0], x0 + v0 * t + g * dt**2 * n * (n + 1) / 2, atol=1e-5)
    assert np.abs(x[0] - (x0 + v0 * t + 0.5 * g * t * t)).max() <= 0.5 * dt * G * t + 1e-5


def fluid_average(sim, p):
    """The fluid's velocity at p [m] (world) as the whitewater reads it (NumPy oracles, tests/sph_oracle.py):
    the kernel average sum_j W_j v_j / sum_j W_j (fluid_sampling = walk), or that of the node sums
    interpolated trilinearly (grid)."""
    m = sim.model
    x, v = m.to_local(sim.get_field("particle_x").astype(np.float64)), sim.get_field("particle_v").astype(np.float64)
    args = (sim.scene.smoothing_kernel, m.smoothing_length, m.support_radius, x, v, m.to_local(np.asarray(p, float)))
    if sim.scene.whitewater.fluid_sampling == "grid":
        lo, s, _ = sim.whitewater.node_grid()
        sums = grid_sample(*args, lo, s)[0]
    else:
        sums = fluid_sums(*args)[0]
    return sums[:3] / sums[3]


@pytest.mark.parametrize("sampling", ["grid", "walk"])
def test_bubbles_rise_through_the_fluid(device, sampling):
    """Each step v <- v - dt k_b g + k_d (v~_f - v), x <- x + dt v with v~_f the fluid's velocity as sampled
    (oracle), inside a settling pool; relative to the fluid the bubble rises."""
    c = {"buoyancy": 2.0, "drag": 0.5, "fluid_sampling": sampling}
    sim = Simulation(small_tank("bubble", fluid=[{"min": [0.0, 0.0, 0.0], "max": [0.8, 0.6, 0.3]}], whitewater=c),
                     device=device)
    inject(sim, [0.4, 0.3, 0.15], [0.0, 0.0, 0.0], kind=3)
    dt = 2e-3
    g = np.array([0.0, 0.0, -G])
    for _ in range(15):
        x0, v0, _ = state(sim)
        sim.step(dt)
        x, v, kind = state(sim)
        vf = fluid_average(sim, x0[0])
        want = v0[0] - dt * c["buoyancy"] * g + c["drag"] * (vf - v0[0])
        np.testing.assert_allclose(v[0], want, atol=1e-5)
        np.testing.assert_allclose(x[0], x0[0] + dt * want, atol=1e-6)
    assert kind.tolist() == [3]
    # relative to the fluid around it: up, at about the terminal dt k_b |g| / k_d
    assert (v[0] - vf)[2] == pytest.approx(dt * c["buoyancy"] * G / c["drag"], rel=0.5)


def test_foam_moves_with_a_uniform_flow_and_ages(device):
    u = np.array([1.0, 0.5, 0.0])
    sim = Simulation(small_tank("flow", container=False, gravity=[0.0, 0.0, 0.0],
                                fluid=[{"min": [0.0, 0.0, 0.0], "max": [0.6, 0.5, 0.5], "velocity": u.tolist()}],
                                whitewater={"spray_neighbors": 1, "bubble_neighbors": 10_000}), device=device)
    x0 = np.array([0.3, 0.25, 0.25])
    inject(sim, x0, [0.0, 0.0, 0.0], kind=2, life=0.015)
    dt = 1e-3
    for _ in range(10):
        sim.step(dt)
    x, v, kind = state(sim)
    np.testing.assert_allclose(v[0], u, atol=1e-4)
    np.testing.assert_allclose(x[0], x0 + u * 10 * dt, atol=1e-5)
    assert kind.tolist() == [2] and sim.whitewater.host_arrays()["age"][0] == pytest.approx(0.01, rel=1e-4)
    for _ in range(6):  # its lifetime ends after 15 steps
        sim.step(dt)
    assert sim.whitewater.count == 0


def run_drop(out, frames, **kw):
    d = drop_scene()
    d["output"] = {"usd": True, "surface": False, "checkpoint_every": 2}
    return runner.run(scene_from_dict(d), out=out, frames=frames, progress=False, device="cpu",
                      threaded_export=False, log=quiet, **kw)


def test_resume_continues_bit_for_bit(tmp_path):
    from pxr import Usd, UsdGeom

    ref, cut = tmp_path / "ref", tmp_path / "cut"
    run_drop(ref, 9)
    run_drop(cut, 7)  # checkpoints at 1, 3, 5, 7
    (cut / "checkpoints" / "checkpoint_000007.npz").unlink()  # stopped before it: resume from frame 5
    runner.run(None, resume=cut, frames=9, progress=False, device="cpu", threaded_export=False, log=quiet)
    a = np.load(ref / "checkpoints" / "checkpoint_000009.npz")
    b = np.load(cut / "checkpoints" / "checkpoint_000009.npz")
    assert len(a["whitewater_x"]) > 50
    for k in ("x", "v", "age", "life", "kind", "counters"):
        np.testing.assert_array_equal(a[f"whitewater_{k}"], b[f"whitewater_{k}"], err_msg=k)
    stages = [Usd.Stage.Open(str(p / "ww_drop.usdc")) for p in (ref, cut)]
    for name in KINDS:
        pts = [np.asarray(UsdGeom.Points(s.GetPrimAtPath(f"/sph/whitewater/{name}")).GetPointsAttr().Get(9))
               for s in stages]
        np.testing.assert_array_equal(pts[0], pts[1])
    foam = [UsdGeom.PrimvarsAPI(s.GetPrimAtPath("/sph/whitewater/foam")) for s in stages]
    ages = [np.asarray(f.GetPrimvar("age").Get(9)) for f in foam]
    np.testing.assert_array_equal(ages[0], ages[1])
    assert len(ages[0]) == len(UsdGeom.Points(stages[0].GetPrimAtPath("/sph/whitewater/foam")).GetPointsAttr().Get(9))


def test_full_capacity_drops_new_particles_with_one_warning(device):
    sim = Simulation(scene_from_dict(drop_scene(max_particles=40)), device=device)
    with pytest.warns(RuntimeWarning, match="whitewater.max_particles = 40 is full") as record:
        for _ in range(9):
            sim.advance_frame()
    assert len([w for w in record if "max_particles" in str(w.message)]) == 1
    assert sim.whitewater.dropped > 0 and sim.whitewater.count <= 40
    assert sim.whitewater.generated - sim.whitewater.dropped >= sim.whitewater.count  # births kept


@pytest.mark.parametrize("table, message", [
    ("lifetime_min = -1.0", "whitewater.lifetime_min: expected a finite number > 0, got -1"),
    ("lifetime_min = 3.0\nlifetime_max = 2.0", "whitewater.lifetime_max: expected >= whitewater.lifetime_min (3)"),
    ("trapped_air_min = 20.0\ntrapped_air_max = 5.0",
     "whitewater.trapped_air_max: expected > whitewater.trapped_air_min"),
    ("wave_crest_max = 0.0", "whitewater.wave_crest_max: expected a finite number > 0"),
    ("foam_rate = 3.0", "whitewater.foam_rate: unknown key; expected one of enabled, seed"),
    ("max_particles = 0", "whitewater.max_particles: expected an integer >= 1"),
])
def test_bad_input_one_line_exit_2(tmp_path, capsys, table, message):
    scene = tmp_path / "s.toml"
    scene.write_text('particle_radius = 0.05\n[container]\nmin = [0, 0, 0]\nmax = [0.8, 0.6, 0.8]\n'
                     f'[[fluid]]\nmin = [0, 0, 0]\nmax = [0.6, 0.5, 0.5]\n[whitewater]\n{table}\n')
    out = tmp_path / "never"
    assert main(["run", str(scene), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not out.exists()
    with pytest.raises(SceneError):
        from warp_sph.scene.load import load_scene

        load_scene(str(scene))
