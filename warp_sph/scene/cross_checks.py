"""The cross-checks of a typed ``Scene`` (``Validator.scene`` calls them last): relations between values
that no single parameter row can state. time.dt_min <= time.dt_max, the packing pass only for still fluid
under gravity, output.surface_spray_neighbors below a flat surface's neighbour count, a mesh sequence only
with a surface, fluid inside the container and obstacles not entirely outside it, distinct names of moving
bodies, the solver x boundary pairing, each method's own checks (``validate``), forces, bodies, probes,
whitewater thresholds and emission. ``fail(keypath, message)`` raises the SceneError.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.smoothing import lattice_offsets
from ..methods import registry
from .meshes import load_triangle_mesh
from .types import Scene


def cross_checks(scene: Scene, fail) -> None:
    """Every cross-check of ``scene``; the first that fails raises through ``fail``."""
    time = scene.time
    if time.dt_min > time.dt_max:
        fail("time.dt_min", f"expected <= time.dt_max ({time.dt_max:g}), got {time.dt_min:g}")
    if time.settle > 0.0:  # the packing pass (warp_sph.run.settle) moves fluid only, under gravity
        moving = [what for what, there in (("[[bodies]]", scene.bodies), ("[[emitters]]", scene.emitters),
                                           ("animated [[obstacles]]", any(o.animated for o in scene.obstacles)))
                  if there]
        if moving:
            fail("time.settle", f"the packing pass moves only fluid; this scene has {moving[0]}: set "
                 f"time.settle = 0, got {time.settle:g}")
        if not math.hypot(*scene.gravity) > 0.0:
            fail("time.settle", f"the packing pass settles the fluid under gravity and gravity is 0: set "
                 f"time.settle = 0, got {time.settle:g}")
    o = scene.output
    if o.surface_spray_neighbors:
        full, flat = lattice_neighbor_counts(scene)
        if o.surface_spray_neighbors > flat:
            fail("output.surface_spray_neighbors", f"expected <= {flat}, the neighbours of a particle on "
                 f"a flat free surface within the support radius (in the bulk: {full}); with more, the "
                 f"whole surface{' and all the fluid' if o.surface_spray_neighbors > full else ''} would "
                 f"be spray; got {o.surface_spray_neighbors}")
    if o.mesh_sequence and not o.surface:
        fail("output.mesh_sequence", f"{o.mesh_sequence!r} needs output.surface = true (the sequence holds "
             "the reconstructed surface); set output.surface = true or output.mesh_sequence = ''")
    c = scene.container
    if c is not None:
        tol = 1e-9 * max(1.0, *map(abs, tuple(c.min) + tuple(c.max)))
        for i, block in enumerate(scene.fluid):
            lo, hi = block.bounds()
            if block.shape == "mesh":  # filled where it overlaps the container (sampling clips it)
                if any(b <= cl for b, cl in zip(hi, c.min)) or any(a >= ch for a, ch in zip(lo, c.max)):
                    fail(f"fluid[{i}]", f"mesh {block.file!r} (bounds {[round(x, 6) for x in lo]}.."
                         f"{[round(x, 6) for x in hi]} after scale and translate) has no volume inside the "
                         f"container {list(c.min)}..{list(c.max)}; check translate and scale")
                continue
            if any(a < cl - tol for a, cl in zip(lo, c.min)) or any(b > ch + tol for b, ch in zip(hi, c.max)):
                what = "sphere" if block.shape == "sphere" else "box"
                fail(f"fluid[{i}]", f"{what} {list(lo)}..{list(hi)} is not inside the container "
                     f"{list(c.min)}..{list(c.max)}")
        for i, ob in enumerate(scene.obstacles):
            lo, hi = _obstacle_bounds(ob)
            if ob.animated:
                from .paths import check_inside

                check_inside(ob.path, lo, hi, c, scene.duration, getattr(ob, "origin", f"obstacles[{i}]"),
                             fail)
                continue
            if np.any(hi < np.asarray(c.min)) or np.any(lo > np.asarray(c.max)):
                fail(f"obstacles[{i}]", f"lies entirely outside the container {list(c.min)}..{list(c.max)} "
                     f"(its bounds {lo.round(6).tolist()}..{hi.round(6).tolist()}); move it inside or remove it")
    if any(ob.animated for ob in scene.obstacles):  # along its path, in world coordinates
        from ..rigid.checks import check_obstacle_paths

        check_obstacle_paths(scene, fail)
    moving = [(f"bodies[{i}].name", b.name or f"body{i}", False) for i, b in enumerate(scene.bodies)]
    moving += [(f"{getattr(ob, 'origin', f'obstacles[{i}]')}.name", ob.name or f"obstacle{i}", True)
               for i, ob in enumerate(scene.obstacles) if ob.animated]  # kinematic bodies among them
    seen: dict[str, tuple[str, bool]] = {}
    for key, name, collider in moving:  # one USD prim /sph/bodies/<name> and one run.json entry each
        if name in seen and (collider or seen[name][1]):
            fail(key, f"{name!r} is also the name of {seen[name][0].rsplit('.', 1)[0]}; moving bodies and "
                 "animated obstacles need distinct names")  # two dynamic bodies: rigid.checks says so
        seen.setdefault(name, (key, collider))
    solver = registry.solver(scene.solver)
    boundary = registry.boundary(scene.boundary)
    refusal = solver.refuses_boundary(boundary)
    if refusal:
        fail("boundary", f"{scene.boundary!r} does not work with solver {scene.solver!r}: {refusal}")
    for name, cls in registry.methods_with_parameters().items():
        cls.validate(scene, fail)
    from ..methods.force import check_scene_forces

    check_scene_forces(scene, fail)
    if scene.bodies:
        from ..rigid.checks import check_bodies

        check_bodies(scene, fail)
    if scene.probes:
        from .probes import check_probes

        check_probes(scene, fail)
    if scene.whitewater is not None:
        w = scene.whitewater
        for lo, hi in (("trapped_air_min", "trapped_air_max"), ("wave_crest_min", "wave_crest_max"),
                       ("kinetic_energy_min", "kinetic_energy_max")):
            if not getattr(w, hi) > getattr(w, lo):
                fail(f"whitewater.{hi}", f"expected > whitewater.{lo} ({getattr(w, lo):g}), got {getattr(w, hi):g}")
        if w.lifetime_max < w.lifetime_min:
            fail("whitewater.lifetime_max", f"expected >= whitewater.lifetime_min ({w.lifetime_min:g}), "
                 f"got {w.lifetime_max:g}")
        if w.bubble_neighbors < w.spray_neighbors:
            fail("whitewater.bubble_neighbors", f"expected >= whitewater.spray_neighbors "
                 f"({w.spray_neighbors}), got {w.bubble_neighbors}")
    if scene.emitters or scene.sinks or scene.max_particles or (scene.container is not None and scene.container.open):
        from .emitters import check_emission

        check_emission(scene, fail)


def lattice_neighbor_counts(scene) -> tuple[int, int]:
    """(neighbours within the kernel support of a particle inside a rest lattice of spacing d,
    of a particle in the top layer of a flat free surface), self excluded."""
    offsets = lattice_offsets(scene.spacing, scene.support_radius)
    below = offsets[:, 2] <= 1e-9 * scene.spacing
    return len(offsets) - 1, int(np.count_nonzero(below)) - 1


def _obstacle_bounds(ob) -> tuple[np.ndarray, np.ndarray]:
    if ob.shape == "box":
        return np.asarray(ob.min, dtype=float), np.asarray(ob.max, dtype=float)
    if ob.shape == "sphere":  # an animated one: its path moves the corners of this box (conservative)
        from .sphere_obstacle import sphere_bounds

        return sphere_bounds(ob)
    lo, hi = load_triangle_mesh(ob.file).transformed(ob.scale, ob.translate).bounds
    return lo, hi
