"""Rigid bodies of a scene (``[[bodies]]``): their parameters, checks and geometry in the body frame.

A body's frame has its origin at the centre of mass and the axes of the shape as given (a box's
edges, a mesh file's axes); ``position`` places the centre of mass and ``rotation`` turns the body
about it. Geometry here is host-side NumPy in float64, positions in metres.

``Body`` is the typed ``[[bodies]]`` entry (generated from its rows in ``scene/parameters.py``, listed
again here as ``BODY_PARAMETERS``); ``check_body`` is the cross-key check that table rows cannot
express (exactly one of density and mass; the mesh closed).

Posed at t = 0 (``posed``, ``inside_body``): x_world = R(rotation) x_body + position; ``body_inset`` is
how far below the surface its boundary particles sit (wall gap - r).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import SceneError
from ..scene.parameters import BODY_SHAPES, Param, core_parameters
from ..scene.types import Body
from ..scene.mesh_volume import closed_surface_problem, volume_and_centroid
from ..scene.meshes import TriangleMesh, load_triangle_mesh, points_inside

#: Parameter-table rows of ``[[bodies]]`` (key paths ``bodies[].key``) and the ``rigid`` table, declared
#: with the core rows in ``scene/parameters.py``.
BODY_PARAMETERS: tuple[Param, ...] = tuple(p for p in core_parameters()
                                           if p.path == "bodies" or p.path.startswith("bodies[]."))
RIGID_PARAMETERS: tuple[Param, ...] = tuple(p for p in core_parameters()
                                            if p.path == "rigid" or p.path.startswith("rigid."))


@dataclass
class BodyGeometry:
    """A body's shape in its own frame (origin at the centre of mass) [m].

    vertices (V, 3) and triangles (T, 3): a closed surface wound counter-clockwise seen from
    outside (the USD mesh, the mesh Newton collides as a convex hull, the surface that is sampled);
    half_extents (box) or radius (sphere) for Newton's primitive shapes; volume [m^3]; mass [kg].
    """

    shape: str
    vertices: np.ndarray
    triangles: np.ndarray
    volume: float
    mass: float
    half_extents: np.ndarray | None = None
    radius: float | None = None
    extra: dict = field(default_factory=dict)

    @property
    def density(self) -> float:
        """Mean density [kg/m^3]."""
        return self.mass / self.volume

    @property
    def mesh(self) -> TriangleMesh:
        return TriangleMesh(self.vertices, self.triangles)


def body_name(body: Body, index: int) -> str:
    """The body's name, or body<index> when none is given."""
    return body.name or f"body{index}"


def check_body(body: Body, keypath: str, source: str = "<dict>") -> None:
    """Checks across keys (SceneError naming ``source: keypath.key``): exactly one of density and
    mass; a box size > 0 on every axis; a mesh that loads, is closed and encloses a volume."""
    def fail(key, msg):
        raise SceneError(f"{source}: {keypath}.{key}: {msg}")

    if (body.density is None) == (body.mass is None):
        which = "both" if body.density is not None else "neither"
        fail("density", f"expected exactly one of density [kg/m^3] and mass [kg], got {which}")
    if body.shape == "box" and not all(s > 0.0 for s in body.size):
        fail("size", f"expected 3 edge lengths > 0, got {list(body.size)}")
    if body.shape == "mesh":
        mesh = load_triangle_mesh(body.file)
        volume = volume_and_centroid(mesh.vertices, mesh.triangles)[0]
        problem = closed_surface_problem(mesh)
        if problem:
            fail("file", f"mesh {body.file!r} is not closed and consistently oriented: {problem} (every edge must join "
                 "exactly two triangles, traversed in opposite directions)")
        if not abs(volume) > 0.0:
            fail("file", f"mesh {body.file!r} encloses no volume")


