"""What emitters and sinks cost (issue #29's goal, ``warp-sph bench emission``, docs/emitters.md): the frame's
removal and emission against a NumPy oracle, their per-frame stages on the step graph's timers, and the
bench's in-run arithmetic, table and command line.
"""
import json
import time

import numpy as np
import pytest

from warp_sph.benchmarks import emission as E
from warp_sph.core.step_graph import Stage, StepGraph
from warp_sph.run.simulation import Simulation
from warp_sph.scene import scene_from_dict

from test_emission import BASE


def test_removal_and_emission_against_a_numpy_oracle(device):
    """begin_frame: the particles inside the sink removed and the others kept in order in every carried field
    (x, v, ids, DFSPH's warm starts), the due layers appended with new ids and zero warm starts, one count."""
    sim = Simulation(scene_from_dict({**BASE, "solver": "dfsph"}, source="flow.toml"), device=device)
    n = sim.model.fluid_count
    rng = np.random.default_rng(3)
    x = sim.get_field("particle_x")
    x[::7, 0] = 0.7  # every 7th particle into the sink (x >= 0.65 m)
    inside = x[:, 0] >= 0.65
    sim.set_field("particle_x", x)
    v = rng.normal(size=(n, 3)).astype(np.float32)
    sim.set_field("particle_v", v)
    warm = {name: rng.normal(size=n).astype(np.float32) for name in ("dfsph_pressure", "dfsph_divergence_warm")}
    for name, values in warm.items():
        sim.set_field(name, values)
    ids = sim.get_field("particle_id")
    sim.state.time = 0.1  # layers due: the emitter starts at 0 s
    assert sim.flow.begin_frame()
    left = int((~inside).sum())
    k = sim.model.fluid_count - left
    assert k > 0 and sim.flow.removed == int(inside.sum()) and sim.flow.emitted == k
    assert np.array_equal(sim.get_field("particle_x")[:left], x[~inside])
    assert np.array_equal(sim.get_field("particle_v")[:left], v[~inside])
    assert np.array_equal(sim.get_field("particle_id"), np.concatenate([ids[~inside], n + np.arange(k)]))
    for name, values in warm.items():
        got = sim.get_field(name)
        assert len(got) == left + k and np.array_equal(got[:left], values[~inside]) and not got[left:].any(), name
    # the new layers at the nozzle (x = 0.2 m), moving at 1 m/s along +x
    assert np.all(np.abs(sim.get_field("particle_x")[left:, 0] - 0.2) < 0.1 + 1e-6)
    assert np.allclose(sim.get_field("particle_v")[left:, 0], 1.0)
    rows = {r["stage"]: r for r in sim.graph.frame_timing_table()}
    assert rows["flow_sinks"]["calls"] == rows["flow_emitters"]["calls"] == rows["flow_count"]["calls"] == 1
    assert not sim.flow.begin_frame()  # nothing due, nothing inside: the same count, no new views
    rows = {r["stage"]: r for r in sim.graph.frame_timing_table()}
    assert rows["flow_sinks"]["calls"] == rows["flow_emitters"]["calls"] == 2 and rows["flow_count"]["calls"] == 1


def test_frame_stages_on_the_step_graph_timers():
    """StepGraph.timed: calls, wall and process CPU time of each named block (first call apart), in a table
    of its own (the substeps' timing_table is unchanged)."""
    g = StepGraph([Stage("a", lambda sim, dt: None)], set())
    cpu = []
    for k in range(3):
        c = time.process_time()
        with g.timed("busy"):
            t = time.process_time()
            while time.process_time() - t < 0.01 * (k + 1):
                pass
        cpu.append(time.process_time() - c)
    (row,) = g.frame_timing_table()
    assert row["stage"] == "busy" and row["calls"] == 3
    assert row["first_call_cpu_seconds"] == pytest.approx(cpu[0], abs=2e-3)
    assert row["cpu_seconds"] == pytest.approx(sum(cpu), abs=6e-3)
    assert row["cpu_ms_per_call"] == pytest.approx(1e3 * (row["cpu_seconds"] - row["first_call_cpu_seconds"]) / 2)
    assert row["seconds"] >= row["cpu_seconds"] * 0.5
    assert [r["stage"] for r in g.timing_table()] == ["a"]
    with pytest.raises(ValueError):  # an error inside still counts the call
        with g.timed("busy"):
            raise ValueError
    assert g.frame_timing_table()[0]["calls"] == 4


def _record(solver, radius, variant, cpu, flow, steps, particles, repeat=1):
    return {"status": "ok", "label": f"{solver} {variant}",
            "params": {"scene": "river", "solver": solver, "particle_radius": radius, "variant": variant,
                       "repeat": repeat},
            "series": {"cpu": cpu, "frame_stage_cpu": flow, "steps": steps, "particles": particles},
            "frame_stage_times": [{"stage": "flow_sinks", "calls": len(cpu) - 1, "cpu_ms_per_call": 7.5}]}


