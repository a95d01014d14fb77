"""``warp-sph sweep``: case expansion, the serial and Dask executors, resume, failures, Ctrl-C.

The Dask tests run on a LocalCluster of 2 worker processes (the ``test`` extra installs Dask);
cases are tiny dam breaks (r = 0.1 m: 64 fluid particles)."""
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from warp_sph.sweep import (Case, DaskExecutor, SerialExecutor, SweepError, build_cases, load_sweep_file,
                            parse_param, run_sweep)
from warp_sph.sweep.cases import case_name, split_values, toml_value

TINY = ["particle_radius=0.1", "output.usd=false", "output.surface=false"]


# --- cases -----------------------------------------------------------------------------------------
def test_params_expand_to_named_cases():
    assert parse_param("solver=wcsph,pbf") == ("solver", ["wcsph", "pbf"])
    assert split_values('[0,0,-9.81],[0,0,-5]') == ["[0,0,-9.81]", "[0,0,-5]"]
    assert split_values('"a,b",c') == ['"a,b"', "c"]
    with pytest.raises(SweepError, match="expected KEY=V1,V2"):
        parse_param("solver")
    cases = build_cases("dam_break", {"solver": ["wcsph", "pbf"], "time.cfl": ["0.2", "0.4", "0.8"]},
                        fixed=["particle_radius=0.1"], frames=3)
    assert len(cases) == 6
    assert cases[1].name == "solver=wcsph,time.cfl=0.4"
    assert cases[1].overrides == ["particle_radius=0.1", "solver=wcsph", "time.cfl=0.4"]
    assert cases[1].params == {"solver": "wcsph", "time.cfl": "0.4"} and cases[1].frames == 3
    assert case_name({"gravity": "[0,0,-9.81]"}) == "gravity=0-0--9.81"
    assert case_name({}) == "default"
    long = case_name({"k": "x" * 300})
    assert len(long) <= 120 and long != case_name({"k": "x" * 301})
    assert [toml_value(v) for v in (True, 3, 0.25, "pbf", [0, 0.5])] == ["true", "3", "0.25", '"pbf"', "[0, 0.5]"]


def test_sweep_file_lists_cases(tmp_path):
    (tmp_path / "scene.toml").write_text((Path(__file__).parents[1] / "scenes" / "dam_break.toml").read_text())
    f = tmp_path / "s.toml"
    f.write_text('[sweep]\nscene = "scene.toml"\nframes = 2\nset = { particle_radius = 0.1, output = { usd = false } }\n'
                 'param = { solver = ["wcsph", "pbf"] }\n\n'
                 '[[case]]\nname = "tank"\nscene = "hydrostatic"\nset = { particle_radius = 0.05 }\nframes = 3\n')
    cases = load_sweep_file(str(f))
    assert [c.name for c in cases] == ["scene,solver=wcsph", "scene,solver=pbf", "tank"]
    assert cases[0].scene == str(tmp_path / "scene.toml") and cases[0].frames == 2
    assert cases[0].overrides == ["particle_radius=0.1", "output.usd=false", 'solver="wcsph"']
    assert cases[2].scene == "hydrostatic" and cases[2].frames == 3
    assert cases[2].overrides[-1] == "particle_radius=0.05"
    f.write_text('[sweep]\nscene = "dam_break"\ncolour = 1\n')
    with pytest.raises(SweepError, match=r"sweep.colour: unknown key"):
        load_sweep_file(str(f))


