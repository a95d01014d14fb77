"""Tables and plots from the benchmark JSON lines; ``warp-sph bench report`` writes RESULTS.md.

Every number in the report comes from ``<results>/<kind>.jsonl``; for each kind (and each sweep
name) the latest invocation is shown. Plots need matplotlib (``pip install matplotlib``, the
``plots`` extra). ``<results>/plots.json`` notes which records each plot was drawn from, so that a
report rebuilt without matplotlib still links the plots of sections whose records did not change
(and drops only those it would have to redraw).
"""
from __future__ import annotations

import datetime as _dt
import json
import math
import os
from pathlib import Path

from . import bodies, emission, executor_speed, extremes, matrix, validation_report, whitewater
from . import plan as plan_bench
from . import metrics as M
from .plots import SPEED_KEY, Figures, plot_adaptive, plot_scaling, plot_series, plot_tradeoff
from .records import host_info



def load_records(results_dir: Path) -> dict[str, list[dict]]:
    """{kind: [records]} from every ``*.jsonl`` in results_dir (bad lines are skipped)."""
    out: dict[str, list[dict]] = {}
    for path in sorted(Path(results_dir).glob("*.jsonl")):
        for line in path.read_text().splitlines():
            line = line.strip()
            if not line:
                continue
            try:
                r = json.loads(line)
            except json.JSONDecodeError:
                continue
            out.setdefault(r.get("kind", path.stem), []).append(r)
    return out


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


def _m(r: dict, key: str):
    return (r.get("metrics") or {}).get(key)


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(row) + " |" for row in rows]
    return out


def sweep_table(records: list[dict]) -> list[str]:
    """Markdown rows for accuracy runs; '*' marks the Pareto front of speed against mean density error."""
    front = M.pareto_front([_m(r, SPEED_KEY) if r.get("status") in ("ok", "time_limit") else None for r in records],
                           [_m(r, "density_error_mean_avg") for r in records])
    hydro = any(_m(r, "pressure_error_mean_abs") is not None for r in records)
    header = ["case", "status", "fluid N", "steps", "wall s / sim s", "particle-steps/s", "ms/step",
              "mean ρ err %", "max ρ err %", "max |vol drift| %", "energy change", "front [m]", "bytes/particle"]
    if hydro:
        header.insert(-1, "p err %")
    rows = []
    for r, best in zip(records, front):
        row = [("**" + r["label"] + "** *" if best else r["label"]), r.get("status", "?"),
               fmt(r.get("fluid_particles")), fmt(_m(r, "steps")), fmt(_m(r, SPEED_KEY)),
               fmt(_m(r, "particle_steps_per_second")), fmt(_m(r, "ms_per_step")),
               fmt(_m(r, "density_error_mean_avg"), 100), fmt(_m(r, "density_error_max"), 100),
               fmt(_m(r, "volume_drift_max_abs"), 100), fmt(_m(r, "energy_change_final")),
               fmt(_m(r, "front_final")), fmt(_m(r, "bytes_per_particle"))]
        if hydro:
            row.insert(-1, fmt(_m(r, "pressure_error_mean_abs"), 100))
        rows.append(row)
    return _table(header, rows)


def stage_table(records: list[dict]) -> list[str]:
    stages: list[str] = []
    for r in records:
        for s in r.get("stage_times") or []:
            if s["stage"] not in stages:
                stages.append(s["stage"])
    if not stages:
        return []
    rows = []
    for r in records:
        by = {s["stage"]: s for s in r.get("stage_times") or []}
        rows.append([r["label"]] + [(fmt(by[s]["ms_per_call"]) + f" ({100 * by[s].get('fraction', 0):.0f}%)")
                                    if s in by and by[s]["calls"] else "-" for s in stages])
    return _table(["case (ms per call, share)"] + stages, rows)


def _failures(records: list[dict]) -> list[str]:
    out = []
    for r in records:
        if r.get("status") not in ("ok",) and r.get("error"):
            out.append(f"- `{r['label']}`: {r['status']}: {str(r['error']).splitlines()[0][:300]}")
    return out


