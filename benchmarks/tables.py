"""The table helpers every report section shares: the latest invocation of records, number cells,
Markdown tables, the failure lines and the lines under a section title (command, machine, versions)."""
from __future__ import annotations

import math


def latest(records: list[dict]) -> list[dict]:
    """The records of the latest invocation (records without one count as their own)."""
    if not records:
        return []
    inv = max(r.get("invocation", r.get("date", "")) for r in records)
    return [r for r in records if r.get("invocation", r.get("date", "")) == inv]


def fmt(v, scale=1.0, digits=3) -> str:
    """A table cell: ``v * scale`` with ``digits`` significant digits, "-" for None or non-finite
    (the formatter every report section gets)."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, (int, float)):
        x = v * scale
        if x != 0 and (abs(x) >= 1e5 or abs(x) < 1e-3):
            return f"{x:.{digits - 1}e}"
        return f"{x:.{digits}g}"
    return str(v)


def metric(r: dict, key: str):
    return (r.get("metrics") or {}).get(key)


def markdown_table(header: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(row) + " |" for row in rows]
    return out


def failure_lines(records: list[dict]) -> list[str]:
    out = []
    for r in records:
        if r.get("status") not in ("ok",) and r.get("error"):
            out.append(f"- `{r['label']}`: {r['status']}: {str(r['error']).splitlines()[0][:300]}")
    return out


def _machine(records: list[dict]) -> str:
    hosts = {(r.get("host") or {}).get("cpu_model", "?") + f" ({(r.get('host') or {}).get('nproc', '?')} CPUs)"
             for r in records}
    devs = {r.get("device_name") or r.get("device") for r in records if r.get("device")}
    return "; ".join(sorted(hosts)) + (f"; device {', '.join(sorted(map(str, devs)))}" if devs else "")


def _versions(records: list[dict]) -> str:
    for r in records:
        v = r.get("versions") or {}
        if "warp" in v:
            return f"warp-sph {v.get('warp_sph')}, Warp {v.get('warp')}, NumPy {v.get('numpy')}, Python {v.get('python')}"
    return "-"


def section_head(recs: list[dict]) -> list[str]:
    """The lines under a section title: the command, the invocation, the machine and the versions."""
    cmd = recs[0].get("command", "?")
    return [f"Command: `{cmd}`  ", f"Run: {recs[0].get('invocation', recs[0].get('date', '?'))}; "
            f"machine: {_machine(recs)}; {_versions(recs)}", ""]


def invocation_heads(records: list[dict], head=section_head, count_runs: bool = True) -> list[str]:
    """The section head (``head``: command, machine, versions) of each invocation the records come from, oldest
    first; ``count_runs``: first a line saying how many there are when more than one."""
    invocations: dict[str, list[dict]] = {}
    for r in records:
        invocations.setdefault(r.get("invocation", r.get("date", "?")), []).append(r)
    lines = []
    if count_runs and len(invocations) > 1:
        lines += [f"The latest record of each case, from {len(invocations)} runs:", ""]
    for inv in sorted(invocations):
        lines += head(invocations[inv])
    return lines
