"""Probe CSV files in the run folder: ``probe_<name>.csv`` beside run.json, one per probe.

    # warp-sph probe P1: kind pressure, position [2.42, 0.0, 0.021] m, rate 1000 Hz; scene kleefsman
    # time: simulated time after the sampled substep; fill: sum_j V_j W at the probe's first point
    time [s],pressure [Pa],fill [-]
    0.001,0,0
    ...

The header is written atomically when the run starts; each frame's rows are appended in one write
(a crash leaves whole rows of whole frames, or a torn last line that a resume drops). A resume
rewrites each file atomically with the rows up to the checkpoint's time and appends from there, so a
resumed run's files equal an uninterrupted run's (``tests/test_probes.py``). The running summary
(samples, min, max and its time, last value) goes to run.json's ``probes``.
"""
from __future__ import annotations

import math
from pathlib import Path

from ..core.errors import OutputError
from .atomic import atomic_write_bytes, write_error

VALUE_NAMES = {"pressure": "pressure", "height": "height", "front": "front"}


def probe_csv_path(out: Path, name: str) -> Path:
    return Path(out) / f"probe_{name}.csv"


def _header(line, scene_name: str) -> str:
    where = f"position {[round(float(v), 9) for v in line.start]} m"
    if line.kind != "pressure":
        where += f", direction {[round(float(v), 9) for v in line.direction]}, length {line.length:.9g} m"
    return (f"# warp-sph probe {line.name}: kind {line.kind}, {where}, rate {line.rate:g} Hz; scene {scene_name}\n"
            "# time: simulated time after the sampled substep; fill: sum_j V_j W at the probe's (first) point\n"
            f"time [s],{VALUE_NAMES[line.kind]} [{line.unit}],fill [-]\n")


def _row(t: float, value: float, fill: float) -> str:
    return f"{t:.12g},{value:.9g},{fill:.6g}\n"


def read_probe_csv(path: Path) -> tuple[list[str], list[tuple[float, float, float]]]:
    """(header lines, rows (time, value, fill)) of a probe CSV; a torn last line is left out."""
    header, rows = [], []
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise OutputError(f"cannot read {path}: {exc.strerror or exc}") from None
    for line in text.splitlines(keepends=True):
        if not rows and (line.startswith("#") or line.startswith("time")):
            header.append(line)
            continue
        parts = line.strip().split(",")
        if not line.endswith("\n") or len(parts) != 3:
            break
        try:
            rows.append((float(parts[0]), float(parts[1]), float(parts[2])))
        except ValueError:
            break
    return header, rows


class ProbeFiles:
    """The CSV files of a run's probes and their running summary."""

    def __init__(self, out: Path, lines, scene_name: str):
        self.out = Path(out)
        self.lines = list(lines)
        self.scene_name = scene_name
        self.stats = {line.name: {"samples": 0, "min": math.inf, "max": -math.inf, "max_time": None, "last": None}
                      for line in self.lines}

    @classmethod
    def create(cls, out: Path, lines, scene_name: str) -> "ProbeFiles":
        """New files holding only their headers."""
        files = cls(out, lines, scene_name)
        for line in files.lines:
            atomic_write_bytes(probe_csv_path(out, line.name), _header(line, scene_name).encode())
        return files

    @classmethod
    def resume(cls, out: Path, lines, scene_name: str, time: float) -> "ProbeFiles":
        """Files cut back to the rows sampled up to ``time`` [s] (the checkpoint's), rewritten atomically;
        a missing file starts again from its header."""
        files = cls(out, lines, scene_name)
        limit = time * (1.0 + 1e-9) + 1e-12  # stamps are printed to 12 digits
        for line in files.lines:
            path = probe_csv_path(out, line.name)
            rows = read_probe_csv(path)[1] if path.is_file() else []
            rows = [r for r in rows if r[0] <= limit]
            atomic_write_bytes(path, (_header(line, scene_name) + "".join(_row(*r) for r in rows)).encode())
            files._count(line.name, rows)
        return files

    def _count(self, name: str, rows) -> None:
        s = self.stats[name]
        for t, v, _ in rows:
            s["samples"] += 1
            if math.isfinite(v):
                s["min"] = min(s["min"], v)
                if v > s["max"]:
                    s["max"], s["max_time"] = v, t
            s["last"] = v

    def append(self, samples: dict[str, list[tuple[float, float, float]]]) -> None:
        """Append one frame's rows (``Probes.collect()``) to each probe's file, one write per file."""
        for line in self.lines:
            rows = samples.get(line.name) or []
            if not rows:
                continue
            path = probe_csv_path(self.out, line.name)
            try:
                with open(path, "a") as f:
                    f.write("".join(_row(*r) for r in rows))
            except OSError as exc:
                raise write_error(path, exc) from None
            self._count(line.name, rows)

    def summary(self, skipped: dict[str, int] | None = None) -> dict:
        """run.json's ``probes``: per probe its kind, unit, file, rate and the running figures."""
        out = {}
        for line in self.lines:
            s = self.stats[line.name]
            out[line.name] = {
                "kind": line.kind, "unit": line.unit, "file": probe_csv_path(self.out, line.name).name,
                "position": [float(v) for v in line.start], "rate": line.rate, "samples": s["samples"],
                "min": s["min"] if math.isfinite(s["min"]) else None,
                "max": s["max"] if math.isfinite(s["max"]) else None,
                "max_time": s["max_time"], "last": s["last"],
                "skipped": (skipped or {}).get(line.name, 0),
            }
            if line.kind != "pressure":
                out[line.name].update(direction=[float(v) for v in line.direction], length=line.length)
        return out
