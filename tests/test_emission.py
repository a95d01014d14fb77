"""Emitters and sinks (``warp_sph.run.emission``, docs/emitters.md): mass bookkeeping every frame, an
emitter's flow rate, the inlet's density, persistent ids, checkpoint + resume bit for bit mid-emission, and
the bad inputs refused before any kernel runs.
"""
from pathlib import Path

import numpy as np
import pytest

from warp_sph.cli import main as cli_main
from warp_sph.io import run_folder as rf
from warp_sph.run import runner
from warp_sph.run.simulation import Simulation
from warp_sph.scene import scene_from_dict

BASE = {
    "name": "flow", "particle_radius": 0.025, "duration": 1.0, "fps": 24.0,
    "container": {"min": [0.0, 0.0, 0.0], "max": [0.8, 0.5, 0.8]},
    "fluid": [{"min": [0.0, 0.0, 0.0], "max": [0.8, 0.5, 0.1]}],
    "emitters": [{"shape": "circle", "position": [0.2, 0.25, 0.6], "direction": [1.0, 0.0, 0.0],
                  "radius": 0.1, "speed": 1.0, "end": 0.5}],
    "sinks": [{"min": [0.65, 0.0, 0.0], "max": [0.8, 0.5, 0.8]}],
    "output": {"surface": False, "usd": False, "checkpoint_every": 3},
}


def scene(**changes):
    d = {**BASE, **changes}
    return scene_from_dict(d, source="flow.toml")


def quiet(*args, **kwargs):
    pass


@pytest.mark.parametrize("solver", ["wcsph", "dfsph", "pbf"])
def test_mass_bookkeeping_every_frame(solver, device):
    """initial + emitted - removed = active particles at every frame; ids stay unique; no particle is left
    inside a sink at a frame's start; emitted particles carry new ids."""
    sim = Simulation(scene(solver=solver), device=device)
    n0 = sim.model.fluid_count
    before = 0  # particles emitted before this frame
    for _ in range(8):
        s = sim.advance_frame()
        f = s.flow
        assert f["particles"] == n0 + f["emitted"] - f["removed"] == sim.model.fluid_count
        ids = sim.get_field("particle_id")
        assert len(ids) == f["particles"] and len(np.unique(ids)) == len(ids)
        assert ids.max() < n0 + f["emitted"]
        # the jet moves (+x from the nozzle at x = 0.2 m, 1 m/s): a particle emitted a frame ago or earlier
        # is at least half a frame's travel downstream (every solver integrates the emitted slots)
        x = sim.get_field("particle_x")
        old = (ids >= n0) & (ids < n0 + before)
        assert np.all(x[old, 0] > 0.2 + 0.5 / sim.scene.fps), x[old, 0].min()
        before = f["emitted"]
    assert f["emitted"] > 0 and f["removed"] > 0


def test_flow_rate_within_2_percent(device):
    """An emitter given a flow rate emits that volume per second (particle volume d^3) within 2 %, measured
    over about 1 s (80 layers) between two frames; zero gravity, no container."""
    q = 0.04  # m^3/s: 4 m/s through the 2 x 2 lattice nozzle, 80 layers per second
    sc = scene(gravity=[0.0, 0.0, 0.0], container=False, sinks=[], duration=1.2, solver="dfsph",
               fluid=[{"min": [-1.0, -1.0, -1.0], "max": [-0.9, -0.9, -0.9]}],
               emitters=[{"shape": "rectangle", "position": [0.0, 0.0, 0.0], "direction": [0.0, 0.0, 1.0],
                          "width": 0.1, "height": 0.1, "flow_rate": q}])
    sim = Simulation(sc, device=device)
    d3 = sim.model.spacing ** 3
    counts, times = [], []
    for _ in range(int(1.1 * sc.fps)):
        s = sim.advance_frame()
        counts.append(s.flow["emitted"])
        times.append(s.time)
    rate = (counts[-1] - counts[2]) * d3 / (times[-1] - times[2])
    assert abs(rate / q - 1.0) < 0.02, rate


def test_inlet_density_at_rest_lattice(device):
    """The layers enter one spacing apart: in zero gravity the particles of the inlet's core (a full
    kernel support of emitted fluid around them) read rest density within the DFSPH tolerance."""
    sc = scene(gravity=[0.0, 0.0, 0.0], container=False, sinks=[], duration=1.0, solver="dfsph", fps=20.0,
               fluid=[{"min": [-1.0, -1.0, -1.0], "max": [-0.9, -0.9, -0.9]}],
               emitters=[{"shape": "rectangle", "position": [0.0, 0.0, 0.0], "direction": [0.0, 0.0, 1.0],
                          "width": 0.35, "height": 0.35, "speed": 1.0}])
    sim = Simulation(sc, device=device)
    for _ in range(8):  # 0.4 s: a jet 0.4 m long
        sim.advance_frame()
    x = sim.get_field("particle_x")
    rho = sim.get_field("particle_density") / sim.model.rest_density - 1.0
    d = sim.model.spacing
    # two spacings from the nozzle (no fluid behind the newest layer: the pipe is not simulated) and the head
    core = (np.abs(x[:, 0]) < 1.1 * d) & (np.abs(x[:, 1]) < 1.1 * d) & (x[:, 2] > 2.5 * d) & (x[:, 2] < 0.4 - 3.5 * d)
    assert core.sum() >= 18
    tol = sc.dfsph.target_density_error
    assert np.max(np.abs(rho[core])) <= tol, rho[core]  # measured: 4.2e-4 against 5e-4


