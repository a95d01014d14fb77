"""DFSPH's search with a skin (``dfsph.search_skin``): the pair values of ``kernels/dfsph_search.py``
recomputed every step from neighbour lists built within H_s + skin (``fluid_pairs_kernel``; the wall
terms: ``boundary_factor_kernel(..., lists=True)`` there), the skin test (``max_drift_chunks``) and the
copy of the padded rows into the compressed rows of ``DfsphPairs`` (``compact_pairs``); host half
``warp_sph/methods/solvers/dfsph_search.py``. Kernels taking ``tid_offset`` write only their own
particle: bitwise the same for any thread count.
"""
import functools

import warp as wp

from .neighbors import NeighborList
from .smoothing import SMOOTHING_FUNCTIONS


@functools.cache
def fluid_pairs_kernel(smoothing: str):
    """The fluid half of the search with the search skin: no cell walk, the pairs come from the fluid
    neighbour list (built within H_s + skin, self included, by ``NeighborLists.build_lists`` when a
    particle moved more than half the skin since the last build). For particle i (threads in cell
    order) every listed j closer than the support radius, in the list's order: writes the padded
    rows of j != i (pair_index_out, pair_gradient_out G_ij), room_out[i] = their number, and the fluid
    parts of rho_i = m sum_j W_ij (self included) [kg/m^3], s_i, sum_j |G_ij|^2 and delta_i(v) [1/s]
    (finished by ``boundary_factor_kernel`` with ``lists``): the values of ``fluid_search_kernel``,
    summed in another order (equal to float rounding)."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.kernel(enable_backward=False, module="unique")
    def fluid_pairs(
        tid_offset: int,
        # Fluid neighbour lists (within H_s + skin, self included):
        fluid_neighbors: NeighborList,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        # State in:
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        # Out:
        pair_index_out: wp.array2d(dtype=wp.int32),
        pair_gradient_out: wp.array2d(dtype=wp.vec3),
        room_out: wp.array(dtype=wp.int32),
        particle_density_out: wp.array(dtype=float),
        gradient_sum_out: wp.array(dtype=wp.vec3),
        square_sum_out: wp.array(dtype=float),
        divergence_out: wp.array(dtype=float),
    ):
        i = fluid_neighbors.order[wp.tid() + tid_offset]
        xi = particle_x[i]
        vi = particle_v[i]
        h = smoothing_length
        volume = particle_mass / rest_density
        radius2 = support_radius * support_radius
        # the listed j closer than the support radius into the padded row, without a branch (as the
        # walk of ``fluid_search_kernel``: about half of the listed pairs are kept) ...
        last = pair_index_out.shape[1] - 1
        found = int(0)
        e = int(0)
        e_end = wp.min(fluid_neighbors.count[i], fluid_neighbors.index.shape[1])
        while e < e_end:
            j = fluid_neighbors.index[i, e]
            x_ij = xi - particle_x[j]
            pair_index_out[i, wp.min(found, last)] = j
            found += wp.where(wp.dot(x_ij, x_ij) < radius2, 1, 0)
            e += 1
        # ... then their values (i itself adds W(0) to the density and is dropped from the row)
        w_sum = float(0.0)
        s = wp.vec3(0.0)
        sq = float(0.0)
        div = float(0.0)
        n = int(0)
        e = int(0)
        while e < found:
            j = pair_index_out[i, e]
            x_ij = xi - particle_x[j]
            w_sum += wp.static(value)(wp.length(x_ij), h)
            if j != i:
                g = volume * wp.static(gradient)(x_ij, h)
                s += g
                sq += wp.dot(g, g)
                div += wp.dot(vi - particle_v[j], g)
                pair_index_out[i, n] = j
                pair_gradient_out[i, n] = g
                n += 1
            e += 1
        room_out[i] = n
        particle_density_out[i] = particle_mass * w_sum
        gradient_sum_out[i] = s
        square_sum_out[i] = sq
        divergence_out[i] = div

    return fluid_pairs


@wp.kernel(enable_backward=False)
def max_drift_chunks(
    chunk: int,
    count: int,
    # In:
    particle_x: wp.array(dtype=wp.vec3),
    searched_x: wp.array(dtype=wp.vec3),
    # Out:
    partial_out: wp.array(dtype=float),
):
    """partial_out[k] = the largest |x_i - x_i at the last list build|^2 [m^2] of particles
    k chunk .. (k + 1) chunk - 1 (below ``count``): the skin test of the search."""
    k = wp.tid()
    lo = k * chunk
    hi = wp.min(lo + chunk, count)
    s = float(0.0)
    for i in range(lo, hi):
        s = wp.max(s, wp.length_sq(particle_x[i] - searched_x[i]))
    partial_out[k] = s


@wp.kernel(enable_backward=False)
def compact_pairs(
    tid_offset: int,
    # In:
    neighbor_index: wp.array2d(dtype=wp.int32),
    pair_gradient: wp.array2d(dtype=wp.vec3),
    room: wp.array(dtype=wp.int32),
    offset: wp.array(dtype=wp.int32),
    # Out:
    count_out: wp.array(dtype=wp.int32),
    index_out: wp.array(dtype=wp.int32),
    gradient_out: wp.array(dtype=wp.vec3),
):
    """Row i of the padded pairs to entries offset[i] .. offset[i] + room[i] - 1 (offset: the exclusive
    prefix sum of room)."""
    i = wp.tid() + tid_offset
    base = offset[i]
    n = room[i]
    count_out[i] = n
    k = int(0)
    while k < n:
        index_out[base + k] = neighbor_index[i, k]
        gradient_out[base + k] = pair_gradient[i, k]
        k += 1
