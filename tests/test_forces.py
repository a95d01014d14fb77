"""The Force family (``warp_sph.methods.force``): registry, scene entries and legacy keys, slots per solver,
zero cost when absent, bad input, carried fields through the particle order, checkpoints and resume."""
import re

import numpy as np
import pytest
import warp as wp

from small_scenes import small_tank
from warp_sph.cli import main
from warp_sph.core.errors import SceneError
from warp_sph.core.step_graph import Stage
from warp_sph.methods import registry
from warp_sph.methods.force import FORCE_ACCELERATION, Force
from warp_sph.run.simulation import Simulation
from warp_sph.scene import Param, parameter_table_markdown, scene_from_dict

SOLVERS = registry.solver_names()
FORCES = registry.force_names()


def test_registry_finds_the_forces_and_the_table_lists_their_keys():
    assert {"explicit_viscosity", "xsph", "vorticity_confinement"} <= set(FORCES)
    table = parameter_table_markdown()
    for name, cls in registry.forces().items():
        assert f'"{name}"' in table  # a choice of forces[].method
        for p in cls.parameters:
            assert f"`forces[{name}].{p.key}`" in table and p.unit in table


def test_scene_entries_round_trip_and_keep_their_values():
    scene = small_tank("f", forces=[{"method": "explicit_viscosity", "viscosity": 0.02}, {"method": "xsph"}])
    assert [f.method for f in scene.forces] == ["explicit_viscosity", "xsph"]
    assert scene.forces[0].viscosity == 0.02 and scene.forces[1].factor == 0.05  # the declared default
    data = scene.to_dict()
    assert data["forces"] == [{"method": "explicit_viscosity", "viscosity": 0.02}, {"method": "xsph", "factor": 0.05,
                                                                                    "reference_step": 0.0}]
    assert scene_from_dict(data) == scene
    assert "forces" not in small_tank("bare").to_dict()  # a scene without forces has no [[forces]]


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_scene_without_forces_has_no_force_stage(solver, device):
    sim = Simulation(small_tank("bare", solver, container=False, gravity=[0.0, 0.0, 0.0]), device=device)
    names = sim.graph.names()
    assert not {"viscosity", "apply_forces", "xsph", "vorticity", "kick", "drift"} & set(names), names
    assert FORCE_ACCELERATION not in sim.fields and "particle_vorticity" not in sim.fields
    assert len(sim.forces) == 0 and "forces" not in sim.summary()
    # the alphabetically first force of each kind (explicit_viscosity, not weiler2018)
    one_per_kind = {registry.force(name).kind: name for name in sorted(FORCES, reverse=True)}.values()
    with_all = Simulation(small_tank("all", solver, forces=[{"method": name} for name in one_per_kind]), device=device)
    assert {"viscosity", "xsph", "vorticity"} <= set(with_all.graph.names())


#: the slot of each solver: the stage the forces follow and the one they precede
SLOTS = {"dfsph": ("divergence", "source"), "wcsph": ("density", "pressure"), "pbf": ("update", None)}


@pytest.mark.parametrize("solver", SOLVERS)
def test_each_solver_places_the_phases_at_its_slot(solver, device):
    forces = [{"method": "xsph", "factor": 0.05}, {"method": "explicit_viscosity", "viscosity": 1e-3},
              {"method": "vorticity_confinement", "strength": 0.01}]
    names = Simulation(small_tank("slot", solver, forces=forces), device=device).graph.names()
    after, before = SLOTS[solver]
    k = names.index(after)
    block = names[k + 1:names.index(before) if before else len(names)]
    if solver == "wcsph":  # the filter first (as XSPH always ran there), explicit accelerations into "forces"
        assert block == ["xsph", "vorticity", "viscosity"]
    else:  # explicit forces from the same v, one kick (with the boundary force), then the filter
        assert block == ["vorticity", "viscosity", "apply_forces", "xsph"]


