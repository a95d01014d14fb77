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
import os
from pathlib import Path

from . import bodies, emission, executor_speed, extremes, matrix, validation_report, whitewater
from . import plan as plan_bench
from . import splishsplash_report
from . import metrics as M
from .plots import SPEED_KEY, Figures, plot_scaling, plot_series, plot_tradeoff
from .records import host_info
from .tables import failure_lines, fmt, latest, markdown_table, metric, section_head




#: what the scaling tables' memory columns are (benchmarks/cases.py ``_memory_metrics``)
SCALING_MEMORY_NOTE = ("*bytes/particle*: the bytes of the arrays the bench finds on the simulation (its fields, the "
                       "state, the walls, the solver's own arrays; not the arrays inside neighbour-list and pair-cache "
                       "structs) plus an estimate of two hash grids (2 dim³ int32 cells + 4 int32 per point: the cell "
                       "table dominates at small N), per fluid particle: an allocation, not traffic; *RSS growth/"
                       "particle*: the process's RSS after the timed steps less the RSS before the simulation was "
                       "built, per fluid particle; *peak RSS*: the benchmark process's lifetime peak (ru_maxrss: "
                       "Python, Warp, the warm-up's kernel loading and the run).")
TRAFFIC_NOTE = ("*launch bytes/particle-step (model)*: a model of the bytes a step moves, not a measurement (no "
                "hardware counter is readable on this VM): every kernel launch of the steps run after the timed ones "
                "(traffic_steps in the record) streams each distinct "
                "array among its arguments once (arrays in struct arguments included; row arrays at their used "
                "entries), per fluid particle-step; *passes/step*: that over one pass over the step's arrays "
                "(run.json read_bytes). benchmarks/traffic.py.")


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


def sweep_table(records: list[dict]) -> list[str]:
    """Markdown rows for accuracy runs; '*' marks the Pareto front of speed against mean density error."""
    front = M.pareto_front([metric(r, SPEED_KEY) if r.get("status") in ("ok", "time_limit") else None for r in records],
                           [metric(r, "density_error_mean_avg") for r in records])
    hydro = any(metric(r, "pressure_error_mean_abs") is not None for r in records)
    header = ["case", "status", "fluid N", "steps", "wall s / sim s", "particle-steps/s", "ms/step",
              "mean ρ err %", "max ρ err %", "max |vol drift| %", "energy change", "front [m]", "bytes/particle"]
    if hydro:
        header.insert(-1, "p err %")
    rows = []
    for r, best in zip(records, front):
        row = [("**" + r["label"] + "** *" if best else r["label"]), r.get("status", "?"),
               fmt(r.get("fluid_particles")), fmt(metric(r, "steps")), fmt(metric(r, SPEED_KEY)),
               fmt(metric(r, "particle_steps_per_second")), fmt(metric(r, "ms_per_step")),
               fmt(metric(r, "density_error_mean_avg"), 100), fmt(metric(r, "density_error_max"), 100),
               fmt(metric(r, "volume_drift_max_abs"), 100), fmt(metric(r, "energy_change_final")),
               fmt(metric(r, "front_final")), fmt(metric(r, "bytes_per_particle"))]
        if hydro:
            row.insert(-1, fmt(metric(r, "pressure_error_mean_abs"), 100))
        rows.append(row)
    return markdown_table(header, rows)


def stage_table(records: list[dict]) -> list[str]:
    """Each record's time per stage as a folded Markdown table (``<details>``); [] when no record has stage times."""
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
    return (["<details><summary>time per stage</summary>", ""] + markdown_table(["case (ms per call, share)"] + stages, rows)
            + ["", "</details>", ""])


