"""PBF's device passes (``PbfPasses``, a base of ``PbfSolver``): the workspace fields it allocates,
the neighbour search on x*, one density pass (density, C, lambda; eq. 7/13, 17, 19) and one Jacobi
correction (eq. 18), launching ``kernels/pbf_pairs.py`` (neighbour lists) or ``kernels/pbf_hash_grid.py``
(the reference variant). ``pbf.py`` decides when they run (stages, the solve loop) and what the
solver reports; the attributes the passes read (``lists``, ``margin``, ``epsilon``, ``max_step``,
``tensile_*``, ``query_radius``, ``allowed_drift``) are set by ``PbfSolver.__init__``.

Cost per step (issue #32): the fluid lists are written by the step's first density pass itself
(``search_density_pass``, ``kernels/pbf_search.py``: one walk over the cells, bitwise the build + pass);
the stabilize stage's density pass at x reads the last step's lists, which still hold every pair
closer than H_s there unless a particle drifted past margin / 2 or the frame reordered the particles
(``reuse_neighbors``); a correction adds dx to x* in its own kernel; a particle keeps its static-wall
list until it moved 0.9 margin from where it was searched (``_wall_keep``); the fluid list rows and the pair
cache's hold ``cell_lists.LIST_HEADROOM`` times the neighbours at rest density (``list_capacity``: 58 slots, not 86).

A helper of the solver ``pbf.py`` (it registers nothing; the registry imports it harmlessly).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ...core.launch import LIGHT_MIN_RANGE, MIN_RANGE, Replays, launch
from ...kernels import pbf as _pbf
from ...kernels import pbf_pairs as _pbf_pairs
from ...kernels import pbf_hash_grid as _pbf_grid
from ...kernels import pbf_search as _pbf_search
from ...kernels import reduction as _reduce
from ...neighbors.cell_lists import list_capacity, simulation_neighbor_lists
from .wcsph_lists import static_wall_lists


class PbfPasses:
    """Density and correction passes of position-based fluids on the simulation's workspace."""

    # --- workspace -------------------------------------------------------------------------
    def _allocate(self) -> None:
        sim, m = self.sim, self.model
        n, dev = m.capacity, m.device  # the particle capacity (emitters: the active count changes)
        wp.copy(sim.allocate("predicted_x", wp.vec3), sim.fields["particle_x"])  # x* = x until the first step
        for name, dtype in (("particle_density", float), ("particle_lambda", float), ("pbf_constraint", float),
                            ("pbf_correction_size", float), ("position_correction", wp.vec3),
                            ("boundary_force", wp.vec3), ("particle_acceleration", wp.vec3),
                            ("pbf_neighbor_x", wp.vec3), ("pbf_constraint_offset", float),
                            ("pbf_neighbor_slot", wp.int32)):
            sim.allocate(name, dtype)
        # moving bodies: sum over the step's corrections of -lambda_i / (rho0 dt^2) (``correction``)
        self._term = sim.allocate("boundary_pressure_term", float) if self.with_bodies else wp.zeros(
            1, dtype=float, device=dev)
        # CPU: each call site's launch recorded once and replayed (``_run``)
        self._replays = Replays() if wp.get_device(dev).is_cpu else None
        chunks = max(1, -(-n // _reduce.REDUCE_CHUNK))
        self._error_partial = wp.zeros(chunks, dtype=float, device=dev)
        self._correction_partial = wp.zeros((chunks, 2), dtype=float, device=dev)
        self._drift_partial = wp.zeros(chunks, dtype=float, device=dev)
        terms = sim.boundary_terms
        tensile = bool(self.config.tensile_correction)
        if self.lists:
            radius = m.support_radius + self.margin
            self.nl = simulation_neighbor_lists(sim, self.margin,
                                                fluid_capacity=list_capacity(radius, m.particle_mass / m.rest_density))
            static_wall_lists(self.nl)
            self._density_kernel = _pbf_pairs.density_lambda_pairs_kernel(m.smoothing.name, terms, tensile)
            self._search_kernel = _pbf_search.search_density_lambda_kernel(m.smoothing.name, terms, tensile)
            self._constraint_kernel = _pbf_search.constraint_kernel(m.smoothing.name, terms)
            self._correction_kernel = _pbf_pairs.correction_pairs_kernel(self._with_boundary_gradient, tensile,
                                                                         self.with_bodies and self._with_boundary_gradient)
            pairs = _pbf_pairs.PairCache()
            pairs.count = wp.zeros(n, dtype=wp.int32, device=dev)
            pairs.boundary_gradient = wp.zeros(n, dtype=wp.vec3, device=dev)
            sim.fields["pbf_pairs"] = pairs
            self._pairs_capacity = 0
        else:
            self.nl = None
            self._density_kernel = _pbf_grid.density_lambda_kernel(m.smoothing.name, terms)
            self._correction_kernel = _pbf_grid.correction_kernel(m.smoothing.name, terms, tensile)

    def _run(self, kernel, dim: int, inputs, outputs=(), min_range: int = MIN_RANGE, tag=None) -> None:
        """``launch`` on the model's device; on the CPU a replay of the launch recorded at this call site
        (``core.launch.Replays``: Warp packs the ~20 arguments once, ~50 us less per launch; the same
        ranges, so bitwise ``launch``). ``tag`` tells apart two call sites of one kernel."""
        if self._replays is None:
            launch(kernel, dim, inputs, outputs, device=self.model.device, min_range=min_range)
        elif dim > 0:
            self._replays.get(kernel, dim, inputs, outputs, device=self.model.device, min_range=min_range,
                              tag=tag).launch()

    @property
    def _wall_keep(self) -> float:
        """How far [m] a particle may be from where its static-wall list was searched and keep it: 0.9 of the lists'
        margin (the walls do not move, so the list still holds every wall particle closer than H_s; rounding
        aside, 0.9); -1 (search every list) without a margin or with moving bodies (``NeighborLists.
        build_boundary_lists``)."""
        if self.neighbor_mode != "margin" or self.with_bodies:
            return -1.0
        return 0.9 * (self.nl.search_radius - self.model.support_radius)

    @property
    def _with_boundary_gradient(self) -> bool:
        terms = self.sim.boundary_terms
        return terms is not None and terms.gradient is not None

    def _pair_cache(self):
        """The PairCache, with rows as long as the fluid lists (which grow on overflow)."""
        pairs = self.sim.fields["pbf_pairs"]
        capacity = self.nl.capacities[0]
        if capacity != self._pairs_capacity:
            n, dev = max(self.model.capacity, 1), self.model.device
            pairs.index = wp.zeros((n, capacity), dtype=wp.int32, device=dev)
            pairs.gradient = wp.zeros((n, capacity), dtype=wp.vec3, device=dev)
            pairs.value = wp.zeros((n, capacity) if self.config.tensile_correction else (1, 1), dtype=float, device=dev)
            self._pairs_capacity = capacity
        return pairs

    def _neighbor_args(self):
        """(boundary_neighbors, fluid_neighbors) kernel arguments."""
        if self.lists:
            return self.nl.boundary, self.nl.fluid
        return self.model.boundary_grid_id, self.sim.fluid_grid.id

    # --- passes ----------------------------------------------------------------------------
    def build_neighbors(self) -> None:
        """Neighbours of the current x*; remember where they were searched."""
        x = self.sim.fields["predicted_x"]
        if self.lists:
            self.nl.sort(x)
            self.nl.build_lists(x, boundary=False)
            self.nl.build_boundary_lists(x, self._wall_keep)
        else:
            self.sim.fluid_grid.build(x)
        self._run(_pbf_search.identity_slots, self.model.fluid_count, [], [self.sim.fields["pbf_neighbor_slot"]],
                  min_range=LIGHT_MIN_RANGE)
        self._searched_at(x)

    def sort_neighbors(self) -> None:
        """The first half of ``build_neighbors`` with lists: the fluid sorted into cells on x* and the boundary
        lists; ``search_density_pass`` then builds the fluid lists (and their slots) and runs the density pass
        in one walk."""
        x = self.sim.fields["predicted_x"]
        self.nl.sort(x)
        self.nl.build_boundary_lists(x, self._wall_keep)
        self._searched_at(x)

    def _searched_at(self, x) -> None:
        """Remember that the neighbours were searched at ``x`` (the drift checks measure from there)."""
        self.grid_builds += 1
        wp.copy(self.sim.fields["pbf_neighbor_x"], x)
        self.last_drift = 0.0

    def search_density_pass(self) -> None:
        """The fluid lists on x* (after ``sort_neighbors``) and, in the same walk over the cells, the density
        pass (``density_pass``; ``kernels/pbf_search.py``): bitwise the lists and values of ``build_neighbors``
        + ``density_pass``."""
        m, f, nl = self.model, self.sim.fields, self.nl
        fc = nl.fluid_cells
        self._run(self._search_kernel, m.fluid_count,
                  [fc.lo, fc.inv_cell_size, fc.dims, fc.cell_start, fc.cell_point, fc.sorted_x, nl.search_radius,
                   m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, self.epsilon,
                   self.sim.boundary_params, nl.boundary, m.boundary_x, m.boundary_volume, f["predicted_x"],
                   f["pbf_constraint_offset"]],
                  [nl.fluid, nl.max_count, f["particle_density"], f["particle_lambda"], f["pbf_constraint"],
                   self._pair_cache(), f["pbf_neighbor_slot"]])
        self._sum_error()

    def constraint_pass(self) -> None:
        """Density and C at x* alone (the stabilize stage's offset reads no more): bitwise those of
        ``density_pass``, which it replaces there with lists; its lambda and pair cache stay as they were."""
        if not self.lists:
            self.density_pass()
            return
        m, f = self.model, self.sim.fields
        self._run(self._constraint_kernel, m.fluid_count,
                  [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, self.sim.boundary_params,
                   self.nl.boundary, m.boundary_x, m.boundary_volume, self.nl.fluid, f["predicted_x"],
                   f["pbf_constraint_offset"]],
                  [f["particle_density"], f["pbf_constraint"]])
        self._sum_error()

    def reuse_neighbors(self) -> None:
        """Neighbours of x* = x at a step's start: the last step's, when no boundary particle moved since (no
        bodies), every particle is still at the index it had when they were searched (between frames the
        particles are put in and out of cell order) and x* drifted at most ``allowed_drift`` from where
        they were searched (both measured here: one chunked maximum, one read); else a new build. The same
        pairs closer than H_s either way (the lists' order, and so the order of the sums, can differ)."""
        if self.with_bodies or self.neighbor_mode == "rebuild":
            self.build_neighbors()
            return
        self.last_drift = self.measure_drift()
        self.refresh_neighbors()

    def measure_drift(self) -> float:
        """The largest distance of x* from where the neighbours were searched [m] (device maximum per
        chunk); 1e30 when the particles were reordered since."""
        m, f = self.model, self.sim.fields
        self._run(_pbf_search.neighbor_drift_chunks, self._drift_partial.shape[0],
                  [_reduce.REDUCE_CHUNK, m.fluid_count, f["predicted_x"], f["pbf_neighbor_x"], f["pbf_neighbor_slot"]],
                  [self._drift_partial])
        return float(self._drift_partial.numpy().max())

    def refresh_neighbors(self) -> None:
        """After a correction: rebuild where the neighbours may be incomplete."""
        if self.neighbor_mode == "rebuild" or self.last_drift > self.allowed_drift:
            self.build_neighbors()

    def density_pass(self) -> None:
        """Density, C and lambda at x* (eq. 7/13, 17, 19; C less the offset o_i of the step's
        ``pbf_constraint_offset``); the sum of C_i read once (``last_error_sum``)."""
        m, f = self.model, self.sim.fields
        bn, fn = self._neighbor_args()
        params = self.sim.boundary_params
        if self.lists:
            self._run(self._density_kernel, m.fluid_count,
                      [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, self.epsilon, params,
                       bn, m.boundary_x, m.boundary_volume, fn, f["predicted_x"], f["pbf_constraint_offset"]],
                      [f["particle_density"], f["particle_lambda"], f["pbf_constraint"], self._pair_cache()])
        else:
            self._run(self._density_kernel, m.fluid_count,
                      [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, self.epsilon,
                       self.query_radius, params, bn, m.boundary_x, m.boundary_volume, fn, f["predicted_x"],
                       f["pbf_constraint_offset"]],
                      [f["particle_density"], f["particle_lambda"], f["pbf_constraint"]])
        self._sum_error()

    def _sum_error(self) -> None:
        """``last_error_sum``: the sum of C_i of the pass just run, ``last_error_count`` its particles."""
        m, f = self.model, self.sim.fields
        # sum of C_i in a fixed order: chunk sums on the device, their sum on the host (one read)
        self._run(_reduce.sum_chunks, self._error_partial.shape[0], [_reduce.REDUCE_CHUNK, f["pbf_constraint"]],
                  [self._error_partial])
        self.last_error_sum = float(self._error_partial.numpy().sum(dtype=np.float64))
        self.last_error_count = m.fluid_count

    def correction(self, dt: float) -> None:
        """One Jacobi correction of x* (eq. 18), capped at ``max_step``; wall reaction m dx_b / dt^2."""
        m, f, p = self.model, self.sim.fields, self.config
        bn, fn = self._neighbor_args()
        inv_dt2 = 1.0 / (dt * dt) if dt > 0 else 0.0
        tensile = (float(p.tensile_k), int(p.tensile_n), self.tensile_inv_w, self.tensile_scale)
        if self.lists:
            self._run(self._correction_kernel, m.fluid_count,
                      [m.particle_mass, *tensile, inv_dt2, self.max_step, -inv_dt2 / m.rest_density, fn, f["pbf_pairs"],
                       f["particle_lambda"]],
                      [f["position_correction"], f["boundary_force"], f["pbf_correction_size"], self._term,
                       f["predicted_x"]])  # x* += dx in the same kernel
        else:
            self._run(self._correction_kernel, m.fluid_count,
                      [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, self.query_radius,
                       *tensile, inv_dt2, self.max_step, self.sim.boundary_params, bn, m.boundary_x, m.boundary_volume,
                       fn, f["predicted_x"], f["particle_lambda"]],
                      [f["position_correction"], f["boundary_force"], f["pbf_correction_size"]])
            self._run(_pbf.apply_correction, m.fluid_count, [f["position_correction"]], [f["predicted_x"]],
                      min_range=LIGHT_MIN_RANGE)
        self._run(_pbf.max_correction_drift_chunks, self._correction_partial.shape[0],
                  [_reduce.REDUCE_CHUNK, f["pbf_correction_size"], f["predicted_x"], f["pbf_neighbor_x"]],
                  [self._correction_partial])
        s = self._correction_partial.numpy().max(axis=0)  # one read
        self.last_iteration_correction = float(s[0])
        self.last_drift = float(s[1])
