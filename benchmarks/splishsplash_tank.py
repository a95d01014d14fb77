"""The hydrostatic tank at rest in SPlisHSPlasH beside warp-sph (issue #31): mean |v| and rms speed per 0.25 s.

``python -m benchmarks.splishsplash_tank --radii 0.025,0.0125 --solvers dfsph,wcsph,pbf``

The case is ``scenes/validation/hydrostatic_probes.toml`` (0.6 x 0.6 x 0.5 m of water filling its tank, 2 s).
warp-sph runs it through the validation bench's own ``run_one`` (every solver at its defaults, the scene's damping);
SPlisHSPlasH 2.19 runs each of its solvers at its own defaults with its CFL step (``ADAPTIVE_CFL``), Akinci 2012
walls, on the same fluid lattice (``splishsplash_scene.scene_json``, the same translation as ``bench splishsplash``).

Viscosity: warp-sph's ``material.viscosity`` is SPlisHSPlasH's "Standard" form (kinematic [m^2/s]), so it maps to
viscosityMethod 1 with the same value; SPlisHSPlasH takes one viscosity method per material, so warp-sph's
``material.xsph`` has no counterpart and is left out (its XSPH method, 2, would replace the Standard viscosity).

Walls: SPlisHSPlasH's wall surface r from the first particles' centres (warp-sph's ``container.inner``) throws the
water to the lid, so its box stands ``gap`` d from the outer particles' centres: the first of ``GAPS`` that the run
survives (finite, mean |v| below ``SURVIVE_SPEED`` at every sample) is kept; the slack, gap - 1 d per wall, is in
the record. One JSON line per run to ``<out>/splishsplash_tank.jsonl``.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .splishsplash_case import _env, available
from .splishsplash_scene import ADAPTIVE_CFL, box_obj_text, from_y_up, scene_json, to_y_up

#: wall gaps tried, in spacings d from the outer particles' centres to SPlisHSPlasH's wall surface (1 d: the
#: wall particles continue the lattice; above it, gap - 1 d of slack per wall)
GAPS = (1.0, 1.25, 1.5)
#: a run that exceeds this mean |v| [m/s] at any sample did not survive (the too-close walls throw the water to
#: the lid at 0.7 m/s; the damped tank stays below 0.05)
SURVIVE_SPEED = 0.1
#: the sampling interval [s] of the speed series
SAMPLE = 0.25
#: SPlisHSPlasH's viscosityMethod code of its Standard viscosity
VISCOSITY_STANDARD = 1
DRIVER = Path(__file__).with_name("splishsplash_driver.py")


def tank_scene(radius: float):
    """The hydrostatic case's scene at ``radius`` [m] (the validation bench's loader)."""
    from warp_sph.validation.cases import CASES, load_case_scene

    return load_case_scene(CASES["hydrostatic"], "dfsph", radius)


def speed_series(t, v) -> dict:
    """{"time", "mean_speed", "rms_speed"} of frames ``t`` [s] with velocities ``v`` (frames, n, 3) [m/s]."""
    speeds = [np.linalg.norm(np.asarray(vk, dtype=np.float64), axis=1) for vk in v]
    return {"time": [float(x) for x in t], "mean_speed": [float(s.mean()) for s in speeds],
            "rms_speed": [float(math.sqrt(np.mean(s * s))) for s in speeds]}


def survived(series: dict) -> bool:
    m = series.get("mean_speed") or []
    return bool(m) and all(math.isfinite(x) and x < SURVIVE_SPEED for x in m)


def splishsplash_files(sc, solver: str, gap: float, folder: Path, duration: float) -> Path:
    """Write SPlisHSPlasH's box, scene and driver config for the tank ``sc`` into ``folder``; return the config.

    The box's walls and floor stand gap d from the outer particles' centres of warp-sph's sampled lattice (the
    fluid block); its lid is the scene container's top."""
    from warp_sph.scene.sampling import sample_scene

    r = float(sc.particle_radius)
    d = 2.0 * r
    fx = np.asarray(sample_scene(sc).fluid_x, dtype=np.float64)
    lo = fx.min(axis=0) - gap * d
    hi = fx.max(axis=0) + gap * d
    hi[2] = max(float(sc.container.max[2]), hi[2])
    folder.mkdir(parents=True, exist_ok=True)
    box = folder / "box.obj"
    box.write_text(box_obj_text(to_y_up(lo), to_y_up(hi)))
    sj = scene_json(sc.to_dict(), {}, fx.min(axis=0), fx.max(axis=0), solver, ADAPTIVE_CFL["timeStepSize"], str(box),
                    adaptive=True, time_step={})
    nu = float(sc.material.viscosity)
    if nu > 0.0:
        sj["Materials"][0].update(viscosityMethod=VISCOSITY_STANDARD, viscosity=nu, viscosityBoundary=0.0)
    (folder / "scene.json").write_text(json.dumps(sj, indent=1))
    cfg = {"scene_file": str(folder / "scene.json"), "output_dir": str(folder / "out"), "fps": 1.0 / SAMPLE,
           "frames": int(round(duration / SAMPLE)), "dt": ADAPTIVE_CFL["timeStepSize"], "time_step": {}}
    (folder / "config.json").write_text(json.dumps(cfg))
    return folder / "config.json"


