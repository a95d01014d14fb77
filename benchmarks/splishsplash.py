"""Side by side with SPlisHSPlasH (the ``pysplishsplash`` wheel), optional.

The same dam break runs in both engines: the same box (the scene's container, its six faces as
Akinci 2012 boundary particles), the same fluid lattice (SPlisHSPlasH's block is placed so that its
particles land on warp-sph's sampled positions), the same particle radius, a fixed time step,
WCSPH (SPlisHSPlasH's stiffness and exponent set to warp-sph's equation of state) and PBF
(same iteration limits and target error), plus SPlisHSPlasH's DFSPH as a reference. The same
metrics are computed from the positions, velocities and densities each engine reports per frame.

Differences that remain (stated in the report): SPlisHSPlasH's particle mass is d^3 rho0 (d = 2r, the
lattice cell's volume; its driver records ``getMass(0)``), warp-sph's is calibrated so that a rest lattice
reads rho0 (1.00003 d^3 rho0 at r = 0.025 m: the report prints both from the records); SPlisHSPlasH samples the box walls with
its own surface sampler and places the fluid against them with its own gap; SPlisHSPlasH is Y-up
(coordinates are swapped on the way in and out); SPlisHSPlasH runs OpenMP with OMP_NUM_THREADS
threads, warp-sph's CPU backend runs each kernel on one thread.

``pysplishsplash`` 2.19 imports only with ``LD_PRELOAD=/lib/x86_64-linux-gnu/libGLdispatch.so.0``
(its GUI libraries), so each SPlisHSPlasH case runs in a subprocess with that environment:
``python splishsplash_driver.py CONFIG.json OUT.npz`` (``splishsplash_driver.py``, which imports no
Warp), started by ``splishsplash_case.py``. The scene file each case gives it is written by
``splishsplash_scene.py``. This module runs the comparisons: warp-sph's cases beside SPlisHSPlasH's.
"""
from __future__ import annotations

import math

import numpy as np

from .peak_memory import rss_ratio
from .splishsplash_case import available, run_splishsplash_case
from .splishsplash_scene import ADAPTIVE_CFL

#: Adaptive-step comparison (``run_adaptive``): SPlisHSPlasH's methods as users run them, each with its
#: own defaults (label, method, TimeStep parameters set beside the defaults). WCSPH's default
#: stiffness is for its example scenes' scale; 50,000 keeps the dam break at ~1 % compression.
#: DFSPH also runs with maxError 0.05 %, the value of its DamBreakModel.json scene.
ADAPTIVE_SPLISHSPLASH = (
    ("dfsph", "dfsph", {}),
    ("dfsph maxError=0.05", "dfsph", {"MAX_ERROR": 0.05}),
    ("iisph", "iisph", {}),
    ("pbf", "pbf", {}),
    ("wcsph stiffness=50000", "wcsph", {"STIFFNESS": 50000.0}),
)
#: the fixed-step comparison's solvers (``run_comparison``): wcsph and pbf in both engines, dfsph in SPlisHSPlasH
FIXED_STEP_SOLVERS = ("wcsph", "pbf", "dfsph")
#: (particle radius [m], simulated seconds) of the adaptive comparison: 6,859 and 59,319 fluid particles
ADAPTIVE_RESOLUTIONS = ((0.025, 1.0), (0.0125, 0.3))


def default_dt(model: dict, solver: str, particle_radius: float) -> float:
    """WCSPH: warp-sph's acoustic CFL bound at cfl 0.4 with the reference speed, 0.4 (H_s/2)/(c_s + v_ref);
    PBF and DFSPH: 2 ms at r = 0.025 m, scaled with r."""
    if solver == "wcsph":
        return 0.4 * 0.5 * model["support_radius"] / (model["speed_of_sound"] + model["reference_speed"])
    return 0.002 * particle_radius / 0.025