def test_negative_values_keep_their_sign_and_no_folder_starts_with_a_minus(tmp_path):
    """The leading minus of a value was stripped: ``x=-1`` and ``x=1`` got one folder name (the sweep was
    refused: two cases share it) and ``gravity=-9.81`` read as +9.81; a [[case]] name "-rf" made a folder
    that shell tools take for an option."""
    assert case_name({"gravity": "-9.81"}) == "gravity=-9.81"
    assert case_name({"v": "[-1, 0]"}) != case_name({"v": "[1, 0]"})
    assert case_name({"gravity": "[0,0,-9.81]"}) == "gravity=0-0--9.81"  # names without a leading sign: as before
    cases = build_cases("dam_break", {"material.xsph": ["-0.1", "0.1"], "gravity": ["[-1,0,0]", "[1,0,0]"]})
    names = [c.name for c in cases]
    assert len(set(names)) == 4 and names[0] == "material.xsph=-0.1,gravity=-1-0-0"
    assert case_name({"x": "-1"}, scene="-odd.toml") == "odd,x=-1"
    assert not any(n.startswith(("-", ".")) for n in names)
    f = tmp_path / "s.toml"
    for bad in ("-rf", ".hidden", ".."):
        f.write_text(f'[sweep]\nscene = "dam_break"\n\n[[case]]\nname = "{bad}"\n')
        with pytest.raises(SweepError, match=r"case\[0\]\.name = .*not starting with '-' or '\.'"):
            load_sweep_file(str(f))


# --- helpers ------------------------------------------------------------------------------------
class CountingExecutor(SerialExecutor):
    """The serial executor, remembering which cases it was given."""

    def __init__(self):
        super().__init__(log=lambda *a: None)
        self.keys = []
        self.entered = 0

    def __enter__(self):
        self.entered += 1
        return self

    def map(self, fn, tasks):
        tasks = list(tasks)
        self.keys += [k for k, _ in tasks]
        return super().map(fn, tasks)


def _sweep(cases, out, executor):
    return run_sweep(cases, out, executor, progress=False, log=lambda *a: None)


def _rows(out):
    return {r["case"]: r for r in map(json.loads, (Path(out) / "sweep.jsonl").read_text().splitlines())}


def _frames(folder):
    out = {}
    for p in sorted((Path(folder) / "frames").glob("frame_*.npz")):  # not the hidden temporaries of atomic writes
        with np.load(p) as z:
            out[p.name] = {k: z[k].copy() for k in z.files}
    return out


def _stats(folder):
    info = json.loads((Path(folder) / "run.json").read_text())
    drop = {"wall_time", "seconds"}
    return [{k: v for k, v in f.items() if k not in drop} for f in info["frames"]]


@pytest.fixture(scope="module")
def cluster():
    """One LocalCluster of 2 worker processes for this module's tests (started once)."""
    ex = DaskExecutor(workers=2, log=lambda *a: None)
    ex.start()
    yield ex
    ex.close()