def test_in_run_share_and_side_by_side():
    """The in-run figures over the frames after the first: flow and run CPU per frame, share = flow / (run -
    flow) per particle-step; the fastest repeat counts; the side-by-side column against the fixed scene."""
    # initial state, frame 1 (kernels load: left out), frames 2-4
    a = _record("pbf", 0.025, "flow", [0.0, 1.0, 1.2, 1.4, 1.6], [0.0, 0.5, 0.51, 0.52, 0.53],
                [0, 9, 10, 10, 10], [100, 100, 110, 120, 130])
    b = _record("pbf", 0.025, "flow", [0.0, 1.0, 1.3, 1.6, 1.9], [0.0, 0.5, 0.52, 0.54, 0.56],
                [0, 9, 10, 10, 10], [100, 100, 110, 120, 130], repeat=2)
    fixed = _record("pbf", 0.025, "fixed", [0.0, 1.0, 1.1, 1.2, 1.3], [0.0] * 5, [0, 9, 10, 10, 10], [100] * 5)
    m = E.in_run(a)
    ps = 10 * (110 + 120 + 130)
    assert m["flow_ms"] == pytest.approx(10.0) and m["run_ms"] == pytest.approx(200.0)
    assert m["share"] == pytest.approx(0.03 / 0.57) and m["ns"] == pytest.approx(1e9 * 0.6 / ps)
    assert m["particles"] == (110, 130) and m["steps_per_frame"] == 10 and m["frames"] == 4
    assert m["stages"]["flow_sinks"] == 7.5
    (c,) = E.summary([a, fixed, b])
    assert c["best"]["ns"] == m["ns"] and c["shares"] == pytest.approx([0.03 / 0.57, 0.06 / 0.84])
    assert c["fixed_ns"] == pytest.approx(1e9 * 0.3 / 3000)
    assert c["side_by_side"] == pytest.approx(m["ns"] / c["fixed_ns"] - 1.0) and c["met"] is False
    lines = "\n".join(E.section([a, fixed, b], lambda v, *s: str(v), lambda r: []))
    assert "5.26 %, 7.14 %" in lines and "not met for 0 of 1 cases" in lines
    stopped = E.in_run({**a, "status": "unstable"})  # the watchdog stopped it: the frames it completed count
    assert stopped["share"] == m["share"] and stopped["status"] == "unstable"
    assert E.in_run({**a, "status": "failed"}) is None
    assert E.in_run(_record("pbf", 0.025, "flow", [0.0, 1.0], [0.0, 0.5], [0, 9], [100, 100])) is None  # one frame


def test_bench_emission_records_and_report(tmp_path):
    """warp-sph bench emission on a coarse river, one solver: the flow's record carries its frame stages and a
    per-frame CPU series, the fixed one none; the report's section has the in-run and the side-by-side
    figures."""
    from warp_sph.cli import main

    status = main(["bench", "emission", "--frames", "4", "--repeats", "1", "--radii", "0.05", "--solvers", "pbf",
                   "--in-process", "--out", str(tmp_path)])
    assert status == 0
    records = [json.loads(line) for line in (tmp_path / "emission.jsonl").read_text().splitlines()]
    by = {r["params"]["variant"]: r for r in records}
    assert set(by) == {"flow", "fixed"} and all(r["status"] == "ok" for r in records)
    flow = by["flow"]
    assert {r["stage"] for r in flow["frame_stage_times"]} >= {"flow_sinks", "flow_emitters"}
    assert len(flow["series"]["cpu"]) == 5 and flow["series"]["cpu"] == sorted(flow["series"]["cpu"])
    assert "frame_stage_times" not in by["fixed"] and not any(by["fixed"]["series"]["frame_stage_cpu"])
    m = E.in_run(flow)
    assert m is not None and 0 < m["flow_ms"] < m["run_ms"]
    md = (tmp_path / "RESULTS.md").read_text()
    assert "## Emitters and sinks: their cost per particle-step" in md and "| pbf | 0.05 |" in md


def test_bench_emission_bad_solver_is_one_line_exit_2(tmp_path, capsys, monkeypatch):
    from warp_sph.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["bench", "emission", "--solvers", "sph"]) == 2
    err = capsys.readouterr().err
    assert "--solvers 'sph': unknown 'sph'" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "runs").exists()


def test_run_json_lists_the_flow_stages(tmp_path):
    """run.json's frame_stage_times: the flow's per-frame stages with one call per frame (and none in a scene
    without emitters and sinks); the substeps' stage_times do not hold them."""
    from warp_sph.run import runner

    out = tmp_path / "flow"
    sc = {**BASE, "solver": "wcsph", "output": {"surface": False, "usd": False}}
    info = runner.run(scene_from_dict(sc, source="flow.toml"), out=out, device="cpu", frames=3, progress=False,
                      log=lambda *a, **k: None)
    rows = {r["stage"]: r for r in json.loads((out / "run.json").read_text())["frame_stage_times"]}
    assert rows["flow_sinks"]["calls"] == rows["flow_emitters"]["calls"] == 2  # frames 1-2 (frame 0: the start)
    assert not {r["stage"] for r in info["stage_times"]} & set(rows)
    plain = {k: v for k, v in sc.items() if k not in ("emitters", "sinks")}
    info = runner.run(scene_from_dict(plain, source="plain.toml"), out=tmp_path / "plain", device="cpu", frames=2,
                      progress=False, log=lambda *a, **k: None)
    assert "frame_stage_times" not in info
