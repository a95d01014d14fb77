"""Neighbour lists over a dense cell grid (report section 7.1/7.2): the fluid sorted by cell once
per step, fixed-capacity lists of fluid and boundary neighbours within the search radius that every
neighbour loop of the step reads. Measured faster on the CPU than ``wp.HashGrid`` queries per pass
(``hash_grid.py`` keeps that variant as a documented choice and the test reference).
"""
from __future__ import annotations

import math

import warp as wp

MAX_CELLS = 1 << 22  # the dense cell grid grows its cell size past the search radius beyond this
MAX_MASK_REACH = 4  # the boundary mask of cells smaller than the search radius spans at most this many cells


class CellGrid:
    """Points sorted by the cell of a dense grid over a fixed box, cell size = search radius /
    ``cells_per_radius`` [m] (larger when the box would need more than MAX_CELLS cells).

    Points outside the box are clamped to its border cells, which keeps every query exact.
    After ``build``: ``cell_point`` (sorted index -> point index), ``sorted_x`` (positions in that
    order [m]) and ``cell_start`` (first sorted index of each cell, shape (cell_count + 1,)).
    """

    def __init__(self, search_radius: float, lo, hi, capacity: int, cells_per_radius: int = 1, device="cpu"):
        import numpy as np

        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        cell = float(search_radius) / cells_per_radius
        while True:
            dims = np.maximum(np.ceil((hi - lo) / cell).astype(np.int64), 1)
            if int(np.prod(dims)) <= MAX_CELLS:
                break
            cell *= 1.25
        self.search_radius = float(search_radius)
        self.cell_size = cell
        self.lo = wp.vec3(*lo.astype(np.float32))
        self.inv_cell_size = float(1.0 / cell)
        self.dims = wp.vec3i(*(int(v) for v in dims))
        self.cell_count = int(np.prod(dims))
        self.device = device
        self.capacity = int(capacity)
        self._keys = wp.zeros(2 * max(capacity, 1), dtype=wp.int32, device=device)
        self.cell_point = wp.zeros(2 * max(capacity, 1), dtype=wp.int32, device=device)
        self.sorted_x = wp.zeros(max(capacity, 1), dtype=wp.vec3, device=device)
        self.cell_start = wp.zeros(self.cell_count + 1, dtype=wp.int32, device=device)
        self.count = 0
        self._key_bits = max(1, int(self.cell_count - 1).bit_length())  # bits of the largest cell key
        self._launcher = None  # ``build``'s launches (``_launch``: replayed on the CPU)

    def build(self, points: wp.array) -> None:
        """Sort ``points`` (wp.array of vec3 [m], at most ``capacity``) by cell."""
        from ..kernels import cell_lists as _grid_dev

        n = points.shape[0]
        if n > self.capacity:
            raise ValueError(f"CellGrid holds {self.capacity} points, got {n}")
        self.count = n
        self._launch(_grid_dev.compute_cell_keys, n, [self.lo, self.inv_cell_size, self.dims, points],
                     [self._keys, self.cell_point])
        if n:
            # keys < cell_count: sort only their low bits (measured 0.22 -> 0.1 ms at 6.9k points)
            wp.utils.radix_sort_pairs(self._keys, self.cell_point, n, 0, self._key_bits)
        self._launch(_grid_dev.compute_cell_start, n + 1, [n, self.cell_count, self._keys], [self.cell_start])
        self._launch(_grid_dev.gather_sorted_points, n, [points, self.cell_point], [self.sorted_x])

    def _launch(self, kernel, dim: int, inputs, outputs) -> None:
        """A light launch of ``build`` (``LIGHT_MIN_RANGE``), replayed on the CPU (``core.launch.replaying_launch``:
        arguments packed again only where they changed; the same ranges as ``launch``, so bitwise the same)."""
        from ..core.launch import LIGHT_MIN_RANGE, replaying_launch

        if self._launcher is None:
            self._launcher = replaying_launch(self.device)
        self._launcher(kernel, dim, inputs, outputs, min_range=LIGHT_MIN_RANGE)

    def occupied_near_mask(self, reach: int = 1) -> wp.array:
        """uint8 per cell: 1 where a point lies in the cell or one of its neighbours up to ``reach`` cells
        away along each axis (26 for reach 1; host, after ``build``). With reach cells >= the search
        radius, a query from a 0 cell finds nothing."""
        import numpy as np

        nx, ny, nz = (int(self.dims[k]) for k in range(3))
        start = self.cell_start.numpy()[: self.cell_count + 1]
        occupied = (np.diff(start) > 0).reshape(nz, ny, nx)
        near = occupied.copy()
        for _ in range(reach):
            for axis in range(3):
                grown = near.copy()
                lo = [slice(None)] * 3
                hi = [slice(None)] * 3
                lo[axis], hi[axis] = slice(0, -1), slice(1, None)
                grown[tuple(lo)] |= near[tuple(hi)]
                grown[tuple(hi)] |= near[tuple(lo)]
                near = grown
        return wp.array(near.reshape(-1).astype(np.uint8), dtype=wp.uint8, device=self.device)


