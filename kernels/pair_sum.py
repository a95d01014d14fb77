"""One neighbour loop for the pair sums of the explicit forces: s_i = sum_j pair(data, i, j, x_ij) over the
neighbours j with |x_ij| < H (x_ij = x_i - x_j [m], H the support radius [m]).

``neighbor_sum(pair, Data, neighbors, skip_self)`` builds the @wp.func once per pair term and neighbour
kind: "list" walks particle i's ``NeighborList`` row, "grid" queries the hash grid; both in their own
order, so a kernel that used to write the two loops by hand sums in the same order (bitwise the same).
``pair`` is a @wp.func (data: Data, i: int, j: int, x_ij: wp.vec3) -> wp.vec3; ``Data`` a @wp.struct
holding what the pair term reads (constants and arrays), filled once per particle by the kernel.
The same loop serves the boundary particles: pass the boundary neighbours and positions.
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import neighbor_count


@functools.cache
def neighbor_sum(pair, Data, neighbors: str = "grid", skip_self: bool = False):
    """sum_pairs(neighbors, x, i, x_i, support_radius, data) -> sum_j pair(data, i, j, x_i - x[j]) [the
    pair's unit] over the neighbours j of point x_i within support_radius [m]; skip_self: leave j = i out."""
    lists = neighbors == "list"
    Neighbors = NEIGHBOR_TYPES[neighbors]

    @wp.func(module="unique")
    def sum_pairs(pair_neighbors: Neighbors, x: wp.array(dtype=wp.vec3), i: int, xi: wp.vec3,
                  support_radius: float, data: Data) -> wp.vec3:
        s = wp.vec3(0.0)
        if wp.static(lists):
            k = int(0)
            k_end = int(neighbor_count(pair_neighbors, i))
            while k < k_end:
                j = pair_neighbors.index[i, k]
                if wp.static(not skip_self) or j != i:
                    x_ij = xi - x[j]
                    if wp.length(x_ij) < support_radius:
                        s += wp.static(pair)(data, i, j, x_ij)
                k += 1
        else:
            query = wp.hash_grid_query(pair_neighbors, xi, support_radius)
            j = int(0)
            while wp.hash_grid_query_next(query, j):
                if wp.static(not skip_self) or j != i:
                    x_ij = xi - x[j]
                    if wp.length(x_ij) < support_radius:
                        s += wp.static(pair)(data, i, j, x_ij)
        return s

    return sum_pairs
