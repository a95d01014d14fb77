"""A full disk during a run: one line naming the path and the free space, exit status 2, a USD
that still opens with every frame it had saved, and a resume (after freeing space) that completes
the run exactly as an uninterrupted one. On a small tmpfs, so only where mounting one works (root)."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd

from test_run_outputs import SMALL, assert_same_run, run_checker_strict, run_small, usd_path

FRAMES = 8


@pytest.fixture
def small_disk(tmp_path):
    """A 20 MB tmpfs mounted at tmp_path/disk (skipped unless this process may mount one)."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    disk = tmp_path / "disk"
    disk.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=20m", "tmpfs", str(disk)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


def fill(disk: Path, leave: int) -> Path:
    """A file that leaves about ``leave`` bytes free on ``disk``."""
    st = os.statvfs(disk)
    filler = disk / "filler.bin"
    with open(filler, "wb") as f:
        f.write(b"\0" * max(st.f_bavail * st.f_frsize - leave, 0))
    return filler


def cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "warp_sph.cli", *args], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


def error_lines(stderr: str) -> list[str]:
    assert "Traceback" not in stderr, stderr
    return [ln for ln in stderr.splitlines() if ln.startswith("warp-sph: error:")]


@pytest.mark.parametrize("usd", [True, False])
def test_disk_full_then_resume(usd, small_disk, tmp_path):
    extra = [] if usd else ["output.usd=false"]
    reference = tmp_path / "reference"
    run_small(reference, FRAMES, extra=extra)
    out = small_disk / "run"
    filler = fill(small_disk, 520_000 if usd else 250_000)  # room for about four frames of this run
    sets = [a for s in SMALL + extra for a in ("--set", s)]
    r = cli("run", "--out", str(out), "--frames", str(FRAMES), "--device", "cpu", "--no-progress", *sets)
    assert r.returncode == 2, (r.returncode, r.stderr[-3000:])
    (line,) = error_lines(r.stderr)
    assert "no space left on device" in line and str(out) in line and " free" in line, line
    recorded = sorted(p.name for p in (out / "frames").glob("frame_*.npz"))
    assert 1 <= len(recorded) < FRAMES
    for p in (out / "frames").glob("frame_*.npz"):
        with np.load(p) as data:
            assert np.all(np.isfinite(data["x"]))
    if usd:
        stage = Usd.Stage.Open(str(usd_path(out)))  # opens: the last good save is intact
        end = int(stage.GetEndTimeCode())
        assert end >= 1
        points = stage.GetAttributeAtPath("/sph/particles.points")
        assert [int(t) for t in points.GetTimeSamples()] == list(range(1, end + 1))
        for f in range(1, end + 1):
            assert np.all(np.isfinite(np.asarray(points.Get(f))))
        del stage, points
    filler.unlink()
    r = cli("run", "--resume", str(out), "--no-progress", "--device", "cpu")
    assert r.returncode == 0, r.stderr[-3000:]
    assert_same_run(reference, out) if usd else _same_frames(reference, out)
    if usd:
        run_checker_strict(usd_path(out))


def _same_frames(a: Path, b: Path) -> None:
    fa, fb = sorted((a / "frames").iterdir()), sorted((b / "frames").iterdir())
    assert [p.name for p in fa] == [p.name for p in fb]
    for pa, pb in zip(fa, fb):
        da, db = np.load(pa), np.load(pb)
        for k in da.files:
            assert np.array_equal(da[k], db[k]), (pa.name, k)


def test_usd_save_that_fails_keeps_the_last_good_file(small_disk, monkeypatch):
    """When the space check is fooled (another program fills the disk between the check and the
    save), the failed save is undone: the file opens with every frame saved before."""
    from warp_sph.core.errors import OutputError
    from warp_sph.io import atomic, export_usd

    monkeypatch.setattr(atomic, "free_bytes", lambda path: 1 << 40)  # "plenty of room"
    path = small_disk / "full.usdc"
    fill(small_disk, 3_000_000)
    rng = np.random.default_rng(0)
    writer = export_usd.UsdWriter(path, 24.0, 0.01, primvars=(), with_surface=False)
    written = 0
    with pytest.raises(OutputError, match=r"cannot save .*full\.usdc .*free.*keeps frames up to"):
        for f in range(1, 1000):
            x = rng.random((20_000, 3), dtype=np.float32)
            writer.write_frame(f, x, x)
            written = f
    writer.close()  # no save after a failed one (it crashed the process before)
    assert 3 <= written < 20
    stage = Usd.Stage.Open(str(path))
    assert int(stage.GetEndTimeCode()) == written
    attr = stage.GetAttributeAtPath("/sph/particles.points")
    assert [int(t) for t in attr.GetTimeSamples()] == list(range(1, written + 1))
    assert len(attr.Get(written)) == 20_000