class NeighborLists:
    """Per-step neighbour lists of the fluid: fluid-fluid (self included) and fluid-boundary.

    Built once per step over dense cell grids (``CellGrid``; the boundary one is built once) and
    read by every neighbour loop of the step (density, XSPH, forces). Fixed capacities per
    particle [-]; ``overflow()`` (one host read, once per frame) returns the largest count that did
    not fit, and ``grow`` enlarges the lists for the next steps.

    ``build`` = ``sort`` (fluid particles into cells) + ``build_lists``; ``build_lists`` can also
    sum the SPH density of the listed pairs (WCSPH: one pass for search and density).
    boundary_volume: Akinci V_b per boundary particle [m^3], needed for that density sum.
    Fluid particles in cells with no boundary particle within one cell skip the boundary search.

    Moving boundary particles (rigid bodies): with ``moving_start`` = S < len(boundary_x), particles
    [0, S) are static (their grid is built once, as above) and [S, len) move: a second ``CellGrid``
    (``moving_cells``) over them is rebuilt by ``update_moving`` after they moved (every substep),
    and the boundary lists hold the static neighbours, then the moving ones (indices S + k).
    """

    def __init__(self, search_radius: float, lo, hi, fluid_count: int, boundary_x: wp.array | None = None,
                 fluid_capacity: int = 64, boundary_capacity: int = 48, cells_per_radius: int = 1, device="cpu",
                 boundary_volume: wp.array | None = None, moving_start: int | None = None):
        from ..kernels import neighbors as _dev

        self.search_radius = float(search_radius)
        self.cells_per_radius = int(cells_per_radius)
        self.device = device
        self.fluid_count = int(fluid_count)
        self.fluid_cells = CellGrid(search_radius, lo, hi, fluid_count, cells_per_radius, device=device)
        self.boundary_cells = None
        self.moving_cells = None
        self._no_mask = wp.zeros(1, dtype=wp.uint8, device=device)
        self._no_weight = wp.zeros(1, dtype=float, device=device)
        self._no_density = wp.zeros(1, dtype=float, device=device)
        self._no_params = _dev.NoBoundaryParams()
        self._no_walls = [0.0, wp.vec3i(1, 1, 1), wp.zeros(2, dtype=wp.int32, device=device),
                          wp.zeros(1, dtype=wp.int32, device=device)]
        self._no_keep = [-1.0, wp.zeros(1, dtype=wp.vec3, device=device)]
        #: where each fluid particle's boundary list was last searched [m] (``build_boundary_lists(keep=...)``;
        #: 1e30: search it): written with the row by the list kernel, so the two always agree; part of the lists'
        #: state (whoever saves or restores the boundary rows must save or restore it with them)
        self.boundary_keep_x = wp.full(max(self.fluid_count, 1), wp.vec3(1.0e30), dtype=wp.vec3, device=device)
        #: the static boundary particles in reach of each cell of ``boundary_cells``, built once per run (a
        #: ``WallReach`` of ``neighbors/wall_reach.py``, set by the solver): the boundary lists test
        #: them instead of walking the grid, bitwise the same lists and sums. None: the walk.
        self.static_walls = None
        total = boundary_x.shape[0] if boundary_x is not None else 0
        self.moving_start = total if moving_start is None else int(moving_start)
        if self.moving_start < total:
            k = total - self.moving_start
            self.moving_cells = CellGrid(search_radius, lo, hi, k, cells_per_radius, device=device)
            self._moving_volume = boundary_volume[self.moving_start:] if boundary_volume is not None else None
            self._moving_weight = (wp.zeros(k, dtype=float, device=device) if boundary_volume is not None
                                   else self._no_weight)
            # cells near a moving particle (cells >= the search radius: one cell of growth covers a query)
            mc = self.moving_cells
            self._moving_mask = (wp.zeros(mc.cell_count, dtype=wp.uint8, device=device)
                                 if mc.cell_size >= self.search_radius else None)
            self.update_moving(boundary_x)
            boundary_x = boundary_x[: self.moving_start] if self.moving_start else None
        if boundary_x is not None and boundary_x.shape[0]:
            bc = self.boundary_cells = CellGrid(search_radius, lo, hi, boundary_x.shape[0], cells_per_radius,
                                                device=device)
            bc.build(boundary_x)
            # the mask grows by as many cells as the search radius spans (one for cells >= the radius)
            reach = max(1, math.ceil(self.search_radius / bc.cell_size - 1e-6))
            self._boundary_mask = bc.occupied_near_mask(reach) if reach <= MAX_MASK_REACH else None
            self._boundary_weight = self._no_weight
            if boundary_volume is not None:
                order = bc.cell_point.numpy()[: boundary_x.shape[0]]
                self._boundary_weight = wp.array(boundary_volume.numpy()[order], dtype=float, device=device)
        self._max_count = wp.zeros(max(self.fluid_count, 1), dtype=wp.int32, device=device)  # per particle
        self.fluid = _dev.NeighborList()
        self.boundary = _dev.NeighborList()
        self._allocate(self.fluid, fluid_capacity)
        self._allocate(self.boundary, boundary_capacity if self.has_boundary else 0)

    @property
    def has_boundary(self) -> bool:
        """True when there are boundary particles (static or moving) to list."""
        return self.boundary_cells is not None or self.moving_cells is not None

    def update_moving(self, boundary_x: wp.array) -> None:
        """Re-sort the moving boundary particles ``boundary_x[moving_start:]`` [m] into their cells (after
        they moved), with their volumes in that order (a device gather, no host copy)."""
        from ..core.launch import LIGHT_MIN_RANGE, launch
        from ..kernels import cell_lists as _grid_dev
        from ..kernels import particle_order as _order_dev

        mc = self.moving_cells
        if mc is None:
            return
        moving_x = boundary_x[self.moving_start:]
        mc.build(moving_x)
        if self._moving_volume is not None:
            launch(_order_dev.gather_by_order, mc.count, [mc.cell_point, self._moving_volume], [self._moving_weight],
                   device=self.device, min_range=LIGHT_MIN_RANGE)
        if self._moving_mask is not None:
            self._moving_mask.zero_()
            launch(_grid_dev.mark_near_cells, mc.count, [mc.lo, mc.inv_cell_size, mc.dims, moving_x], [self._moving_mask],
                   device=self.device, min_range=LIGHT_MIN_RANGE)

    def _allocate(self, lists, capacity: int) -> None:
        n = max(self.fluid_count, 1)
        if lists is getattr(self, "boundary", None):
            self.boundary_keep_x.fill_(wp.vec3(1.0e30))  # new rows: every boundary list is searched again
        lists.count = wp.zeros(n, dtype=wp.int32, device=self.device)
        lists.index = wp.zeros((n, max(capacity, 1)), dtype=wp.int32, device=self.device)
        lists.order = self.fluid_cells.cell_point

    def sort(self, particle_x: wp.array) -> None:
        """Sort the fluid positions ``particle_x`` [m] into cells (the first half of ``build``)."""
        self.fluid_cells.build(particle_x)

    def build(self, particle_x: wp.array) -> None:
        """Rebuild both lists for fluid positions ``particle_x`` [m]."""
        self.sort(particle_x)
        self.build_lists(particle_x)

    def build_lists(self, particle_x: wp.array, density_out: wp.array | None = None, smoothing: str = "",
                    smoothing_length: float = 0.0, particle_mass: float = 0.0, rest_density: float = 0.0,
                    boundary_terms=None, boundary_params=None, boundary: bool = True) -> None:
        """Both lists (``boundary`` False: the fluid list alone, the boundary list kept as it is) for the
        positions ``particle_x`` [m] that ``sort`` was given; with ``density_out``
        also rho_i = m sum_j W_ij [+ rho0 sum_b density_b(W_ib, V_b) with a boundary method's
        ``boundary_terms`` that has a density term, and its ``boundary_params``] [kg/m^3] over the same
        pairs (``smoothing`` kernel name, h [m], m [kg], rho0 [kg/m^3]; the boundary term needs
        ``boundary_volume``)."""
        from ..core.launch import launch
        from ..kernels import neighbors as _dev

        with_density = density_out is not None
        boundary_density = (with_density and self.has_boundary and boundary_terms is not None
                            and boundary_terms.density is not None)
        if boundary_density and self.boundary_cells is not None and self._boundary_weight is self._no_weight:
            raise ValueError("NeighborLists: the boundary density term needs boundary_volume")
        kernel = _dev.neighbor_list_kernel(smoothing if with_density else "")
        density = density_out if with_density else self._no_density
        n = particle_x.shape[0]
        fc = self.fluid_cells
        launch(kernel, n,
               [fc.lo, fc.inv_cell_size, fc.dims, fc.cell_start, fc.cell_point, fc.sorted_x, self._no_weight,
                self._no_mask, 0, 0, 0, self.search_radius, float(smoothing_length), float(particle_mass),
                self._no_params] + self._no_walls + self._no_keep + [fc.cell_point, particle_x],
               [self.fluid.count, self.fluid.index, self._max_count, density], device=self.device)
        if not boundary:
            return
        self._build_boundary(particle_x, density, smoothing, smoothing_length, rest_density, boundary_terms,
                             boundary_params, boundary_density)

    def build_boundary_lists(self, particle_x: wp.array, keep: float = -1.0) -> None:
        """The fluid-boundary lists alone for the positions ``particle_x`` [m] that ``sort`` was given (a solver
        that builds the fluid lists in a search of its own, e.g. PBF's fused search and density pass).
        keep [m] >= 0 (static walls only, no moving boundary particles): a particle within ``keep`` of where its
        list was last searched keeps it; with keep <= search radius - H_s the list still holds every wall
        particle closer than H_s, in the same order (the walls are sorted once per run), so a pass that sums the
        pairs closer than H_s gets bitwise the sums of a list searched now."""
        self._build_boundary(particle_x, self._no_density, "", 0.0, 0.0, None, None, False, keep)

    def _build_boundary(self, particle_x, density, smoothing, smoothing_length, rest_density, boundary_terms,
                        boundary_params, boundary_density: bool, keep: float = -1.0) -> None:
        from ..core.launch import launch
        from ..kernels import neighbors as _dev

        n = particle_x.shape[0]
        fc = self.fluid_cells
        if not self.has_boundary:
            return
        kind = (smoothing, boundary_terms) if boundary_density else ("", None)
        kernel = _dev.neighbor_list_kernel(*kind, False)  # the walk (moving boundary particles)
        params = boundary_params if boundary_density else self._no_params
        bc = self.boundary_cells
        if bc is not None:
            mask = self._boundary_mask
            walls = self.static_walls
            listed = walls is not None and walls.cells is bc  # the per-run lists of the static walls, or the walk
            wall_args = [walls.inv_size, walls.dims, walls.start, walls.entry] if listed else self._no_walls
            kept = keep >= 0.0 and self.moving_cells is None and not boundary_density
            keep_args = [float(keep), self.boundary_keep_x] if kept else self._no_keep
            launch(_dev.neighbor_list_kernel(*kind, listed), n,
                   [bc.lo, bc.inv_cell_size, bc.dims, bc.cell_start, bc.cell_point, bc.sorted_x, self._boundary_weight,
                    self._no_mask if mask is None else mask, int(mask is not None), 0, 0, self.search_radius,
                    float(smoothing_length), float(rest_density), params] + wall_args + keep_args
                   + [fc.cell_point, particle_x],
                   [self.boundary.count, self.boundary.index, self._max_count, density], device=self.device)
        mc = self.moving_cells
        if mc is not None:  # the moving particles after the static ones (the lists then hold both)
            mask = self._moving_mask
            launch(kernel, n,
                   [mc.lo, mc.inv_cell_size, mc.dims, mc.cell_start, mc.cell_point, mc.sorted_x, self._moving_weight,
                    self._no_mask if mask is None else mask, int(mask is not None), self.moving_start,
                    int(bc is not None), self.search_radius,
                    float(smoothing_length), float(rest_density), params] + self._no_walls + self._no_keep
                   + [fc.cell_point, particle_x],
                   [self.boundary.count, self.boundary.index, self._max_count, density], device=self.device)

    @property
    def boundary_weight(self):
        """Boundary volume V_b per boundary particle in the boundary grid's cell order [m^3] (a
        one-value placeholder without boundary volumes)."""
        return self._boundary_weight if self.boundary_cells is not None else self._no_weight

    @property
    def moving_weight(self):
        """Volume V_b per moving boundary particle in the moving grid's cell order [m^3] (rebuilt by
        ``update_moving``; a one-value placeholder without boundary volumes or moving particles)."""
        return self._moving_weight if self.moving_cells is not None else self._no_weight

    @property
    def moving_mask(self):
        """uint8 per cell of the moving grid: 0 where no moving particle is within one cell; None when
        there is no moving grid or its cells are smaller than the search radius."""
        return self._moving_mask if self.moving_cells is not None else None

    @property
    def max_count(self):
        """Per fluid particle: the largest neighbour count that did not fit since the last ``overflow``
        (a search kernel of its own writes it as ``build_lists`` does)."""
        return self._max_count

    @property
    def boundary_mask(self):
        """uint8 per cell of the boundary grid: 0 where no boundary particle is within one cell (the fluid
        there skips the boundary search); None when the cells are smaller than the search radius."""
        return self._boundary_mask if self.boundary_cells is not None else None

    @property
    def capacities(self) -> tuple[int, int]:
        return self.fluid.index.shape[1], self.boundary.index.shape[1]

    def overflow(self) -> int:
        """Largest neighbour count that exceeded a capacity since the last call (0: none). Host read."""
        worst = int(self._max_count.numpy().max())
        if worst:
            self._max_count.zero_()
        return worst

    def grow(self, count: int) -> None:
        """Make room for ``count`` neighbours (plus a margin) in both lists."""
        fcap, bcap = self.capacities
        new = int(count * 1.5) + 8
        if new > fcap:
            self._allocate(self.fluid, new)
        if self.has_boundary and new > bcap:
            self._allocate(self.boundary, new)

    def grow_to_fit(self) -> bool:
        """Grow both lists for the largest neighbour count that overflowed a row (one host read); True when they
        grew, so the caller's pass runs again with every pair. The overflow flag is left set: a frame whose steps
        overflowed is still redone by the frame loop (``overflow`` clears it). A start sampled denser than rest
        needs this, its rows holding 1.3x the rest count (DFSPH's and PBF's ``refresh_density``)."""
        worst = int(self._max_count.numpy().max())
        if not worst:
            return False
        before = self.capacities
        self.grow(worst)
        return self.capacities != before


