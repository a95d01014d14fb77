"""Memory figures of the benchmarks (issue #32): each case's peak RSS against a known allocation, the
SPlisHSPlasH driver's frames file, the report's RSS columns and ratio from the records, and the scaling bench's
launch-bytes model against launches of known arrays."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import warp as wp

from warp_sph.benchmarks import peak_memory as PM
from warp_sph.benchmarks import records as REC
from warp_sph.benchmarks import splishsplash as S
from warp_sph.benchmarks import splishsplash_report as SR
from warp_sph.benchmarks import traffic as T
from warp_sph.benchmarks.report import write_report
from warp_sph.benchmarks.splishsplash_driver import read_frames
from warp_sph.benchmarks.tables import fmt

BENCHMARKS = Path(PM.__file__).parent
ARRAY = 200_000_000  # [bytes] the child's array

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")


def _child(code: str) -> dict:
    """Run ``code`` in a fresh Python that imports peak_memory by its plain name, as SPlisHSPlasH's driver does;
    its last stdout line as JSON."""
    prog = f"import sys; sys.path.insert(0, {str(BENCHMARKS)!r}); import json; import numpy as np\n" \
           f"from peak_memory import MemoryWindow\n{code}"
    out = subprocess.run([sys.executable, "-c", prog], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_window_reads_a_child_allocation_of_known_size():
    """A child allocates (and touches) a 200 MB array inside the window: the case's peak is within 10 % above the
    baseline plus 200 MB, and per particle it is that over the particle count."""
    m = _child("w = MemoryWindow().open()\na = np.ones(25_000_000)\nprint(json.dumps(w.close(1000)))")
    assert m["rss_peak_scope"] == "case"
    assert ARRAY <= m["rss_peak_increment_bytes"] <= 1.1 * ARRAY
    assert m["rss_case_peak_bytes"] == m["rss_baseline_bytes"] + m["rss_peak_increment_bytes"]
    assert m["rss_peak_per_particle"] == pytest.approx(m["rss_peak_increment_bytes"] / 1000)


def test_window_excludes_what_the_process_held_before_it():
    """400 MB held and freed before the window (the warm-up, an earlier case) is in the process's peak, not the
    case's: the case peak resets to the RSS at open()."""
    m = _child("b = np.ones(50_000_000); del b\nw = MemoryWindow().open()\na = np.ones(12_500_000)\n"
               "print(json.dumps(w.close(1)))")
    assert ARRAY / 2 <= m["rss_peak_increment_bytes"] <= 1.1 * ARRAY / 2
    assert m["rss_process_peak_bytes"] >= 2 * ARRAY > m["rss_case_peak_bytes"]


def test_driver_frames_file_reads_back_as_stacked_frames(tmp_path):
    """grab() writes position, velocity, density of each frame to one file; read_frames stacks them as the npz
    held them before (NumPy oracle)."""
    rng = np.random.default_rng(3)
    n, frames = 7, 4
    x, v, rho = (rng.random((frames, n, 3), dtype=np.float32), rng.random((frames, n, 3), dtype=np.float32),
                 rng.random((frames, n), dtype=np.float32))
    with open(tmp_path / "f.bin", "wb") as f:
        for k in range(frames):
            for a in (x[k], v[k], rho[k]):
                f.write(np.ascontiguousarray(a, dtype=np.float32).tobytes())
    got = read_frames(tmp_path / "f.bin", [n] * frames)
    for a, b in zip(got, (x, v, rho)):
        assert np.array_equal(a, b)


def _record(engine, case, n, peak, inc, invocation="2026-11-26T00:00:00", mode="adaptive", solver="dfsph"):
    return {"schema": REC.SCHEMA, "kind": "splishsplash", "engine": engine, "status": "ok", "threads": 2,
            "label": f"{engine} {case}", "fluid_particles": n, "invocation": invocation, "command": "cmd",
            "params": {"engine": engine, "solver": solver, "mode": mode, "case": case, "particle_radius": 0.025,
                       "dt": None if mode == "adaptive" else 0.002},
            "metrics": {"wall_per_simulated_second": 2.0, "cpu_per_simulated_second": 2.0, "density_error_mean_avg": 1e-3,
                        "simulated_seconds": 1.0, "steps": 100, "rss_case_peak_bytes": peak,
                        "rss_peak_increment_bytes": inc, "rss_peak_per_particle": inc / n}}


