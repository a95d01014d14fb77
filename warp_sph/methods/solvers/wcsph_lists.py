"""WCSPH's neighbour lists kept over several steps (``wcsph.search_skin`` > 0; Verlet lists), a helper of
``wcsph.py`` (it registers nothing).

The lists hold every pair closer than H_s + s (s = skin [m]); a pair closer than H_s can be missing from them
only once two particles closed in by more than s since the search, |d_i - d_j| > s with d_i = x_i - x_i(search)
(d = 0 for the static wall particles). Both 2 max_i |d_i| and the diagonal of the bounding box of all d_i and of
0 bound |d_i - d_j| for every pair, so the lists are kept while the smaller of the two is at most s: the first
is the usual "no particle moved more than s / 2"; the second allows up to twice as long when the fluid moves one
way (a block in free fall: the box's diagonal is max |d|), and is never used where it is larger. A step then skips the cell sort and the cell walk: its density is a pass over the kept
lists (``kernels/density.py``, list variant; pairs beyond H_s add W = 0), and the force kernel reads the same
lists (pairs beyond H_s filtered out). Otherwise the step sorts and walks as without a skin, over cells of
H_s + s, and sums the density in the same walk. WCSPH's acoustic step moves a particle far less than a
spacing per step (the dam break at c_s = 11 sqrt(2 g H): at most 0.04 d), so one search serves several steps.

The lists are searched anew when that bound exceeds s (chunked maxima of |d_i| and of the box's corners on the
device, one host read per step), when the particles were reordered since (the frame's cell-order sort: a per-particle slot
field that is permuted with them, as PBF's, ``kernels/pbf_search.py``), when the particle count or the lists'
capacities changed, with moving bodies (their particles move every step), and after a restore or a density
refresh. Results differ from the per-step search (skin 0) only by the order of the sums (the cells are larger).

The fluid-static-wall lists (same radius H_s + s) are kept across fluid searches, with their own reference
positions x_i(wall search): a wall particle does not move, so a pair closes in by at most |x_i - x_i(wall search)|
and the wall lists hold every wall pair closer than H_s while that drift is at most s (the fluid lists' rule,
two moving particles, gives out at about s / 2). Past s they are searched again: with the fluid's when that step
searches, else alone (over the static grid, with no fluid sort). Reordered particles, a new count or new
capacities, a restore or a density refresh search them with the fluid's; with moving bodies they are searched at
every step as before. The kept wall lists hold the fresh lists' pairs in the same order (the walk visits the wall
cells in grid order) plus pairs beyond H_s that add nothing, so the results are bitwise those of wall lists searched
with every fluid search (``keep_walls = False``).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ...core.launch import LIGHT_MIN_RANGE, replaying_launch
from ...core.step_graph import Stage
from ...kernels import wcsph_lists as _wcsph
from ...kernels import pbf_search as _lists_reuse  # identity_slots: generic list-reuse slots
from ...kernels import reduction as _reduce
from ...neighbors.cell_lists import simulation_neighbor_lists
from ...neighbors.wall_reach import WallReach

#: the static walls' boundary lists are built from per-run sub-cell lists (``static_wall_lists``); False: the
#: per-search walk of the wall grid (the reference: the same lists bitwise)
STATIC_WALL_LISTS = True


def static_wall_lists(nl) -> None:
    """Give the lists ``nl`` (``NeighborLists``) the static wall particles in reach of each cell of their wall grid
    (DFSPH's ``WallReach`` at the lists' radius, built once per run): their boundary searches (WCSPH's wall lists,
    PBF's boundary lists) then test one short list per fluid particle instead of walking the wall cells, bitwise
    the same lists. Moving boundary particles keep the walk of their own grid."""
    bc = nl.boundary_cells
    if not STATIC_WALL_LISTS or bc is None:
        nl.static_walls = None
    elif nl.static_walls is None or nl.static_walls.cells is not bc:
        nl.static_walls = WallReach(bc, nl.search_radius, device=nl.device)


def pair_cache(n: int, capacity: int, device) -> _wcsph.PairCache:
    """A ``PairCache`` (``kernels/pbf_pairs.py``) with n rows of ``capacity`` pairs: index and grad W (no values, no
    boundary gradient: WCSPH's force kernel reads the boundary lists)."""
    pairs = _wcsph.PairCache()
    pairs.count = wp.zeros(max(n, 1), dtype=wp.int32, device=device)
    pairs.index = wp.zeros((max(n, 1), max(capacity, 1)), dtype=wp.int32, device=device)
    pairs.gradient = wp.zeros((max(n, 1), max(capacity, 1)), dtype=wp.vec3, device=device)
    pairs.value = wp.zeros((1, 1), dtype=float, device=device)
    pairs.boundary_gradient = wp.zeros(1, dtype=wp.vec3, device=device)
    return pairs


class KeptLists:
    """The "neighbors" and "density" stages of WCSPH with lists kept while the particles drift less than
    skin / 2 [m] (see the module docstring). ``builds`` counts the searches, ``steps`` the density stages."""

    def __init__(self, sim, skin: float, moving_bodies: bool):
        self.sim = sim
        self._launch = replaying_launch(sim.model.device)
        self.skin = float(skin)
        self.moving_bodies = bool(moving_bodies)
        self.nl = simulation_neighbor_lists(sim, self.skin)
        static_wall_lists(self.nl)
        m = sim.model
        for name, dtype in (("particle_density", float), ("wcsph_neighbor_x", wp.vec3), ("wcsph_neighbor_slot", wp.int32)):
            sim.allocate(name, dtype)  # (per-particle fields: read from sim.fields, which emitters resize)
        chunks = max(1, -(-m.capacity // _reduce.REDUCE_CHUNK))
        sim.allocate("wcsph_wall_x", wp.vec3)  # where each particle was when the static-wall lists were searched
        self._drift_partial = wp.zeros((chunks, 8), dtype=float, device=m.device)  # max |d|, box corners, wall drift
        self._density_kernel = _wcsph.density_pairs_kernel(m.smoothing.name, sim.boundary_terms)
        self._search_kernel = _wcsph.search_density_pairs_kernel(m.smoothing.name, sim.boundary_terms)
        self.fused_search = True  # False: a search step builds the lists, then runs the density pass over them
        self.pairs = None  # the step's ``PairCache`` (``wcsph_pairs``), rows as long as the fluid lists'
        self._built = None  # (fluid count, capacities) at the last search; None: search at the next step
        self._search = True
        self.keep_walls = True  # False: search the wall lists at every fluid search (the reference behaviour)
        self._walls_valid = False  # the wall lists hold every wall pair closer than H_s + s of x(wall search)
        self._search_walls = True
        self.builds = 0
        self.wall_builds = 0  # searches of the fluid-static-wall lists
        self.last_wall_drift = 0.0  # max |x_i - x_i(wall search)| at the last check [m]
        self.steps = 0
        self.last_drift = 0.0
        self.last_spread = 0.0  # bound on |d_i - d_j| at the last check [m] (``_must_search``)

    def invalidate(self) -> None:
        """Search at the next step (after a restore, or positions changed from outside)."""
        self._built = None
        self._walls_valid = False

    def _must_search(self) -> bool:
        """Whether this step searches the fluid lists; sets ``_search_walls`` (whether it searches the wall lists,
        with the fluid's or alone)."""
        m, nl, f = self.sim.model, self.nl, self.sim.fields
        self._search_walls = True
        if self._built is None or self.moving_bodies or self._built != (m.fluid_count, nl.capacities):
            self._walls_valid = False
            return True
        n = m.fluid_count
        if n == 0:
            self._search_walls = False
            return False
        chunks = -(-n // _reduce.REDUCE_CHUNK)
        self._launch(_wcsph.displacement_bounds_chunks, chunks,
                     [_reduce.REDUCE_CHUNK, n, f["particle_x"], f["wcsph_neighbor_x"], f["wcsph_neighbor_slot"],
                      f["wcsph_wall_x"]], [self._drift_partial])
        b = self._drift_partial.numpy()[:chunks].max(axis=0).astype(np.float64)  # one read
        self.last_drift = float(b[0])
        # the box of the d_i and of d = 0, the static walls' (a pair with a wall particle closes in by |d_i|)
        diagonal = float(np.linalg.norm(np.maximum(b[1:4], 0.0) + np.maximum(b[4:7], 0.0)))
        self.last_spread = min(2.0 * self.last_drift, diagonal)
        # a wall pair closes in by |x_i - x_i(wall search)|: s bounds it for the walls' lists
        self.last_wall_drift = float(b[7])
        search = self.last_spread > self.skin
        walls_ok = self._walls_valid and self.last_wall_drift <= self.skin
        self._search_walls = not walls_ok if self.keep_walls else search
        return search

    def run_neighbors(self, sim, dt) -> None:
        """Decide whether this step searches; if so, sort the fluid into the cells."""
        self._search = self._must_search()
        if self._search:
            self.nl.sort(sim.fields["particle_x"])

    def run_density(self, sim, dt) -> None:
        """The lists and, in the same walk, the density (a search step), or the density over the kept lists."""
        m, f, nl = sim.model, sim.fields, self.nl
        x = f["particle_x"]
        self.steps += 1
        capacity = nl.capacities[0]
        if self.pairs is None or self.pairs.index.shape[1] != capacity:
            self.pairs = f["wcsph_pairs"] = pair_cache(m.capacity, capacity, m.device)
        if self._search:
            if not self.fused_search:
                nl.build_lists(x, boundary=self._search_walls)
            else:  # the wall lists first (the fused kernel reads them), then the fluid lists with the density
                if self._search_walls:
                    nl.build_boundary_lists(x)
                fc = nl.fluid_cells
                self._launch(self._search_kernel, m.fluid_count,
                             [fc.lo, fc.inv_cell_size, fc.dims, fc.cell_start, fc.cell_point, fc.sorted_x,
                              nl.search_radius, m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density,
                              sim.boundary_params, nl.boundary, m.boundary_x, m.boundary_volume, x],
                             [nl.fluid, nl.max_count, f["particle_density"], self.pairs])
            if self._search_walls:
                wp.copy(f["wcsph_wall_x"], x, count=m.fluid_count)
                self.wall_builds += 1
                self.last_wall_drift = 0.0
            self._walls_valid = True
            self._launch(_lists_reuse.identity_slots, m.fluid_count, [], [f["wcsph_neighbor_slot"]],
                         min_range=LIGHT_MIN_RANGE)
            wp.copy(f["wcsph_neighbor_x"], x, count=m.fluid_count)
            self._built = (m.fluid_count, nl.capacities)
            self.builds += 1
            self.last_drift = 0.0
            self.last_spread = 0.0
        elif self._search_walls:  # the fluid lists still hold: the wall lists alone (the static grid, no sort)
            nl.build_boundary_lists(x)
            wp.copy(f["wcsph_wall_x"], x, count=m.fluid_count)
            self.wall_builds += 1
            self.last_wall_drift = 0.0
        if self._search and self.fused_search:
            return
        self._launch(self._density_kernel, m.fluid_count,
                     [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, sim.boundary_params,
                      nl.boundary, m.boundary_x, m.boundary_volume, nl.fluid, x],
                     [f["particle_density"], self.pairs])

    def stages(self, boundary_reads: tuple[str, ...]) -> tuple[Stage, Stage]:
        """(neighbors, density) stages for the solver's graph."""
        kept = ("neighbor_lists", "wcsph_neighbor_x", "wcsph_neighbor_slot", "wcsph_wall_x")
        moving = ("moving_boundary_grid",) if getattr(self.sim, "bodies", None) is not None else ()
        s = self.sim.model.spacing
        return (Stage("neighbors", self.run_neighbors, reads=("particle_x",), updates=kept[1:],
                      writes=("neighbor_cells",),
                      doc=f"when two particles may have closed in by > {self.skin / s:.3g} d since the last search "
                          f"(min(2 max |d|, the displacements' box diagonal); or the particles were reordered): fluid "
                          f"sorted into cells of {self.nl.search_radius:.4g} m"),
                Stage("density", self.run_density, reads=("neighbor_cells", "particle_x") + boundary_reads + moving,
                      updates=kept, writes=("particle_density", "wcsph_pairs"),
                      doc=f"neighbour lists within H_s + {self.skin / s:.3g} d (capacities {self.nl.capacities}) "
                          "when the step searched; the static-wall lists when a particle moved > "
                          f"{self.skin / s:.3g} d since they were searched (or they are stale); eq. 7/13 "
                          "over the lists and the pairs closer than H_s with grad W (PairCache) for the forces"))
