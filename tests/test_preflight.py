"""Pre-flight and validation name the right cause (first-hour issue items 12-15): the speed of sound
follows an explicit stiffness, absurd step counts are refused with the measured cost, each extreme
value is blamed on its own key, and scenes that cannot be what the user meant are refused."""
import math
import re

import numpy as np
import pytest

from warp_sph.core.errors import SceneError
from warp_sph.run.preflight import preflight_checks
from warp_sph.run.simulation import Simulation
from warp_sph.scene import load_scene, scene_from_dict


def small(**extra):
    d = {"particle_radius": 0.05, "container": {"min": [0, 0, 0], "max": [1.0, 0.5, 1.0]},
         "fluid": [{"min": [0, 0, 0], "max": [0.4, 0.5, 0.4]}], "output": {"usd": False}, "duration": 0.5}
    for k, v in extra.items():
        d[k] = {**d.get(k, {}), **v} if isinstance(v, dict) else v
    if "wcsph" in extra:  # WCSPH's settings are tested with WCSPH (the default solver is DFSPH)
        d.setdefault("solver", "wcsph")
    return scene_from_dict(d)


def refusal(scene) -> str:
    with pytest.raises(SceneError) as info:
        preflight_checks(scene, Simulation(scene), warn=False)
    return str(info.value)


# --- item 12: the speed of sound follows the stiffness actually used ------------------------------------
@pytest.mark.parametrize("eos, factor", [("linear", 1.0), ("tait", 7.0)])
def test_speed_of_sound_follows_explicit_stiffness(eos, factor):
    sim = Simulation(small(wcsph={"stiffness": 1e8, "equation_of_state": eos}))
    c = math.sqrt(factor * 1e8 / 1000.0)
    assert sim.model.speed_of_sound == pytest.approx(c, rel=1e-12)
    assert sim.solver.stiffness == 1e8
    acoustic = next(b for b in sim.time_step_bounds(0.0) if b.name == "acoustic CFL")
    assert acoustic.seconds == pytest.approx(0.4 * 0.5 * sim.model.support_radius / c, rel=1e-9)
    assert "wcsph.stiffness" in acoustic.keys


def test_stiff_explicit_stiffness_runs_without_gaining_energy():
    """Before the fix the step ignored the stiffness: energy rose from 5.0 to 9.6 J/kg (issue item 12). The
    start's compression energy at c_s = 316 m/s (2.3 % of this scene's) stops the run at once under the energy
    rule (tests/test_energy_watchdog.py); this checks the step from frame 1 on, with that rule off."""
    sim = Simulation(small(wcsph={"stiffness": 1e8}))
    sim.watchdog.energy.enabled = False
    e0 = None
    for _ in range(6):
        st = sim.advance_frame()
        e = st.kinetic_energy + st.potential_energy
        e0 = e if e0 is None else e0
        assert st.outside == 0 and st.non_finite == 0
        assert e <= e0 + 1e-3 * abs(e0) + 1e-6


# --- item 13: absurd step counts --------------------------------------------------------------------------
def test_tiny_fixed_step_is_refused_with_the_measured_cost():
    msg = refusal(small(time={"fixed_dt": 1e-30}))
    assert "time.fixed_dt = 1e-30 s" in msg and "time.max_steps" in msg
    assert re.search(r"ns per particle-step measured here that is more than a century", msg), msg


def test_endless_duration_is_refused():
    msg = refusal(small(duration=1e30))
    assert "duration 1e+30 s" in msg and "time.max_steps" in msg


def test_max_steps_lets_a_long_run_through():
    scene = small(duration=0.5, time={"max_steps": 10})
    assert "time.max_steps = 10" in refusal(scene)
    ok = small(duration=0.5, time={"max_steps": 1_000_000})
    assert preflight_checks(ok, Simulation(ok), warn=False) == []


# --- item 14: each extreme value blamed on its own key -------------------------------------------------------
@pytest.mark.parametrize("override, key", [
    ({"material": {"rest_density": 1e-300}}, r"material\.rest_density: expected a finite number >= 0\.001"),
    ({"pbf": {"tensile_n": 1000}}, r"pbf\.tensile_n: expected an integer >= 1 and <= 16"),
    ({"output": {"surface_cell_per_radius": 1e-3}}, r"output\.surface_cell_per_radius: expected a finite number >= 0\.1"),
])
def test_extreme_values_refused_at_validation(override, key):
    with pytest.raises(SceneError, match=key):
        small(**override)


