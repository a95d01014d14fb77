"""Runs that must reach their end (issue #21, issue #15 items 18-19): PBF's iterations per step do not
grow with the fluid's depth, a one-layer wall holds a lone particle below the escape speed the watchdog
quotes (and the advice for a faster one is about stiffness, not the step), an impact at 14 m/s runs to
the end with every registered solver, and the built-in hydrostatic tank comes to rest with every
registered solver. Figures and commands: /work/notes/robust.md.
"""
import math

import numpy as np
import pytest

from warp_sph.core.errors import SimulationError
from warp_sph.methods import registry
from warp_sph.methods.solvers.pbf import lattice_transport, rest_denominator
from warp_sph.methods.solvers.wcsph import WALL_ESCAPE_FRACTION
from warp_sph.run.simulation import Simulation
from warp_sph.scene import load_scene, scene_from_dict

NO_OUTPUT = {"usd": False, "surface": False}
SOLVERS = registry.solver_names()


# --------------------------------------------------------------------------------------------
# PBF: iterations per step against the depth of the fluid in particles
# --------------------------------------------------------------------------------------------
def column(layers: int, device=None, **pbf) -> Simulation:
    """A narrow column 4 x 4 particles wide and ``layers`` deep (d = 0.05 m) in a tank that fits it."""
    d = 0.05
    width = 4 * d + 2 * 1.1 * d - d + 1e-4  # 4 columns plus the rest gap to the walls on both sides
    scene = {"name": "column", "particle_radius": d / 2, "fps": 24.0, "solver": "pbf", "pbf": pbf,
             "container": {"min": [0, 0, 0], "max": [width, width, 1.2 * layers * d + 0.2]},
             "fluid": [{"shape": "box", "min": [0, 0, 0], "max": [width, width, layers * d]}],
             "output": NO_OUTPUT}
    return Simulation(scene_from_dict(scene), device=device)


def iterations_after_start(sim: Simulation, frames: int = 12, last: int = 4) -> float:
    stats = [sim.advance_frame() for _ in range(frames)]
    for s in stats:
        assert s.outside == 0 and s.non_finite == 0
    return float(np.mean([s.solver["iterations"]["mean"] for s in stats[-last:]]))


def test_lattice_transport_matches_its_definition():
    """kappa from the lattice sum against a brute-force correction of a linear constraint field."""
    from warp_sph.core.smoothing import calibrated_mass, evaluate, lattice_offsets

    d = 0.05
    h = d
    m = calibrated_mass("cubic", h, d, 1000.0)
    kappa = lattice_transport("cubic", h, d, m, 1000.0, 0.0)
    d0 = rest_denominator("cubic", h, d, m, 1000.0)
    # lambda_j = -C_j / D0 with C = c' z: dx_i = sum_j V (lambda_i + lambda_j) grad_i W_ij at i = origin
    c_prime = 1e-3
    off = lattice_offsets(d, 2 * h)
    _, g = evaluate("cubic", -off, h)
    lam = -c_prime * off[:, 2] / d0
    dx = (m / 1000.0) * np.sum(lam[:, None] * g.astype(np.float64), axis=0)
    assert dx[2] == pytest.approx(-kappa * d * d * c_prime, rel=1e-5)
    assert kappa == pytest.approx(2.40, abs=0.01)  # cubic h = d (measured law: see solve_bound)
    assert lattice_transport("cubic", h, d, m, 1000.0, d0) == pytest.approx(kappa / 2, rel=1e-6)


def test_pbf_iterations_do_not_grow_with_depth(device):
    """From rest, a 10-layer and an 80-layer column need about the same iterations per step (the solve
    bound sizes the step for pbf.target_iterations = 4); main needed 2.1 and 15.2 at its 4.6 ms step."""
    its = {n: iterations_after_start(column(n, device=device)) for n in (10, 80)}
    assert max(its.values()) <= 6.0, its
    # the test can fail: without the bound the deep column needs its depth / 5 iterations
    deep = iterations_after_start(column(80, target_iterations=0.0, device=device))
    assert deep > 10.0, deep


