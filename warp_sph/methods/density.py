"""Shared stages: the neighbour search and the density summation (report eq. 7, 13).

Two compile-time variants of the same kernels: with ``lists`` the fluid is sorted into the cells of
the per-step neighbour lists (``neighbors``) and one pass builds the fluid-fluid and fluid-boundary
lists and sums the density over the pairs it finds (``density``); without, the fluid hash grid is
rebuilt (``neighbors``) and the density queries it (the reference variant).
"""
from __future__ import annotations

from ..core.launch import launch
from ..core.step_graph import Stage
from ..kernels import density as _density
from ..neighbors.cell_lists import simulation_neighbor_lists


def neighbor_args(sim, lists: bool) -> tuple:
    """(boundary_neighbors, fluid_neighbors): a kernel launch's neighbour arguments (``kernels.density.NEIGHBOR_TYPES``)
    at the time of the call: the neighbour lists' boundary and fluid parts (``lists``), or the boundary and fluid
    hash grids' ids."""
    if lists:
        nl = sim.fields["neighbor_lists"]
        return nl.boundary, nl.fluid
    return sim.model.boundary_grid_id, sim.fluid_grid.id


def neighbors_stage(sim, lists: bool = True, margin: float = 0.0) -> Stage:
    """Sort the fluid into the cells of the neighbour lists (``density_stage`` then builds the lists), or
    rebuild the fluid hash grid (cell = search radius = support radius H_s; lists: H_s + margin [m])."""
    if lists:
        nl = simulation_neighbor_lists(sim, margin)

        def run_sort(sim, dt):
            nl.sort(sim.fields["particle_x"])

        return Stage("neighbors", run_sort, reads=("particle_x",), writes=("neighbor_cells",),
                     doc=f"fluid sorted into cells of {nl.search_radius:.4g} m (dense cell grid)")

    def run(sim, dt):
        sim.fluid_grid.build(sim.fields["particle_x"])

    return Stage("neighbors", run, reads=("particle_x",), writes=("fluid_grid",),
                 doc=f"wp.HashGrid rebuild, radius H_s = {sim.model.support_radius:.4g} m")


def density_stage(sim, lists: bool = True) -> Stage:
    """rho_i = m sum_j W_ij + rho0 sum_b density_b(W_ib, V_b) (report eq. 7/13; the boundary term is the
    boundary method's, Akinci: V_b W_ib). With ``lists`` the same pass builds the fluid-fluid and
    fluid-boundary neighbour lists every later pass of the step reads."""
    m = sim.model
    terms, params = sim.boundary_terms, sim.boundary_params
    with_boundary = terms is not None and terms.density is not None
    sim.allocate("particle_density", float)
    boundary_reads = ("boundary_x", "boundary_volume") if with_boundary else ()
    what = "eq. 7" + (f" + {terms.name} boundary density" if with_boundary else "")
    if lists:
        nl = simulation_neighbor_lists(sim)

        def run_lists(sim, dt):
            nl.build_lists(sim.fields["particle_x"], sim.fields["particle_density"], m.smoothing.name,
                           m.smoothing_length, m.particle_mass, m.rest_density, terms, params)

        moving = ("moving_boundary_grid",) if getattr(sim, "bodies", None) is not None else ()
        return Stage("density", run_lists, reads=("neighbor_cells", "particle_x") + boundary_reads + moving,
                     writes=("neighbor_lists", "particle_density"),
                     doc=f"neighbour lists within H_s (capacities {nl.capacities}) and, over the same pairs, {what}")
    kernel = _density.density_kernel(m.smoothing.name, terms, "grid")

    def run(sim, dt):
        f = sim.fields
        launch(kernel, m.fluid_count,
               [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, params,
                m.boundary_grid_id, m.boundary_x, m.boundary_volume, sim.fluid_grid.id, f["particle_x"]],
               [f["particle_density"]], device=m.device)

    return Stage("density", run, reads=("fluid_grid", "particle_x") + boundary_reads
                 + (("boundary_grid",) if with_boundary else ()), writes=("particle_density",), doc=what)
