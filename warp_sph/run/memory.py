"""Memory pre-flight: the particle count estimated from a scene's geometry (before sampling), the
bytes a run of that size needs against what the host (``/proc/meminfo`` MemAvailable and the cgroup
limit) or device has free, and ``check_memory``, which refuses a scene that cannot fit. The other
pre-flight checks are in ``preflight.py``, which reports ``memory_verdict`` for the sampled counts.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import warp as wp

from ..core.errors import SceneError

#: device memory the queued frame snapshots may hold [bytes]: the simulation goes on while the export
#: runs behind (default dam break: ~0.25 MB a frame, so it never waits) and the export catches up after
#: the last step; at the limit the simulation waits for a slot
SNAPSHOT_QUEUE_BYTES = 1 << 30

#: Warn when the run needs more than this fraction of the available memory; refuse above 1.
MEMORY_WARN = 0.5


# Memory model [bytes], from the arrays a WCSPH run allocates (x, v, density, pressure, acceleration,
# boundary force, XSPH correction: 68 B), hash-grid indices (~32 B), the watchdog's frame-start copy
# (24 B) and solver workspace; host: sampling temporaries in float64 and the export copies. A rough but
# conservative model; the check refuses only what cannot fit. The export's queue of frame snapshots and
# the whitewater capacity are counted on their own (``_export_queue_bytes``, ``_whitewater_bytes``).
DEVICE_BYTES_PER_FLUID = 160
#: a frame snapshot of the export (``Exporter.snapshot``), per fluid slot: x, v (12 B each), density,
#: pressure, id (4 B each)
SNAPSHOT_BYTES_PER_FLUID = 36
#: whitewater (``run.whitewater``) per slot of ``whitewater.max_particles``: two buffers of x, v, age, life,
#: kind (36 B each) and the alive flags and offsets (8 B) on the device; per fluid particle: its
#: generation flags and offsets (8 B), normal and potentials (24 B)
WHITEWATER_BYTES_PER_SLOT = 80
WHITEWATER_BYTES_PER_FLUID = 32
#: a frame snapshot's whitewater (host copies: the live arrays, world x in float64, per-kind selections)
WHITEWATER_SNAPSHOT_BYTES_PER_SLOT = 100
DEVICE_BYTES_PER_BOUNDARY = 64
HOST_BYTES_PER_FLUID = 512
HOST_BYTES_PER_BOUNDARY = 128
HASH_GRID_BYTES = 2 * 128**3 * 4 * 2  # fluid and boundary grids: cell starts and ends
# Surface reconstruction (sparse grid, marching cubes, smoothing, decimation buffers) per cell of the
# fluid's volume grown 8x (``_surface_bytes``): the default dam break (6,859 particles, frames 1, 13 and
# 25) holds 30.2 MiB of Warp arrays at 1 r cells (72 B per such cell, most of it the mesh's buffers) and
# 117 MiB at 0.5 r (35 B per cell); 80 B covers both (measured as docs/limits.md says).
SURFACE_BYTES_PER_CELL = 80


def available_host_memory() -> int | None:
    """Bytes the process may still allocate: MemAvailable from /proc/meminfo, lowered by a cgroup
    limit when one is set; None where neither can be read."""
    avail = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = int(line.split()[1]) * 1024
                break
    except (OSError, ValueError, IndexError):
        pass
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            limit = Path(limit_file).read_text().strip()
            usage = int(Path(usage_file).read_text().strip())
        except (OSError, ValueError):
            continue
        if limit.isdigit() and int(limit) < 1 << 60:
            room = max(int(limit) - usage, 0)
            avail = room if avail is None else min(avail, room)
        break
    return avail


def available_device_memory(device) -> int | None:
    """Free memory [bytes] of a CUDA device; None on the CPU (host memory applies)."""
    d = wp.get_device(device)
    if not d.is_cuda:
        return None
    free = getattr(d, "free_memory", None)
    return int(free) if free else None


def particle_count_contributions(scene) -> list[tuple[str, str, int]]:
    """[(key path, "fluid" | "boundary", particles)] estimated from the scene's geometry without
    sampling: a box block's lattice inside the container less the wall gap (``_box_lattice_count``), another
    block's volume / (s d)^3, a wall's or obstacle's area / d^2."""
    d = scene.spacing
    out = []
    for i, b in enumerate(scene.fluid):
        step = b.spacing_scale * d
        if b.shape == "box":
            out.append((f"fluid[{i}]", "fluid", _box_lattice_count(scene, b)))
            continue
        vol = b.volume()  # sphere or closed mesh [m^3]
        out.append((f"fluid[{i}]", "fluid", int(min(vol / step**3, 2**62))))

    def box_area(lo, hi):
        e = np.subtract(hi, lo)
        return 2.0 * (e[0] * e[1] + e[1] * e[2] + e[0] * e[2])

    if scene.container is not None:
        out.append(("container", "boundary", int(min(box_area(scene.container.min, scene.container.max) / d**2, 2**62))))
    for i, ob in enumerate(scene.obstacles):
        if ob.shape == "box":
            area = box_area(ob.min, ob.max)
        elif ob.shape == "sphere":
            area = 4.0 * np.pi * float(ob.radius) ** 2
        else:
            try:
                from ..scene.meshes import load_triangle_mesh

                mesh = load_triangle_mesh(ob.file).transformed(ob.scale, ob.translate)
                a, b, c = mesh.triangle_corners()
                area = 0.5 * float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
            except Exception:
                area = 0.0
        out.append((f"obstacles[{i}]", "boundary", int(min(area / d**2, 2**62))))
    if getattr(scene, "emitters", None) or getattr(scene, "max_particles", 0):  # the capacity beyond the blocks
        from ..scene.emitters import emitted_total

        initial = sum(n for _, kind, n in out if kind == "fluid")
        extra = scene.max_particles - initial if scene.max_particles else int(1.05 * emitted_total(scene))
        if extra > 0:
            out.append(("max_particles" if scene.max_particles else "emitters", "fluid", int(min(extra, 2**62))))
    return out


