"""DFSPH's per-step search on the host (``DfsphSearch``, a base of ``DfsphSolver``): the pair cache
and search kernels it allocates, and the one search per step that launches ``kernels/dfsph_search.py``
(neighbour lists, density, factor f_i = 1/D_i [m^2], the pair cache G_ij = V grad W_ij [1/m] in
one row per particle, divergence source and warm start). ``dfsph.py`` decides when it runs (the "density"
and "stabilize" stages) and runs the solves on what it leaves; the attributes the search reads
(``factor_floor``, ``neighbor_threshold``, ``with_bodies``, ``config``, ``skin``) are set by
``DfsphSolver.__init__``.

Search skin (``dfsph.search_skin`` = s > 0): the neighbour lists hold the pairs within H_s + s and are
built (``NeighborLists.build_lists``, the shared list kernel) only when a particle moved more than s / 2
since the last build (or the particle count, the list capacity or a moving boundary changed); every
step then recomputes the pair values from the lists, keeping the pairs closer than H_s. The values
equal those of the per-step search up to float rounding (the sums run in the lists' order). With
s = 0 the one search of ``kernels/dfsph_search.py`` runs every step, bitwise as before.

A helper of the solver ``dfsph.py`` (it registers nothing; the registry imports it harmlessly).
"""
from __future__ import annotations

import warp as wp

from ...core.launch import LIGHT_MIN_RANGE, MIN_RANGE, cpu_threads, launch, run_loop
from ...core.smoothing import get_smoothing_kernel, lattice_offsets
from ...kernels import dfsph_factor as _factor
from ...kernels import dfsph_search as _search
from ...kernels import dfsph_skin as _skin
from ...kernels import reduction as _reduce
from ...neighbors import wall_reach as _walls

#: neighbours (fluid + boundary, self excluded) a particle needs for its divergence error to count,
#: on the cubic lattice with support 2d (26 interior, 17 on a flat free surface; SPlisHSPlasH: 20)
NEIGHBOR_THRESHOLD_CUBIC = 20
#: D_i d^2 below this: the particle is nearly isolated and gets no pressure (f_i = 0)
FACTOR_FLOOR = 1e-6


def neighbor_threshold(smoothing: str, h: float, spacing: float) -> int:
    """SPlisHSPlasH's 20-neighbour rule scaled with the support: round(20/26 N) for N neighbours of an
    interior particle of a cubic lattice at spacing d (N = 26 for support 2d)."""
    kernel = get_smoothing_kernel(smoothing)
    interior = len(lattice_offsets(spacing, kernel.support_radius(h))) - 1
    return int(round(NEIGHBOR_THRESHOLD_CUBIC * interior / 26.0))