@pytest.mark.parametrize("key,legacy,entry", [
    ("material.viscosity", {"material": {"viscosity": 0.01}}, {"method": "explicit_viscosity", "viscosity": 0.01}),
    ("material.xsph", {"material": {"xsph": 0.1}}, {"method": "xsph", "factor": 0.1}),
    ("pbf.vorticity", {"solver": "pbf", "pbf": {"vorticity": 0.05}},
     {"method": "vorticity_confinement", "strength": 0.05}),
])
def test_legacy_keys_set_the_same_force_bit_for_bit(key, legacy, entry, device):
    solver = legacy.get("solver", "dfsph")
    old = Simulation(small_tank("old", **legacy), device=device)
    new = Simulation(small_tank("new", solver, forces=[entry]), device=device)
    assert old.graph.names() == new.graph.names()
    assert [f.keypath for f in old.forces] == [key] and [f.keypath for f in new.forces] == ["forces[0]"]
    for sim in (old, new):
        for _ in range(3):
            sim.step(2e-3)
    assert np.array_equal(old.get_field("particle_v"), new.get_field("particle_v"))


def test_pbf_vorticity_key_sets_nothing_for_another_solver(device):
    """As before the family: pbf.vorticity belongs to PBF's section and only acts with solver = "pbf"."""
    sim = Simulation(small_tank("wc", "wcsph", pbf={"vorticity": 0.05}), device=device)
    assert len(sim.forces) == 0


def test_time_step_bounds_and_hints_come_from_the_force(device):
    sim = Simulation(small_tank("v", forces=[{"method": "explicit_viscosity", "viscosity": 0.05}]), device=device)
    bounds = {b.name: b for b in sim.time_step_bounds(1.0)}
    h = 0.5 * sim.model.support_radius
    assert bounds["viscous"].seconds == pytest.approx(0.0625 * h * h / 0.05)
    assert bounds["viscous"].keys == ("forces[0].viscosity",)
    hint = sim.forces.instability_hint("non_finite", "viscosity")
    assert "forces[0]" in hint and "weiler2018" in hint
    legacy = Simulation(small_tank("v", material={"viscosity": 0.05}), device=device)
    assert {b.name: b for b in legacy.time_step_bounds(1.0)}["viscous"].keys == ("material.viscosity",)


# --- bad input: one line, exit status 2, before any kernel, nothing written ---------------------------
GOOD = """
name = "tiny"
particle_radius = 0.05
duration = 0.05
fps = 20.0
[container]
min = [0.0, 0.0, 0.0]
max = [0.8, 0.6, 0.8]
[[fluid]]
min = [0.0, 0.0, 0.0]
max = [0.4, 0.6, 0.4]
[output]
usd = false
surface = false
"""

