"""Numerical stability at the extremes (physics notes section 6): time steps around the bound, tiny
systems, rest lattices, stiff/soft/viscous fluids, impacts, long hydrostatic runs, far-away
coordinates; and the watchdog and pre-flight checks that turn a blow-up into a clear error.

Every scene here is small (tens to a few hundred particles, particle_radius 0.05 m) so the file
runs in about a minute on one CPU core.
"""
import math
import warnings

import numpy as np
import pytest
import warp as wp

from warp_sph.core.errors import SceneError, SimulationError
from warp_sph.run.preflight import PreflightWarning, preflight_checks, time_step_bounds
from warp_sph.scene import scene_from_dict
from warp_sph.run.simulation import Simulation
from warp_sph.core.step_graph import Stage

KERNELS = ["cubic", "quintic", "quadric"]


def make_scene(base: dict, **kw):
    d = dict(base)
    for k, v in kw.items():
        if isinstance(v, dict) and isinstance(d.get(k), dict):
            d[k] = {**d[k], **v}
        else:
            d[k] = v
    d.setdefault("output", {"usd": False, "surface": False})
    d.setdefault("solver", "wcsph")  # these extremes are WCSPH's (the default solver until DFSPH); others are named
    return scene_from_dict(d)


DAM = {
    "name": "small_dam",
    "particle_radius": 0.05,
    "fps": 30.0,
    "container": {"min": [0.0, 0.0, 0.0], "max": [1.6, 0.6, 1.2]},
    "fluid": [{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.8, 0.6, 0.8]}],
}


def dam(**kw):
    return make_scene(DAM, **kw)


def free(n_box=(1, 1, 1), gravity=(0.0, 0.0, -9.81), **kw):
    """A block of n_box lattice points with no container (d = 0.1 m)."""
    d = 0.1
    base = {"name": "free", "particle_radius": 0.05, "fps": 30.0, "container": False, "gravity": list(gravity),
            "fluid": [{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [n * d for n in n_box]}]}
    return make_scene(base, **kw)


def frames(sim, n):
    return [sim.advance_frame() for _ in range(n)]


# --------------------------------------------------------------------------------------------
# 1. time step 0.25x, 1x, 4x the bound
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def acoustic_bound():
    sim = Simulation(dam())
    bounds = time_step_bounds(sim)
    assert set(bounds) == {"acoustic CFL"}
    return bounds["acoustic CFL"]


@pytest.fixture(scope="module")
def reference_run(acoustic_bound):
    """Kinetic energy per frame at 0.25x the bound: the converged reference."""
    sim = Simulation(dam(time={"fixed_dt": 0.25 * acoustic_bound}))
    return [s.kinetic_energy for s in frames(sim, 8)]


@pytest.mark.parametrize("factor", [0.25, 1.0, 4.0])
def test_time_step_sweep(factor, acoustic_bound, reference_run, device):
    scene = dam(time={"fixed_dt": factor * acoustic_bound})
    sim = Simulation(scene, device=device)
    if factor > 1.0:
        # above the bound: refused before the first step, with the bound in the message
        with pytest.raises(SceneError, match=r"time\.fixed_dt.*acoustic CFL time-step bound"):
            preflight_checks(scene, sim)
        # adaptive steps: the same scene without fixed_dt stays below the bound every frame
        sim = Simulation(dam(), device=device)
        speed = sim.statistics().max_speed
        for s in frames(sim, 4):
            assert s.dt_max <= min(time_step_bounds(sim, speed).values()) * (1 + 1e-9)
            speed = s.max_speed
        return
    preflight_checks(scene, sim)
    ke = [s.kinetic_energy for s in frames(sim, 8)]  # advance_frame raises on NaN or escape
    assert all(math.isfinite(e) for e in ke)
    # stable and converged: the kinetic energy follows the 0.25x run (measured: within 2.7 % at 1x)
    np.testing.assert_allclose(ke, reference_run, rtol=0.10, atol=0.5)


