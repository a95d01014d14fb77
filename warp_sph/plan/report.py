"""What ``warp-sph plan`` shows and writes: --budget / --target-error parsing, the table, the Pareto plot
(matplotlib, the plots extra) and --apply's scene file or ``--set`` flags."""
from __future__ import annotations

import math
import os
import re
from pathlib import Path

from .advisor import Candidate, Plan
from .calibrate import PlanError, tolerance_key, variant_dict

_UNITS = {"": 1.0, "s": 1.0, "sec": 1.0, "m": 60.0, "min": 60.0, "h": 3600.0, "hr": 3600.0}


def parse_budget(text: str) -> float:
    """Seconds of a wall-time budget: ``90``, ``90s``, ``10m``, ``1.5h``, ``1h30m``. PlanError otherwise."""
    t = str(text).strip().lower().replace(" ", "")
    parts = re.findall(r"(\d+(?:\.\d*)?|\.\d+)(h|hr|min|m|sec|s)?", t)
    if not t or "".join(a + b for a, b in parts) != t or len({u for _, u in parts}) != len(parts):
        raise PlanError(f"--budget {text!r}: expected a wall time such as 90s, 10m, 1.5h or 1h30m")
    seconds = sum(float(v) * _UNITS[u] for v, u in parts)
    if not (seconds > 0 and math.isfinite(seconds)):
        raise PlanError(f"--budget {text!r}: expected a wall time > 0")
    return seconds


def parse_error(text: str, given: str | None = None) -> float:
    """A mean density error as a fraction: ``0.5%`` -> 0.005, ``0.005`` -> 0.005. PlanError otherwise, quoting
    ``given`` (the whole --target-error text, e.g. ``front:abc``) when the error is a part of it."""
    t = str(text).strip()
    pct = t.endswith("%")
    try:
        v = float(t[:-1] if pct else t) / (100.0 if pct else 1.0)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and 0 < v < 1):
        raise PlanError(f"--target-error {given if given is not None else text!r}: expected an error such as 0.5% "
                        "or 0.005 (between 0 and 1), "
                        "optionally after a metric: front:4%")
    return v


def parse_target(text: str) -> tuple[str, float]:
    """(metric, error as a fraction) of --target-error: ``0.5%`` -> ("density", 0.005), ``front:4%`` ->
    ("front", 0.04). Whether the scene has the metric is checked later (``metrics.check_metric``)."""
    t = str(text).strip()
    metric, sep, value = t.rpartition(":")
    if not sep:
        return "density", parse_error(t)
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", metric.strip()):
        raise PlanError(f"--target-error {text!r}: expected METRIC:ERROR such as front:4% (a metric name, then the "
                        "error)")
    return metric.strip(), parse_error(value, given=t)


def duration_text(s: float) -> str:
    """A wall time [s] in s, min or h."""
    if s < 120:
        return f"{s:.3g} s"
    if s < 7200:
        return f"{s / 60:.3g} min"
    return f"{s / 3600:.3g} h"


def bytes_text(n: float) -> str:
    """Bytes in MiB or GiB."""
    return f"{n / 2**30:.3g} GiB" if n >= 2**30 else f"{n / 2**20:.3g} MiB"


def _row(c: Candidate, mark: str) -> list[str]:
    tol = "-" if c.tolerance is None else f"{100 * c.tolerance:.3g} %"
    row = [mark, c.solver, f"{c.particle_radius:.4g} m", tol, f"{c.fluid_particles:,}", f"{c.steps:,}",
           duration_text(c.wall_time), bytes_text(c.memory), f"{100 * c.density_error:.3g} %"]
    return row + ([f"{100 * c.metric_error:.3g} %"] if c.metric_error is not None else [])