def _rows(text: str, title: str, first: str) -> list[list[str]]:
    section = text.split(title)[1]
    return [[c.strip() for c in line.strip("|").split("|")] for line in section.splitlines() if line.startswith(first)]


def test_report_rss_columns_and_ratio_come_from_the_records(tmp_path):
    """Adaptive and fixed-step tables: peak RSS [MiB] and RSS/particle [B] of each record, and the ratio
    warp-sph / SPlisHSPlasH of RSS per particle in the comparison tables (NumPy oracle)."""
    n = 6859
    peaks = np.array([420e6, 60e6])
    incs = np.array([25e6, 9e6])
    recs = [_record("warp-sph", "dfsph", n, peaks[0], incs[0]), _record("splishsplash", "dfsph", n, peaks[1], incs[1])]
    recs += [_record("warp-sph", "pbf", n, peaks[0], incs[0], mode="fixed", solver="pbf"),
             _record("splishsplash", "pbf", n, peaks[1], incs[1], mode="fixed", solver="pbf")]
    with open(tmp_path / "splishsplash.jsonl", "w") as f:
        for r in recs:
            f.write(json.dumps(r) + "\n")
    text = write_report(tmp_path, log=lambda *a: None).read_text()
    ratio = fmt(float(np.divide(incs[0] / n, incs[1] / n)))
    adaptive = "## Side by side with SPlisHSPlasH, each with its own adaptive step"
    rows = {r[0]: r for r in _rows(text, adaptive, ("| warp-sph |", "| splishsplash |"))}
    for k, engine in enumerate(("warp-sph", "splishsplash")):
        assert rows[engine][-2:] == [fmt(peaks[k] / 2 ** 20), fmt(incs[k] / n)]
    assert _rows(text, adaptive, "| dfsph |")[0][-1] == ratio
    assert S.adaptive_ratios(recs[:2])[0]["rss_ratio"] == pytest.approx(incs[0] / incs[1])
    fixed = text.split(adaptive)[0].split("## Side by side with SPlisHSPlasH")[1]
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in fixed.splitlines()
             if line.startswith(("| warp-sph pbf |", "| splishsplash pbf |"))]
    assert [c[-2:] for c in cells] == [[fmt(peaks[k] / 2 ** 20), fmt(incs[k] / n)] for k in range(2)]
    assert [line for line in fixed.splitlines() if line.startswith("| pbf |")][0].strip("|").split("|")[-1].strip() == ratio
    assert "peak RSS [MiB] | RSS/particle [B]" in text and "warp-sph RSS/particle / its" in text