def run_comparison(particle_radius: float = 0.025, frames: int = 25, threads: int = 1,
                   solvers=FIXED_STEP_SOLVERS, dt: dict | None = None, device=None, isolate: bool = True,
                   skip_warp_sph: bool = False, scene: str = "dam_break", splishsplash_gap: float | None = None,
                   warp_sph_overrides: list[str] | None = None, repeats: int = 1, log=print) -> list[dict]:
    """Run the dam break in warp-sph (wcsph, pbf) and SPlisHSPlasH (wcsph, pbf, dfsph) with fixed steps.

    splishsplash_gap: None places SPlisHSPlasH's fluid on warp-sph's lattice (the same gap to the
    walls); a number moves its block so that the lattice sits that many spacings d from the walls it
    touches (SPlisHSPlasH's PBF blows up at t = 0 with fluid 1.1 d from its walls; 1.5 d is stable).
    warp_sph_overrides: scene overrides for warp-sph's runs only ("wcsph.*" keys for its WCSPH run,
    "pbf.*" keys for its PBF run, others for both); SPlisHSPlasH keeps the parameters (stiffness,
    time step) of the scene without them.
    repeats: runs of each engine's case of a solver, in turns (warp-sph, SPlisHSPlasH, warp-sph, ...), the
    fastest of each kept (``fastest_of``): one run's time on a 2-core VM scatters by 10-30 % (measured: WCSPH
    0.51x and 0.68x of SPlisHSPlasH's in two runs a minute apart on an idle machine).
    """
    import warp as wp

    from warp_sph.core.model import build_model
    from warp_sph.scene.sampling import sample_scene
    from warp_sph.scene import load_scene

    from .cases import RunSpec, run_specs

    sc = load_scene(scene, overrides=[f"particle_radius={particle_radius}"])
    sampled = sample_scene(sc)
    model, _ = build_model(sc, sampled, wp.get_device("cpu"))
    summary = model.summary()
    # WCSPH's stiffness as warp-sph's WCSPH derives it (warp_sph.methods.solvers.wcsph)
    eos = sc.wcsph.equation_of_state
    summary["equation_of_state"] = eos
    summary["stiffness"] = (float(sc.wcsph.stiffness) if sc.wcsph.stiffness > 0 else
                            model.rest_density * model.speed_of_sound * model.speed_of_sound / (7.0 if eos == "tait" else 1.0))
    fx = np.asarray(sampled.fluid_x, dtype=np.float64)
    fmin, fmax = fx.min(axis=0), fx.max(axis=0)
    if splishsplash_gap is not None and sc.container is not None:
        lo = np.asarray(sc.container.min, dtype=np.float64)
        gap = fmin - lo
        shift = np.where(gap < 2.0 * sc.spacing, np.maximum(0.0, splishsplash_gap * sc.spacing - gap), 0.0)
        fmin, fmax = fmin + shift, fmax + shift
    dt = {k: v for k, v in (dt or {}).items() if v}
    frame_dt = 1.0 / float(sc.fps)
    dts = {}
    for s in solvers:
        target = dt.get(s) or (dt.get("pbf") if s == "dfsph" else None) or default_dt(summary, s, particle_radius)
        # a whole number of steps per frame, so warp-sph's frame loop takes exactly this step too
        dts[s] = frame_dt / math.ceil(frame_dt / target - 1e-9)
    records = []
    ok, why = available()
    if not ok:
        log(f"SPlisHSPlasH: not run: {why}")
    from warp_sph.core.launch import cpu_threads

    from .records import print_row

    def ours(s):
        own = [o for o in warp_sph_overrides or () if o.split("=", 1)[0].split(".", 1)[0] not in
               ({"wcsph", "pbf"} - {s})]
        spec = RunSpec(scene=scene, overrides=[f"particle_radius={particle_radius}", f"solver={s}",
                                               f"time.fixed_dt={dts[s]}", *own],
                       frames=frames, device=device, kind="splishsplash", name="splishsplash",
                       params={"engine": "warp-sph", "solver": s, "dt": dts[s], "particle_radius": particle_radius,
                               **({"overrides": " ".join(own)} if own else {})})
        r = run_specs([spec], isolate=isolate, log=log)[0]
        r["label"] = f"warp-sph {s}" + (f" ({', '.join(own)})" if own else "")
        r["threads"] = cpu_threads()  # warp-sph splits particle-parallel CPU launches over these
        return r

    def theirs(s):
        log(f"SPlisHSPlasH {s} (dt {dts[s]:.3g} s, OMP_NUM_THREADS={threads})")
        r = run_splishsplash_case(sc.to_dict(), summary, fmin, fmax, s, dts[s], frames, threads)
        r["params"]["fluid_gap"] = "warp-sph" if splishsplash_gap is None else f"{splishsplash_gap:g} d"
        if splishsplash_gap is not None:
            r["label"] += f" (fluid {splishsplash_gap:g} d from the walls)"
        print_row(r, log)
        return r

    for s in solvers:
        runs = {"ours": [], "theirs": []}
        for k in range(repeats):
            if repeats > 1:
                log(f"{s}: repeat {k + 1} of {repeats}")
            if s in ("wcsph", "pbf") and not skip_warp_sph:
                runs["ours"].append(ours(s))
            runs["theirs"].append(theirs(s))
        for rs in runs.values():
            if rs:
                records.append(fastest_of(rs) if repeats > 1 else rs[0])
    return records


