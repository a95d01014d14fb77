"""A probe on a wall at the start of a run: the walls' force it reads exists only after a substep, so its
first row is taken at the end of the first substep (it read 0 Pa at t = 0); a probe inside the fluid
still has its t = 0 row."""
from warp_sph.io.probe_files import read_probe_csv
from warp_sph.run import runner

from small_scenes import small_tank

PROBES = [{"name": "floor", "kind": "pressure", "position": [0.3, 0.25, 0.0], "rate": 100.0},
          {"name": "inner", "kind": "pressure", "position": [0.3, 0.25, 0.2], "rate": 100.0}]


def test_wall_probe_first_row_after_the_first_substep(tmp_path):
    scene = small_tank("probe_start", probes=PROBES)
    runner.run(scene, out=tmp_path / "run", frames=2, progress=False, device="cpu", threaded_export=False,
               log=lambda *a, **k: None)
    floor = read_probe_csv(tmp_path / "run" / "probe_floor.csv")[1]
    inner = read_probe_csv(tmp_path / "run" / "probe_inner.csv")[1]
    assert inner[0][0] == 0.0                       # the initial state is sample 0 inside the fluid
    t0, p0, _ = floor[0]
    assert 0.0 < t0 < 1.0 / 100.0                   # the first substep's end (shorter than 1 / rate here)
    assert p0 > 0.0                                 # the floor holds the water from the first substep on
    assert all(p > 0.0 for _, p, _ in floor)
    # the same sample times after it: nothing skipped, nothing doubled
    assert [r[0] for r in floor[1:]] == [r[0] for r in inner[1:]]
