"""`warp-sph bench splishsplash --adaptive --solvers ...` runs only the named methods in both engines,
and the report keeps the rows of the cases a filtered run did not run. Both engines are stubbed: no
SPlisHSPlasH and no warp-sph stepping is needed."""
import json

import pytest

from warp_sph.benchmarks import cases as C
from warp_sph.benchmarks import records as REC
from warp_sph.benchmarks import splishsplash as S
from warp_sph.benchmarks import splishsplash_report as SR
from warp_sph.benchmarks.report import write_report


def _fake_engines(monkeypatch, ran: list):
    """Replace both engines' runs by records that say which case ran."""
    def fake_run_specs(specs, isolate, log, executor=None):
        ran.append(("warp-sph", specs[0].params["case"]))
        return [{"status": "ok", "engine": "warp-sph", "params": dict(specs[0].params), "spec": {},
                 "fluid_particles": 64, "metrics": {"wall_per_simulated_second": 2.0}}]

    def fake_case(scene, model, fmin, fmax, method, dt, frames, threads, adaptive=False, time_step=None, label=None):
        ran.append(("splishsplash", label))
        return {"status": "ok", "engine": "splishsplash", "label": f"SPlisHSPlasH {label}", "fluid_particles": 64,
                "params": {"engine": "splishsplash", "solver": method, "mode": "adaptive", "case": label},
                "metrics": {"wall_per_simulated_second": 1.0}}

    monkeypatch.setattr(C, "run_specs", fake_run_specs)
    monkeypatch.setattr(S, "run_splishsplash_case", fake_case)
    monkeypatch.setattr(S, "available", lambda *a, **k: (True, ""))


@pytest.mark.parametrize("solvers,expected", [
    ("dfsph", {("warp-sph", "dfsph"), ("splishsplash", "dfsph"), ("splishsplash", "dfsph maxError=0.05")}),
    ("iisph,pbf", {("splishsplash", "iisph"), ("warp-sph", "pbf"), ("splishsplash", "pbf")}),
])
def test_adaptive_solvers_filter_both_engines(solvers, expected, monkeypatch, tmp_path):
    """--solvers dfsph used to run every warp-sph solver and every SPlisHSPlasH case in adaptive mode."""
    from warp_sph.cli import main

    ran = []
    _fake_engines(monkeypatch, ran)
    status = main(["bench", "splishsplash", "--adaptive", "--in-process", "--solvers", solvers,
                   "--resolutions", "0.1:0.05", "--out", str(tmp_path), "--no-report"])
    assert status == 0
    assert set(ran) == expected and len(ran) == len(expected)
    written = [json.loads(line) for line in (tmp_path / "splishsplash.jsonl").read_text().splitlines()]
    assert {(r["engine"], r["params"]["case"]) for r in written} == expected


def test_adaptive_without_solvers_runs_every_case(monkeypatch, tmp_path):
    from warp_sph.cli import main
    from warp_sph.methods.registry import solver_names

    ran = []
    _fake_engines(monkeypatch, ran)
    assert main(["bench", "splishsplash", "--adaptive", "--in-process", "--resolutions", "0.1:0.05",
                 "--out", str(tmp_path), "--no-report"]) == 0
    assert ran == ([("warp-sph", s) for s in solver_names()]
                   + [("splishsplash", label) for label, _, _ in S.ADAPTIVE_SPLISHSPLASH])