def rotation_quaternion(rotation_deg) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of Euler angles [deg] about X, then Y, then Z (extrinsic; Blender's
    XYZ mode): R = Rz Ry Rx."""
    hx, hy, hz = (math.radians(float(a)) * 0.5 for a in rotation_deg)
    qx = np.array([math.sin(hx), 0.0, 0.0, math.cos(hx)])
    qy = np.array([0.0, math.sin(hy), 0.0, math.cos(hy)])
    qz = np.array([0.0, 0.0, math.sin(hz), math.cos(hz)])
    return quat_multiply(qz, quat_multiply(qy, qx))


def quat_multiply(a, b) -> np.ndarray:
    """Hamilton product a b of quaternions (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrix (3, 3) of a unit quaternion (x, y, z, w)."""
    x, y, z, w = (float(c) for c in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def box_mesh(half_extents) -> tuple[np.ndarray, np.ndarray]:
    """Closed box mesh centred at the origin: 8 vertices, 12 triangles, outward (CCW seen from outside)."""
    h = np.asarray(half_extents, dtype=np.float64)
    verts = np.array([[(h if (v >> a) & 1 else -h)[a] for a in range(3)] for v in range(8)])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int64)
    return verts, tris


def sphere_mesh(radius: float, subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Icosphere of ``radius`` [m] centred at the origin (20 * 4^subdivisions triangles), outward."""
    t = (1.0 + math.sqrt(5.0)) / 2.0
    verts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
             (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    tris = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
            (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5),
            (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.asarray(v, dtype=np.float64) / np.linalg.norm(v) for v in verts]
    for _ in range(subdivisions):
        cache: dict[tuple[int, int], int] = {}

        def middle(i, j):
            key = (min(i, j), max(i, j))
            if key not in cache:
                m = verts[i] + verts[j]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        new = []
        for a, b, c in tris:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        tris = new
    return np.asarray(verts) * float(radius), np.asarray(tris, dtype=np.int64)


def body_geometry(body: Body) -> BodyGeometry:
    """The body's closed surface, volume and mass in its frame (origin at the centre of mass).

    Box and sphere: exact volume (8 hx hy hz, 4/3 pi R^3); the sphere's USD mesh is an icosphere.
    Mesh: the file scaled, wound outward (flipped if its signed volume is negative) and moved so
    that the centroid of the enclosed volume (the centre of mass at uniform density) is the origin.
    Mass = density * volume, or the given mass.
    """
    extra = {}
    half = radius = None
    if body.shape == "box":
        half = 0.5 * np.asarray(body.size, dtype=np.float64)
        verts, tris = box_mesh(half)
        volume = float(8.0 * half.prod())
    elif body.shape == "sphere":
        radius = float(body.radius)
        verts, tris = sphere_mesh(radius)
        volume = 4.0 / 3.0 * math.pi * radius**3
    elif body.shape == "mesh":
        mesh = load_triangle_mesh(body.file)
        verts = mesh.vertices * float(body.scale if body.scale is not None else 1.0)
        tris = np.asarray(mesh.triangles, dtype=np.int64)
        volume, centroid = volume_and_centroid(verts, tris)
        if volume < 0.0:
            tris = tris[:, ::-1].copy()
            volume = -volume
        if not volume > 0.0:
            raise SceneError(f"body mesh {body.file!r} encloses no volume")
        verts = verts - centroid
        extra["file_centroid"] = centroid
    else:
        raise SceneError(f"body shape {body.shape!r}: expected one of {', '.join(BODY_SHAPES)}")
    mass = float(body.mass) if body.mass is not None else float(body.density) * volume
    return BodyGeometry(shape=body.shape, vertices=verts, triangles=tris, volume=volume, mass=mass,
                        half_extents=half, radius=radius, extra=extra)


def body_inset(scene) -> float:
    """Inset [m] of a body's boundary particles below its surface: wall gap g - r (``rigid.sampling``)."""
    return max(scene.wall_gap - scene.particle_radius, 0.0)


def posed(geometry: BodyGeometry, body) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), centre of mass [m] (3,)) of a body at t = 0."""
    return quat_to_matrix(rotation_quaternion(body.rotation)), np.asarray(body.position, dtype=np.float64)


def inside_body(geometry: BodyGeometry, body, points: np.ndarray, tolerance: float) -> np.ndarray:
    """Mask of world ``points`` [m] strictly inside the body at t = 0 (more than ``tolerance`` [m] deep)."""
    R, c = posed(geometry, body)
    local = (np.asarray(points, dtype=np.float64).reshape(-1, 3) - c) @ R  # R^T (x - c)
    if geometry.shape == "box":
        return np.all(np.abs(local) < geometry.half_extents - tolerance, axis=1)
    if geometry.shape == "sphere":
        return np.linalg.norm(local, axis=1) < geometry.radius - tolerance
    inside = points_inside(geometry.mesh, local)
    if tolerance > 0.0 and inside.any():  # keep points deeper than the tolerance: none of 6 offsets leaves
        for axis in range(3):
            for sign in (-1.0, 1.0):
                shifted = local.copy()
                shifted[:, axis] += sign * tolerance
                inside &= points_inside(geometry.mesh, shifted)
    return inside
