"""The summary of a sweep, rewritten as its cases finish.

    DIR/sweep.jsonl   one row per finished case (``runs.ROW_KEYS``: parameters, status, one-line
                      error, wall time per simulated second, density error, front, peak memory)
    DIR/sweep.md      the results page: the table and the speed/accuracy plot
    DIR/sweep.png     stepping wall time per simulated second against the mean density error,
                      the Pareto front marked (needs matplotlib: the ``plots`` extra)

Both files are written atomically; a re-run reads sweep.jsonl back, so the rows of cases it skips
(complete already) keep their figures.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

from ..pyplot import pyplot_or_none
from .runs import ROW_KEYS, pareto_front

JSONL = "sweep.jsonl"
PAGE = "sweep.md"
PLOT = "sweep.png"
SPEED = "step_wall_per_simulated_second"
ERROR = "density_error_mean"


def read_rows(out: Path) -> dict[str, dict]:
    """{case: row} from DIR/sweep.jsonl (missing file or bad lines: nothing)."""
    path = Path(out) / JSONL
    rows = {}
    if path.is_file():
        for line in path.read_text().splitlines():
            try:
                r = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(r, dict) and r.get("case"):
                rows[r["case"]] = r
    return rows


def _clean(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    return v


def _fmt(v, scale=1.0) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return str(v)
    x = v * scale
    if x != 0 and (abs(x) >= 1e5 or abs(x) < 1e-3):
        return f"{x:.2e}"
    return f"{x:.3g}"


def plot_tradeoff(rows: list[dict], path: Path, title: str) -> Path | None:
    """Speed against mean density error of the completed rows; None without matplotlib or points."""
    pts = [r for r in rows if r.get("status") == "completed" and r.get(SPEED) and r.get(ERROR) is not None]
    plt = pyplot_or_none() if pts else None
    if plt is None:
        return None
    cost = [float(r[SPEED]) for r in pts]
    err = [100.0 * float(r[ERROR]) for r in pts]
    front = pareto_front(cost, err)
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    ax.scatter(cost, err, c=["C3" if f else "C0" for f in front], zorder=3)
    for c, e, r in zip(cost, err, pts):
        ax.annotate(r["case"], (c, e), fontsize=6, xytext=(3, 3), textcoords="offset points")
    fp = sorted((c, e) for c, e, f in zip(cost, err, front) if f)
    if fp:
        ax.step([p[0] for p in fp], [p[1] for p in fp], where="post", color="C3", lw=1, label="Pareto front")
        ax.legend(fontsize=7)
    ax.set_xscale("log")
    ax.set_xlabel("stepping wall seconds per simulated second (lower is faster)")
    ax.set_ylabel("mean density error (time average) [%]")
    ax.grid(True, alpha=0.3)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)
    return path


class SweepSummary:
    """Rows of one sweep (in case order) and the files made from them.

    page_every / plot_every: seconds between rewrites of the page and of its plot while cases
    finish (the JSON lines are rewritten after every case; matplotlib is slow to start, and the
    client's time between cases is time a LocalCluster's scheduler, in this process, shares);
    ``close()`` writes all of them.
    """

    def __init__(self, out: Path, case_names: list[str], command: str = "", executor: str = "",
                 page_every: float = 5.0, plot_every: float = 30.0):
        self.out = Path(out)
        self.order = list(case_names)
        self.command = command
        self.executor = executor
        self.rows: dict[str, dict] = {}
        self.page_every = page_every
        self.plot_every = plot_every
        self._page_at = 0.0
        self._plot_at = None  # never drawn

    def add(self, row: dict) -> None:
        self.rows[row["case"]] = _clean({k: row.get(k) for k in ROW_KEYS} | {k: v for k, v in row.items()
                                                                              if k not in ROW_KEYS})
        self.write_rows()
        if time.monotonic() - self._page_at >= self.page_every:
            self.write_page()

    def ordered(self) -> list[dict]:
        return [self.rows[n] for n in self.order if n in self.rows]

    def write_rows(self) -> Path:
        from ..io.atomic import atomic_write_bytes

        self.out.mkdir(parents=True, exist_ok=True)
        text = "".join(json.dumps(r, allow_nan=False) + "\n" for r in self.ordered())
        path = self.out / JSONL
        atomic_write_bytes(path, text.encode())
        return path

    def close(self) -> Path:
        self.write_rows()
        return self.write_page(plot=True)

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for r in self.rows.values():
            out[r["status"]] = out.get(r["status"], 0) + 1
        return out

    def write_page(self, plot: bool | None = None) -> Path:
        """The page; its plot too when ``plot``, or (None) when the last one is ``plot_every`` old."""
        from ..io.atomic import atomic_write_bytes

        self._page_at = time.monotonic()
        rows = self.ordered()
        if plot is None:
            plot = self._plot_at is not None and time.monotonic() - self._plot_at >= self.plot_every
            plot = plot or (self._plot_at is None and len(rows) > 0)
        png = self.out / PLOT if (self.out / PLOT).is_file() else None
        if plot:
            self._plot_at = time.monotonic()
            png = plot_tradeoff(rows, self.out / PLOT, f"{self.out.name}: {len(rows)} cases")
        done = self.counts()
        lines = [f"# Sweep: {self.out.name}", ""]
        if self.command:
            lines += [f"Command: `{self.command}`  "]
        lines += [f"Executor: {self.executor or '-'}; {len(rows)} of {len(self.order)} cases finished ("
                  + ", ".join(f"{n} {s}" for s, n in sorted(done.items())) + "); "
                  f"written {time.strftime('%Y-%m-%dT%H:%M:%S%z')}. Rows: `{JSONL}`; each case's run folder: "
                  "`<case>/`.", ""]
        if png is not None:
            lines += [f"![speed against accuracy]({png.name})", ""]
        elif pyplot_or_none() is None:
            lines += ["> Plot skipped: matplotlib is not installed (the `plots` extra: `pip install -e '.[plots]'`).", ""]
        lines += ["*step wall / sim s*: stepping wall time per simulated second (setup, kernel loading and "
                  "exports excluded); *wall / sim s* the whole run's; *mean ρ err*: mean over frames of the "
                  "mean compression max(ρ/ρ0 − 1, 0); *max ρ err*: the largest ρ/ρ0 − 1; *front*: the 99.9th "
                  "percentile of x from the wall at the last frame (dam-break-like scenes); *peak RSS*: the "
                  "process's resident-set high-water mark during the case. **Bold** cases are on the Pareto "
                  "front of speed against mean density error.", ""]
        front = pareto_front([r.get(SPEED) if r.get("status") == "completed" else None for r in rows],
                             [r.get(ERROR) for r in rows])
        header = ["case", "status", "fluid N", "frames", "steps", "step wall / sim s", "wall / sim s",
                  "mean ρ err %", "max ρ err %", "front [m]", "peak RSS [MiB]"]
        lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for r, best in zip(rows, front):
            mib = r["peak_rss_bytes"] / 2 ** 20 if r.get("peak_rss_bytes") else None
            lines.append("| " + " | ".join([f"**{r['case']}**" if best else r["case"], r["status"],
                                             _fmt(r.get("fluid_particles")), _fmt(r.get("frames")),
                                             _fmt(r.get("steps")), _fmt(r.get(SPEED)),
                                             _fmt(r.get("wall_per_simulated_second")), _fmt(r.get(ERROR), 100),
                                             _fmt(r.get("density_error_max"), 100), _fmt(r.get("front")),
                                             _fmt(mib)]) + " |")
        errors = [f"- `{r['case']}`: {r['status']}: {r['error']}" for r in rows if r.get("error")]
        if errors:
            lines += ["", "## Stopped and failed cases", ""] + errors
        path = self.out / PAGE
        atomic_write_bytes(path, ("\n".join(lines).rstrip() + "\n").encode())
        return path
