"""The report's two SPlisHSPlasH sections (``warp-sph bench splishsplash``, with and without --adaptive).

Fixed step: the latest invocation at each fluid particle count. Adaptive step: the latest record of
each case (engine, case) at each particle radius, so that a run filtered with --solvers replaces only
the rows of the cases it ran. The particle masses are read from the records: SPlisHSPlasH's
``getMass(0)`` (``record["splishsplash"]["mass"]``) and warp-sph's ``model.particle_mass``.
"""
from __future__ import annotations

from .peak_memory import rss_ratio
from .plots import SPEED_KEY, Figures, plot_adaptive, plot_series, plot_tradeoff
from .tables import failure_lines, fmt, invocation_heads, latest, markdown_table, metric, section_head


#: the memory columns of both comparisons' tables (``rss_cells``) and of their ratio tables
RSS_HEADER = ["peak RSS [MiB]", "RSS/particle [B]"]
RSS_RATIO_HEADER = "warp-sph RSS/particle / its"
RSS_NOTE = ("*peak RSS*: the most the case's process held while the case ran (VmHWM reset right before the case "
            "built its simulation: after warp-sph's warm-up loaded its kernels, after `import pysplishsplash`), "
            "interpreter and libraries included; *RSS/particle*: that peak less the RSS at the reset, per fluid "
            "particle (walls included), each engine's case in its own process (benchmarks/peak_memory.py).")


def rss_cells(r: dict) -> list[str]:
    """The ``RSS_HEADER`` cells of a record: its case's peak RSS [MiB] and (peak - baseline) / fluid N [bytes]."""
    peak = metric(r, "rss_case_peak_bytes")
    return [fmt(peak / 2 ** 20 if peak is not None else None), fmt(metric(r, "rss_peak_per_particle"))]


def speed_ratios(records: list[dict]) -> list[dict]:
    """warp-sph against SPlisHSPlasH per solver: ratio of wall time per simulated second (both run the
    same fixed time step, so this is also the ratio of time per step), of peak RSS per fluid particle
    (``rss_ratio``) and the two mean density errors."""
    out = []
    ok = [r for r in records if r.get("status") == "ok"]
    for solver in ("wcsph", "pbf"):
        ours = [r for r in ok if r.get("engine") != "splishsplash" and (r.get("params") or {}).get("solver") == solver]
        ref = [r for r in ok if r.get("engine") == "splishsplash" and (r.get("params") or {}).get("solver") == solver]
        if ours and ref and metric(ours[0], SPEED_KEY) and metric(ref[0], SPEED_KEY):
            q = {"solver": solver, "threads": ref[0].get("threads"),
                 "ratio": metric(ours[0], SPEED_KEY) / metric(ref[0], SPEED_KEY),
                 "ours_error": metric(ours[0], "density_error_mean_avg"),
                 "ref_error": metric(ref[0], "density_error_mean_avg")}
            cpu_ours, cpu_ref = metric(ours[0], "cpu_per_simulated_second"), metric(ref[0], "cpu_per_simulated_second")
            if cpu_ours and cpu_ref:  # process CPU time of every thread: the steadier measure on a shared machine
                q["cpu_ratio"] = cpu_ours / cpu_ref
            q["rss_ratio"] = rss_ratio(ours[0].get("metrics") or {}, ref[0].get("metrics") or {})
            out.append(q)
    return out


def particle_masses(records: list[dict]) -> dict[str, float]:
    """{engine: particle mass / (d^3 rho0)} of the finished records (d = 2 r): SPlisHSPlasH's mass as its
    driver read it (``getMass(0)``), warp-sph's calibrated one (``model.particle_mass``)."""
    out = {}
    for r in records:
        p = r.get("params") or {}
        d = 2.0 * float(p.get("particle_radius") or 0.0)
        if r.get("status") != "ok" or d <= 0:
            continue
        if r.get("engine") == "splishsplash":
            info = r.get("splishsplash") or {}
            mass, rho0 = info.get("mass"), info.get("rest_density")
        else:
            model = r.get("model") or {}
            mass, rho0 = model.get("particle_mass"), model.get("rest_density")
        if mass and rho0:
            out.setdefault("SPlisHSPlasH" if r.get("engine") == "splishsplash" else "warp-sph",
                           float(mass) / (d ** 3 * float(rho0)))
    return out


