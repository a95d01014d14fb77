"""``warp-sph bench`` refuses bad input with one line and exit status 2 before any case runs, and writes nothing:
an unknown preset, a scene without what the benchmark measures, a --param or --set every case would fail on."""
from __future__ import annotations

import pytest

from warp_sph.cli import main


@pytest.mark.parametrize("argv, expected", [
    (["bench", "sweep", "--preset", "nope"], "--preset 'nope': unknown preset; expected one of quick, tradeoff"),
    (["bench", "bodies", "--scene", "hydrostatic"], "scene 'hydrostatic' has no [[bodies]]"),
    (["bench", "emission", "--scene", "hydrostatic"], "scene 'hydrostatic' has no [[emitters]] or [[sinks]]"),
    (["bench", "sweep", "--param", "bogus=1,2", "--frames", "1", "--in-process"], "bogus: unknown key"),
    (["bench", "scaling", "--set", "time.cfl=7", "--steps", "1", "--in-process"], "time.cfl: expected a finite number"),
    (["bench", "forces", "--forces", "bogus", "--frames", "1", "--in-process"], "--forces 'bogus': unknown 'bogus'"),
    (["bench", "extremes", "--families", "dt,bogus", "--quick"], "--families 'dt,bogus': unknown 'bogus'"),
    (["bench", "report"], "holds no benchmark records (*.jsonl)"),
])
def test_bad_bench_input_is_one_line_before_any_case(argv, expected, tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(argv + ["--out", str(out)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warp-sph: error:") and expected in lines[0], captured.err
    assert "[1/" not in captured.out  # no case started
    assert not out.exists()


def test_a_case_that_loads_still_runs_beside_one_that_does_not(tmp_path, capsys):
    """Only a load error common to every case is refused: a sweep with one bad value keeps its good cases."""
    from warp_sph.benchmarks.commands import refuse_unloadable
    from warp_sph.benchmarks.cases import RunSpec

    good = RunSpec(scene="hydrostatic", overrides=["particle_radius=0.05"])
    bad = RunSpec(scene="hydrostatic", overrides=["particle_radius=-1"])
    refuse_unloadable([bad, good])  # no error: the good case runs, the bad one is a failed record
    from warp_sph.core.errors import SceneError

    with pytest.raises(SceneError, match="every case: .*particle_radius"):
        refuse_unloadable([bad, bad])
