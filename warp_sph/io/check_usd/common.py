"""The report every check writes to (errors, warnings, per-prim findings), per-sample problem
grouping, and reading USD attributes."""
from __future__ import annotations

import numpy as np
from pxr import Usd

MAX_TIMES_LISTED = 5  # per problem kind and prim, list at most this many offending times


class Report:
    """Collects stage info, per-prim findings, errors and warnings."""

    def __init__(self, path: str):
        self.path = path
        self.stage: dict = {}
        self.prims: list[dict] = []
        self.errors: list[str] = []
        self.warnings: list[str] = []
        self.infos: list[str] = []

    def error(self, msg: str, prim: dict | None = None):
        self.errors.append(msg)
        if prim is not None:
            prim["errors"].append(msg)

    def warn(self, msg: str, prim: dict | None = None):
        self.warnings.append(msg)
        if prim is not None:
            prim["warnings"].append(msg)

    def to_dict(self) -> dict:
        return {
            "file": self.path,
            "ok": not self.errors,
            "n_errors": len(self.errors),
            "n_warnings": len(self.warnings),
            "stage": self.stage,
            "prims": self.prims,
            "errors": self.errors,
            "warnings": self.warnings,
            "infos": self.infos,
        }


class TimeIssues:
    """Groups one kind of per-sample problem so a 200-frame failure prints one line, not 200."""

    def __init__(self):
        self.kinds: dict[str, list[float]] = {}
        self.details: dict[str, str] = {}

    def add(self, kind: str, t: float, detail: str | None = None):
        """Record problem `kind` at time t; `detail` (numbers etc.) is kept for the first time only."""
        self.kinds.setdefault(kind, []).append(t)
        if detail and kind not in self.details:
            self.details[kind] = f"{detail} at time {_fmt_t(t)}"

    def flush(self, rep: Report, prim: dict, path: str, as_error: bool = True):
        for kind, times in self.kinds.items():
            shown = ", ".join(_fmt_t(t) for t in times[:MAX_TIMES_LISTED])
            more = f" (+{len(times) - MAX_TIMES_LISTED} more)" if len(times) > MAX_TIMES_LISTED else ""
            detail = f" [first: {self.details[kind]}]" if kind in self.details else ""
            msg = f"{path}: {kind} at time {shown}{more}{detail}"
            (rep.error if as_error else rep.warn)(msg, prim)


def _fmt_t(t) -> str:
    if t is None:
        return "default"
    return str(int(t)) if float(t).is_integer() else f"{t:g}"


def _np(value, dtype=None):
    if value is None:
        return None
    arr = np.asarray(value)
    if dtype is not None:
        arr = arr.astype(dtype, copy=False)
    return arr


def _get(attr: Usd.Attribute, t):
    """Value of attr at time t (t=None -> default), or None."""
    if not attr or not attr.HasAuthoredValue():
        return None
    return attr.Get() if t is None else attr.Get(Usd.TimeCode(t))


def _sample_times(attr: Usd.Attribute) -> list[float]:
    return list(attr.GetTimeSamples()) if attr and attr.HasAuthoredValue() else []