def _box_lattice_count(scene, block) -> int:
    """Lattice points of a box fluid block as ``sampling.lattice_block`` places them, without placing them: per axis
    floor(extent / (s d)) of the block clipped to the container shrunk by the wall gap g d - s r. Measured, hydrostatic
    at r = 0.0426 m (a 0.61 m tank): 125 sampled where volume / d^3 gave 300 (the gap takes a column a side)."""
    from ..scene.sampling import _EPS

    step = block.spacing_scale * scene.spacing
    lo, hi = (np.asarray(x, dtype=np.float64) for x in block.bounds())
    c = scene.container
    if c is not None:
        shrink = scene.wall_gap - 0.5 * step
        lo, hi = np.maximum(lo, np.asarray(c.min) + shrink), np.minimum(hi, np.asarray(c.max) - shrink)
    n = np.floor((hi - lo) / step + _EPS)
    return 0 if np.any(n <= 0) else int(min(float(np.prod(n)), 2**62))


def estimate_particle_counts(scene) -> tuple[int, int]:
    """(fluid, boundary) particle counts estimated from the scene's geometry, without sampling."""
    parts = particle_count_contributions(scene)
    return (sum(n for _, kind, n in parts if kind == "fluid"), sum(n for _, kind, n in parts if kind == "boundary"))


def _surface_bytes(scene, fluid_count: int) -> int:
    """Bytes of the surface reconstruction: SURFACE_BYTES_PER_CELL per cell of the volume it can cover. The
    grid is sparse (``warp_sph.surface.grid``: blocks around the particles only), so that volume is the
    fluid's, N d^3, grown 8x (a splash that doubles the fluid's extent, the blocks' margin), and
    never more than the container: a large container with little fluid needs a small grid."""
    o = scene.output
    if not (o.surface and (o.usd or o.mesh_sequence)):
        return 0
    cell = o.surface_cell_per_radius * scene.particle_radius
    volume = 8.0 * fluid_count * scene.spacing**3
    if scene.container is not None:
        volume = min(volume, float(np.prod(np.subtract(scene.container.max, scene.container.min))))
    return int(min(SURFACE_BYTES_PER_CELL * volume / cell**3, 2**62))


