"""Surface decimation to a triangle budget or an error bound: quadric-error edge collapses
(Garland & Heckbert 1997) in parallel rounds of independent collapses.

Device code: ``kernels/surface_decimation.py``; the mesh is compacted by ``compaction.py``. Every round rebuilds the connectivity, costs each
edge, collapses the edges that are cheaper than every edge around them, and drops the two faces of
each collapsed edge; it stops when the mesh has at most ``triangle_budget`` triangles, when no edge
is cheaper than ``max_error``^2 (the squared distances of the merged vertex from the planes of all the
original faces it stands for sum to at most max_error^2, so it lies within max_error of each), after
a round that merged under 1 % of the vertices, or after ``max_rounds``. Collapses keep the mesh closed and manifold (link
condition) and turn no face by more than ``max_turn_deg``.
"""
from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..core.buffers import ArrayPool
from ..core.errors import SceneError
from ..core.launch import LIGHT_MIN_RANGE
from ..kernels import surface_decimation as _dev
from .compaction import drop_degenerate, drop_merged_vertices, identity_maps
from .grid import launch
from .smoothing import MeshConnectivity

_RANGE = LIGHT_MIN_RANGE // 8
#: stop after a round that merges fewer than this fraction of the vertices
MIN_ROUND_FRACTION = 0.01