BAD = {
    "unknown_method": ('[[forces]]\nmethod = "navier"\n', r"forces\[0\]\.method: expected one of .*'xsph'.*got 'navier'"),
    "no_method": ("[[forces]]\nviscosity = 0.1\n", r"forces\[0\]\.method: missing"),
    "negative": ('[[forces]]\nmethod = "explicit_viscosity"\nviscosity = -0.1\n',
                 r"forces\[0\]\.viscosity: expected a finite number >= 0, got -0\.1"),
    "nan": ('[[forces]]\nmethod = "xsph"\nfactor = nan\n', r"forces\[0\]\.factor: expected a finite number"),
    "unknown_key": ('[[forces]]\nmethod = "xsph"\nviscosity = 0.1\n', r"forces\[0\]\.viscosity: unknown key; expected one of factor"),
    "two_of_a_kind": ('[[forces]]\nmethod = "explicit_viscosity"\n[[forces]]\nmethod = "explicit_viscosity"\n',
                      r"forces\[1\]: a second viscosity force .*forces\[0\] already sets 'explicit_viscosity'"),
    "legacy_and_entry": ('[material]\nviscosity = 0.01\n[[forces]]\nmethod = "explicit_viscosity"\n',
                         r"material\.viscosity: a second viscosity force .*forces\[0\] already sets"),
    "too_viscous_legacy": ("[material]\nviscosity = 100.0\n",  # issue 36: DFSPH gained energy at this step bound
                           r"material\.viscosity: 100 m\^2/s needs .* more than 1000; use \[\[forces\]\] method = \"weiler2018\""),
    "fixed_step_above_bound": ("[material]\nviscosity = 1.0\n[time]\nfixed_dt = 0.005\n",
                               r"material\.viscosity: the explicit viscous time-step bound 0\.000625 s .* is below "
                               r"time\.fixed_dt = 0\.005 s; .*weiler2018"),
    "too_viscous": ('[[forces]]\nmethod = "explicit_viscosity"\nviscosity = 100.0\n',
                    r"forces\[0\]\.viscosity: 100 m\^2/s needs the explicit viscous time-step bound .* substeps per "
                    r"frame, more than 1000; use \[\[forces\]\] method = \"weiler2018\""),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_force_input_is_one_line_exit_2_and_writes_nothing(case, tmp_path, monkeypatch, capsys):
    text, pattern = BAD[case]
    monkeypatch.chdir(tmp_path)
    scene = tmp_path / "scene.toml"
    scene.write_text(GOOD + text)
    out = tmp_path / "run"
    launched = []
    monkeypatch.setattr("warp_sph.core.launch.wp.launch", lambda *a, **k: launched.append(a))
    code = main(["run", str(scene), "--out", str(out), "--no-progress", "--frames", "2"])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("warp-sph: error:")]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert re.search(pattern, lines[0]), lines[0]
    assert not out.exists() and not launched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]


class NoWcsph(Force):
    """A test force that refuses WCSPH (and does nothing)."""

    name = "no_wcsph_test"
    title = "a force WCSPH cannot host (test)"
    kind = "drag"
    parameters = (Param("no_wcsph_test.coefficient", "float", "1/s", 1.0, "unused", ge=0.0),)

    @classmethod
    def refuses_solver(cls, solver_cls):
        return "it needs a pressure solve after it" if solver_cls.name == "wcsph" else None

    def stages(self, slot):
        return []


class Memory(Force):
    """A test force carrying two values per particle: its time m_i (0 at the start, + dt each substep) and
    its stable index; it adds a drag -scale m_i v_i, so its state reaches the motion."""

    name = "memory_test"
    title = "a force with a carried field (test)"
    kind = "drag"
    parameters = (Param("memory_test.scale", "float", "1/s^2", 1.0, "acceleration per unit of memory", ge=0.0),)

    def __init__(self, sim, config, keypath):
        super().__init__(sim, config, keypath)
        sim.allocate("memory_test_m", float)  # zeros
        self.ids = sim.allocate("memory_test_id", float)
        self.ids.assign(np.arange(sim.model.fluid_count, dtype=np.float32))

    def stages(self, slot):
        scale = float(self.config.scale)

        def run(sim, dt):
            m, v, a = (sim.fields[k].numpy() for k in ("memory_test_m", "particle_v", FORCE_ACCELERATION))
            m = m + np.float32(dt)
            sim.fields["memory_test_m"].assign(m)
            a = a - np.float32(scale) * m[:, None] * v
            sim.fields[FORCE_ACCELERATION].assign(wp.array(a, dtype=wp.vec3, device=sim.device))

        return [Stage("memory", run, reads=("particle_v",), updates=("memory_test_m", slot.acceleration))]

    def carried_fields(self):
        return ("memory_test_m", "memory_test_id")


@pytest.fixture
def test_forces():
    registry.register_force(NoWcsph)
    registry.register_force(Memory)
    yield
    registry.unregister(NoWcsph.name)
    registry.unregister(Memory.name)