# --- serial: resume -------------------------------------------------------------------------------
def test_rerun_runs_nothing_and_a_new_value_runs_only_new_cases(tmp_path):
    out = tmp_path / "sw"
    first = CountingExecutor()
    s = _sweep(build_cases("dam_break", {"solver": ["wcsph", "pbf"]}, fixed=TINY, frames=2), out, first)
    assert first.keys == ["solver=wcsph", "solver=pbf"] and s.counts() == {"completed": 2}
    rows = _rows(out)
    assert rows["solver=pbf"]["fluid_particles"] == 64 and rows["solver=pbf"]["frames"] == 2
    for k in ("wall_per_simulated_second", "step_wall_per_simulated_second", "density_error_mean",
              "density_error_max", "front", "peak_rss_bytes"):
        assert isinstance(rows["solver=wcsph"][k], (int, float)) and rows["solver=wcsph"][k] > 0, k
    mtime = (out / "solver=wcsph" / "run.json").stat().st_mtime_ns
    again = CountingExecutor()
    s = _sweep(build_cases("dam_break", {"solver": ["wcsph", "pbf"]}, fixed=TINY, frames=2), out, again)
    assert again.keys == [] and again.entered == 0 and s.counts() == {"completed": 2}
    assert (out / "solver=wcsph" / "run.json").stat().st_mtime_ns == mtime
    assert _rows(out) == rows  # the rows of skipped cases keep their figures (peak memory included)
    more = CountingExecutor()
    _sweep(build_cases("dam_break", {"solver": ["wcsph", "pbf"], "smoothing_kernel": ["cubic", "quintic"]},
                       fixed=TINY, frames=2), out / "k", more)
    assert len(more.keys) == 4
    added = CountingExecutor()
    _sweep(build_cases("dam_break", {"solver": ["wcsph", "pbf"], "smoothing_kernel": ["cubic", "quintic", "quadric"]},
                       fixed=TINY, frames=2), out / "k", added)
    assert added.keys == ["solver=wcsph,smoothing_kernel=quadric", "solver=pbf,smoothing_kernel=quadric"]
    assert len(_rows(out / "k")) == 6
    page = (out / "k" / "sweep.md").read_text()
    assert "6 of 6 cases finished (6 completed)" in page
    assert re.search(r"\| (\*\*)?solver=pbf,smoothing_kernel=quadric(\*\*)? \| completed \| 64 \|", page)
    # a folder that holds something else is refused, never overwritten
    (out / "x" / "solver=wcsph").mkdir(parents=True)
    (out / "x" / "solver=wcsph" / "mine.txt").write_text("keep")
    s = _sweep(build_cases("dam_break", {"solver": ["wcsph"]}, fixed=TINY, frames=2), out / "x", CountingExecutor())
    r = _rows(out / "x")["solver=wcsph"]
    assert r["status"] == "failed" and "holds something other than a run" in r["error"]
    assert (out / "x" / "solver=wcsph" / "mine.txt").read_text() == "keep"


# --- Dask ------------------------------------------------------------------------------------------
def test_local_cluster_gives_the_serial_results_bitwise(tmp_path, cluster):
    cases = build_cases("dam_break", {"solver": ["wcsph", "pbf"], "smoothing_kernel": ["cubic", "quintic"]},
                        fixed=TINY, frames=4)
    _sweep(cases, tmp_path / "serial", SerialExecutor())
    _sweep(cases, tmp_path / "dask", cluster)
    serial, dask = _rows(tmp_path / "serial"), _rows(tmp_path / "dask")
    assert len(serial) == len(dask) == 4
    pids = {r["pid"] for r in dask.values()}
    assert os.getpid() not in pids and len(pids) >= 1  # ran in the workers
    for c in cases:
        a, b = tmp_path / "serial" / c.name, tmp_path / "dask" / c.name
        assert serial[c.name]["status"] == dask[c.name]["status"] == "completed"
        fa, fb = _frames(a), _frames(b)
        assert list(fa) == list(fb) and len(fa) == 4
        for name in fa:
            for k in fa[name]:
                assert np.array_equal(fa[name][k], fb[name][k]), (c.name, name, k)
        assert _stats(a) == _stats(b)
        for k in ("density_error_mean", "density_error_max", "front", "steps", "simulated_time"):
            assert serial[c.name][k] == dask[c.name][k], (c.name, k)


def _kill_when_running(ex, folder: Path, frame: int, killed: list, timeout=120.0):
    """Kill (SIGKILL) the worker process running the case of ``folder`` once its run has written
    ``frame`` frames."""
    t0 = time.time()
    while time.time() - t0 < timeout:
        try:
            info = json.loads((folder / "run.json").read_text())
        except (OSError, ValueError):
            info = {}
        if len(info.get("frames", [])) >= frame and info.get("status") == "running":
            busy = ex.client.processing()
            pids = ex.client.run(os.getpid)
            for addr, keys in busy.items():
                if any(str(k).startswith(folder.name + "#") for k in keys):
                    os.kill(pids[addr], signal.SIGKILL)
                    killed.append(pids[addr])
                    return
        time.sleep(0.02)


