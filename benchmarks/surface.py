"""Surface reconstruction speed (``warp-sph bench surface``): warp-sph and splashsurf on the same
particles, cell size and thread count, in the same run.

Particles: the dam break at ``time`` [s] for each particle radius. For every cell size and thread
count, three warp-sph variants and, when ``pysplashsurf`` is installed, two splashsurf ones:

- ``raw``: warp-sph's spray split + narrow band + field + marching cubes, no post-processing;
  splashsurf's ``reconstruct_surface`` (its density and field, marching cubes);
- ``pipeline``: raw plus 25 feature-weighted smoothing steps, vertex normals and 10 normal smoothing
  steps on both sides (splashsurf: ``reconstruction_pipeline`` with mesh cleanup, the smoothing
  weights and the same iteration counts; warp-sph restores the volume after smoothing);
- ``default`` (warp-sph only, once per thread count): the run's default settings (the scene's cell
  size, smoothing, decimation and normals).

Both use the same kernel support (splashsurf's smoothing_length l = R / 2r) and iso level 0.6.
splashsurf runs in a subprocess per thread count (``RAYON_NUM_THREADS`` is read once per
process); warp-sph sets ``WARP_SPH_CPU_THREADS``. Times are the median of ``repeats`` warm calls.
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SPLASHSURF_SMOOTHING_ITERATIONS = 25
SPLASHSURF_NORMAL_ITERATIONS = 10
ISO_LEVEL = 0.6


def particles_at(radius: float, t: float, device=None):
    """The dam-break Simulation advanced to time t [s] (positions in its local frame)."""
    from warp_sph.run.simulation import Simulation
    from warp_sph.scene import load_scene

    scene = load_scene("dam_break", [f"particle_radius={radius}", "output.usd=false", "output.surface=false"])
    sim = Simulation(scene, device=device)
    while sim.state.time < t - 1e-9:
        sim.advance_frame()
    return sim


def _time_warp_sph(sim, cell_per_radius: float, variant: str, threads: int, repeats: int) -> dict:
    import warp as wp

    from warp_sph.surface import SurfaceReconstructor, surface_settings
    from warp_sph.surface.reconstruction import STAGES

    m = sim.model
    r = m.particle_radius
    if variant == "default":
        kw = surface_settings(sim.scene.output, r)
    else:
        kw = dict(cell_size=cell_per_radius * r, iso_level=ISO_LEVEL, decimation=None,
                  smoothing_iterations=SPLASHSURF_SMOOTHING_ITERATIONS if variant == "pipeline" else 0,
                  normal_smoothing_iterations=SPLASHSURF_NORMAL_ITERATIONS, normals=variant == "pipeline")
    rec = SurfaceReconstructor(m.smoothing.name, m.smoothing_length, r, device=sim.device, **kw)
    x = wp.clone(sim.fields["particle_x"])
    old = os.environ.get("WARP_SPH_CPU_THREADS")
    os.environ["WARP_SPH_CPU_THREADS"] = str(threads)
    try:
        rec.reconstruct(x)  # compile, load and size the buffers
        times, stages, frame = [], [], None
        for _ in range(repeats):
            wp.synchronize_device(sim.device)
            t0 = time.perf_counter()
            frame = rec.reconstruct(x)
            times.append(1e3 * (time.perf_counter() - t0))
            stages.append(frame.timings)
    finally:
        if old is None:
            os.environ.pop("WARP_SPH_CPU_THREADS", None)
        else:
            os.environ["WARP_SPH_CPU_THREADS"] = old
    stage_ms = {s: 1e3 * statistics.median(t.get(s, 0.0) for t in stages) for s in STAGES}
    usd = _time_usd_write(sim, frame, repeats) if variant == "default" else {}
    return {"engine": "warp-sph", "ms": statistics.median(times), "ms_all": times, "stage_ms": stage_ms, **usd,
            "vertices": len(frame.vertices), "triangles": len(frame.triangles), "spray": int(frame.spray.sum()),
            "band_fallback": frame.stats.get("band_fallback", 0), "band_blocks": frame.stats.get("band_blocks"),
            "meshed_blocks": frame.stats.get("meshed_blocks"), "block_nodes": frame.stats.get("block_nodes")}


def _time_usd_write(sim, frame, repeats: int) -> dict:
    """USD write of one frame (particles, surface with normals, spray) as the run writes it: median
    time [ms] and bytes (each repeat writes the next frame of a new file)."""
    from warp_sph.io.export_usd import UsdWriter

    m = sim.model
    x = m.to_world(sim.fields["particle_x"].numpy()).astype(np.float32)
    v = sim.fields["particle_v"].numpy()
    rho = sim.fields["particle_density"].numpy()
    verts = m.to_world(frame.vertices).astype(np.float32)
    times, sizes = [], []
    with tempfile.TemporaryDirectory() as tmp:
        with UsdWriter(Path(tmp) / "bench.usdc", fps=sim.scene.fps, particle_radius=m.particle_radius,
                       with_normals=True, with_spray=True) as writer:
            for f in range(1, repeats + 2):
                writer.write_frame(f, x, v, {"density": rho}, (verts, frame.triangles, frame.normals),
                                   spray=(x[frame.spray], v[frame.spray]))
            times, sizes = writer.write_seconds[1:], writer.frame_bytes[1:]  # frame 1 also creates the file
    return {"usd_write_ms": 1e3 * statistics.median(times), "usd_bytes_per_frame": int(statistics.median(sizes))}


def _splashsurf_driver(args: list[str]) -> int:
    """Subprocess entry: ``_splashsurf PARTICLES.npz THREADS CELL REPEATS``; prints one JSON line per
    variant. RAYON_NUM_THREADS is set by the parent before this process imports pysplashsurf."""
    import pysplashsurf as ps

    data = np.load(args[0])
    x = np.ascontiguousarray(data["x"], dtype=np.float32)
    r, support = float(data["radius"]), float(data["support_radius"])
    cell, repeats = float(args[2]), int(args[3])
    common = dict(particle_radius=r, smoothing_length=support / (2.0 * r), cube_size=cell,
                  iso_surface_threshold=ISO_LEVEL)  # pysplashsurf multiplies both by r (notes/surface.md)
    variants = {
        "raw": lambda: ps.reconstruct_surface(x, **common).mesh,
        "pipeline": lambda: ps.reconstruction_pipeline(
            x, **common, mesh_cleanup=True, mesh_smoothing_weights=True,
            mesh_smoothing_iters=SPLASHSURF_SMOOTHING_ITERATIONS, compute_normals=True,
            normals_smoothing_iters=SPLASHSURF_NORMAL_ITERATIONS)[0].mesh,
    }
    for name, call in variants.items():
        mesh = call()  # warm up
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            mesh = call()
            times.append(1e3 * (time.perf_counter() - t0))
        print(json.dumps({"variant": name, "ms": statistics.median(times), "ms_all": times,
                          "vertices": int(len(mesh.vertices)), "triangles": int(len(mesh.triangles)),
                          "version": getattr(ps, "__version__", None)}), flush=True)
    return 0


def splashsurf_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("pysplashsurf") is not None


def _time_splashsurf(sim, cell_per_radius: float, threads: int, repeats: int, log) -> list[dict]:
    m = sim.model
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "particles.npz"
        np.savez(path, x=sim.fields["particle_x"].numpy(), radius=m.particle_radius,
                 support_radius=m.smoothing.support_radius(m.smoothing_length))
        env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
        cmd = [sys.executable, "-m", "warp_sph.benchmarks.surface", "_splashsurf", str(path), str(threads),
               str(cell_per_radius), str(repeats)]
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=1800)
    out = []
    for line in proc.stdout.splitlines():
        if line.startswith("{"):
            rec = json.loads(line)
            out.append({"engine": "splashsurf", **rec})
    if proc.returncode != 0 or not out:
        log(f"splashsurf failed (exit {proc.returncode}): {proc.stderr.strip()[-500:]}")
        return [{"engine": "splashsurf", "variant": v, "status": "failed", "error": proc.stderr.strip()[-2000:]}
                for v in ("raw", "pipeline")]
    return out


def run_surface_bench(radii=(0.025,), times=(0.3,), cells=(0.5,), threads=(1, 2), repeats: int = 5,
                      splashsurf: bool = True, device=None, log=print) -> list[dict]:
    """Records (kind "surface") for every radius, cell size, thread count, engine and variant."""
    records = []
    with_ss = splashsurf and splashsurf_available()
    if splashsurf and not with_ss:
        log("pysplashsurf is not installed (pip install pysplashsurf): warp-sph only")
    for radius, t in zip(radii, times):
        sim = particles_at(radius, t, device=device)
        n = sim.model.fluid_count
        base = {"kind": "surface", "status": "ok", "particle_radius": radius, "time": t, "fluid_particles": n,
                "device": str(sim.device), "iso_level": ISO_LEVEL}
        for cell in cells:
            for nthreads in threads:
                found = []
                for variant in ("raw", "pipeline") + (("default",) if cell == cells[0] else ()):
                    rec = _time_warp_sph(sim, cell, variant, nthreads, repeats)
                    c = sim.scene.output.surface_cell_per_radius if variant == "default" else cell
                    found.append({**base, "cell_per_radius": c, "threads": nthreads, "variant": variant, **rec})
                if with_ss:
                    for rec in _time_splashsurf(sim, cell, nthreads, repeats, log):
                        found.append({**base, "cell_per_radius": cell, "threads": nthreads, **rec,
                                      "status": rec.get("status", "ok")})
                ss = {r["variant"]: r for r in found if r["engine"] == "splashsurf" and r["status"] == "ok"}
                for r in found:
                    ref = ss.get(r["variant"])
                    if r["engine"] == "warp-sph" and ref:
                        r["splashsurf_ms"] = ref["ms"]
                        r["ratio_to_splashsurf"] = r["ms"] / ref["ms"]
                    if r["status"] == "ok":
                        log(f"surface N={n} cell={cell}r threads={nthreads} {r['engine']} {r['variant']}: "
                            f"{r['ms']:.1f} ms, {r['triangles']} triangles"
                            + (f" (x{r['ratio_to_splashsurf']:.2f} splashsurf)" if "ratio_to_splashsurf" in r else ""))
                records += found
    return records


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "_splashsurf":
        sys.exit(_splashsurf_driver(sys.argv[2:]))
    sys.exit(2)
