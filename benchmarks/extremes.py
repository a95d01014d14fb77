"""``warp-sph bench extremes``: every solver at the extremes, and how each case ended (issue 36).

Families (each case x every registered solver; r = 0.05 m, short runs):
- ``dt``: the small dam break (0.8 x 0.6 x 0.8 m block in a 1.6 x 0.6 x 1.2 m box) at fixed steps 1e-6 ..
  1e-3 s and at the adaptive (CFL) step;
- ``drop``: a 0.4 m cube hitting the floor at the speed of a drop from 0.1 to 20 m (it starts 0.15 m above
  the floor with v = -sqrt(2 g h));
- ``viscosity``: the small dam break with explicit viscosity from water's 1e-6 to 100 m^2/s;
- ``stiffness`` (WCSPH's keys, WCSPH only): speed of sound 1000 m/s, stiffness 1e3 and 1e8 Pa, factor 3;
- ``body``: a 0.2 m box of density 1 .. 1e5 kg/m^3 dropped 0.1 m onto a 0.3 m pool;
- ``single``: one particle in free fall (no container), and one dropped 0.5 m into a box;
- ``scale``: the small dam break shrunk to 1 mm and grown to 1 km (r and the box scaled, fps by sqrt).

Each case ends ``completed``, ``stopped`` (the watchdog's SimulationError) or ``refused`` (a scene or
pre-flight error before any step); ``crashed`` is any other exception. Measured per case, independently of
the watchdog (host reads in float64): the energy drift (E - E(0)) / scale with E the fluid's kinetic +
potential energy plus the bodies' (the scale as the watchdog's: the initial energy counted from the floor),
its largest rise, the largest speed (fluid or body) against the physical bound (sqrt(|v0|^2 + 2 g H), H the
highest point above the floor; without a container the ballistic |v0| + g t), the largest density error and,
with bodies, the largest rise of a body's own energy above its initial value (a dropped body can not rise
above its release point). A case is **silent bad** when it completed although its energy rose by more than
1 % of the scale (beyond what its initial compression can release), its top speed exceeded twice the
bound, a body's energy rose by more than 5 % of its own, or a value turned non-finite; or when it stopped,
was refused or crashed without one clear line. Goal: 0 silent bad results.
"""
from __future__ import annotations

import math
import time
import traceback
import warnings
from dataclasses import asdict, dataclass, field

import numpy as np

from .records import SCHEMA, host_info, now
from .tables import invocation_heads

G = 9.81
#: allowed rise of the total energy [-] of the scale (the watchdog's ENERGY_GROWTH_LIMIT)
ENERGY_LIMIT = 0.01
#: allowed top speed against the physical bound [-]
SPEED_LIMIT = 2.0
#: allowed rise of a body's own energy [-] of its initial energy above the floor
BODY_LIMIT = 0.05
R = 0.05
#: the small dam break's box is 1.6 m long: these factors make it 1 mm and 1 km long
MM, KM = 1e-3 / 1.6, 1e3 / 1.6


@dataclass
class Case:
    """One extreme case: a scene (as a dict) run for ``frames`` frames."""

    family: str
    value: str            # the extreme, as text ("1e-05 s", "20 m", ...)
    solver: str
    scene: dict = field(default_factory=dict)
    frames: int = 4
    note: str = ""

    @property
    def label(self) -> str:
        return f"{self.family} {self.value} {self.solver}"


def _dam(solver: str, scale: float = 1.0, **extra) -> dict:
    s = scale
    d = {"name": "extreme_dam", "particle_radius": R * s, "fps": 30.0 / math.sqrt(s), "solver": solver,
         "output": {"usd": False, "surface": False},
         "container": {"min": [0.0, 0.0, 0.0], "max": [1.6 * s, 0.6 * s, 1.2 * s]},
         "fluid": [{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.8 * s, 0.6 * s, 0.8 * s]}]}
    for k, v in extra.items():
        d[k] = {**d.get(k, {}), **v} if isinstance(v, dict) else v
    return d


def _drop(solver: str, height: float) -> dict:
    v = math.sqrt(2.0 * G * height)
    return {"name": "extreme_drop", "particle_radius": R, "fps": 30.0, "solver": solver,
            "output": {"usd": False, "surface": False},
            "container": {"min": [0.0, 0.0, 0.0], "max": [1.2, 1.2, 1.0]},
            "fluid": [{"shape": "box", "min": [0.4, 0.4, 0.15], "max": [0.8, 0.8, 0.55], "velocity": [0.0, 0.0, -v]}]}


