"""Methods as plug-ins: the registry, a solver defined here, the solver x boundary matrix, and stages that
touch only the fields they declare."""
import math

import numpy as np
import pytest
import warp as wp

from warp_sph.core.errors import SceneError
from warp_sph.core.launch import LIGHT_MIN_RANGE, launch
from warp_sph.core.step_graph import Stage
from warp_sph.kernels import integrate as integrate_dev
from warp_sph.methods import registry
from warp_sph.methods.density import density_stage, neighbors_stage
from warp_sph.methods.solver import Solver, TimeStepBound
from warp_sph.run.simulation import Simulation
from warp_sph.scene import Param, load_scene, scene_from_dict

SOLVERS = registry.solver_names()
BOUNDARIES = registry.boundary_names()


def force_groups() -> list[list[str]]:
    """Every registered force in as few scenes as the one-per-kind rule allows: group k holds the k-th
    force of each kind (a force registered later joins the matrix by itself)."""
    by_kind: dict[str, list[str]] = {}
    for name, cls in registry.forces().items():
        by_kind.setdefault(cls.kind, []).append(name)
    return [[names[k] for names in by_kind.values() if k < len(names)]
            for k in range(max(map(len, by_kind.values()), default=0))]


FORCE_GROUPS = force_groups()


def tank(solver="wcsph", boundary="akinci2012", **extra):
    """A 0.2 m deep pool filling a 0.2 x 0.2 x 0.4 m tank, r = 0.0125 m (about 1,300 particles)."""
    d = {
        "particle_radius": 0.0125, "solver": solver, "boundary": boundary, "fps": 20.0,
        "container": {"min": [0, 0, 0], "max": [0.2, 0.2, 0.4]},
        "fluid": [{"min": [0, 0, 0], "max": [0.2, 0.2, 0.2]}],
        "output": {"usd": False},
    }
    for k, v in extra.items():
        d[k] = {**d.get(k, {}), **v} if isinstance(v, dict) else v
    return scene_from_dict(d)


# --- a solver defined in this file ----------------------------------------------------------------
class TinySolver(Solver):
    """Gravity and linear damping only (no pressure): the smallest solver that runs."""

    name = "tiny"
    title = "gravity with linear damping (a test solver)"
    parameters = (Param("tiny.damping", "float", "1/s", 0.5, "velocity damping rate", ge=0.0, le=100.0),)

    @classmethod
    def validate(cls, scene, fail):
        if scene.section("tiny").damping > 50.0 and scene.gravity[2] == 0.0:
            fail("tiny.damping", "a damping above 50 /s needs gravity")

    def stages(self):
        sim, m = self.sim, self.model
        sim.allocate("particle_acceleration", wp.vec3)
        g = np.asarray(m.gravity, dtype=np.float64)

        def run_accelerate(sim, dt):
            v = sim.fields["particle_v"].numpy().astype(np.float64)
            a = g[None] - self.config.damping * v
            sim.fields["particle_acceleration"].assign(wp.array(a.astype(np.float32), dtype=wp.vec3,
                                                                device=m.device))

        def run_integrate(sim, dt):
            f = sim.fields
            launch(integrate_dev.integrate_symplectic_euler, m.fluid_count, [f["particle_acceleration"], float(dt)],
                   [f["particle_v"], f["particle_x"]], device=m.device, min_range=LIGHT_MIN_RANGE)

        return [neighbors_stage(sim), density_stage(sim),
                Stage("accelerate", run_accelerate, reads=("particle_v",), writes=("particle_acceleration",)),
                Stage("integrate", run_integrate, reads=("particle_acceleration",),
                      updates=("particle_v", "particle_x"))]

    def time_step_bounds(self, speed):
        return [TimeStepBound("tiny CFL", 0.4 * self.model.spacing / max(speed, 1e-3), "0.4 d / v")]


@pytest.fixture
def tiny_solver():
    registry.register_solver(TinySolver)
    yield TinySolver
    registry.unregister("tiny")


