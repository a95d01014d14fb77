"""The default-run case of ``warp-sph bench surface``: every frame of the default dam break (default
settings, ``duration * fps + 1`` frames) through warp-sph's surface and splashsurf's full pipeline.

One simulation per particle radius records every frame's positions and the CPU and wall time of
each frame's simulation; then, per thread count, warp-sph's surface at the scene's defaults
(``surface_settings``: cell, smoothing, decimation, normals) and splashsurf's
``reconstruction_pipeline`` (mesh cleanup, weighted smoothing 25, normals, normal smoothing 10; same
iso level, kernel support and thread count) on the same frames, at warp-sph's cell size and at
splashsurf's coarsest recommended one (1.0 r). Per frame the USD bytes of the frame (particles,
surface, spray, as the run writes them) and the times of Warp's own marching cubes (dense
``IsoSurfaceMarchingCubes`` and ``sparse_marching_cubes_from_cells``) on the same nodes as
warp-sph's extraction pass (their inputs built untimed; docs/ARCHITECTURE.md).

With Newton installed, its ``ParticleSurface`` on the same frames too (``time_newton``: a cost
reference; one launch per kernel, so one CPU thread).

Figures per record: ``ms`` and ``cpu_ms`` (mean over the frames, warm: one untimed call on frame 1
first), the simulation's ``sim_ms`` / ``sim_cpu_ms`` per frame, the ratios to both, triangles per
frame, USD bytes of the whole run. Goal (issue 30): ms <= 0.5 x splashsurf's pipeline and
<= 0.25 x the simulation's time per frame.
"""
from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .surface import ISO_LEVEL, SPLASHSURF_NORMAL_ITERATIONS, SPLASHSURF_SMOOTHING_ITERATIONS

#: splashsurf's coarsest recommended cube size [r] (its README: 0.5-1.0), compared as well
SPLASHSURF_CELL = 1.0


def simulate_frames(radius: float, device=None, frames: int | None = None, log=print):
    """(sim, [positions (N, 3) float32 of every frame, local frame], sim wall [s] and CPU [s] per frame
    after the first) of the default dam break at particle radius ``radius``."""
    from warp_sph.run.simulation import Simulation
    from warp_sph.scene import load_scene

    scene = load_scene("dam_break", [f"particle_radius={radius}", "output.usd=false", "output.surface=false"])
    sim = Simulation(scene, device=device)
    total = frames or int(round(scene.duration * scene.fps)) + 1
    xs = [sim.fields["particle_x"].numpy().copy()]
    wall, cpu = [], []
    for k in range(1, total):
        t0, c0 = time.perf_counter(), time.process_time()
        sim.advance_frame()
        sim.fields["particle_x"].numpy()  # synchronises
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        xs.append(sim.fields["particle_x"].numpy().copy())
        if k % 10 == 0:
            log(f"  simulated frame {k + 1}/{total}")
    return sim, xs, wall, cpu


