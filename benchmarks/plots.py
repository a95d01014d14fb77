"""The benchmark report's plots (matplotlib, optional: the ``plots`` extra) and which records each
was drawn from (``Figures``, ``<results>/plots.json``)."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

from warp_sph.pyplot import pyplot_or_none

from . import metrics as M

#: Accuracy metrics plotted against speed: (key in record metrics, axis label, scale).
ACCURACY_METRICS = (
    ("density_error_mean_avg", "mean density error (time average) [%]", 100.0),
    ("density_error_max", "max density error [%]", 100.0),
    ("volume_drift_max_abs", "max |volume drift| [%]", 100.0),
    ("energy_change_final", "total energy change / (M g h_com) [-]", 1.0),
    ("pressure_error_mean_abs", "hydrostatic pressure error (layer mean |err|) [%]", 100.0),
)
SPEED_KEY = "wall_per_simulated_second"


def _m(r: dict, key: str):
    return (r.get("metrics") or {}).get(key)


# --------------------------------------------------------------------------------------------
# Plots
# --------------------------------------------------------------------------------------------
def _short_label(label: str) -> str:
    """'scene=dam_break solver=pbf smoothing_kernel=cubic time.cfl=0.4' -> 'pbf cubic cfl=0.4'."""
    parts = []
    for tok in label.split():
        k, sep, v = tok.partition("=")
        if not sep:
            parts.append(tok)
        elif k in ("solver", "smoothing_kernel", "engine"):
            parts.append(v)
        elif k != "scene":
            parts.append(f"{k.rpartition('.')[2]}={v}")
    return " ".join(parts)


def plot_tradeoff(records: list[dict], path: Path, title: str) -> Path | None:
    """Speed against each accuracy metric present, Pareto front marked; None if nothing to plot."""
    plt = pyplot_or_none()
    ok = [r for r in records if r.get("status") in ("ok", "time_limit") and _m(r, SPEED_KEY) is not None]
    present = [(k, lab, s) for k, lab, s in ACCURACY_METRICS if any(_m(r, k) is not None for r in ok)]
    if plt is None or not ok or not present:
        return None
    fig, axes = plt.subplots(1, len(present), figsize=(4.6 * len(present), 4.2), squeeze=False)
    for ax, (key, label, scale) in zip(axes[0], present):
        pts = [(float(_m(r, SPEED_KEY)), abs(float(_m(r, key))) * scale, r["label"]) for r in ok if _m(r, key) is not None]
        cost = [p[0] for p in pts]
        err = [p[1] for p in pts]
        front = M.pareto_front(cost, err)
        ax.scatter(cost, err, c=["C3" if f else "C0" for f in front], zorder=3)
        for c, e, lab in pts:
            ax.annotate(_short_label(lab), (c, e), fontsize=6, xytext=(3, 3), textcoords="offset points")
        fp = sorted((c, e) for (c, e, _), f in zip(pts, front) if f)
        if fp:
            ax.step([p[0] for p in fp], [p[1] for p in fp], where="post", color="C3", lw=1, label="Pareto front")
            ax.legend(fontsize=7)
        ax.set_xscale("log")
        ax.set_xlabel("wall seconds per simulated second (lower is faster)")
        ax.set_ylabel(("|" + label + "|") if key == "energy_change_final" else label)
        ax.grid(True, alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_adaptive(records: list[dict], path: Path, title: str) -> Path | None:
    """Speed (wall and CPU seconds per simulated second) against the mean density error of an adaptive
    comparison: warp-sph circles, SPlisHSPlasH triangles, the Pareto front over both engines in red."""
    plt = pyplot_or_none()
    ok = [r for r in records if r.get("status") == "ok" and _m(r, SPEED_KEY) is not None
          and _m(r, "density_error_mean_avg") is not None]
    if plt is None or not ok:
        return None
    panels = [(SPEED_KEY, "wall seconds per simulated second")]
    if all(_m(r, "cpu_per_simulated_second") is not None for r in ok):
        panels.append(("cpu_per_simulated_second", "CPU seconds per simulated second (all threads)"))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.4 * len(panels), 4.4), squeeze=False)
    for ax, (key, xlabel) in zip(axes[0], panels):
        pts = [(float(_m(r, key)), 100.0 * float(_m(r, "density_error_mean_avg")), r) for r in ok]
        front = M.pareto_front([p[0] for p in pts], [p[1] for p in pts])
        for engine, marker, color in (("warp-sph", "o", "C0"), ("splishsplash", "^", "C1")):
            sel = [(c, e, f) for (c, e, r), f in zip(pts, front) if r.get("engine") == engine]
            if sel:
                ax.scatter([c for c, _, _ in sel], [e for _, e, _ in sel], marker=marker, color=color, zorder=3,
                           edgecolors=["C3" if f else color for _, _, f in sel], linewidths=1.8,
                           label="warp-sph" if engine == "warp-sph" else "SPlisHSPlasH")
        for c, e, r in pts:
            case = (r.get("params") or {}).get("case") or (r.get("params") or {}).get("solver", "?")
            ax.annotate(case, (c, e), fontsize=7, xytext=(4, 3), textcoords="offset points")
        fp = sorted((c, e) for (c, e, _), f in zip(pts, front) if f)
        if fp:
            ax.step([p[0] for p in fp], [p[1] for p in fp], where="post", color="C3", lw=1, label="Pareto front")
        ax.set_xscale("log")
        ax.set_yscale("log")
        from matplotlib.ticker import NullFormatter

        ax.xaxis.set_minor_formatter(NullFormatter())  # decade labels only: minor ones overlap
        ax.set_xlabel(xlabel + " (lower is faster)")
        ax.set_ylabel("mean density error (time average) [%]")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_series(records: list[dict], keys: list[tuple[str, str, float]], path: Path, title: str) -> Path | None:
    """Per-frame series (front, density error, energy, ...) of every run against time."""
    plt = pyplot_or_none()
    ok = [r for r in records if r.get("series") and r["series"].get("time")]
    if plt is None or not ok:
        return None
    fig, axes = plt.subplots(1, len(keys), figsize=(4.6 * len(keys), 4.0), squeeze=False)
    for ax, (key, label, scale) in zip(axes[0], keys):
        for r in ok:
            t = r["series"]["time"]
            y = r["series"].get(key)
            if not y:
                continue
            pts = [(a, b * scale) for a, b in zip(t, y) if b is not None]
            if pts:
                ax.plot([p[0] for p in pts], [p[1] for p in pts], label=r["label"], lw=1)
        ax.set_xlabel("time [s]")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0][0].legend(fontsize=6)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_scaling(records: list[dict], path: Path) -> Path | None:
    plt = pyplot_or_none()
    ok = [r for r in records if r.get("status") == "ok" and r.get("fluid_particles")]
    if plt is None or not ok:
        return None
    ok.sort(key=lambda r: r["fluid_particles"])
    n = [r["fluid_particles"] for r in ok]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    axes[0].plot(n, [_m(r, "ns_per_particle_step") for r in ok], "o-")
    axes[0].set_ylabel("time per particle-step [ns]")
    axes[1].plot(n, [_m(r, "bytes_per_particle") for r in ok], "o-", label="arrays + hash grids")
    axes[1].plot(n, [_m(r, "rss_growth_per_particle") for r in ok], "s--", label="process RSS growth")
    if any(_m(r, "device_pool_peak_bytes") for r in ok):
        axes[1].plot(n, [(_m(r, "device_pool_peak_bytes") or 0) / r["fluid_particles"] for r in ok], "^:",
                     label="device pool peak")
    axes[1].set_ylabel("bytes per fluid particle")
    axes[1].legend(fontsize=7)
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xlabel("fluid particles N")
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


class Figures:
    """The report's plots in the results folder. With matplotlib each is drawn and the signature of
    its records noted in ``plots.json``; without it a plot drawn before is kept (linked) while its
    records are unchanged, and left out once they changed (it would show other results)."""

    MANIFEST = "plots.json"

    def __init__(self, results_dir: Path):
        self.dir = Path(results_dir)
        self.can_draw = pyplot_or_none() is not None
        try:
            self.manifest = json.loads((self.dir / self.MANIFEST).read_text())
        except (OSError, ValueError):
            self.manifest = {}
        self.changed = False

    @staticmethod
    def signature(records: list[dict]) -> str:
        return hashlib.sha1(json.dumps(records, sort_keys=True, default=str).encode()).hexdigest()

    def get(self, name: str, records: list[dict], draw) -> Path | None:
        """draw(path) -> Path | None makes the plot ``name`` from ``records``."""
        path = self.dir / name
        sig = self.signature(records)
        if self.can_draw:
            made = draw(path)
            if made is not None and self.manifest.get(name) != sig:
                self.manifest[name] = sig
                self.changed = True
            elif made is None and name in self.manifest:
                del self.manifest[name]
                self.changed = True
            return made
        return path if path.is_file() and self.manifest.get(name) == sig else None

    def save(self) -> None:
        if self.changed:
            self.dir.mkdir(parents=True, exist_ok=True)
            (self.dir / self.MANIFEST).write_text(json.dumps(self.manifest, indent=1, sort_keys=True) + "\n")
