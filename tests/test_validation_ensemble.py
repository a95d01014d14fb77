"""The Lobovsky ensemble (issue #31): its statistics from synthetic runs against a NumPy oracle (the bench's own
functions), the seeded start perturbation (fluid[].jitter) reproducible and bounded, and bad input one line."""
from __future__ import annotations

import numpy as np
import pytest

from small_scenes import small_tank
from warp_sph.benchmarks import validation as V
from warp_sph.benchmarks import validation_report as VR
from warp_sph.core.errors import SceneError, WarpSphError
from warp_sph.scene.sampling import sample_scene
from warp_sph.validation import errors as E

G, H = 9.81, 0.3
SCALE = 100.0 / (1000.0 * G * H)  # mbar -> P


def _figures():
    """A record's figures as ``cases.evaluate`` makes them: the curve's peak and time, Table 2 from the shipped
    table (median and band, in P)."""
    table, _ = E.load_table("lobovsky_2014_peaks")
    out = {}
    for s, (pe, te) in zip(V.LOBOVSKY_SENSORS, ((2.84, 2.45), (1.52, 2.77), (0.577, 3.55))):
        k = int(np.argmin(np.abs(table["z_mm"] - V.LOBOVSKY_HEIGHTS_MM[s])))
        t2 = E.peak_statistics(1.0, table["median_mbar"][k] * SCALE, table["p2_5_mbar"][k] * SCALE,
                               table["p97_5_mbar"][k] * SCALE)
        out[s] = {"exp_peak": pe, "exp_time": te, "table2": t2}
    return out


