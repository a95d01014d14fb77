"""Run the cases of a sweep on an executor and keep its summary current (``warp-sph sweep``)."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

from ..io.atomic import not_a_folder
from .cases import Case, SweepError
from .runs import ROW_KEYS, folder_state, requested_frames, row_from_run, run_case
from .summary import JSONL, PAGE, PLOT, SweepSummary, read_rows


def check_sweep_folder(out: Path) -> None:
    """Refuse (SweepError, one line) a sweep folder that is a file or lies under one, or a folder that holds
    no sweep.jsonl and files of its own beside the sweep's (sweep.md, sweep.png and their temporary files; a
    sweep.md only when it is a sweep's page): a sweep writes sweep.jsonl, sweep.md, sweep.png and a folder per
    case there, never over a user's file. A new or empty folder, an earlier sweep's (resumed, also one killed
    before its first case finished) or one of folders only is fine: each case folder is checked on its own."""
    out = Path(out)
    where = not_a_folder(out)
    if where:
        raise SweepError(f"--out {out} {where}; expected a folder for the sweep")
    if not out.is_dir() or (out / JSONL).is_file():
        return
    foreign = sorted(f.name for f in out.iterdir() if not f.is_dir() and f.name not in (PAGE, PLOT)
                     and not f.name.startswith(f".{JSONL.split('.')[0]}."))
    page = out / PAGE
    if page.is_file():
        try:
            ours = f"Rows: `{JSONL}`" in page.read_text(errors="replace")
        except OSError:
            ours = False
        if not ours:
            foreign.insert(0, PAGE)
    if foreign:
        raise SweepError(f"--out {out} holds {foreign[0]}" + (f" and {len(foreign) - 1} more files" if len(foreign) > 1
                         else "") + f" and no sweep ({JSONL}); choose a new or empty folder, or the folder of an "
                         "earlier sweep to resume it")


def _failed_row(case: Case, folder: Path, error: str) -> dict:
    row = {k: None for k in ROW_KEYS}
    row.update(case=case.name, params=case.params, scene=Path(case.scene).stem, status="failed", error=error,
               folder=str(folder), started=time.time(), finished=time.time())
    return row


def plan(cases: list[Case], out: Path, previous: dict[str, dict]) -> tuple[list[Case], dict[str, dict]]:
    """(cases to run, rows of the cases that need no run): a case whose folder holds a completed run
    of the same scene and frame count keeps its previous row (or one made from its run.json); a case
    whose scene does not load (a bad value) fails here, without a run. When every case fails to load with
    the same error (an unknown key, a bad fixed --set), the sweep is refused once: SweepError, nothing run."""
    from ..core.errors import SceneError
    from ..scene import load_scene

    todo, done = [], {}
    for c in cases:
        folder = Path(out) / c.name
        try:
            scene = load_scene(c.scene, overrides=list(c.overrides))
        except SceneError as e:
            done[c.name] = _failed_row(c, folder, str(e).splitlines()[0])
            continue
        if folder_state(folder, scene, requested_frames(c.to_dict(), scene)) == "complete":
            old = previous.get(c.name)
            if old and old.get("status") == "completed":
                done[c.name] = old
            else:
                row = {k: None for k in ROW_KEYS}
                row.update(case=c.name, params=c.params, scene=Path(c.scene).stem, status="completed",
                           folder=str(folder))
                row.update(row_from_run(folder, scene))
                done[c.name] = row
            continue
        todo.append(c)
    errors = {r["error"] for r in done.values() if r.get("status") == "failed"}
    if cases and not todo and len(errors) == 1 and all(done[c.name].get("status") == "failed" for c in cases):
        raise SweepError(f"{'every case' if len(cases) > 1 else 'case ' + cases[0].name}: {errors.pop()}")
    return todo, done


def _line(row: dict) -> str:
    def pct(v):
        return f"{100 * v:.3g} %" if isinstance(v, (int, float)) else "-"

    speed = row.get("step_wall_per_simulated_second")
    took = (row["finished"] - row["started"]) if row.get("finished") and row.get("started") else None
    text = (f"{row['case']}: {row['status']}"
            + (f" in {took:.1f} s" if took is not None else "")
            + (f"; {speed:.3g} s per simulated s" if isinstance(speed, (int, float)) else "")
            + f"; mean density error {pct(row.get('density_error_mean'))}")
    if row.get("attempts", 1) and (row.get("attempts") or 1) > 1:
        text += " (second attempt: its first worker died)"
    return text + (f"; {row['error']}" if row.get("error") else "")


def run_sweep(cases: list[Case], out: Path, executor, device: str | None = None, progress: bool = True,
              command: str = "", log: Callable = print) -> SweepSummary:
    """Run every case not complete yet into ``out/<case>`` on ``executor`` (entered here, only when a
    case needs running) and write the summary as they finish. Ctrl-C cancels the cases not
    finished and propagates after the summary is written (a re-run resumes)."""
    from ..run.progress import Progress

    out = Path(out)
    check_sweep_folder(out)
    previous = read_rows(out)
    todo, done = plan(cases, out, previous)
    out.mkdir(parents=True, exist_ok=True)
    names = [c.name for c in cases]
    summary = SweepSummary(out, names + [n for n in previous if n not in set(names)], command=command)
    for n, r in previous.items():
        if n not in set(names):
            summary.rows[n] = r
    for n in names:
        if n in done:
            summary.rows[n] = done[n]
    for n in names:  # cases refused before a run (a scene value out of range): each with its reason
        if n in done and done[n].get("status") != "completed":
            log(f"{n}: {done[n]['status']}; {done[n].get('error')}")
    skipped = sum(1 for n in done if done[n].get("status") == "completed")
    if skipped:
        log(f"{skipped} of {len(cases)} cases complete already in {out}: not run again")
    if not todo:
        summary.executor = "none needed"
        summary.close()
        return summary
    bar = Progress(len(cases), enabled=progress, unit="cases")
    finished = len(done)
    try:
        with executor:
            summary.executor = executor.describe()
            log(f"running {len(todo)} case(s) on {summary.executor}; results: {out}")
            summary.write_page()
            tasks = [(c.name, {"case": c.to_dict(), "folder": str(out / c.name), "device": device}) for c in todo]
            by_name = {c.name: c for c in todo}
            for o in executor.map(run_case, tasks):
                row = o.result if o.result is not None else _failed_row(by_name[o.key], out / o.key, o.error)
                row.update(attempts=o.attempts, submitted=o.submitted, received=o.received)
                summary.add(row)
                finished += 1
                if bar.enabled and bar.tty:  # the case's line replaces the bar, which is drawn again below it
                    bar.stream.write("\r" + " " * 160 + "\r")
                log(f"[{finished}/{len(cases)}] {_line(row)}")
                bar.update(finished, row["case"])
    finally:
        bar.close()
        summary.close()
    return summary