def test_failures_do_not_stop_the_others_and_a_killed_worker_is_retried(tmp_path, cluster):
    out = tmp_path / "sw"
    long = ["particle_radius=0.05", "output.usd=false", "output.surface=false", "output.checkpoint_every=5"]
    cases = [Case("bad-value", "dam_break", TINY + ["particle_radius=-1"], {"particle_radius": "-1"}, 2),
             Case("raises", "dam_break", TINY + ["time.fixed_dt=0.02"], {"time.fixed_dt": "0.02"}, 2),
             Case("unstable", "dam_break", TINY + ["solver=wcsph", "wcsph.speed_of_sound=0.5"],
                  {"wcsph.speed_of_sound": "0.5"}, 12),
             Case("killed", "dam_break", long, {"particle_radius": "0.05"}, 49),
             Case("fine", "dam_break", TINY, {}, 3)]
    killed = []
    killer = threading.Thread(target=_kill_when_running, args=(cluster, out / "killed", 12, killed), daemon=True)
    killer.start()
    s = _sweep(cases, out, cluster)
    killer.join(5)
    assert killed, "the killed case finished before its worker could be killed"
    rows = _rows(out)
    assert rows["bad-value"]["status"] == "failed" and "particle_radius" in rows["bad-value"]["error"]
    assert rows["raises"]["status"] == "failed" and "time.fixed_dt" in rows["raises"]["error"]
    assert rows["unstable"]["status"] == "stopped" and "likely cause" in rows["unstable"]["error"]
    for r in rows.values():
        assert r["error"] is None or "\n" not in r["error"]
    assert rows["fine"]["status"] == "completed"
    k = rows["killed"]
    assert k["status"] == "completed" and k["attempts"] == 2 and k["frames"] == 49, k
    assert k["pid"] != killed[0]
    assert s.counts() == {"failed": 2, "stopped": 1, "completed": 2}
    # the retried case continued from its checkpoint: bitwise the uninterrupted run
    ref = tmp_path / "ref"
    _sweep([Case("killed", "dam_break", long, {"particle_radius": "0.05"}, 49)], ref, SerialExecutor())
    fa, fb = _frames(out / "killed"), _frames(ref / "killed")
    assert list(fa) == list(fb) and all(np.array_equal(fa[n]["x"], fb[n]["x"]) for n in fa)
    # the failed and stopped cases are listed with their reasons on the results page
    page = (out / "sweep.md").read_text()
    assert "`unstable`: stopped:" in page and "`raises`: failed:" in page


def test_dask_executor_records_errors_and_a_second_worker_death(cluster):
    outcomes = {o.key: o for o in cluster.map(int, [("three", "3"), ("oops", "x")])}
    assert outcomes["three"].result == 3 and outcomes["three"].error is None
    assert outcomes["oops"].result is None and outcomes["oops"].error.startswith("ValueError: invalid literal")
    # a task that kills its worker every time: submitted once more, then recorded
    (o,) = list(cluster.map(os._exit, [("dies", 3)]))
    assert o.result is None and o.attempts == 2 and "worker died twice" in o.error
    # the cluster still works
    (o,) = list(cluster.map(int, [("after", "7")]))
    assert o.result == 7