def mass_note(records: list[dict]) -> str:
    """One sentence on the two engines' particle masses, from the records ("" when none says)."""
    masses = particle_masses(records)
    if not masses:
        return ""
    parts = [f"{engine} {value:.5f}" for engine, value in sorted(masses.items())]
    return (f"Particle mass m / (d³ρ0), d = 2r: {', '.join(parts)} (SPlisHSPlasH's getMass(0); warp-sph "
            "calibrates its mass so that the rest lattice reads ρ0).")


def case_key(record: dict) -> tuple:
    """An adaptive comparison's case: (engine, case, particle radius [m], device)."""
    p = record.get("params") or {}
    return (record.get("engine"), p.get("case") or p.get("solver"), p.get("particle_radius"),
            record.get("device") or "cpu")


def latest_per_case(records: list[dict]) -> list[dict]:
    """The latest record of each case (``case_key``), in the order of first appearance: an adaptive
    comparison may be run in parts (``--solvers dfsph``) and each part replaces only its own cases."""
    best: dict[tuple, dict] = {}
    for r in records:
        k = case_key(r)
        when = r.get("invocation", r.get("date", ""))
        if k not in best or when >= best[k].get("invocation", best[k].get("date", "")):
            best[k] = r
    return list(best.values())


def fixed_step_section(records: list[dict], figures: Figures, rel: str) -> list[str]:
    """The fixed-step comparisons: the latest invocation at each fluid particle count, smallest first."""
    by_size: dict[int, list[dict]] = {}
    for r in records:
        if (r.get("params") or {}).get("mode") != "adaptive":
            by_size.setdefault(int(r.get("fluid_particles") or 0), []).append(r)
    lines = ["## Side by side with SPlisHSPlasH", ""] if by_size else []
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
                         fmt(r.get("threads")), fmt(r.get("fluid_particles")), fmt(metric(r, "steps")),
                         fmt(metric(r, SPEED_KEY)), fmt(metric(r, "particle_steps_per_second")),
                         fmt(metric(r, "density_error_mean_avg"), 100), fmt(metric(r, "density_error_max"), 100),
                         fmt(metric(r, "volume_drift_max_abs"), 100), fmt(metric(r, "energy_change_final")),
                         fmt(metric(r, "front_final"))] + rss_cells(r))
        lines += markdown_table(["case", "solver", "status", "dt [s]", "threads", "fluid N", "steps", "wall s / sim s",
                         "particle-steps/s", "mean ρ err %", "max ρ err %", "max |vol drift| %", "energy change",
                         "front [m]"] + RSS_HEADER, rows) + [""]
        ratios = speed_ratios(sph)
        if ratios:
            lines += markdown_table(["solver", "SPlisHSPlasH threads", "warp-sph time / SPlisHSPlasH time", "(CPU)",
                             "warp-sph mean ρ err %", "SPlisHSPlasH mean ρ err %", RSS_RATIO_HEADER],
                            [[q["solver"], fmt(q["threads"]), fmt(q["ratio"]), fmt(q.get("cpu_ratio")),
                              fmt(q["ours_error"], 100), fmt(q["ref_error"], 100), fmt(q.get("rss_ratio"))]
                             for q in ratios]) + [""]
        lines += ["Threads: SPlisHSPlasH runs with OMP_NUM_THREADS as listed; warp-sph splits each particle-parallel "
                  "kernel over all cores (WARP_SPH_CPU_THREADS). Same box, fluid lattice, particle radius, fixed step "
                  "and Akinci 2012 walls; SPlisHSPlasH samples the walls with its own sampler "
                  "(benchmarks/splishsplash.py). " + mass_note(sph), "", RSS_NOTE, ""]
        ok = [r for r in sph if r.get("status") == "ok"]
        png = figures.get(f"splishsplash_series{suffix}.png", ok, lambda p, ok=ok: plot_series(
            ok, [("front", "surge front [m]", 1.0), ("density_error_mean", "mean density error [%]", 100.0),
                 ("density_error_max", "max density error [%]", 100.0)], p, "warp-sph and SPlisHSPlasH over time"))
        if png:
            lines += [f"![warp-sph and SPlisHSPlasH]({rel}/{png.name})", ""]
        png = figures.get(f"splishsplash_tradeoff{suffix}.png", ok,
                          lambda p, ok=ok: plot_tradeoff(ok, p, "warp-sph and SPlisHSPlasH"))
        if png:
            lines += [f"![speed against accuracy]({rel}/{png.name})", ""]
        lines += failure_lines([r for r in sph if r.get("engine") != "splishsplash"]) + [""]
    return lines


