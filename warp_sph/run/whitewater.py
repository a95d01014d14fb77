"""Whitewater of a running simulation (``sim.whitewater``; scene table ``[whitewater]``, docs/whitewater.md):
spray, foam and air bubbles as secondary particles after Ihmsen et al. 2012 (the model behind
SPlisHSPlasH's FoamGenerator), stepped with the fluid by one stage after the solver's last.

The stage, every substep of dt [s] (equations in ``kernels/whitewater_potentials.py`` and
``kernels/whitewater.py``):
1. the three potentials (trapped air, wave crest, kinetic energy) per fluid particle, and how many
   secondary particles each generates this step: work only for the particles fast enough to generate,
   normals only where a wave crest can form (three passes);
2. each secondary particle classified by its fluid neighbours (spray / foam / bubble) and moved:
   spray ballistically, foam with the fluid's kernel-averaged velocity (ageing), bubbles with
   buoyancy and drag; foam past its lifetime and particles leaving the container die (not above an open
   top: spray there falls back, as the fluid does). The velocity
   and the count are sampled trilinearly from nodes H/2 apart, evaluated once per step where a
   secondary particle is (``fluid_sampling = "grid"``, kernels/whitewater_sample.py), or walked
   per particle (``"walk"``);
3. survivors compacted (order kept), then the new ones appended in fluid-slot order (one thread per new
   particle that fits); those beyond ``max_particles`` are dropped (one warning per run).
Exclusive scans fix every slot, the sampling draws from one seeded stream per fluid slot and step, so a
run, a retried frame and a resume give the same particles bit for bit. One host read per substep (the
two totals). A scene without ``[whitewater]`` has no stage, no array and no cost.
"""
from __future__ import annotations

import warnings

import numpy as np
import warp as wp

from ..core.errors import SceneError
from ..core.launch import launch
from ..core.step_graph import Stage
from ..kernels import whitewater as _ww
from ..kernels import whitewater_potentials as _pot
from ..kernels import whitewater_sample as _sample
from ..scene.emitters import open_faces
from .emission import open_top

#: names of the kinds, index = kind code - 1 (``kernels.whitewater.KIND_*``); also the USD prim names
KINDS = ("spray", "foam", "bubbles")
#: the per-particle arrays of the state, in checkpoint order
_ARRAYS = (("x", wp.vec3), ("v", wp.vec3), ("age", float), ("life", float), ("kind", wp.int32))
#: node spacing of the sampled fluid (``kernels/whitewater_sample.py``) per fluid cell (= support radius)
NODES_PER_CELL = 2
#: most nodes of that grid (21 bytes each); beyond it the nodes are one per fluid cell
MAX_NODES = 1 << 22