@wp.kernel(enable_backward=False)
def _axpy(a: wp.array(dtype=float), b: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = a[i] + b[i][0]


@wp.struct
class _Rows:
    count: wp.array(dtype=wp.int32)
    value: wp.array(dtype=float)


@wp.kernel(enable_backward=False)
def _row_sum(rows: _Rows, out: wp.array(dtype=float)):
    i = wp.tid()
    s = float(0.0)
    for k in range(rows.count[i]):
        s += rows.value[i * 4 + k]
    out[i] = s


def test_launch_bytes_count_every_launch_of_known_arrays():
    """Two plain launches and three replays of a recorded launch with a struct argument: launches and bytes equal
    the sums of the distinct arrays' nbytes (an array given twice counts once); row arrays at their used entries
    where sizes are given; a launch only recorded counts nothing; the thread setting is restored."""
    n = 100
    a, out = wp.zeros(n, dtype=float, device="cpu"), wp.zeros(n, dtype=float, device="cpu")
    b = wp.zeros(n, dtype=wp.vec3, device="cpu")
    rows = _Rows()
    rows.count = wp.array(np.full(n, 2, dtype=np.int32), device="cpu")
    rows.value = wp.array(np.ones(4 * n, dtype=np.float32), device="cpu")
    before = os.environ.get("WARP_SPH_CPU_THREADS")
    with T.counting_launches(threads=1) as c:
        assert os.environ["WARP_SPH_CPU_THREADS"] == "1"
        wp.launch(_axpy, dim=n, inputs=[a, b], outputs=[out], device="cpu")
        wp.launch(_axpy, dim=n, inputs=[a, b], outputs=[a], device="cpu")  # a given twice: once
        cmd = wp.launch(_row_sum, dim=n, inputs=[rows], outputs=[out], device="cpu", record_cmd=True)
        for _ in range(3):
            cmd.launch()
    assert os.environ.get("WARP_SPH_CPU_THREADS") == before
    nb = {k: x.numpy().nbytes for k, x in (("a", a), ("b", b), ("out", out), ("count", rows.count), ("value", rows.value))}
    assert c.launches == 5
    assert c.bytes() == (nb["a"] + nb["b"] + nb["out"]) + (nb["a"] + nb["b"]) + 3 * (nb["count"] + nb["value"] + nb["out"])
    used = {id(rows.value): nb["value"] // 2}  # 2 of each row's 4 slots
    assert c.bytes(used) == c.bytes() - 3 * nb["value"] // 2
    assert np.array_equal(out.numpy(), np.full(n, 2.0, dtype=np.float32))  # the replays ran: 2 slots of 1.0 per row


def test_counted_steps_are_the_steps_a_run_takes():
    """Counting wraps the launches and changes nothing: a dam break stepped with and without counting ends
    bitwise the same; the traffic metrics are consistent (bytes per particle-step = per step / fluid N)."""
    from warp_sph.run.simulation import Simulation
    from warp_sph.scene import load_scene

    sims = [Simulation(load_scene("dam_break", overrides=["particle_radius=0.1", "solver=dfsph"]), device="cpu")
            for _ in range(2)]
    dt = sims[0].time_step(0.0)
    with sims[0].in_cell_order():
        for _ in range(2):
            sims[0].step(dt)
    met = T.step_traffic(sims[1], dt, steps=2)
    for name in ("particle_x", "particle_v", "particle_density"):
        assert np.array_equal(sims[0].get_field(name), sims[1].get_field(name))
    n = sims[1].model.fluid_count
    assert met["launches_per_step"] > 5
    assert met["launch_bytes_per_particle_step"] == pytest.approx(met["launch_bytes_per_step"] / n)
    assert 0 < met["launch_bytes_per_particle_step"] <= met["launch_allocation_bytes_per_particle_step"]


def test_rss_per_added_particle_from_two_resolutions(tmp_path):
    """The adaptive section's RSS per added fluid particle: (increment at the large N - at the small N) / (N
    difference) of each case, from the records (NumPy oracle: the slope of a line through the two points)."""
    ns, incs = np.array([6859, 59319]), np.array([[30e6, 120e6], [8e6, 50e6]])
    recs = []
    for k, engine in enumerate(("warp-sph", "splishsplash")):
        for n, inc, r in zip(ns, incs[k], (0.025, 0.0125)):
            rec = _record(engine, "dfsph", int(n), 4e8, inc)
            rec["params"]["particle_radius"] = r
            recs.append(rec)
    slopes = {(e, c): b for e, c, _, _, b in SR.rss_slopes(recs)}
    for k, engine in enumerate(("warp-sph", "splishsplash")):
        assert slopes[(engine, "dfsph")] == pytest.approx(np.polyfit(ns, incs[k], 1)[0])
    with open(tmp_path / "splishsplash.jsonl", "w") as f:
        for r in recs:
            f.write(json.dumps(r) + "\n")
    text = write_report(tmp_path, log=lambda *a: None).read_text()
    assert f"warp-sph dfsph {fmt(slopes[('warp-sph', 'dfsph')])} B (6,859 -> 59,319)" in text