def run_adaptive(resolutions=ADAPTIVE_RESOLUTIONS, threads: int = 2, warp_sph_solvers=None,
                 splishsplash_cases=ADAPTIVE_SPLISHSPLASH, device=None, isolate: bool = True,
                 skip_warp_sph: bool = False, scene: str = "dam_break", warp_sph_overrides: list[str] | None = None,
                 repeats: int = 1, log=print) -> list[dict]:
    """The dam break with each engine's own adaptive step, as users run them: every registered warp-sph
    solver (or those of ``warp_sph_solvers``; an empty list runs none) with its defaults (the scene's CFL bound), and SPlisHSPlasH's methods (``splishsplash_cases``)
    with its CFL step (``ADAPTIVE_CFL``: cflMethod 1) and their defaults, at each (particle radius [m],
    simulated seconds) of ``resolutions``. Records carry wall and CPU seconds per simulated second and
    the mean density error (each engine's own densities at the frames, mean of max(rho/rho0 - 1, 0)).

    Like with like: the same box (Akinci 2012 wall particles in both), the same fluid lattice (the
    SPlisHSPlasH block is placed on warp-sph's sampled positions), the same radius and rest density.
    What differs is each engine's own convention for the mass: SPlisHSPlasH's is d^3 rho0 (d = 2r), warp-sph's
    is calibrated so that the lattice reads rho0 (the two agree to 3e-5 on this lattice; the records hold
    both: ``record["splishsplash"]["mass"]``, ``record["model"]["particle_mass"]``); each engine reports its
    error against its own rho0.
    threads: OMP_NUM_THREADS of SPlisHSPlasH; warp-sph splits kernels over WARP_SPH_CPU_THREADS (default:
    every core this process may use). repeats: runs of every case, in turns (all cases, then all again),
    the fastest of each kept (``fastest_of``): a 2-core VM's timings scatter by 10-40 % between runs.
    """
    import warp as wp

    from warp_sph.core.launch import cpu_threads
    from warp_sph.core.model import build_model
    from warp_sph.methods import registry
    from warp_sph.scene import load_scene
    from warp_sph.scene.sampling import sample_scene

    from .cases import RunSpec, run_specs
    from .records import print_row

    solvers = list(registry.solver_names() if warp_sph_solvers is None else warp_sph_solvers)
    records = []
    ok, why = available()
    if not ok:
        log(f"SPlisHSPlasH: not run: {why}")
    for radius, duration in resolutions:
        sc = load_scene(scene, overrides=[f"particle_radius={radius}"])
        frames = max(1, int(math.ceil(float(duration) * float(sc.fps) - 1e-9)))
        cases = []  # (key, run) of this resolution; each repeat runs them all in this order
        if not skip_warp_sph:
            for s in solvers:
                # a solver's section goes to that solver's run only; other keys to every run
                own = [o for o in warp_sph_overrides or () if o.split("=", 1)[0].split(".", 1)[0] not in
                       (set(registry.solver_names()) - {s})]
                spec = RunSpec(scene=scene, overrides=[f"particle_radius={radius}", f"solver={s}", *own],
                               frames=frames, device=device, kind="splishsplash", name="splishsplash",
                               params={"engine": "warp-sph", "solver": s, "mode": "adaptive", "case": s,
                                       "particle_radius": radius, **({"overrides": " ".join(own)} if own else {})})

                def run_ours(spec=spec, s=s, own=own):
                    r = run_specs([spec], isolate=isolate, log=log)[0]
                    r["label"] = f"warp-sph {s}" + (f" ({', '.join(own)})" if own else "")
                    r["threads"] = cpu_threads()
                    return r

                cases.append((f"warp-sph {s}", run_ours))
        sampled = sample_scene(sc)
        model, _ = build_model(sc, sampled, wp.get_device("cpu"))
        summary = model.summary()
        fx = np.asarray(sampled.fluid_x, dtype=np.float64)
        for label, method, values in splishsplash_cases:
            def run_ref(label=label, method=method, values=values):
                log(f"SPlisHSPlasH {label} (r = {radius} m, {frames} frames, CFL step, OMP_NUM_THREADS={threads})")
                r = run_splishsplash_case(sc.to_dict(), summary, fx.min(axis=0), fx.max(axis=0), method,
                                          ADAPTIVE_CFL["timeStepSize"], frames, threads, adaptive=True,
                                          time_step=dict(values), label=label)
                print_row(r, log)
                return r

            cases.append((f"splishsplash {label}", run_ref))
        runs: dict[str, list[dict]] = {}
        for k in range(max(1, int(repeats))):
            if repeats > 1:
                log(f"r = {radius} m: repeat {k + 1} of {repeats}")
            for key, run in cases:
                runs.setdefault(key, []).append(run())
        records += [fastest_of(rs) for rs in runs.values()]
    return records