def test_far_above_bound_is_never_a_silent_nan(acoustic_bound, device):
    """8x the bound, pre-flight bypassed: the energy rule stops the run (the energy rises before any
    particle escapes) and names the frame, the rise and the cause; with the energy rule off (a test-only
    switch), the device rules catch the blow-up later and the replay names stage, step, particle."""
    sim = Simulation(dam(time={"fixed_dt": 8 * acoustic_bound}), device=device)
    with pytest.raises(SimulationError) as err:
        frames(sim, 12)
    msg = str(err.value)
    assert msg.startswith("the total energy rose by") and "by frame" in msg
    assert "likely cause: time step too large" in msg
    assert "\n" not in msg
    sim = Simulation(dam(time={"fixed_dt": 8 * acoustic_bound}), device=device)
    sim.watchdog.energy.limit = lambda: math.inf
    with pytest.raises(SimulationError) as err:
        frames(sim, 12)
    msg = str(err.value)
    assert "stage '" in msg and "at step" in msg and "particle" in msg
    assert "likely cause: time step too large" in msg
    assert "\n" not in msg


# --------------------------------------------------------------------------------------------
# 2. tiny systems
# --------------------------------------------------------------------------------------------
def test_single_particle_free_fall(device):
    """x_n = x0 + v0 t_n + g dt^2 n(n+1)/2 (semi-implicit Euler); density m W(0), no NaN."""
    v0 = np.array([0.5, 0.0, 1.0])
    sim = Simulation(free(fluid=[{"shape": "box", "min": [0, 0, 0], "max": [0.1, 0.1, 0.1],
                                  "velocity": list(v0)}], time={"fixed_dt": 1e-3}), device=device)
    assert sim.model.fluid_count == 1
    x0 = sim.get_field("particle_x")[0]
    g = np.array([0.0, 0.0, -9.81])
    n = 0
    for _ in range(6):
        s = sim.advance_frame()
        dt = s.dt_max
        n += s.steps
        t = n * dt
        expected = x0 + v0 * t + g * dt * dt * n * (n + 1) / 2
        np.testing.assert_allclose(sim.get_field("particle_x")[0], expected, rtol=0, atol=2e-5)
        np.testing.assert_allclose(sim.get_field("particle_v")[0], v0 + g * t, rtol=0, atol=2e-5)
    # O(dt) offset against the exact parabola: g dt t / 2
    exact = x0 + v0 * t + 0.5 * g * t * t
    np.testing.assert_allclose(sim.get_field("particle_x")[0] - exact, 0.5 * g * dt * t, atol=2e-5)
    from sph_oracle import W

    m = sim.model
    rho = sim.get_field("particle_density")[0]
    assert rho == pytest.approx(m.particle_mass * W(m.smoothing.name, np.array(0.0), m.smoothing_length), rel=1e-5)


def _pair(separation, velocity=(0.0, 0.0, 0.0), device=None, **kw):
    """Two particles (no gravity, no container) ``separation`` [m] apart along x, approaching."""
    sim = Simulation(free(n_box=(2, 1, 1), gravity=(0.0, 0.0, 0.0), **kw), device=device)
    o = sim.model.origin
    x = np.array([o - [separation / 2, 0, 0], o + [separation / 2, 0, 0]])
    sim.set_field("particle_x", x)
    sim.set_field("particle_v", np.array([velocity, np.negative(velocity)]))
    sim.refresh_density()
    return sim


def test_two_particles_equal_and_opposite(device):
    """Viscous pair (isolated particles are under-dense, so the clamped pressure is zero): the forces
    are equal and opposite and the momentum is conserved to float32 rounding."""
    sim = _pair(0.12, velocity=(1.0, 0.3, -0.2), material={"viscosity": 0.05}, time={"fixed_dt": 1e-4}, device=device)
    m = sim.model
    for _ in range(50):
        sim.step(1e-4)
        a = sim.fields["particle_acceleration"].numpy().astype(np.float64)
        assert np.linalg.norm(a[0]) > 0
        np.testing.assert_allclose(a[0], -a[1], rtol=1e-6, atol=1e-6 * np.linalg.norm(a[0]))
    v = sim.get_field("particle_v").astype(np.float64)
    np.testing.assert_allclose(v.sum(0), 0.0, atol=1e-6)
    assert np.all(np.isfinite(v))
    # the viscosity slowed the approach
    assert abs(v[0, 0]) < 1.0 and m.fluid_count == 2


