"""``warp-sph plot RUN``: one PNG per probe of a run, its value against simulated time.

Reads the probe CSVs named in run.json's ``probes`` (``warp_sph.io.probe_files``) and writes
``RUN/plots/probe_<name>.png`` (or into ``out``) through a temporary file and a rename; a probe naming a measured
series (``probes[].experiment``) has it drawn beside, in SI units (``validation.cases.experiment_series``). Needs
matplotlib, the ``plots`` extra; without it the command says so in one line.
"""
from __future__ import annotations

import os
from pathlib import Path

from ..core.errors import OutputError
from ..io import atomic
from ..io import run_folder as rf
from ..io.probe_files import probe_csv_path, read_probe_csv
from ..pyplot import pyplot

LABELS = {"pressure": "pressure [Pa]", "height": "surface elevation z [m]", "front": "front position [m]"}


def save_figure(fig, path: Path) -> Path:
    """Save a figure as PNG atomically (a temporary file beside ``path``, then a rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.png")
    try:
        fig.savefig(tmp, dpi=110)
        os.replace(tmp, path)
    except OSError as exc:
        if tmp.exists():
            tmp.unlink()
        raise atomic.write_error(path, exc) from None
    return path


def _check_out(folder: Path, run: Path, names: list[str], overwrite: bool) -> None:
    """Refuse, before plotting, an output folder that is a file or lies under one, and (without
    ``overwrite``) a file of a name it would write in a folder other than the run's own plots/."""
    where = atomic.not_a_folder(folder)
    if where:
        raise OutputError(f"--out {folder} {where}; expected a folder for the plots")
    if overwrite or folder.resolve() == (run / "plots").resolve():
        return
    there = [n for n in names if (folder / n).exists()]
    if there:
        more = f" (and {len(there) - 1} more)" if len(there) > 1 else ""
        raise OutputError(f"--out {folder} already holds {there[0]}{more}; pass --overwrite to replace them, or "
                          f"choose another --out (plots in the run's own folder {run / 'plots'} are replaced without "
                          "asking)")


def plot_run(run: Path, out: Path | None = None, overwrite: bool = False) -> list[Path]:
    """PNG of every probe of the run folder ``run``; returns the files written. ``out``: another folder
    (default ``run/plots``), where files of the same names are replaced only with ``overwrite``."""
    run = Path(run)
    info = rf.read_run_json(run)
    probes = info.get("probes") or {}
    if not probes:
        raise OutputError(f"{run}: the run has no probes ([[probes]] in its scene); nothing to plot")
    folder = Path(out) if out else run / "plots"
    _check_out(folder, run, [f"probe_{name}.png" for name in probes], overwrite)
    plt = pyplot()
    experiments = {p.get("name"): p.get("experiment") for p in (info.get("scene") or {}).get("probes") or []}
    written = []
    for name, meta in probes.items():
        path = probe_csv_path(run, name)
        if not path.is_file():
            raise OutputError(f"{run}: run.json names probe {name!r} but {path.name} is missing")
        rows = read_probe_csv(path)[1]
        fig, ax = plt.subplots(figsize=(7.0, 3.6))
        ax.plot([r[0] for r in rows], [r[1] for r in rows], lw=1.2, label=f"{name} ({meta.get('kind')})")
        if experiments.get(name) and rows:  # probes[].experiment: the measured series over the run's time span
            from ..validation.cases import experiment_series

            te, ve, label = experiment_series(experiments[name])
            keep = te <= rows[-1][0] + 1e-9
            ax.plot(te[keep], ve[keep], "k.-", lw=0.8, ms=3, label=label)
        ax.set_xlabel("simulated time [s]")
        ax.set_ylabel(LABELS.get(meta.get("kind"), f"value [{meta.get('unit', '')}]"))
        ax.set_title(f"{info['scene'].get('name', run.name)}: probe {name}, {meta.get('rate', 0):g} Hz, "
                     f"at {[round(v, 4) for v in meta.get('position', [])]} m", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        written.append(save_figure(fig, folder / f"probe_{name}.png"))
        plt.close(fig)
    return written
