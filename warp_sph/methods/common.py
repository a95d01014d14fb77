"""Stages shared by every solver: neighbours, density summation, XSPH.

Neighbour loops come in two compile-time variants of the same kernels: ``lists=False`` queries the
fluid hash grid (``fluid_grid``) in every pass; ``lists=True`` builds fixed-capacity neighbour lists
once per step (``neighbor_lists``, fluid-fluid and fluid-boundary) that every later pass reads.
"""
from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..kernels import density as _density
from ..kernels import integrate as _integrate
from ..core.launch import LIGHT_MIN_RANGE, launch
from ..neighbors import NeighborLists
from ..core.step_graph import Stage


def neighbor_lists(sim, margin: float = 0.0) -> NeighborLists:
    """The simulation's per-step neighbour lists (created on first use, field ``neighbor_lists``).

    Their dense cell grid covers the container, the boundary and the initial fluid, padded by two
    support radii (by a quarter of the extent without a container); particles beyond it stay exact.
    margin [m]: the search radius is H_s + margin (lists that stay complete while particles move
    by up to margin / 2); the capacities grow with the searched volume. Lists of another search
    radius are replaced.
    """
    lists = sim.fields.get("neighbor_lists")
    if lists is not None and not math.isclose(lists.search_radius, sim.model.support_radius + margin, rel_tol=1e-6):
        lists = None  # another search radius (a solver swapped in): new lists replace the old ones
    if lists is None:
        m = sim.model
        x = sim.state.particle_x.numpy()
        boxes = [x.min(axis=0), x.max(axis=0)]
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
        with_boundary = m.boundary_method != "none"
        lists = NeighborLists(radius, lo - pad, hi + pad, m.fluid_count,
                              m.boundary_x if with_boundary else None,
                              fluid_capacity=int(math.ceil(64 * volume)), boundary_capacity=int(math.ceil(48 * volume)),
                              device=m.device, boundary_volume=m.boundary_volume if with_boundary else None)
        sim.fields["neighbor_lists"] = lists
    return lists


def _neighbor_args(sim, lists: bool):
    """(boundary_neighbors, fluid_neighbors) kernel arguments of the chosen neighbour variant."""
    if lists:
        nl = sim.fields["neighbor_lists"]
        return nl.boundary, nl.fluid
    return sim.model.boundary_grid_id, sim.fluid_grid.id


def neighbors_stage(sim, lists: bool = False) -> Stage:
    """Rebuild the fluid hash grid (cell = search radius = support radius H_s), or with ``lists``
    sort the fluid into the cells of the neighbour lists (``density_stage`` then builds the lists
    and sums the density in one pass)."""
    if lists:
        nl = neighbor_lists(sim)

        def run_sort(sim, dt):
            nl.sort(sim.fields["particle_x"])

        return Stage("neighbors", run_sort, reads=("particle_x",), writes=("neighbor_cells",),
                     doc=f"fluid sorted into cells of H_s = {sim.model.support_radius:.4g} m (dense cell grid)")

    def run(sim, dt):
        sim.fluid_grid.build(sim.fields["particle_x"])

    return Stage("neighbors", run, reads=("particle_x",), writes=("fluid_grid",),
                 doc=f"wp.HashGrid rebuild, radius H_s = {sim.model.support_radius:.4g} m")


def density_stage(sim, positions: str = "particle_x", lists: bool = False) -> Stage:
    """rho_i = m sum_j W_ij (+ sum_b Psi_b W_ib with Akinci boundaries), report eq. 7/13.

    With ``lists`` the same pass builds the fluid-fluid and fluid-boundary neighbour lists (after the
    "neighbors" stage sorted the fluid into cells) that every later pass of the step reads: the
    search already visits every pair, so the density costs no second walk over the neighbours."""
    m = sim.model
    with_boundary = m.boundary_method == "akinci2012"
    sim.allocate("particle_density", float)
    if lists:
        nl = neighbor_lists(sim)

        def run_lists(sim, dt):
            nl.build_lists(sim.fields[positions], sim.fields["particle_density"], m.smoothing.name,
                           m.smoothing_length, m.particle_mass, m.rest_density, boundary_density=with_boundary)

        reads = ("neighbor_cells", positions) + (("boundary_x", "boundary_volume") if with_boundary else ())
        return Stage("density", run_lists, reads=reads, writes=("neighbor_lists", "particle_density"),
                     doc=f"neighbour lists within H_s (capacities {nl.capacities}) and, over the same pairs, eq. 7"
                         + (" + Akinci boundary eq. 13-15" if with_boundary else ""))
    kernel = _density.density_kernel(m.smoothing.name, with_boundary, "grid")

    def run(sim, dt):
        f = sim.fields
        boundary_neighbors, fluid_neighbors = _neighbor_args(sim, lists)
        launch(kernel, m.fluid_count,
               [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density,
                boundary_neighbors, m.boundary_x, m.boundary_volume, fluid_neighbors, f[positions]],
               [f["particle_density"]], device=m.device)

    reads = ("fluid_grid", positions)
    reads += (("boundary_x", "boundary_volume", "boundary_grid") if with_boundary else ())
    return Stage("density", run, reads=reads, writes=("particle_density",),
                 doc="eq. 7" + (" + Akinci boundary eq. 13-15" if with_boundary else ""))


def xsph_stage(sim, positions: str = "particle_x", lists: bool = False) -> Stage:
    """XSPH velocity filter (report eq. 21) with factor eps = material.xsph [-]."""
    m = sim.model
    kernel = _integrate.xsph_kernel(m.smoothing.name, "list" if lists else "grid")
    sim.allocate("velocity_correction", wp.vec3)

    def run(sim, dt):
        f = sim.fields
        _, fluid_neighbors = _neighbor_args(sim, lists)
        launch(kernel, m.fluid_count,
               [m.particle_mass, m.smoothing_length, m.support_radius, m.xsph,
                fluid_neighbors, f[positions], f["particle_v"], f["particle_density"]],
               [f["velocity_correction"]], device=m.device)
        launch(_integrate.add_velocity_correction, m.fluid_count, [f["velocity_correction"]],
               [f["particle_v"]], device=m.device, min_range=LIGHT_MIN_RANGE)

    return Stage("xsph", run, reads=("neighbor_lists" if lists else "fluid_grid", positions, "particle_density"),
                 writes=("velocity_correction",), updates=("particle_v",), doc=f"XSPH eq. 21, eps = {m.xsph}")