def test_capacity_full_warns_once(device):
    sim = Simulation(scene(max_particles=130, sinks=[]), device=device)
    with pytest.warns(RuntimeWarning, match="capacity") as rec:
        for _ in range(8):
            s = sim.advance_frame()
    assert len([w for w in rec if "capacity" in str(w.message)]) == 1
    assert s.flow["particles"] == 130 and s.flow["skipped"] > 0


def test_resume_bitwise_mid_emission(tmp_path):
    """A run resumed from its frame-4 checkpoint (emission and removal under way) writes the frames of the
    uninterrupted run bit for bit, ids included."""
    ref = tmp_path / "ref"
    runner.run(scene(solver="dfsph"), out=ref, device="cpu", frames=7, progress=False, log=quiet)
    out = tmp_path / "res"
    runner.run(scene(solver="dfsph"), out=out, device="cpu", frames=5, progress=False, log=quiet,
               threaded_export=False)
    rf.checkpoint_path(out, 5).unlink()
    info = runner.run(None, frames=7, resume=out, progress=False, device="cpu", log=quiet)
    assert info["status"] == "completed"
    counts = set()
    for k in range(1, 8):
        a, b = np.load(rf.frame_path(ref, k)), np.load(rf.frame_path(out, k))
        for key in ("x", "v", "id"):
            assert np.array_equal(a[key], b[key]), (k, key)
        counts.add(len(a["x"]))
    assert len(counts) > 1  # the count changed during the run
    assert [f["flow"] for f in info["frames"]] == [f["flow"] for f in
                                                   __import__("json").loads((ref / "run.json").read_text())["frames"]]


BAD = [
    ({"emitters": [{**BASE["emitters"][0], "position": [0.9, 0.25, 0.6]}]}, "emitters[0]: the nozzle"),
    ({"obstacles": [{"min": [0.1, 0.1, 0.5], "max": [0.3, 0.4, 0.7]}]}, "inside obstacles[0]"),
    ({"emitters": [{**BASE["emitters"][0], "speed": 0.0}]}, "emitters[0].speed"),
    ({"emitters": [{**BASE["emitters"][0], "speed": -1.0}]}, "emitters[0].speed"),
    ({"emitters": [{**BASE["emitters"][0], "flow_rate": 0.001}]}, "both"),
    ({"emitters": [{**BASE["emitters"][0], "start": 0.6}]}, "emitters[0].end"),
    ({"emitters": [{**{k: v for k, v in BASE["emitters"][0].items() if k != "end"}, "start": 1.0}]},
     "emitters[0].start: expected a time before the scene's duration = 1.0 s"),
    ({"sinks": [{"min": [1.0, 0.0, 0.0], "max": [1.2, 0.5, 0.8]}]}, "sinks[0]"),
    ({"max_particles": 10}, "max_particles"),
]