def test_compressed_cluster_conserves_momentum(device):
    """27 particles squeezed to 0.7 d and jittered, no gravity: pressure pushes them apart, the total
    momentum stays zero (pairwise antisymmetric pressure forces). Without viscosity: the explicit
    viscosity (SPlisHSPlasH 'standard' form, m/rho_j) is not antisymmetric when rho_i != rho_j
    (measured: net momentum 0.1 kg m/s here with nu = 0.01). cfl 0.1: the first frame's steps are sized
    for the start at rest, and the explosive expansion (0.5 c_s) then gains energy in first order of dt:
    7.3, 2.2, 0.48 % of the compression energy at cfl 0.4, 0.2, 0.1, which the energy rule stops above 1 %."""
    sim = Simulation(free(n_box=(3, 3, 3), gravity=(0.0, 0.0, 0.0), time={"cfl": 0.1}), device=device)
    x = sim.get_field("particle_x")
    c = x.mean(0)
    rng = np.random.default_rng(1)
    x = c + 0.7 * (x - c) + rng.uniform(-0.05, 0.05, x.shape) * 0.1
    sim.set_field("particle_x", x)
    sim.refresh_density()
    s = frames(sim, 3)[-1]
    assert s.kinetic_energy > 1e-3  # it did expand
    v = sim.get_field("particle_v").astype(np.float64)
    speed_scale = np.abs(v).max()
    np.testing.assert_allclose(v.sum(0), 0.0, atol=1e-5 * speed_scale * len(v))


@pytest.mark.parametrize("boundary", ["none", "akinci2012", "penalty"])
def test_coincident_particles(boundary, device):
    """Two fluid particles at the same point (r = 0), and one on top of a wall particle: no NaN."""
    if boundary == "none":
        sim = Simulation(free(n_box=(3, 3, 3), material={"viscosity": 0.01, "xsph": 0.1}), device=device)
    else:
        sim = Simulation(dam(boundary=boundary, material={"viscosity": 0.01, "xsph": 0.1, "boundary_friction": 0.2}), device=device)
    x = sim.get_field("particle_x")
    x[1] = x[0]
    if boundary != "none":
        x[2] = sim.get_field("boundary_x")[0]  # a corner wall particle
    sim.set_field("particle_x", x)
    sim.refresh_density()
    sim.check_health(sim.statistics())
    for _ in range(5):
        sim.step(1e-4)
        for name in ("particle_x", "particle_v", "particle_density", "particle_acceleration"):
            assert np.all(np.isfinite(sim.get_field(name))), name


@pytest.mark.parametrize("kernel", KERNELS)
def test_particle_at_support_radius_feels_no_force(kernel, device):
    """Two particles exactly H_s apart (binary-exact values): W = grad W = 0, so a = g exactly."""
    r = 0.0625  # d = 0.125 m; cubic/quadric h = d, quintic h = 2d/3: H_s = 0.25 m for all three
    sim = Simulation(free(n_box=(2, 1, 1), particle_radius=r, gravity=(0.0, 0.0, 0.0), smoothing_kernel=kernel,
                          material={"viscosity": 0.1}, fluid=[{"shape": "box", "min": [0, 0, 0],
                                                                "max": [0.25, 0.125, 0.125]}]), device=device)
    m = sim.model
    assert m.support_radius == 0.25
    o = m.origin
    sim.set_field("particle_x", np.array([o - [0.125, 0, 0], o + [0.125, 0, 0]]))
    sim.set_field("particle_v", np.array([[1.0, 0, 0], [-1.0, 0, 0]]))
    local = sim.fields["particle_x"].numpy()
    assert np.linalg.norm(local[1] - local[0]) == np.float32(0.25)
    sim.step(1e-5)
    from sph_oracle import W

    np.testing.assert_array_equal(sim.fields["particle_acceleration"].numpy(), 0.0)
    w0 = W(kernel, np.array(0.0), m.smoothing_length)
    np.testing.assert_allclose(sim.get_field("particle_density"), m.particle_mass * w0, rtol=1e-6)


# --------------------------------------------------------------------------------------------
# 3. zero-gravity rest block
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kernel", KERNELS)
def test_zero_gravity_block_stays_at_rest(kernel, device):
    """A 6x6x6 lattice block at rest, no gravity, no container: calibrated mass and clamped pressure
    keep it still. 500 steps at the acoustic bound; max |v| < 1e-4 m/s and drift < 1e-3 d."""
    sim = Simulation(free(n_box=(6, 6, 6), gravity=(0.0, 0.0, 0.0), smoothing_kernel=kernel), device=device)
    x0 = sim.get_field("particle_x")
    dt = min(time_step_bounds(sim).values())
    for _ in range(500):
        sim.step(dt)
    s = sim.statistics()
    assert s.non_finite == 0
    assert s.max_speed < 1e-4
    drift = np.abs(sim.get_field("particle_x") - x0).max()
    assert drift < 1e-3 * sim.model.spacing


