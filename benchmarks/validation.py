"""``warp-sph bench validation``: every solver against published experiments, at two resolutions.

Cases (scenes in ``scenes/validation/``, data in ``warp_sph/validation/data/`` with their citations):

martin_moyce   column collapse, n^2 = 2 (Martin & Moyce 1952): surge front Z = x/a against T = t sqrt(2 g / a)
               (relative RMS with a start-time shift |s| <= 0.2, goal 4 %) and residual height eta/(2a) against
               tau = t sqrt(g / a) (RMS in units of the initial height). a and the initial height are the probes'
               readings at t = 0 (the front and the height line), so Z(0) = 1 as in the paper.
lobovsky       dam break onto a wall (Lobovsky et al. 2014, H = 0.3 m): pressure at sensors 1, 3, 4, P = p/(rho g H)
               against T = t sqrt(g / H): peak and its time (goals 10 % and 5 %), the simulated signal as sampled (no
               filter); the peak also against the experiment's per-run peak statistics (Table 2: median, 2.5-97.5 %).
hydrostatic    the hydrostatic tank with probes: floor and mid-depth pressure against rho0 g (h - z), h from the
               height probe, averaged over the second half of the run (goal 1 %).

Ensemble (lobovsky only): a wall-pressure peak is a chaotic quantity (a rounding change moves it by tens of %), and
Lobovsky's Table 2 is a statistic of 100 repeated runs; so the case runs N times per solver and resolution
(``--ensemble``, default 5 at coarse, 3 at fine), the first from the lattice as it is (its figures are the one-run
figures), the others with every particle's start moved by a seeded uniform draw of at most ``--jitter`` d per
coordinate (``fluid[].jitter``, seeds 1 .. N-1). Each run's per-sensor peak and time are kept in the record's
``ensemble``; the goals are judged on the median peak against Table 2's median and the median time against the
curve's (``ensemble_figures``, ``errors.ensemble_statistics``).

Each case runs with every solver (or ``--solvers``) at its coarse and fine particle radius (``--resolution``);
one JSON line per run goes to ``<results>/validation.jsonl`` (figures, goals, the dimensionless series) and one
plot per case with the experiment beside the simulations to ``<results>/validation_<case>.png``. The error
figures are ``warp_sph/validation/errors.py``'s functions, the same the tests feed the shipped data.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from warp_sph.validation import errors as E
from warp_sph.validation.cases import (CASES, GOALS, LOBOVSKY_HEIGHTS_MM, LOBOVSKY_SENSORS, Case, case_kind,  # noqa: F401
                                      _scene_dir, evaluate, has_pressure, load_case_scene, read_probe)


#: the cases run as an ensemble, the runs per resolution (the first the unperturbed start) and the jitter [d]: a
#: chaotic peak needs several samples; 3 at fine keeps the bench affordable (fine is ~8x coarse's CPU per run).
#: 1e-4 d (2 um at r = 0.01 m) lies far below the resolution and the solvers' density tolerances, yet above
#: float32's rounding of the positions (~1e-5 d in the 1.6 m tank)
ENSEMBLE_CASES = ("lobovsky",)
ENSEMBLE_DEFAULT = {"coarse": 5, "fine": 3}
JITTER_DEFAULT = 1e-4


def ensemble_settings(text: str | None, jitter: float | None) -> dict:
    """--ensemble and --jitter -> {"coarse": N, "fine": N, "jitter": a}; --ensemble is N (both resolutions) or
    COARSE,FINE, each >= 1; 0 < a < 1 (a fraction of d). WarpSphError (one line, exit 2) otherwise."""
    from warp_sph.core.errors import WarpSphError

    out = dict(ENSEMBLE_DEFAULT)
    if text is not None:
        parts = [p.strip() for p in str(text).split(",")]
        try:
            counts = [int(p) for p in parts]
        except ValueError:
            counts = []
        if len(counts) not in (1, 2) or min(counts) < 1:
            raise WarpSphError(f"bench validation: --ensemble {text!r}: expected N or COARSE,FINE, the runs per "
                               "solver and resolution, whole numbers >= 1")
        out["coarse"], out["fine"] = counts[0], counts[-1]
    a = JITTER_DEFAULT if jitter is None else jitter
    if not (isinstance(a, (int, float)) and math.isfinite(a) and 0.0 < a < 1.0):
        raise WarpSphError(f"bench validation: --jitter {jitter!r}: expected a fraction of the particle spacing d, "
                           "0 < jitter < 1")
    out["jitter"] = float(a)
    return out


def ensemble_figures(figures: dict, members: list[dict]) -> tuple[dict, dict]:
    """(per-sensor ensemble statistics, goals met) of a Lobovsky record's ``figures`` (the experiment's peak, time
    and Table 2 statistics) and its runs ``members`` (each {"status", <sensor>: {"peak", "time"}}): the completed
    runs' peaks through ``errors.ensemble_statistics``; the goals on the median peak against Table 2's median
    (the curve's peak without one) and the median time against the curve's."""
    out, met = {}, {}
    done = [m for m in members if m.get("status") == "completed"]
    for s in LOBOVSKY_SENSORS:
        v = figures.get(s)
        runs = [m[s] for m in done if s in m]
        if not v or not runs:
            continue
        t2 = v.get("table2") or {}
        st = E.ensemble_statistics([r["peak"] for r in runs], [r["time"] for r in runs], v["exp_peak"], v["exp_time"],
                                   t2.get("median"), *(t2.get("band") or [None, None]))
        out[s] = st
        perr = st["table2"]["median_error"] if "table2" in st else st["peak_error"]
        met[s] = {"peak": abs(perr) <= GOALS["peak_error"], "time": abs(st["time_error"]) <= GOALS["time_error"]}
    return out, met


def member_figures(figures: dict) -> dict:
    """What an ensemble keeps of one run's Lobovsky figures: per sensor its peak and time, and the steadier
    figures beside them (the arrival's error, the mean over the curve's peak span, the 4 ms peak)."""
    keep = ("rise_time_error", "span_mean_error", "peak_4ms_error", "kernel_peak_error")
    return {s: {"peak": v["sim_peak"], "time": v["sim_time"], **{k: v.get(k) for k in keep}}
            for s, v in figures.items() if isinstance(v, dict)}


def run_member(case: Case, solver: str, resolution: str, radius: float, out_root: Path, seed: int, jitter: float,
               device=None, extra=None) -> dict:
    """One perturbed run of an ensemble (every fluid block's ``jitter`` [d] and ``seed``) into
    out_root/<case>-<solver>-<res>-seed<seed>: {"seed", "status", "cpu_time", <sensor>: {"peak", "time"}}."""
    from warp_sph.run import runner

    blocks = len(load_case_scene(case, solver, radius, extra).fluid)
    perturb = [f"fluid[{i}].{k}" for i in range(blocks) for k in ("jitter", "seed")]
    values = [jitter, seed] * blocks
    scene = load_case_scene(case, solver, radius, list(extra or []) + [f"{k}={v!r}" for k, v in zip(perturb, values)])
    folder = Path(out_root) / f"{case.name}-{solver}-{resolution}-seed{seed}"
    out = {"seed": seed, "status": "failed"}
    try:
        c0 = time.process_time()
        info = runner.run(scene, out=folder, overwrite=True, progress=False, device=device, log=lambda *a: None)
        out.update(status=info["status"], cpu_time=time.process_time() - c0)
        figures, _, _ = evaluate(case.name, folder, info)
        out.update(member_figures(figures))
    except Exception as exc:  # a failed run is kept as one; the ensemble's statistics use the completed ones
        out["error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    return out


def run_ensemble(rec: dict, case: Case, solver: str, resolution: str, radius: float, out_root: Path, runs: int,
                 jitter: float, device=None, extra=None, log=print) -> None:
    """Add ``ensemble`` (and ``ensemble_goals_met``) to the completed record ``rec``: its own run (seed 0, the
    lattice as it is) and runs - 1 perturbed ones (seeds 1 ..)."""
    f = rec.get("figures") or {}
    members = [{"seed": 0, "jitter": 0.0, "status": rec["status"], "cpu_time": rec.get("cpu_time")}]
    members[0].update(member_figures(f))
    for seed in range(1, runs):
        m = run_member(case, solver, resolution, radius, out_root, seed, jitter, device=device, extra=extra)
        m["jitter"] = jitter
        members.append(m)
        log(f"    seed {seed} (jitter {jitter:g} d): {m['status']}" + (f": {m['error']}" if m.get("error") else "")
            + "; ".join([""] + [f"{s} {m[s]['peak']:.3g} at T {m[s]['time']:.3g}" for s in LOBOVSKY_SENSORS if s in m]))
    stats, met = ensemble_figures(f, members)
    rec["ensemble"] = {"runs": runs, "jitter": jitter, "completed": sum(m["status"] == "completed" for m in members),
                       "cpu_time": float(sum(m.get("cpu_time") or 0.0 for m in members)), "members": members,
                       "sensors": stats}
    rec["ensemble_goals_met"] = met


def run_one(case: Case, solver: str, resolution: str, out_root: Path, device=None, extra=None, log=print,
            radius: float | None = None, runs: int = 1, jitter: float = JITTER_DEFAULT) -> dict:
    """Run ``case`` with ``solver`` at ``resolution`` ("coarse" or "fine", or the label of ``radius`` [m] when
    given: ``--radius``) into out_root/<case>-<solver>-<res> and return its record; a case of ``ENSEMBLE_CASES``
    with ``runs`` > 1 runs runs - 1 more times, perturbed by ``jitter`` [d] (``run_ensemble``)."""
    from warp_sph.run import runner

    radius = radius or case.radii[0 if resolution == "coarse" else 1]
    from .records import SCHEMA

    rec = {"schema": SCHEMA, "kind": "validation", "label": f"{case.name} {solver} {resolution}", "case": case.name,
           "solver": solver, "resolution": resolution, "particle_radius": radius, "status": "failed"}
    folder = Path(out_root) / f"{case.name}-{solver}-{resolution}"
    try:
        scene = load_case_scene(case, solver, radius, extra)
        if scene is None:
            rec.update(status="skipped", error=f"{solver} has no pressure field; the case has only pressure probes")
            log(f"  {case.name} {solver} {resolution}: skipped ({rec['error']})")
            return rec
        c0, w0 = time.process_time(), time.perf_counter()
        info = runner.run(scene, out=folder, overwrite=True, progress=False, device=device, log=lambda *a: None)
        rec.update(cpu_time=time.process_time() - c0, wall_time=time.perf_counter() - w0,
                   fluid_particles=info["fluid_particles"], steps=info["steps"],
                   simulated_time=info["simulated_time"], status=info["status"], out=str(folder))
        if info.get("settle"):  # the packing pass before t = 0 (time.settle): its steps, CPU s, last speed
            rec["settle"] = info["settle"]
        figures, met, series = evaluate(case.name, folder, info)
        rec.update(figures=figures, goals_met=met, series=series)
        frames = [f for f in info.get("frames") or [] if f.get("density_error_mean") is not None]
        if frames:  # the incompressibility figure beside the error against the experiment
            rec["density_error_mean_avg"] = float(np.mean([f["density_error_mean"] for f in frames]))
            last = frames[-1]
            if last.get("kinetic_energy") is not None:
                mass = float(info["model"]["particle_mass"]) * float(info["fluid_particles"])
                rec["rms_speed_final"] = math.sqrt(2.0 * float(last["kinetic_energy"]) / mass)
                if case_kind(case.name) == "hydrostatic" and "settled" not in met:  # no last state: rms >= mean |v|
                    met["settled"] = rec["rms_speed_final"] < GOALS["settled_speed"]
        if case_kind(case.name) in ("lobovsky", "hydrostatic"):
            # wall probes read the walls' force (before: the particle pressure); Lobovsky's are 4.2 mm transducers
            rec["pressure_probe"] = "transducer" if case.name == "lobovsky" else "wall load"
        if rec["simulated_time"]:
            rec["cpu_per_simulated_second"] = rec["cpu_time"] / float(rec["simulated_time"])
        if case.name in ENSEMBLE_CASES and runs > 1 and rec["status"] == "completed":
            run_ensemble(rec, case, solver, resolution, radius, out_root, runs, jitter, device=device, extra=extra,
                         log=log)
    except Exception as exc:  # a failed case is a record, the others still run
        rec["error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    log(f"  {case.name} {solver} {resolution} (r = {radius:g} m): {rec['status']}"
        + (f", {rec.get('fluid_particles')} particles, {rec.get('cpu_time', 0):.0f} s CPU" if "cpu_time" in rec else "")
        + (f": {rec['error']}" if rec.get("error") else f"  {summary_text(rec)}"))
    return rec


def summary_text(rec: dict) -> str:
    f = rec.get("figures") or {}
    if rec["case"] == "martin_moyce" and f.get("front_rms") is not None:
        return (f"front RMS {100 * f['front_rms']:.1f} % (shift {f['front_shift']:+.3f} T; unshifted "
                f"{100 * f['front_rms_unshifted']:.1f} %), residual RMS {f['residual_rms']:.3f} H0")
    if rec["case"] == "lobovsky":
        return "; ".join(f"{s}: peak {100 * v['peak_error']:+.0f} %, time {100 * v['time_error']:+.1f} %"
                         + (f" (2D-kernel load {100 * v['kernel_peak_error']:+.0f} %)" if "kernel_peak_error" in v else "")
                         for s, v in f.items() if isinstance(v, dict)) or f.get("note", "")
    if case_kind(rec["case"]) == "hydrostatic":
        return ", ".join(f"{k} {100 * v:+.2f} %" for k, v in f.items() if k.endswith("_error")) or \
            f"surface {f.get('surface_height', 0):.4f} m (no pressure field)"
    return ""


def run_validation(cases: list[str], solvers: list[str], resolutions: list[str], out_root: Path, device=None,
                   extra=None, log=print, radius: float | None = None, ensemble: dict | None = None) -> list[dict]:
    """Every case, resolution and solver; with ``radius`` [m] one run per case and solver at that particle radius
    instead (its resolution label ``r=<radius>``, the ensemble's fine count); ``ensemble``: ``ensemble_settings``
    (default: its defaults)."""
    ensemble = ensemble or ensemble_settings(None, None)
    if radius is not None:
        resolutions = [f"r={radius:g}"]
    records = []
    for name in cases:
        for res in resolutions:
            for solver in solvers:
                records.append(run_one(CASES[name], solver, res, out_root, device=device, extra=extra, log=log,
                                       radius=radius, runs=ensemble["coarse" if res == "coarse" else "fine"],
                                       jitter=ensemble["jitter"]))
    return records


# --------------------------------------------------------------------------------------------
# Plots and the report section
# --------------------------------------------------------------------------------------------
def add_arguments(v) -> None:
    """The options of ``warp-sph bench validation`` (runner.py registers the command)."""
    v.add_argument("--cases", default=None, help=f"comma-separated cases (default: all: {', '.join(CASES)})")
    v.add_argument("--solvers", default=None, help="comma-separated solvers (default: every solver)")
    v.add_argument("--resolution", choices=("coarse", "fine", "both"), default="both",
                   help="the cases' coarse or fine particle radius, or both (default)")
    v.add_argument("--radius", type=float, default=None,
                   help="one run per case and solver at this particle radius [m] instead of --resolution (a third, "
                        "finer point of a convergence study; its records' resolution is r=<radius>)")
    v.add_argument("--ensemble", default=None, metavar="N|COARSE,FINE",
                   help=f"runs of the lobovsky case per solver and resolution: the first from the lattice as it is, "
                        f"the others with the start perturbed by --jitter (default {ENSEMBLE_DEFAULT['coarse']},"
                        f"{ENSEMBLE_DEFAULT['fine']}: {ENSEMBLE_DEFAULT['coarse']} at coarse, "
                        f"{ENSEMBLE_DEFAULT['fine']} at fine; 1: one run)")
    v.add_argument("--jitter", type=float, default=None,
                   help=f"the ensemble's perturbation, a fraction of d: each coordinate of each particle's start moves "
                        f"by a seeded uniform draw in [-jitter d, +jitter d] (default {JITTER_DEFAULT:g})")
    v.add_argument("--runs", default=str(Path("runs") / "bench" / "validation"),
                   help="folder of the run folders (default runs/bench/validation); a case's folder <case>-<solver>-<resolution> "
                        "is replaced when that case runs again, the others are kept")


def check_scenes(cases, solvers, resolutions, extra=None, radius: float | None = None) -> None:
    """Load every case's scene with every solver at every resolution (no kernel runs) so that a bad ``--set`` key or
    value is one line (SceneError, exit 2) before the first case starts, not one failed record per case."""
    for name in cases:
        case = CASES[name]
        for res in resolutions:
            r = radius or case.radii[0 if res == "coarse" else 1]
            for solver in solvers:
                load_case_scene(case, solver, r, extra)


def case_names(text: str | None) -> list[str]:
    """--cases text -> case names; WarpSphError (one line) for an unknown one."""
    from warp_sph.core.errors import WarpSphError

    cases = [c.strip() for c in text.split(",") if c.strip()] if text else list(CASES)
    bad = [c for c in cases if c not in CASES]
    if bad:
        raise WarpSphError(f"bench validation: --cases {text!r}: unknown {', '.join(map(repr, bad))}; "
                           f"expected some of {', '.join(CASES)}")
    return cases