@pytest.mark.parametrize("changes,words", BAD)
def test_bad_input_one_line_exit_2(tmp_path, capsys, changes, words):
    import tomllib  # noqa: F401  (the scene is written as TOML below)

    path = tmp_path / "bad.toml"
    path.write_text(_toml({**BASE, **changes}))
    out = tmp_path / "out"
    assert cli_main(["run", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def _toml(d: dict, prefix: str = "") -> str:
    """A tiny TOML writer for the scenes above (tables, arrays of tables, numbers, strings, lists)."""
    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(v)

    lines, tables = [], []
    for k, v in d.items():
        if isinstance(v, dict):
            tables.append((k, v, False))
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            tables.append((k, v, True))
        else:
            lines.append(f"{k} = {val(v)}")
    for k, v, many in tables:
        for t in (v if many else [v]):
            lines.append(f"[[{k}]]" if many else f"[{k}]")
            lines += [f"{a} = {val(b)}" for a, b in t.items()]
    return "\n".join(lines) + "\n"


def test_energy_rule_counts_the_flow(device):
    """The emitted particles bring energy in (0.6 m up, 1 m/s): the total rises far beyond the rule's 1 %, and
    the run goes on because that rise is what the emitter brought; a pump stage inserted by hand on top of
    the same flow is still stopped."""
    from test_energy_watchdog import _pump
    from warp_sph.core.errors import SimulationError
    from warp_sph.run.energy import ENERGY_GROWTH_LIMIT

    sim = Simulation(scene(solver="dfsph", sinks=[]), device=device)
    watch = sim.watchdog.energy
    for _ in range(8):
        s = sim.advance_frame()
        assert s.energy_growth <= ENERGY_GROWTH_LIMIT
    raw = (s.kinetic_energy + s.potential_energy - watch.reference_total) / watch.scale
    assert raw > 5 * ENERGY_GROWTH_LIMIT and sim.flow.exchanged > 0.0  # without the flow's account: stopped
    sim = Simulation(scene(solver="dfsph", sinks=[]), device=device)
    sim.graph.insert(_pump(3.0 * 9.81))
    with pytest.raises(SimulationError, match="the total energy rose by"):
        for _ in range(8):
            sim.advance_frame()


@pytest.mark.parametrize("solver", ["wcsph", "dfsph", "pbf"])
def test_a_scene_of_emitters_alone_starts_empty(solver, device):
    """No [[fluid]] block: the run starts with no fluid particle and fills from the nozzle; emitted -
    removed = the fluid count every frame, the count grows layer by layer and nothing leaves the
    container. Without a container such a scene is refused in one line (nothing bounds the grid)."""
    sc = scene_from_dict({k: v for k, v in BASE.items() if k != "fluid"} | {"solver": solver, "sinks": []},
                         source="flow.toml")
    sim = Simulation(sc, device=device)
    assert sim.model.fluid_count == 0
    counts = []
    for _ in range(5):
        stats = sim.advance_frame()
        flow = stats.flow
        assert flow["emitted"] - flow["removed"] == flow["particles"] == sim.model.fluid_count
        counts.append(flow["particles"])
        assert np.isfinite(sim.get_field("particle_x")).all()
    assert counts[0] >= 0 and counts[-1] > counts[1] > 0 and counts == sorted(counts)
    assert stats.outside == 0 and stats.max_speed < 3.0


def test_emitters_alone_need_a_container(tmp_path, capsys):
    d = {k: v for k, v in BASE.items() if k != "fluid"} | {"sinks": [], "container": False}
    path = tmp_path / "open.toml"
    path.write_text(_toml(d))
    out = tmp_path / "out"
    assert cli_main(["run", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "container" in err and len(err.splitlines()) == 1, err
    assert not out.exists()


DRAIN = {"name": "drain", "particle_radius": 0.05, "fps": 30.0, "output": {"usd": False, "surface": False},
         "container": {"min": [0.0, 0.0, 0.0], "max": [1.6, 0.6, 1.2]},
         "fluid": [{"min": [0.0, 0.0, 0.0], "max": [0.8, 0.6, 0.8]}]}


@pytest.mark.parametrize("solver", ["wcsph", "dfsph", "pbf"])
def test_a_sink_that_empties_the_tank(solver):
    """A sink over the whole tank removes every particle at the first frame's start: the run goes on with
    none (PBF divided its error sum by the count 0; DFSPH's frame end copied its kept wall force, count 0
    meaning the whole array, into the empty view)."""
    sim = Simulation(scene_from_dict({**DRAIN, "solver": solver,
                                      "sinks": [{"min": [0.0, 0.0, 0.0], "max": [1.6, 0.6, 1.2]}]}), device="cpu")
    n0 = sim.model.fluid_count
    for _ in range(2):
        stats = sim.advance_frame()
    assert sim.model.fluid_count == 0 and stats.flow["removed"] == n0


def test_pbf_stabilisation_reads_the_mean_of_its_last_pass():
    """PBF pre-stabilises when the last density pass read a mean error over 2x the target; after a sink
    removed particles at a frame's start it divided that pass's sum by the new, smaller count. Here the
    frame's last pass reads 1.5x the target (its sum set by hand) and a sink removes 140 of 196 particles:
    no stabilisation (it ran on 1.5 x 196 / 56 = 5.25x)."""
    sim = Simulation(scene_from_dict({**DRAIN, "solver": "pbf",
                                      "sinks": [{"min": [0.0, 0.0, 0.0], "max": [1.6, 0.6, 0.55]}]}), device="cpu")
    s = sim.solver
    n0, target = sim.model.fluid_count, float(s.config.target_density_error)
    calls = []
    stabilize = s._stabilize
    s._stabilize = lambda: (calls.append(sim.model.fluid_count), stabilize())
    sim.flow.begin_frame()  # the frame's start: the sink
    assert sim.model.fluid_count == 56 and n0 == 196
    s.last_error_sum, s.last_error_count = 1.5 * target * n0, n0  # the frame's last pass, before the sink
    sim.step(1e-3)
    assert calls == []
