"""Weakly compressible SPH (Becker & Teschner 2007); kernels in ``kernels/wcsph.py``.

Step: neighbours -> density (eq. 7/13, + the delta-SPH density correction) -> [filters: XSPH, eq. 21] -> [explicit forces: their
accelerations] -> pressure (eq. 9 or Tait) -> forces (eq. 10, the boundary method's terms, artificial
viscosity, the explicit forces' accelerations, gravity; the delta-SPH diffusion: delta rho += dt D) ->
semi-implicit Euler (eq. 11); with an
implicit force: kick (v += dt a) -> [implicit forces on v*] -> drift (x += dt v). The forces' slot is
"before_pressure" (``warp_sph.methods.force``).

delta-SPH (``wcsph.density_diffusion`` = delta > 0; Molteni & Colagrossi 2009, the hydrostatic-corrected
form of Fourtakas et al. 2019, DualSPHysics' "DDT" type 2): the continuity equation gains
D_i = 2 delta h c_s sum_j (rho_j - rho_i - rho^H_ji) (x_ji . grad_i W_ij) / (|x_ij|^2 + 0.01 h^2) V_j, a diffusion
of the density that damps the acoustic noise and the water hammer rho0 c_s v of an impact. Here the density
is a summation (eq. 7), which is the exact time integral of the continuity equation's convective part
sum_j m v_ij . grad W_ij; the diffusion's part is integrated into a per-particle correction delta rho
(``wcsph_density_correction``, carried, checkpointed) that the density stage adds: rho = sum_j m W_ij + delta rho,
whose rate is the delta-SPH continuity equation.
"""
from __future__ import annotations

import math

import numpy as np
import warp as wp

from ...core.launch import LIGHT_MIN_RANGE, launch, replaying_launch
from ...core.step_graph import Stage
from ...kernels import integrate as _integrate
from ...kernels import wcsph as _wcsph
from ...scene.parameters import Param
from ..density import density_stage, neighbor_args, neighbors_stage
from ..registry import register_solver
from ..solver import Solver, TimeStepBound
from ..force import FORCE_ACCELERATION, ForceSlot
from .wcsph_lists import KeptLists, pair_cache

EQUATIONS_OF_STATE = ("linear", "tait")

#: The fastest approach, as a fraction of c_s, at which one Akinci wall layer still turns a lone particle
#: (a spray drop) back, by the wall pressure term: its own density m W(0) = 0.32 rho0 leaves it without
#: pressure until the wall adds 0.68 rho0, so the wall's energy barrier is ~0.035 c_s^2 per kg. Measured by
#: throwing one particle at the floor (c_s = 100 m/s, d = 0.1 m, tests/test_robust.py): eq16 turns
#: 0.25 c_s back and lets 0.30 c_s through, mirrored 0.40 / 0.50. Independent of the time step.
WALL_ESCAPE_FRACTION = {"eq16": 0.25, "mirrored": 0.40}

#: default ``wcsph.search_skin`` [spacings d] (issue #32)
SEARCH_SKIN = 0.2