def test_pbf_solve_bound_follows_depth_and_spacing(device):
    sim = column(40, device=device)
    b = {x.name: x for x in sim.time_step_bounds(0.0)}["pressure solve"]
    m = sim.model
    eta = sim.scene.pbf.target_density_error
    depth = sim.solver.fluid_depth
    assert depth == pytest.approx(40 * m.spacing, rel=0.03)
    assert b.seconds == pytest.approx(m.spacing * math.sqrt(2 * sim.solver.kappa * 4.0 * eta / (9.81 * depth)))
    assert "pbf.target_iterations" in b.keys


def test_fixed_step_beyond_the_cfl_names_the_step(device):
    """A state stepped with a step sized at rest (as the scaling benchmark did) until the flow is 2 d per
    step: check_health names the step against the bound at the flow's speed now, not the scene (the bound it
    exceeds most: PBF's pressure-solve bound since its relaxation comes from the lattice, kappa 1.13)."""
    sim = Simulation(load_scene("dam_break", ["particle_radius=0.05", "solver=pbf", "output.usd=false"]), device=device)
    dt = 0.04  # v dt / d ~ 2 at t = 0.3 s
    for _ in range(8):
        sim.step(dt)
    stats = sim.statistics(steps=8, dt_min=dt, dt_max=dt)
    if not stats.outside:
        pytest.skip("no particle left at this step (the message is what is tested)")
    with pytest.raises(SimulationError, match=r"are [0-9.]+x the (velocity CFL|pressure solve) bound .* at the flow's "
                       r"speed now"):
        sim.check_health(stats)


# --------------------------------------------------------------------------------------------
# one wall layer and a lone particle (WCSPH)
# --------------------------------------------------------------------------------------------
def lone_particle(fraction: float, boundary_pressure: str = "eq16", mode: str = "stop", device=None) -> Simulation:
    """One particle (d = 0.1 m) thrown at the floor at ``fraction`` c_s (c_s = 100 m/s), no gravity."""
    c = 100.0
    scene = {"name": "lone", "particle_radius": 0.05, "fps": 100.0, "solver": "wcsph", "gravity": [0, 0, 0],
             "container": {"min": [0, 0, 0], "max": [1, 1, 1]},
             "fluid": [{"shape": "box", "min": [0.45, 0.45, 0.5], "max": [0.55, 0.55, 0.6],
                        "velocity": [0, 0, -fraction * c]}],
             "wcsph": {"speed_of_sound": c, "boundary_pressure": boundary_pressure},
             "time": {"on_instability": mode}, "output": NO_OUTPUT}
    sim = Simulation(scene_from_dict(scene), device=device)
    assert sim.model.fluid_count == 1
    return sim


@pytest.mark.parametrize("boundary_pressure", sorted(WALL_ESCAPE_FRACTION))
def test_wall_turns_back_a_lone_particle_below_the_escape_speed(boundary_pressure, device):
    """Measured: eq16 turns 0.26 c_s back and lets 0.27 c_s through, mirrored 0.40 / 0.42; the watchdog
    quotes 0.25 / 0.40."""
    esc = WALL_ESCAPE_FRACTION[boundary_pressure]
    sim = lone_particle(esc, boundary_pressure, device=device)
    for _ in range(4):  # reaches the floor after 0.02 s, bounces
        s = sim.advance_frame()
        assert s.outside == 0
    assert sim.get_field("particle_v")[0, 2] > 0.0  # on its way up
    fast = lone_particle(1.25 * esc, boundary_pressure, device=device)
    # or the energy rule first, when the integrator gains energy inside the wall
    with pytest.raises(SimulationError, match="outside the container|the total energy rose"):
        for _ in range(4):
            fast.advance_frame()


def test_advice_for_a_particle_through_the_wall_is_stiffness_not_the_step(device):
    """0.28 c_s: through the wall whatever the step (main advised 'lower time.cfl'; retry halved the
    step five times and stopped with the same advice)."""
    sim = lone_particle(0.28, mode="retry", device=device)
    with pytest.raises(SimulationError) as e:
        for _ in range(4):
            sim.advance_frame()
    text = str(e.value)
    assert "after 5 retries" in text
    assert "wcsph.speed_of_sound_factor" not in text  # c_s was given as wcsph.speed_of_sound
    assert "raise wcsph.speed_of_sound to at least" in text and "halving it does not help" in text


