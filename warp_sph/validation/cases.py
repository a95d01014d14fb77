"""The validation cases (published experiments) and their error figures: the case table, loading a case's
scene at a resolution, and ``evaluate``, which reads a finished run's probe files and computes the figures
against the experiment (``errors.py``'s functions on the data shipped in ``data/`` with their citations).
Used by ``warp-sph bench validation`` (benchmarks/validation.py) and by ``warp-sph plan``'s errors against
an experiment (warp_sph/plan/metrics.py), so both compute the same figures."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..scene.container import water_offset  # noqa: F401  (the water's boundary inside a wall plane [m])
from . import errors as E

SCENE_DIR = Path(__file__).resolve().parents[2] / "scenes" / "validation"
G = 9.81
#: the issue's goals
GOALS = {"front_rms": 0.04, "peak_error": 0.10, "time_error": 0.05, "hydrostatic_error": 0.01,
         "settled_speed": 1e-3}


#: a checkpoint every this many frames: more than a validation run has, so only the first and the last frame's
#: state are written (the runner checkpoints frame 1 and the last frame whenever checkpoint_every > 0)
LAST_STATE_EVERY = 100000


@dataclass
class Case:
    name: str
    scene: str                       # file in scenes/validation
    radii: tuple[float, float]       # coarse, fine particle radius [m]
    overrides: dict = field(default_factory=dict)   # per-resolution extra overrides (callable of d)
    title: str = ""


def _centred_probe(index: int, z: float):
    """An override placing probe ``index`` at the centre of the fcc tank (``fcc_tank_width``) at height z [m]."""
    return lambda d: (f"probes[{index}].position=[{fcc_tank_width(d) / 2:.12g}, {fcc_tank_width(d) / 2:.12g}, "
                      f"{z:g}]")


def _scene_dir() -> Path:
    """scenes/validation in the source tree, or the installed package's copy."""
    if SCENE_DIR.is_dir():
        return SCENE_DIR
    import importlib.resources

    return Path(str(importlib.resources.files("warp_sph.scenes"))) / "validation"


CASES = {
    "martin_moyce": Case("martin_moyce", "martin_moyce.toml", (0.01, 0.005),
                         {"front_height": lambda d: f"probes[0].position=[0.0, 0.05, {1.25 * d:.6g}]"},
                         "Column collapse, Martin & Moyce 1952 (n² = 2)"),
    "lobovsky": Case("lobovsky", "lobovsky.toml", (0.01, 0.005), {},
                     "Dam break onto a wall, Lobovsky et al. 2014 (H = 0.3 m)"),
    # the hydrostatic tank keeps its last frame's state (a checkpoint at the first and the last frame only):
    # ``evaluate`` reads its velocities for the mean speed at the end (issue #31: mean |v| < 1e-3 m/s after 2 s)
    "hydrostatic": Case("hydrostatic", "hydrostatic_probes.toml", (0.025, 0.0125),
                        {"last_state": lambda d: f"output.checkpoint_every={LAST_STATE_EVERY}"},
                        "Hydrostatic tank, floor and mid-depth pressure"),
    # the same tank started on the fcc lattice (``fluid[].lattice``), which holds under load where the cubic one's
    # columns slip (docs/validation-notes.md "The fcc lattice"); its tank is the fcc block's own width
    # (``fcc_tank_width``), so the water fills it exactly at both radii, as the cubic case's 0.6 m tank does
    "hydrostatic_fcc": Case("hydrostatic_fcc", "hydrostatic_probes.toml", (0.025, 0.0125),
                            {"last_state": lambda d: f"output.checkpoint_every={LAST_STATE_EVERY}",
                             "lattice": lambda d: "fluid[0].lattice=fcc",
                             "tank": lambda d: f"container.max=[{fcc_tank_width(d):.12g}, {fcc_tank_width(d):.12g}, 1.0]",
                             "water": lambda d: f"fluid[0].max=[{fcc_tank_width(d):.12g}, {fcc_tank_width(d):.12g}, 0.5]",
                             **{f"probe{i}": _centred_probe(i, z) for i, z in ((0, 0.0), (1, 0.25), (2, 0.0))}},
                            "Hydrostatic tank started on the fcc lattice"),
}
#: the cases whose figures are the hydrostatic tank's (``case_kind``)
HYDROSTATIC_CASES = ("hydrostatic", "hydrostatic_fcc")