def _warp_mc_ms(grid, iso: float) -> tuple[float, float]:
    """Times [ms] of Warp's own marching cubes on the nodes of the grid's meshed blocks: the dense
    ``IsoSurfaceMarchingCubes`` (the blocks' bounding box, zero elsewhere) and
    ``sparse_marching_cubes_from_cells`` (every cell of the meshed blocks with its 8 corner values);
    their inputs are built untimed."""
    import warp as wp
    import warp.geometry

    b = grid.block_nodes
    meshed = grid.meshed_block.numpy()[: grid.meshed_count]
    coords = grid.block_coord.numpy()[meshed]
    lo, hi = coords.min(0) * b, (coords.max(0) + 1) * b
    dense = np.zeros(tuple(hi - lo + 1), np.float32)
    field = grid.field.numpy()[: grid.meshed_count * b**3].reshape(-1, b, b, b)
    for c, block in zip(coords, field):
        o = c * b - lo
        dense[o[0]:o[0] + b, o[1]:o[1] + b, o[2]:o[2] + b] = block
    local = np.stack(np.meshgrid(*[np.arange(b)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cells = (coords[:, None, :] * b - lo + local[None]).reshape(-1, 3)
    cells = cells[np.all(cells < np.array(dense.shape) - 1, axis=1)]
    offsets = np.asarray(warp.geometry.IsoSurfaceMarchingCubes.CUBE_CORNER_OFFSETS, dtype=np.int64).reshape(8, 3)
    corners = np.stack([dense[tuple((cells + o).T)] for o in offsets], axis=1).astype(np.float32)
    dev = grid.device
    arr = wp.array(dense, dtype=float, device=dev)
    cells_wp = wp.array(cells.astype(np.int32), dtype=wp.vec3i, device=dev)
    corners_wp = wp.array(corners, dtype=float, device=dev)
    times = []
    for call in (lambda: warp.geometry.IsoSurfaceMarchingCubes.extract(arr, iso),
                 lambda: warp.geometry.sparse_marching_cubes_from_cells(cells_wp, corners_wp, threshold=iso, device=dev)):
        wp.synchronize_device(dev)
        t0 = time.perf_counter()
        call()
        wp.synchronize_device(dev)
        times.append(1e3 * (time.perf_counter() - t0))
    return times[0], times[1]


def _usd_bytes(sim, xs, meshes) -> int:
    """Bytes of a USD with every frame's particles, surface (normals) and spray, as the run writes it."""
    from warp_sph.io.export_usd import UsdWriter

    m = sim.model
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.usdc"
        with UsdWriter(path, fps=sim.scene.fps, particle_radius=m.particle_radius, with_normals=True,
                       with_spray=True, primvars=("density",)) as w:
            zeros = np.zeros(len(xs[0]), np.float32)
            for f, (x, mesh) in enumerate(zip(xs, meshes), start=1):
                xw = m.to_world(x).astype(np.float32)
                v = np.zeros_like(xw)
                w.write_frame(f, xw, v, {"density": zeros}, (m.to_world(mesh[0]).astype(np.float32), mesh[1], mesh[2]),
                              spray=(xw[mesh[3]], v[mesh[3]]))
        return path.stat().st_size


def time_warp_sph(sim, xs, threads: int, with_warp_mc: bool = True) -> dict:
    """warp-sph's surface at the scene's defaults on every frame: mean wall and CPU ms, stages, counts."""
    import warp as wp

    from warp_sph.surface import SurfaceReconstructor, surface_settings
    from warp_sph.surface.reconstruction import STAGES

    m = sim.model
    kw = surface_settings(sim.scene.output, m.particle_radius)
    rec = SurfaceReconstructor(m.smoothing.name, m.smoothing_length, m.particle_radius, device=sim.device, **kw)
    old = os.environ.get("WARP_SPH_CPU_THREADS")
    os.environ["WARP_SPH_CPU_THREADS"] = str(threads)
    wall, cpu, tris, mc_ms, sparse_ms, meshes = [], [], [], [], [], []
    stages = {s: 0.0 for s in STAGES}
    try:
        rec.reconstruct(wp.array(xs[0], dtype=wp.vec3, device=sim.device))  # compile, load, size buffers
        if with_warp_mc:
            _warp_mc_ms(rec.grid, rec.iso_level)  # Warp's modules too
        for x in xs:
            a = wp.array(x, dtype=wp.vec3, device=sim.device)
            wp.synchronize_device(sim.device)
            t0, c0 = time.perf_counter(), time.process_time()
            f = rec.reconstruct(a)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            for k, v in f.timings.items():
                stages[k] += v
            tris.append(len(f.triangles))
            # copies: on the CPU the frame's arrays view the reconstructor's reused buffers
            meshes.append((f.vertices.copy(), f.triangles.copy(), f.normals.copy(), f.spray.copy()))
            if with_warp_mc:
                dense_ms, cells_ms = _warp_mc_ms(rec.grid, rec.iso_level)
                mc_ms.append(dense_ms)
                sparse_ms.append(cells_ms)
    finally:
        if old is None:
            os.environ.pop("WARP_SPH_CPU_THREADS", None)
        else:
            os.environ["WARP_SPH_CPU_THREADS"] = old
    n = len(xs)
    out = {"engine": "warp-sph", "cell_per_radius": kw["cell_size"] / m.particle_radius,
           "ms": 1e3 * float(np.mean(wall)), "cpu_ms": 1e3 * float(np.mean(cpu)),
           "stage_ms": {k: 1e3 * v / n for k, v in stages.items()},
           "triangles": float(np.mean(tris)), "triangles_max": int(max(tris)),
           "usd_bytes": _usd_bytes(sim, xs, meshes)}
    out["usd_bytes_per_frame"] = out["usd_bytes"] / n
    if mc_ms:
        out["warp_dense_mc_ms"] = float(np.mean(mc_ms))
        out["warp_sparse_mc_ms"] = float(np.mean(sparse_ms))
    return out


def time_newton(sim, xs, cell_per_radius: float, threads: int) -> dict:
    """Newton's ``ParticleSurface`` (isotropic kernels of our support radius, voxels of our cell,
    its default level 0.25, 5 mesh smoothing steps, normals) on every frame: mean wall and CPU ms,
    triangles. Its field differs from ours (not a like-for-like mesh): a reference for the cost."""
    import newton.geometry
    import warp as wp

    m = sim.model
    ps = newton.geometry.ParticleSurface(cell_per_radius * m.particle_radius,
                                         kernel_radius=m.smoothing.support_radius(m.smoothing_length),
                                         mesh_smooth_iterations=5, device=sim.device)
    radii = wp.full(len(xs[0]), m.particle_radius, dtype=float, device=sim.device)
    arrays = [wp.array(x, dtype=wp.vec3, device=sim.device) for x in xs]
    ps.extract(arrays[0], radii)  # compile, load
    wall, cpu, tris = [], [], []
    for a in arrays:
        wp.synchronize_device(sim.device)
        t0, c0 = time.perf_counter(), time.process_time()
        mesh = ps.extract(a, radii)
        wp.synchronize_device(sim.device)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        tris.append(mesh.indices.size // 3)
    return {"engine": "newton", "status": "ok", "cell_per_radius": cell_per_radius,
            "ms": 1e3 * float(np.mean(wall)), "cpu_ms": 1e3 * float(np.mean(cpu)), "triangles": float(np.mean(tris)),
            "version": importlib.metadata.version("newton")}


def _splashsurf_frames_driver(args: list[str]) -> int:
    """Subprocess entry: ``_splashsurf_frames FRAMES.npz CELL``: splashsurf's full pipeline on every
    frame (one untimed call on frame 0 first); prints one JSON line. RAYON_NUM_THREADS is set by the
    parent before this process imports pysplashsurf."""
    import pysplashsurf as ps

    data = np.load(args[0])
    xs = data["x"]
    r, support, cell = float(data["radius"]), float(data["support_radius"]), float(args[1])
    common = dict(particle_radius=r, smoothing_length=support / (2.0 * r), cube_size=cell,
                  iso_surface_threshold=ISO_LEVEL)  # pysplashsurf multiplies both by r (notes/surface.md)

    def call(x):
        return ps.reconstruction_pipeline(
            np.ascontiguousarray(x, dtype=np.float32), **common, mesh_cleanup=True, mesh_smoothing_weights=True,
            mesh_smoothing_iters=SPLASHSURF_SMOOTHING_ITERATIONS, compute_normals=True,
            normals_smoothing_iters=SPLASHSURF_NORMAL_ITERATIONS)[0].mesh

    call(xs[0])
    wall, cpu, tris = [], [], []
    for x in xs:
        t0, c0 = time.perf_counter(), time.process_time()
        mesh = call(x)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        tris.append(len(mesh.triangles))
    print(json.dumps({"ms": 1e3 * float(np.mean(wall)), "cpu_ms": 1e3 * float(np.mean(cpu)),
                      "triangles": float(np.mean(tris)), "version": importlib.metadata.version("pysplashsurf")}), flush=True)
    return 0


def time_splashsurf(sim, xs, cell: float, threads: int, log=print) -> dict:
    m = sim.model
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "frames.npz"
        np.savez(path, x=np.stack(xs), radius=m.particle_radius,
                 support_radius=m.smoothing.support_radius(m.smoothing_length))
        env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
        cmd = [sys.executable, "-m", "warp_sph.benchmarks.surface_run", "_splashsurf_frames", str(path), str(cell)]
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=3600)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        log(f"splashsurf failed (exit {proc.returncode}): {proc.stderr.strip()[-500:]}")
        return {"engine": "splashsurf", "status": "failed", "error": proc.stderr.strip()[-2000:]}
    return {"engine": "splashsurf", "status": "ok", "cell_per_radius": cell, **json.loads(lines[0])}


def run_default_run_bench(radii=(0.025,), threads=(2,), splashsurf: bool = True, device=None, frames=None,
                          newton: bool = True, log=print) -> list[dict]:
    """Records (kind "surface", variant "run") for every radius and thread count: warp-sph's defaults
    and splashsurf's pipeline (at warp-sph's cell and at SPLASHSURF_CELL) on every frame, and Newton's
    ParticleSurface when Newton is installed."""
    from .surface import splashsurf_available

    records = []
    with_ss = splashsurf and splashsurf_available()
    for radius in radii:
        sim, xs, sim_wall, sim_cpu = simulate_frames(radius, device=device, frames=frames, log=log)
        n = sim.model.fluid_count
        base = {"kind": "surface", "status": "ok", "variant": "run", "particle_radius": radius,
                "fluid_particles": n, "frames": len(xs), "device": str(sim.device), "iso_level": ISO_LEVEL,
                "sim_ms": 1e3 * float(np.mean(sim_wall)), "sim_cpu_ms": 1e3 * float(np.mean(sim_cpu)),
                "sim_threads": int(os.environ.get("WARP_SPH_CPU_THREADS") or os.cpu_count() or 1)}
        for nthreads in threads:
            ours = {**base, "threads": nthreads, **time_warp_sph(sim, xs, nthreads)}
            found = [ours]
            if newton and importlib.util.find_spec("newton") is not None:
                found.append({**base, "threads": nthreads, **time_newton(sim, xs, ours["cell_per_radius"], nthreads)})
            if with_ss:
                for cell in dict.fromkeys((ours["cell_per_radius"], SPLASHSURF_CELL)):
                    found.append({**base, "threads": nthreads, **time_splashsurf(sim, xs, cell, nthreads, log)})
            ss = [r for r in found if r["engine"] == "splashsurf" and r["status"] == "ok"]
            ours["sim_ratio"] = ours["ms"] / ours["sim_ms"]
            ours["sim_cpu_ratio"] = ours["cpu_ms"] / ours["sim_cpu_ms"]
            for r in ss:
                key = "" if abs(r["cell_per_radius"] - ours["cell_per_radius"]) < 1e-9 else "_at_1r"
                ours[f"splashsurf_ms{key}"] = r["ms"]
                ours[f"ratio_to_splashsurf{key}"] = ours["ms"] / r["ms"]
                ours[f"cpu_ratio_to_splashsurf{key}"] = ours["cpu_ms"] / r["cpu_ms"]
            for r in found:
                if r["status"] == "ok":
                    log(f"surface run N={n} threads={nthreads} {r['engine']} cell={r['cell_per_radius']:g}r: "
                        f"{r['ms']:.1f} ms ({r['cpu_ms']:.1f} ms CPU) per frame, {r['triangles']:.0f} triangles")
            log(f"  warp-sph / simulation per frame: {ours['sim_ratio']:.2f} wall, {ours['sim_cpu_ratio']:.2f} CPU "
                f"(simulation {ours['sim_ms']:.0f} ms, {ours['sim_cpu_ms']:.0f} ms CPU); USD "
                f"{ours['usd_bytes'] / 1e6:.1f} MB; extraction {ours['stage_ms']['extraction']:.1f} ms, Warp's dense "
                f"marching cubes on the same nodes {ours.get('warp_dense_mc_ms', float('nan')):.1f} ms, its "
                f"sparse_marching_cubes_from_cells {ours.get('warp_sparse_mc_ms', float('nan')):.1f} ms"
                + "".join(f"; / splashsurf{k.replace('ratio_to_splashsurf', '') or ''} {ours[k]:.2f} wall, "
                          f"{ours['cpu_' + k]:.2f} CPU" for k in ("ratio_to_splashsurf", "ratio_to_splashsurf_at_1r")
                          if k in ours))
            records += found
    return records


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "_splashsurf_frames":
        sys.exit(_splashsurf_frames_driver(sys.argv[2:]))
    sys.exit(2)