# --------------------------------------------------------------------------------------------
# 4. very stiff, very soft, PBF iterations, very viscous
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("factor,max_density_error", [(40.0, 0.01), (3.0, 0.5)])
def test_wcsph_stiffness_extremes(factor, max_density_error, device):
    """c_s = 40 v_ref (stiff: 4x the steps, density error well under 1 %) and c_s = 3 v_ref (soft:
    compression ~ (v/c_s)^2 ~ 10 %, but it must stay finite, inside and bounded)."""
    sim = Simulation(dam(wcsph={"speed_of_sound_factor": factor}), device=device)
    stats = frames(sim, 6)
    assert max(s.density_error_max for s in stats) < max_density_error
    assert max(s.max_speed for s in stats) < 2.0 * sim.model.reference_speed
    if factor > 10:  # the acoustic bound scales as 1/c_s: about 4x the steps of the default factor 10
        default_steps = math.ceil(sim.frame_dt / Simulation(dam(), device=device).time_step(0.0))
        assert stats[0].steps >= 3 * default_steps


@pytest.mark.parametrize("iterations", [1, 100])
def test_pbf_iterations(iterations, device):
    pytest.importorskip("warp_sph.methods.solvers.pbf")
    sim = Simulation(dam(solver="pbf", pbf={"min_iterations": iterations, "max_iterations": iterations}), device=device)
    stats = frames(sim, 6)
    assert all(s.non_finite == 0 and s.outside == 0 for s in stats)
    assert max(s.max_speed for s in stats) < 2.0 * sim.model.reference_speed
    limit = 0.5 if iterations == 1 else 0.05
    assert max(s.density_error_max for s in stats) < limit


VISCOUS_BOUND_XFAIL = pytest.mark.xfail(
    strict=True, reason="wcsph.time_step_bound: 0.125 (H_s/2)^2/nu is too loose for the 10-nu explicit form; "
    "measured on this column (nu = 1, d = 0.05): stable at 0.8x, thrown to the ceiling at 1x; use 0.0625")


@pytest.mark.parametrize("viscosity,fixed", [(0.1, 0.0), (1.0, 0.0),
                                             (1.0, 0.5)])
def test_viscous_column_spreads_monotonically(viscosity, fixed, device):
    """A column (0.3 x 0.3 x 0.6 m, d = 0.05 m) with nu up to 1 m^2/s slumps: its height falls and
    its footprint grows monotonically, no oscillation, no explosion; at nu = 1 the viscous bound
    0.125 (H_s/2)^2/nu binds (adaptive, fixed = 0) or the step is ``fixed`` x that bound."""
    base = {"name": "column", "particle_radius": 0.025, "fps": 20.0,
            "container": {"min": [0.0, 0.0, 0.0], "max": [1.2, 1.2, 0.8]},
            "fluid": [{"shape": "box", "min": [0.45, 0.45, 0.0], "max": [0.75, 0.75, 0.6]}],
            "material": {"viscosity": viscosity}}
    sim = Simulation(make_scene(base), device=device)
    bounds = time_step_bounds(sim)
    if fixed:
        sim = Simulation(make_scene(base, time={"fixed_dt": fixed * bounds["viscous"]}), device=device)
    heights, widths = [], []

    def measure():
        x = sim.get_field("particle_x")
        heights.append(x[:, 2].mean())
        c = x[:, :2].mean(0)
        widths.append(np.sqrt(((x[:, :2] - c) ** 2).sum(1).mean()))

    measure()
    for _ in range(6):
        s = sim.advance_frame()
        measure()
    if viscosity >= 1.0:
        assert bounds["viscous"] < bounds["acoustic CFL"]
        assert s.dt_max <= bounds["viscous"] * (1 + 1e-9)
    tol = 1e-3 * sim.model.spacing
    assert np.all(np.diff(heights) <= tol), heights
    assert np.all(np.diff(widths) >= -tol), widths
    assert heights[-1] < heights[0] - 0.5 * sim.model.spacing  # it did slump