def _body(solver: str, density: float) -> dict:
    return {"name": "extreme_body", "particle_radius": R, "fps": 24.0, "solver": solver,
            "output": {"usd": False, "surface": False},
            "container": {"min": [0.0, 0.0, 0.0], "max": [0.8, 0.8, 0.8]},
            "fluid": [{"shape": "box", "min": [0.0, 0.0, 0.0], "max": [0.8, 0.8, 0.3]}],
            "bodies": [{"name": "box", "shape": "box", "size": [0.2, 0.2, 0.2], "density": density,
                        "position": [0.4, 0.4, 0.5]}]}


def _single(solver: str, contained: bool) -> dict:
    d = {"name": "extreme_single", "particle_radius": R, "fps": 30.0, "solver": solver,
         "output": {"usd": False, "surface": False},
         "fluid": [{"shape": "box", "min": [0.2, 0.2, 0.5], "max": [0.3, 0.3, 0.6]}]}
    if contained:
        d["container"] = {"min": [0.0, 0.0, 0.0], "max": [0.5, 0.5, 0.7]}
    else:
        d["container"] = False
    return d


def extreme_cases(solvers=None, quick: bool = False) -> list[Case]:
    """Every case of the bench (``quick``: a handful, for the test suite)."""
    from .records import solver_names

    solvers = list(solvers or solver_names())
    cases: list[Case] = []
    if quick:
        for s in solvers:
            cases.append(Case("dt", "1e-05 s", s, _dam(s, time={"fixed_dt": 1e-5}, fps=1000.0), frames=1))
            cases.append(Case("single", "free fall", s, _single(s, False), frames=3))
        cases.append(Case("body", "1 kg/m^3", solvers[-1], _body(solvers[-1], 1.0), frames=6))
        cases.append(Case("scale", "1 km", solvers[0], _dam(solvers[0], KM), frames=2))
        return cases
    for s in solvers:
        for dt in (1e-6, 1e-5, 1e-4, 1e-3):
            # fps 200 for the small steps: 5 ms frames, 5000 steps of 1e-6 s
            fps = 200.0 if dt < 1e-4 else 30.0
            cases.append(Case("dt", f"{dt:g} s", s, _dam(s, time={"fixed_dt": dt}, fps=fps), frames=2 if dt < 1e-4 else 4))
        cases.append(Case("dt", "CFL", s, _dam(s), frames=8))
        for h in (0.1, 1.0, 5.0, 20.0):
            cases.append(Case("drop", f"{h:g} m", s, _drop(s, h), frames=8))
        for nu in (1e-6, 1e-2, 1.0, 100.0):
            cases.append(Case("viscosity", f"{nu:g} m^2/s", s, _dam(s, material={"viscosity": nu}, fps=200.0),
                              frames=3))
        for rho in (1.0, 10.0, 100.0, 200.0, 1e3, 1e4, 1e5):
            cases.append(Case("body", f"{rho:g} kg/m^3", s, _body(s, rho), frames=12))
        cases.append(Case("single", "free fall", s, _single(s, False), frames=6))
        cases.append(Case("single", "in a box", s, _single(s, True), frames=12))
        cases.append(Case("scale", "1 mm", s, _dam(s, MM), frames=6))
        cases.append(Case("scale", "1 km", s, _dam(s, KM), frames=6))
    if "wcsph" in solvers:
        for value, section in (("speed_of_sound 1000 m/s", {"speed_of_sound": 1000.0}),
                               ("stiffness 1e8 Pa", {"stiffness": 1e8}), ("stiffness 1e3 Pa", {"stiffness": 1e3}),
                               ("speed_of_sound_factor 3", {"speed_of_sound_factor": 3.0})):
            cases.append(Case("stiffness", value, "wcsph", _dam("wcsph", wcsph=section), frames=4))
    return cases


# --------------------------------------------------------------------------------------------
# one case
# --------------------------------------------------------------------------------------------
def _floor_and_top(sim) -> tuple[float | None, float]:
    """(floor height, highest initial point) along up [m], local coordinates; floor None without gravity."""
    m = sim.model
    g = np.asarray(m.gravity, dtype=np.float64)
    gn = float(np.linalg.norm(g))
    if gn == 0:
        return None, 0.0
    up = -g / gn
    h = sim.fields["particle_x"].numpy().astype(np.float64) @ up
    if sim.bodies is not None and m.boundary_count > m.static_boundary_count:
        h = np.concatenate([h, m.boundary_x.numpy()[m.static_boundary_count:].astype(np.float64) @ up])
    if m.container_lo is not None:
        lo, hi = np.asarray(m.container_lo, float), np.asarray(m.container_hi, float)
        floor = min(float(np.array([a, b, c]) @ up) for a in (lo[0], hi[0]) for b in (lo[1], hi[1])
                    for c in (lo[2], hi[2]))
    else:
        floor = float(h.min())
    return floor, float(h.max())


