"""DFSPH's per-step neighbour search, factor and pair cache: the search half of ``kernels/dfsph.py``
(notation there: V = m / rho0 [m^3], G_ij = V grad_i W_ij [1/m], the boundary term gb_ib [1/m],
s_i, D_i, f_i = 1 / D_i [m^2], delta_i(u)); host half ``warp_sph/methods/solvers/dfsph_search.py``.

Neighbours and the factor come from one search per step (``fluid_search_kernel`` here, then
``boundary_factor_kernel`` of ``kernels/dfsph_factor.py``, over the cell grids of
``warp_sph.neighbors.NeighborLists``, walked with ``cell_rows`` / ``row_points`` of
``kernels/neighbors.py``: rows of cells trimmed to the sphere): each pair within
the support radius is found once, and its G_ij goes straight into row i of the pair cache
(``DfsphPairs``; on the CPU the rows are written packed in cell order, one range per thread; a device
puts row i at i x the list capacity), read as one stream per particle by every later pass;
the solves evaluate no smoothing kernel (with the search skin the pairs come from lists, in compressed
rows: ``kernels/dfsph_skin.py``). The same search writes the fluid and boundary
neighbour lists (fluid lists without i itself) that the shared viscosity and XSPH stages read.
Kernels taking ``tid_offset`` are split over CPU cores and write only their own particle (no
atomics), so results are bitwise reproducible for any thread count.
"""
import functools

import warp as wp

from .neighbors import cell_rows, row_points
from .smoothing import SMOOTHING_FUNCTIONS


@wp.struct
class DfsphPairs:
    """The step's fluid pairs in compressed rows, and what the solves need per particle.

    Pairs of particle i (neighbours j != i closer than the support radius): entries
    offset[i] .. offset[i] + count[i] - 1 of index (neighbour j) and gradient (G_ij = V grad_i W_ij
    [1/m]); the 1-D arrays hold fluid_count x the list capacity entries (the per-step search puts row i
    at i x capacity on a device, and packs the rows in cell order per thread range on the CPU;
    the search skin's rows are compressed, one after the other). gradient_sum[i] = s_i [1/m]; boundary_gradient[i] = sum_b gb_ib [1/m];
    boundary_velocity[i] = sum_b v_b . gb_ib [1/s]; active[i] = 1 when i has at least the threshold
    of neighbours (fluid, plus boundary when the boundary enters the density): its divergence error
    counts.
    """

    offset: wp.array(dtype=wp.int32)
    count: wp.array(dtype=wp.int32)
    index: wp.array(dtype=wp.int32)
    gradient: wp.array(dtype=wp.vec3)
    gradient_sum: wp.array(dtype=wp.vec3)
    boundary_gradient: wp.array(dtype=wp.vec3)
    boundary_velocity: wp.array(dtype=float)
    active: wp.array(dtype=wp.int32)