def test_unknown_solver_is_one_line_error_before_any_case(monkeypatch, tmp_path, capsys):
    from warp_sph.cli import main

    ran = []
    _fake_engines(monkeypatch, ran)
    assert main(["bench", "splishsplash", "--adaptive", "--solvers", "dfsph,sph", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--solvers 'dfsph,sph': unknown 'sph'" in err[0] and "iisph" in err[0]
    assert ran == [] and not (tmp_path / "splishsplash.jsonl").exists()
    assert main(["bench", "splishsplash", "--solvers", "iisph", "--out", str(tmp_path)]) == 2  # fixed step: no IISPH
    assert "unknown 'iisph'; expected some of wcsph, pbf, dfsph" in capsys.readouterr().err


def _record(engine, case, solver, wall, invocation, r=0.0125, n=59319, mass=None):
    rec = {"schema": REC.SCHEMA, "kind": "splishsplash", "engine": engine, "status": "ok", "threads": 2,
           "label": f"{engine} {case}", "fluid_particles": n, "invocation": invocation, "command": "cmd " + invocation,
           "params": {"engine": engine, "solver": solver, "mode": "adaptive", "case": case, "particle_radius": r},
           "metrics": {"wall_per_simulated_second": wall, "cpu_per_simulated_second": wall,
                       "density_error_mean_avg": 1e-3, "simulated_seconds": 0.3, "steps": 100}}
    if mass is not None:
        if engine == "splishsplash":
            rec["splishsplash"] = {"mass": mass, "rest_density": 1000.0}
        else:
            rec["model"] = {"particle_mass": mass, "rest_density": 1000.0}
    return rec


def test_report_keeps_the_cases_a_filtered_run_did_not_run(tmp_path):
    """A --solvers dfsph run published after a full one replaced the whole resolution's table with its
    three rows; now each case shows its latest record, the others stay."""
    old, new = "2026-01-01T00:00:00", "2026-02-01T00:00:00"
    full = [_record("warp-sph", s, s, 10.0, old) for s in ("dfsph", "pbf", "wcsph")]
    full += [_record("splishsplash", label, method, 20.0, old) for label, method, _ in S.ADAPTIVE_SPLISHSPLASH]
    part = [_record("warp-sph", "dfsph", "dfsph", 4.0, new),
            _record("splishsplash", "dfsph", "dfsph", 8.0, new),
            _record("splishsplash", "dfsph maxError=0.05", "dfsph", 2.0, new)]
    with open(tmp_path / "splishsplash.jsonl", "w") as f:
        for r in full + part:
            f.write(json.dumps(r) + "\n")
    kept = SR.latest_per_case(full + part)
    assert len(kept) == 3 + len(S.ADAPTIVE_SPLISHSPLASH)
    by = {(r["engine"], r["params"]["case"]): r for r in kept}
    assert by[("warp-sph", "dfsph")]["invocation"] == new and by[("warp-sph", "pbf")]["invocation"] == old
    assert by[("splishsplash", "iisph")]["invocation"] == old
    text = write_report(tmp_path, log=lambda *a: None).read_text()
    section = text.split("## Side by side with SPlisHSPlasH, each with its own adaptive step")[1]
    table = [line for line in section.splitlines() if line.startswith(("| warp-sph |", "| splishsplash |"))]
    assert len(table) == 3 + len(S.ADAPTIVE_SPLISHSPLASH)
    assert "| warp-sph | pbf |" in section and "| splishsplash | iisph |" in section
    assert "Command: `cmd " + old + "`" in section and "Command: `cmd " + new + "`" in section
    ratios = {q["case"]: q["ratio"] for q in S.adaptive_ratios(kept)}
    assert ratios == {"dfsph": pytest.approx(0.5), "dfsph maxError=0.05": pytest.approx(2.0)}


def test_particle_masses_come_from_the_records():
    """The report said SPlisHSPlasH's mass is 0.8 d^3 rho0; its driver records getMass(0) = d^3 rho0."""
    d3 = (2 * 0.0125) ** 3
    recs = [_record("splishsplash", "dfsph", "dfsph", 1.0, "x", mass=d3 * 1000.0),
            _record("warp-sph", "dfsph", "dfsph", 1.0, "x", mass=1.00003 * d3 * 1000.0)]
    masses = SR.particle_masses(recs)
    assert masses["SPlisHSPlasH"] == pytest.approx(1.0) and masses["warp-sph"] == pytest.approx(1.00003)
    assert "SPlisHSPlasH 1.00000, warp-sph 1.00003" in SR.mass_note(recs)
    assert SR.mass_note([_record("warp-sph", "dfsph", "dfsph", 1.0, "x")]) == ""


def test_fixed_step_repeats_alternate_engines_and_keep_the_fastest(monkeypatch, tmp_path):
    """`bench splishsplash --repeats 3` (fixed step) runs each solver's two cases in turns and keeps each
    case's fastest run with every run's time beside it (one run's time scatters by 10-30 % on a 2-core VM)."""
    from warp_sph.cli import main

    ran, walls = [], {"warp-sph": iter([3.0, 1.5, 2.0]), "splishsplash": iter([4.0, 5.0, 3.5])}

    def fake_run_specs(specs, isolate, log, executor=None):
        ran.append("warp-sph")
        return [{"status": "ok", "engine": "warp-sph", "params": dict(specs[0].params), "spec": {}, "fluid_particles": 64,
                 "metrics": {"wall_per_simulated_second": next(walls["warp-sph"]), "mean_density_error": 1e-3}}]

    def fake_case(scene, model, fmin, fmax, method, dt, frames, threads, adaptive=False, time_step=None, label=None):
        ran.append("splishsplash")
        return {"status": "ok", "engine": "splishsplash", "label": f"SPlisHSPlasH {method}", "fluid_particles": 64,
                "threads": threads, "params": {"engine": "splishsplash", "solver": method, "dt": dt},
                "metrics": {"wall_per_simulated_second": next(walls["splishsplash"]), "mean_density_error": 1e-3}}

    monkeypatch.setattr(C, "run_specs", fake_run_specs)
    monkeypatch.setattr(S, "run_splishsplash_case", fake_case)
    monkeypatch.setattr(S, "available", lambda *a, **k: (True, ""))
    assert main(["bench", "splishsplash", "--in-process", "--solvers", "wcsph", "--repeats", "3",
                 "--particle-radius", "0.1", "--frames", "1", "--out", str(tmp_path), "--no-report"]) == 0
    assert ran == ["warp-sph", "splishsplash"] * 3
    written = [json.loads(line) for line in (tmp_path / "splishsplash.jsonl").read_text().splitlines()]
    assert [r["engine"] for r in written] == ["warp-sph", "splishsplash"]
    assert [r["metrics"]["wall_per_simulated_second"] for r in written] == [1.5, 3.5]
    assert written[0]["repeat_wall_per_simulated_second"] == [3.0, 1.5, 2.0] and written[1]["repeats"] == 3