def table_lines(p: Plan) -> list[str]:
    """The recommendation and each other solver's best, as an aligned text table, then what is extrapolated."""
    head = ["", "solver", "radius", "tolerance", "fluid N", "steps", "wall time", "memory", "mean density error"]
    if p.chosen.metric_error is not None:
        head.append(f"{p.metric} error")
    rows = [_row(p.chosen, "*")] + [_row(c, " ") for c in p.alternatives]
    widths = [max(len(r[i]) for r in [head] + rows) for i in range(len(head))]
    out = ["  ".join(v.ljust(w) for v, w in zip(r, widths)).rstrip() for r in [head] + rows]
    asked = []
    if p.budget_s is not None:
        asked.append(f"budget {duration_text(p.budget_s)}")
    if p.target_error is not None:
        asked.append(f"target {p.metric} error {100 * p.target_error:.3g} %")
    out.insert(0, f"plan for {p.scene} ({', '.join(asked)}; {p.duration:g} s simulated, {p.frames} frames), "
                  f"predicted for this machine:")
    for c in [p.chosen] + p.alternatives:
        ext = c.extrapolated()
        out.append(f"{c.solver}: " + (f"extrapolated: {ext}" if ext else "within the calibrated range"))
    out += [model_line(m) for m in p.models.values()]
    for s, why in p.failed_solvers.items():
        out.append(f"{s}: not a candidate, its calibration failed: {why}")
    if p.budget_used is not None:
        out.append(f"budget used: {100 * p.budget_used:.0f} % predicted ({duration_text(p.chosen.wall_time)} of "
                   f"{duration_text(p.budget_s)})")
    when = "from the cache, nothing ran now" if p.calibration_cached else "run now"
    out.append(f"calibration: {duration_text(p.calibration_seconds)} of runs ({when}; {p.cache_path})")
    out += [f"note: {n}" for n in p.notes]
    return out


def _order(law) -> str:
    if law is None:
        return "-"
    if law.clipped:
        return f"d^{law.exponent:.2f} (measured {law.measured:.2f}, clamped)"
    return f"d^{law.exponent:.2f}" + (" (one radius: constant)" if law.measured is None else "")


def _steps_text(rate) -> str:
    """The step-rate model in words: the calibration's law, the scene's viscous bound, the whole run's speeds."""
    text = ("steps/s at the floor " if rate.at_floor and rate.speeds else
            f"steps/s ~ d^{rate.law.exponent:.2f} above ") + f"{rate.floor:.4g}"
    if rate.known is not None:
        text += f", the viscous bound's {rate.known.coefficient:.3g} d^-2"
    if rate.speeds and rate.cfl > 0:
        text += (f", each frame's velocity CFL at the whole run's speeds (up to {max(rate.speeds):.3g} m/s at "
                 f"d = {rate.speed_spacing:.3g} m, ~ d^{rate.speed_exponent:.2f})")
    return text


def model_line(m) -> str:
    """One solver's fitted models in words: error orders, step rate, cost, the tolerance's effect."""
    text = f"{m.solver} models: density error ~ {_order(m.error)} in the first {m.calibrated_frames} frames, "
    if m.has_profile(len(m.profile)):
        text += f"later frames x {m.later_ratio(len(m.profile)):.3g} that (the error's course over a whole run)"
    else:
        text += f"then ~ {_order(m.error_last)} (the last calibrated frame's, held)"
    if m.metric_error is not None:
        text += f"; {m.metric} error ~ {_order(m.metric_error)}"
    text += (f"; {_steps_text(m.steps_per_second)}; "
             f"{1e9 * m.step_time.fluid:.3g} ns per fluid particle-step + {1e9 * m.step_time.boundary:.3g} ns per wall "
             f"particle-step + {1e3 * m.step_time.intercept:.3g} ms per step")
    if m.step_time_split is not None:
        c = m.step_time_split
        text += (f" (from {m.split_particles:,} particles, where the CPU launches split over the threads: "
                 f"{1e9 * c.fluid:.3g} + {1e9 * c.boundary:.3g} ns + {1e3 * c.intercept:.3g} ms)")
    if m.count_law is not None:
        text += (f"; beyond {m.count_fluid:,} fluid particles at least ~ Nf^{m.count_law.exponent:.2f} from its "
                 f"{1e9 * m.count_law(m.count_fluid) / m.count_fluid:.3g} ns per fluid particle-step (measured "
                 f"exponent {m.count_law.measured:.2f})")
    if m.cost_ratio_measured is not None:
        text += (f"; whole-run step cost x {m.cost_ratio:.3g} the calibration's (measured "
                 f"{m.cost_ratio_measured:.3g})")
    if m.tolerance is None:
        text += "; no tolerance"
    elif len(m.tolerances) < 2:
        text += f"; tolerance {m.tolerance:.3g} (not varied)"
    else:
        k = m.tolerance_exponents
        text += (f"; tolerance {min(m.tolerances):.3g}-{max(m.tolerances):.3g}: cost per step ~ t^{k['step_time']:.2f}, "
                 f"steps ~ t^{k['steps_per_second']:.2f}, error ~ t^{k['error_last']:.2f}")
    return text