def case_kind(name: str) -> str:
    """The kind of figures a case has: its own name, or "hydrostatic" for every hydrostatic tank."""
    return "hydrostatic" if name in HYDROSTATIC_CASES else name


def fcc_tank_width(d: float, width: float = 0.6) -> float:
    """Width [m] of the tank an fcc block of nearest spacing d [m] fills exactly, nearest to ``width``: its square
    face nets have n columns d / sqrt(2) apart, so d + (n - 1) d / sqrt(2) (0.6157 m at d = 0.05 m, 0.6084 m at
    0.025 m)."""
    step = d / math.sqrt(2.0)
    return d + round((width - d) / step) * step
LOBOVSKY_SENSORS = ("sensor1", "sensor3", "sensor4")
LOBOVSKY_HEIGHTS_MM = {"sensor1": 3.0, "sensor3": 30.0, "sensor4": 80.0}
#: the shipped series a probe may name (``probes[].experiment``): (time unit [s], value unit [SI], label) of their
#: dimensionless columns; Lobovsky: T = t sqrt(g/H), P = p / (rho g H), H = 0.3 m, rho = 1000 kg/m^3
EXPERIMENTS = {f"lobovsky_2014_{s}": (math.sqrt(0.3 / G), 1000.0 * G * 0.3,
                                      f"experiment: Lobovsky et al. 2014, {s} ({LOBOVSKY_HEIGHTS_MM[s]:g} mm)")
               for s in LOBOVSKY_SENSORS}


def experiment_series(name: str) -> tuple[np.ndarray, np.ndarray, str]:
    """(time [s], value [SI], label) of the shipped series ``name`` (``EXPERIMENTS``; its citation in data/)."""
    t, v, _ = E.load_series(name)
    time_unit, value_unit, label = EXPERIMENTS[name]
    return t * time_unit, v * value_unit, label


def load_case_scene(case: Case, solver: str, radius: float, extra: list[str] | None = None):
    """The case's scene at ``radius`` with ``solver``, no USD or surface, no checkpoints; pressure probes inside
    the fluid dropped for a solver without a pressure field (those on a wall read the wall load)."""
    from ..methods import registry
    from ..scene import load_scene, scene_from_dict

    d = 2.0 * radius
    overrides = [f"particle_radius={radius}", f"solver={solver}", "output.usd=false", "output.surface=false",
                 "output.checkpoint_every=0"] + [f(d) for f in case.overrides.values()] + list(extra or [])
    scene = load_scene(str(_scene_dir() / case.scene), overrides=overrides)
    if not has_pressure(registry.solver(solver)):
        from ..run.probes import probe_lines

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
    from ..io.probe_files import probe_csv_path, read_probe_csv

    rows = np.array(read_probe_csv(probe_csv_path(folder, name))[1], dtype=np.float64).reshape(-1, 3)
    return rows[:, 0], rows[:, 1]


def _series(t, v, digits: int = 5) -> list[list[float]]:
    return [[float(f"{a:.{digits}g}"), float(f"{b:.{digits}g}")] for a, b in zip(t, v)]


