"""Benchmark metrics: pure functions of arrays (NumPy, float64), so each one can be checked on a
known configuration (tests/test_bench.py).

Speed
    wall time per simulated second, particle-steps per second, time per stage: ``speed_metrics``.
Memory
    bytes per particle of the simulation's arrays plus its hash grids: ``array_bytes``,
    ``hash_grid_bytes``; process peak memory: ``host_memory``, ``device_memory``.
Accuracy
    density error statistics (``density_error_stats``: same definitions as
    ``FrameStatistics``), volume drift (``compression_volume``), total energy
    (``kinetic_energy`` + ``potential_energy``; ``energy_summary``), hydrostatic pressure error
    against rho0 g depth (``hydrostatic_pressure_error``, physics notes section 2) and the
    dam-break surge front (``surge_front``).
"""
from __future__ import annotations

import math
import os
import resource
from typing import Iterable, Sequence

import numpy as np

# shared with warp-sph sweep's summary (warp_sph/sweep/runs.py), which may not import the benchmarks
from warp_sph.sweep.runs import pareto_front, surge_front  # noqa: F401  (re-exported)


# --------------------------------------------------------------------------------------------
# Accuracy
# --------------------------------------------------------------------------------------------
def density_error_stats(density: np.ndarray, rest_density: float) -> dict:
    """Density error of one state, as ``FrameStatistics`` defines it.

    mean: mean over particles of max(rho/rho0 - 1, 0) (compression only, as SPlisHSPlasH: free-surface
    particles read under-dense from kernel truncation, which no solver corrects); max: max of
    rho/rho0 - 1; min: min of rho/rho0 - 1 [-].
    """
    e = np.asarray(density, dtype=np.float64) / float(rest_density) - 1.0
    if e.size == 0:
        return {"mean": 0.0, "max": 0.0, "min": 0.0}
    return {"mean": float(np.maximum(e, 0.0).mean()), "max": float(e.max()), "min": float(e.min())}


def compression_volume(density: np.ndarray, mass: float | np.ndarray, rest_density: float) -> float:
    """Fluid volume [m^3] as sum_i m_i / max(rho_i, rho0).

    Each particle counts at most its rest volume m/rho0: free-surface particles (whose SPH sum falls
    short because their kernel support is cut) and splashes do not read as growth, so the measure
    is robust to the changing surface area of a dam break, and a fall below the t = 0 value
    measures compression (volume lost to the solver). Drift: V(t) / V(0) - 1.
    """
    rho = np.maximum(np.asarray(density, dtype=np.float64), float(rest_density))
    m = np.broadcast_to(np.asarray(mass, dtype=np.float64), rho.shape)
    return float(np.sum(m / rho))


def kinetic_energy(v: np.ndarray, mass: float | np.ndarray) -> float:
    """sum_i 1/2 m_i |v_i|^2 [J]; v [m/s] shape (n, 3), mass [kg] scalar or shape (n,)."""
    v = np.asarray(v, dtype=np.float64)
    m = np.broadcast_to(np.asarray(mass, dtype=np.float64), v.shape[:1])
    return float(0.5 * np.sum(m * np.einsum("ij,ij->i", v, v)))


def potential_energy(x: np.ndarray, mass: float | np.ndarray, gravity: Sequence[float],
                     reference: Sequence[float] = (0.0, 0.0, 0.0)) -> float:
    """sum_i -m_i g . (x_i - reference) [J]: zero for particles at the reference point's height."""
    x = np.asarray(x, dtype=np.float64) - np.asarray(reference, dtype=np.float64)
    m = np.broadcast_to(np.asarray(mass, dtype=np.float64), x.shape[:1])
    return float(-np.sum(m * (x @ np.asarray(gravity, dtype=np.float64))))


def energy_summary(total_energy: Sequence[float], scale: float) -> dict:
    """Total-energy history (kinetic + potential [J], one value per frame, frame 0 first) in units of
    ``scale`` [J] (the benchmark uses M |g| h_com(0), the potential energy of the fluid's centre of
    mass above the floor, so numbers compare across resolutions and engines).

    change_final: (E_end - E_0)/scale (negative: dissipated); rise_max: max_t (E_t - E_0)/scale,
    which must stay <= 0 up to noise in a closed box with no external work (physics notes 6.12).
    """
    e = np.asarray(total_energy, dtype=np.float64)
    if e.size == 0 or not scale > 0:
        return {"change_final": float("nan"), "rise_max": float("nan")}
    d = (e - e[0]) / scale
    return {"change_final": float(d[-1]), "rise_max": float(d.max())}


