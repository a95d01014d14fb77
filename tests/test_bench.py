"""Benchmark runner and metrics. Speed is never asserted: only that the runner works and each metric
is right on a configuration whose answer is known."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from warp_sph.benchmarks import cases as C
from warp_sph.benchmarks import metrics as M
from warp_sph.benchmarks import records as REC
from warp_sph.benchmarks import report as R
from warp_sph.benchmarks import runner as B
from warp_sph.benchmarks import splishsplash as S
from warp_sph.benchmarks import splishsplash_scene as SS


# --- metrics ---------------------------------------------------------------------------------
def test_surge_front_ignores_outermost_tenth_of_a_percent():
    x = np.zeros((1000, 3))
    x[:, 0] = np.linspace(0.0, 0.999, 1000)   # 0.000, 0.001, ..., 0.999
    x[-1, 0] = 50.0                            # one splash far out: 0.1 % of the particles
    front = M.surge_front(x, wall=0.0)
    assert 0.997 <= front <= 0.999 + 1e-12
    assert M.surge_front(x, wall=-1.0) == pytest.approx(front + 1.0)
    # a known point set: 0.999 quantile of 0..1 sampled at 1001 points is 0.999
    xs = np.linspace(0.0, 1.0, 1001)
    assert M.surge_front(xs) == pytest.approx(0.999)


def test_density_error_stats():
    rho0 = 1000.0
    rho = np.array([990.0, 1000.0, 1010.0, 1030.0])
    s = M.density_error_stats(rho, rho0)
    assert s["mean"] == pytest.approx((0.0 + 0.0 + 0.01 + 0.03) / 4)
    assert s["max"] == pytest.approx(0.03)
    assert s["min"] == pytest.approx(-0.01)


def test_compression_volume_counts_rest_volume_at_most():
    m, rho0 = 2.0, 1000.0
    assert M.compression_volume(np.full(10, rho0), m, rho0) == pytest.approx(10 * m / rho0)
    # under-dense (surface) particles count their rest volume, compressed ones less
    assert M.compression_volume(np.array([500.0, 1000.0]), m, rho0) == pytest.approx(2 * m / rho0)
    assert M.compression_volume(np.array([1100.0]), m, rho0) == pytest.approx(m / 1100.0)


def test_energy():
    v = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    assert M.kinetic_energy(v, 3.0) == pytest.approx(0.5 * 3.0 * (1.0 + 4.0))
    x = np.array([[0.0, 0.0, 1.0], [5.0, 5.0, 3.0]])
    g = (0.0, 0.0, -9.81)
    assert M.potential_energy(x, 2.0, g) == pytest.approx(2.0 * 9.81 * 4.0)
    assert M.potential_energy(x, 2.0, g, reference=(0.0, 0.0, 1.0)) == pytest.approx(2.0 * 9.81 * 2.0)
    s = M.energy_summary([10.0, 11.0, 7.0], scale=2.0)
    assert s["change_final"] == pytest.approx(-1.5)
    assert s["rise_max"] == pytest.approx(0.5)


def _column(depth=0.5, d=0.02, rho0=1000.0, g=9.81):
    z = np.arange(d / 2, depth, d)                 # layer centres; surface = top centre + d/2
    zz = np.repeat(z, 9)
    hs = z.max() + d / 2
    return zz, rho0 * g * (hs - zz), hs


def test_hydrostatic_pressure_error_zero_for_exact_profile():
    z, p, hs = _column()
    e = M.hydrostatic_pressure_error(z, p, 1000.0, 9.81, 0.02, exclude_depth=0.04)
    assert e["surface"] == pytest.approx(hs)
    assert e["layers"] > 10
    assert e["mean_abs"] == pytest.approx(0.0, abs=1e-12)
    assert e["max_abs"] == pytest.approx(0.0, abs=1e-12)


def test_hydrostatic_pressure_error_of_perturbed_profile():
    z, p, _ = _column()
    e = M.hydrostatic_pressure_error(z, 1.03 * p, 1000.0, 9.81, 0.02, exclude_depth=0.04)
    assert e["mean_abs"] == pytest.approx(0.03)
    assert e["mean"] == pytest.approx(0.03)
    # a constant offset: error falls with depth; the shallowest kept layer has the largest
    e = M.hydrostatic_pressure_error(z, p + 100.0, 1000.0, 9.81, 0.02, exclude_depth=0.04)
    expected_max = 100.0 / (1000.0 * 9.81 * min(e["profile"]["depth"]))
    assert e["max_abs"] == pytest.approx(expected_max)
    # layers within exclude_depth of the surface are left out, whatever their pressure
    z2, p2, _ = _column()
    p2[z2 > z2.max() - 0.03] = 0.0
    assert M.hydrostatic_pressure_error(z2, p2, 1000.0, 9.81, 0.02, exclude_depth=0.04)["mean_abs"] == pytest.approx(0.0, abs=1e-12)


def test_speed_metrics_and_pareto():
    s = M.speed_metrics(wall_seconds=2.0, simulated_seconds=0.5, steps=100, fluid_count=1000)
    assert s["wall_per_simulated_second"] == pytest.approx(4.0)
    assert s["particle_steps_per_second"] == pytest.approx(5e4)
    assert s["ms_per_step"] == pytest.approx(20.0)
    assert s["ns_per_particle_step"] == pytest.approx(2e4)
    assert M.pareto_front([1, 2, 3, 2, None], [3, 1, 0.5, 2, 0]) == [True, True, True, False, False]


def test_array_bytes_and_nan_to_none():
    import warp as wp

    a = wp.zeros(10, dtype=wp.vec3, device="cpu")
    assert M.array_bytes([a, a, np.zeros(4), "not an array"]) == 120 + 32
    assert M.nan_to_none({"a": [float("nan"), 1.0], "b": np.float32(2.0)}) == {"a": [None, 1.0], "b": 2.0}


# --- sweep parsing -----------------------------------------------------------------------------
def test_parse_and_expand_params():
    from warp_sph.sweep.cases import SweepError, expand_product, parse_param

    assert parse_param("solver=wcsph,pbf") == ("solver", ["wcsph", "pbf"])
    assert parse_param("gravity=[0,0,-9.81],[0,0,-5]") == ("gravity", ["[0,0,-9.81]", "[0,0,-5]"])
    combos = expand_product({"solver": ["wcsph", "pbf"], "time.cfl": ["0.2", "0.4", "0.8"]})
    assert len(combos) == 6 and combos[0] == {"solver": "wcsph", "time.cfl": "0.2"}
    with pytest.raises(SweepError):
        parse_param("solver")


# --- the runner on a tiny case ----------------------------------------------------------------------
def test_sweep_writes_json_lines_and_table(tmp_path):
    argv = ["sweep", "--scene", "dam_break", "--set", "particle_radius=0.1", "--param", "solver=wcsph",
            "--param", "smoothing_kernel=cubic,quintic", "--frames", "2", "--out", str(tmp_path), "--in-process"]
    assert B.main(argv) == 0
    lines = (tmp_path / "sweep.jsonl").read_text().splitlines()
    assert len(lines) == 2
    for line in lines:
        r = json.loads(line)  # valid JSON, no NaN
        assert r["schema"] == REC.SCHEMA and r["status"] == "ok", r.get("error")
        assert r["command"].startswith("warp-sph bench sweep")
        assert r["scene"]["particle_radius"] == 0.1
        assert r["fluid_particles"] > 0 and r["versions"]["warp"]
        m = r["metrics"]
        assert m["frames"] == 2 and m["steps"] > 0
        for k in ("wall_per_simulated_second", "particle_steps_per_second", "bytes_per_particle",
                  "density_error_mean_avg", "volume_drift_max_abs", "energy_change_final", "front_final",
                  "peak_rss_bytes"):
            assert isinstance(m[k], (int, float)) and math.isfinite(m[k]), k
        assert len(r["series"]["time"]) == 3 and len(r["series"]["front"]) == 3
        assert {s["stage"] for s in r["stage_times"]} >= {"neighbors", "density"}
    md = (tmp_path / "RESULTS.md").read_text()
    assert "warp-sph bench sweep" in md and "| case |" in md
    assert "solver=wcsph smoothing_kernel=quintic" in md


def test_hydrostatic_run_reports_pressure_error(tmp_path):
    spec = C.RunSpec(scene="hydrostatic", overrides=["particle_radius=0.05"], frames=1, name="t",
                     params={"scene": "hydrostatic"})
    r = C.run_warp_sph(spec)
    assert r["status"] == "ok", r.get("error")
    assert r["metrics"]["pressure_error_mean_abs"] is not None
    assert r["pressure_profile"]["depth"]


def test_scaling_records_time_and_memory(tmp_path):
    argv = ["scaling", "--radii", "0.1,0.07", "--steps", "2", "--out", str(tmp_path), "--in-process"]
    assert B.main(argv) == 0
    recs = [json.loads(x) for x in (tmp_path / "scaling.jsonl").read_text().splitlines()]
    assert [r["status"] for r in recs] == ["ok", "ok"]
    assert recs[1]["fluid_particles"] > recs[0]["fluid_particles"]
    assert all(r["metrics"]["ns_per_particle_step"] > 0 and r["metrics"]["bytes_per_particle"] > 0 for r in recs)
    md = (tmp_path / "RESULTS.md").read_text()
    assert "## Scaling: wcsph" in md and "Flatness: the slowest cost per particle-step is" in md
    # a run with other overrides gets a section of its own; iterative solvers report per iteration
    argv = ["scaling", "--solver", "pbf", "--set", "pbf.max_iterations=2", "--radii", "0.1", "--steps", "2",
            "--repeats", "1", "--out", str(tmp_path), "--in-process"]
    assert B.main(argv) == 0
    md = (tmp_path / "RESULTS.md").read_text()
    assert "## Scaling: wcsph" in md and "## Scaling: pbf (pbf.max_iterations=2)" in md
    assert "ns/particle-iteration" in md


def test_scaling_fixed_step_scales_with_the_radius_and_records_cpu_time(tmp_path):
    """--fixed-dt is the step at r = 0.025 m, scaled with r (one section for every radius); the records
    carry the process CPU time of the timed block and, for DFSPH, the divergence sweeps per step."""
    argv = ["scaling", "--solver", "dfsph", "--fixed-dt", "0.002", "--radii", "0.1,0.05", "--steps", "2",
            "--repeats", "1", "--out", str(tmp_path), "--in-process"]
    assert B.main(argv) == 0
    recs = [json.loads(x) for x in (tmp_path / "scaling.jsonl").read_text().splitlines()]
    assert [r["status"] for r in recs] == ["ok", "ok"]
    assert [r["spec"]["overrides"][2] for r in recs] == ["time.fixed_dt=0.008", "time.fixed_dt=0.004"]
    for r in recs:
        met = r["metrics"]
        assert met["simulated_seconds"] == pytest.approx(2 * float(r["spec"]["overrides"][2].split("=")[1]))
        assert 0 < met["cpu_seconds"] == min(r["block_cpu_seconds"])
        assert met["cpu_ns_per_particle_step"] == pytest.approx(1e9 * met["cpu_seconds"] / (2 * r["fluid_particles"]))
        assert met["divergence_iterations_mean"] >= 1 and met["solver_iterations_mean"] >= 2
        # the launch-bytes model of steps run after the timed ones (benchmarks/traffic.py), over one pass
        assert met["traffic_steps"] >= 1 and met["launches_per_step"] > 0 and met["read_bytes"] > 0
        assert met["passes_per_step"] == pytest.approx(met["launch_bytes_per_step"] / met["read_bytes"])
    md = (tmp_path / "RESULTS.md").read_text()
    assert "launch bytes/particle-step (model) | passes/step (model)" in md
    assert md.count("## Scaling: dfsph") == 1 and "## Scaling: dfsph (" not in md
    assert "CPU ns/particle-step" in md and "divergence it./step" in md
    assert "Flatness: the slowest cost per particle-step (CPU) is" in md


def test_failed_case_is_a_record_not_a_crash(tmp_path):
    r = C.run_warp_sph(C.RunSpec(scene="dam_break", overrides=["particle_radius=-1"], frames=1))
    assert r["status"] == "failed" and "particle_radius" in r["error"]


def test_report_from_json_lines_only(tmp_path):
    rec = {"schema": REC.SCHEMA, "kind": "sweep", "name": "quick", "label": "solver=wcsph", "status": "ok",
           "invocation": "2020-01-01T00:00:00", "command": "warp-sph bench sweep --preset quick",
           "host": {"nproc": 2, "cpu_model": "Test CPU"}, "fluid_particles": 10,
           "params": {"scene": "dam_break", "solver": "wcsph"},
           "metrics": {"wall_per_simulated_second": 3.0, "density_error_mean_avg": 0.01},
           "series": {"time": [0.0, 0.1], "front": [0.5, 0.6], "density_error_mean": [0, 0.01], "total_energy": [1, 1]}}
    (tmp_path / "sweep.jsonl").write_text(json.dumps(rec) + "\n" + json.dumps(dict(rec, invocation="2019")) + "\n")
    md = R.write_report(tmp_path).read_text()
    assert "Test CPU (2 CPUs)" in md and "warp-sph bench sweep --preset quick" in md
    assert md.count("| **solver=wcsph** * |") == 1  # only the latest invocation


# --- SPlisHSPlasH scene translation (no pysplishsplash needed) ---------------------------------------
def test_splishsplash_scene_matches_the_warp_sph_scene():
    scene = {"particle_radius": 0.025, "gravity": (0.0, 0.0, -9.81), "material": {"rest_density": 1000.0},
             "pbf": {"max_iterations": 50, "min_iterations": 2, "target_density_error": 0.005}}
    model = {"stiffness": 2.0e6, "equation_of_state": "linear"}
    sj = SS.scene_json(scene, model, (0.055, 0.055, 0.055), (0.955, 0.955, 0.955), "wcsph", 4e-4, "/tmp/box.obj")
    c = sj["Configuration"]
    assert c["gravitation"] == [0.0, -9.81, 0.0]            # Y-up
    assert c["simulationMethod"] == 0 and c["boundaryHandlingMethod"] == 0 and c["cflMethod"] == 0
    assert c["WCSPH"] == {"stiffness": 2.0e6, "exponent": 1.0}
    b = sj["FluidBlocks"][0]
    # SPlisHSPlasH puts particles at start + d ... end - d: the lattice corners -/+ d
    assert b["start"] == pytest.approx([0.005, 0.005, 0.005]) and b["end"] == pytest.approx([1.005, 1.005, 1.005])
    assert SS.time_step_values(scene, model, "pbf")["MAX_ERROR"] == pytest.approx(0.5)
    assert SS.from_y_up(np.array([[1.0, 2.0, 3.0]])).tolist() == [[1.0, 3.0, 2.0]]
    assert SS.box_obj_text((0, 0, 0), (1, 2, 3)).count("\nf ") == 12


def test_isolated_run_in_a_fresh_process():
    r = C.run_isolated(C.RunSpec(scene="dam_break", overrides=["particle_radius=0.1"], frames=1,
                                  params={"scene": "dam_break"}))
    assert r["status"] == "ok", r.get("error")
    assert r["metrics"]["peak_rss_bytes"] > 0


def test_surface_bench_tiny(tmp_path):
    """The surface benchmark runs on a tiny dam break and its section lands in the report."""
    from warp_sph.benchmarks.runner import main

    out = tmp_path / "res"
    assert main(["surface", "--radius", "0.1", "--time", "0", "--cell", "1.0", "--threads", "1", "--repeats", "1",
                 "--frames", "3", "--out", str(out)]) == 0
    import importlib.util
    import json

    recs = [json.loads(line) for line in (out / "surface.jsonl").read_text().splitlines()]
    ours = {r["variant"]: r for r in recs if r["engine"] == "warp-sph"}
    assert set(ours) == {"raw", "pipeline", "default", "run"}
    run = ours.pop("run")  # every frame of the default run (3 here), with the simulation's time per frame
    assert run["frames"] == 3 and run["triangles"] > 0 and run["usd_bytes"] > 0 and run["sim_ms"] > 0.0
    assert run["sim_ratio"] == pytest.approx(run["ms"] / run["sim_ms"]) and run["warp_dense_mc_ms"] > 0.0 < run["warp_sparse_mc_ms"]
    assert run["cell_per_radius"] == pytest.approx(2.0)  # the scene default, not --cell
    for r in ours.values():
        assert r["kind"] == "surface" and r["triangles"] > 0 and r["ms"] > 0 and r["threads"] == 1
        assert sum(r["stage_ms"].values()) <= r["ms"] * 1.01
    assert ours["raw"]["stage_ms"]["smoothing"] == 0.0 and ours["pipeline"]["stage_ms"]["smoothing"] > 0.0
    assert ours["default"]["usd_write_ms"] > 0.0 and ours["default"]["usd_bytes_per_frame"] > 0
    if importlib.util.find_spec("pysplashsurf") is not None:  # measured beside, on the same particles
        theirs = {r["variant"]: r for r in recs if r["engine"] == "splashsurf" and r["variant"] != "run"}
        assert set(theirs) == {"raw", "pipeline"} and all(r["status"] == "ok" for r in theirs.values())
        assert ours["raw"]["splashsurf_ms"] == theirs["raw"]["ms"]
        # same cell, level and support: meshes of comparable size (marching cubes on both sides)
        assert 0.5 < ours["raw"]["triangles"] / theirs["raw"]["triangles"] < 2.0
        # the run case: splashsurf's pipeline on the same frames at the same cell and at 1.0 r
        cells = sorted(r["cell_per_radius"] for r in recs if r["engine"] == "splashsurf" and r["variant"] == "run")
        assert cells == [1.0, 2.0] and run["ratio_to_splashsurf"] == pytest.approx(run["ms"] / run["splashsurf_ms"])
    assert "## Surface reconstruction" in (out / "RESULTS.md").read_text()


def test_speed_ratio_against_splishsplash():
    """The ratio is warp-sph's wall time per simulated second over SPlisHSPlasH's, per solver."""
    from warp_sph.benchmarks.splishsplash_report import speed_ratios

    def rec(engine, solver, speed, err, cpu=None):
        return {"engine": engine, "status": "ok", "threads": 2, "params": {"solver": solver},
                "metrics": {"wall_per_simulated_second": speed, "density_error_mean_avg": err,
                            "cpu_per_simulated_second": cpu}}

    records = [rec("warp_sph", "wcsph", 6.0, 0.001, 9.0), rec("splishsplash", "wcsph", 8.0, 0.005, 12.0),
               rec("warp_sph", "pbf", 30.0, 0.003), rec("splishsplash", "dfsph", 5.0, 0.0001)]
    (q,) = speed_ratios(records)
    assert q["solver"] == "wcsph" and q["ratio"] == pytest.approx(0.75)
    assert q["cpu_ratio"] == pytest.approx(0.75)  # process CPU time of every thread, beside the wall ratio
    assert q["ours_error"] == 0.001 and q["ref_error"] == 0.005


# --- where results go (issue #15, item 25) -------------------------------------------------------------
def _snapshot(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_quick_and_adhoc_runs_leave_the_committed_results_alone(tmp_path, monkeypatch):
    """`bench sweep --preset quick` used to rewrite the committed RESULTS.md and results/sweep.jsonl;
    quick and ad-hoc runs now go to runs/bench in the working directory, and the committed page
    changes only with --publish."""
    pkg = tmp_path / "pkg"
    committed = pkg / "results"
    committed.mkdir(parents=True)
    (committed / "sweep.jsonl").write_text("")
    (pkg / "RESULTS.md").write_text("# the committed page\n")
    for mod in (REC, B, R):  # the committed results folder, wherever the code reads it from
        if hasattr(mod, "RESULTS_DIR"):
            monkeypatch.setattr(mod, "RESULTS_DIR", committed.resolve())
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    before = _snapshot(pkg)
    assert B.main(["sweep", "--preset", "quick", "--in-process"]) == 0
    assert B.main(["sweep", "--set", "particle_radius=0.1", "--frames", "1", "--in-process", "--name", "mine"]) == 0
    assert B.main(["report"]) == 0
    assert _snapshot(pkg) == before
    mine = work / "runs" / "bench"
    assert len((mine / "sweep.jsonl").read_text().splitlines()) == 6
    page = (mine / "RESULTS.md").read_text()
    assert "## Sweep: quick" in page and "## Sweep: mine" in page
    # asked to: --publish writes the committed results and page
    assert B.main(["sweep", "--set", "particle_radius=0.1", "--frames", "1", "--in-process", "--publish"]) == 0
    assert len((committed / "sweep.jsonl").read_text().splitlines()) == 1
    assert "## Sweep: custom" in (pkg / "RESULTS.md").read_text()


def test_report_without_matplotlib_keeps_the_plots_of_sections_it_did_not_rerun(tmp_path, monkeypatch):
    """Without matplotlib a rebuilt report used to drop every plot link; now it drops only the links of
    plots whose records changed since they were drawn."""
    from warp_sph.benchmarks import plots as P

    def rec(name, invocation, speed):
        return {"schema": REC.SCHEMA, "kind": "sweep", "name": name, "label": "solver=wcsph", "status": "ok",
                "invocation": invocation, "command": f"warp-sph bench sweep --name {name}",
                "host": {"nproc": 2, "cpu_model": "Test CPU"}, "fluid_particles": 10,
                "params": {"scene": "dam_break", "solver": "wcsph"},
                "metrics": {"wall_per_simulated_second": speed, "density_error_mean_avg": 0.01},
                "series": {"time": [0.0, 0.1], "front": [0.5, 0.6], "density_error_mean": [0, 0.01],
                           "total_energy": [1, 1]}}

    def fake_plot(records, path, *a):  # as matplotlib would: a file, its path
        Path(path).write_bytes(b"png of " + json.dumps([r["invocation"] for r in records]).encode())
        return Path(path)

    lines = [rec("a", "2020-01-01T00:00:00", 3.0), rec("b", "2020-01-01T00:00:00", 4.0)]
    (tmp_path / "sweep.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    monkeypatch.setattr(P, "pyplot_or_none", lambda: object())
    monkeypatch.setattr(R, "plot_tradeoff", lambda recs, path, title: fake_plot(recs, path))
    monkeypatch.setattr(R, "plot_series", lambda recs, keys, path, title: fake_plot(recs, path))
    md = R.write_report(tmp_path).read_text()
    assert "(./sweep_a_dam_break_tradeoff.png)" in md and "(./sweep_b_dam_break_tradeoff.png)" in md
    # a new run of sweep b only, report rebuilt without matplotlib
    with open(tmp_path / "sweep.jsonl", "a") as f:
        f.write(json.dumps(rec("b", "2021-01-01T00:00:00", 5.0)) + "\n")
    monkeypatch.setattr(P, "pyplot_or_none", lambda: None)
    monkeypatch.setattr(R, "plot_tradeoff", lambda *a: None)
    monkeypatch.setattr(R, "plot_series", lambda *a: None)
    md = R.write_report(tmp_path).read_text()
    a, b = md.split("## Sweep: b")
    assert "(./sweep_a_dam_break_tradeoff.png)" in a and "(./sweep_a_dam_break_series.png)" in a
    assert ".png)" not in b  # b's plots show the old run: not linked
    assert "matplotlib is not installed" in md


# --- module structure (issue #16) ------------------------------------------------------------------------
def _benchmark_imports() -> dict[str, set[str]]:
    import ast

    folder = Path(R.__file__).parent
    names = {p.stem for p in folder.glob("*.py")}
    graph = {}
    for p in folder.glob("*.py"):
        deps = set()
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                if node.module:
                    deps.add(node.module.split(".")[0])
                else:
                    deps.update(a.name for a in node.names)
        graph[p.stem] = deps & names
    return graph


def test_benchmarks_have_no_import_cycle_and_the_core_does_not_import_them():
    graph = _benchmark_imports()
    assert not any("runner" in deps for deps in graph.values())  # runner.py is only the command line
    state = {}

    def visit(n, path):
        assert state.get(n) != "open", f"import cycle: {' -> '.join(path + [n])}"
        if state.get(n) == "done":
            return
        state[n] = "open"
        for d in sorted(graph[n]):
            visit(d, path + [n])
        state[n] = "done"

    for n in graph:
        visit(n, [])
    import ast

    root = Path(R.__file__).resolve().parents[1] / "warp_sph"
    if not root.is_dir():  # an installed copy: the package is the parent of benchmarks
        root = Path(R.__file__).resolve().parents[1]
    for p in root.rglob("*.py"):
        if "benchmarks" in p.parts:
            continue
        tree = ast.parse(p.read_text())
        top = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))]
        for node in ast.walk(tree):
            mods = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                    [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            if any("benchmarks" in m for m in mods):
                assert p.name == "cli.py" and node not in top, f"{p} imports the benchmarks"


def test_benchmark_solver_lists_come_from_one_function():
    from warp_sph.methods import registry

    assert REC.solver_names() == registry.solver_names() and set(REC.solver_names()) >= {"wcsph", "pbf"}
    from warp_sph.benchmarks.matrix import matrix_specs

    specs = matrix_specs(scenes=["dam_break"], radii=[0.1], frames=1)
    assert [s.params["solver"] for s in specs] == list(REC.solver_names())


# --- executors -----------------------------------------------------------------------------------------
def test_scheduler_overhead_of_known_timestamps():
    from warp_sph.benchmarks.executor_speed import scheduler_overhead

    rows = [  # worker 1: two cases back to back; worker 2: one case
        {"host": "h", "pid": 1, "submitted": 0.0, "started": 0.3, "finished": 2.0, "received": 2.1},
        {"host": "h", "pid": 1, "submitted": 0.0, "started": 2.2, "finished": 3.0, "received": 3.05},
        {"host": "h", "pid": 2, "submitted": 1.0, "started": 1.5, "finished": 4.0, "received": 4.0},
    ]
    assert sorted(scheduler_overhead(rows)) == pytest.approx(sorted([0.3 + 0.1, 0.2 + 0.05, 0.5 + 0.0]))


def test_bench_scaling_on_a_local_cluster(tmp_path):
    argv = ["scaling", "--radii", "0.1,0.07", "--steps", "2", "--repeats", "1", "--out", str(tmp_path),
            "--in-process", "--workers", "2", "--no-report"]
    assert B.main(argv) == 0
    recs = [json.loads(x) for x in (tmp_path / "scaling.jsonl").read_text().splitlines()]
    assert [r["params"]["particle_radius"] for r in recs] == [0.1, 0.07]  # in the order asked, not finished
    assert [r["status"] for r in recs] == ["ok", "ok"]
    assert all(r["host"]["warp_sph_cpu_threads"] == "1" for r in recs)  # each worker pinned to one thread


def test_executor_benchmark_runs_both_executors(tmp_path):
    from warp_sph.benchmarks.executor_speed import measure

    (rec,) = measure(workers=2, particle_radius=0.1, frames=3, repeats=1, log=lambda *a: None)
    m = rec["metrics"]
    assert rec["status"] == "ok", rec.get("error")
    assert m["results_identical"] is True and m["worker_processes"] == 2
    assert m["serial_seconds"] > 0 and m["local_cluster_seconds"] > m["cases_window_seconds"] > 0
    assert m["ratio"] == pytest.approx(m["local_cluster_seconds"] / m["serial_seconds"])
    assert 0 <= m["overhead_per_case_mean"] <= m["overhead_per_case_max"]
    assert len(m["case_seconds_serial"]) == 8
# --- adaptive-step comparison (warp-sph bench splishsplash --adaptive) ------------------------------
def test_adaptive_splishsplash_scene_uses_its_cfl_step_and_method_defaults():
    scene = {"particle_radius": 0.025, "gravity": (0.0, 0.0, -9.81), "material": {"rest_density": 1000.0}}
    sj = SS.scene_json(scene, {}, (0.055,) * 3, (0.955,) * 3, "iisph", 1e-3, "/tmp/box.obj", adaptive=True,
                      time_step={})
    c = sj["Configuration"]
    assert c["cflMethod"] == 1 and c["cflFactor"] == 1.0 and c["cflMaxTimeStepSize"] == 0.005
    assert c["simulationMethod"] == 3 and c["IISPH"] == {}  # its defaults: nothing set
    cases = {label: (method, values) for label, method, values in S.ADAPTIVE_SPLISHSPLASH}
    assert cases["wcsph stiffness=50000"] == ("wcsph", {"STIFFNESS": 50000.0})
    assert {m for m, _ in cases.values()} == {"dfsph", "iisph", "pbf", "wcsph"}
    sj = SS.scene_json(scene, {}, (0.055,) * 3, (0.955,) * 3, "wcsph", 1e-3, "/tmp/box.obj", adaptive=True,
                      time_step={"STIFFNESS": 50000.0})
    assert sj["Configuration"]["WCSPH"] == {"stiffness": 50000.0}
    from warp_sph.benchmarks.arguments import parse_resolutions
    from warp_sph.core.errors import WarpSphError

    assert parse_resolutions("0.025:1.0,0.0125:0.3") == [(0.025, 1.0), (0.0125, 0.3)]
    with pytest.raises(WarpSphError, match="RADIUS:SECONDS"):
        parse_resolutions("0.025:x")


def test_adaptive_ratios_and_report_section(tmp_path):
    """warp-sph DFSPH over each SPlisHSPlasH DFSPH case of the same radius, and the report's section."""
    import json

    from warp_sph.benchmarks.report import write_report

    def rec(engine, case, solver, wall, cpu, err, n=6859, r=0.025):
        return {"schema": REC.SCHEMA, "kind": "splishsplash", "engine": engine, "status": "ok", "threads": 2,
                "label": f"{engine} {case}", "fluid_particles": n, "invocation": "2026-01-01T00:00:00",
                "params": {"engine": engine, "solver": solver, "mode": "adaptive", "case": case, "particle_radius": r},
                "metrics": {"wall_per_simulated_second": wall, "cpu_per_simulated_second": cpu,
                            "density_error_mean_avg": err, "simulated_seconds": 1.0, "steps": 300}}

    records = [rec("warp-sph", "dfsph", "dfsph", 3.0, 5.0, 5e-4), rec("warp-sph", "pbf", "pbf", 6.0, 9.0, 1.3e-3),
               rec("splishsplash", "dfsph", "dfsph", 12.0, 10.0, 2e-4),
               rec("splishsplash", "dfsph maxError=0.05", "dfsph", 6.0, 5.0, 5.4e-4),
               rec("splishsplash", "iisph", "iisph", 9.0, 8.0, 7e-4)]
    ratios = {q["case"]: q for q in S.adaptive_ratios(records)}
    assert set(ratios) == {"dfsph", "dfsph maxError=0.05"}
    assert ratios["dfsph maxError=0.05"]["ratio"] == pytest.approx(0.5)
    assert ratios["dfsph"]["cpu_ratio"] == pytest.approx(0.5) and ratios["dfsph"]["ref_error"] == 2e-4
    with open(tmp_path / "splishsplash.jsonl", "w") as f:
        for r in records:
            f.write(json.dumps(r) + "\n")
    text = write_report(tmp_path, log=lambda *a: None).read_text()
    assert "## Side by side with SPlisHSPlasH, each with its own adaptive step" in text
    assert "### 6,859 fluid particles" in text and "dfsph maxError=0.05" in text
    assert "## Side by side with SPlisHSPlasH\n" not in text  # adaptive records stay out of the fixed-step section