@functools.cache
def fluid_search_kernel(smoothing: str, packed: bool = False):
    """The fluid search in one pass per particle i (threads in cell order, k_i = i's sorted index) over
    the fluid cell grid. First the walk: the sorted indices k of every point within the support radius
    (i itself included), in walk order, into row i of neighbor_index_out (the first ``capacity``; when
    more are found the last slot keeps being overwritten, and the step is redone with larger lists),
    without a branch per candidate (an unpredictable branch per candidate was measured 15 % slower).
    Then, over that row while it is in cache, the kept points in walk order: the fluid neighbour list
    (j != i, rewritten in place; the count is exact; when i and its neighbours do not fit the capacity,
    entries are dropped and max_count_out[i] keeps the largest such number), row i of the pair cache
    (count, index j, G_ij, from its offset) and the fluid parts of: rho_i = m sum_j W_ij (self
    included) [kg/m^3], s_i, sum_j |G_ij|^2 and delta_i(v) [1/s] (finished by ``boundary_factor_kernel``).

    Row i's offset: i x capacity (one thread per particle; a device), or with ``packed`` (the CPU) packed
    in cell order: thread r of ``range_count`` walks the sorted indices [n r / R, n (r + 1) / R) one
    after the other, the first row at its k x capacity and every next one right after the one before (the
    running sum of the counts is their exclusive scan), so no row needs moving afterwards and the solves,
    which visit particles in cell order, read the cache as one stream. The same pairs in the same order
    as the padded rows: every value and sum is bitwise the same for any range count."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.func(module="unique")
    def search_particle(
        k_self: int,
        base: int,
        grid_lo: wp.vec3,
        inv_cell_size: float,
        grid_dims: wp.vec3i,
        cell_start: wp.array(dtype=wp.int32),
        cell_point: wp.array(dtype=wp.int32),
        sorted_points: wp.array(dtype=wp.vec3),
        support_radius: float,
        particle_mass: float,
        smoothing_length: float,
        rest_density: float,
        particle_v: wp.array(dtype=wp.vec3),
        neighbor_count_out: wp.array(dtype=wp.int32),
        neighbor_index_out: wp.array2d(dtype=wp.int32),
        max_count_out: wp.array(dtype=wp.int32),
        pair_offset_out: wp.array(dtype=wp.int32),
        pair_count_out: wp.array(dtype=wp.int32),
        pair_index_out: wp.array(dtype=wp.int32),
        pair_gradient_out: wp.array(dtype=wp.vec3),
        particle_density_out: wp.array(dtype=float),
        gradient_sum_out: wp.array(dtype=wp.vec3),
        square_sum_out: wp.array(dtype=float),
        divergence_out: wp.array(dtype=float),
    ):
        """The search of the particle at sorted index k_self, its pair row written from entry ``base``;
        returns the pairs written (at most the capacity)."""
        i = int(cell_point[k_self])
        xi = sorted_points[k_self]
        q = (xi - grid_lo) * inv_cell_size
        qr = support_radius * inv_cell_size
        radius2 = support_radius * support_radius
        capacity = neighbor_index_out.shape[1]
        rows = cell_rows(q, qr, grid_dims)
        last = capacity - 1
        found = int(0)
        self_rank = capacity  # where i itself falls among the found (kept when < capacity)
        for z in range(rows[2], rows[3] + 1):
            for y in range(rows[0], rows[1] + 1):
                span = row_points(q, qr, y, z, grid_dims, cell_start)
                k = span[0]
                k_end = span[1]
                while k < k_end:
                    x_ij = xi - sorted_points[k]
                    neighbor_index_out[i, wp.min(found, last)] = k
                    self_rank = wp.where(k == k_self, found, self_rank)
                    found += wp.where(wp.dot(x_ij, x_ij) < radius2, 1, 0)
                    k += 1
        # the values over the row just written, in walk order; i itself adds W(0) to the density and is
        # dropped from the lists
        keep = wp.min(found, capacity) - wp.where(self_rank < capacity, 1, 0)
        vi = particle_v[i]
        h = smoothing_length
        volume = particle_mass / rest_density
        w_sum = float(0.0)
        s = wp.vec3(0.0)
        sq = float(0.0)
        div = float(0.0)
        n = int(0)
        e = int(0)
        e_end = wp.min(found, capacity)
        while e < e_end:
            k = neighbor_index_out[i, e]
            x_ij = xi - sorted_points[k]
            w_sum += wp.static(value)(wp.length(x_ij), h)
            j = cell_point[k]
            if j != i and n < keep:
                g = volume * wp.static(gradient)(x_ij, h)
                s += g
                sq += wp.dot(g, g)
                div += wp.dot(vi - particle_v[j], g)
                neighbor_index_out[i, n] = j
                pair_index_out[base + n] = j
                pair_gradient_out[base + n] = g
                n += 1
            e += 1
        pair_offset_out[i] = base
        pair_count_out[i] = n
        written = n
        if found > capacity:  # pairs were dropped: the frame is redone with larger lists
            max_count_out[i] = wp.max(max_count_out[i], found)  # per particle, no atomics
            n = found - 1
        neighbor_count_out[i] = n
        particle_density_out[i] = particle_mass * w_sum
        gradient_sum_out[i] = s
        square_sum_out[i] = sq
        divergence_out[i] = div
        return written

    @wp.kernel(enable_backward=False, module="unique")
    def search_fluid(
        tid_offset: int,
        # Ranges (with ``packed``: the particle count n and the range count R; else unused):
        particle_count: int,
        range_count: int,
        # Fluid cell grid:
        grid_lo: wp.vec3,
        inv_cell_size: float,
        grid_dims: wp.vec3i,
        cell_start: wp.array(dtype=wp.int32),
        cell_point: wp.array(dtype=wp.int32),
        sorted_points: wp.array(dtype=wp.vec3),
        support_radius: float,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        rest_density: float,
        # State in:
        particle_v: wp.array(dtype=wp.vec3),
        # Out:
        neighbor_count_out: wp.array(dtype=wp.int32),
        neighbor_index_out: wp.array2d(dtype=wp.int32),
        max_count_out: wp.array(dtype=wp.int32),
        pair_offset_out: wp.array(dtype=wp.int32),
        pair_count_out: wp.array(dtype=wp.int32),
        pair_index_out: wp.array(dtype=wp.int32),
        pair_gradient_out: wp.array(dtype=wp.vec3),
        particle_density_out: wp.array(dtype=float),
        gradient_sum_out: wp.array(dtype=wp.vec3),
        square_sum_out: wp.array(dtype=float),
        divergence_out: wp.array(dtype=float),
    ):
        capacity = neighbor_index_out.shape[1]
        if wp.static(packed):
            r = wp.tid() + tid_offset
            lo = (particle_count * r) // range_count
            hi = (particle_count * (r + 1)) // range_count
            dest = lo * capacity
            for k_self in range(lo, hi):
                dest += search_particle(k_self, dest, grid_lo, inv_cell_size, grid_dims, cell_start, cell_point,
                                        sorted_points, support_radius, particle_mass, smoothing_length, rest_density,
                                        particle_v, neighbor_count_out, neighbor_index_out, max_count_out,
                                        pair_offset_out, pair_count_out, pair_index_out, pair_gradient_out,
                                        particle_density_out, gradient_sum_out, square_sum_out, divergence_out)
        else:
            k_self = wp.tid() + tid_offset
            search_particle(k_self, int(cell_point[k_self]) * capacity, grid_lo, inv_cell_size, grid_dims,
                            cell_start, cell_point, sorted_points, support_radius, particle_mass, smoothing_length,
                            rest_density, particle_v, neighbor_count_out, neighbor_index_out, max_count_out,
                            pair_offset_out, pair_count_out, pair_index_out, pair_gradient_out, particle_density_out,
                            gradient_sum_out, square_sum_out, divergence_out)

    return search_fluid
