"""``warp-sph bench validation``: every solver against published experiments, at two resolutions.

Cases (scenes in ``scenes/validation/``, data in ``validation_data/`` with their citations):

martin_moyce   column collapse, n^2 = 2 (Martin & Moyce 1952): surge front Z = x/a against T = t sqrt(2 g / a)
               (relative RMS with a start-time shift |s| <= 0.2, goal 4 %) and residual height eta/(2a) against
               tau = t sqrt(g / a) (RMS in units of the initial height). a and the initial height are the probes'
               readings at t = 0 (the front and the height line), so Z(0) = 1 as in the paper.
lobovsky       dam break onto a wall (Lobovsky et al. 2014, H = 0.3 m): pressure at sensors 1, 3, 4, P = p/(rho g H)
               against T = t sqrt(g / H): peak and its time (goals 10 % and 5 %), the simulated signal as sampled (no
               filter); the peak also against the experiment's per-run peak statistics (Table 2: median, 2.5-97.5 %).
hydrostatic    the hydrostatic tank with probes: floor and mid-depth pressure against rho0 g (h - z), h from the
               height probe, averaged over the second half of the run (goal 1 %).

Each case runs with every solver (or ``--solvers``) at its coarse and fine particle radius (``--resolution``);
one JSON line per run goes to ``<results>/validation.jsonl`` (figures, goals, the dimensionless series) and one
plot per case with the experiment beside the simulations to ``<results>/validation_<case>.png``. The error
figures are ``validation_errors.py``'s functions, the same the tests feed the shipped data.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import validation_errors as E

SCENE_DIR = Path(__file__).resolve().parent.parent / "scenes" / "validation"
G = 9.81
#: the issue's goals
GOALS = {"front_rms": 0.04, "peak_error": 0.10, "time_error": 0.05, "hydrostatic_error": 0.01,
         "settled_speed": 1e-3}


@dataclass
class Case:
    name: str
    scene: str                       # file in scenes/validation
    radii: tuple[float, float]       # coarse, fine particle radius [m]
    overrides: dict = field(default_factory=dict)   # per-resolution extra overrides (callable of d)
    title: str = ""


def _scene_dir() -> Path:
    """scenes/validation in the source tree, or the installed package's copy."""
    if SCENE_DIR.is_dir():
        return SCENE_DIR
    import warp_sph.scenes

    return Path(warp_sph.scenes.__file__).resolve().parent / "validation"


CASES = {
    "martin_moyce": Case("martin_moyce", "martin_moyce.toml", (0.01, 0.005),
                         {"front_height": lambda d: f"probes[0].position=[0.0, 0.05, {1.25 * d:.6g}]"},
                         "Column collapse, Martin & Moyce 1952 (n² = 2)"),
    "lobovsky": Case("lobovsky", "lobovsky.toml", (0.01, 0.005), {},
                     "Dam break onto a wall, Lobovsky et al. 2014 (H = 0.3 m)"),
    "hydrostatic": Case("hydrostatic", "hydrostatic_probes.toml", (0.025, 0.0125), {},
                        "Hydrostatic tank, floor and mid-depth pressure"),
}
LOBOVSKY_SENSORS = ("sensor1", "sensor3", "sensor4")
LOBOVSKY_HEIGHTS_MM = {"sensor1": 3.0, "sensor3": 30.0, "sensor4": 80.0}


def load_case_scene(case: Case, solver: str, radius: float, extra: list[str] | None = None):
    """The case's scene at ``radius`` with ``solver``, no USD or surface, no checkpoints; pressure probes inside
    the fluid dropped for a solver without a pressure field (those on a wall read the wall load)."""
    from warp_sph.methods import registry
    from warp_sph.scene import load_scene, scene_from_dict

    d = 2.0 * radius
    overrides = [f"particle_radius={radius}", f"solver={solver}", "output.usd=false", "output.surface=false",
                 "output.checkpoint_every=0"] + [f(d) for f in case.overrides.values()] + list(extra or [])
    scene = load_scene(str(_scene_dir() / case.scene), overrides=overrides)
    if not has_pressure(registry.solver(solver)):
        from warp_sph.run.probes import probe_lines

        c = scene.container
        lo, hi = (None, None) if c is None else (c.min, c.max)
        on_wall = [line.wall(lo, hi, scene.wall_gap) is not None for line in probe_lines(scene)]
        data = scene.to_dict()
        # a probe on a wall reads the walls' force (every solver has one); one inside the fluid its pressure
        data["probes"] = [p for p, w in zip(data.get("probes", []), on_wall) if p["kind"] != "pressure" or w]
        if not data["probes"]:
            return None
        scene = scene_from_dict(data, source=scene.source)
    return scene


