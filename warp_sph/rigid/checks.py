"""Scene checks of ``[[bodies]]`` that need the bodies' geometry, run by scene validation before any
kernel: names, mass, thickness against the boundary inset, inside the container, no overlap with
obstacles or each other at t = 0, a solver and boundary method that couple, Newton installed.

Posed geometry (``spec.posed``): x_world = R(rotation) x_body + position, ``x_body`` relative to the
centre of mass.
"""
from __future__ import annotations

import re

import numpy as np

from ..scene.meshes import box_surface, load_triangle_mesh, points_inside, sample_surface
from .sampling import surface_samples
from .spec import BodyGeometry, body_geometry, body_inset, body_name, check_body, inside_body, posed

_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
#: lightest body the explicit (weak) fluid coupling moves stably, as its mean density over the fluid's rest
#: density: lighter bodies gain energy at every bounce (added-mass instability). Measured (docs/extremes.md):
#: a 0.2 m box dropped 0.1 m onto a pool at r = 0.05 m rises above its release point at 0.1 (PBF, WCSPH;
#: bench extremes' pool) and below 0.03 (DFSPH, PBF) or 0.07 (WCSPH) in a larger pool; at 0.2 it stays below
#: it in every solver for 1 s. Finer particles are more stable (r = 0.025 m: DFSPH held 0.001, WCSPH 0.01).
MIN_DENSITY_RATIO = 0.2


def surface_points(geometry: BodyGeometry, body, spacing: float) -> np.ndarray:
    """Points about ``spacing`` [m] apart on the body's true surface at t = 0, world frame [m]."""
    x, _ = surface_samples(geometry, spacing, 0.0)
    R, c = posed(geometry, body)
    verts = geometry.vertices
    return np.concatenate([x, verts]) @ R.T + c


def check_bodies(scene, fail) -> list[BodyGeometry]:
    """Refuse (``fail(keypath, message)``) bodies a run cannot start with; return their geometries.

    Per body: a valid, unique name; exactly one of density and mass; a mean density at least
    ``MIN_DENSITY_RATIO`` times the fluid's (the added-mass limit of the explicit coupling); larger than
    twice the boundary inset in every direction; inside the container. Between bodies and obstacles: no overlap at t = 0
    (surface samples d/2 apart of each one tested inside the other, 0.1 d tolerance). The solver and
    boundary method must couple (``Solver.refuses_bodies``); Newton must be installed.
    """
    from ..methods import registry
    from .world import require_newton

    if not scene.bodies:
        return []
    d = scene.spacing
    tol = 0.1 * d
    inset = body_inset(scene)
    names: dict[str, int] = {}
    geometries = []
    for i, body in enumerate(scene.bodies):
        kp = f"bodies[{i}]"
        name = body_name(body, i)
        if not _IDENTIFIER.match(name):
            fail(f"{kp}.name", f"expected letters, digits and '_' not starting with a digit (a USD prim name), "
                 f"got {name!r}")
        if name in names:
            fail(f"{kp}.name", f"{name!r} is also the name of bodies[{names[name]}]; body names must be unique")
        names[name] = i
        check_body(body, kp, scene.source)
        geo = body_geometry(body)
        rho0 = float(scene.material.rest_density)
        if not geo.density >= MIN_DENSITY_RATIO * rho0:
            given = (f"density {geo.density:.4g} kg/m^3" if body.density is not None else
                     f"mass {geo.mass:.4g} kg (a mean density of {geo.density:.4g} kg/m^3)")
            fail(f"{kp}.{'density' if body.density is not None else 'mass'}",
                 f"expected a mean density >= {MIN_DENSITY_RATIO * rho0:.4g} kg/m^3 ({MIN_DENSITY_RATIO:g}x the fluid's "
                 f"material.rest_density), got {given}: the fluid-body coupling is explicit and a lighter body gains "
                 "energy at every bounce (added-mass instability, measured in docs/extremes.md)")
        small = 2.0 * inset
        if geo.shape == "box" and not np.all(2.0 * geo.half_extents > small):
            fail(f"{kp}.size", f"expected every edge > {small:.4g} m (twice the boundary inset wall gap - r "
                 f"= {inset:.4g} m), got {list(body.size)}; make the box larger or the particles smaller")
        if geo.shape == "sphere" and not geo.radius > inset:
            fail(f"{kp}.radius", f"expected > {inset:.4g} m (the boundary inset wall gap - r), got {geo.radius:g}; "
                 "make the sphere larger or the particles smaller")
        if geo.shape == "mesh":
            lo, hi = geo.vertices.min(axis=0), geo.vertices.max(axis=0)
            if not np.all(hi - lo > small):
                fail(f"{kp}.file", f"the mesh is {np.round(hi - lo, 6).tolist()} m across; expected more than "
                     f"{small:.4g} m (twice the boundary inset) in every direction")
        c = scene.container
        if c is not None:
            R, p = posed(geo, body)
            verts = geo.vertices @ R.T + p
            lo, hi = verts.min(axis=0), verts.max(axis=0)
            ctol = 1e-9 * max(1.0, float(np.max(np.abs(verts))))
            if np.any(lo < np.asarray(c.min) - ctol) or np.any(hi > np.asarray(c.max) + ctol):
                fail(kp, f"spans {np.round(lo, 6).tolist()}..{np.round(hi, 6).tolist()} at its initial pose, not inside "
                     f"the container {list(c.min)}..{list(c.max)}")
        geometries.append(geo)
    # overlaps at t = 0
    samples = [surface_points(g, b, 0.5 * d) for g, b in zip(geometries, scene.bodies)]
    for i, (gi, bi) in enumerate(zip(geometries, scene.bodies)):
        for j in range(i):
            gj, bj = geometries[j], scene.bodies[j]
            if inside_body(gj, bj, samples[i], tol).any() or inside_body(gi, bi, samples[j], tol).any():
                fail(f"bodies[{i}]", f"overlaps bodies[{j}] at t = 0; move one of them")
        for k, ob in enumerate(scene.obstacles):
            if ob.shape == "box":
                lo, hi = np.asarray(ob.min, dtype=np.float64), np.asarray(ob.max, dtype=np.float64)
                in_ob = np.all((samples[i] > lo + tol) & (samples[i] < hi - tol), axis=1)
                ob_points, _ = box_surface(lo, hi, 0.5 * d, inward=False)
            elif ob.shape == "sphere":
                from ..scene.sphere_obstacle import sphere_surface

                c, r = np.asarray(ob.center, dtype=np.float64), float(ob.radius)
                in_ob = np.linalg.norm(samples[i] - c, axis=1) < r - tol
                ob_points = sphere_surface(ob, 0.5 * d)[0]
            else:
                mesh = load_triangle_mesh(ob.file).transformed(ob.scale, ob.translate)
                in_ob = points_inside(mesh, samples[i])
                ob_points = np.concatenate([sample_surface(mesh, 0.5 * d)[0], mesh.vertices])
            if in_ob.any() or inside_body(gi, bi, ob_points, tol).any():
                fail(f"bodies[{i}]", f"overlaps obstacles[{k}] at t = 0; move the body or the obstacle")
    solver = registry.solver(scene.solver)
    boundary = registry.boundary(scene.boundary)
    refusal = solver.refuses_bodies(boundary)
    if refusal:
        fail("bodies", f"solver {scene.solver!r} with boundary {scene.boundary!r} cannot move bodies: {refusal}")
    require_newton()
    return geometries
