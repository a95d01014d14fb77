"""USD with a changing particle count (emitters and sinks): per-frame point counts, ``ids`` and the
``id`` primvar, the shipped checker's --strict pass, ``warp-sph export`` from the recorded frames, and
the import in real Blender 5.0 (bpy, in a subprocess as in test_blender.py).
"""
import contextlib
import io
import json
import subprocess
import textwrap

import numpy as np
import pytest
from pxr import Usd

from test_blender import BLENDER_PYTHON
from test_emission import BASE
from warp_sph.io import check_usd
from warp_sph.io import run_folder as rf
from warp_sph.io.reexport import export_run
from warp_sph.run import runner
from warp_sph.scene import scene_from_dict

FRAMES = 6


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("flow") / "run"
    sc = scene_from_dict({**BASE, "output": {"surface": True, "usd": True, "checkpoint_every": 0}}, source="flow.toml")
    runner.run(sc, out=out, device="cpu", frames=FRAMES, progress=False, log=lambda *a: None)
    return out


def strict(path) -> None:
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        code = check_usd.main([str(path), "--strict"])
    assert code == 0, text.getvalue()


def usd_counts_and_ids(path):
    stage = Usd.Stage.Open(str(path))
    pts, ids = stage.GetAttributeAtPath("/sph/particles.points"), stage.GetAttributeAtPath("/sph/particles.ids")
    pv = stage.GetAttributeAtPath("/sph/particles.primvars:id")
    return {f: (np.asarray(pts.Get(f)), np.asarray(ids.Get(f)), np.asarray(pv.Get(f))) for f in range(1, FRAMES + 1)}


def test_usd_points_and_ids_follow_the_frames(run_dir):
    usd = run_dir / "flow.usdc"
    strict(usd)
    got = usd_counts_and_ids(usd)
    counts = set()
    for f, (x, ids, pv) in got.items():
        frame = np.load(rf.frame_path(run_dir, f))
        assert np.array_equal(x, frame["x"]) and np.array_equal(ids, frame["id"]) and np.array_equal(pv, frame["id"])
        counts.add(len(x))
    assert len(counts) > 1
    info = json.loads((run_dir / "run.json").read_text())
    assert [len(got[f][0]) for f in range(2, FRAMES + 1)] == [r["flow"]["particles"] for r in info["frames"][1:]]


def test_reexport_with_changing_count(run_dir, tmp_path):
    target = export_run(run_dir, "usd", out=tmp_path / "again.usdc")
    strict(target)
    a, b = usd_counts_and_ids(run_dir / "flow.usdc"), usd_counts_and_ids(target)
    for f in a:
        assert np.array_equal(a[f][0], b[f][0]) and np.array_equal(a[f][1], b[f][1])


PROBE = textwrap.dedent(
    """
    import json, sys
    import bpy
    import numpy as np

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.usd_import(filepath=sys.argv[1])
    scene = bpy.context.scene
    out = {}
    ob = bpy.data.objects["particles"]
    for f in range(scene.frame_start, scene.frame_end + 1):
        scene.frame_set(f)
        data = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
        n = len(data.points)
        ids = np.zeros(n, np.int32)
        if "id" in data.attributes:
            data.attributes["id"].data.foreach_get("value", ids)
        out[f] = {"points": n, "ids": ids.tolist(), "attributes": sorted(a.name for a in data.attributes)}
    print("PROBE-JSON " + json.dumps(out))
    """
)


@pytest.mark.skipif(BLENDER_PYTHON is None, reason="no Python with bpy (see test_blender.py)")
def test_blender_plays_changing_count(run_dir):
    proc = subprocess.run([BLENDER_PYTHON, "-c", PROBE, str(run_dir / "flow.usdc")], capture_output=True, text=True,
                          timeout=300)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("PROBE-JSON ")]
    assert proc.returncode == 0 and lines, proc.stdout[-2000:] + proc.stderr[-2000:]
    got = json.loads(lines[-1][len("PROBE-JSON "):])
    for f in range(1, FRAMES + 1):
        frame = np.load(rf.frame_path(run_dir, f))
        assert got[str(f)]["points"] == len(frame["x"]), f
        assert "id" in got[str(f)]["attributes"]
        assert got[str(f)]["ids"] == frame["id"].tolist(), f