def has_pressure(solver_cls) -> bool:
    """Whether a solver computes a pressure field (PBF's position correction is none)."""
    return solver_cls.name != "pbf"


def read_probe(folder: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    from warp_sph.io.probe_files import probe_csv_path, read_probe_csv

    rows = np.array(read_probe_csv(probe_csv_path(folder, name))[1], dtype=np.float64).reshape(-1, 3)
    return rows[:, 0], rows[:, 1]


def _series(t, v, digits: int = 5) -> list[list[float]]:
    return [[float(f"{a:.{digits}g}"), float(f"{b:.{digits}g}")] for a, b in zip(t, v)]


def evaluate(case: str, folder: Path, info: dict, pressure_window: float = E.PRESSURE_WINDOW) -> tuple[dict, dict, dict]:
    """(figures, goals met, dimensionless series) of a finished run of ``case`` in ``folder`` (its probe CSVs and
    run.json's ``probes``); simulated pressures are averaged over ``pressure_window`` seconds before their peak (0: as
    sampled, the bench's choice, ``validation_errors.PRESSURE_WINDOW``)."""
    probes = info.get("probes") or {}
    figures, met, series = {}, {}, {}
    if case == "martin_moyce":
        t, x = read_probe(folder, "front")
        th, h = read_probe(folder, "residual")
        a, h0 = float(x[0]), float(h[0])
        T, Z = t * math.sqrt(2.0 * G / a), x / a
        tau, Hs = th * math.sqrt(G / a), h / h0
        te, ze, _ = E.load_series("martin_moyce_1952_front")
        tr, hr, _ = E.load_series("martin_moyce_1952_residual")
        front = E.front_rms(T, Z, te, ze)
        resid = E.gauge_rms(tau, Hs, tr, hr)
        figures = {"a": a, "initial_height": h0, "front_rms": front["rms"], "front_shift": front["shift"],
                   "front_rms_unshifted": front["rms_unshifted"], "front_points": front["points"],
                   "residual_rms": resid["rms"], "residual_points": resid["points"]}
        met = {"front_rms": front["rms"] is not None and front["rms"] <= GOALS["front_rms"]}
        series = {"front": _series(T, Z), "residual": _series(tau, Hs)}
    elif case == "lobovsky":
        H = 0.3
        table, _ = E.load_table("lobovsky_2014_peaks")
        for s in LOBOVSKY_SENSORS:
            if s not in probes:
                continue
            t, p = read_probe(folder, s)
            T, P = t * math.sqrt(G / H), p / (1000.0 * G * H)
            te, pe, _ = E.load_series(f"lobovsky_2014_{s}")
            raw = E.peak(T, P, te, pe)
            old = E.peak(T, E.moving_average(t, P, E.OLD_PRESSURE_WINDOW), te, pe)
            P = E.moving_average(t, P, pressure_window)
            pk = E.peak(T, P, te, pe)
            pk.update(raw_peak=raw["sim_peak"], raw_time=raw["sim_time"], filter_window_s=pressure_window,
                      peak_4ms=old["sim_peak"], peak_4ms_error=old["peak_error"])
            k = int(np.argmin(np.abs(table["z_mm"] - LOBOVSKY_HEIGHTS_MM[s])))  # Table 2: the per-run peaks
            scale = 100.0 / (1000.0 * G * H)  # mbar -> P
            pk["table2"] = E.peak_statistics(pk["sim_peak"], table["median_mbar"][k] * scale,
                                             table["p2_5_mbar"][k] * scale, table["p97_5_mbar"][k] * scale)
            figures[s] = pk
            met[s] = {"peak": abs(pk["peak_error"]) <= GOALS["peak_error"],
                      "time": abs(pk["time_error"]) <= GOALS["time_error"]}
            series[s] = _series(T, P, 4)
        if not figures:
            figures["note"] = "no pressure field (solver without pressure): pressure probes not run"
    elif case == "hydrostatic":
        t, h = read_probe(folder, "surface")
        late = t >= 0.5 * t[-1]
        out = {}
        # the floor's surface: the fluid rests a wall gap above the floor's particles (on z = 0) and each
        # particle fills d/2 = r around its centre, so the water starts at z = gap - r (the depth the
        # floor carries: its load at rest is the weight of the water from there to the surface)
        from warp_sph.scene import scene_from_dict

        sc = scene_from_dict(info["scene"])
        floor = sc.wall_gap - sc.particle_radius
        figures["floor_surface"] = floor
        for name, z in (("floor", floor), ("middle", 0.25)):
            if name not in probes:
                continue
            tp, p = read_probe(folder, name)
            ratio = p / (1000.0 * G * (np.interp(tp, t, h) - z))
            out[name] = float(np.mean(ratio[tp >= 0.5 * tp[-1]]) - 1.0)
            series[name] = _series(tp, ratio, 4)
        figures.update({f"{k}_error": v for k, v in out.items()})
        figures["surface_height"] = float(np.mean(h[late]))
        # the depth the water's volume gives over the floor it covers once spread to the walls (its edges
        # gap - r from the wall particles, as on the floor), and how far below that level the surface settled
        # [d]: the sampled columns need not fill the tank (r = 0.0125 m leaves 0.22 d of slack at one side of
        # each axis), the water spreads into the slack and re-packs, and the height probe reads where it is
        c, d = sc.container, 2.0 * sc.particle_radius
        model = info.get("model") or {}
        if c is not None and model.get("particle_mass") and info.get("fluid_particles"):
            area = float(np.prod([c.max[a] - c.min[a] - 2.0 * floor for a in (0, 1)]))
            volume = float(info["fluid_particles"]) * float(model["particle_mass"]) / float(model.get("rest_density", 1000.0))
            figures["depth_by_volume"] = volume / area
            figures["surface_drop_d"] = (floor + figures["depth_by_volume"] - figures["surface_height"]) / d
        met = {k: abs(v) <= GOALS["hydrostatic_error"] for k, v in figures.items() if k.endswith("_error")}
    return figures, met, series


def run_one(case: Case, solver: str, resolution: str, out_root: Path, device=None, extra=None, log=print) -> dict:
    """Run ``case`` with ``solver`` at ``resolution`` ("coarse" or "fine") into out_root/<case>-<solver>-<res>
    and return its record."""
    from warp_sph.run import runner

    radius = case.radii[0 if resolution == "coarse" else 1]
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
        figures, met, series = evaluate(case.name, folder, info)
        rec.update(figures=figures, goals_met=met, series=series)
        frames = [f for f in info.get("frames") or [] if f.get("density_error_mean") is not None]
        if frames:  # the incompressibility figure beside the error against the experiment
            rec["density_error_mean_avg"] = float(np.mean([f["density_error_mean"] for f in frames]))
            last = frames[-1]
            if last.get("kinetic_energy") is not None:
                mass = float(info["model"]["particle_mass"]) * float(info["fluid_particles"])
                rec["rms_speed_final"] = math.sqrt(2.0 * float(last["kinetic_energy"]) / mass)
                if case.name == "hydrostatic":  # at rest after the run (rms >= mean |v|: a sufficient test)
                    met["settled"] = rec["rms_speed_final"] < GOALS["settled_speed"]
        if case.name in ("lobovsky", "hydrostatic"):
            rec["pressure_probe"] = "wall load"  # wall probes read the walls' force (before: the particle pressure)
        if rec["simulated_time"]:
            rec["cpu_per_simulated_second"] = rec["cpu_time"] / float(rec["simulated_time"])
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
                         for s, v in f.items() if isinstance(v, dict)) or f.get("note", "")
    if rec["case"] == "hydrostatic":
        return ", ".join(f"{k} {100 * v:+.2f} %" for k, v in f.items() if k.endswith("_error")) or \
            f"surface {f.get('surface_height', 0):.4f} m (no pressure field)"
    return ""


def run_validation(cases: list[str], solvers: list[str], resolutions: list[str], out_root: Path, device=None,
                   extra=None, log=print) -> list[dict]:
    records = []
    for name in cases:
        for res in resolutions:
            for solver in solvers:
                records.append(run_one(CASES[name], solver, res, out_root, device=device, extra=extra, log=log))
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
    v.add_argument("--runs", default=str(Path("runs") / "bench" / "validation"),
                   help="folder of the run folders (default runs/bench/validation; replaced on every run)")


def case_names(text: str | None) -> list[str]:
    """--cases text -> case names; WarpSphError (one line) for an unknown one."""
    from warp_sph.core.errors import WarpSphError

    cases = [c.strip() for c in text.split(",") if c.strip()] if text else list(CASES)
    bad = [c for c in cases if c not in CASES]
    if bad:
        raise WarpSphError(f"bench validation: --cases {text!r}: unknown {', '.join(map(repr, bad))}; "
                           f"expected some of {', '.join(CASES)}")
    return cases
