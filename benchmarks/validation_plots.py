"""``warp-sph bench validation``'s plots (matplotlib; None without it): one per case with the experiment beside
the simulations (``plot_case``), and cost against the error (``plot_trade``). The report section is
``validation_report.py``."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from warp_sph.pyplot import pyplot_or_none
from warp_sph.validation import errors as E
from .validation import CASES, GOALS, LOBOVSKY_SENSORS


def plot_case(case: str, records: list[dict], path: Path) -> Path | None:
    """The experiment (markers) beside every simulation of ``case`` (lines); None without matplotlib."""
    plt = pyplot_or_none()
    if plt is None:
        return None
    recs = [r for r in records if r["case"] == case and r.get("series")]
    if not recs:
        return None
    if case == "martin_moyce":
        panels = [("front", "martin_moyce_1952_front", "T = t √(2g/a)", "Z = x / a", (0, 4.5)),
                  ("residual", "martin_moyce_1952_residual", "τ = t √(g/a)", "η / (2a)", (0, 4.0))]
    elif case == "lobovsky":
        panels = [(s, f"lobovsky_2014_{s}", "T = t √(g/H)", "p / (ρ g H)", (0, 4.6)) for s in LOBOVSKY_SENSORS]
    else:
        panels = [("floor", None, "t [s]", "p / (ρ0 g (h - z)), floor", None),
                  ("middle", None, "t [s]", "p / (ρ0 g (h - z)), mid-depth", None)]
    below = case == "lobovsky"  # its legend (a line per run, an ensemble marker per run) goes under the panels
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 5.0 if below else 3.8), squeeze=False)
    for ax, (key, data, xl, yl, xlim) in zip(axes[0], panels):
        if data:
            te, ve, cite = E.load_series(data)
            ax.plot(te, ve, "ko", ms=3.5, zorder=10, label=cite[0].split("(")[0].strip().rstrip(",") + " (experiment)")
        else:
            ax.axhline(1.0, color="k", lw=1, label="ρ0 g (h − z)")
        for i, r in enumerate(recs):  # one colour per run in every panel (PBF has no mid-depth series)
            s = np.array(r["series"].get(key) or [], dtype=float).reshape(-1, 2)
            if len(s):
                ax.plot(s[:, 0], s[:, 1], lw=0.9, alpha=0.8, ls="-" if r["resolution"] == "fine" else "--",
                        color=f"C{i % 10}", label=f"{r['solver']} {r['resolution']} (r = {r['particle_radius']:g} m)")
        if case == "lobovsky":  # the ensembles: median peak at the median time, the runs' range as a bar
            t2 = None
            for i, r in enumerate(recs):
                st = ((r.get("ensemble") or {}).get("sensors") or {}).get(key)
                if st:
                    ax.errorbar([st["median_time"]], [st["median_peak"]],
                                yerr=[[st["median_peak"] - st["peak_min"]], [st["peak_max"] - st["median_peak"]]],
                                fmt="D" if r["resolution"] == "fine" else "d", ms=5, capsize=3, color=f"C{i % 10}",
                                mfc="none" if r["resolution"] != "fine" else f"C{i % 10}", zorder=11,
                                label=f"{r['solver']} {r['resolution']}: median of {st['runs']} runs' peaks (bar: "
                                      "their range)" if key == LOBOVSKY_SENSORS[0] else None)
                    t2 = st.get("table2") or t2
                    texp = st["exp_time"]
            if t2:
                lo, hi = t2["band"]
                ax.errorbar([texp], [t2["median"]], yerr=[[t2["median"] - lo], [hi - t2["median"]]],
                            fmt="ks", ms=5, capsize=4, zorder=12, label="Table 2: median, 2.5-97.5 % of 100 runs")
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        if xlim:
            ax.set_xlim(*xlim)
        ax.set_title(key, fontsize=9)
        ax.grid(alpha=0.3)
    fig.suptitle(CASES[case].title, fontsize=10)
    if below:
        fig.legend(*axes[0][0].get_legend_handles_labels(), loc="lower center", ncol=3, fontsize=7)
        fig.tight_layout(rect=(0.0, 0.2, 1.0, 1.0))
    else:
        axes[0][0].legend(fontsize=7)
        fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


TRADE_CAPTION = ("Cost (CPU seconds per simulated second) against the error that matters to an engineer, the "
                 "surge-front RMS against Martin & Moyce 1952, beside the mean density error, per solver and "
                 "resolution (`warp-sph bench validation`).")


def plot_trade(records: list[dict], path: Path) -> Path | None:
    """Cost against the front RMS of the column collapse (and the mean density error where recorded): one point
    per solver and resolution, solvers by colour, coarse hollow, fine filled; None without matplotlib or data."""
    plt = pyplot_or_none()
    if plt is None:
        return None
    pts = [r for r in records if r.get("case") == "martin_moyce" and (r.get("figures") or {}).get("front_rms") is not None
           and r.get("cpu_time") and r.get("simulated_time")]
    if not pts:
        return None
    panels = [("front", "surge-front RMS against Martin & Moyce 1952 [%]")]
    if any(r.get("density_error_mean_avg") is not None for r in pts):
        panels.append(("density", "mean density error (incompressibility) [%]"))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.2), squeeze=False)
    colours = {}
    for ax, (key, label) in zip(axes[0], panels):
        for r in pts:
            y = 100.0 * (r["figures"]["front_rms"] if key == "front" else (r.get("density_error_mean_avg") or math.nan))
            x = float(r["cpu_time"]) / float(r["simulated_time"])
            c = colours.setdefault(r["solver"], f"C{len(colours)}")
            fine = r.get("resolution") == "fine"
            ax.scatter([x], [y], s=46, color=c if fine else "none", edgecolors=c, zorder=3,
                       label=f"{r['solver']} {r['resolution']} (r = {r['particle_radius']:g} m, {r.get('fluid_particles')} p.)")
        for solver, c in colours.items():
            line = sorted((float(r["cpu_time"]) / float(r["simulated_time"]),
                           100.0 * (r["figures"]["front_rms"] if key == "front" else (r.get("density_error_mean_avg") or math.nan)))
                          for r in pts if r["solver"] == solver)
            ax.plot([a for a, _ in line], [b for _, b in line], color=c, lw=0.8, alpha=0.6)
        if key == "front":
            ax.axhline(100.0 * GOALS["front_rms"], color="k", lw=0.8, ls=":", label="goal 4 %")
        ax.set_xscale("log")
        ax.set_xlabel("CPU seconds per simulated second (lower is cheaper)")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle("Column collapse: cost against error (coarse hollow, fine filled)", fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