def test_a_force_a_solver_cannot_host_is_refused(test_forces):
    with pytest.raises(SceneError, match=r"forces\[0\]: force 'no_wcsph_test' does not work with solver 'wcsph': "
                                         r"it needs a pressure solve after it$"):
        small_tank("x", "wcsph", forces=[{"method": "no_wcsph_test"}])
    small_tank("x", "dfsph", forces=[{"method": "no_wcsph_test"}])


def test_carried_fields_follow_the_particle_order_and_resume_bit_for_bit(test_forces, tmp_path, device):
    """A force's carried fields are graph inputs, sorted with the particles each frame (at stable indices
    outside it), in the checkpoint, and restored: the resumed run equals the uninterrupted one."""
    from test_run_outputs import assert_same_run, quiet

    from warp_sph.io import run_folder as rf
    from warp_sph.run import runner
    from warp_sph.scene import load_scene

    extra = ["particle_radius=0.05", "output.checkpoint_every=2", 'forces=[{method = "memory_test"}, '
             '{method = "vorticity_confinement"}, {method = "explicit_viscosity", viscosity = 0.001}, {method = "xsph"}]']
    sim = Simulation(load_scene("dam_break", extra + ["output.usd=false"]), device=device)
    assert {"memory_test_m", "memory_test_id"} <= sim.graph.inputs
    sim.advance_frame()
    assert sim._cell_order is not None and not np.array_equal(sim._cell_order.order.numpy(),
                                                              np.arange(sim.model.fluid_count))  # it did sort
    np.testing.assert_array_equal(sim.fields["memory_test_id"].numpy(), np.arange(sim.model.fluid_count))
    np.testing.assert_allclose(sim.fields["memory_test_m"].numpy(), sim.state.time, rtol=1e-5)

    def run(out, frames, **kw):
        return runner.run(load_scene("dam_break", extra + ["output.surface=false"]), out=out, device="cpu",
                          frames=frames, progress=False, log=quiet, **kw)

    reference, resumed = tmp_path / "reference", tmp_path / "resumed"
    run(reference, 5)
    run(resumed, 4, threaded_export=False)
    rf.checkpoint_path(resumed, 4).unlink()  # frames 3 and 4 are recomputed from the checkpoint of frame 2
    with np.load(rf.latest_checkpoint(resumed)) as cp:
        assert cp["memory_test_m"].min() > 0
    runner.run(None, frames=5, resume=resumed, progress=False, device="cpu", log=quiet)
    assert_same_run(reference, resumed)


def test_bench_forces_covers_every_solver_and_force_and_costs_the_extra_stages():
    from warp_sph.benchmarks import forces as F

    specs = F.specs("dam_break", 1, 2)
    assert {(s.params["solver"], s.params["force"]) for s in specs} == {(s, f) for s in SOLVERS
                                                                       for f in ("none",) + FORCES}
    assert len(specs) == 2 * len(SOLVERS) * (1 + len(FORCES))

    def record(force, stages, repeat):  # steady seconds per call: (seconds - first) / (calls - 1)
        return {"status": "ok", "fluid_particles": 1000, "params": {"solver": "dfsph", "force": force, "repeat": repeat},
                "stage_times": [{"stage": s, "calls": 11, "seconds": 1.0 + 10 * t, "first_call_seconds": 1.0}
                                for s, t in stages.items()]}

    bare = {"density": 2e-3, "pressure": 3e-3}
    records = [record("none", bare, 1), record("xsph", {**bare, "xsph": 1e-3}, 1),
               record("xsph", {"density": 4e-3, "pressure": 3e-3, "xsph": 2e-3}, 2)]  # slower repeat: not counted
    (s,) = F.summary(records)
    assert (s["solver"], s["force"]) == ("dfsph", "xsph")
    assert s["force_ns"] == pytest.approx(1e3) and s["step_ns"] == pytest.approx(6e3)
    assert s["bare_step_ns"] == pytest.approx(5e3)