def _energies(sim) -> tuple[float, np.ndarray]:
    """(fluid kinetic + potential + bodies' energy [J], per-body energy [J]), float64 from host copies."""
    m = sim.model
    x = sim.fields["particle_x"].numpy().astype(np.float64)
    v = sim.fields["particle_v"].numpy().astype(np.float64)
    g = np.asarray(m.gravity, dtype=np.float64)
    e = 0.5 * m.particle_mass * float((v * v).sum()) - m.particle_mass * float((x @ g).sum())
    bodies = np.zeros(0)
    if sim.bodies is not None:
        k, p = sim.bodies.energy()
        bodies = k + p
    return e + float(bodies.sum()), bodies


def run_case(case: Case, device=None) -> dict:
    """Run one case in this process; never raises. The record's ``status`` is completed / stopped / refused /
    crashed, ``error`` the one line it stopped with, ``metrics`` what was measured, ``bad`` the verdict."""
    from warp_sph.core.errors import SimulationError, WarpSphError
    from warp_sph.run.preflight import preflight_checks
    from warp_sph.run.simulation import Simulation
    from warp_sph.scene import scene_from_dict

    rec = {"schema": SCHEMA, "kind": "extremes", "name": "extremes", "engine": "warp-sph", "label": case.label,
           "params": {"family": case.family, "value": case.value, "solver": case.solver},
           "case": asdict(case), "date": now(), "host": host_info(), "status": "crashed", "metrics": {}}
    t0 = time.perf_counter()
    met = rec["metrics"]
    try:
        try:
            scene = scene_from_dict(case.scene, source=f"extremes[{case.label}]")
            sim = Simulation(scene, device=device)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                preflight_checks(scene, sim)
            sim.check_health(sim.statistics())
        except WarpSphError as e:
            rec.update(status="refused", error=str(e))
            return _finish(rec, t0)
        m = sim.model
        rec["fluid_particles"] = m.fluid_count
        floor, top = _floor_and_top(sim)
        v0 = float(np.linalg.norm(sim.fields["particle_v"].numpy(), axis=1).max())
        if sim.bodies is not None:
            v0 = max(v0, sim.bodies.max_speed())
        gn = float(np.linalg.norm(m.gravity))
        e0, b0 = _energies(sim)
        scale = sim.watchdog.energy.scale
        allowance = sim.watchdog.energy.allowance
        body_scale = None
        if sim.bodies is not None:
            masses = np.asarray(sim.bodies.world.masses, dtype=np.float64)
            q = sim.bodies.world.body_q.numpy().astype(np.float64)
            up = -np.asarray(m.gravity, float) / max(gn, 1e-30)
            # each body's own energy counted from the floor: what it holds to give
            body_scale = b0 - masses * gn * (floor if floor is not None else (q[:, :3] @ up).min())
        met.update(scale=scale, allowance=allowance, frames=0, energy_rise_max=0.0, energy_drift=0.0,
                   max_speed=v0, density_error_max=0.0, body_rise_max=0.0 if body_scale is not None else None)
        stats = None
        try:
            for _ in range(case.frames):
                stats = sim.advance_frame()
                sim.check_health(stats)
                e, b = _energies(sim)
                drift = (e - e0) / scale
                met["frames"] += 1
                met["energy_drift"] = drift
                met["energy_rise_max"] = max(met["energy_rise_max"], drift) if math.isfinite(drift) else math.inf
                met["max_speed"] = max(met["max_speed"], stats.max_speed, stats.body_speed)
                met["density_error_max"] = max(met["density_error_max"], stats.density_error_max)
                if body_scale is not None:
                    rise = float(np.max((b - b0) / np.maximum(body_scale, 1e-30)))
                    met["body_rise_max"] = max(met["body_rise_max"], rise)
            rec["status"] = "completed"
        except SimulationError as e:
            rec.update(status="stopped", error=str(e))
        t_end = float(sim.state.time)
        if m.container_lo is not None and floor is not None:
            bound = math.sqrt(v0 * v0 + 2.0 * gn * max(top - floor, 0.0))
        else:
            bound = v0 + gn * t_end
        met.update(speed_bound=bound, speed_ratio=met["max_speed"] / bound if bound > 0 else None,
                   simulated_seconds=t_end, steps=int(sim.state.step), energy_limit=ENERGY_LIMIT + allowance / scale)
    except Exception as e:  # noqa: BLE001 - a crash is a result of the bench
        rec.update(status="crashed", error=f"{type(e).__name__}: {e}", traceback=traceback.format_exc(limit=8))
    return _finish(rec, t0)


def _finish(rec: dict, t0: float) -> dict:
    rec["metrics"]["wall_seconds"] = time.perf_counter() - t0
    rec["verdict"] = verdict(rec)
    rec["bad"] = rec["verdict"] != "ok"
    from .metrics import nan_to_none

    return nan_to_none(rec)