def adaptive_section(records: list[dict], figures: Figures, rel: str) -> list[str]:
    """The adaptive-step comparisons (``warp-sph bench splishsplash --adaptive``): per resolution a table of
    the latest record of each case (``latest_per_case``), the DFSPH ratios and one speed/accuracy plot."""
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
             "(mean of max(ρ/ρ0 − 1, 0)). *CPU s / sim s* counts every thread of the process: on a shared machine "
             "it is the steadier measure of work. Each table holds the latest run of each case (a run filtered "
             "with --solvers replaces only its own rows).", "", RSS_NOTE, ""]
    for radius in sorted(by_radius, reverse=True):
        recs = latest_per_case(by_radius[radius])
        n = max((r.get("fluid_particles") or 0) for r in recs)
        lines += [f"### {n:,} fluid particles (r = {radius:g} m)", ""]
        lines += invocation_heads(recs, count_runs=False)
        note = mass_note(recs)
        if note:
            lines += [note, ""]
        rows = []
        for r in sorted(recs, key=lambda r: (metric(r, SPEED_KEY) is None, metric(r, SPEED_KEY) or 0)):
            p = r.get("params") or {}
            rows.append([r.get("engine", "?"), p.get("case") or p.get("solver", "?"), r.get("status", "?"),
                         fmt(r.get("threads")), fmt(r.get("fluid_particles")), fmt(metric(r, "simulated_seconds")),
                         fmt(metric(r, "steps")), fmt(metric(r, "dt_mean"), 1e3), fmt(metric(r, "solver_iterations_mean")),
                         fmt(metric(r, "divergence_iterations_mean")), fmt(metric(r, SPEED_KEY)),
                         fmt(metric(r, "cpu_per_simulated_second")), fmt(metric(r, "density_error_mean_avg"), 100),
                         fmt(metric(r, "density_error_max"), 100)] + rss_cells(r))
        lines += markdown_table(["engine", "case", "status", "threads", "fluid N", "sim s", "steps", "mean dt [ms]",
                         "iterations/step", "divergence it./step", "wall s / sim s", "CPU s / sim s", "mean ρ err %",
                         "max ρ err %"] + RSS_HEADER, rows) + [""]
        ratios = adaptive_ratios(recs)
        if ratios:
            lines += markdown_table(["SPlisHSPlasH case", "its threads", "warp-sph dfsph / it (wall)", "(CPU)",
                             "warp-sph mean ρ err %", "its mean ρ err %", RSS_RATIO_HEADER],
                            [[q["case"], fmt(q["threads"]), fmt(q["ratio"]), fmt(q.get("cpu_ratio")),
                              fmt(q["ours_error"], 100), fmt(q["ref_error"], 100), fmt(q.get("rss_ratio"))]
                             for q in ratios]) + [""]
        png = figures.get(f"splishsplash_adaptive_{n}.png", recs, lambda p, recs=recs, n=n: plot_adaptive(
            recs, p, f"dam break, {n:,} fluid particles: speed against accuracy (each engine's adaptive step)"))
        if png:
            lines += [f"![speed against accuracy, {n} particles]({rel}/{png.name})", ""]
        lines += failure_lines(recs) + [""]
    slopes = rss_slopes([r for rs in by_radius.values() for r in latest_per_case(rs)])
    if slopes:
        lines += ["RSS per added fluid particle between the smallest and the largest resolution, (Δ peak increment) / "
                  "(Δ fluid N), which leaves out what a case allocates whatever its size: "
                  + "; ".join(f"{engine} {case} {fmt(b)} B ({n0:,} -> {n1:,})" for engine, case, n0, n1, b in slopes)
                  + ".", ""]
    return lines


def rss_slopes(records: list[dict]) -> list[tuple]:
    """(engine, case, smallest N, largest N, bytes per added fluid particle) of each adaptive case with a finished
    record at two or more fluid particle counts: the difference of the peak increments (``rss_peak_increment_bytes``)
    over the difference of the fluid counts."""
    by_case: dict[tuple, dict[int, float]] = {}
    for r in records:
        inc, n = metric(r, "rss_peak_increment_bytes"), r.get("fluid_particles")
        if r.get("status") == "ok" and inc is not None and n:
            p = r.get("params") or {}
            by_case.setdefault((r.get("engine"), p.get("case") or p.get("solver")), {})[int(n)] = float(inc)
    out = []
    for (engine, case), points in sorted(by_case.items(), key=lambda kv: (str(kv[0][0]), str(kv[0][1]))):
        if len(points) > 1:
            n0, n1 = min(points), max(points)
            out.append((engine, case, n0, n1, (points[n1] - points[n0]) / (n1 - n0)))
    return out