def fastest_of(runs: list[dict]) -> dict:
    """The record of the fastest finished run of one case (wall seconds per simulated second; the first
    run when none finished), with every run's wall and CPU seconds per simulated second beside it
    (``repeat_wall_per_simulated_second``, ``repeat_cpu_per_simulated_second``)."""
    def metric(r, key):
        return (r.get("metrics") or {}).get(key)

    done = [r for r in runs if r.get("status") == "ok" and metric(r, "wall_per_simulated_second")]
    best = dict(min(done, key=lambda r: metric(r, "wall_per_simulated_second")) if done else runs[0])
    best["repeats"] = len(runs)
    best["repeat_wall_per_simulated_second"] = [metric(r, "wall_per_simulated_second") for r in runs]
    best["repeat_cpu_per_simulated_second"] = [metric(r, "cpu_per_simulated_second") for r in runs]
    return best


def adaptive_ratios(records: list[dict]) -> list[dict]:
    """Per resolution: warp-sph DFSPH against each SPlisHSPlasH DFSPH case of an adaptive comparison:
    the ratio of wall (and CPU) seconds per simulated second, of peak RSS per fluid particle (``rss_ratio``,
    None for records without it) and both mean density errors."""
    ok = [r for r in records if r.get("status") == "ok" and (r.get("params") or {}).get("mode") == "adaptive"]
    out = []
    for n in sorted({r.get("fluid_particles") for r in ok if r.get("engine") == "warp-sph"} - {None}):
        ours = [r for r in ok if r.get("engine") == "warp-sph" and r.get("fluid_particles") == n
                and (r.get("params") or {}).get("solver") == "dfsph"]
        if not ours:
            continue
        mo = ours[-1]["metrics"]
        for ref in ok:
            p = ref.get("params") or {}
            if ref.get("engine") != "splishsplash" or p.get("solver") != "dfsph":
                continue
            if abs((p.get("particle_radius") or 0) - (ours[-1]["params"].get("particle_radius") or 0)) > 1e-12:
                continue
            mr = ref["metrics"]
            row = {"fluid_particles": n, "case": p.get("case", "dfsph"), "threads": ref.get("threads"),
                   "ratio": mo["wall_per_simulated_second"] / mr["wall_per_simulated_second"],
                   "ours_error": mo.get("density_error_mean_avg"), "ref_error": mr.get("density_error_mean_avg")}
            if mo.get("cpu_per_simulated_second") and mr.get("cpu_per_simulated_second"):
                row["cpu_ratio"] = mo["cpu_per_simulated_second"] / mr["cpu_per_simulated_second"]
            row["rss_ratio"] = rss_ratio(mo, mr)  # peak RSS per fluid particle, each case in its own process
            out.append(row)
    return out