# --------------------------------------------------------------------------------------------
# 5. impact: a block dropped from 10x its height
# --------------------------------------------------------------------------------------------
def test_block_dropped_from_ten_heights_stays_above_floor(device):
    base = {"name": "drop", "particle_radius": 0.05, "fps": 20.0,
            "container": {"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 2.6]},
            "fluid": [{"shape": "box", "min": [0.25, 0.25, 2.0], "max": [0.75, 0.75, 2.2]}]}
    sim = Simulation(make_scene(base), device=device)
    lowest = []
    for s in frames(sim, 16):  # fall time 0.64 s, impact and splash until 0.8 s
        x = sim.get_field("particle_x")
        lowest.append(x[:, 2].min())
        assert s.outside == 0
    assert max(s.max_speed for s in [s]) < 2 * sim.model.reference_speed
    assert min(lowest) > 0.0, lowest   # no particle through the floor plane z = 0


# --------------------------------------------------------------------------------------------
# 6. a hydrostatic tank for 10^4 steps
# --------------------------------------------------------------------------------------------
def test_hydrostatic_tank_long_run(device):
    """10^4 steps of a coarse tank (0.8 x 0.8 x 0.5 m of water, d = 0.1 m, ~180 particles) with the
    damping overrides material.viscosity = 0.005, xsph = 0.1 (without them the default WCSPH sloshes
    at ~2 m/s with boundary_pressure 'eq16' and blows up within 1.4 s with 'mirrored'): no leak, no
    creep, and the walls carry the weight M g (averaged over the last 500 steps) within 3 %
    (measured: mean height range 1.1 % d over the second half, wall load 0.995 M g)."""
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([0.8, 0.8, 0.8])
    base = {"name": "tank", "particle_radius": 0.05, "fps": 1.0,
            "container": {"min": list(lo), "max": list(hi)},
            "fluid": [{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.8, 0.8, 0.5]}],
            "material": {"viscosity": 0.005, "xsph": 0.1}}
    sim = Simulation(make_scene(base), device=device)
    n0 = sim.model.fluid_count
    mass = n0 * sim.model.particle_mass
    steps = 0
    heights = []
    while steps < 9500:
        s = sim.advance_frame()
        steps += s.steps
        heights.append(sim.get_field("particle_x")[:, 2].mean())
    dt = s.dt_max
    fz = 0.0
    for _ in range(500):
        sim.step(dt)
        fz += sim.fields["boundary_force"].numpy()[:, 2].astype(np.float64).sum() / 500
    steps += 500
    s = sim.statistics()
    x = sim.get_field("particle_x")
    assert sim.model.fluid_count == n0 and steps >= 10_000
    assert np.all((x > lo) & (x < hi)), "a particle leaked through a wall"
    # residual sloshing (measured 0.05 v_ref = 0.15 m/s after 10^4 steps; the WCSPH damping is being tuned)
    assert s.max_speed < 0.1 * sim.model.reference_speed, s.max_speed
    # no creep: the mean height moved less than 2 % of d over the second half of the run
    half = heights[len(heights) // 2:]
    assert max(half) - min(half) < 0.02 * sim.model.spacing, half
    assert fz == pytest.approx(mass * 9.81, rel=0.03)


# --------------------------------------------------------------------------------------------
# 7. coordinates far from the origin
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def dam_at_origin():
    sim = Simulation(dam())
    stats = frames(sim, 6)
    return sim.get_field("particle_x")[:, 0].max(), [s.kinetic_energy for s in stats]


@pytest.mark.parametrize("offset", [1e2, 1e3, 1e4])
def test_far_from_origin(offset, dam_at_origin, device):
    """The dam break translated by (offset, offset/2, offset/3) m: same front and kinetic energy."""
    shift = np.array([offset, offset / 2, offset / 3])
    c = DAM["container"]
    f = DAM["fluid"][0]
    scene = dam(container={"min": list(np.add(c["min"], shift)), "max": list(np.add(c["max"], shift))},
                fluid=[{**f, "min": list(np.add(f["min"], shift)), "max": list(np.add(f["max"], shift))}])
    sim = Simulation(scene, device=device)
    if sim.sampled.fluid_x.dtype != np.float64:
        pytest.xfail("sampling.SampledScene stores world positions in float32 (ulp 6e-5 m at 10^3 m, 1e-3 m at "
                     "10^4 m) before the model subtracts the local origin; measured front differences 2-3.5 mm "
                     "and KE 0.7-8 %; with float64 sampled positions 1.7e-6 m and 4e-5 up to 10^5 m")
    stats = frames(sim, 6)
    front = sim.get_field("particle_x")[:, 0].max() - shift[0]
    front0, ke0 = dam_at_origin
    # tolerance: the dam break is chaotic (a 1e-6 m jitter at the origin moves the front 3e-4 m by
    # frame 6), so the local origin must reproduce it far better than that
    assert abs(front - front0) < 1e-3 * sim.model.spacing
    np.testing.assert_allclose([s.kinetic_energy for s in stats], ke0, rtol=1e-3)


# --------------------------------------------------------------------------------------------
# 8. the watchdog: names the stage, retries, keeps the frames written so far
# --------------------------------------------------------------------------------------------
def _poison_stage(at_step, particle=7, field="particle_density", when=None):
    """A stage that writes NaN into one particle's value at a given step (and dt condition)."""

    def run(sim, dt):
        if sim.state.step + 1 == at_step and (when is None or when(dt)):
            a = sim.fields[field]
            vals = a.numpy()
            vals[particle] = np.nan
            a.assign(wp.array(vals, dtype=a.dtype, device=a.device))

    return Stage("poison", run, reads=(field,), updates=(field,), doc="test: writes a NaN")


def test_watchdog_names_stage_step_and_particle(device):
    sim = Simulation(dam(), device=device)
    sim.graph.insert(_poison_stage(at_step=40), after="density")
    with pytest.raises(SimulationError) as err:
        frames(sim, 3)
    msg = str(err.value)
    assert "stage 'poison' produced a non-finite value in particle_density at step 40" in msg
    assert "particle 7" in msg and "t = " in msg
    assert "not one of the wcsph solver's own stages" in msg


def test_watchdog_first_stage_of_a_propagating_nan(device):
    """A NaN velocity spreads to every field within a step; the replay names the stage that made it."""
    sim = Simulation(dam(), device=device)
    sim.graph.insert(_poison_stage(at_step=5, particle=3, field="particle_v"), before="integrate")
    with pytest.raises(SimulationError, match=r"stage 'poison' produced a non-finite value in particle_v at step 5"):
        frames(sim, 1)


def test_watchdog_retry_halves_the_step(device):
    """on_instability = 'retry': a fault that only appears with a large step is retried away."""
    sim = Simulation(dam(time={"on_instability": "retry"}), device=device)
    dt0 = min(time_step_bounds(sim).values())
    sim.graph.insert(_poison_stage(at_step=3, field="particle_v", when=lambda dt: dt > 0.3 * dt0),
                     before="integrate")
    s = sim.advance_frame()
    assert s.retries >= 2 and s.non_finite == 0
    assert s.dt_max <= 0.3 * dt0
    later = frames(sim, 3)
    assert all(f.retries == 0 for f in later)
    assert later[-1].dt_max > 2 * s.dt_max  # the reduction relaxes again, doubling per clean frame


def test_watchdog_speed_and_escape_rules(device):
    sim = Simulation(dam(), device=device)
    v = sim.get_field("particle_v")
    v[4] = [0.0, 0.0, 100.0 * sim.model.reference_speed]
    sim.set_field("particle_v", v)
    s = sim.statistics()
    assert s.watch["fast"] == 1 and s.watch["first_fast"] == 4
    with pytest.raises(SimulationError, match="faster than the speed limit: particle 4"):
        sim.check_health(s)
    sim = Simulation(dam(), device=device)
    x = sim.get_field("particle_x")
    x[9] = [0.5, 0.3, -1.0]
    sim.set_field("particle_x", x)
    s = sim.statistics()
    assert s.outside == 1
    with pytest.raises(SimulationError, match="outside the container: particle 9"):
        sim.check_health(s)


def test_run_keeps_frames_written_before_a_blow_up(tmp_path, monkeypatch):
    """Through the runner: the error names the stage; every frame written so far stays readable."""
    import json

    from warp_sph.run import runner

    class Poisoned(Simulation):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self.graph.insert(_poison_stage(at_step=100), after="density")

    monkeypatch.setattr(runner, "Simulation", Poisoned)
    scene = dam(output={"usd": False, "surface": False, "checkpoint_every": 0})
    out = tmp_path / "run"
    with pytest.raises(SimulationError, match="stage 'poison'"):
        runner.run(scene, out=out, frames=10, progress=False, threaded_export=False, log=lambda *a: None)
    info = json.loads((out / "run.json").read_text())
    assert info["status"] == "failed"
    written = sorted(p.name for p in (out / "frames").glob("frame_*.npz"))
    steps_per_frame = info["frames"][1]["steps"]
    assert len(written) == 1 + 99 // steps_per_frame
    for p in (out / "frames").glob("frame_*.npz"):
        assert np.all(np.isfinite(np.load(p)["x"]))


# --------------------------------------------------------------------------------------------
# 9. pre-flight checks
# --------------------------------------------------------------------------------------------
def test_preflight_viscous_bound_named():
    """A fixed step above the explicit viscosity's bound is refused when the scene is loaded (the force's
    own check, before any kernel), naming the bound and the implicit method."""
    with pytest.raises(SceneError, match=r"material\.viscosity: the explicit viscous time-step bound .*0\.0625 "
                                         r"\(H_s/2\)\^2/nu.*weiler2018"):
        dam(material={"viscosity": 4.0}, time={"fixed_dt": 5e-4})


def test_preflight_dt_min_above_bound(device):
    scene = dam(time={"dt_min": 4e-3})
    with pytest.raises(SceneError, match=r"time\.dt_min"):
        preflight_checks(scene, Simulation(scene, device=device))


def test_preflight_fluid_inside_obstacles(device):
    obstacle = {"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.5, 0.6, 0.5]}
    scene = dam(obstacles=[obstacle])
    with pytest.warns(PreflightWarning, match=r"sampling removed \d+ of \d+ fluid particles"):
        preflight_checks(scene, Simulation(scene, device=device))
    # a second block entirely inside the obstacle is refused
    scene = dam(obstacles=[obstacle], fluid=DAM["fluid"] + [{"min": [0.1, 0.1, 0.1], "max": [0.3, 0.3, 0.3]}])
    with pytest.raises(SceneError, match=r"fluid\[1\]: all \d+ of its particles lie inside obstacles"):
        preflight_checks(scene, Simulation(scene, device=device))


def test_preflight_lattice_bias_warning(device):
    scene = dam(h_per_spacing=0.6)
    with pytest.warns(PreflightWarning, match=r"rest lattice before mass calibration"):
        preflight_checks(scene, Simulation(scene, device=device))


def test_preflight_clean_scene_has_no_warnings(device):
    scene = dam()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert preflight_checks(scene, Simulation(scene, device=device)) == []


def test_memory_refused_before_sampling(device):
    """10^11 particles: refused from the scene's geometry, before any array is allocated."""
    scene = dam(particle_radius=2e-4)
    with pytest.raises(SceneError, match=r"particle_radius: about [\d,]+ fluid .* memory.*raise particle_radius"):
        Simulation(scene, device=device)


# --------------------------------------------------------------------------------------------
# 10. issue #36: no solver creates energy at the extremes
# --------------------------------------------------------------------------------------------
def energy_above_floor(sim) -> float:
    """Kinetic + potential energy [J] with heights from the container floor (positive, so that "1 % of the
    initial total" means something); float64 sums of the run.json quantities."""
    x, v = sim.get_field("particle_x").astype(np.float64), sim.get_field("particle_v").astype(np.float64)
    g = -float(sim.scene.gravity[2])
    floor = float(sim.scene.container.min[2])
    return sim.model.particle_mass * (0.5 * (v * v).sum() + g * (x[:, 2] - floor).sum())


def corner_block(solver: str, fixed_dt: float, fps: float = 500.0, device=None, **kw):
    """The issue's corner block: 0.3 m of water in the corner of a 0.6 m box, r = 0.025 m (125 particles);
    sampled, its corner and edge particles are 0.79 % and 0.26 % over rest density (the wall gap is calibrated
    on a flat wall); for WCSPH the Akinci sampling relaxes that to 0.03 %."""
    base = {"name": "corner", "particle_radius": 0.025, "fps": fps, "solver": solver,
            "container": {"min": [0.0, 0.0, 0.0], "max": [0.6, 0.6, 0.6]},
            "fluid": [{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.3, 0.3, 0.3]}],
            "time": {"fixed_dt": fixed_dt}}
    return Simulation(make_scene(base, **kw), device=device)


@pytest.mark.parametrize("solver,steps", [("dfsph", (1e-3, 1e-4, 1e-5)), ("pbf", (1e-3, 1e-4, 5e-5))])
def test_smaller_fixed_step_does_not_kick_the_walls(solver, steps, device):
    """Issue #36 finding 1: the corner block over 4 ms at smaller and smaller fixed steps. Main turned the
    walls' start-up over-density into a velocity ~ e d / dt in the first step (DFSPH 26 m/s, PBF 32 m/s at
    1e-5 s; 2.6 and 3.2 m/s at 1e-4 s); now it is corrected over half the adaptive step. Bounds: the
    fastest particle below a tenth of sqrt(2 g H) (H = 0.3 m, the speed of a collapsed block) and no faster
    than at 1e-3 s plus 0.1 m/s; the energy never above 1.001 of the initial total."""
    bound = math.sqrt(2 * 9.81 * 0.3)
    fastest = {}
    for dt in steps:
        sim = corner_block(solver, dt, device=device)
        e0 = energy_above_floor(sim)
        top = 0.0
        for _ in range(2):
            s = sim.advance_frame()
            top = max(top, s.max_speed)
            assert energy_above_floor(sim) <= 1.001 * e0, (dt, energy_above_floor(sim) / e0)
        fastest[dt] = top
    assert max(fastest.values()) < 0.1 * bound, fastest
    assert max(fastest.values()) <= fastest[steps[0]] + 0.1, fastest


def test_pbf_fixed_step_below_float32_floor_is_refused(device):
    """PBF at a fixed 1e-5 s in a 0.6 m box: |g| dt^2 = 1e-9 m is below the float32 spacing of the positions
    (3e-8 m), so the solve's corrections come in whole ulps and the fluid gains energy; pre-flight refuses
    it in one line naming time.fixed_dt and the floor; 5e-5 s passes."""
    scene = make_scene({"name": "corner", "particle_radius": 0.025, "solver": "pbf",
                        "container": {"min": [0.0, 0.0, 0.0], "max": [0.6, 0.6, 0.6]},
                        "fluid": [{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.3, 0.3, 0.3]}],
                        "time": {"fixed_dt": 1e-5}})
    with pytest.raises(SceneError, match=r"time\.fixed_dt: 1e-05 s is below the pbf solver's smallest step "
                                         r"3\.\d+e-05 s \(float32 position resolution") as err:
        preflight_checks(scene, Simulation(scene, device=device))
    assert "\n" not in str(err.value)
    ok = make_scene({**scene.to_dict(), "time": {"fixed_dt": 5e-5}})
    preflight_checks(ok, Simulation(ok, device=device), warn=False)


