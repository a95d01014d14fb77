"""Mesh compaction after vertex merges (the decimation's edge collapses), on the device: a vertex map
(each vertex -> the vertex it merged into, itself if kept) renumbers the triangles, degenerate ones
are dropped, and at the end the unused vertices are dropped. Device code: ``kernels/surface_compaction.py``.
"""
from __future__ import annotations

import warp as wp

from ..core.buffers import ArrayPool
from ..core.launch import LIGHT_MIN_RANGE
from ..kernels import surface_compaction as _dev
from .grid import launch


def identity_maps(count: int, vertex_map: wp.array, vertex_index: wp.array, blocked_with: wp.array, device) -> None:
    """vertex_map[v] = vertex_index[v] = v and blocked_with[v] = -1 for the first ``count`` vertices."""
    launch(_dev.identity_map, count, [], [vertex_map, vertex_index, blocked_with], device=device,
           min_range=LIGHT_MIN_RANGE)


def drop_degenerate(triangles: wp.array, vertex_map: wp.array, vertex_index: wp.array, alive: wp.array,
                    alive_scan: wp.array, triangles_out: wp.array, device) -> int:
    """Renumber ``triangles`` (T,) in place through ``vertex_map`` and pack those with three distinct
    vertices, renumbered by ``vertex_index``, into ``triangles_out``; returns their count.
    alive, alive_scan: scratch of at least T entries."""
    nt = len(triangles)
    launch(_dev.remap_triangles, nt, [vertex_map], [triangles, alive], device=device, min_range=LIGHT_MIN_RANGE)
    wp.utils.array_scan(alive[:nt], alive_scan[:nt], inclusive=True)
    n_alive = int(alive_scan[nt - 1: nt].numpy()[0])
    launch(_dev.compact_triangles, nt, [triangles, alive, alive_scan, vertex_index], [triangles_out[:n_alive]],
           device=device, min_range=LIGHT_MIN_RANGE)
    return n_alive


def drop_merged_vertices(vertex_x: wp.array, triangles: wp.array, vertex_map: wp.array, vertex_index: wp.array,
                         pool: ArrayPool, device) -> tuple[wp.array, wp.array]:
    """(kept vertices (V',) vec3 [m], triangles (T,) vec3i renumbered to them): the vertices the map
    kept (vertex_map[v] == v), in order; scratch arrays come from the caller's ``pool``."""
    nv, nt = len(vertex_x), len(triangles)
    kept = pool.get("kept", nv, wp.int32)
    kept_scan = pool.get("kscan", nv, wp.int32)
    launch(_dev.kept_vertices, nv, [vertex_map], [kept], device=device, min_range=LIGHT_MIN_RANGE)
    wp.utils.array_scan(kept[:nv], kept_scan[:nv], inclusive=True)
    n_kept = int(kept_scan[nv - 1: nv].numpy()[0]) if nv else 0
    x_out = pool.get("x_out", n_kept, wp.vec3)[:n_kept]
    launch(_dev.compact_vertices, nv, [vertex_x, kept, kept_scan], [x_out, vertex_index], device=device,
           min_range=LIGHT_MIN_RANGE)
    ones = pool.get("ones", nt, wp.int32)[:nt]
    ones.fill_(1)
    alive_scan = pool.get("ascan", nt, wp.int32)
    wp.utils.array_scan(ones, alive_scan[:nt], inclusive=True)
    t_out = pool.get("t_out", nt, wp.vec3i)[:nt]
    launch(_dev.compact_triangles, nt, [triangles, ones, alive_scan, vertex_index], [t_out], device=device,
           min_range=LIGHT_MIN_RANGE)
    return x_out, t_out