@pytest.mark.parametrize("override, key", [
    ({"wcsph": {"stiffness": 1e30}}, "wcsph.stiffness"),
    ({"material": {"boundary_friction": 1e30}}, "material.boundary_friction"),
    ({"fluid": None}, "fluid[0].velocity"),
])
def test_extreme_values_blamed_on_their_key(override, key):
    if "fluid" in override:
        scene = small(fluid=[{"min": [0, 0, 0], "max": [0.4, 0.5, 0.4], "velocity": [1e30, 0, 0]}])
    else:
        scene = small(**override)
    with np.errstate(all="raise"):  # no NumPy overflow warning on the way
        msg = refusal(scene)
    assert key in msg and "time.max_steps" in msg, msg
    assert "lower time.dt_min" not in msg  # the old advice, which blamed the step


@pytest.fixture
def two_gib(monkeypatch):
    """This host has 2 GiB free (the CPU: one pool for particles and surface)."""
    from warp_sph.run import memory

    monkeypatch.setattr(memory, "available_host_memory", lambda: 2 * 2**30)
    return memory


def test_tiny_radius_is_blamed_on_particle_radius(two_gib):
    """r = 1.5 mm in a 1 x 0.5 x 1 m tank: about 3 M fluid particles (2.3 GB, more than the 2 GiB free) whose
    dense surface grid over the container (4.7 GB) was blamed: "raise output.surface_cell_per_radius",
    which cannot make the particles fit."""
    scene = small(particle_radius=0.0015, output={"usd": True})
    fluid, boundary = two_gib.estimate_particle_counts(scene)
    kind, msg = two_gib.memory_verdict(scene, fluid, boundary, "cpu", estimated=True)
    assert kind == "refuse" and ": particle_radius: " in msg and "surface_cell_per_radius" not in msg, msg
    assert re.search(r"particle_radius about 0\.00\d+ m would fit", msg), msg


def test_surface_is_blamed_only_when_the_particles_alone_fit(two_gib):
    scene = small(particle_radius=0.01, output={"usd": True, "surface_cell_per_radius": 0.1})
    fluid, boundary = two_gib.estimate_particle_counts(scene)
    kind, msg = two_gib.memory_verdict(scene, fluid, boundary, "cpu", estimated=True)
    assert kind == "refuse" and msg.startswith("<dict>: output.surface_cell_per_radius: "), msg
    assert "the particles alone fit, but the surface grid at 0.1 r cells" in msg


def test_surface_grid_of_a_large_container_is_sparse(two_gib):
    """A 100 m container around a small block (r = 0.05 m: about 6 M wall particles, 1.1 GB) ran in 20 s with
    the surface off, yet was refused with it on: the surface was estimated as a dense grid over the
    container (about 240 GiB) although the grid holds blocks around the particles only."""
    scene = small(container={"min": [0, 0, 0], "max": [100.0, 100.0, 100.0]}, output={"usd": True})
    fluid, boundary = two_gib.estimate_particle_counts(scene)
    per_cell = two_gib.SURFACE_BYTES_PER_CELL
    cell = scene.output.surface_cell_per_radius * scene.particle_radius
    assert two_gib._surface_bytes(scene, fluid) == pytest.approx(per_cell * 8 * fluid * 0.1**3 / cell**3)
    assert two_gib.memory_verdict(scene, fluid, boundary, "cpu", estimated=True)[0] == "warn"  # 55 %, not refused
    # the container still bounds it: a full tank's surface grid is no larger than the tank
    full = small(fluid=[{"min": [0, 0, 0], "max": [1.0, 0.5, 1.0]}], output={"usd": True})
    assert two_gib._surface_bytes(full, 10**6) == pytest.approx(per_cell * 0.5 / cell**3, abs=1)