@pytest.mark.parametrize("wcsph", [{"speed_of_sound": 1000.0}, {"stiffness": 1e8},
                                   {"stiffness": 1e8, "equation_of_state": "tait"}])
def test_stiff_wcsph_gains_no_energy(wcsph, device):
    """Issue #36 finding 5: a stiff WCSPH corner block gained kinetic + potential energy (main: 7.44 J of
    23.7 J in a frame at c_s = 1000 m/s). The step already followed c_s = sqrt(K / rho0) (sqrt(7 B / rho0)
    for Tait); the energy was the elastic energy sum m u(rho), ~ c_s^2 delta^2 / 2 per kg, of the sampled
    start's over-dense corner and edges (0.79 %, 0.26 %), which the Akinci sampling now relaxes away. Bounds:
    kinetic + potential energy within 0.5 % of its start, and with the elastic energy too."""
    sim = corner_block("wcsph", 0.0, fps=120.0, wcsph=wcsph, device=device)
    c = sim.model.speed_of_sound
    if "stiffness" in wcsph:
        k = 7.0 if wcsph.get("equation_of_state") == "tait" else 1.0
        assert c == pytest.approx(math.sqrt(k * wcsph["stiffness"] / 1000.0))
    bound = time_step_bounds(sim, 0.0)["acoustic CFL"]
    assert bound == pytest.approx(sim.scene.time.cfl * 0.5 * sim.model.support_radius / c)
    sim.refresh_density()
    e0, u0 = energy_above_floor(sim), sim.solver.internal_energy()
    sim.advance_frame()
    e1, u1 = energy_above_floor(sim), sim.solver.internal_energy()
    assert e1 <= 1.005 * e0, (e1 - e0, u0)
    assert e1 + u1 <= 1.005 * (e0 + u0)


def test_akinci_start_is_at_rest_density_in_corners(device):
    """The corner block's sampled start for WCSPH (``Solver.relaxed_start``): 0.79 % over rest density at the
    corner before the relaxation (``akinci2012_start``), at most its tolerance after it, measured by the run's
    own density stage; the particles moved by less than 1 % of d."""
    from warp_sph.methods.boundaries.akinci2012_start import START_TOLERANCE
    from warp_sph.scene.sampling import sample_scene

    assert corner_block("dfsph", 0.0, device=device).sampled.start_rounds == 0  # DFSPH and PBF: error_share instead
    sim = corner_block("wcsph", 0.0, device=device)
    assert sim.sampled.start_error == pytest.approx(0.0079, abs=2e-4)
    assert 0 < sim.sampled.start_rounds < 10
    assert sim.statistics().density_error_max <= START_TOLERANCE + 1e-5
    moved = np.linalg.norm(sim.sampled.fluid_x - sample_scene(sim.scene).fluid_x, axis=1)
    assert moved.max() < 0.01 * sim.model.spacing