def test_a_solver_defined_in_a_test_registers_validates_and_runs(tiny_solver, device):
    assert "tiny" in registry.solver_names()
    from warp_sph.scene import parameter_table_markdown

    assert "`tiny.damping`" in parameter_table_markdown()
    scene = load_scene("hydrostatic", ["solver=tiny", "tiny.damping=2.0", "particle_radius=0.05"])
    assert scene.tiny.damping == 2.0 and scene.to_dict()["tiny"] == {"damping": 2.0}
    with pytest.raises(SceneError, match=r"tiny\.damping: expected a finite number >= 0 and <= 100, got -1"):
        load_scene("hydrostatic", ["solver=tiny", "tiny.damping=-1"])
    with pytest.raises(SceneError, match=r"tiny\.damping: a damping above 50 /s needs gravity"):
        load_scene("hydrostatic", ["solver=tiny", "tiny.damping=60", "gravity=[0, 0, 0]"])
    sim = Simulation(scene, device=device)
    assert sim.graph.names() == ["neighbors", "density", "accelerate", "integrate"]
    z0 = sim.get_field("particle_x")[:, 2].mean()
    stats = sim.advance_frame()
    assert stats.steps >= 1 and stats.non_finite == 0
    assert sim.get_field("particle_x")[:, 2].mean() < z0  # it fell
    registry.unregister("tiny")
    with pytest.raises(SceneError, match=r"solver: expected one of"):
        load_scene("hydrostatic", ["solver=tiny"])


def test_registry_refuses_a_taken_or_reserved_name():
    class Clash(Solver):
        name = "pbf"

    with pytest.raises(ValueError, match="already taken"):
        registry.register_solver(Clash)

    class Reserved(Solver):
        name = "material"

    with pytest.raises(ValueError, match="already taken"):
        registry.register_solver(Reserved)


# --- every solver with every boundary ---------------------------------------------------------------
@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("solver", SOLVERS)
def test_solver_boundary_matrix_small_tank(solver, boundary, device):
    """Nobody leaves the tank, and averaged over 1 s after a settling second the walls carry the fluid's
    weight within 3 % (a penalty wall is a soft spring: the pool bounces on it for a second)."""
    sim = Simulation(tank(solver, boundary), device=device)
    m = sim.model
    weight = m.fluid_count * m.particle_mass * 9.81
    t_end, t_avg = 2.0, 1.0
    loads = []

    def record_wall_load(sim, dt):  # the walls' force on the fluid along +z, every substep after t_avg
        if sim.state.time >= t_avg:
            loads.append(float(sim.get_field("boundary_force")[:, 2].sum()))

    sim.graph.insert(Stage("wall_load", record_wall_load, reads=("boundary_force",)))
    while sim.state.time < t_end - 1e-9:
        stats = sim.advance_frame()
        assert stats.outside == 0 and stats.non_finite == 0, (solver, boundary, stats.time)
    load = float(np.mean(loads))
    assert load == pytest.approx(weight, rel=0.03), (solver, boundary, load / weight)


@pytest.mark.parametrize("group", range(len(FORCE_GROUPS)))
@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("solver", SOLVERS)
def test_solver_boundary_force_matrix_runs(solver, boundary, group, device):
    """Every force (at its defaults) with every solver and boundary: its stages run every substep, at the
    solver's slot, and the pool neither leaves the tank nor blows up (0.15 s, 125 particles)."""
    names = FORCE_GROUPS[group]
    sim = Simulation(tank(solver, boundary, particle_radius=0.02, forces=[{"method": n} for n in names]), device=device)
    assert {f.name for f in sim.forces} == set(names)  # every force is active at its defaults
    steps = 0
    for _ in range(3):
        stats = sim.advance_frame()
        steps += stats.steps
        assert stats.outside == 0 and stats.non_finite == 0, (solver, boundary, names, stats.time)
    force_stages = [s for s in sim.graph.names() if s not in _bare_names(solver, boundary)]
    assert force_stages and all(sim.graph.timings[s].calls == steps for s in force_stages), force_stages
    assert np.linalg.norm(sim.get_field("particle_v"), axis=1).max() < 2.0  # a 0.2 m pool sloshing