def test_adaptive_warp_sph_runs_record_cpu_time_and_iterations():
    """Every registered solver runs with its defaults and its own step; DFSPH records both solves."""
    records = S.run_adaptive([(0.1, 0.1)], splishsplash_cases=(), isolate=False, log=lambda *a: None)
    from warp_sph.methods import registry

    assert [r["params"]["solver"] for r in records] == list(registry.solver_names())
    for r in records:
        assert r["status"] == "ok", r.get("error")
        m = r["metrics"]
        assert m["cpu_per_simulated_second"] > 0 and m["dt_mean"] > 0 and r["params"]["mode"] == "adaptive"
        assert not any(o.startswith("time.fixed_dt") for o in r["spec"]["overrides"])
    dfsph = next(r for r in records if r["params"]["solver"] == "dfsph")
    assert dfsph["metrics"]["solver_iterations_mean"] >= 2 and dfsph["metrics"]["divergence_iterations_mean"] >= 1


def test_adaptive_repeats_keep_the_fastest_run_of_each_case(monkeypatch):
    """--repeats N runs every case N times in turns and keeps each case's fastest finished run, with all
    runs' wall and CPU seconds beside it."""
    walls = iter([5.0, 3.0, 4.0, 2.0, 6.0, 7.0])  # case A, B, A, B, A, B
    order = []

    def fake_run_specs(specs, isolate, log):
        order.append(specs[0].params["solver"])
        w = next(walls)
        return [{"status": "ok", "params": dict(specs[0].params), "spec": {},
                 "metrics": {"wall_per_simulated_second": w, "cpu_per_simulated_second": 1.5 * w}}]

    monkeypatch.setattr(C, "run_specs", fake_run_specs)
    records = S.run_adaptive([(0.1, 0.05)], warp_sph_solvers=["pbf", "dfsph"], splishsplash_cases=(), isolate=False,
                             repeats=3, log=lambda *a: None)
    assert order == ["pbf", "dfsph"] * 3
    by = {r["params"]["solver"]: r for r in records}
    assert by["pbf"]["metrics"]["wall_per_simulated_second"] == 4.0 and by["pbf"]["repeats"] == 3
    assert by["pbf"]["repeat_wall_per_simulated_second"] == [5.0, 4.0, 6.0]
    assert by["dfsph"]["metrics"]["wall_per_simulated_second"] == 2.0
    assert by["dfsph"]["repeat_cpu_per_simulated_second"] == [4.5, 3.0, 10.5]
    failed = S.fastest_of([{"status": "failed", "metrics": {}}, {"status": "failed", "metrics": {}}])
    assert failed["status"] == "failed" and failed["repeats"] == 2