def test_workers_without_the_extra_is_a_one_line_error(monkeypatch, capsys, tmp_path):
    from warp_sph.cli import main

    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    code = main(["sweep", "dam_break", "--set", "particle_radius=0.1", "--workers", "2", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err[-1] == ("warp-sph: error: --workers and --scheduler need Dask's distributed scheduler: "
                       "pip install -e '.[distributed]' in the warp-sph checkout (into the environment warp-sph "
                       "runs in, e.g. .venv/bin/pip)")
    assert not (tmp_path / "o").exists()


def test_ctrl_c_cancels_cleanly_and_a_rerun_resumes(tmp_path):
    out = tmp_path / "sw"
    # WCSPH: its cases take seconds, so the Ctrl-C lands while they run
    cmd = [sys.executable, "-m", "warp_sph.cli", "sweep", "dam_break", "--param", "time.cfl=0.2,0.3,0.4",
           "--set", "solver=wcsph", "--set", "particle_radius=0.05", "--set", "output.usd=false",
           "--set", "output.surface=false",
           "--frames", "13", "--out", str(out), "--workers", "2", "--no-progress"]
    # SIGINT as a terminal leaves it: a suite started in the background by a non-interactive shell
    # (`bash .ci/run &`) runs with SIGINT ignored, and children inherit that (the sweep then exited 0)
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    t0 = time.time()
    while time.time() - t0 < 120 and not any(out.glob("*/run.json")) and p.poll() is None:
        time.sleep(0.05)
    assert p.poll() is None, "the sweep finished before a case started: make its cases longer"
    os.killpg(p.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    stdout, stderr = p.communicate(timeout=120)
    assert p.returncode == 130, stderr[-2000:]
    assert "Traceback" not in stderr and "interrupted; the cases finished so far are kept" in stderr
    deadline = time.time() + 30
    while time.time() < deadline:  # the workers are gone with it
        r = subprocess.run(["ps", "-o", "stat=", "-g", str(p.pid)], capture_output=True, text=True)
        if all(s.startswith("Z") for s in r.stdout.split()):
            break
        time.sleep(0.2)
    else:
        pytest.fail(f"processes of the sweep remain: {r.stdout}")
    done = _rows(out) if (out / "sweep.jsonl").is_file() else {}
    assert len(done) < 3
    r = subprocess.run(cmd[:-3] + ["--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    rows = _rows(out)
    assert {x["status"] for x in rows.values()} == {"completed"} and len(rows) == 3
    assert all(x["frames"] == 13 for x in rows.values())


def test_leftovers_of_a_killed_run_are_cleared_and_other_files_refused(tmp_path):
    from warp_sph.scene import load_scene
    from warp_sph.sweep.runs import folder_state

    scene = load_scene("dam_break", TINY)
    f = tmp_path / "case"
    assert folder_state(f, scene, 3) == "empty"
    (f / "frames").mkdir(parents=True)
    (f / "frames" / ".frame_000001.npz.abc.tmp.npz").write_bytes(b"")
    (f / "dam_break.usdc").write_bytes(b"")
    assert folder_state(f, scene, 3) == "leftovers"  # killed before its run.json
    (f / "notes.txt").write_text("mine")
    assert folder_state(f, scene, 3) == "other"
    (f / "notes.txt").unlink()
    _sweep([Case("case", "dam_break", TINY, {}, 3)], tmp_path, SerialExecutor())
    row = _rows(tmp_path)["case"]
    assert row["status"] == "completed" and row["frames"] == 3
    assert folder_state(f, scene, 3) == "complete" and folder_state(f, scene, 5) == "incomplete"
    assert folder_state(f, load_scene("dam_break", TINY + ["solver=pbf"]), 3) == "other"
    # more frames than the complete run: it continues from its latest checkpoint
    _sweep([Case("case", "dam_break", TINY, {}, 5)], tmp_path, SerialExecutor())
    assert _rows(tmp_path)["case"]["frames"] == 5 and folder_state(f, scene, 5) == "complete"


def test_a_started_executor_is_closed_by_the_with_that_started_it(monkeypatch):
    ex = DaskExecutor(workers=1)
    calls = []
    monkeypatch.setattr(ex, "start", lambda: (calls.append("start"), setattr(ex, "client", object())))
    monkeypatch.setattr(ex, "close", lambda: (calls.append("close"), setattr(ex, "client", None)))
    with ex:
        with ex:  # e.g. run_sweep inside a block that started the cluster
            pass
        assert calls == ["start"] and ex.client is not None
    assert calls == ["start", "close"] and ex.client is None


# --- issue 36: one clear line, before anything runs or is written ------------------------------------------
def _sweep_cli(args, capsys):
    from warp_sph.cli import main

    code = main(["sweep"] + args)
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    return code, out


def test_bad_scheduler_address_is_one_line(tmp_path, capsys):
    """``--scheduler junk`` ended in a ValueError traceback from distributed."""
    pytest.importorskip("distributed")
    code, out = _sweep_cli(["dam_break", "--set", "particle_radius=0.1", "--scheduler", "junk",
                            "--out", str(tmp_path / "o")], capsys)
    assert code == 2
    assert out.err.strip() == ("warp-sph: error: --scheduler 'junk': not a Dask scheduler address (ValueError: "
                               "missing port number in address 'junk'); expected tcp://HOST:PORT, e.g. "
                               "tcp://10.0.0.5:8786")
    assert not (tmp_path / "o").exists()


def test_workers_zero_is_refused_and_bare_workers_means_every_core(tmp_path, capsys):
    """``--workers 0`` silently meant one worker per core."""
    from warp_sph.cli import build_parser
    from warp_sph.cli_parser import ALL_CORES

    code, out = _sweep_cli(["dam_break", "--workers", "0", "--out", str(tmp_path / "o")], capsys)
    assert code == 2
    assert out.err.strip() == ("warp-sph: error: --workers 0: expected a number of worker processes >= 1 "
                               "(--workers alone starts one per core)")
    assert not (tmp_path / "o").exists()
    assert build_parser().parse_args(["sweep", "dam_break", "--workers"]).workers is ALL_CORES
    assert build_parser().parse_args(["sweep", "dam_break", "--workers", "3"]).workers == 3


def test_cases_refused_by_validation_print_their_reason(tmp_path, capsys):
    """A sweep whose cases failed validation printed only "2 cases: 2 failed"."""
    code, out = _sweep_cli(["dam_break", "--param", "particle_radius=-0.5,2000", "--out", str(tmp_path / "o"),
                            "--no-progress"], capsys)
    assert code == 1
    lines = out.out.strip().splitlines()
    assert re.fullmatch(r"particle_radius=-0\.5: failed; .*dam_break\.toml: particle_radius: expected a finite "
                        r"number > 0 and <= 1000, got -0\.5", lines[0]), lines
    assert re.fullmatch(r"particle_radius=2000: failed; .*particle_radius: expected .* got 2000", lines[1]), lines
    assert lines[-1].startswith("2 cases: 2 failed")


def test_an_unknown_key_is_refused_once_before_any_case(tmp_path, capsys):
    """``--param bogus=1,2`` failed in every case, one by one (exit 1, a sweep folder of failed rows); an
    error every case shares is the command line's: one line, exit 2, no folder."""
    out = tmp_path / "o"
    code, res = _sweep_cli(["dam_break", "--param", "bogus_key=1,2", "--param", "particle_radius=-1,0.1", "--out",
                            str(out), "--no-progress"] + sum((["--set", t] for t in TINY[1:]), []), capsys)
    assert code == 2 and res.out == ""
    (line,) = res.err.strip().splitlines()
    assert re.fullmatch(r"warp-sph: error: every case: .*dam_break\.toml: bogus_key: unknown key; expected one of .*",
                        line), line
    assert not out.exists()


@pytest.mark.parametrize("content, pattern", [
    (b'[sweep]\nscene = "dam_break"\nparam = { solver = ["wcsph", "pbf" }\n', r"bad\.toml: malformed TOML: "),
    (bytes(range(256)) * 4, r"bad\.toml: not a UTF-8 text file \(byte 0x80 at offset 128\)"),
])
def test_malformed_or_binary_sweep_file_is_refused(content, pattern, tmp_path, capsys):
    """A sweep file that is not TOML text was run as a scene: every case failed, one by one."""
    bad = tmp_path / "bad.toml"
    bad.write_bytes(content)
    code, out = _sweep_cli([str(bad), "--out", str(tmp_path / "o"), "--no-progress"], capsys)
    assert code == 2
    (line,) = out.err.strip().splitlines()
    assert line.startswith("warp-sph: error: ") and re.search(pattern, line), line
    assert not (tmp_path / "o").exists() and out.out == ""


def test_sweep_folder_among_a_users_files_or_a_file_is_refused(tmp_path, capsys):
    """``sweep --out FILE`` ended in a FileExistsError traceback; ``--out`` a folder of the user's wrote
    sweep.jsonl, sweep.md (replacing one of theirs) and case folders among their files. Now one line, exit 2,
    before any case, the files as they were; an earlier sweep's folder is still resumed."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "sweep.md").write_text("my notes")
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    args = ["dam_break", "--param", "particle_radius=0.1", "--frames", "2", "--no-progress", "--set"] + TINY[1:2]
    for out, what in ((notes, "is a file; expected a folder"), (notes / "sub", f"lies under the file {notes}"),
                      (mine, "holds sweep.md and no sweep (sweep.jsonl)")):
        code, res = _sweep_cli(args + ["--out", str(out)], capsys)
        assert code == 2 and res.err.strip().startswith(f"warp-sph: error: --out {out} {what}"), res.err
        assert len(res.err.strip().splitlines()) == 1 and res.out == ""
    assert (mine / "sweep.md").read_text() == "my notes" and [p.name for p in mine.iterdir()] == ["sweep.md"]
    assert notes.read_text() == "mine"


def test_a_param_given_twice_or_also_set_is_refused_before_any_case(tmp_path, capsys):
    """``--param r=0.1 --param r=0.2`` ran only r = 0.2 (the first list silently dropped), and ``--set r=0.1
    --param r=0.2,0.3`` ignored the --set in every case: one line each, exit 2, no folder."""
    out = tmp_path / "o"
    code, res = _sweep_cli(["dam_break", "--param", "particle_radius=0.1", "--param", "particle_radius=0.2,0.1",
                            "--out", str(out)], capsys)
    assert code == 2 and res.out == "" and not out.exists()
    assert res.err.strip() == ("warp-sph: error: --param particle_radius is given twice; give its values in one "
                               "list: --param particle_radius=0.1,0.2")
    code, res = _sweep_cli(["dam_break", "--set", "particle_radius=0.1", "--param", "particle_radius=0.2,0.3",
                            "--out", str(out)], capsys)
    assert code == 2 and res.out == "" and not out.exists()
    assert res.err.strip() == ("warp-sph: error: --set particle_radius=0.1 has no effect: --param particle_radius "
                               "sets particle_radius in every case; drop one of them")


def test_another_solvers_keys_are_named_once_by_the_sweep_not_again_by_each_case(tmp_path, capsys):
    """The sweep's process names a key of an unused solver's table once (one line); a case, which runs in a Dask
    worker of its own, does not say it again (there in Python's two-line format, once per worker)."""
    from warp_sph.scene.unused import UnusedKeyWarning
    from warp_sph.sweep.runs import run_case

    f = tmp_path / "mine.toml"
    f.write_text((Path(__file__).parents[1] / "scenes" / "dam_break.toml").read_text() + "\n[pbf]\nmax_iterations = 3\n")
    code, res = _sweep_cli([str(f), "--param", "time.cfl=0.3,0.4", "--frames", "2", "--out", str(tmp_path / "o"),
                            "--no-progress"] + sum((["--set", t] for t in TINY), []), capsys)
    assert code == 0
    assert res.err.strip().splitlines() == [f"warp-sph: warning: {f}: pbf.max_iterations: no effect with solver "
                                            "'dfsph' (the [pbf] keys apply with solver = 'pbf', e.g. --set solver=pbf)"]
    case = Case("c", str(f), TINY, {}, 2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        row = run_case({"case": case.to_dict(), "folder": str(tmp_path / "c"), "device": None})
    assert row["status"] == "completed" and not [w for w in caught if w.category is UnusedKeyWarning]