@pytest.mark.parametrize("approach", [1.0, -1.0])
def test_artificial_viscosity_pair_matches_numpy_oracle(approach, device):
    """Two isolated particles (under-dense: no pressure): a_i = -m Pi_ij grad W_ij with
    Pi_ij = -nu (v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2), nu = 2 alpha h c_s / (rho_i + rho_j), only when
    approaching (Monaghan 1992); receding pairs feel nothing."""
    from sph_oracle import grad_W

    d = 0.1
    scene = {"name": "pair", "solver": "wcsph", "particle_radius": d / 2, "fps": 30.0, "container": False,
             "gravity": [0, 0, 0],
             "fluid": [{"shape": "box", "min": [0, 0, 0], "max": [2 * d, d, d]}],
             "wcsph": {"artificial_viscosity": 0.5, "speed_of_sound": 20.0}, "output": NO_OUTPUT}
    sim = Simulation(scene_from_dict(scene), device=device)
    m = sim.model
    x = np.array([m.origin - [0.06, 0.01, 0.0], m.origin + [0.06, 0.01, 0.0]])
    v = approach * np.array([[1.0, 0.2, -0.3], [-1.0, -0.2, 0.3]])
    sim.set_field("particle_x", x)
    sim.set_field("particle_v", v)
    sim.refresh_density()
    for stage in sim.graph.stages:
        if stage.name in ("pressure", "forces"):
            stage.run(sim, 1e-4)
    a = sim.fields["particle_acceleration"].numpy().astype(np.float64)
    rho = sim.get_field("particle_density").astype(np.float64)
    assert (rho < m.rest_density).all()
    h = m.smoothing_length
    x_ij, v_ij = x[0] - x[1], v[0] - v[1]
    vx = float(v_ij @ x_ij)
    nu = 2 * 0.5 * h * 20.0 / (rho[0] + rho[1])
    pi = -nu * min(vx, 0.0) / (x_ij @ x_ij + 0.01 * h * h)
    expected = -m.particle_mass * pi * grad_W("cubic", x_ij, h)
    if approach > 0:
        assert np.linalg.norm(expected) > 1.0
    np.testing.assert_allclose(a[0], expected, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(a[1], -expected, rtol=1e-4, atol=1e-5)


# --------------------------------------------------------------------------------------------
# impact at 14 m/s (issue #15 item 18)
# --------------------------------------------------------------------------------------------
#: WCSPH needs a stiffer fluid and dissipation to hold an impact: one wall layer turns a lone particle
#: back only below 0.25 c_s, and a flat impact at v squeezes its bottom edge out at 2.9 v (c_s = 10 v,
#: no dissipation) = 0.29 c_s; with c_s = 15 v and artificial viscosity 0.5 the edge leaves at 2.5-2.7 v
#: = 0.17 c_s and 70 % of the energy is dissipated (notes: robust.md).
IMPACT_SETTINGS = {"wcsph": {"speed_of_sound_factor": 15.0, "artificial_viscosity": 0.5}}


def impact_scene(solver: str) -> dict:
    """A 1 m cube 0.3 m above the floor moving down at sqrt(2 g 10 m) = 14 m/s: the impact of a drop
    from 10 m without simulating the 1.4 s of free fall (d = 0.1 m, 1000 particles)."""
    v0 = math.sqrt(2 * 9.81 * 10.0)
    return {"name": "impact", "particle_radius": 0.05, "fps": 60.0, "solver": solver, **IMPACT_SETTINGS,
            "container": {"min": [0, 0, 0], "max": [3, 3, 3]},
            "fluid": [{"shape": "box", "min": [1, 1, 0.3], "max": [2, 2, 1.3], "velocity": [0, 0, -v0]}],
            "output": NO_OUTPUT}


def pressure_impulse_edge_speed(a: float, c: float, d: float, terms: int = 301) -> float:
    """Largest speed after impact [in units of the impact speed] at the lattice points (centres d/2 inside
    the faces) of an incompressible a x a x c block hitting a floor (Cooker & Peregrine 1995: pressure
    impulse P harmonic, P = 0 on the free faces, dP/dz = -rho V on the impact face, u = u0 - grad P / rho),
    by the Fourier series. Log-singular at the bottom edges: 1.25 V at d = 0.1 m for a 1 m cube."""
    m = np.arange(1, terms + 1, 2)[:, None]
    n = np.arange(1, terms + 1, 2)[None, :]
    al, be = m * np.pi / a, n * np.pi / a
    k = np.sqrt(al ** 2 + be ** 2)
    coef = 16.0 / (np.pi ** 2 * m * n)
    best = 0.0
    for x in np.arange(d / 2, a / 2 + 1e-9, d):
        for y in np.arange(d / 2, a / 2 + 1e-9, d):
            z = d / 2
            ch = np.exp(-k * z) * (1 + np.exp(-2 * k * (c - z))) / (1 + np.exp(-2 * k * c))
            sh = np.exp(-k * z) * (1 - np.exp(-2 * k * (c - z))) / (1 + np.exp(-2 * k * c))
            u = np.sum(coef / k * al * np.cos(al * x) * np.sin(be * y) * sh)
            v = np.sum(coef / k * be * np.sin(al * x) * np.cos(be * y) * sh)
            w = -1.0 + np.sum(coef * np.sin(al * x) * np.sin(be * y) * ch)
            best = max(best, math.sqrt(u * u + v * v + w * w))
    return best


def test_pressure_impulse_reference():
    # at the middle of the face the fluid stops (w = 0 on the impact face), and the edge grows as log(a/d)
    assert pressure_impulse_edge_speed(1.0, 1.0, 0.1) == pytest.approx(1.25, abs=0.01)
    assert pressure_impulse_edge_speed(1.0, 1.0, 0.05) > pressure_impulse_edge_speed(1.0, 1.0, 0.1) + 0.3


@pytest.mark.parametrize("solver", SOLVERS)
def test_impact_at_14_m_s_runs_to_the_end(solver, device):
    """Every registered solver: the splash of a 14 m/s impact stays in the container, nobody leaves the
    impact faster than 3 v (the incompressible edge speed at this spacing is 1.25 v; measured: PBF 1.6 v,
    WCSPH 2.5-2.7 v), and the energy never rises."""
    sim = Simulation(scene_from_dict(impact_scene(solver)), device=device)
    m = sim.model
    v0 = math.sqrt(2 * 9.81 * 10.0)

    def energy():
        x, v = sim.get_field("particle_x"), sim.get_field("particle_v")
        return m.particle_mass * (0.5 * (v.astype(np.float64) ** 2).sum() + 9.81 * x[:, 2].astype(np.float64).sum())

    e0 = energy()
    fastest = 0.0
    for _ in range(30):  # 0.5 s: impact at 0.02 s, the splash reaches the walls and falls back
        s = sim.advance_frame()
        assert s.outside == 0 and s.non_finite == 0
        fastest = max(fastest, s.max_speed)
        assert energy() <= 1.01 * e0
    assert fastest <= 3.0 * v0, (fastest, fastest / v0)
    assert 3.0 > fastest / v0 > pressure_impulse_edge_speed(1.0, 1.0, m.spacing) - 0.2


# --------------------------------------------------------------------------------------------
# the built-in hydrostatic tank comes to rest (issue #15 item 19)
# --------------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("solver", SOLVERS)
def test_hydrostatic_scene_settles(solver, device):
    """With the scene's own settings: mean |v| below 1e-3 sqrt(g H) (H = 0.5 m) averaged over the
    last 0.5 s of 5 s (22 settling times sqrt(H/g)), and the mean height does not rise (main, WCSPH:
    0.03-0.08 m/s for 10 s and +2.8 mm: the mirrored wall pressure is not energy-consistent)."""
    sim = Simulation(load_scene("hydrostatic", [f"solver={solver}", "output.usd=false"]), device=device)
    g, depth = 9.81, 0.5
    z0 = sim.get_field("particle_x")[:, 2].mean()
    speeds, heights = [], []
    while sim.state.time < 5.0 - 1e-9:
        s = sim.advance_frame()
        assert s.outside == 0 and s.non_finite == 0
        if sim.state.time > 4.5 + 1e-9:
            speeds.append(np.linalg.norm(sim.get_field("particle_v"), axis=1).mean())
        heights.append(sim.get_field("particle_x")[:, 2].mean())
    assert np.mean(speeds) < 1e-3 * math.sqrt(g * depth), np.mean(speeds)
    assert max(heights[len(heights) // 2:]) <= z0
