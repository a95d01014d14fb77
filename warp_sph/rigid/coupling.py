"""Host side of the two-way coupling (device code in ``kernels/rigid.py``): move the bodies' boundary
particles with their poses, and reduce the fluid's forces on them into one wrench per body.

The moving boundary particles sit after the static ones in the Model's boundary arrays, body by
body: body k owns boundary indices ``start + offsets[k] .. start + offsets[k + 1] - 1``.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import warp as wp

from ..core.launch import LIGHT_MIN_RANGE, launch
from ..core.step_graph import Stage
from ..kernels import rigid as _rigid
from .sampling import BodySamples

#: moving particles per chunk of the wrench reduction (a chunk is summed by one thread, in order)
WRENCH_CHUNK = 256


class BodyParticles:
    """The moving boundary particles of all bodies (constant body-frame data on the device).

    Args:
        samples: one ``BodySamples`` per body, in body order.
        start: boundary index of the first moving particle (the number of static boundary particles).
        device: Warp device.
        chunk: particles per reduction chunk (changes the summation order, so keep it fixed in a run).

    Fields: ``count`` moving particles; ``offsets`` (body_count + 1,) int; ``particle_body`` [-],
    ``local_x`` [m] and ``volume`` [m^3] per moving particle (wp.arrays).
    """

    def __init__(self, samples: Sequence[BodySamples], start: int, device=None, chunk: int = WRENCH_CHUNK):
        self.device = wp.get_device(device)
        self.start = int(start)
        counts = np.array([s.count for s in samples], dtype=np.int64)
        self.body_count = len(samples)
        self.offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.count = int(self.offsets[-1])
        local = np.concatenate([s.local_x for s in samples]) if self.count else np.zeros((0, 3))
        vol = np.concatenate([s.volume for s in samples]) if self.count else np.zeros(0)
        body = np.repeat(np.arange(self.body_count, dtype=np.int32), counts)
        self.local_x = wp.array(local.astype(np.float32), dtype=wp.vec3, device=self.device)
        self.volume = wp.array(vol.astype(np.float32), dtype=float, device=self.device)
        self.particle_body = wp.array(body, dtype=int, device=self.device)
        # reduction chunks: consecutive particles of one body, then each body's chunks in order
        c_start, c_end, c_body, b_first, b_last = [], [], [], [], []
        for k in range(self.body_count):
            b_first.append(len(c_start))
            lo, hi = int(self.offsets[k]), int(self.offsets[k + 1])
            for a in range(lo, hi, chunk):
                c_start.append(a)
                c_end.append(min(a + chunk, hi))
                c_body.append(k)
            b_last.append(len(c_start))
        self.chunk_count = len(c_start)
        self._chunk_start = wp.array(np.asarray(c_start, np.int32), dtype=int, device=self.device)
        self._chunk_end = wp.array(np.asarray(c_end, np.int32), dtype=int, device=self.device)
        self._chunk_body = wp.array(np.asarray(c_body, np.int32), dtype=int, device=self.device)
        self._body_chunk_start = wp.array(np.asarray(b_first, np.int32), dtype=int, device=self.device)
        self._body_chunk_end = wp.array(np.asarray(b_last, np.int32), dtype=int, device=self.device)
        self._chunk_wrench = wp.zeros(max(self.chunk_count, 1), dtype=wp.spatial_vector, device=self.device)

    def place(self, body_q: wp.array, body_qd: wp.array, body_com: wp.array,
              boundary_x: wp.array, boundary_v: wp.array) -> None:
        """Write the moving particles' positions x = R x_local + p [m] and velocities
        v = v_com + omega x (x - x_com) [m/s] into boundary_x / boundary_v at ``start``..."""
        launch(_rigid.place_body_particles, self.count,
               [self.start, self.particle_body, self.local_x, body_com, body_q, body_qd],
               [boundary_x, boundary_v], device=self.device, min_range=LIGHT_MIN_RANGE)

    def wrench(self, body_q: wp.array, body_com: wp.array, boundary_x: wp.array,
               body_particle_force: wp.array, body_f_out: wp.array) -> None:
        """body_f_out[k] = (sum F_i, sum (x_i - x_com) x F_i) over body k's particles [N, N m]: world frame,
        torque about the centre of mass, summed in a fixed order (bitwise reproducible). F_i =
        ``body_particle_force[i]`` (one per moving particle), x_i = ``boundary_x[start + i]``."""
        if self.body_count == 0:
            return
        launch(_rigid.body_wrench_chunks, self.chunk_count,
               [self.start, self._chunk_start, self._chunk_end, self._chunk_body, body_com, body_q,
                boundary_x, body_particle_force], [self._chunk_wrench], device=self.device)
        launch(_rigid.sum_body_wrench, self.body_count,
               [self._body_chunk_start, self._body_chunk_end, self._chunk_wrench], [body_f_out],
               device=self.device)


def insert_coupling_stages(stages: list[Stage], solver, force_stage, motion_stage, what: str) -> list[Stage]:
    """The solver's stages with ``force_stage(solver.body_coupling_velocity)`` right after its coupling stage
    (``solver.body_coupling_after``) and ``motion_stage()`` at the end: bodies and animated obstacles alike.
    ``what``: the scene's word for them in the one-line SceneError of a solver naming a stage it lacks."""
    from ..core.errors import SceneError

    names = [s.name for s in stages]
    after = solver.body_coupling_after
    if after not in names:
        raise SceneError(f"{what}: the {solver.name} solver names stage {after!r} as its coupling point, but its "
                         f"stages are {', '.join(names)}")
    k = names.index(after) + 1
    return stages[:k] + [force_stage(solver.body_coupling_velocity)] + stages[k:] + [motion_stage()]


def boundary_force_stage(sim, name: str, start: int, count: int, force: wp.array, writes: str, doc: str,
                         velocity: str = "particle_v") -> Stage:
    """The stage that gathers the fluid's force [N] on the moving boundary particles ``start ..
    start + count - 1`` into ``force``: the negative of the scene's boundary terms, pair by pair (Akinci
    et al. 2012). Bodies (the wrench) and animated obstacles (their work) share it; ``velocity``: the
    workspace field of the fluid velocities the boundary terms were evaluated with
    (``Solver.body_coupling_velocity``)."""
    m = sim.model
    terms, params = sim.boundary_terms, sim.boundary_params
    kernel = _rigid.body_particle_force_kernel(m.smoothing.name, terms)
    with_pressure = terms.pressure is not None
    no_term = wp.zeros(1, dtype=float, device=m.device)

    def run(sim, dt):
        f = sim.fields
        nl = f["neighbor_lists"]
        fc = nl.fluid_cells
        term = f["boundary_pressure_term"] if with_pressure else no_term
        launch(kernel, count,
               [m.particle_mass, m.smoothing_length, m.support_radius, params, start,
                m.boundary_x, m.boundary_v, m.boundary_volume, fc.lo, fc.inv_cell_size, fc.dims, fc.cell_start,
                fc.cell_point, nl.search_radius, f["particle_x"], f[velocity], f["particle_density"], term],
               [force], device=m.device)

    reads = ("neighbor_lists", "particle_x", velocity, "particle_density", "boundary_x", "boundary_v",
             "boundary_volume") + (("boundary_pressure_term",) if with_pressure else ())
    return Stage(name, run, reads=reads, writes=(writes,), doc=doc)