def _bare_names(solver, boundary) -> set:
    return set(Simulation(tank(solver, boundary, particle_radius=0.02)).graph.names())


# --- stages touch only what they declare --------------------------------------------------------------
def _arrays(value):
    """{name: wp.array} inside a workspace entry (an array, or a struct or object holding arrays)."""
    if isinstance(value, wp.array):
        return {"": value}
    out = {}
    for holder_name in ("fluid", "boundary"):  # NeighborLists
        holder = getattr(value, holder_name, None)
        if holder is not None and hasattr(holder, "count"):
            out[f".{holder_name}.count"] = holder.count
            out[f".{holder_name}.index"] = holder.index
    keep_x = getattr(value, "boundary_keep_x", None)  # where each kept boundary row was searched (PBF)
    if out and isinstance(keep_x, wp.array):
        out[".boundary_keep_x"] = keep_x
    if not out:  # a struct of arrays (PBF's PairCache, DFSPH's DfsphPairs)
        for attr in ("count", "index", "gradient", "value", "boundary_gradient", "gradient_sum", "boundary_velocity",
                     "active", "offset"):
            a = getattr(value, attr, None)
            if isinstance(a, wp.array):
                out[f".{attr}"] = a
    return out


def _snapshot(sim):
    snap = {}
    for name, value in sim.fields.items():
        for suffix, a in _arrays(value).items():
            snap[name + suffix] = a.numpy().copy()
    return snap


def _float_arrays(sim, name):
    value = sim.fields[name]
    if isinstance(value, wp.array) and value.dtype in (wp.float32, wp.vec3) and value.ndim == 1:
        return [value]
    return []


#: every registered solver with every boundary method, plus variants with the optional stages
CONFIGS = {f"{s}-{b}-plain": dict(solver=s, boundary=b) for s in SOLVERS for b in BOUNDARIES}
CONFIGS |= {
    "wcsph": dict(material={"xsph": 0.05, "viscosity": 1e-3}),
    "wcsph-friction": dict(material={"boundary_friction": 0.3}),
    "wcsph-grid": dict(material={"xsph": 0.05}, options={"lists": False}),
    "wcsph-penalty": dict(boundary="penalty"),
    "pbf": dict(solver="pbf", material={"xsph": 0.05, "viscosity": 1e-3, "boundary_friction": 0.3},
                pbf={"vorticity": 0.01, "tensile_correction": True}),
    "pbf-penalty": dict(solver="pbf", boundary="penalty"),
    "pbf-grid": dict(solver="pbf", material={"xsph": 0.05}, options={"lists": False, "neighbor_mode": "margin"}),
    "pbf-stabilize": dict(solver="pbf", compressed=True),
    "dfsph": dict(solver="dfsph", material={"xsph": 0.05, "viscosity": 1e-3, "boundary_friction": 0.3}),
    "dfsph-penalty": dict(solver="dfsph", boundary="penalty", material={"viscosity": 1e-3}),
    "dfsph-no-divergence": dict(solver="dfsph", dfsph={"divergence_solve": False}),
    "dfsph-stabilize": dict(solver="dfsph", compressed=True),
}
#: the implicit viscosity (force weiler2018) at each solver's slot, with its wall term
WEILER = [{"method": "weiler2018", "viscosity": 1.0, "boundary_viscosity": 0.5}]
CONFIGS |= {f"{s}-weiler2018": dict(solver=s, forces=WEILER) for s in SOLVERS}
#: a floating box (moving rigid body, two-way coupled): the body_forces and bodies stages join the graph
BODY = {"bodies": [{"shape": "box", "size": [0.1, 0.1, 0.08], "position": [0.1, 0.1, 0.2], "density": 500.0,
                    "velocity": [0.1, 0.0, -0.2], "angular_velocity": [0.5, 0.0, 0.0]}]}