# --------------------------------------------------------------------------------------------
# The report
# --------------------------------------------------------------------------------------------
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


def speed_ratios(records: list[dict]) -> list[dict]:
    """warp-sph against SPlisHSPlasH per solver: ratio of wall time per simulated second (both run the
    same fixed time step, so this is also the ratio of time per step) and the two mean density errors."""
    out = []
    ok = [r for r in records if r.get("status") == "ok"]
    for solver in ("wcsph", "pbf"):
        ours = [r for r in ok if r.get("engine") != "splishsplash" and (r.get("params") or {}).get("solver") == solver]
        ref = [r for r in ok if r.get("engine") == "splishsplash" and (r.get("params") or {}).get("solver") == solver]
        if ours and ref and _m(ours[0], SPEED_KEY) and _m(ref[0], SPEED_KEY):
            q = {"solver": solver, "threads": ref[0].get("threads"),
                 "ratio": _m(ours[0], SPEED_KEY) / _m(ref[0], SPEED_KEY),
                 "ours_error": _m(ours[0], "density_error_mean_avg"),
                 "ref_error": _m(ref[0], "density_error_mean_avg")}
            cpu_ours, cpu_ref = _m(ours[0], "cpu_per_simulated_second"), _m(ref[0], "cpu_per_simulated_second")
            if cpu_ours and cpu_ref:  # process CPU time of every thread: the steadier measure on a shared machine
                q["cpu_ratio"] = cpu_ours / cpu_ref
            out.append(q)
    return out


def adaptive_section(records: list[dict], figures: Figures, rel: str) -> list[str]:
    """The adaptive-step comparisons (``warp-sph bench splishsplash --adaptive``): per resolution a table,
    the DFSPH ratios and one speed/accuracy plot."""
    from .splishsplash import adaptive_ratios

    by_radius: dict[float, list[dict]] = {}
    for r in records:
        p = r.get("params") or {}
        if p.get("mode") == "adaptive":
            by_radius.setdefault(float(p.get("particle_radius") or 0.0), []).append(r)
    if not by_radius:
        return []
    lines = ["## Side by side with SPlisHSPlasH, each with its own adaptive step", "",
             "Each engine with its defaults and its own CFL step (SPlisHSPlasH: cflMethod 1, cflFactor 1, 5 ms cap; "
             "warp-sph: time.cfl 0.4 against the last frame's top speed plus |g| frame_dt), Akinci 2012 wall "
             "particles in both, the same fluid lattice. *mean ρ err* is each engine's own density at the frames "
             "(mean of max(ρ/ρ0 − 1, 0)); SPlisHSPlasH's mass is 0.8 (2r)³ρ0 (its lattice settles into 80 % of "
             "the sampled volume), warp-sph calibrates its mass so that the lattice reads ρ0. *CPU s / sim s* "
             "counts every thread of the process: on a shared machine it is the steadier measure of work.", ""]
    for radius in sorted(by_radius, reverse=True):
        recs = latest(by_radius[radius])
        n = max((r.get("fluid_particles") or 0) for r in recs)
        lines += [f"### {n:,} fluid particles (r = {radius:g} m)", ""] + section_head(recs)
        rows = []
        for r in sorted(recs, key=lambda r: (_m(r, SPEED_KEY) is None, _m(r, SPEED_KEY) or 0)):
            p = r.get("params") or {}
            rows.append([r.get("engine", "?"), p.get("case") or p.get("solver", "?"), r.get("status", "?"),
                         fmt(r.get("threads")), fmt(r.get("fluid_particles")), fmt(_m(r, "simulated_seconds")),
                         fmt(_m(r, "steps")), fmt(_m(r, "dt_mean"), 1e3), fmt(_m(r, "solver_iterations_mean")),
                         fmt(_m(r, "divergence_iterations_mean")), fmt(_m(r, SPEED_KEY)),
                         fmt(_m(r, "cpu_per_simulated_second")), fmt(_m(r, "density_error_mean_avg"), 100),
                         fmt(_m(r, "density_error_max"), 100)])
        lines += _table(["engine", "case", "status", "threads", "fluid N", "sim s", "steps", "mean dt [ms]",
                         "iterations/step", "divergence it./step", "wall s / sim s", "CPU s / sim s", "mean ρ err %",
                         "max ρ err %"], rows) + [""]
        ratios = adaptive_ratios(recs)
        if ratios:
            lines += _table(["SPlisHSPlasH case", "its threads", "warp-sph dfsph / it (wall)", "(CPU)",
                             "warp-sph mean ρ err %", "its mean ρ err %"],
                            [[q["case"], fmt(q["threads"]), fmt(q["ratio"]), fmt(q.get("cpu_ratio")),
                              fmt(q["ours_error"], 100), fmt(q["ref_error"], 100)] for q in ratios]) + [""]
        png = figures.get(f"splishsplash_adaptive_{n}.png", recs, lambda p, recs=recs, n=n: plot_adaptive(
            recs, p, f"dam break, {n:,} fluid particles: speed against accuracy (each engine's adaptive step)"))
        if png:
            lines += [f"![speed against accuracy, {n} particles]({rel}/{png.name})", ""]
        lines += _failures(recs) + [""]
    return lines