class Decimator:
    """Edge-collapse decimation of closed triangle meshes on the device.

    Args:
        max_error: bound [m] on the summed squared distances (squared) of a merged vertex from the
            planes of the original faces it replaces (0: no bound, then ``triangle_budget`` alone
            stops it).
        triangle_budget: stop once the mesh has at most this many triangles (0: no budget).
        length_scale: a length [m] of the mesh's finest detail (the particle radius); costs below
            (1e-3 length_scale)^2 share the first priority bucket (default: max_error).
        max_rounds: most collapse rounds per call (each rebuilds the connectivity).
        passes: selection passes per round; each further pass selects among the edges whose faces no
            collapse of the round touched.
        max_turn_deg: largest change of a face normal a collapse may cause [degrees].
    """

    def __init__(self, max_error: float = 0.0, triangle_budget: int = 0, length_scale: float = 0.0,
                 max_rounds: int = 40, passes: int = 3, max_turn_deg: float = 60.0, device=None):
        if max_error < 0.0 or triangle_budget < 0:
            raise SceneError(f"decimation needs max_error >= 0 and triangle_budget >= 0; got {max_error}, "
                             f"{triangle_budget}")
        if max_error == 0.0 and triangle_budget == 0:
            raise SceneError("decimation needs an error bound or a triangle budget")
        self.max_error = float(max_error)
        self.length_scale = float(length_scale or max_error)
        if not self.length_scale > 0.0:
            raise SceneError("decimation with a triangle budget alone needs a length_scale > 0 [m]")
        self.triangle_budget = int(triangle_budget)
        self.max_rounds = int(max_rounds)
        self.passes = max(1, int(passes))
        self.min_cos = math.cos(math.radians(max_turn_deg))
        self.device = device
        self.rounds = 0
        self._buf: ArrayPool | None = None  # on the device of the first call
        self._conn: MeshConnectivity | None = None

    def decimate(self, vertex_x: wp.array, triangles: wp.array, connectivity: MeshConnectivity | None = None
                 ) -> tuple[wp.array, wp.array]:
        """Decimated (vertices (V',) vec3 [m], triangles (T',) vec3i); the inputs are not changed.
        connectivity: that of (vertex_x, triangles) if the caller has it (saves the first build)."""
        dev = wp.get_device(self.device if self.device is not None else vertex_x.device)
        if self.device is None or self._conn is None:
            self.device = dev
            self._conn = MeshConnectivity(dev)
            self._buf = ArrayPool(dev)
        nv, nt = len(vertex_x), len(triangles)
        x = self._buf.get("x", nv, wp.vec3)[:nv]
        wp.copy(x, vertex_x)
        tris = self._buf.get("tris", nt, wp.vec3i)[:nt]
        wp.copy(tris, triangles)
        tris_b = self._buf.get("tris_b", nt, wp.vec3i)
        vmap = self._buf.get("map", nv, wp.int32)
        vindex = self._buf.get("vindex", nv, wp.int32)
        blocked = self._buf.get("blocked", nv, wp.int32)
        identity_maps(nv, vmap, vindex, blocked, dev)
        quadric = self._buf.get("q", nv, wp.mat44)
        best_key = self._buf.get("bk", nv, wp.int64)
        best_cost = self._buf.get("bc", nv, float)
        best_other = self._buf.get("bo", nv, wp.int32)
        best_slot = self._buf.get("bs", nv, wp.int32)
        collapsed = self._buf.get("col", nv, wp.int32)
        collapsed_sum = self._buf.get("cols", nv, wp.int32)
        locked = self._buf.get("locked", nv, wp.int32)
        alive = self._buf.get("alive", nt, wp.int32)
        alive_scan = self._buf.get("ascan", nt, wp.int32)
        max_cost = self.max_error**2 if self.max_error > 0.0 else float(np.finfo(np.float32).max)
        cost_scale = max_cost / 64.0 if self.max_error > 0.0 else (1e-3 * self.length_scale) ** 2
        conn = connectivity if connectivity is not None else self._conn.build(nv, tris)
        launch(_dev.vertex_quadrics, nv, [x, tris, conn.face_start, conn.face_count, conn.faces], [quadric],
               device=dev, min_range=_RANGE)
        self.rounds = 0
        while self.rounds < self.max_rounds and nt > 0 and not (self.triangle_budget and nt <= self.triangle_budget):
            self.rounds += 1
            cost = self._buf.get("ecost", 6 * nt, float)
            ex = self._buf.get("ex", 6 * nt, wp.vec3)
            launch(_dev.edge_costs, nv, [x, quadric, blocked, conn.face_start, conn.neighbors, conn.neighbor_count],
                   [cost, ex], device=dev, min_range=_RANGE)
            collapsed.zero_()
            locked.zero_()
            for sub in range(self.passes):
                launch(_dev.vertex_best_edge, nv, [cost_scale, conn.face_start, conn.neighbors, conn.neighbor_count, cost,
                                                   locked], [best_key, best_cost, best_other, best_slot], device=dev,
                       min_range=_RANGE)
                launch(_dev.collapse_edges, nv, [max_cost, self.min_cos, tris, conn.face_start, conn.face_count,
                                                 conn.faces, conn.neighbors, conn.neighbor_count, best_key, best_cost,
                                                 best_other, best_slot, ex], [x, quadric, vmap, blocked, collapsed],
                       device=dev, min_range=_RANGE)
                if sub + 1 < self.passes:
                    launch(_dev.lock_collapsed, nv, [conn.face_start, conn.neighbors, conn.neighbor_count, collapsed,
                                                     best_other], [locked], device=dev, min_range=_RANGE)
            wp.utils.array_scan(collapsed[:nv], collapsed_sum[:nv], inclusive=True)
            ncol = int(collapsed_sum[nv - 1: nv].numpy()[0])
            if ncol == 0:
                break
            # a round that merges under MIN_ROUND_FRACTION of the vertices (~ nt / 2) is the last: the
            # next ones would cost as much for less (measured at 59k particles: 33 rounds to converge,
            # the last 16 of them for 5 % of the triangles)
            last = ncol < MIN_ROUND_FRACTION * 0.5 * nt
            n_alive = drop_degenerate(tris, vmap, vindex, alive, alive_scan, tris_b, dev)
            tris, tris_b = tris_b[:n_alive], tris
            nt = n_alive
            if last or self.rounds >= self.max_rounds or (self.triangle_budget and nt <= self.triangle_budget):
                break  # no connectivity for a round that will not run
            conn = self._conn.build(nv, tris)
        # drop the vertices collapses removed, renumber the triangles
        return drop_merged_vertices(x, tris, vmap, vindex, self._buf, dev)