class DfsphSearch:
    """The neighbour search, density, factor and pair cache of divergence-free SPH, once per step."""

    def _allocate_search(self) -> None:
        """The pair cache (the workspace field ``dfsph_pairs``), the search's scratch and its kernels."""
        sim, m = self.sim, self.model
        n, dev = m.capacity, m.device
        size = max(n, 1)
        pairs = _search.DfsphPairs()
        for name, dtype in (("offset", wp.int32), ("count", wp.int32), ("gradient_sum", wp.vec3),
                            ("boundary_gradient", wp.vec3), ("boundary_velocity", float), ("active", wp.int32)):
            setattr(pairs, name, wp.zeros(size, dtype=dtype, device=dev))
        sim.fields["dfsph_pairs"] = pairs
        self._room = wp.zeros(size, dtype=wp.int32, device=dev)    # pairs kept per particle (search skin)
        self._square_sum = wp.zeros(size, dtype=float, device=dev)  # sum_j |G_ij|^2 (fluid part of D_i)
        self._pairs_capacity = 0
        # CPU: the search writes its pair rows packed, one range of sorted indices per thread
        self._packed_rows = dev.is_cpu
        self._search = _search.fluid_search_kernel(m.smoothing.name, packed=self._packed_rows)
        terms = sim.boundary_terms
        moving = self.with_bodies and self.nl.moving_cells is not None
        # static walls: their sub-cell lists in reach (``neighbors/wall_reach.py``, built on the first search)
        self._wall_subcells = _walls.WALL_SUBCELLS if self.nl.boundary_cells is not None else 0
        self._walls = None
        self._boundary_factor = _factor.boundary_factor_kernel(m.smoothing.name, terms, m.boundary_count > 0, moving,
                                                               walls=self._wall_subcells > 0)
        self._no_volume = wp.zeros(1, dtype=float, device=dev)
        self._no_mask = wp.zeros(1, dtype=wp.uint8, device=dev)
        self._no_cells = wp.zeros(2, dtype=wp.int32, device=dev)  # an empty grid: one cell, no point
        self.list_builds = 0   # list builds with the search skin (tests and run statistics read it)
        if self.skin > 0.0:
            self._pairs_from_lists = _skin.fluid_pairs_kernel(m.smoothing.name)
            self._boundary_from_lists = _factor.boundary_factor_kernel(m.smoothing.name, terms, m.boundary_count > 0,
                                                                       moving, lists=True)
            self._searched_x = wp.zeros(size, dtype=wp.vec3, device=dev)  # x at the last list build
            self._drift_partial = wp.zeros(max(1, -(-size // _reduce.REDUCE_CHUNK)), dtype=float, device=dev)
            self._built = None  # (particle count, list arrays) of the last build

    def _pairs(self):
        """The pair cache, sized for the fluid lists' capacity (which grows on overflow): the rows the solves
        read (row i at i x capacity on a device, packed on the CPU; with the skin compressed, and a padded row per particle for the pair pass)."""
        pairs = self.sim.fields["dfsph_pairs"]
        capacity = self.nl.capacities[0]
        if capacity != self._pairs_capacity:
            n, dev = max(self.model.capacity, 1), self.model.device
            pairs.index = wp.zeros(n * capacity, dtype=wp.int32, device=dev)
            pairs.gradient = wp.zeros(n * capacity, dtype=wp.vec3, device=dev)
            if self.skin > 0.0:  # padded rows of the pairs (the lists themselves hold H_s + skin)
                self._pair_rows = wp.zeros((n, capacity), dtype=wp.vec3, device=dev)
                self._pair_index_rows = wp.zeros((n, capacity), dtype=wp.int32, device=dev)
            self._pairs_capacity = capacity
        return pairs

    @property
    def nl(self):
        return self.sim.fields["neighbor_lists"]

    # --- passes ----------------------------------------------------------------------------
    def search(self, dt: float) -> None:
        """The step's one search at the current x (the fluid sorted into cells by the "neighbors" stage):
        neighbour lists, density, pair cache, factor, divergence source and warm start."""
        if self.skin > 0.0:
            self._search_with_skin(dt)
            return
        m, f = self.model, self.sim.fields
        nl = self.nl
        n, dev = m.fluid_count, m.device
        pairs = self._pairs()
        fc = nl.fluid_cells
        ranges = cpu_threads() if self._packed_rows else 0
        search = (self._search, ranges if self._packed_rows else n,
                  [n, max(ranges, 1), fc.lo, fc.inv_cell_size, fc.dims, fc.cell_start, fc.cell_point, fc.sorted_x,
                   m.support_radius,
                   m.particle_mass, m.smoothing_length, m.rest_density, f["particle_v"]],
                  [nl.fluid.count, nl.fluid.index, nl.max_count, pairs.offset, pairs.count, pairs.index, pairs.gradient,
                   f["particle_density"], pairs.gradient_sum, self._square_sum, f["dfsph_divergence_source"]])
        empty = [wp.vec3(0.0), 0.0, wp.vec3i(1, 1, 1), self._no_cells, self._no_cells, m.boundary_x,
                 self._no_volume, self._no_mask, 0]
        bc = nl.boundary_cells
        if bc is not None:
            mask = nl.boundary_mask
            grid = [bc.lo, bc.inv_cell_size, bc.dims, bc.cell_start, bc.cell_point, bc.sorted_x,
                    nl.boundary_weight, self._no_mask if mask is None else mask, int(mask is not None)]
        else:
            grid = list(empty)
        grid += self._wall_reach(bc)
        mc = nl.moving_cells if self.with_bodies else None
        if mc is not None:  # the bodies' particles, after the static ones (``NeighborLists.update_moving``)
            mask = nl.moving_mask
            grid += [mc.lo, mc.inv_cell_size, mc.dims, mc.cell_start, mc.cell_point, mc.sorted_x,
                     nl.moving_weight, self._no_mask if mask is None else mask, int(mask is not None), nl.moving_start]
        else:
            grid += empty + [0]
        factor = (self._boundary_factor, n,
                  grid + [m.smoothing_length, m.support_radius, m.rest_density, self.factor_floor,
                          self.neighbor_threshold, self.sim.boundary_params, m.boundary_v, float(self.config.warm_start),
                          1.0 / dt if dt > 0 else 0.0, fc.cell_point, f["particle_x"], f["particle_v"],
                          f["dfsph_divergence_warm"], nl.fluid.count, self._square_sum, m.boundary_x, self._no_volume,
                          f["particle_density"], pairs.gradient_sum, f["dfsph_divergence_source"]],
                  [nl.boundary.count, nl.boundary.index, nl.max_count, pairs.boundary_gradient,
                   pairs.boundary_velocity, pairs.active, f["dfsph_factor"], f["dfsph_divergence_pressure"],
                   f["dfsph_acceleration"], f["dfsph_error"], f["boundary_force"]])
        replays = getattr(self, "_replays", None)
        min_range = 1 if self._packed_rows else MIN_RANGE  # packed: a range per thread
        if replays is not None and self.sweep_loop and n > 0:
            # CPU: the passes in one run_loop (one hand-off, recorded launches; bitwise the launches below)
            run_loop([[replays.get(*search, device=dev, tag="search", min_range=min_range)],
                      [replays.get(*factor, device=dev, tag="search")]], 1)
            return
        if n > 0 or not self._packed_rows:
            launch(*search, device=dev, min_range=min_range)
        launch(*factor, device=dev)

    def _wall_reach(self, cells) -> list:
        """The boundary kernel's arguments for the static walls' sub-cell lists (``WallReach`` over the static
        boundary grid ``cells``, built on first use and again when the grid is replaced); placeholders
        without them."""
        if cells is None or self._wall_subcells <= 0:
            return [0.0, wp.vec3i(1, 1, 1), self._no_cells, self._no_cells]
        if self._walls is None or self._walls.cells is not cells:
            self._walls = _walls.WallReach(cells, self.model.support_radius, self._wall_subcells, self.model.device)
        w = self._walls
        return [w.inv_size, w.dims, w.start, w.entry]

    # --- search skin -----------------------------------------------------------------------
    def _lists_stale(self) -> bool:
        """True when the lists (within H_s + skin) may miss a pair closer than H_s: no build yet, another
        particle count or list arrays (grown), moving boundary particles, or a particle farther than
        skin / 2 from where the lists were built (two particles then close in by at most the skin)."""
        m, nl = self.model, self.nl
        n = m.fluid_count
        if self._built is None or self._built != (n, nl.fluid.index, nl.boundary.index):
            return True
        if nl.moving_cells is not None:
            return True
        launch(_skin.max_drift_chunks, self._drift_partial.shape[0],
               [_reduce.REDUCE_CHUNK, n, self.sim.fields["particle_x"], self._searched_x], [self._drift_partial],
               device=m.device)
        drift2 = float(self._drift_partial.numpy().max())
        return drift2 > (0.5 * self.skin) ** 2

    def _search_with_skin(self, dt: float) -> None:
        """The search with a skin (see the module docstring): lists rebuilt when stale, pair values every step."""
        m, f = self.model, self.sim.fields
        nl = self.nl
        n, dev = m.fluid_count, m.device
        x = f["particle_x"]
        if self._lists_stale():
            nl.build_lists(x)
            wp.copy(self._searched_x, x, count=n)
            self._built = (n, nl.fluid.index, nl.boundary.index)
            self.list_builds += 1
        pairs = self._pairs()
        launch(self._pairs_from_lists, n,
               [nl.fluid, m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, x, f["particle_v"]],
               [self._pair_index_rows, self._pair_rows, self._room, f["particle_density"], pairs.gradient_sum,
                self._square_sum, f["dfsph_divergence_source"]], device=dev)
        empty = [wp.vec3(0.0), 0.0, wp.vec3i(1, 1, 1), self._no_cells, self._no_cells, m.boundary_x,
                 self._no_volume, self._no_mask, 0]
        launch(self._boundary_from_lists, n,
               empty + self._wall_reach(None) + empty + [0]
               + [m.smoothing_length, m.support_radius, m.rest_density, self.factor_floor, self.neighbor_threshold,
                  self.sim.boundary_params, m.boundary_v, float(self.config.warm_start),
                  1.0 / dt if dt > 0 else 0.0, nl.fluid_cells.cell_point, x, f["particle_v"],
                  f["dfsph_divergence_warm"], self._room, self._square_sum,
                  m.boundary_x, m.boundary_volume if m.boundary_volume is not None else self._no_volume,
                  f["particle_density"], pairs.gradient_sum, f["dfsph_divergence_source"]],
               [nl.boundary.count, nl.boundary.index, nl.max_count, pairs.boundary_gradient, pairs.boundary_velocity,
                pairs.active, f["dfsph_factor"], f["dfsph_divergence_pressure"], f["dfsph_acceleration"],
                f["dfsph_error"], f["boundary_force"]], device=dev)
        wp.utils.array_scan(self._room, pairs.offset, inclusive=False)
        launch(_skin.compact_pairs, n, [self._pair_index_rows, self._pair_rows, self._room, pairs.offset],
               [pairs.count, pairs.index, pairs.gradient], device=dev, min_range=LIGHT_MIN_RANGE)