def plot_pareto(p: Plan, path: Path) -> Path | None:
    """The candidates' predicted wall time against error, the Pareto front and the choice, as a PNG; None
    without matplotlib (the plots extra)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for solver in p.models:
        cs = [c for c in p.candidates if c.solver == solver]
        ax.plot([c.wall_time for c in cs], [100 * c.error for c in cs], ".", alpha=0.5, label=solver)
    front = sorted((c for c in p.candidates if c.pareto), key=lambda c: c.wall_time)
    ax.plot([c.wall_time for c in front], [100 * c.error for c in front], "k-", lw=1, label="Pareto front")
    ax.plot([p.chosen.wall_time], [100 * p.chosen.error], "r*", ms=14, label="chosen")
    if p.budget_s:
        ax.axvline(p.budget_s, color="grey", ls="--", lw=1, label="budget")
    if p.target_error:
        ax.axhline(100 * p.target_error, color="grey", ls=":", lw=1, label="target error")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("predicted wall time [s]")
    ax.set_ylabel("predicted mean density error [%]" if p.metric == "density" else f"predicted {p.metric} error [%]")
    ax.set_title(f"plan: {p.scene}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)
    return path


def set_flags(p: Plan) -> list[str]:
    """The ``--set`` flags of the chosen setting (the [plan] prediction included)."""
    c = p.chosen
    flags = [f"solver={c.solver}", f"particle_radius={c.particle_radius:.6g}"]
    key = tolerance_key(c.solver)
    if key is not None and c.tolerance is not None:
        flags.append(f"{key}={c.tolerance:.6g}")
    flags += [f"plan.{k}={v:.6g}" if isinstance(v, float) else f'plan.{k}="{v}"' if isinstance(v, str)
              else f"plan.{k}={v}" for k, v in p.prediction().items()]
    return flags


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else "nan"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"no TOML form for {v!r}")


def _key(k: str) -> str:
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else _toml_value(k)


def toml_text(data: dict, header: str = "") -> str:
    """A scene dict (``Scene.to_dict``) as TOML text: scalars first, then tables, then arrays of tables."""
    lines = [header.rstrip()] if header else []
    scalars = {k: v for k, v in data.items() if not isinstance(v, dict)
               and not (isinstance(v, list) and v and all(isinstance(x, dict) for x in v))}
    lines += [f"{_key(k)} = {_toml_value(v)}" for k, v in scalars.items()]
    for k, v in data.items():
        if isinstance(v, dict):
            lines += ["", f"[{_key(k)}]"] + [f"{_key(a)} = {_toml_value(b)}" for a, b in v.items()]
    for k, v in data.items():
        if isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for item in v:
                lines += ["", f"[[{_key(k)}]]"] + [f"{_key(a)} = {_toml_value(b)}" for a, b in item.items()]
    return "\n".join(lines) + "\n"


def check_apply_path(out: Path, force: bool) -> None:
    """Refuse an --apply path that is not a .toml file in an existing folder, or an existing file without --force."""
    if out.suffix.lower() != ".toml":
        raise PlanError(f"--apply {out}: expected a .toml scene file path")
    if out.exists() and not force:
        raise PlanError(f"--apply {out}: the file exists; pass --force to replace it")
    if not out.parent.is_dir():
        raise PlanError(f"--apply {out}: folder {out.parent} does not exist")


def check_plot_and_cache(args) -> None:
    """Before any calibration: refuse a --plot that is not a .png path or names an existing file (without
    --force: a picture of the user's is never replaced silently), and a --cache that is not a folder."""
    if args.plot:
        png = Path(args.plot)
        if png.suffix.lower() != ".png":
            raise PlanError(f"--plot {png}: expected a .png file path")
        if png.exists() and not args.force:
            raise PlanError(f"--plot {png}: the file exists; pass --force to replace it")
    cache = Path(args.cache).expanduser() if args.cache else None
    p = cache
    while p is not None and not p.exists() and p != p.parent:
        p = p.parent
    if p is not None and not p.is_dir():
        raise PlanError(f"--cache {cache}: " + ("is a file" if p == cache else f"lies under the file {p}") +
                        "; expected a folder for the calibration cache")


def apply_scene(scene, p: Plan, out: Path, force: bool = False) -> Path:
    """Write ``scene`` with the chosen setting and its [plan] prediction to ``out`` (atomic; an existing file
    only with ``force``). The file loads with ``load_scene(out)``."""
    from ..io.atomic import atomic_write_bytes
    from ..scene import scene_from_dict

    out = Path(out)
    check_apply_path(out, force)
    d = variant_dict(scene, p.chosen.solver, p.chosen.particle_radius, p.chosen.tolerance)
    d["plan"] = p.prediction()
    scene_from_dict(d, source=str(out), base_dir=out.parent)  # what is written loads again
    tol = "" if p.chosen.tolerance is None else f", tolerance {p.chosen.tolerance:.3g}"
    header = (f"# written by warp-sph plan from {scene.source}: {p.chosen.solver}, particle_radius "
              f"{p.chosen.particle_radius:.4g} m{tol}, predicted {duration_text(p.chosen.wall_time)} wall and "
              f"{100 * p.chosen.density_error:.3g} % mean density error on {p.machine}")
    atomic_write_bytes(out, toml_text(d, header).encode())
    return out


def run_command(args, log=print) -> int:
    """``warp-sph plan``: parse, calibrate (progress bar on stderr), print the table, the plot and --apply."""
    from ..scene import load_scene
    from . import plan as make_plan

    if args.budget is None and args.target_error is None:
        raise PlanError("plan: give --budget (e.g. 10m) or --target-error (e.g. 0.5%)")
    budget = parse_budget(args.budget) if args.budget is not None else None
    metric, target = parse_target(args.target_error) if args.target_error is not None else ("density", None)
    solvers = [s.strip() for s in args.solvers.split(",") if s.strip()] if args.solvers else None
    if args.apply:
        check_apply_path(Path(args.apply), args.force)
    check_plot_and_cache(args)
    scene = load_scene(args.scene, overrides=args.set)
    p = make_plan(scene, budget_s=budget, target_error=target, device=args.device, solvers=solvers,
                  cache=args.cache, refresh=args.refresh, progress=not args.no_progress, log=log, metric=metric)
    for line in table_lines(p):
        log(line)
    png = Path(args.plot) if args.plot else Path(p.cache_path).with_name(f"pareto-{_safe(p.scene)}.png")
    path = plot_pareto(p, png)
    log(f"Pareto front: {path}" if path else "Pareto plot skipped: matplotlib is not installed (the plots extra: "
        "pip install -e '.[plots]')")
    if args.apply:
        log(f"wrote {apply_scene(scene, p, Path(args.apply), force=args.force)}: warp-sph run {args.apply}")
    else:
        log("settings: warp-sph run " + args.scene + " " + " ".join(f"--set {f}" for f in set_flags(p)))
    return 0


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]", "_", name)
