"""Sparse narrow-band grid of the fluid surface: which particles are spray, which blocks of grid
nodes can hold the iso-surface, and the colour field Phi on those blocks only.

Device code: ``kernels/surface_grid.py``. Steps 1-3 are one call of :meth:`SparseGrid.build`;
step 4 is ``band.classify(grid)`` and step 5 ``field.compute_field(grid)``, separate modules that
read the built grid (they import this one, never the reverse):

1. particle bounds (one host read), grid origin and block size B (nodes per block edge, so that
   a block edge B c >= max(support radius, band radius));
2. particles sorted by block key and, within a block, by node layer along x (radix sort;
   ``kernels/surface_rows.py``); occupied blocks; *candidate* blocks = occupied
   blocks and their 26 neighbours (every block a particle's support reaches), in a hash table;
3. per particle, over the 27 blocks around it: neighbour count, weighted neighbour count
   n_i = sum_j (1 - r_ij^2/R^2) and rho~_i = sum_j W_ij. Spray: fewer than ``spray_neighbors``
   neighbours (left out of Phi, returned as points). Surface: n_i < ``surface_fraction`` x the
   value of a full lattice neighbourhood;
4. block classes: *band* if a surface particle lies within the band radius D of its nodes,
   *inside* if only interior particles do (Phi >= iso assumed there), *outside* otherwise;
5. Phi on the band blocks only (each thread fills its own nodes, no atomics).

The band argument: the iso-surface lies within ~1.2 r of the outermost particles (the surface
particles) and cells are at most c wide, so a cell that the surface crosses has all its corners
within D = 2.5 r + 2 c of a surface particle, i.e. in band blocks (measured on the dam break at
6,859 particles: every crossing lies within 2.2 r of a surface particle). The marching cubes pass
counts crossing edges that touch a non-band node; if there is one, the field is rebuilt with every
block within the support radius of a particle as band (exact everywhere; ``band_fallbacks``).
"""
from __future__ import annotations

import ctypes
import math
import threading

import numpy as np
import warp as wp

from ..core.buffers import ArrayPool
from ..core.errors import SimulationError
from ..core import launch as _launch_module
from ..core.launch import LIGHT_MIN_RANGE
from ..core.smoothing import get_smoothing_kernel
from ..kernels import surface_grid as _dev
from .replay import replay

#: band radius D = BAND_RADIUS_R r + BAND_RADIUS_CELLS c around surface particles
BAND_RADIUS_R = 2.5
BAND_RADIUS_CELLS = 2.0
#: fewest blocks per CPU thread in block-parallel kernels
BLOCK_MIN_RANGE = 8
#: the same for light block kernels (a few loads per block: flags, scans' compaction, value ranges),
#: 50-140 us per frame on one thread at 6.9k particles, less than a split's hand-off saves
LIGHT_BLOCK_MIN_RANGE = 4096

_policy = threading.local()


def split_launches(enabled: bool) -> None:
    """Whether surface kernels launched from the calling thread split over CPU threads (default on).
    The run's export thread turns it off: the simulation keeps the cores busy, and its share of the
    thread pool would make the export wait behind the simulation's work."""
    _policy.split = bool(enabled)


def launch(kernel, dim: int | tuple[int, ...], inputs, outputs=(), device=None,
           min_range: int = _launch_module.MIN_RANGE, tag=None) -> None:
    """``warp_sph.core.launch.launch`` for the surface kernels, without splitting where
    :func:`split_launches` turned it off for this thread; 1-D launches are replayed from a
    recording (``replay.py``; ``tag`` names the call site of a kernel launched from several)."""
    if not getattr(_policy, "split", True):
        min_range = 1 << 30
    if isinstance(dim, tuple) or dim <= 0:
        _launch_module.launch(kernel, dim, inputs, outputs, device=device, min_range=min_range)
        return
    replay(kernel, dim, inputs, outputs, device, min_range, tag)


def read_int32(arr: wp.array, index: int) -> int:
    """``arr[index]`` of a 1-D int32 array, on the host (a scan's total). On the CPU it is read in
    place (launches there are synchronous): a numpy view or a one-element slice cost 10-30 us of
    Python each, several times per frame; elsewhere a one-element copy."""
    if arr.device.is_cpu:
        return ctypes.c_int32.from_address(arr.ptr + index * arr.strides[0]).value
    return int(arr[index: index + 1].numpy()[0])


def record(kernel, dim: int, inputs, outputs=(), device=None, min_range: int = _launch_module.MIN_RANGE
           ) -> _launch_module.Recorded:
    """``warp_sph.core.launch.record`` for the surface kernels, without splitting where
    :func:`split_launches` turned it off for this thread."""
    if not getattr(_policy, "split", True):
        min_range = 1 << 30
    return _launch_module.record(kernel, dim, inputs, outputs, device=device, min_range=min_range)