def test_whitewater_capacity_is_counted_and_blamed(two_gib, tmp_path, monkeypatch, capsys):
    """whitewater.max_particles slots are allocated at the start (two buffers of 36 B, flags) and copied for
    the export of every frame, yet the memory check counted none of them: 10^8 slots (about 35 GiB with
    the copies) beside 80 fluid particles passed and failed in the allocation."""
    from warp_sph.cli import main as cli_main

    scene = small(whitewater={"max_particles": 100_000_000})
    fluid, boundary = two_gib.estimate_particle_counts(scene)
    kind, msg = two_gib.memory_verdict(scene, fluid, boundary, "cpu", estimated=True)
    assert kind == "refuse" and msg.startswith("<dict>: whitewater.max_particles: "), msg
    assert re.search(r"\(whitewater \d+(\.\d+)? GiB of it\)", msg) and "100,000,000 slots" in msg, msg
    assert two_gib.memory_verdict(small(whitewater={}), fluid, boundary, "cpu", estimated=True) is None  # 200,000
    monkeypatch.chdir(tmp_path)  # the command line: one line, exit 2, before sampling, no run folder
    code = cli_main(["run", "dam_break", "--set", "particle_radius=0.1", "--set", "whitewater.max_particles=100000000"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "whitewater.max_particles: " in err[0], err
    assert not (tmp_path / "runs").exists()


def test_emitters_that_cannot_fit_are_blamed_on_the_emitters(two_gib):
    """A faucet pouring 100 m^3/s for 4 s needs about 27 M particle slots; the refusal named particle_radius and
    told to "shrink the fluid blocks", though the emitters are what fills the memory."""
    scene = load_scene("faucet", ['emitters=[{shape="circle", position=[0.4, 0.4, 0.8], direction=[0, 0, -1], '
                                  'radius=0.1, flow_rate=100.0}]'])
    fluid, boundary = two_gib.estimate_particle_counts(scene)
    kind, msg = two_gib.memory_verdict(scene, fluid, boundary, "cpu", estimated=True)
    assert kind == "refuse" and ": emitters: " in msg and "lower the emitters' flow_rate or speed" in msg, msg
    assert "fluid blocks" not in msg


def test_export_snapshot_queue_is_counted(monkeypatch):
    """The export thread queues frame snapshots (x, v, density, pressure, id: 36 B a particle) while they
    hold at most SNAPSHOT_QUEUE_BYTES (1 GiB), one more waits in the simulation's hands; the model counted
    three (96 B a particle). 10^6 particles over 49 frames hold about 1.1 GB of snapshots: with 1.2 GB free
    the run was let through (67 %) and now is refused, with the figure."""
    from warp_sph.run import exporter, memory

    monkeypatch.setattr(memory, "available_host_memory", lambda: 1_200_000_000)
    scene = small(duration=2.0, fps=24.0, output={"usd": True, "surface": False})
    kind, msg = memory.memory_verdict(scene, 10**6, 0, "cpu", estimated=False)
    size = memory.SNAPSHOT_BYTES_PER_FLUID * 10**6
    held = min(49, exporter.SNAPSHOT_QUEUE_BYTES // size + 1)  # the queue's admission rule (test_export_queue)
    assert memory.estimate_memory(scene, 10**6, 0)["device"] >= held * size
    assert kind == "refuse" and f"the export's frame snapshots {held * size / 2**30:.3g} GiB of it" in msg, msg
    # a run of 3 frames holds 3 snapshots at most, and fits
    assert memory.memory_verdict(scene, 10**6, 0, "cpu", estimated=False, frames=3)[0] == "warn"


def test_huge_obstacle_blamed_on_the_obstacle(tmp_path):
    mesh = tmp_path / "tet.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    scene = small(obstacles=[{"shape": "mesh", "file": str(mesh), "scale": 1e30}])
    with pytest.raises(SceneError, match=r"obstacles\[0\]: .*obstacles\[0\] needs about .* boundary particles"):
        Simulation(scene)


def test_quoted_bound_is_the_one_the_step_used():
    """The watchdog's cause names the bound at the speed the frame's step was sized for (the default step at
    rest was 8 % over the bound the message quoted)."""
    sim = Simulation(small())
    speed = 0.3
    dt = sim.time_step(speed)
    tight = sim.time_step_bounds(speed)[0]
    assert dt <= tight.seconds * (1 + 1e-12)
    cause = sim.watchdog.likely_cause("non_finite", None, dt, speed)
    assert "time step too large" not in cause


# --- item 15: scenes that cannot be what the user meant --------------------------------------------------------
def test_open_obstacle_mesh_refused(tmp_path):
    mesh = tmp_path / "open.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(SceneError, match=r"obstacles\[0\]\.file: mesh .* is not closed \(3 edges"):
        small(obstacles=[{"shape": "mesh", "file": str(mesh), "scale": 0.1}])


def test_obstacle_outside_the_container_refused():
    with pytest.raises(SceneError, match=r"obstacles\[0\]: lies entirely outside the container"):
        small(obstacles=[{"min": [2, 2, 2], "max": [3, 3, 3]}])


def test_mesh_sequence_without_surface_refused():
    with pytest.raises(SceneError, match=r"output\.mesh_sequence: 'obj' needs output\.surface = true"):
        small(output={"mesh_sequence": "obj", "surface": False})


def test_builtin_obstacle_scene_still_loads():
    assert load_scene("obstacle").obstacles[0].shape == "mesh"