#: fluid list rows hold this many times the neighbours a particle has at rest density within the search radius,
#: (4/3) pi R^3 / V (44.6 at H_s + 0.2 d; the dam break, drop_into_pool, crown_splash and hydrostatic scenes listed at
#: most 52 = 1.17x at their frame ends over 0.5-1 s, the cubic start lattice 33); a row that
#: overflows grows the lists and redoes the frame (``run.frame_loop``). The solvers' pair caches follow: PBF's rows 58 slots
#: at H_s + 0.2 d, against 86 at the lists' general 64 per support volume (issue #32, PBF: the solve stage 5.2-5.5 ->
#: 4.0-4.4 ms per step on a loaded machine; rows packed further gained nothing: docs/performance.md, "PBF's step")
LIST_HEADROOM = 1.3


def list_capacity(search_radius: float, particle_volume: float) -> int:
    """Fluid neighbours per list row [-]: ``LIST_HEADROOM`` (4/3) pi R^3 / V, R the search radius [m] and V = m / rho0
    the volume of a fluid particle [m^3] (the neighbours of a particle at rest density, itself included)."""
    return int(math.ceil(LIST_HEADROOM * (4.0 / 3.0) * math.pi * search_radius ** 3 / particle_volume))


def simulation_neighbor_lists(sim, margin: float = 0.0, cells_per_radius: int = 1, *,
                              fluid_capacity: int | None = None) -> NeighborLists:
    """The simulation's per-step neighbour lists (created on first use, workspace field ``neighbor_lists``).

    Their dense cell grid covers the container, the boundary and the initial fluid, padded by two
    support radii (by a quarter of the extent without a container); particles beyond it stay exact.
    margin [m]: the search radius is H_s + margin (lists that stay complete while particles move
    by up to margin / 2); the capacities grow with the searched volume. cells_per_radius: cells per
    search radius along each axis (2: cells of half the radius, fewer candidates per query). Lists of
    another search radius or cell size are replaced. fluid_capacity: neighbours per fluid row when the lists are
    created (default 64 per support volume of the search radius); lists that exist keep theirs (``grow``).
    """

    import numpy as np

    lists = sim.fields.get("neighbor_lists")
    if lists is not None and (not math.isclose(lists.search_radius, sim.model.support_radius + margin, rel_tol=1e-6)
                              or lists.cells_per_radius != cells_per_radius):
        lists = None  # another search radius or cell size (a solver swapped in): new lists replace the old ones
    if lists is None:
        m = sim.model
        x = sim.state.particle_x.numpy()
        boxes = [x.min(axis=0), x.max(axis=0)] if len(x) else []  # (none yet: a scene that starts empty)
        if m.boundary_count:
            bx = m.boundary_x.numpy()
            boxes += [bx.min(axis=0), bx.max(axis=0)]
        if m.container_lo is not None:
            boxes += [m.container_lo, m.container_hi]
        lo = np.min(boxes, axis=0).astype(np.float64)
        hi = np.max(boxes, axis=0).astype(np.float64)
        pad = 2.0 * m.support_radius + (0.0 if m.container_lo is not None else 0.25 * float(np.max(hi - lo)))
        radius = m.support_radius + margin
        volume = (radius / m.support_radius) ** 3
        with_boundary = m.boundary_count > 0
        lists = NeighborLists(radius, lo - pad, hi + pad, m.capacity,
                              m.boundary_x if with_boundary else None,
                              fluid_capacity=int(fluid_capacity or math.ceil(64 * volume)), boundary_capacity=int(math.ceil(48 * volume)),
                              device=m.device, boundary_volume=m.boundary_volume if with_boundary else None,
                              moving_start=m.static_boundary_count if with_boundary else None,
                              cells_per_radius=cells_per_radius)
        sim.fields["neighbor_lists"] = lists
    return lists
