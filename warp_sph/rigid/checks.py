"""Scene checks of solids that need their geometry, run by scene validation before any kernel.

``check_bodies``: ``[[bodies]]``' names, mass, thickness against the boundary inset, inside the container,
no overlap with obstacles or each other at t = 0, a solver and boundary method that couple, Newton
installed. ``check_obstacle_paths``: an animated obstacle (keyframes, animation, kinematic body) never runs
into a static obstacle or another animated one along its path.

Posed geometry (``spec.posed``): x_world = R(rotation) x_body + position, ``x_body`` relative to the
centre of mass. An animated obstacle's geometry is in its own frame, placed by its path (``scene.paths``):
x_world = R(t) x_local + T(t); a static obstacle's is in the world (R = 1, T = 0).
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


def obstacle_solid(ob, spacing: float):
    """(points about ``spacing`` [m] apart on the obstacle's surface, with its corners or vertices, and
    ``inside(x, tol)``: mask of points [m] deeper than ``tol`` inside it), both in the obstacle's own
    frame (the world for a static obstacle)."""
    if ob.shape == "box":
        lo, hi = np.asarray(ob.min, dtype=np.float64), np.asarray(ob.max, dtype=np.float64)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        points = np.concatenate([box_surface(lo, hi, spacing, inward=False)[0], corners])
        return points, lambda x, tol: np.all((x > lo + tol) & (x < hi - tol), axis=-1)
    if ob.shape == "sphere":
        from ..scene.sphere_obstacle import sphere_surface

        c, r = np.asarray(ob.center, dtype=np.float64), float(ob.radius)
        return sphere_surface(ob, spacing)[0], lambda x, tol: np.linalg.norm(x - c, axis=-1) < r - tol
    mesh = load_triangle_mesh(ob.file).transformed(ob.scale, ob.translate)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in mesh.bounds)

    def inside(x, tol):
        mask = np.all((x > lo + tol) & (x < hi - tol), axis=-1)  # the winding number only inside the box
        if mask.any():
            mask[mask] = points_inside(mesh, x[mask])
        return mask

    return np.concatenate([sample_surface(mesh, spacing)[0], mesh.vertices]), inside


def _pose(ob, t):
    """(R (..., 3, 3), T (..., 3)) of an obstacle at times ``t`` [s]: its path's, identity when static."""
    if ob.animated:
        return ob.path.pose(t)
    shape = np.shape(t)
    return np.broadcast_to(np.eye(3), shape + (3, 3)), np.zeros(shape + (3,))


def _path_times(scene, spacing: float, reach: dict[int, float]) -> np.ndarray:
    """Times [s] over [0, duration] at which the animated obstacles' poses are compared: every key, and
    steps in which none moves more than ``spacing`` [m] (50 to 2000 of them; ``reach``: obstacle index ->
    its farthest surface point from its local origin [m])."""
    duration = float(scene.duration)
    speed = max(scene.obstacles[i].path.max_speed(r, 0.0, duration) for i, r in reach.items())
    n = int(np.clip(np.ceil(speed * duration / spacing) + 1, 50, 2000))
    keys = np.concatenate([scene.obstacles[i].path.times for i in reach])
    return np.unique(np.concatenate([np.linspace(0.0, duration, n), keys[(keys >= 0.0) & (keys <= duration)]]))


def check_obstacle_paths(scene, fail) -> None:
    """``fail(keypath, message)`` when an animated obstacle, moved along its path over [0, duration], runs
    into a static obstacle or another animated obstacle: a surface point of either deeper than 0.1 d inside
    the other at one of the sampled times (``_path_times``), all in world coordinates. The fluid it runs
    through is what it is for; dynamic bodies are checked at t = 0 (``check_bodies``)."""
    moving = [i for i, ob in enumerate(scene.obstacles) if ob.animated]
    if not moving:
        return
    d = scene.spacing
    tol = 0.1 * d
    solids = [obstacle_solid(ob, d) for ob in scene.obstacles]
    t = _path_times(scene, d, {i: float(np.max(np.linalg.norm(solids[i][0], axis=1))) for i in moving})
    poses = [_pose(ob, t) for ob in scene.obstacles]

    def key(i):
        return getattr(scene.obstacles[i], "origin", f"obstacles[{i}]")

    for i in moving:
        for j in range(len(scene.obstacles)):
            if j == i or (j in moving and j < i):
                continue
            hit = None
            for a, b in ((i, j), (j, i)):  # a's surface points inside b, at every sampled time
                (Ra, Ta), (Rb, Tb) = poses[a], poses[b]
                points = solids[a][0]
                step = max(1, 200_000 // max(len(points), 1))  # times per chunk: bounded memory
                for k0 in range(0, len(t), step):
                    sl = slice(k0, k0 + step)
                    world = np.einsum("kij,nj->kni", Ra[sl], points) + Ta[sl, None, :]
                    inside = solids[b][1](np.einsum("kni,kij->knj", world - Tb[sl, None, :], Rb[sl]), tol)
                    if inside.any():
                        k, n = np.argwhere(inside)[0]
                        if hit is None or k0 + k < hit[0]:
                            hit = (k0 + k, world[k, n])
                        break
            if hit is not None:
                what = "animated" if j in moving else "static"
                fail(key(i), f"its path runs into {key(j)} ({what}) at t = {t[hit[0]]:.4g} s (a point of their "
                     f"surfaces at {np.round(hit[1], 6).tolist()} m lies inside the other); an animated obstacle "
                     "may pass through the fluid, not through another solid: change its path or move the obstacle")


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
            points, inside = obstacle_solid(ob, 0.5 * d)
            R, T = _pose(ob, 0.0)  # an animated obstacle where its path puts it at t = 0
            in_ob = inside((samples[i] - T) @ R, tol)
            if in_ob.any() or inside_body(gi, bi, points @ R.T + T, tol).any():
                name = getattr(ob, "origin", f"obstacles[{k}]")
                fail(f"bodies[{i}]", f"overlaps {name} at t = 0; move the body or the obstacle")
    solver = registry.solver(scene.solver)
    boundary = registry.boundary(scene.boundary)
    refusal = solver.refuses_bodies(boundary)
    if refusal:
        fail("bodies", f"solver {scene.solver!r} with boundary {scene.boundary!r} cannot move bodies: {refusal}")
    require_newton()
    return geometries