def lattice_weighted_count(support_radius: float, spacing: float) -> float:
    """n = sum_j (1 - r_j^2/R^2) over a full cubic lattice of spacing d around a particle (self
    excluded): 12.5 for R = 2 d (the cubic spline with h = d)."""
    m = int(math.ceil(support_radius / spacing))
    k = np.arange(-m, m + 1, dtype=np.float64)
    r2 = ((np.stack(np.meshgrid(k, k, k, indexing="ij"), -1).reshape(-1, 3) * spacing) ** 2).sum(1)
    r2 = r2[(r2 > 0.0) & (r2 < support_radius**2)]
    return float(np.sum(1.0 - r2 / support_radius**2))


class SparseGrid:
    """Blocks of grid nodes around the particles, particle statistics and Phi on the band.

    Args:
        smoothing: kernel name ("cubic", "quintic", "quadric"); Phi uses its shape.
        h: smoothing length [m].
        particle_radius: r [m] (spacing d = 2 r).
        cell_size: grid cell edge c [m].
        spray_neighbors: a particle with fewer neighbours than this within the support radius is
            spray (not part of the surface).
        surface_fraction: surface particles have a weighted neighbour count below this fraction of
            a full lattice's (0.85: the outermost layer of a flat free surface has ~0.70).
        device: Warp device.
    """

    def __init__(self, smoothing: str, h: float, particle_radius: float, cell_size: float,
                 spray_neighbors: int = 5, surface_fraction: float = 0.85, device="cpu"):
        kernel = get_smoothing_kernel(smoothing)
        self.smoothing = smoothing
        self.h = float(h)
        self.support_radius = float(kernel.support_radius(self.h))
        self.particle_radius = float(particle_radius)
        self.cell_size = float(np.float32(cell_size))
        self.spray_neighbors = int(spray_neighbors)
        self.device = wp.get_device(device)
        # (never wider than the support: a band that wide is the exact classification)
        self.band_radius = min(BAND_RADIUS_R * self.particle_radius + BAND_RADIUS_CELLS * self.cell_size,
                               self.support_radius)
        reach = max(self.support_radius, self.band_radius)
        self.block_nodes = max(4, int(math.ceil(reach / self.cell_size - 1e-6)))
        self.lattice_count = lattice_weighted_count(self.support_radius, 2.0 * self.particle_radius)
        self.surface_count = float(surface_fraction) * self.lattice_count
        # GPU: one thread per node layer of a block; CPU: one per block (threads split over blocks)
        self.slabs = 1 if self.device.is_cpu else self.block_nodes
        self._buf = ArrayPool(self.device)
        self._bounds_init = wp.array([math.inf] * 3 + [-math.inf] * 3 + [0.0], dtype=float, device=self.device)
        self.exact = False
        self.particle_count = 0
        self.band_count = 0

    # -- stages ----------------------------------------------------------------------------------
    def _bounds(self, particle_x: wp.array) -> tuple[np.ndarray, np.ndarray]:
        bounds = self._buf.get("bounds", 7, float)
        wp.copy(bounds, self._bounds_init, count=7)
        launch(_dev.particle_bounds, len(particle_x), [particle_x], [bounds], device=self.device)
        b = bounds.numpy()[:7].astype(np.float64)
        if b[6] > 0 or not np.all(np.isfinite(b[:6])):
            raise SimulationError(f"surface reconstruction: {int(b[6])} particle positions are not finite")
        return b[:3], b[3:6]

    def _unique(self, keys: wp.array, n: int, prefix: str, divisor: int = 1) -> tuple[int, wp.array, wp.array, wp.array]:
        """Runs of equal keys // divisor in sorted keys[:n]: (count, run keys // divisor, run starts, run lengths)."""
        head = self._buf.get(prefix + "_head", n, wp.int32)
        scan = self._buf.get(prefix + "_scan", n, wp.int32)
        div = wp.int64(divisor)
        launch(_dev.mark_runs, n, [keys, div], [head], device=self.device, min_range=LIGHT_MIN_RANGE, tag=prefix)
        wp.utils.array_scan(head[:n], scan[:n], inclusive=True)
        runs = read_int32(scan, n - 1)
        run_key = self._buf.get(prefix + "_key", runs, wp.int64)
        run_start = self._buf.get(prefix + "_start", runs, wp.int32)
        run_len = self._buf.get(prefix + "_len", runs, wp.int32)
        launch(_dev.compact_runs, n, [keys, div, head, scan], [run_key, run_start], device=self.device,
               min_range=LIGHT_MIN_RANGE, tag=prefix)
        launch(_dev.run_lengths, runs, [run_start, runs, n], [run_len], device=self.device, min_range=LIGHT_MIN_RANGE,
               tag=prefix)
        return runs, run_key, run_start, run_len

    def build(self, particle_x: wp.array) -> None:
        """Sort and classify the particles at ``particle_x`` [m] (wp.array of vec3): steps 1-3.

        Afterwards: ``sorted_index`` (sorted -> particle), ``particle_flag`` (sorted order:
        SPRAY / INTERIOR / SURFACE), ``weighted_count`` (sorted order), and the candidate blocks
        (then ``band.classify(grid)`` and ``field.compute_field(grid)``)."""
        n = len(particle_x)
        self.particle_count = n
        dev = self.device
        lower, upper = self._bounds(particle_x)
        c = self.cell_size
        b = self.block_nodes
        # one empty block (plus a cell) below the particles, so every dilated block index is >= 0
        origin = (lower - (b + 1) * c).astype(np.float32).astype(np.float64)
        self.grid_origin = origin
        top = np.floor((upper - origin) / c).astype(np.int64) // b
        dims = top + 2
        if int(np.prod(dims)) >= 2**62:
            raise SimulationError(f"surface grid of {dims.tolist()} blocks is too large (particles spread over "
                                  f"{(upper - lower).tolist()} m)")
        self.block_dims = wp.vec3i(*(int(v) for v in dims))
        key_bits = max(1, int(np.prod(dims) - 1).bit_length())
        layer_bits = max(1, int(b * np.prod(dims) - 1).bit_length())  # particle keys: block key B + x layer
        o = wp.vec3(*origin)

        keys = self._buf.get("pkeys", 2 * n, wp.int64)
        index = self._buf.get("pindex", 2 * n, wp.int32)
        launch(_dev.particle_block_keys, n, [o, c, b, self.block_dims, particle_x], [keys, index], device=dev,
               min_range=LIGHT_MIN_RANGE)
        wp.utils.radix_sort_pairs(keys, index, n, 0, layer_bits)
        self.sorted_index = index
        n_occ, occ_key, occ_start, occ_len = self._unique(keys, n, "occ", divisor=b)

        dkeys = self._buf.get("dkeys", 2 * 27 * n_occ, wp.int64)
        dindex = self._buf.get("dindex", 2 * 27 * n_occ, wp.int32)
        launch(_dev.dilate_blocks, (n_occ, 27), [occ_key, self.block_dims], [dkeys, dindex], device=dev)
        wp.utils.radix_sort_pairs(dkeys, dindex, 27 * n_occ, 0, key_bits)
        n_cand, cand_key, _, _ = self._unique(dkeys, 27 * n_occ, "cand")
        self.candidate_count = n_cand

        capacity = 1 << max(4, (2 * n_cand - 1).bit_length())
        table_key = self._buf.get("table_key", capacity, wp.int64)[:capacity]
        table_value = self._buf.get("table_value", capacity, wp.int32)[:capacity]
        table_key.fill_(-1)
        launch(_dev.hash_insert, n_cand, [cand_key], [table_key, table_value], device=dev)

        self.block_coord = self._buf.get("coord", n_cand, wp.vec3i)
        self.block_neighbor = self._buf.get("nbr", n_cand, wp.int32, width=27)
        launch(_dev.block_neighbors, n_cand, [cand_key, self.block_dims, table_key, table_value],
               [self.block_coord, self.block_neighbor], device=dev, min_range=BLOCK_MIN_RANGE)
        self.block_count = self._buf.get("bcount", n_cand, wp.int32)
        self.block_count.zero_()
        self.layer_start = self._buf.get("lstart", n_cand, wp.int32, width=b + 1)
        self.particle_block = self._buf.get("pblock", n, wp.int32)
        launch(_dev.block_particle_ranges, n_occ, [occ_key, occ_start, occ_len, keys, b, table_key, table_value],
               [self.block_count, self.layer_start, self.particle_block], device=dev)

        self.sorted_x = self._buf.get("sorted_x", n, wp.vec3)
        launch(_dev.gather_sorted, n, [particle_x, index], [self.sorted_x], device=dev, min_range=LIGHT_MIN_RANGE)
        self.neighbor_count = self._buf.get("ncount", n, wp.int32)
        self.weighted_count = self._buf.get("wcount", n, float)
        self.kernel_sum = self._buf.get("ksum", n, float)
        launch(_dev.particle_stats, n, [self.support_radius, wp.vec3(*self.grid_origin), self.cell_size, self.block_nodes,
                                        self.block_coord, self.sorted_x, self.particle_block, self.block_neighbor,
                                        self.layer_start, self.block_count],
               [self.neighbor_count, self.weighted_count, self.kernel_sum], device=dev)
        self.particle_flag = self._buf.get("pflag", n, wp.int32)
        self.inv_kernel_sum = self._buf.get("invk", n, float)
        launch(_dev.classify_particles, n, [self.spray_neighbors, self.surface_count, self.neighbor_count,
                                            self.weighted_count, self.kernel_sum],
               [self.particle_flag, self.inv_kernel_sum], device=dev, min_range=LIGHT_MIN_RANGE)

    # -- host views ------------------------------------------------------------------------------
    def spray_mask(self) -> np.ndarray:
        """bool per particle (original order): True for spray."""
        n = self.particle_count
        mask = np.zeros(n, dtype=bool)
        if n:
            flags = self.particle_flag.numpy()[:n]
            mask[self.sorted_index.numpy()[:n]] = flags == 0
        return mask
