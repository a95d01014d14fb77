"""The packing pass before t = 0 (``time.settle``, warp_sph/run/settle.py): a small resting tank packed by it
comes to rest and stays there (and does not without it), the run starts from the packed state at t = 0 with
its floor reading the water's weight, and bad values of the key are one line before any kernel runs."""
import json
import math

import numpy as np
import pytest

from small_scenes import small_tank
from warp_sph.cli import main
from warp_sph.run.simulation import Simulation
from warp_sph.run.settle import settle

RHO0, G = 1000.0, 9.81
R = 0.025
COLUMNS = 7
#: 7 columns at d = 0.05 m plus the ~1.1 d rest gap to the wall particles at both sides
WIDTH = COLUMNS * 2 * R + 0.06


def tank(tol: float, **kw):
    """7 x 7 columns of 5 layers (245 particles; a 0.3 m block less the floor gap) in a tank they fill, the hydrostatic scene's
    damping (docs/validation-notes.md), DFSPH at its defaults."""
    return small_tank("settle", "dfsph", particle_radius=R, container={"min": [0, 0, 0], "max": [WIDTH, WIDTH, 0.5]},
                      fluid=[{"shape": "box", "min": [0, 0, 0], "max": [WIDTH, WIDTH, 0.3]}],
                      material={"viscosity": 0.05, "xsph": 0.4}, time={"settle": tol}, **kw)


def late_mean_speed(sim, frames=24, late=12) -> float:
    """Mean over frames late..frames of the fluid's mean |v| [m/s] at each frame's end."""
    out = []
    for f in range(frames):
        sim.advance_frame()
        if f >= late:
            out.append(np.linalg.norm(sim.get_field("particle_v"), axis=1).mean())
    return float(np.mean(out))


def test_settled_tank_stays_at_rest_and_the_lattice_start_does_not():
    """Packed until a frame's mean |v| is below 1.2e-3 m/s, the tank stays below 3e-3 m/s over 0.5-1 s of the run
    (measured 1.4e-3); started from its lattice it is at 5e-3 m/s then (the first step's free fall and the
    layer-alternating kick that the solvers cannot see, docs/validation-notes.md)."""
    sim = Simulation(tank(1.2e-3))
    rec = settle(sim)
    assert rec["converged"] and rec["steps"] < sim.scene.time.settle_steps and rec["mean_speed"] < 1.2e-3
    assert rec["mean_displacement"] > 0.05 * 2 * R  # the packing moved: not a pass that stopped at once
    assert sim.state.time == 0.0 and sim.state.step == 0
    assert not np.any(sim.get_field("particle_v"))
    settled = late_mean_speed(sim)
    lattice = late_mean_speed(Simulation(tank(0.0)))
    assert settled < 3e-3 < lattice


def test_run_starts_packed_at_t0_and_the_floor_carries_the_water(tmp_path):
    """Through the runner: run.json keeps the pass's record, the probes' first sample is the run's first substep (none
    from the packing), the fluid starts where the packing left it at rest, and the floor probe (the walls' load per area)
    reads rho0 g D within 2 % over 0.25-0.5 s, D the water's volume over the floor it covers (each wall gap - r
    from the walls' particles)."""
    from warp_sph.io.probe_files import probe_csv_path, read_probe_csv
    from warp_sph.run import runner

    scene = tank(1.2e-3, duration=0.5, probes=[{"name": "floor", "kind": "pressure",
                                                 "position": [WIDTH / 2, WIDTH / 2, 0.0], "rate": 48.0}])
    info = runner.run(scene, out=tmp_path / "run", progress=False, log=lambda *a: None)
    rec = json.loads((tmp_path / "run" / "run.json").read_text())["settle"]
    assert rec["converged"] and rec["tolerance"] == 1.2e-3
    rows = np.array(read_probe_csv(probe_csv_path(tmp_path / "run", "floor"))[1], dtype=float).reshape(-1, 3)
    # a wall probe's first row is taken after the run's first substep (docs/probes.md), so it lies in (0, one
    # sample interval): a row from the packing would have a negative or a later time
    assert 0.0 < rows[0, 0] < 1.0 / 48 and np.all(np.diff(rows[:, 0]) > 0) and rows[-1, 0] == pytest.approx(0.5)
    floor = scene.wall_gap - R
    volume = info["fluid_particles"] * (2 * R) ** 3
    depth = volume / (WIDTH - 2 * floor) ** 2
    p = rows[rows[:, 0] >= 0.25, 1].mean()
    assert p == pytest.approx(RHO0 * G * depth, rel=2e-2)


@pytest.mark.parametrize("extra, pattern", [
    (["--set", "time.settle=-0.001"], "time.settle: expected a finite number >= 0, got -0.001"),
    (["--set", "time.settle=0.001", "--set", "gravity=[0,0,0]"], "time.settle: the packing pass settles the fluid "
                                                                   "under gravity and gravity is 0"),
    (["--set", "time.settle_steps=0"], "time.settle_steps: expected an integer >= 1, got 0"),
])
def test_bad_settle_values_are_one_line(extra, pattern, tmp_path, capsys, monkeypatch):
    """Exit status 2 and one line naming the key, before any kernel runs (no run folder made)."""
    def no_simulation(*a, **k):
        raise AssertionError("a Simulation was built")

    monkeypatch.setattr(Simulation, "__init__", no_simulation)
    scene = tmp_path / "scene.toml"
    scene.write_text(f'particle_radius = 0.05\nduration = 0.05\n[container]\nmax = [0.8, 0.6, 0.8]\n[[fluid]]\n'
                     f'min = [0.0, 0.0, 0.0]\nmax = [0.4, 0.6, 0.4]\n[output]\nusd = false\nsurface = false\n')
    code = main(["run", str(scene), "--out", str(tmp_path / "out"), "--no-progress"] + extra)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("warp-sph: error:")]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err
    assert pattern in lines[0], lines[0]
    assert not (tmp_path / "out").exists()