def verdict(rec: dict) -> str:
    """"ok", or why the case is a silent bad result (see the module docstring)."""
    status = rec.get("status")
    err = str(rec.get("error") or "")
    if status in ("stopped", "refused"):
        return "ok" if err.strip() and "\n" not in err.strip() else f"{status} without one clear line"
    if status != "completed":
        return f"crashed: {err.splitlines()[0] if err else '?'}"
    m = rec.get("metrics") or {}
    why = []
    rise, limit = m.get("energy_rise_max"), m.get("energy_limit", ENERGY_LIMIT)
    if rise is None or not rise <= limit:
        why.append(f"energy rose {100 * rise:.3g} % of the scale" if rise is not None else "energy not finite")
    ratio = m.get("speed_ratio")
    if ratio is None or not ratio <= SPEED_LIMIT:
        why.append(f"top speed {ratio:.3g}x the physical bound" if ratio is not None else "speed not finite")
    body = m.get("body_rise_max")
    if body is not None and not body <= BODY_LIMIT:
        why.append(f"a body's energy rose {100 * body:.3g} % of its own")
    return "silent bad: " + "; ".join(why) if why else "ok"


def run_cases(cases: list[Case], device=None, log=print) -> list[dict]:
    out = []
    for k, c in enumerate(cases):
        r = run_case(c, device=device)
        m = r["metrics"]
        log(f"[{k + 1}/{len(cases)}] {c.label}: {r['status']}, {r['verdict']} ({m.get('wall_seconds', 0):.1f} s)"
            + (f": {r['error'][:160]}" if r.get("error") else ""))
        out.append(r)
    return out


# --------------------------------------------------------------------------------------------
# report
# --------------------------------------------------------------------------------------------
def latest_per_case(records: list[dict]) -> list[dict]:
    """The latest record of each case (family, extreme, solver), in the order of first appearance: the bench
    may be run in parts (``--solvers``, ``--families``) and a part re-run."""
    best: dict[str, dict] = {}
    for r in records:
        k, when = r.get("label"), r.get("invocation", r.get("date", ""))
        if k not in best or when >= best[k].get("invocation", best[k].get("date", "")):
            best[k] = r
    return list(best.values())


def section(records: list[dict], fmt, head) -> list[str]:
    """Markdown of the latest record of each case (``latest_per_case``): one row per case, then the silent bad
    results."""
    records = latest_per_case(records)
    if not records:
        return []
    bad = [r for r in records if r.get("bad")]
    counts: dict[str, int] = {}
    for r in records:
        counts[r.get("status", "?")] = counts.get(r.get("status", "?"), 0) + 1
    lines = ["## Extremes: every solver at the extremes", ""]
    lines += invocation_heads(records, head)
    lines += [f"{len(records)} cases: " + ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
              + f"; **{len(bad)} silent bad** (goal 0). *energy* is (E − E(0)) / scale, E the fluid's kinetic + "
              "potential energy plus the bodies', the scale the initial energy counted from the floor (its largest "
              "rise and its last value); *speed / bound* the top speed (fluid or body) against sqrt(|v0|² + 2 g H) "
              "(without a container |v0| + g t); *body rise* the largest rise of a body's own energy; a completed "
              f"case is bad above {100 * ENERGY_LIMIT:g} % energy rise (beyond what the start's compression can "
              f"release), {SPEED_LIMIT:g}x the speed bound or a {100 * BODY_LIMIT:g} % body rise "
              "(benchmarks/extremes.py).", ""]
    header = ["family", "extreme", "solver", "ended", "verdict", "frames", "energy rise max %", "energy end %",
              "speed / bound", "max ρ err %", "body rise %", "wall s", "reason"]
    rows = []
    for r in records:
        p, m = r.get("params") or {}, r.get("metrics") or {}
        why = str(r.get("error") or "").strip().splitlines()
        why = why[0] if why else ""
        rows.append([p.get("family", "?"), p.get("value", "?"), p.get("solver", "?"), r.get("status", "?"),
                     "ok" if not r.get("bad") else "**bad**", fmt(m.get("frames")), fmt(m.get("energy_rise_max"), 100),
                     fmt(m.get("energy_drift"), 100), fmt(m.get("speed_ratio")), fmt(m.get("density_error_max"), 100),
                     fmt(m.get("body_rise_max"), 100), fmt(m.get("wall_seconds")),
                     (why[:140] + ("…" if len(why) > 140 else "")).replace("|", "\\|")])
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
    if bad:
        lines += ["Silent bad results:", ""]
        lines += [f"- `{r.get('label')}`: {r.get('verdict')}" for r in bad] + [""]
    return lines