def write_report(results_dir: Path, md_path: Path | None = None, log=print) -> Path:
    """Regenerate the Markdown report (and PNG plots in results_dir) from the JSON lines."""
    from .records import report_path

    results_dir = Path(results_dir)
    if md_path is None:
        md_path = report_path(results_dir)
    data = load_records(results_dir)
    figures = Figures(results_dir)
    rel = os.path.relpath(results_dir, md_path.parent)
    cpu = _host_line()
    lines = ["# warp-sph benchmark results", "",
             "Generated by `warp-sph bench report` from the JSON lines in "
             f"`{rel}/` on {_dt.datetime.now().astimezone().isoformat(timespec='seconds')} "
             f"(report written on: {cpu}). Do not edit by hand: rerun the commands below.", ""]
    if not figures.can_draw:
        lines += ["> Plots not redrawn: matplotlib is not installed (`pip install matplotlib`, or the `plots` extra); "
                  "plots of sections whose results did not change are kept.", ""]
    lines += ["Metrics (benchmarks/metrics.py): *wall s / sim s* is stepping wall time per simulated second "
              "(setup and kernel compilation excluded); *mean ρ err* the time average over frames of the "
              "mean compression max(ρ/ρ0 − 1, 0); *max ρ err* the largest ρ/ρ0 − 1 seen; *vol drift* "
              "Σ m/max(ρ, ρ0) against t = 0; *energy change* (E_end − E_0)/(M g h_com); *front* the 99.9th "
              "percentile of x from the wall at the last frame; *p err* the layer-averaged hydrostatic "
              "pressure error deeper than 2h below the surface; *bytes/particle* the simulation's arrays plus "
              "its hash grids (estimated) per fluid particle. **Bold \\*** rows are on the Pareto front of speed "
              "against mean density error.", ""]

    sweeps = data.get("sweep", [])
    names = sorted({r.get("name", "custom") for r in sweeps}, key=lambda n: (n != "tradeoff", n))
    for name in names:
        recs = latest([r for r in sweeps if r.get("name", "custom") == name])
        lines += [f"## Sweep: {name}", ""] + section_head(recs)
        scenes = []
        for r in recs:
            s = (r.get("params") or {}).get("scene") or (r.get("scene") or {}).get("name", "?")
            if s not in scenes:
                scenes.append(s)
        for s in scenes:
            sr = [r for r in recs if ((r.get("params") or {}).get("scene") or (r.get("scene") or {}).get("name")) == s]
            lines += [f"### {s}", ""] + sweep_table(sr) + [""]
            png = figures.get(f"sweep_{name}_{s}_tradeoff.png", sr, lambda p: plot_tradeoff(sr, p, f"{name}: {s}"))
            if png:
                lines += [f"![speed against accuracy, {s}]({rel}/{png.name})", ""]
            keys = [("front", "surge front [m]", 1.0), ("density_error_mean", "mean density error [%]", 100.0),
                    ("total_energy", "total energy [J]", 1.0)]
            if any((r.get("series") or {}).get("pressure_error_mean_abs") for r in sr):
                keys[0] = ("pressure_error_mean_abs", "pressure error [%]", 100.0)
            png = figures.get(f"sweep_{name}_{s}_series.png", sr,
                              lambda p: plot_series(sr, keys, p, f"{name}: {s} over time"))
            if png:
                lines += [f"![series, {s}]({rel}/{png.name})", ""]
            st = stage_table(sr)
            if st:
                lines += ["<details><summary>time per stage</summary>", ""] + st + ["", "</details>", ""]
        lines += _failures(recs) + [""]

    # the latest scaling run of each solver
    by_solver: dict[tuple, list[dict]] = {}  # (solver, the command's other --set overrides)
    for r in data.get("scaling", []):
        solver = (r.get("params") or {}).get("solver", "wcsph")
        extra = tuple(o for o in (r.get("spec") or {}).get("overrides", [])
                      if not o.startswith(("particle_radius=", "solver=", "time.fixed_dt=")))  # --fixed-dt: per radius
        by_solver.setdefault((solver, extra), []).append(r)
    for solver, extra in sorted(by_solver, key=lambda k: (k[0] != "wcsph", k)):
        scaling = latest(by_solver[(solver, extra)])
        lines += [f"## Scaling: {solver}" + (f" ({', '.join(extra)})" if extra else ""), ""] + section_head(scaling)
        iterative = any(_m(r, "ns_per_particle_iteration") for r in scaling)
        with_cpu = any(_m(r, "cpu_ns_per_particle_step") for r in scaling)  # records since the CPU column
        with_div = any(_m(r, "divergence_iterations_mean") for r in scaling)
        rows = []
        for r in sorted(scaling, key=lambda r: r.get("fluid_particles") or 0):
            rows.append([fmt((r.get("params") or {}).get("particle_radius")), r.get("status", "?"),
                         fmt(r.get("fluid_particles")), fmt(r.get("boundary_particles")), fmt(_m(r, "steps")),
                         fmt(_m(r, "ms_per_step")), fmt(_m(r, "ns_per_particle_step"))]
                        + ([fmt(_m(r, "cpu_ns_per_particle_step"))] if with_cpu else [])
                        + [fmt(_m(r, "particle_steps_per_second")), fmt(_m(r, "bytes_per_particle")),
                           fmt(_m(r, "rss_growth_per_particle")), fmt((_m(r, "peak_rss_bytes") or 0) / 2**20)]
                        + ([fmt(_m(r, "solver_iterations_mean")), fmt(_m(r, "ns_per_particle_iteration"))]
                           if iterative else [])
                        + ([fmt(_m(r, "divergence_iterations_mean"))] if with_div else []))
        lines += _table(["radius [m]", "status", "fluid N", "boundary N", "steps", "ms/step", "ns/particle-step"]
                        + (["CPU ns/particle-step"] if with_cpu else [])
                        + ["particle-steps/s", "bytes/particle", "RSS growth/particle", "peak RSS [MiB]"]
                        + (["iterations/step", "ns/particle-iteration"] if iterative else [])
                        + (["divergence it./step"] if with_div else []), rows) + [""]
        if with_cpu:
            lines += ["ns/particle-step is the wall time of the fastest block of steps; CPU ns/particle-step its "
                      "process CPU time over every thread (the steadier measure on a shared machine).", ""]
        for key, what in (("ns_per_particle_step", "particle-step"), ("cpu_ns_per_particle_step", "particle-step (CPU)"),
                          ("ns_per_particle_iteration", "particle-iteration")):
            cost = [_m(r, key) for r in scaling if r.get("status") == "ok"]
            cost = [c for c in cost if c]
            if len(cost) > 1:
                lines += [f"Flatness: the slowest cost per {what} is {max(cost) / min(cost):.2f}x the fastest "
                          f"({fmt(min(cost))} to {fmt(max(cost))} ns).", ""]
        stem = "scaling" + ("" if solver == "wcsph" else f"_{solver}") + "".join(
            "_" + "".join(c if c.isalnum() else "_" for c in o) for o in extra)
        png = figures.get(f"{stem}.png", scaling, lambda p: plot_scaling(scaling, p))
        if png:
            lines += [f"![scaling, {solver}]({rel}/{png.name})", ""]
        st = stage_table(scaling)
        if st:
            lines += ["<details><summary>time per stage</summary>", ""] + st + ["", "</details>", ""]
        lines += _failures(scaling) + [""]

    # the latest comparison at each resolution (fluid particle count), smallest first
    by_size: dict[int, list[dict]] = {}
    for r in data.get("splishsplash", []):
        if (r.get("params") or {}).get("mode") != "adaptive":
            by_size.setdefault(int(r.get("fluid_particles") or 0), []).append(r)
    if by_size:
        lines += ["## Side by side with SPlisHSPlasH", ""]
    for size in sorted(by_size):
        sph = latest(by_size[size])
        suffix = "" if size == min(by_size) else f"_{size}"
        lines += [f"### {size:,} fluid particles", ""] + section_head(sph)
        skipped = [r for r in sph if r.get("engine") == "splishsplash" and r.get("status") != "ok"]
        if skipped:
            lines += [f"SPlisHSPlasH runs not available: {skipped[0].get('error')}", ""]
        rows = []
        for r in sph:
            p = r.get("params") or {}
            rows.append([r.get("label", r.get("engine", "?")), p.get("solver", "?"), r.get("status", "?"), fmt(p.get("dt")),
                         fmt(r.get("threads")), fmt(r.get("fluid_particles")), fmt(_m(r, "steps")),
                         fmt(_m(r, SPEED_KEY)), fmt(_m(r, "particle_steps_per_second")),
                         fmt(_m(r, "density_error_mean_avg"), 100), fmt(_m(r, "density_error_max"), 100),
                         fmt(_m(r, "volume_drift_max_abs"), 100), fmt(_m(r, "energy_change_final")),
                         fmt(_m(r, "front_final"))])
        lines += _table(["case", "solver", "status", "dt [s]", "threads", "fluid N", "steps", "wall s / sim s",
                         "particle-steps/s", "mean ρ err %", "max ρ err %", "max |vol drift| %", "energy change",
                         "front [m]"], rows) + [""]
        ratios = speed_ratios(sph)
        if ratios:
            lines += _table(["solver", "SPlisHSPlasH threads", "warp-sph time / SPlisHSPlasH time", "(CPU)",
                             "warp-sph mean ρ err %", "SPlisHSPlasH mean ρ err %"],
                            [[q["solver"], fmt(q["threads"]), fmt(q["ratio"]), fmt(q.get("cpu_ratio")),
                              fmt(q["ours_error"], 100), fmt(q["ref_error"], 100)] for q in ratios]) + [""]
        lines += ["Threads: SPlisHSPlasH runs with OMP_NUM_THREADS as listed; warp-sph splits each particle-parallel "
                  "kernel over all cores (WARP_SPH_CPU_THREADS). Same box, fluid lattice, particle radius, fixed step and Akinci 2012 "
                  "walls; SPlisHSPlasH's particle mass is 0.8 d³ρ0 (warp-sph calibrates its mass to a rest "
                  "lattice), and it samples the walls with its own sampler (benchmarks/splishsplash.py).", ""]
        ok = [r for r in sph if r.get("status") == "ok"]
        png = figures.get(f"splishsplash_series{suffix}.png", ok, lambda p: plot_series(
            ok, [("front", "surge front [m]", 1.0), ("density_error_mean", "mean density error [%]", 100.0),
                 ("density_error_max", "max density error [%]", 100.0)], p, "warp-sph and SPlisHSPlasH over time"))
        if png:
            lines += [f"![warp-sph and SPlisHSPlasH]({rel}/{png.name})", ""]
        png = figures.get(f"splishsplash_tradeoff{suffix}.png", ok,
                          lambda p: plot_tradeoff(ok, p, "warp-sph and SPlisHSPlasH"))
        if png:
            lines += [f"![speed against accuracy]({rel}/{png.name})", ""]
        lines += _failures([r for r in sph if r.get("engine") != "splishsplash"]) + [""]

    adaptive = adaptive_section(data.get("splishsplash", []), figures, rel)
    lines += adaptive

    surf = latest(data.get("surface", []))
    if surf:
        lines += ["## Surface reconstruction", ""] + section_head(surf)
        rows = []
        for r in surf:
            if r.get("status") != "ok":
                continue
            st = r.get("stage_ms") or {}
            stages = " / ".join(fmt(st.get(k)) for k in ("particles", "band", "field", "extraction", "smoothing",
                                                         "decimation", "normals")) if st else ""
            usd = (f"{fmt(r.get('usd_write_ms'))} ms, {fmt(r.get('usd_bytes_per_frame'))} B"
                   if r.get("usd_write_ms") is not None else "")
            rows.append([fmt(r.get("fluid_particles")), fmt(r.get("cell_per_radius")), fmt(r.get("threads")),
                         r.get("engine", "?"), r.get("variant", "?"), fmt(r.get("ms")), fmt(r.get("cpu_ms")),
                         fmt(r.get("triangles")), fmt(r.get("ratio_to_splashsurf")),
                         fmt(r.get("cpu_ratio_to_splashsurf")), stages, usd])
        lines += _table(["fluid N", "cell / r", "threads", "engine", "variant", "ms/frame", "CPU ms/frame",
                         "triangles", "x splashsurf", "x splashsurf (CPU)",
                         "warp-sph stages [ms]: particles (spray split included) / band / field / "
                         "extraction / smoothing / decimation / normals", "USD write of the frame"], rows) + [""]
        lines += ["Both tools on the same dam-break particles, cell size, iso level 0.6, kernel support and "
                  "thread count, in the same run (benchmarks/surface.py); median of the timed calls, warm "
                  "(*run*: mean over every frame of the default run, benchmarks/surface_run.py). "
                  "*raw*: field and marching cubes (warp-sph: spray split and narrow band included); "
                  "*pipeline*: raw + 25 weighted smoothing steps + normals + 10 normal smoothing steps "
                  "(splashsurf: with mesh cleanup); *default*: warp-sph's run settings (its cell size, "
                  "smoothing and decimation). *x splashsurf*: warp-sph time / splashsurf time of the same "
                  "variant; *(CPU)*: the same with the CPU time of the process (all its threads), the figure that compares on a "
                  "loaded machine.", ""]

    mat = data.get("matrix", [])  # the latest record of each case (matrix.section)
    lines += matrix.section(mat, fmt, section_head)
    execs = latest(data.get("executors", []))
    lines += executor_speed.section(execs, fmt, section_head)
    moving = latest(data.get("bodies", []))
    lines += bodies.section(moving, fmt, section_head)
    lines += whitewater.section(latest(data.get("whitewater", [])), fmt, section_head)
    emitted = latest(data.get("emission", []))
    lines += emission.section(emitted, fmt, section_head)
    checked = data.get("validation", [])  # the latest record of each run (validation_report.section)
    lines += validation_report.section(checked, fmt, section_head)

    extreme = data.get("extremes", [])  # the latest record of each case (extremes.section)
    lines += extremes.section(extreme, fmt, section_head)

    planned = latest(data.get("plan", []))
    lines += plan_bench.section(planned, fmt, section_head)

    if not (sweeps or by_solver or by_size or adaptive or surf or mat or execs or moving or checked or extreme
            or planned or emitted):
        lines += [f"No results yet in `{rel}/`: run `warp-sph bench sweep --preset tradeoff`.", ""]
    figures.save()
    md_path.parent.mkdir(parents=True, exist_ok=True)
    md_path.write_text("\n".join(lines).rstrip() + "\n")
    return md_path


def _host_line() -> str:
    h = host_info()
    return f"{h['cpu_model'] or 'unknown CPU'}, {h['nproc']} CPUs"