def hydrostatic_pressure_error(z: np.ndarray, pressure: np.ndarray, rest_density: float, gravity: float,
                               spacing: float, exclude_depth: float, surface: float | None = None) -> dict:
    """Layer-averaged pressure against the hydrostatic p = rho0 g (H_s - z) (physics notes section 2.1).

    z: particle heights [m] (along -gravity), pressure [Pa], gravity: |g| [m/s^2], spacing d [m].
    surface: H_s [m]; default the top particle centre + d/2 (the particles' volume ends there).
    Particles are binned into layers of thickness d (by floor((H_s - z)/d): a lattice's layer
    centres sit at (k + 1/2) d below H_s, mid-bin); only layers whose mean
    depth is more than ``exclude_depth`` [m] below the surface take part (near the surface the
    summation deficit and clamped pressures make p ~ 0; the benchmark uses 2h). For each layer,
    err = (mean p - rho0 g mean depth) / (rho0 g mean depth).

    Returns mean_abs (mean |err| over layers), max_abs, signed mean, the layer count and the
    profile (depth [m], measured [Pa], expected [Pa]) for plots. NaN when no layer is deep enough.
    """
    z = np.asarray(z, dtype=np.float64)
    p = np.asarray(pressure, dtype=np.float64)
    hs = float(z.max() + 0.5 * spacing) if surface is None else float(surface)
    depth = hs - z
    layer = np.floor(depth / spacing).astype(np.int64)
    depths, measured, expected, errs = [], [], [], []
    for k in np.unique(layer):
        sel = layer == k
        dm = float(depth[sel].mean())
        if dm <= exclude_depth:
            continue
        pm = float(p[sel].mean())
        pe = rest_density * gravity * dm
        depths.append(dm)
        measured.append(pm)
        expected.append(pe)
        errs.append((pm - pe) / pe)
    if not errs:
        nan = float("nan")
        return {"mean_abs": nan, "max_abs": nan, "mean": nan, "layers": 0, "surface": hs,
                "profile": {"depth": [], "measured": [], "expected": []}}
    errs = np.asarray(errs)
    return {"mean_abs": float(np.abs(errs).mean()), "max_abs": float(np.abs(errs).max()),
            "mean": float(errs.mean()), "layers": len(errs), "surface": hs,
            "profile": {"depth": depths, "measured": measured, "expected": expected}}


def series_summary(values: Iterable[float]) -> dict:
    """mean and max of a per-frame series, ignoring NaN (empty: NaN)."""
    a = np.asarray([v for v in values if v is not None], dtype=np.float64)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {"mean": float("nan"), "max": float("nan")}
    return {"mean": float(a.mean()), "max": float(a.max())}


# --------------------------------------------------------------------------------------------
# Speed
# --------------------------------------------------------------------------------------------
def speed_metrics(wall_seconds: float, simulated_seconds: float, steps: int, fluid_count: int) -> dict:
    """wall_per_simulated_second [s/s], particle_steps_per_second [1/s], ms_per_step [ms],
    ns_per_particle_step [ns] from the timed stepping wall time [s]."""
    ps = float(steps) * float(fluid_count)
    return {
        "wall_per_simulated_second": wall_seconds / simulated_seconds if simulated_seconds > 0 else float("nan"),
        "particle_steps_per_second": ps / wall_seconds if wall_seconds > 0 else float("nan"),
        "ms_per_step": 1e3 * wall_seconds / steps if steps else float("nan"),
        "ns_per_particle_step": 1e9 * wall_seconds / ps if ps > 0 else float("nan"),
    }


def stage_fractions(timing_table: list[dict]) -> list[dict]:
    """graph.timing_table() rows plus each stage's share of the total stage time [-]."""
    total = sum(r["seconds"] for r in timing_table) or 1.0
    return [dict(r, fraction=r["seconds"] / total) for r in timing_table]


# --------------------------------------------------------------------------------------------
# Memory
# --------------------------------------------------------------------------------------------
def array_bytes(arrays: Iterable[object]) -> int:
    """Sum of the bytes held by arrays (wp.array: ``capacity``; NumPy: ``nbytes``); others are skipped;
    an array listed twice counts once."""
    seen, total = set(), 0
    for a in arrays:
        if id(a) in seen:
            continue
        seen.add(id(a))
        n = getattr(a, "capacity", None)
        if n is None:
            n = getattr(a, "nbytes", None)
        if isinstance(n, (int, np.integer)):
            total += int(n)
    return total


def hash_grid_bytes(dim: int, point_count: int) -> int:
    """Estimated bytes of one ``wp.HashGrid`` of dim^3 cells over point_count points: two int32 cell
    range arrays (starts, ends) plus four int32 per point (ids, hashes and their sort scratch)."""
    return 2 * 4 * dim ** 3 + 4 * 4 * point_count


def current_rss_bytes() -> int:
    """Resident set size of this process now [bytes] (Linux /proc; 0 where unavailable)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def host_memory() -> dict:
    """Peak resident set size of this process [bytes] (getrusage ru_maxrss, KiB on Linux) and the
    current one. Native allocations (Warp's CPU arrays) count, unlike tracemalloc."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return {"peak_rss_bytes": int(peak), "rss_bytes": current_rss_bytes()}


def device_memory(device) -> dict:
    """CUDA memory-pool use [bytes] (current and high-water) and total device memory; {} on CPU."""
    import warp as wp

    if not getattr(device, "is_cuda", False):
        return {}
    out = {"device_total_bytes": int(getattr(device, "total_memory", 0) or 0)}
    try:
        out["device_pool_used_bytes"] = int(wp.get_mempool_used_mem_current(device))
        out["device_pool_peak_bytes"] = int(wp.get_mempool_used_mem_high(device))
    except Exception:  # mempool not supported on this device / driver
        pass
    return out


# --------------------------------------------------------------------------------------------
# JSON
# --------------------------------------------------------------------------------------------
def nan_to_none(value):
    """JSON has no NaN: floats that are not finite become None, recursively."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: nan_to_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [nan_to_none(v) for v in value]
    if isinstance(value, np.generic):
        return nan_to_none(value.item())
    return value