@register_solver
class WcsphSolver(Solver):
    """Explicit WCSPH. Time step: acoustic CFL dt <= cfl (H_s/2) / (c_s + v_max); the forces add their own
    bounds. Stiffness K [Pa]: ``wcsph.stiffness``, or rho0 c_s^2
    (linear) / rho0 c_s^2 / 7 (Tait) from the model's speed of sound c_s.

    lists: neighbour lists built once per step and read by density, the forces and the force kernel (default), or
    hash-grid queries in every pass (``lists=False``, the reference variant)."""

    name = "wcsph"
    title = "weakly compressible SPH (Becker & Teschner 2007)"
    body_coupling_after = "forces"  # the wall's p/rho^2 is its boundary_pressure_term
    relaxed_start = True  # an over-dense start is elastic energy ~ c_s^2 delta^2 / 2 per kg (issue #36)
    section_doc = "weakly compressible SPH settings"
    parameters = (
        Param("wcsph.equation_of_state", "str", "-", "linear", "p = k (rho/rho0 - 1) (linear) or "
              "p = B ((rho/rho0)^7 - 1) (Tait, Becker & Teschner 2007)", choices=EQUATIONS_OF_STATE),
        Param("wcsph.speed_of_sound", "float", "m/s", 0.0, "speed of sound c_s (0: derived from "
              "speed_of_sound_factor); also sets the Akinci friction and the penalty force", ge=0.0),
        Param("wcsph.speed_of_sound_factor", "float", "-", 10.0, "c_s = factor * sqrt(2 g H_fluid) when "
              "speed_of_sound is 0 (factor 10 keeps the density error near 1 %)", gt=0.0),
        Param("wcsph.stiffness", "float", "Pa", 0.0, "stiffness k (linear) or B (Tait); 0: derived "
              "from c_s, k = rho0 c_s^2 or B = rho0 c_s^2 / 7; when > 0 it sets c_s = sqrt(k / rho0) or "
              "sqrt(7 B / rho0) (the time step follows it)", ge=0.0),
        Param("wcsph.boundary_pressure", "str", "-", "eq16", "pressure term of Akinci boundary particles: "
              "'eq16' (report eq. 16, p_i/rho_i^2: energy-consistent, but layers near a wall read 15-70 % over "
              "rho0 g depth) or 'mirrored' (p_i/rho_i^2 + p_i/rho0^2, as SPlisHSPlasH: hydrostatic profile within "
              "4 %, but not energy-consistent: it pumps energy into a resting tank, which then never settles)", choices=("eq16", "mirrored")),
        Param("wcsph.density_diffusion", "float", "-", 0.0, "delta of the delta-SPH density diffusion (Molteni & "
              "Colagrossi 2009; the hydrostatic-corrected form of Fourtakas et al. 2019 that DualSPHysics uses, usually "
              "0.1): D_i = 2 delta h c_s sum_j (rho_j - rho_i - rho^H_ji) x_ji . grad W_ij / r_ij^2 V_j in the "
              "continuity equation, every particle starting at rho0, pairs next to a wall left out (their wall share of the "
              "density is the wall's push); damps acoustic noise (a settling tank) but a negative correction a "
              "particle takes at a free surface goes with it into a splash, which the one-layer wall then holds less "
              "well (docs/validation-notes.md), hence off (0) by default", ge=0.0, le=1.0),
        Param("wcsph.artificial_viscosity", "float", "-", 0.0, "artificial viscosity alpha (Monaghan 1992, "
              "Becker & Teschner 2007): nu = 2 alpha h c_s / (rho_i + rho_j) on approaching pairs only; dissipates "
              "impacts (a 14 m/s drop keeps 30 % of its energy with 0.5 instead of 100 %), the acoustic step shrinks "
              "by 1 + 0.6 alpha", ge=0.0, le=10.0),
        Param("wcsph.search_skin", "float", "-", SEARCH_SKIN, "neighbour lists within H_s + skin (in spacings d) kept "
              "over the steps until two particles may have closed in by more than the skin (Verlet lists; "
              "the smaller of twice the largest displacement and the diagonal of the displacements' box, "
              "``wcsph_lists.py``): the acoustic step moves particles far less than d per step, so one cell walk "
              "serves several steps; 0: a search every step. Changes results only by the order of sums",
              ge=0.0, le=2.0),
    )

    def __init__(self, sim, lists: bool = True):
        super().__init__(sim)
        self.lists = bool(lists)
        m = self.model
        c_s = m.speed_of_sound
        eos = self.config.equation_of_state
        self.stiffness = float(self.config.stiffness) if self.config.stiffness > 0 else (
            m.rest_density * c_s * c_s / (7.0 if eos == "tait" else 1.0))
        self.density_diffusion = float(self.config.density_diffusion)
        self.search_skin = float(self.config.search_skin) * m.spacing if self.lists else 0.0  # [m]
        self.kept_lists = None  # ``KeptLists`` with a skin (``stages``)
        self._started = False  # the start's correction is set once (``refresh_density``)

    def density_diffusion_constants(self) -> tuple[float, wp.vec3]:
        """(2 delta h c_s [m^2/s], rho0 g / c^2 [kg/m^4]) of the delta-SPH term, c^2 = dp/drho at rho0
        (K / rho0 linear, 7 B / rho0 Tait: the hydrostatic density difference is linearised, so that it is
        exactly antisymmetric and the term conserves sum_i V_i delta rho_i)."""
        m = self.model
        bulk = self.stiffness * (7.0 if self.config.equation_of_state == "tait" else 1.0)  # rho0 c^2 [Pa]
        c = math.sqrt(bulk / m.rest_density)
        coefficient = 2.0 * self.density_diffusion * m.smoothing_length * c
        g = np.asarray(m.gravity, dtype=np.float64) * m.rest_density * m.rest_density / bulk
        return float(coefficient), wp.vec3(*[float(v) for v in g])

    def stages(self) -> list[Stage]:
        sim, m = self.sim, self.model
        sim.allocate("particle_pressure", float)
        sim.allocate("wcsph_pressure_term", float)  # p / rho^2, read per pair by the forces
        sim.allocate("particle_acceleration", wp.vec3)
        sim.allocate("boundary_force", wp.vec3)
        terms, params = sim.boundary_terms, sim.boundary_params
        with_boundary = terms is not None
        mirrored = self.config.boundary_pressure == "mirrored"
        pressure_kernel = _wcsph.pressure_kernel(self.config.equation_of_state)
        bodies = self.with_bodies
        slot = ForceSlot("before_pressure", "list" if self.lists else "grid", "particle_x", gravity_in_velocity=True)
        forces = sim.forces
        explicit = forces.explicit_stages(slot)
        implicit = forces.implicit_stages(slot)
        with_forces = bool(explicit)
        accel = sim.fields[FORCE_ACCELERATION] if with_forces else wp.zeros(1, dtype=wp.vec3, device=m.device)
        diffusion = self.density_diffusion > 0.0
        skin = self.search_skin > 0.0
        force_kernel = _wcsph.acceleration_kernel(m.smoothing.name, terms, with_forces, mirrored,
                                                  "pairs" if skin else "list" if self.lists else "grid",
                                                  self.config.artificial_viscosity > 0.0, bodies, diffusion)
        correction = (sim.allocate("wcsph_density_correction", float) if diffusion
                      else wp.zeros(1, dtype=float, device=m.device))
        coefficient, hydrostatic = self.density_diffusion_constants()
        term = sim.allocate("boundary_pressure_term", float) if bodies else wp.zeros(1, dtype=float, device=m.device)
        gravity = wp.vec3(*m.gravity)
        neighbors = "neighbor_lists" if self.lists else "fluid_grid"
        stiffness = self.stiffness
        run = replaying_launch(m.device)  # the step's own launches, replayed on the CPU

        def run_pressure(sim, dt):
            run(pressure_kernel, m.fluid_count, [m.rest_density, stiffness, sim.fields["particle_density"]],
                [sim.fields["particle_pressure"], sim.fields["wcsph_pressure_term"]], min_range=LIGHT_MIN_RANGE)

        no_pairs = None if skin else pair_cache(1, 1, m.device)  # the pairs argument without a skin (unread)

        def pairs():
            return self.kept_lists.pairs if skin else no_pairs

        def run_forces(sim, dt):
            f = sim.fields
            bn, fn = neighbor_args(sim, self.lists)
            run(force_kernel, m.fluid_count,
                [m.particle_mass, m.smoothing_length, m.support_radius, m.rest_density, gravity,
                 float(self.config.artificial_viscosity * m.smoothing_length * m.speed_of_sound),
                 coefficient, hydrostatic, float(dt), params, bn,
                 m.boundary_x, m.boundary_v, m.boundary_volume, fn, pairs(), f["particle_x"], f["particle_v"],
                 f["particle_density"], f["particle_pressure"], f["wcsph_pressure_term"], accel],
                [f["particle_acceleration"], f["boundary_force"], term, correction])

        def run_integrate(sim, dt):
            f = sim.fields
            run(_integrate.integrate_symplectic_euler, m.fluid_count, [f["particle_acceleration"], float(dt)],
                [f["particle_v"], f["particle_x"]], min_range=LIGHT_MIN_RANGE)

        def run_kick(sim, dt):
            f = sim.fields
            launch(_integrate.kick, m.fluid_count, [f["particle_acceleration"], float(dt)], [f["particle_v"]], device=m.device,
                   min_range=LIGHT_MIN_RANGE)

        def run_drift(sim, dt):
            f = sim.fields
            launch(_integrate.drift, m.fluid_count, [float(dt), f["particle_v"]], [f["particle_x"]], device=m.device,
                   min_range=LIGHT_MIN_RANGE)

        boundary_reads = (("boundary_x", "boundary_volume") + (() if self.lists else ("boundary_grid",))
                          + (("boundary_v",) if bodies else ()) if with_boundary else ())
        terms_doc = ["pressure (eq. 10)"]
        if with_boundary:
            terms_doc.append(f"{terms.name} boundary" + (" (mirrored pressure)" if mirrored and terms.pressure else ""))
        if self.config.artificial_viscosity > 0.0:
            terms_doc.append("artificial viscosity")
        if diffusion:
            terms_doc.append(f"delta-SPH density diffusion (delta = {self.density_diffusion:g}: delta rho += dt D)")
        if with_forces:
            terms_doc.append("forces (" + ", ".join(f.name for f in forces.of_mode("explicit")) + ")")
        terms_doc.append("gravity")
        if skin:
            self.kept_lists = KeptLists(sim, self.search_skin, bodies)
            neighbors_and_density = self.kept_lists.stages(
                ("boundary_x", "boundary_volume") if terms is not None and terms.density is not None else ())
        else:
            neighbors_and_density = (neighbors_stage(sim, self.lists), density_stage(sim, self.lists))
        density = neighbors_and_density[1]
        if diffusion:  # rho = the summation + the density the diffusion moved (module docstring)
            summation = density.run

            def run_density(sim, dt):
                summation(sim, dt)
                run(_wcsph.add_density_correction, m.fluid_count, [correction], [sim.fields["particle_density"]],
                    min_range=LIGHT_MIN_RANGE)

            density = Stage("density", run_density, reads=density.reads + ("wcsph_density_correction",),
                            writes=density.writes, updates=density.updates,
                            doc=density.doc + " + delta rho (delta-SPH density correction)")
        stages = [neighbors_and_density[0], density]
        stages += forces.filter_stages(slot) + explicit
        stages += [
            Stage("pressure", run_pressure, reads=("particle_density",),
                  writes=("particle_pressure", "wcsph_pressure_term"),
                  doc=f"{self.config.equation_of_state} equation of state, K = {stiffness:.4g} Pa"),
            Stage("forces", run_forces,
                  reads=(neighbors, "particle_x", "particle_v", "particle_density", "particle_pressure")
                  + ("wcsph_pressure_term",) + (("wcsph_pairs",) if skin else ()) + boundary_reads
                  + ((FORCE_ACCELERATION,) if with_forces else ()),
                  writes=("particle_acceleration", "boundary_force") + (("boundary_pressure_term",) if bodies else ()),
                  updates=("wcsph_density_correction",) if diffusion else (),
                  doc=" + ".join(terms_doc)),
        ]
        if implicit:  # the implicit forces act on v* = v + dt a, before the positions move
            stages += [Stage("kick", run_kick, reads=("particle_acceleration",), updates=("particle_v",),
                             doc="v += dt a (eq. 11, velocity)")]
            stages += implicit
            stages += [Stage("drift", run_drift, reads=("particle_v",), updates=("particle_x",), doc="x += dt v (eq. 11, position)")]
        else:
            stages += [Stage("integrate", run_integrate, reads=("particle_acceleration",),
                             updates=("particle_v", "particle_x"), doc="semi-implicit Euler (eq. 11)")]
        return stages

    def refresh_density(self) -> None:
        """The density at the current positions; at the start (the first refresh of a run's first step, unless
        a checkpoint was restored) with delta-SPH, the correction is set so that every particle starts at rho0
        (``start_density_correction``); otherwise (a resume, a retry, later) the carried correction is added."""
        if self.kept_lists is not None:
            self.kept_lists.invalidate()  # positions changed from outside: search anew
        if self.density_diffusion > 0.0 and not self._started and self.sim.state.step == 0:
            self._started = True
            f = self.sim.fields
            f["wcsph_density_correction"].zero_()
            super().refresh_density()
            launch(_wcsph.start_density_correction, self.model.fluid_count, [self.model.rest_density],
                   [f["particle_density"], f["wcsph_density_correction"]], device=self.model.device,
                   min_range=LIGHT_MIN_RANGE)
            return
        super().refresh_density()

    def carried_fields(self) -> tuple[str, ...]:
        """The delta-SPH density correction (when on): the density the diffusion moved so far; with a search skin
        the kept neighbour lists and where (and at which index) each particle was when they were searched."""
        kept = (("neighbor_lists", "wcsph_neighbor_x", "wcsph_neighbor_slot", "wcsph_wall_x") if self.search_skin > 0.0
                else ())
        return (("wcsph_density_correction",) if self.density_diffusion > 0.0 else ()) + kept

    def checkpoint_arrays(self) -> dict:
        return ({"wcsph_density_correction": self.sim.fields["wcsph_density_correction"]} if self.density_diffusion > 0.0
                else {})

    def restore_arrays(self, arrays) -> None:
        if self.kept_lists is not None:
            self.kept_lists.invalidate()
        if self.density_diffusion <= 0.0:
            return
        self._started = True  # the restored correction is the state: no start rule after it
        f = self.sim.fields["wcsph_density_correction"]
        a = arrays.get("wcsph_density_correction")
        if a is None:
            f.zero_()
        else:
            f.assign(a if isinstance(a, wp.array) else wp.array(np.asarray(a), dtype=float, device=self.model.device))

    def time_step_bounds(self, speed: float) -> list[TimeStepBound]:
        m = self.model
        cfl = self.sim.scene.time.cfl
        length = 0.5 * m.support_radius
        keys = ("wcsph.stiffness",) if self.config.stiffness > 0 else (
            ("wcsph.speed_of_sound",) if self.config.speed_of_sound > 0 else ("wcsph.speed_of_sound_factor",))
        alpha = float(self.config.artificial_viscosity)
        if alpha > 0:  # Becker & Teschner 2007: dt <= 0.4 h / (c_s (1 + 0.6 alpha))
            acoustic = TimeStepBound("acoustic CFL", cfl * length / ((m.speed_of_sound + speed) * (1.0 + 0.6 * alpha)),
                                     f"cfl (H_s/2)/((c_s + v)(1 + 0.6 alpha)) with cfl = {cfl:g}, H_s/2 = {length:.4g} m, "
                                     f"c_s = {m.speed_of_sound:.4g} m/s, v = {speed:.3g} m/s, alpha = {alpha:g}",
                                     keys + ("time.cfl", "wcsph.artificial_viscosity"))
        else:
            acoustic = TimeStepBound("acoustic CFL", cfl * length / (m.speed_of_sound + speed),
                                     f"cfl (H_s/2)/(c_s + v) with cfl = {cfl:g}, H_s/2 = {length:.4g} m, "
                                     f"c_s = {m.speed_of_sound:.4g} m/s, v = {speed:.3g} m/s", keys + ("time.cfl",))
        return [acoustic]

    def _stiffness_key(self) -> str:
        if self.config.stiffness > 0:
            return "wcsph.stiffness"
        return "wcsph.speed_of_sound" if self.config.speed_of_sound > 0 else "wcsph.speed_of_sound_factor"

    def instability_hint(self, rule: str, stage: str | None) -> str | None:
        m = self.model
        c = m.speed_of_sound
        speed = self.sim.last_frame.max_speed if self.sim.last_frame else 0.0
        try:  # the state the watchdog left at the failure (one host read, only on an error)
            speed = max(speed, float(np.linalg.norm(self.sim.fields["particle_v"].numpy(), axis=1).max()))
        except Exception:  # pragma: no cover - advice must never hide the error
            pass
        escape = WALL_ESCAPE_FRACTION.get(self.config.boundary_pressure, 0.25)
        if rule in ("outside", "fast", "non_finite") and speed > 0.8 * escape * c:
            key = self._stiffness_key()
            need = speed / escape
            if key == "wcsph.speed_of_sound_factor":
                todo = (f"raise wcsph.speed_of_sound_factor to at least "
                        f"{1.2 * need / max(m.reference_speed, 1e-12):.3g}")
            elif key == "wcsph.speed_of_sound":
                todo = f"raise wcsph.speed_of_sound to at least {1.2 * need:.3g} m/s"
            else:
                todo = "raise wcsph.stiffness so that c_s is at least " + f"{1.2 * need:.3g} m/s"
            return (f"stiffness too low for the flow: a particle reached {speed:.3g} m/s = {speed / c:.2g} c_s "
                    f"(c_s = {c:.3g} m/s); one wall layer turns a lone particle back only below about "
                    f"{escape:g} c_s = {escape * c:.3g} m/s, whatever the time step (halving it does not help); "
                    f"{todo}, or dissipate the impact with wcsph.artificial_viscosity (e.g. 0.5)")
        if speed > 0.3 * c:
            return (f"stiffness too low: the flow reached {speed:.3g} m/s, {speed / c:.2g}x the speed "
                    f"of sound c_s = {c:.3g} m/s; raise {self._stiffness_key()}")
        if rule == "dense":
            return ("the fluid compressed to twice its rest density: the stiffness is too low for the scene; raise "
                    "wcsph.speed_of_sound_factor")
        return None

    def internal_energy(self) -> float:
        """Elastic energy stored in compression [J]: sum_i m u(rho_i / rho0), with u(X) = int_1^X p / rho^2 drho
        of the clamped equation of state (0 below rho0): K / rho0 (ln X + 1/X - 1) (linear),
        B / rho0 ((X^6 - 1) / 6 + 1/X - 1) (Tait); about c_s^2 delta^2 / 2 per kg at an over-density delta.
        Kinetic + potential + this is what WCSPH conserves (d/dt sum m u = sum m p / rho^2 D rho / Dt, the
        work of the pressure forces). It is why a stiff fluid seems to gain energy from an over-dense start
        (issue #36: the corner block's 0.79 % corner and 0.26 % edge over-density hold 7.44 J at c_s = 1000 m/s,
        exactly the kinetic + potential energy it gains). Reads the density of the last density stage (host
        read of one float per particle)."""
        m = self.model
        x = np.maximum(self.sim.fields["particle_density"].numpy().astype(np.float64) / m.rest_density, 1.0)
        if self.config.equation_of_state == "tait":
            u = (x ** 6 - 1.0) / 6.0 + 1.0 / x - 1.0
        else:
            u = np.log(x) + 1.0 / x - 1.0
        return float(m.particle_mass * self.stiffness / m.rest_density * u.sum())

    def summary(self) -> dict:
        return {"stiffness": self.stiffness, "equation_of_state": self.config.equation_of_state,
                "density_diffusion": self.density_diffusion,
                "acoustic_period": 2.0 * self.model.support_radius / max(self.model.speed_of_sound, 1e-30)}
