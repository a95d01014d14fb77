"""The README's generated table is current and its Python scripting example runs as written."""
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def test_parameter_table_is_current():
    from warp_sph.docs import main

    assert main(["--check", str(README)]) == 0


def test_every_parameter_documented_in_readme():
    from warp_sph.scene import all_parameters

    text = README.read_text()
    for p in all_parameters():
        assert f"`{p.path}`" in text, p.path


def test_quick_start_has_two_commands_and_ci_runs_the_test_one():
    text = README.read_text()
    block = text.split("## Quick start", 1)[1].split("```sh", 1)[1].split("```", 1)[0]
    commands = [line.split("#")[0].strip() for line in block.strip().splitlines()]
    assert commands == ["make run", "make test"]
    assert "make test" in (ROOT / ".ci" / "run").read_text()


def test_scripting_example_runs(capsys, tmp_path):
    import runpy

    text = README.read_text()
    section = text.split("## Python scripting", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    script = tmp_path / "readme_example.py"  # Warp reads kernel source from a real file
    script.write_text(code)
    namespace = runpy.run_path(str(script))
    sim = namespace["sim"]
    names = sim.graph.names()
    assert names[-4:] == ["swirl", "source", "pressure", "integrate"]
    assert sim.state.frame == 3
    x = namespace["x"]
    assert np.isfinite(x).all() and x.shape == (sim.model.fluid_count, 3)
    timing = {r["stage"]: r for r in sim.graph.timing_table()}
    assert timing["swirl"]["calls"] == sim.state.step
    out = capsys.readouterr().out
    assert "swirl" in out


def test_scripting_example_is_quiet(tmp_path):
    """The example run as a user's script prints its own lines only: no Warp banner, no
    "Module ... load on device" lines, no "no CUDA driver" note."""
    import os
    import subprocess
    import sys

    code = re.search(r"```python\n(.*?)```", README.read_text().split("## Python scripting", 1)[1], re.S).group(1)
    script = tmp_path / "example.py"
    script.write_text(code)
    env = dict(os.environ)
    env.pop("WARP_SPH_VERBOSE", None)
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600, cwd=tmp_path,
                       env=env)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stderr == "", r.stderr
    assert not re.search(r"^Warp |Module .* load on device|CUDA", r.stdout, re.M), r.stdout
    assert "swirl" in r.stdout


def test_timing_table_keeps_the_first_call_apart():
    """The first call of a stage loads (or compiles) its kernels: timing_table reports it apart and
    ms_per_call is the mean of the other calls."""
    import time

    import warp_sph as ws

    sim = ws.Simulation(ws.load_scene("dam_break", ["particle_radius=0.1", "output.usd=false"]))
    calls = []

    def slow_first(sim, dt):
        time.sleep(0.25 if not calls else 0.0)
        calls.append(dt)

    sim.graph.insert(ws.Stage("slow_first", slow_first), before="integrate")
    sim.advance_frame()
    row = {r["stage"]: r for r in sim.graph.timing_table()}["slow_first"]
    assert row["calls"] == len(calls) > 2
    assert row["first_call_seconds"] >= 0.25
    assert row["ms_per_call"] < 25.0  # 0.25 s averaged over a frame's few dozen steps would be more
    assert row["ms_per_call"] == pytest.approx(1e3 * (row["seconds"] - row["first_call_seconds"]) / (row["calls"] - 1))


def test_quick_start_says_how_to_reach_the_commands():
    """After ``make run`` the documented ``warp-sph ...`` commands live in .venv: the README says to
    activate it (or to call .venv/bin/warp-sph), and installs extras into it."""
    quick = README.read_text().split("## Quick start", 1)[1].split("\n## ", 1)[0]
    assert "source .venv/bin/activate" in quick and ".venv/bin/warp-sph" in quick
    text = README.read_text()
    assert "pip install 'warp-sph[" not in text  # warp-sph is not on PyPI: that installs nothing useful
    for m in re.finditer(r"pip install[^\n`]*", text):
        assert m.group(0).startswith("pip install -e") and ".venv/bin/pip install" in text, m.group(0)


def test_readme_links_only_files_in_the_repository():
    text = README.read_text()
    assert "../shared" not in text
    for target in re.findall(r"\]\(([^)#]+)\)", text):
        if not target.startswith(("http://", "https://")):
            assert (ROOT / target).exists(), target
