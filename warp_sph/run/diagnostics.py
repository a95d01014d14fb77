"""A frame's diagnostics (``Simulation.statistics``): the host half of kernels/diagnostics.py.

One device reduction over the fluid (speeds, density errors, energies, acceleration) and the watchdog's
device rules, read once per frame, and the energy rule (``warp_sph.run.energy``), as ``FrameStatistics``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import warp as wp

from ..core.launch import launch
from ..kernels import diagnostics as _diag


@dataclass
class FrameStatistics:
    """Diagnostics of the state at the end of a frame (one host read)."""

    frame: int
    time: float                 # [s]
    steps: int                  # substeps in this frame
    dt_min: float               # [s]
    dt_max: float               # [s]
    max_speed: float            # [m/s]
    density_error_mean: float   # mean of max(rho/rho0 - 1, 0) [-] (compression only, as SPlisHSPlasH)
    density_error_max: float    # max of rho/rho0 - 1 [-]
    density_error_min: float    # min of rho/rho0 - 1 [-] (surface particles read under-dense)
    kinetic_energy: float       # [J] of the fluid
    potential_energy: float     # [J] of the fluid, relative to the local origin
    non_finite: int
    outside: int
    max_acceleration: float = 0.0
    body_speed: float = 0.0     # largest speed of a moving boundary particle (bound) [m/s]
    bodies: dict = field(default_factory=dict)  # per body: pose, velocities, fluid force (``SimulationBodies``)
    solver: dict = field(default_factory=dict)
    retries: int = 0            # frames retried with a halved step (time.on_instability = "retry")
    watch: dict = field(default_factory=dict)  # watchdog counts and first particle index per rule
    compression_energy: float = 0.0  # [J] stored by the solver's equation of state (WCSPH; 0 for PBF, DFSPH);
    #                                  not part of the total the energy rule checks (``warp_sph.run.energy``)
    body_energy: float = 0.0    # [J] kinetic + potential of the rigid bodies (local origin)
    energy_growth: float = 0.0  # (E - E(0)) / the scene's energy scale [-] (``warp_sph.run.energy``)
    flow: dict = field(default_factory=dict)  # emitters and sinks: particles, emitted, removed (``ParticleFlow``)

    def to_dict(self) -> dict:
        """The statistics as a plain dict (the per-frame record in run.json; ``flow`` only with emitters or sinks)."""
        out = dict(self.__dict__)
        if not out["flow"]:
            del out["flow"]
        return out


class FrameDiagnostics:
    """The statistics buffer on ``device`` (``STAT_COUNT`` floats) and the frame's reduction into it."""

    def __init__(self, device):
        self.buffer = wp.zeros(_diag.STAT_COUNT, dtype=float, device=device)

    def read(self, sim, steps: int = 0, dt_min: float = 0.0, dt_max: float = 0.0,
             at_time: float | None = None) -> FrameStatistics:
        """``sim``'s state reduced on the device and read once, with the energy rule (see ``Simulation.statistics``)."""
        m = sim.model
        f = sim.fields
        acc = f.get("particle_acceleration")
        if acc is None:
            acc = sim.allocate("particle_acceleration", wp.vec3)
        check = m.container_lo is not None
        tol = m.spacing
        lo = wp.vec3(*(m.container_lo - tol)) if check else wp.vec3(0.0)
        hi = wp.vec3(*(m.container_hi + tol)) if check else wp.vec3(0.0)
        # a particle past an open face's plane left through it (or flies above an open top), one past a side
        # wall's plane over an open top's rim went over it: neither is "outside" (``ParticleFlow.top``)
        open_bounds, top = [[-1e30] * 3, [1e30] * 3], (-1, 1.0, 0.0)
        if check and sim.flow is not None:
            for axis, side in sim.flow.open_faces:
                open_bounds[side][axis] = float((m.container_hi if side else m.container_lo)[axis])
            if sim.flow.top is not None:  # over an open top's rim, or spilled down a side wall's outside
                axis, side = sim.flow.top
                rim = float((m.container_hi if side else m.container_lo)[axis])
                top = (axis, 1.0 if side else -1.0, rim - (1.0 if side else -1.0) * sim.flow.spill_band)
        wd = sim.watchdog
        t = sim.state.time if at_time is None else at_time
        launch(_diag.reset_statistics, 1, [], [self.buffer, wd.watch], device=sim.device)
        launch(_diag.accumulate_statistics, m.fluid_count,
               [m.particle_mass, m.rest_density, wp.vec3(*m.gravity), lo, hi, int(check),
                wp.vec3(*open_bounds[0]), wp.vec3(*open_bounds[1]), top[0], top[1], top[2], float(wd.speed_limit(t)), float(wd.density_limit),
                f["particle_x"], f["particle_v"], f["particle_density"], acc], [self.buffer, wd.watch],
               device=sim.device)
        s = self.buffer.numpy()
        watch = wd.read()
        n = m.fluid_count
        bodies, body_speed = sim.bodies.frame_record() if sim.bodies is not None else ({}, 0.0)
        if sim.colliders is not None:
            bodies = {**bodies, **sim.colliders.frame_record()}
        energy = {"kinetic_energy": float(s[_diag.STAT_KINETIC_ENERGY]),
                  "potential_energy": float(s[_diag.STAT_POTENTIAL_ENERGY])}
        if at_time is None:
            e, growth, bad = wd.energy.check()
            watch["energy"], watch["first_energy"] = int(bad), -1
            energy = {"kinetic_energy": e.kinetic, "potential_energy": e.potential, "compression_energy": e.compression,
                      "body_energy": e.bodies, "energy_growth": growth}
        return FrameStatistics(
            body_speed=body_speed, bodies=bodies,
            frame=sim.state.frame, time=sim.state.time, steps=steps, dt_min=dt_min, dt_max=dt_max,
            max_speed=float(s[_diag.STAT_MAX_SPEED]),
            density_error_mean=float(s[_diag.STAT_SUM_COMPRESSION]) / n if n else 0.0,  # (none yet: emitters)
            density_error_max=float(s[_diag.STAT_MAX_DENSITY_ERROR]) if n else 0.0,
            density_error_min=float(s[_diag.STAT_MIN_DENSITY_ERROR]) if n else 0.0,
            **energy, non_finite=watch["non_finite"], outside=watch["outside"],
            max_acceleration=float(s[_diag.STAT_MAX_ACCELERATION]),
            watch=watch, flow=sim.flow.record() if sim.flow is not None else {},
        )