def evaluate(case: str, folder: Path, info: dict, pressure_window: float = E.PRESSURE_WINDOW) -> tuple[dict, dict, dict]:
    """(figures, goals met, dimensionless series) of a finished run of ``case`` in ``folder`` (its probe CSVs and
    run.json's ``probes``); simulated pressures are averaged over ``pressure_window`` seconds before their peak (0: as
    sampled, the bench's choice, ``errors.PRESSURE_WINDOW``)."""
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
            pk.update(E.peak_shape(T, P, te, pe, GOALS["peak_error"]))  # the peak's span, the arrival, the level
            k = int(np.argmin(np.abs(table["z_mm"] - LOBOVSKY_HEIGHTS_MM[s])))  # Table 2: the per-run peaks
            scale = 100.0 / (1000.0 * G * H)  # mbar -> P
            pk["table2"] = E.peak_statistics(pk["sim_peak"], table["median_mbar"][k] * scale,
                                             table["p2_5_mbar"][k] * scale, table["p97_5_mbar"][k] * scale)
            if f"{s}_kernel" in probes:  # the 2D-kernel wall load at the same point, for comparison
                tk, pk_ = read_probe(folder, f"{s}_kernel")
                kern = E.peak(tk * math.sqrt(G / H), pk_ / (1000.0 * G * H), te, pe)
                pk.update(kernel_peak=kern["sim_peak"], kernel_peak_error=kern["peak_error"],
                          kernel_time=kern["sim_time"], kernel_time_error=kern["time_error"])
            figures[s] = pk
            met[s] = {"peak": abs(pk["peak_error"]) <= GOALS["peak_error"],
                      "time": abs(pk["time_error"]) <= GOALS["time_error"]}
            series[s] = _series(T, P, 4)
        if not figures:
            figures["note"] = "no pressure field (solver without pressure): pressure probes not run"
    elif case_kind(case) == "hydrostatic":
        t, h = read_probe(folder, "surface")
        late = t >= 0.5 * t[-1]
        out = {}
        # the floor's surface: the fluid rests a wall gap above the floor's particles and each particle fills
        # d/2 = r around its centre, so the water starts gap - r above them (the depth the floor carries: its
        # load at rest is the weight of the water from there to the surface); with the case's experiment
        # walls that is the scene's own floor, z = 0
        from ..scene import scene_from_dict

        sc = scene_from_dict(info["scene"])
        off = water_offset(sc)
        floor = (float(sc.container.min[2]) if sc.container is not None else 0.0) + off
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
        # the depth the water's volume gives over the floor it covers (its edges gap - r from the wall
        # particles, as on the floor: the scene's 0.6 m tank), and how far below that level the surface
        # settled [d] (the lattice re-packs; the height probe reads where the surface is)
        c, d = sc.container, 2.0 * sc.particle_radius
        model = info.get("model") or {}
        if c is not None and model.get("particle_mass") and info.get("fluid_particles"):
            area = float(np.prod([c.max[a] - c.min[a] - 2.0 * off for a in (0, 1)]))
            volume = float(info["fluid_particles"]) * float(model["particle_mass"]) / float(model.get("rest_density", 1000.0))
            figures["depth_by_volume"] = volume / area
            figures["surface_drop_d"] = (floor + figures["depth_by_volume"] - figures["surface_height"]) / d
        met = {k: abs(v) <= GOALS["hydrostatic_error"] for k, v in figures.items() if k.endswith("_error")}
        speeds = final_speeds(folder)
        if speeds is not None:  # the figure: mean |v| at the end (the bench also reports the rms speed)
            figures["mean_speed_final"] = float(np.mean(speeds))
            met["settled"] = figures["mean_speed_final"] < GOALS["settled_speed"]
    return figures, met, series


def final_speeds(folder: Path) -> np.ndarray | None:
    """|v| [m/s] of every fluid particle in the run's last checkpoint (the last frame's state with the case's
    ``last_state`` override), or None without a checkpoint."""
    from ..io.run_folder import latest_checkpoint, load_checkpoint

    path = latest_checkpoint(folder)
    if path is None:
        return None
    return np.linalg.norm(np.asarray(load_checkpoint(path)["particle_v"], dtype=np.float64), axis=1)