@pytest.mark.parametrize("argv,message", [
    (["bench", "matrix", "--radii", "abc"], "argument --radii: expected comma-separated numbers > 0, got 'abc'"),
    (["bench", "matrix", "--radii", "0,0.1"], "argument --radii: expected comma-separated numbers > 0"),
    (["bench", "matrix", "--frames", "0"], "argument --frames: expected an integer > 0, got '0'"),
    (["bench", "matrix", "--solvers", "foo,pbf"], "--solvers 'foo,pbf': unknown 'foo'; expected some of dfsph, pbf, wcsph"),
    (["bench", "scaling", "--solver", "nope"], "--solver 'nope': unknown 'nope'"),
    (["bench", "bodies", "--frames", "-2"], "argument --frames: expected an integer > 0, got '-2'"),
    (["bench", "surface", "--threads", "0"], "argument --threads: expected comma-separated integers > 0"),
    (["bench", "splishsplash", "--adaptive", "--resolutions", "x:1"], "--resolutions 'x:1': expected RADIUS:SECONDS"),
])
def test_bench_bad_arguments_are_one_line_errors_before_any_case(argv, message, tmp_path, capsys, monkeypatch):
    """Bad numbers and names are refused up front with exit status 2 (they used to run every case to a
    failure, print a traceback, or run with a negative frame count)."""
    from warp_sph.cli import main

    monkeypatch.chdir(tmp_path)
    try:
        status = main(argv)
    except SystemExit as e:  # argparse's own errors
        status = e.code
    assert status == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "runs").exists()