class Whitewater:
    """The secondary particles of ``sim`` (built by the Simulation when the scene's whitewater is on)."""

    #: key of this part in run.json's summary (``Simulation.parts``)
    name = "whitewater"

    def __init__(self, sim):
        self.sim = sim
        self.config = c = sim.scene.whitewater
        m = sim.model
        self.capacity = int(c.max_particles)
        dev = m.device
        self._buffers = [{name: wp.zeros(self.capacity, dtype=t, device=dev) for name, t in _ARRAYS} for _ in range(2)]
        self.front = 0
        self.count = 0           # live particles (host copy, exact after every substep)
        self.dropped = 0         # generated but dropped for lack of capacity, whole run
        self._warned = False
        n = m.capacity  # per fluid slot: emitters grow the count up to the capacity (``warp_sph.run.emission``)
        self._alive = wp.zeros(self.capacity, dtype=wp.int32, device=dev)
        self._alive_offset = wp.zeros(self.capacity, dtype=wp.int32, device=dev)
        self._generate = wp.zeros(n, dtype=wp.int32, device=dev)
        self._generate_offset = wp.zeros(n, dtype=wp.int32, device=dev)
        #: outward normal n_i [1/m] where the wave-crest potential reads it this substep (else 0 or stale)
        self.normal = wp.zeros(n, dtype=wp.vec3, device=dev)
        self._trapped = wp.zeros(n, dtype=float, device=dev)       # v_diff_i [m/s] of the fast particles
        self._state = wp.zeros(n, dtype=wp.uint8, device=dev)      # SLOW / FAST / CREST (kernels/whitewater_potentials)
        self._need = wp.zeros(n, dtype=wp.uint8, device=dev)       # normal read by a crest candidate (cleared)
        #: (I_ta, I_wc, I_k) in [0, 1] per fluid slot [0, fluid_count) at the last substep (cell order within a frame)
        self.potential = wp.zeros(n, dtype=wp.vec3, device=dev)
        self._totals = wp.zeros(2, dtype=wp.int32, device=dev)
        self._nodes = None       # (fluid cell grid, lo, spacing, dims, flags, row flags, sums): _node_grid
        self._no_nodes = wp.zeros(1, dtype=_sample.vec5, device=dev)  # the advection's node argument when walking
        self.generated = 0       # particles generated, whole run (including dropped ones)
        if m.container_lo is not None:
            pad = m.support_radius
            lo, hi = m.container_lo - pad, m.container_hi + pad
            top = open_top(open_faces(sim.scene), m.gravity)
            if top is not None:  # above an open top's opening spray is in flight and falls back, as the fluid
                (hi if top[1] else lo)[top[0]] = (1.0 if top[1] else -1.0) * 1e30
            self._bounds = (1, wp.vec3(*lo), wp.vec3(*hi))
        else:
            self._bounds = (0, wp.vec3(0.0), wp.vec3(0.0))

    @property
    def arrays(self) -> dict:
        """The live buffers {x, v, age, life, kind}; entries [0, count) are the particles."""
        return self._buffers[self.front]

    # --- graph -----------------------------------------------------------------------------------
    def check_solver(self, solver) -> None:
        if not getattr(solver, "lists", True):
            raise SceneError(f"whitewater: the {solver.name} solver's hash-grid variant (lists=False) has no neighbour "
                             "lists; use its neighbour-list variant (the default)")

    def stage(self) -> Stage:
        c = self.config
        return Stage("whitewater", lambda sim, dt: self.step(dt),
                     reads=("neighbor_lists", "particle_x", "particle_v", "particle_density"), updates=("whitewater",),
                     doc=f"whitewater (Ihmsen et al. 2012): potentials -> generation (k_ta {c.trapped_air_rate:g}/s, "
                         f"k_wc {c.wave_crest_rate:g}/s) -> spray < {c.spray_neighbors} <= foam <= "
                         f"{c.bubble_neighbors} < bubbles, advected -> compacted; at most {self.capacity} particles")

    # --- stepping --------------------------------------------------------------------------------
    def step_seed(self) -> int:
        """Seed of this substep's streams: the scene's seed and the step count (a resume replays it)."""
        return (int(self.config.seed) * 1_000_003 + int(self.sim.state.step) * 7919 + 17) % (2**31 - 1)

    def step(self, dt: float) -> None:
        sim, m, c = self.sim, self.sim.model, self.config
        f = sim.fields
        nl = f["neighbor_lists"]
        dev = m.device
        n = m.fluid_count
        seed = self.step_seed()
        # a fluid slower than sqrt(2 kinetic_energy_min) generates nothing: one reduction skips the passes
        fast = sim.current_speed() ** 2 > 2.0 * float(c.kinetic_energy_min)
        if fast:
            smoothing, kinetic = m.smoothing.name, wp.vec2(c.kinetic_energy_min, c.kinetic_energy_max)
            launch(_pot.fast_pass_kernel(smoothing), n,
                   [m.particle_mass, m.smoothing_length, m.support_radius, kinetic, nl.fluid, f["particle_x"],
                    f["particle_v"], f["particle_density"]], [self.normal, self._trapped, self._state, self._need],
                   device=dev)
            launch(_pot.crest_normals_kernel(smoothing), n,
                   [m.particle_mass, m.smoothing_length, m.support_radius, nl.fluid, f["particle_x"],
                    f["particle_density"], self._state, self._need], [self.normal], device=dev)
            launch(_pot.potentials_kernel(), n,
                   [m.support_radius, float(dt), seed, wp.vec2(c.trapped_air_min, c.trapped_air_max),
                    wp.vec2(c.wave_crest_min, c.wave_crest_max), kinetic, float(c.trapped_air_rate),
                    float(c.wave_crest_rate), nl.fluid, f["particle_x"], f["particle_v"], self.normal, self._trapped,
                    self._state], [self.potential, self._generate], device=dev)
            wp.utils.array_scan(self._generate[:n], self._generate_offset[:n], inclusive=False)
        else:
            self.potential.zero_()
        src = self.arrays
        count = self.count
        if count:
            fc = nl.fluid_cells
            use_bounds, lo, hi = self._bounds
            if c.fluid_sampling == "grid":
                _, node_lo, spacing, dims, flag, row_flag, node = self._node_grid(fc)
            else:  # walked: the advection reads no node (none allocated)
                node_lo, spacing, dims, node = wp.vec3(0.0), 1.0, wp.vec3i(1, 1, 1), self._no_nodes
            node_grid = [node_lo, 1.0 / spacing, dims]
            if c.fluid_sampling == "grid":
                launch(_sample.mark_nodes, count, [*node_grid, src["x"]], [flag, row_flag], device=dev)
                launch(_sample.node_sums_kernel(m.smoothing.name), row_flag.shape[0],
                       [node_lo, spacing, dims, m.smoothing_length, m.support_radius, fc.lo, fc.inv_cell_size, fc.dims,
                        fc.cell_start, fc.cell_point, nl.search_radius, f["particle_x"], f["particle_v"], flag,
                        row_flag], [node], device=dev, min_range=64)
            launch(_ww.advect_kernel(m.smoothing.name), count,
                   [m.smoothing_length, m.support_radius, float(dt), wp.vec3(*m.gravity), float(c.buoyancy),
                    float(c.drag), int(c.spray_neighbors), int(c.bubble_neighbors), use_bounds, lo, hi,
                    fc.lo, fc.inv_cell_size, fc.dims, fc.cell_start, fc.cell_point, nl.search_radius,
                    f["particle_x"], f["particle_v"], int(c.fluid_sampling == "grid"), *node_grid, node],
                   [src["x"], src["v"], src["age"], src["life"], src["kind"], self._alive], device=dev)
            wp.utils.array_scan(self._alive[:count], self._alive_offset[:count], inclusive=False)
        if not (count or fast):
            return
        wp.launch(_ww.scan_totals, 1, inputs=[self._alive, self._alive_offset, count, self._generate,
                                              self._generate_offset, n if fast else 0], outputs=[self._totals],
                  device=dev)
        survivors, generated = (int(v) for v in self._totals.numpy())
        dst = self._buffers[1 - self.front]
        launch(_ww.compact, count,
               [self._alive, self._alive_offset, src["x"], src["v"], src["age"], src["life"], src["kind"]],
               [dst["x"], dst["v"], dst["age"], dst["life"], dst["kind"]], device=dev)
        room = self.capacity - survivors
        # one thread per new particle that fits (none launched when none is generated)
        launch(_ww.emit_kernel(), min(generated, room),
               [float(dt), seed, survivors, n, m.particle_radius, float(c.lifetime_min),
                float(c.lifetime_max), int(c.spray_neighbors), int(c.bubble_neighbors), nl.fluid,
                f["particle_x"], f["particle_v"], self._generate_offset],
               [dst["x"], dst["v"], dst["age"], dst["life"], dst["kind"]], device=dev)
        self.front = 1 - self.front
        self.generated += generated
        if generated > room:
            self.dropped += generated - room
            if not self._warned:
                self._warned = True
                warnings.warn(f"whitewater: whitewater.max_particles = {self.capacity} is full at step "
                              f"{sim.state.step}; new particles are dropped (raise max_particles for more)",
                              RuntimeWarning, stacklevel=2)
        self.count = survivors + min(generated, room)

    def _node_grid(self, fc) -> tuple:
        """The node grid of the sampled fluid over the fluid cell grid ``fc``: nodes NODES_PER_CELL per cell
        (one per cell when that exceeds MAX_NODES); made once per cell grid."""
        if self._nodes is None or self._nodes[0] is not fc:
            cells = np.array([fc.dims[0], fc.dims[1], fc.dims[2]], dtype=np.int64)
            per_cell = NODES_PER_CELL if int(np.prod(NODES_PER_CELL * cells + 1)) <= MAX_NODES else 1
            dims = per_cell * cells + 1
            dev = self.sim.model.device
            self._nodes = (fc, fc.lo, fc.cell_size / per_cell, wp.vec3i(*(int(d) for d in dims)),
                           wp.zeros(int(np.prod(dims)), dtype=wp.uint8, device=dev),
                           wp.zeros(int(dims[1] * dims[2]), dtype=wp.uint8, device=dev),
                           wp.zeros(int(np.prod(dims)), dtype=_sample.vec5, device=dev))
        return self._nodes

    def node_grid(self) -> tuple[np.ndarray, float, tuple[int, int, int]]:
        """(first node [m] local, spacing [m], nodes per axis) of the sampled fluid's node grid (after a step)."""
        _, lo, spacing, dims, _, _, _ = self._node_grid(self.sim.fields["neighbor_lists"].fluid_cells)
        return np.array([lo[0], lo[1], lo[2]], dtype=np.float64), float(spacing), (dims[0], dims[1], dims[2])

    # --- reads (once per frame) -------------------------------------------------------------------
    def host_arrays(self) -> dict[str, np.ndarray]:
        """Copies of the live particles: x [m] local, v [m/s], age [s], life [s], kind (1 spray, 2 foam, 3 bubble)."""
        return {name: np.array(a.numpy()[: self.count], copy=True) for name, a in self.arrays.items()}

    def kind_counts(self, kind: np.ndarray | None = None) -> dict[str, int]:
        """{spray, foam, bubbles: live count}."""
        kind = self.host_arrays()["kind"] if kind is None else kind
        return {name: int(np.count_nonzero(kind == code)) for code, name in enumerate(KINDS, start=1)}

    def snapshot(self) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """{kind name: (positions [m] world, velocities [m/s], ages [s])} for the export."""
        a = self.host_arrays()
        x = self.sim.model.to_world(a["x"])
        return {name: (x[a["kind"] == code], a["v"][a["kind"] == code], a["age"][a["kind"] == code])
                for code, name in enumerate(KINDS, start=1)}

    def summary(self) -> dict:
        return {"max_particles": self.capacity, "seed": int(self.config.seed)}

    def frame_record(self) -> dict:
        """Counts for run.json: live per kind, generated and dropped so far."""
        return {**self.kind_counts(), "generated": self.generated, "dropped": self.dropped}

    # --- checkpoints, frame retries -----------------------------------------------------------------
    def checkpoint_arrays(self) -> dict[str, np.ndarray]:
        out = {f"whitewater_{k}": v for k, v in self.host_arrays().items()}
        out["whitewater_counters"] = np.array([self.generated, self.dropped, int(self._warned)], dtype=np.int64)
        return out

    def restore_arrays(self, arrays) -> None:
        if "whitewater_x" not in arrays:
            raise SceneError("whitewater: the checkpoint holds no whitewater state (written by a run without "
                             "[whitewater]?)")
        n = len(arrays["whitewater_x"])
        if n > self.capacity:
            raise SceneError(f"whitewater: the checkpoint holds {n} particles, more than max_particles = "
                             f"{self.capacity}")
        self.front = 0
        for name, dtype in _ARRAYS:
            values = np.asarray(arrays[f"whitewater_{name}"])
            if n:
                self.arrays[name][:n].assign(wp.array(values, dtype=dtype, device=self.sim.model.device))
        self.count = n
        self.generated, self.dropped, warned = (int(v) for v in np.asarray(arrays["whitewater_counters"]))
        self._warned = bool(warned)

    def save(self) -> dict:
        """The state at a frame start (the watchdog's retry)."""
        return self.checkpoint_arrays()

    def restore(self, saved: dict) -> None:
        self.restore_arrays(saved)