CONFIGS |= {
    "wcsph-bodies": dict(material={"viscosity": 1e-3, "boundary_friction": 0.3}, **BODY),
    "wcsph-penalty-bodies": dict(boundary="penalty", **BODY),
    "pbf-bodies": dict(solver="pbf", material={"xsph": 0.05, "boundary_friction": 0.3}, **BODY),
    "pbf-penalty-bodies": dict(solver="pbf", boundary="penalty", **BODY),
    "dfsph-bodies": dict(solver="dfsph", material={"xsph": 0.05, "viscosity": 1e-3, "boundary_friction": 0.3}, **BODY),
    "dfsph-penalty-bodies": dict(solver="dfsph", boundary="penalty", **BODY),
    "dfsph-no-divergence-bodies": dict(solver="dfsph", dfsph={"divergence_solve": False}, **BODY),
    "dfsph-stabilize-bodies": dict(solver="dfsph", compressed=True, **BODY),
}
#: whitewater (the stage after the solver's): its reads are the step's end state
CONFIGS |= {f"{s}-whitewater": dict(solver=s, whitewater={"kinetic_energy_min": 0.0}) for s in SOLVERS}
#: every solver x boundary x force (the forces at their defaults, coarse: r = 0.02 m, 125 fluid particles)
CONFIGS |= {f"{s}-{b}-forces{k}": dict(solver=s, boundary=b, particle_radius=0.02,
                                       forces=[{"method": name} for name in group])
            for s in SOLVERS for b in BOUNDARIES for k, group in enumerate(FORCE_GROUPS)}


def _restore(sim, snap, names):
    for name in names:
        for suffix, a in _arrays(sim.fields[name]).items():
            a.assign(wp.array(snap[name + suffix], dtype=a.dtype, device=a.device))


@pytest.mark.parametrize("config", sorted(CONFIGS))
def test_stages_touch_only_the_fields_they_declare(config, device):
    """Each stage runs twice from the same state, with every float field it does not declare filled with
    one poison value and then another: no undeclared field changes, and what it writes or updates is the
    same both times (it read no field it did not declare)."""
    c = dict(CONFIGS[config])
    options = c.pop("options", {})
    compressed = c.pop("compressed", False)
    scene = tank(**c)
    if compressed:
        data = scene.to_dict()
        data["fluid"][0]["spacing_scale"] = 0.92
        scene = scene_from_dict(data)
    sim = Simulation(scene, solver_options=options, device=device)
    if not compressed:
        sim.step(1e-4)  # every field holds a value (the compressed start keeps its error for "stabilize")
    stabilized = 0
    for stage in sim.graph.stages:
        declared = set(stage.writes) | set(stage.updates)
        keep = set(stage.reads) | set(stage.updates)
        before = _snapshot(sim)
        solver_state = dict(vars(sim.solver))
        results = []
        for poison in (-7.77e5, 3.33e4):
            _restore(sim, before, sim.fields)
            sim.solver.__dict__.update(solver_state)
            for name in sim.fields:
                if name not in keep:
                    for a in _float_arrays(sim, name):
                        a.fill_(poison)
            poisoned = _snapshot(sim)
            stage.run(sim, 1e-4)
            after = _snapshot(sim)
            changed = {k.partition(".")[0] for k in after if not np.array_equal(after[k], poisoned[k], equal_nan=True)}
            assert changed <= declared, f"{config}: {stage.name!r} changed undeclared {sorted(changed - declared)}"
            results.append({k: v for k, v in after.items() if k.partition(".")[0] in declared})
        for k in results[0]:
            assert np.array_equal(results[0][k], results[1][k], equal_nan=True), \
                f"{config}: {stage.name!r} wrote {k} from a field it does not declare (differs between poisons)"
        stabilized = max(stabilized, getattr(sim.solver, "last_stabilization", 0))
        _restore(sim, before, [n for n in sim.fields if n not in declared])
    if compressed:
        assert stabilized > 0  # the stabilize stage did its work under the poison


def test_set_solver_swaps_the_graph_and_keeps_the_state(device):
    sim = Simulation(tank(), device=device)
    x = sim.get_field("particle_x")
    sim.set_solver("pbf")
    assert sim.solver.name == "pbf" and "solve" in sim.graph.names()
    np.testing.assert_array_equal(sim.get_field("particle_x"), x)
    assert math.isfinite(sim.advance_frame().max_speed)