@pytest.mark.parametrize("n", [1, 4, 5])
def test_ensemble_statistics_match_a_numpy_oracle(n):
    rng = np.random.default_rng(7 + n)
    figures = _figures()
    members = [{"status": "completed", **{s: {"peak": float(rng.uniform(0.5, 5.0)), "time": float(rng.uniform(2, 4))}
                                          for s in V.LOBOVSKY_SENSORS}} for _ in range(n)]
    # a failed run counts in no statistic
    members.append({"status": "failed", **{s: {"peak": 100.0, "time": 100.0} for s in V.LOBOVSKY_SENSORS}})
    stats, met = V.ensemble_figures(figures, members)
    for s in V.LOBOVSKY_SENSORS:
        p = np.array([m[s]["peak"] for m in members[:n]])
        t = np.array([m[s]["time"] for m in members[:n]])
        srt, tsrt = np.sort(p), np.sort(t)
        med = srt[n // 2] if n % 2 else 0.5 * (srt[n // 2 - 1] + srt[n // 2])  # the oracle: sorted, middle
        tmed = tsrt[n // 2] if n % 2 else 0.5 * (tsrt[n // 2 - 1] + tsrt[n // 2])
        st, f, t2 = stats[s], figures[s], figures[s]["table2"]
        assert st["runs"] == n
        assert st["median_peak"] == pytest.approx(med, rel=1e-12)
        assert st["median_time"] == pytest.approx(tmed, rel=1e-12)
        assert (st["peak_min"], st["peak_max"]) == (p.min(), p.max())
        assert st["spread"] == pytest.approx((p.max() - p.min()) / med, rel=1e-12)
        assert st["peak_error"] == pytest.approx(med / f["exp_peak"] - 1.0, rel=1e-12)
        assert st["time_error"] == pytest.approx(tmed / f["exp_time"] - 1.0, rel=1e-12)
        assert st["table2"]["median_error"] == pytest.approx(med / t2["median"] - 1.0, rel=1e-12)
        lo, hi = t2["band"]
        assert st["table2"]["in_band"] == bool(lo <= med <= hi)
        assert st["table2"]["exp_spread"] == pytest.approx((hi - lo) / t2["median"], rel=1e-12)
        # the goals on the medians: the peak against Table 2's median, the time against the curve's
        assert met[s] == {"peak": abs(med / t2["median"] - 1.0) <= 0.10,
                          "time": abs(tmed / f["exp_time"] - 1.0) <= 0.05}


def test_ensemble_goals_and_refinement_in_the_report():
    """Runs whose median lies on Table 2's median and the curve's time meet the goals although each run misses;
    the report says which figure moves toward the experiment from coarse to fine."""
    figures = _figures()
    recs = []
    for res, factor in (("coarse", 1.3), ("fine", 1.05)):
        members = [{"status": "completed", **{s: {"peak": figures[s]["table2"]["median"] * factor * x,
                                                  "time": figures[s]["exp_time"] * (1.0 + 0.1 * (x - 1.0)),
                                                  "span_mean_error": (factor - 1.0) * x, "rise_time_error": 0.02 * x}
                                              for s in V.LOBOVSKY_SENSORS}} for x in (0.8, 1.0, 1.2)]
        stats, met = V.ensemble_figures(figures, members)
        recs.append({"solver": "dfsph", "resolution": res, "ensemble": {"runs": 3, "completed": 3, "jitter": 1e-4,
                                                                       "cpu_time": 1.0, "sensors": stats,
                                                                       "members": members},
                     "ensemble_goals_met": met})
        assert all(m["time"] for m in met.values())
        assert all(m["peak"] for m in met.values()) == (res == "fine")  # median off by 30 % (coarse), 5 % (fine)
    text = "\n".join(VR.ensemble_rows(recs, lambda v, k=1: f"{v * k:.3g}"))
    assert "Ensemble misses" in text and "dfsph coarse sensor1: median peak +30.0 %" in text
    assert "dfsph fine" not in text.split("Ensemble misses")[1].split("Refining")[0]
    same = "time +0.0 -> +0.0 % (unchanged)"
    assert f"dfsph sensor1: peak +30 -> +5 % (toward), {same}, arrival +2.0 -> +2.0 % (unchanged)" in text
    assert f"dfsph sensor3: peak +30 -> +5 % (toward), {same}, peak-span mean +30 -> +5 % (toward)" in text


def _tank(jitter=None, seed=None):
    block = {"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.6, 0.5, 0.5]}
    if jitter is not None:
        block.update(jitter=jitter, seed=seed)
    return small_tank("jitter", fluid=[block])


def test_jitter_is_seeded_and_below_its_amplitude():
    a = 0.01
    base = sample_scene(_tank())
    d = base.spacing
    one, again, other = (sample_scene(_tank(a, s)) for s in (3, 3, 4))
    assert np.array_equal(one.fluid_x, again.fluid_x)  # the same seed: bit for bit
    assert len(one.fluid_x) == len(other.fluid_x) == len(base.fluid_x)  # a seed changes no particle count
    for x in (one.fluid_x, other.fluid_x):
        dev = np.abs(x - base.fluid_x)
        assert dev.max() <= a * d * (1 + 1e-9) and dev.max() > 0.5 * a * d  # every coordinate within a d
    diff = np.abs(one.fluid_x - other.fluid_x)
    assert 0.0 < diff.max() <= 2.0 * a * d * (1 + 1e-9)  # two seeds differ, only below the amplitude
    assert np.array_equal(sample_scene(_tank(0.0, 3)).fluid_x, base.fluid_x)  # no jitter: the lattice as it is


def test_same_seed_runs_are_bitwise_equal(tmp_path):
    from warp_sph.io.run_folder import latest_checkpoint, load_checkpoint
    from warp_sph.run import runner

    def run(name, seed):
        scene = small_tank(name, fluid=[{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.6, 0.5, 0.5],
                                         "jitter": 0.01, "seed": seed}],
                           output={"checkpoint_every": 1}, duration=0.1, fps=20.0)
        # on the CPU: CUDA's atomics may reorder sums
        runner.run(scene, out=tmp_path / name, device="cpu", progress=False, log=lambda *a: None)
        cp = load_checkpoint(latest_checkpoint(tmp_path / name))
        return np.concatenate([np.asarray(cp["particle_x_local"]), np.asarray(cp["particle_v"])])

    a, b, c = run("a", 5), run("b", 5), run("c", 6)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("text, jitter", [("0", None), ("5,0", None), ("-1", None), ("x", None), ("1,2,3", None),
                                          (None, 0.0), (None, 1.0), (None, 2.5), (None, float("nan"))])
def test_bad_ensemble_or_jitter_is_one_line(text, jitter):
    with pytest.raises(WarpSphError) as e:
        V.ensemble_settings(text, jitter)
    assert "\n" not in str(e.value) and ("--ensemble" in str(e.value) or "--jitter" in str(e.value))


def test_ensemble_settings():
    assert V.ensemble_settings(None, None) == {**V.ENSEMBLE_DEFAULT, "jitter": V.JITTER_DEFAULT}
    assert V.ensemble_settings("4", 0.01) == {"coarse": 4, "fine": 4, "jitter": 0.01}
    assert V.ensemble_settings("5,1", None)["fine"] == 1


def test_bench_refuses_bad_input_with_exit_2(tmp_path, capsys):
    from warp_sph.cli import main

    for args in (["--ensemble", "0"], ["--jitter", "1.0"]):
        rc = main(["bench", "validation", "--cases", "lobovsky", "--solvers", "dfsph", "--resolution", "coarse",
                   "--out", str(tmp_path / "o"), "--runs", str(tmp_path / "r")] + args)
        err = capsys.readouterr().err.strip()
        assert rc == 2 and len(err.splitlines()) == 1 and args[0] in err
        assert not (tmp_path / "r").exists()  # before any run


@pytest.mark.parametrize("jitter, seed, key", [(1.0, 0, "jitter"), (-0.1, 0, "jitter"), (0.1, -1, "seed")])
def test_scene_jitter_of_d_or_more_or_a_negative_seed_is_refused(jitter, seed, key):
    with pytest.raises(SceneError, match=rf"fluid\[0\]\.{key}") as e:
        _tank(jitter, seed)
    assert "\n" not in str(e.value)