def test_publish_without_the_reference_tool_is_refused(tmp_path, capsys, monkeypatch):
    """`--publish` would replace the committed side-by-side rows with warp-sph-only ones when the other
    tool is missing: refused up front (one line, exit 2), nothing written."""
    from warp_sph.benchmarks import surface as SURF
    from warp_sph.cli import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(SURF, "splashsurf_available", lambda: False)
    monkeypatch.setattr(S, "available", lambda *a, **k: (False, "No module named 'pysplishsplash'"))
    published = REC.RESULTS_DIR / "surface.jsonl"
    before = published.read_bytes() if published.is_file() else None
    assert main(["bench", "surface", "--publish"]) == 2
    assert "pip install pysplashsurf (or pass --no-splashsurf)" in capsys.readouterr().err
    assert main(["bench", "splishsplash", "--adaptive", "--publish"]) == 2
    assert "pip install pysplishsplash" in capsys.readouterr().err
    assert (published.read_bytes() if published.is_file() else None) == before


def test_results_folder_that_is_a_file_is_refused_before_the_benchmark(tmp_path, capsys):
    """``bench emission --out FILE`` ran the whole benchmark, then ended in a FileExistsError traceback
    writing its results. Now one line, exit 2, before anything runs; the file is kept."""
    from warp_sph.cli import main

    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    for out, what in ((notes, "is a file"), (notes / "sub", f"lies under the file {notes}")):
        assert main(["bench", "emission", "--frames", "2", "--repeats", "1", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"warp-sph: error: --out {out} {what}; expected a results folder"], err
    assert notes.read_text() == "mine" and [p.name for p in tmp_path.iterdir()] == ["notes.txt"]