def run_splishsplash(sc, solver: str, gap: float, threads: int, folder: Path, duration: float) -> dict:
    """One SPlisHSPlasH run of the tank (``splishsplash_files``) through its driver; the record."""
    r = float(sc.particle_radius)
    rec = {"engine": "splishsplash", "solver": solver, "particle_radius": r, "gap_d": gap, "slack_d": gap - 1.0,
           "threads": threads, "status": "failed",
           "viscosity": {"method": "standard" if float(sc.material.viscosity) > 0 else "none",
                         "value": float(sc.material.viscosity), "xsph": "not mapped"}}
    cfg = splishsplash_files(sc, solver, gap, folder, duration)
    out = folder / "out.npz"
    c0 = time.perf_counter()
    proc = subprocess.run([sys.executable, str(DRIVER), str(cfg), str(out)], capture_output=True, text=True,
                          env=_env(threads))
    rec["wall_time"] = time.perf_counter() - c0
    if proc.returncode or not out.exists():
        tail = (proc.stderr or proc.stdout).strip().splitlines()
        rec["error"] = tail[-1] if tail else f"exit status {proc.returncode}"
        return rec
    data = np.load(out)
    info = json.loads(str(data["info"]))
    v = [from_y_up(vk) for vk in data["v"]]
    rec.update(status="completed", fluid_particles=info["fluid_particles"],
               boundary_particles=info.get("boundary_particles"), steps=info["steps"],
               cpu_time=info.get("cpu_seconds"), series=speed_series(data["t"], v))
    rec["survived"] = survived(rec["series"])
    return rec


def run_splishsplash_tank(sc, solver: str, threads: int, folder: Path, duration: float, gaps=GAPS, log=print) -> dict:
    """SPlisHSPlasH's ``solver`` on the tank at the smallest of ``gaps`` it survives (the last tried when none);
    the record lists every gap tried and whether it survived (``gaps_tried``)."""
    tried, rec = [], None
    for gap in gaps:
        rec = run_splishsplash(sc, solver, gap, threads, folder / f"{solver}-gap{gap:g}", duration)
        ok = rec["status"] == "completed" and rec["survived"]
        s = rec.get("series") or {}
        tried.append({"gap_d": gap, "survived": ok, "max_mean_speed": max(s.get("mean_speed") or [float("nan")])})
        log(f"  SPlisHSPlasH {solver} r = {sc.particle_radius:g} m, gap {gap:g} d: "
            + (f"{'survived' if ok else 'did not survive'}, mean |v| at {s['time'][-1]:.2f} s {s['mean_speed'][-1]:.2e} m/s"
               if s else rec.get("error", "failed")))
        if ok:
            break
    rec["gaps_tried"] = tried
    return rec


def warp_sph_series(folder: Path) -> dict:
    """warp-sph's speed series every ``SAMPLE`` s from its run folder's frames (frames/*.npz velocities); without
    them the rms speed from run.json's kinetic energies (mean |v| then missing)."""
    frames = sorted(Path(folder).glob("frames/frame_*.npz"))
    t, v = [], []
    for f in frames:
        z = np.load(f)
        tk = float(z["time"])
        if abs(tk / SAMPLE - round(tk / SAMPLE)) < 1e-6:
            t.append(tk)
            v.append(z["v"])
    if t:
        return speed_series(t, v)
    info = json.loads((Path(folder) / "run.json").read_text())
    mass = float(info["model"]["particle_mass"]) * float(info["fluid_particles"])
    keep = [f for f in info.get("frames") or [] if abs(f["time"] / SAMPLE - round(f["time"] / SAMPLE)) < 1e-6]
    return {"time": [f["time"] for f in keep], "mean_speed": None,
            "rms_speed": [math.sqrt(2.0 * f["kinetic_energy"] / mass) for f in keep]}


