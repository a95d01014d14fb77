"""``python -m benchmarks.splishsplash_tank``: SPlisHSPlasH on the hydrostatic tank at rest (issue #31). The engine is
stubbed (a fake driver writing its out.npz) for the gap search, the box and the speed figures; one real tiny run
needs ``pysplishsplash``."""
import json

import numpy as np
import pytest

from warp_sph.benchmarks import splishsplash_tank as T


@pytest.fixture(scope="module")
def coarse():
    return T.tank_scene(0.05)


def _lattice(sc):
    from warp_sph.scene.sampling import sample_scene

    return np.asarray(sample_scene(sc).fluid_x, dtype=np.float64)


def test_files_place_the_walls_gap_d_from_the_lattice_and_map_the_viscosity(coarse, tmp_path):
    cfg = json.loads(T.splishsplash_files(coarse, "dfsph", 1.25, tmp_path, 2.0).read_text())
    fx, d = _lattice(coarse), 2.0 * coarse.particle_radius
    verts = np.array([[float(c) for c in line.split()[1:]] for line in (tmp_path / "box.obj").read_text().splitlines()
                      if line.startswith("v ")])[:, [0, 2, 1]]  # Y-up -> Z-up
    np.testing.assert_allclose(verts.min(axis=0), fx.min(axis=0) - 1.25 * d, atol=1e-6)
    np.testing.assert_allclose(verts.max(axis=0)[:2], fx.max(axis=0)[:2] + 1.25 * d, atol=1e-6)
    assert verts.max(axis=0)[2] >= coarse.container.max[2]  # the lid: the container's top
    scene = json.loads((tmp_path / "scene.json").read_text())
    mat = scene["Materials"][0]
    assert mat["viscosityMethod"] == T.VISCOSITY_STANDARD and mat["viscosity"] == coarse.material.viscosity == 0.05
    assert scene["Configuration"]["cflMethod"] == 1 and scene["Configuration"]["DFSPH"] == {}  # its own defaults
    assert cfg["fps"] == 1.0 / T.SAMPLE and cfg["frames"] == 8


def test_speed_series_against_numpy():
    rng = np.random.default_rng(3)
    v = rng.normal(size=(3, 50, 3))
    s = T.speed_series([0.0, 0.25, 0.5], v)
    sp = np.linalg.norm(v, axis=2)
    np.testing.assert_allclose(s["mean_speed"], sp.mean(axis=1))
    np.testing.assert_allclose(s["rms_speed"], np.sqrt((sp ** 2).mean(axis=1)))
    assert T.survived({"mean_speed": [0.0, 0.05]}) and not T.survived({"mean_speed": [0.0, 0.2, 0.01]})
    assert not T.survived({"mean_speed": [0.0, float("nan")]})


def test_gap_search_keeps_the_smallest_gap_that_survives(coarse, tmp_path, monkeypatch):
    """A fake driver: the water is thrown (0.7 m/s) unless the walls stand >= 1.25 d off; the search must stop there."""
    calls = []

    class Done:
        returncode, stdout, stderr = 0, "", ""

    def fake_run(cmd, capture_output, text, env):
        cfg = json.loads(open(cmd[2]).read())
        gap = float(cmd[2].split("gap")[-1].split("/")[0])
        calls.append(gap)
        assert "libGLdispatch" in env.get("LD_PRELOAD", "libGLdispatch") and env["OMP_NUM_THREADS"] == "2"
        n, k = 20, cfg["frames"] + 1
        speed = 0.7 if gap < 1.25 else 0.01
        v = np.zeros((k, n, 3), dtype=np.float32)
        v[1:, :, 1] = speed  # Y-up vertical
        info = {"fluid_particles": n, "steps": 10, "boundary_particles": 5, "cpu_seconds": 1.0}
        np.savez(cmd[3], x=np.zeros((k, n, 3)), v=v, rho=np.ones((k, n)), t=np.arange(k) * T.SAMPLE,
                 steps=np.arange(k), info=json.dumps(info))
        return Done()

    monkeypatch.setattr(T.subprocess, "run", fake_run)
    rec = T.run_splishsplash_tank(coarse, "pbf", 2, tmp_path, 2.0, log=lambda *a: None)
    assert calls == [1.0, 1.25]
    assert rec["gap_d"] == 1.25 and rec["slack_d"] == pytest.approx(0.25) and rec["survived"]
    assert [g["survived"] for g in rec["gaps_tried"]] == [False, True]
    assert rec["series"]["mean_speed"][-1] == pytest.approx(0.01) and len(rec["series"]["time"]) == 9
    assert rec["viscosity"] == {"method": "standard", "value": 0.05, "xsph": "not mapped"}


def test_warp_sph_series_reads_the_frames_every_sample(tmp_path):
    (tmp_path / "frames").mkdir()
    for i, t in enumerate(np.arange(0, 0.55, 1 / 24)):
        np.savez(tmp_path / "frames" / f"frame_{i + 1:06d}.npz", v=np.full((4, 3), t), time=np.float64(t))
    s = T.warp_sph_series(tmp_path)
    assert s["time"] == pytest.approx([0.0, 0.25, 0.5])
    np.testing.assert_allclose(s["mean_speed"], np.sqrt(3) * np.array([0.0, 0.25, 0.5]), rtol=1e-6)


def test_bad_solver_is_one_line_exit_2(capsys):
    assert T.main(["--solvers", "dfsph,iisph"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'dfsph,iisph'" in err[0]


def test_real_tiny_run(coarse, tmp_path):
    """SPlisHSPlasH's DFSPH, 180 particles, 0.5 s: walls 0.5 d from the lattice (its wall particles overlapping the
    fluid) throw the water (measured 228 m/s mean |v|); 1.25 d keeps it near rest (0.21 m/s at 0.25 s, the start's
    transient at this coarse radius)."""
    from warp_sph.benchmarks.splishsplash_case import available

    ok, why = available()
    if not ok:
        pytest.skip(why)
    bad = T.run_splishsplash(coarse, "dfsph", 0.5, 1, tmp_path / "bad", 0.5)
    good = T.run_splishsplash(coarse, "dfsph", 1.25, 1, tmp_path / "good", 0.5)
    assert good["status"] == "completed" and good["fluid_particles"] == len(_lattice(coarse)) == 180
    assert good["series"]["time"] == pytest.approx([0.0, 0.25, 0.5], abs=0.01)
    assert max(good["series"]["mean_speed"]) < 0.5 and good["series"]["mean_speed"][-1] < good["series"]["mean_speed"][1]
    assert bad["status"] != "completed" or (not bad["survived"] and max(bad["series"]["mean_speed"]) > 10.0)
