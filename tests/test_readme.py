"""The README's generated table is current and its Python scripting example runs as written."""
import re
from pathlib import Path

import numpy as np

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
    assert sim.graph.names()[-2:] == ["swirl", "integrate"]
    assert sim.state.frame == 3
    x = namespace["x"]
    assert np.isfinite(x).all() and x.shape == (sim.model.fluid_count, 3)
    timing = {r["stage"]: r for r in sim.graph.timing_table()}
    assert timing["swirl"]["calls"] == sim.state.step
    out = capsys.readouterr().out
    assert "swirl" in out
