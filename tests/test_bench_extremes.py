"""``warp-sph bench extremes`` (benchmarks/extremes.py): the verdict of a case, and a handful of cases run
for real: none may be a silent bad result (issue 36)."""
import json

import pytest

from warp_sph.benchmarks import extremes as X
from warp_sph.benchmarks import report as R
from warp_sph.benchmarks import runner as B


def _rec(status, error=None, **metrics):
    m = {"energy_rise_max": 0.0, "energy_limit": 0.01, "speed_ratio": 1.0, "body_rise_max": None}
    m.update(metrics)
    return {"status": status, "error": error, "metrics": m}


@pytest.mark.parametrize("record,expected", [
    (_rec("completed"), "ok"),
    (_rec("completed", energy_rise_max=0.02), "silent bad: energy rose 2 % of the scale"),
    (_rec("completed", energy_rise_max=0.02, energy_limit=0.03), "ok"),  # the start's compression may return it
    (_rec("completed", speed_ratio=2.5), "silent bad: top speed 2.5x the physical bound"),
    (_rec("completed", speed_ratio=None), "silent bad: speed not finite"),
    (_rec("completed", energy_rise_max=float("nan")), "silent bad: energy rose nan % of the scale"),
    (_rec("completed", body_rise_max=0.3), "silent bad: a body's energy rose 30 % of its own"),
    (_rec("stopped", "the total energy rose by 3 J ...; likely cause: ..."), "ok"),
    (_rec("refused", "scene: bodies[0].density: expected ..."), "ok"),
    (_rec("stopped", "line one\nline two"), "stopped without one clear line"),
    (_rec("refused", ""), "refused without one clear line"),
    (_rec("crashed", "ZeroDivisionError: float division by zero"), "crashed: ZeroDivisionError: float division by zero"),
])
def test_verdict(record, expected):
    assert X.verdict(record) == expected


def test_quick_cases_no_silent_bad_result(tmp_path):
    """The quick set through the command line: every case ends completed, stopped or refused with one line,
    none is a silent bad result, the light body is refused; JSON lines and the RESULTS.md table are written."""
    logs = []
    args = B.build_parser().parse_args(["extremes", "--quick", "--out", str(tmp_path)])
    rc = args.func(args, ["extremes", "--quick", "--out", str(tmp_path)], log=logs.append)
    records = [json.loads(line) for line in (tmp_path / "extremes.jsonl").read_text().splitlines()]
    assert len(records) == len(X.extreme_cases(quick=True))
    assert {r["status"] for r in records} <= {"completed", "stopped", "refused"}
    assert [r for r in records if r["bad"]] == [] and rc == 0
    body = [r for r in records if r["params"]["family"] == "body"]
    assert body and all(r["status"] == "refused" and "bodies[0].density" in r["error"] for r in body)
    for r in records:
        if r["status"] == "completed":
            m = r["metrics"]
            assert m["energy_rise_max"] <= m["energy_limit"] and m["speed_ratio"] <= X.SPEED_LIMIT
    md = (tmp_path / "RESULTS.md").read_text()
    assert "## Extremes: every solver at the extremes" in md and "**0 silent bad** (goal 0)" in md
    assert R.load_records(tmp_path)["extremes"]