def _whitewater_capacity(scene) -> int:
    """``whitewater.max_particles`` when the scene generates whitewater, else 0."""
    ww = getattr(scene, "whitewater", None)
    return int(ww.max_particles) if ww is not None and ww.enabled else 0


def _whitewater_bytes(scene, fluid_count: int) -> int:
    """Device bytes of the whitewater state, allocated whole at the start (``max_particles`` slots)."""
    slots = _whitewater_capacity(scene)
    return WHITEWATER_BYTES_PER_SLOT * slots + WHITEWATER_BYTES_PER_FLUID * fluid_count if slots else 0


def _export_queue_bytes(scene, fluid_count: int, frames: int | None = None) -> tuple[int, int]:
    """(device, host) bytes of the frame snapshots the export holds at its peak: the queue of
    ``ExportThread`` admits frames while they hold at most ``SNAPSHOT_QUEUE_BYTES`` (always ``depth``
    frames), and the simulation holds one more while it waits for room; never more than the run's
    frames (``frames``, default duration * fps + 1). Device: the particles' copies; host: whitewater's."""
    dev = SNAPSHOT_BYTES_PER_FLUID * fluid_count
    host = WHITEWATER_SNAPSHOT_BYTES_PER_SLOT * _whitewater_capacity(scene)
    size = max(dev + host, 1)
    total = int(round(scene.duration * scene.fps)) + 1 if frames is None else int(frames)
    held = min(max(total, 1), max(2, SNAPSHOT_QUEUE_BYTES // size) + 1)
    return held * dev, held * host


def estimate_memory(scene, fluid_count: int, boundary_count: int, frames: int | None = None) -> dict[str, int]:
    """{"device": bytes, "host": bytes} a run of ``scene`` needs at its peak (rough, conservative):
    the particles, the hash grid, the surface grid, the whitewater capacity and the export's
    queue of frame snapshots (``frames``: the frames the run writes, default duration * fps + 1).
    On the CPU both live in host memory."""
    queue_dev, queue_host = _export_queue_bytes(scene, fluid_count, frames)
    device = (DEVICE_BYTES_PER_FLUID * fluid_count + DEVICE_BYTES_PER_BOUNDARY * boundary_count
              + HASH_GRID_BYTES + _surface_bytes(scene, fluid_count) + _whitewater_bytes(scene, fluid_count)
              + queue_dev)
    host = HOST_BYTES_PER_FLUID * fluid_count + HOST_BYTES_PER_BOUNDARY * boundary_count + queue_host
    return {"device": int(device), "host": int(host)}


def _gib(n: float) -> str:
    return f"{n / 2**30:.3g} GiB" if n >= 2**28 else f"{n / 2**20:.3g} MiB"


def _largest_cost(scene, fluid: int, boundary: int, surface_to_blame: int = 0,
                  whitewater_to_blame: int = 0) -> tuple[str, str]:
    """(key path, advice) of what to change: the whitewater capacity or the surface grid when
    ``whitewater_to_blame`` / ``surface_to_blame`` > 0 (the particles alone would fit), else the particles'
    largest part: a fluid block, the walls or an obstacle."""
    per = {"fluid": DEVICE_BYTES_PER_FLUID + HOST_BYTES_PER_FLUID,
           "boundary": DEVICE_BYTES_PER_BOUNDARY + HOST_BYTES_PER_BOUNDARY}
    parts = [(n * per[kind], key, kind, n) for key, kind, n in particle_count_contributions(scene)]
    cost, key, kind, n = max(parts) if parts else (0, "particle_radius", "fluid", fluid)
    if whitewater_to_blame > 0:
        slots = _whitewater_capacity(scene)
        return ("whitewater.max_particles",
                f"the fluid alone fits, but whitewater.max_particles = {slots:,} slots need "
                f"{_gib(whitewater_to_blame)} (allocated at the start, and copied for the export of each frame); "
                "lower whitewater.max_particles")
    if surface_to_blame > 0:
        return ("output.surface_cell_per_radius",
                f"the particles alone fit, but the surface grid at {scene.output.surface_cell_per_radius:g} r "
                f"cells needs {_gib(surface_to_blame)}; raise output.surface_cell_per_radius (memory scales as "
                "1/cell^3) or set output.surface = false")
    if key.startswith("obstacles"):
        return key, (f"{key} needs about {n:,} boundary particles at spacing d = {scene.spacing:g} m; check its "
                     "size (scale, min/max) or raise particle_radius")
    if key in ("emitters", "max_particles"):  # the capacity beyond the initial fluid (docs/emitters.md)
        what = ("the emitters add" if key == "emitters" else f"max_particles = {scene.max_particles:,} allocates") + \
            f" about {n:,} particle slots"
        return key, (f"{what}; lower the emitters' flow_rate or speed or their start..end, or set max_particles "
                     "lower (layers that do not fit are skipped with a warning)")
    if key == "container":
        return key, (f"the container walls need about {n:,} boundary particles at spacing d = {scene.spacing:g} m; "
                     "shrink the container or raise particle_radius")
    return "particle_radius", f"{key} needs about {n:,} fluid particles; raise particle_radius or shrink the fluid blocks"


def memory_verdict(scene, fluid: int, boundary: int, device, estimated: bool,
                   frames: int | None = None) -> tuple[str, str] | None:
    """("refuse" | "warn", message) or None. ``frames``: the frames the run writes (default duration *
    fps + 1), which bound the export's snapshot queue."""
    need = estimate_memory(scene, fluid, boundary, frames)
    host_avail = available_host_memory()
    dev_avail = available_device_memory(device)
    if dev_avail is None:
        pools = [("host", need["device"] + need["host"], host_avail)]
    else:
        pools = [("device", need["device"], dev_avail), ("host", need["host"], host_avail)]
    count = f"{'about ' if estimated else ''}{fluid:,} fluid and {boundary:,} boundary particles"
    worst = None
    for pool, n, avail in pools:
        if avail is None or avail <= 0:
            continue
        ratio = n / avail
        if worst is None or ratio > worst[0]:
            worst = (ratio, pool, n, avail)
    if worst is None:
        return None
    ratio, pool, n, avail = worst
    # the surface grid lives in device memory (host memory on the CPU); blame it only when the
    # particles alone would fit (in the half of the memory a run should leave free)
    on_device = pool == "device" or dev_avail is None
    surface = _surface_bytes(scene, fluid) if on_device else 0
    queue_dev, queue_host = _export_queue_bytes(scene, fluid, frames)
    queue = queue_dev if on_device else 0  # the particles' copies (whitewater's are counted as whitewater)
    whitewater = (_whitewater_bytes(scene, fluid) if on_device else 0) + (
        queue_host if pool == "host" else 0)  # its share of the export's copies lives on the host
    # memory scales as 1/r^3: the radius that would fit in half the available memory
    r_fit = scene.particle_radius * max(ratio / MEMORY_WARN, 1.0) ** (1.0 / 3.0)
    extra = [f"{what} {_gib(b)}" for what, b in (("whitewater", whitewater), ("the export's frame snapshots", queue))
             if b >= 0.05 * n]
    text = (f"{count} need about {_gib(n)} of {pool} memory{' (' + ', '.join(extra) + ' of it)' if extra else ''}, "
            f"{100 * ratio:.0f} % of the {_gib(avail)} available")
    if ratio > 1.0:
        fits_without = n - whitewater <= MEMORY_WARN * avail
        key, advice = _largest_cost(scene, fluid, boundary,
                                    surface if not (whitewater and fits_without) and n - surface <= MEMORY_WARN * avail
                                    else 0, whitewater if whitewater and fits_without else 0)
        if key == "particle_radius":
            advice += f" (particle_radius about {r_fit:.3g} m would fit; memory scales as 1/r^3)"
        return "refuse", f"{scene.source}: {key}: {text}; {advice}"
    if ratio > MEMORY_WARN:
        return "warn", f"{text}; the run may swap or fail (particle_radius {r_fit:.3g} m would halve that)"
    return None


def check_memory(scene, device=None) -> None:
    """Refuse a scene whose estimated particle count cannot fit in memory, before sampling it."""
    fluid, boundary = estimate_particle_counts(scene)
    verdict = memory_verdict(scene, fluid, boundary, device, estimated=True)
    if verdict is not None and verdict[0] == "refuse":
        raise SceneError(verdict[1])