def run_warp_sph(solver: str, radius: float, out_root: Path, log=print) -> dict:
    """warp-sph's run of the case (``benchmarks.validation.run_one``) with its speed series."""
    from warp_sph.validation.cases import CASES

    from .validation import run_one

    v = run_one(CASES["hydrostatic"], solver, f"r={radius:g}", out_root, radius=radius, log=log)
    rec = {"engine": "warp-sph", "solver": solver, "particle_radius": radius, "status": v["status"],
           "fluid_particles": v.get("fluid_particles"), "steps": v.get("steps"), "cpu_time": v.get("cpu_time"),
           "mean_speed_final": (v.get("figures") or {}).get("mean_speed_final"), "rms_speed_final": v.get("rms_speed_final")}
    if v.get("error"):
        rec["error"] = v["error"]
    if v.get("out"):
        rec["series"] = warp_sph_series(Path(v["out"]))
    return rec


def main(argv=None) -> int:
    from warp_sph.core.errors import WarpSphError

    p = argparse.ArgumentParser(prog="python -m benchmarks.splishsplash_tank", description=__doc__.split("\n")[0])
    p.add_argument("--radii", default="0.025,0.0125", help="particle radii [m], comma-separated")
    p.add_argument("--solvers", default="dfsph,wcsph,pbf", help="solvers of both engines, comma-separated")
    p.add_argument("--gaps", default=",".join(f"{g:g}" for g in GAPS),
                   help="SPlisHSPlasH wall gaps to try, in d, smallest first")
    p.add_argument("--threads", type=int, default=1, help="OMP_NUM_THREADS of SPlisHSPlasH (default 1)")
    p.add_argument("--out", default=str(Path("benchmarks") / "results"), help="folder of splishsplash_tank.jsonl")
    p.add_argument("--runs", default=None, help="folder of the run folders (default: a temporary folder)")
    p.add_argument("--skip-warp-sph", action="store_true", help="run only SPlisHSPlasH")
    a = p.parse_args(argv)
    try:
        radii = [float(x) for x in a.radii.split(",") if x.strip()]
        gaps = [float(x) for x in a.gaps.split(",") if x.strip()]
    except ValueError:
        print(f"splishsplash_tank: --radii {a.radii!r} / --gaps {a.gaps!r}: expected comma-separated numbers",
              file=sys.stderr)
        return 2
    solvers = [s.strip() for s in a.solvers.split(",") if s.strip()]
    bad = [s for s in solvers if s not in ("dfsph", "wcsph", "pbf")]
    if bad or not radii or min(radii) <= 0 or not gaps or min(gaps) <= 0:
        print(f"splishsplash_tank: --solvers {a.solvers!r} / --radii {a.radii!r} / --gaps {a.gaps!r}: expected "
              "solvers among dfsph, wcsph, pbf and positive radii and gaps", file=sys.stderr)
        return 2
    try:
        scenes = {r: tank_scene(r) for r in radii}
    except WarpSphError as e:
        print(str(e), file=sys.stderr)
        return 2
    ok, why = available()
    if not ok:
        print(f"SPlisHSPlasH: not run: {why}")
    from .records import SCHEMA

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    command = "python -m benchmarks.splishsplash_tank " + " ".join(sys.argv[1:] if argv is None else argv)
    with tempfile.TemporaryDirectory(prefix="ssh_tank_") as tmp:
        root = Path(a.runs or tmp)
        for r, sc in scenes.items():
            duration = float(sc.duration)
            for s in solvers:
                recs = []
                if not a.skip_warp_sph:
                    recs.append(run_warp_sph(s, r, root / "warp-sph"))
                if ok:
                    recs.append(run_splishsplash_tank(sc, s, a.threads, root / "splishsplash" / f"r{r:g}", duration, gaps))
                for rec in recs:
                    rec.update(schema=SCHEMA, kind="splishsplash_tank", command=command,
                               load_average=list(os.getloadavg()),
                               date=time.strftime("%Y-%m-%dT%H:%M:%S+00:00", time.gmtime()))
                    with open(out / "splishsplash_tank.jsonl", "a") as f:
                        f.write(json.dumps(rec) + "\n")
                    print(table_row(rec))
    return 0


def table_row(rec: dict) -> str:
    """One markdown row: engine, solver, r, gap, mean |v| and rms speed at every sample."""
    s = rec.get("series") or {}
    mean = s.get("mean_speed") or [None] * len(s.get("time") or [])
    cells = [f"{m:.1e} / {q:.1e}" if m is not None else f"- / {q:.1e}" for m, q in zip(mean, s.get("rms_speed") or [])]
    gap = f"{rec['gap_d']:g} d" if "gap_d" in rec else "-"
    return f"| {rec['engine']} | {rec['solver']} | {rec['particle_radius']:g} | {gap} | {rec['status']} | " + " | ".join(cells) + " |"


if __name__ == "__main__":
    sys.exit(main())