# --------------------------------------------------------------------------------------------
# The report
# --------------------------------------------------------------------------------------------
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
            lines += stage_table(sr)
        lines += failure_lines(recs) + [""]

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
        iterative = any(metric(r, "ns_per_particle_iteration") for r in scaling)
        with_cpu = any(metric(r, "cpu_ns_per_particle_step") for r in scaling)  # records since the CPU column
        with_div = any(metric(r, "divergence_iterations_mean") for r in scaling)
        with_traffic = any(metric(r, "launch_bytes_per_particle_step") for r in scaling)  # records since the model
        rows = []
        for r in sorted(scaling, key=lambda r: r.get("fluid_particles") or 0):
            rows.append([fmt((r.get("params") or {}).get("particle_radius")), r.get("status", "?"),
                         fmt(r.get("fluid_particles")), fmt(r.get("boundary_particles")), fmt(metric(r, "steps")),
                         fmt(metric(r, "ms_per_step")), fmt(metric(r, "ns_per_particle_step"))]
                        + ([fmt(metric(r, "cpu_ns_per_particle_step"))] if with_cpu else [])
                        + [fmt(metric(r, "particle_steps_per_second")), fmt(metric(r, "bytes_per_particle")),
                           fmt(metric(r, "rss_growth_per_particle")), fmt((metric(r, "peak_rss_bytes") or 0) / 2**20)]
                        + ([fmt(metric(r, "solver_iterations_mean")), fmt(metric(r, "ns_per_particle_iteration"))]
                           if iterative else [])
                        + ([fmt(metric(r, "divergence_iterations_mean"))] if with_div else [])
                        + ([fmt(metric(r, "launch_bytes_per_particle_step")), fmt(metric(r, "passes_per_step"))]
                           if with_traffic else []))
        lines += markdown_table(["radius [m]", "status", "fluid N", "boundary N", "steps", "ms/step", "ns/particle-step"]
                        + (["CPU ns/particle-step"] if with_cpu else [])
                        + ["particle-steps/s", "bytes/particle", "RSS growth/particle", "peak RSS [MiB]"]
                        + (["iterations/step", "ns/particle-iteration"] if iterative else [])
                        + (["divergence it./step"] if with_div else [])
                        + (["launch bytes/particle-step (model)", "passes/step (model)"] if with_traffic else []),
                        rows) + [""]
        lines += [SCALING_MEMORY_NOTE + (" " + TRAFFIC_NOTE if with_traffic else ""), ""]
        if with_cpu:
            lines += ["ns/particle-step is the wall time of the fastest block of steps; CPU ns/particle-step its "
                      "process CPU time over every thread (the steadier measure on a shared machine).", ""]
        for key, what in (("ns_per_particle_step", "particle-step"), ("cpu_ns_per_particle_step", "particle-step (CPU)"),
                          ("ns_per_particle_iteration", "particle-iteration")):
            cost = [metric(r, key) for r in scaling if r.get("status") == "ok"]
            cost = [c for c in cost if c]
            if len(cost) > 1:
                lines += [f"Flatness: the slowest cost per {what} is {max(cost) / min(cost):.2f}x the fastest "
                          f"({fmt(min(cost))} to {fmt(max(cost))} ns).", ""]
        stem = "scaling" + ("" if solver == "wcsph" else f"_{solver}") + "".join(
            "_" + "".join(c if c.isalnum() else "_" for c in o) for o in extra)
        png = figures.get(f"{stem}.png", scaling, lambda p: plot_scaling(scaling, p))
        if png:
            lines += [f"![scaling, {solver}]({rel}/{png.name})", ""]
        lines += stage_table(scaling)
        lines += failure_lines(scaling) + [""]

    compared = splishsplash_report.fixed_step_section(data.get("splishsplash", []), figures, rel)
    compared += splishsplash_report.adaptive_section(data.get("splishsplash", []), figures, rel)
    lines += compared

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
        lines += markdown_table(["fluid N", "cell / r", "threads", "engine", "variant", "ms/frame", "CPU ms/frame",
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

    if not (sweeps or by_solver or compared or surf or mat or execs or moving or checked or extreme
            or planned or emitted):
        lines += [f"No results yet in `{rel}/`: run `warp-sph bench sweep --preset tradeoff`.", ""]
    figures.save()
    md_path.parent.mkdir(parents=True, exist_ok=True)
    md_path.write_text("\n".join(lines).rstrip() + "\n")
    return md_path


def _host_line() -> str:
    h = host_info()
    return f"{h['cpu_model'] or 'unknown CPU'}, {h['nproc']} CPUs"
