"""Initial particles of a scene: fluid on a lattice, walls and obstacles as boundary particles.

Rules (d = 2 r is the rest spacing, g d = ``scene.wall_gap``: boundary_gap * d, or by default the
gap at which the first fluid layer over one Akinci wall layer is at rest density, about 1.1 d):
- Fluid lattice: a block's particle centres are min + s r + k s d (s = ``spacing_scale``), so an
  aligned box holds exactly volume / (s d)^3 particles; a sphere keeps the lattice points of its
  bounding box whose centres are inside it, a closed mesh those inside it (generalised winding
  number where a ray would graze an edge, ray parity per lattice column elsewhere:
  ``meshes.lattice_inside``), about volume / (s d)^3 of them.
- fcc start (``fluid[].lattice = "fcc"``, ``_fcc_points``): the block's points on a cubic grid of spacing
  s d / sqrt 2 with even index sums (face-centred cubic, nearest neighbours s d), first plane at the gap, the
  leftover split as for clipped sides; the container's faces then are (100) nets of that grid in the hollows of
  the nearest fluid plane (``_fcc_walls``), the wall gap calibrated on the fcc lattice (``scene.wall_gap``).
- Walls: the six faces of the container carry one layer of boundary particles on a square
  lattice (spacing L/round(L/d), i.e. d when the size is a multiple of d) on the wall planes.
- Gap at walls: a block touching (or closer than the gap to) a wall is first clipped to the
  container shrunk by g d - s r, and its lattice starts from the clipped side, so its first
  layer sits exactly g d from the wall plane (a block clipped by two opposite walls is centred
  between them). Without this the first layer of a box given flush with the wall would sit
  r = d/2 from the wall particles and start far over-dense; physics notes section 7 measured
  +6 % density at a gap of 1.0 d and rest density at 1.1 d with one Akinci layer (cubic kernel),
  which ``smoothing.wall_gap`` reproduces per kernel and h.
- Obstacles: boxes are sampled on their faces like the container; spheres on a Fibonacci lattice
  (``sphere_obstacle``, on |x - c| = R); meshes with ``meshes.sample_surface`` (spacing about d). Obstacle particles closer than d/2 to an
  earlier boundary particle (e.g. a mesh resting on the floor) are dropped.
- Fluid removal: fluid inside an obstacle (box test, |x - c| <= R, mesh winding number) and fluid whose
  centre is closer than g d to any boundary particle are removed; a fluid particle closer than
  d/2 to a particle of an earlier fluid block is removed (overlapping blocks).
- Moving bodies (``[[bodies]]``, ``warp_sph.rigid.sampling``): their particles sit g d - r below
  their surface; fluid inside a body or closer than g d to its particles is removed (so the fluid
  starts r from the true surface, where it rests).
- Jitter (``fluid[].jitter``, ``fluid[].seed``): last, each coordinate of a block's kept particles moves by a
  seeded uniform draw in [-jitter d, +jitter d] (``jitter_blocks``): a start perturbed below the resolution.

All geometry is NumPy in float64; positions stay float64 until the model subtracts its local
origin (float32 would round them by 1e-3 m at 10^4 m from the origin); velocities are float32.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.errors import SceneError
from .emitters import open_faces
from .mesh_volume import lattice_inside
from .meshes import box_surface, load_triangle_mesh, points_inside, sample_surface
from .sphere_obstacle import sphere_inside, sphere_surface
from .types import FluidBlock, Scene

#: Points this close (relative to d) are one point (overlapping fluid blocks, shared boundary).
DUPLICATE_DISTANCE = 0.5
#: Relative tolerance on lattice counts and gap checks (float rounding of aligned sizes).
_EPS = 1e-6


@dataclass
class SampledScene:
    """Initial particles of a scene.

    fluid_x: fluid positions [m], shape (fluid_count, 3), float64.
    fluid_v: fluid velocities [m/s], shape (fluid_count, 3), float32.
    fluid_block: index of the [[fluid]] block each particle came from, shape (fluid_count,), int32.
    boundary_x: boundary particle positions [m], shape (boundary_count, 3), float64.
    boundary_normals: unit normals pointing into the fluid side (container walls: inward,
        obstacles: outward; edges and corners: the normalised sum), shape (boundary_count, 3), float32.
    boundary_object: -1 for container walls, i for ``scene.obstacles[i]``, shape (boundary_count,), int32.
    body_geometries, body_samples: per ``[[bodies]]`` entry, its ``rigid.BodyGeometry`` and
        ``rigid.BodySamples`` (moving boundary particles in the body frame, with their volumes);
    body_x: those particles' world positions at t = 0, body after body [m], (K, 3) float64.
    colliders, collider_x: the animated obstacles (``rigid.colliders``) and their particles at t = 0 [m].
        The static boundary arrays above hold the walls and obstacles only.
    particle_radius: r [m]; spacing: d = 2 r [m].
    container_min, container_max: container corners [m], or None without a container.
    """

    fluid_x: np.ndarray
    fluid_v: np.ndarray
    fluid_block: np.ndarray
    boundary_x: np.ndarray
    boundary_normals: np.ndarray
    boundary_object: np.ndarray
    particle_radius: float
    spacing: float
    container_min: tuple[float, float, float] | None
    container_max: tuple[float, float, float] | None
    body_geometries: list = field(default_factory=list)
    body_samples: list = field(default_factory=list)
    body_x: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    #: animated obstacles (``rigid.colliders.Collider``) and their particles at t = 0 [m], after the bodies'
    colliders: list = field(default_factory=list)
    collider_x: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def fluid_count(self) -> int:
        """Number of fluid particles."""
        return int(self.fluid_x.shape[0])

    @property
    def boundary_count(self) -> int:
        """Number of boundary particles."""
        return int(self.boundary_x.shape[0])

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) corners [m] of all particles, fluid and boundary."""
        pts = np.concatenate([self.fluid_x, self.boundary_x]) if self.boundary_count else self.fluid_x
        return pts.min(axis=0), pts.max(axis=0)


class PointGrid:
    """Uniform hash grid over fixed points for nearest-distance queries within a cutoff (NumPy)."""

    _BITS = 21
    _OFFSET = 1 << 20

    def __init__(self, points: np.ndarray, cell: float):
        self.points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        self.cell = float(cell)
        keys = self._keys(np.floor(self.points / self.cell).astype(np.int64))
        self.order = np.argsort(keys, kind="stable")
        self.sorted_keys = keys[self.order]

    @classmethod
    def _keys(cls, c: np.ndarray) -> np.ndarray:
        c = c + cls._OFFSET
        return (c[:, 0] << (2 * cls._BITS)) | (c[:, 1] << cls._BITS) | c[:, 2]

    def nearest_distance(self, query: np.ndarray, cutoff: float | None = None) -> np.ndarray:
        """Distance [m] from each query point to its nearest grid point, or inf beyond ``cutoff``
        (default and at most the cell size)."""
        query = np.asarray(query, dtype=np.float64).reshape(-1, 3)
        cutoff = self.cell if cutoff is None else min(float(cutoff), self.cell)
        best = np.full(len(query), np.inf)
        if len(query) == 0 or len(self.points) == 0:
            return best
        qc = np.floor(query / self.cell).astype(np.int64)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    keys = self._keys(qc + np.array([dx, dy, dz]))
                    lo = np.searchsorted(self.sorted_keys, keys, side="left")
                    hi = np.searchsorted(self.sorted_keys, keys, side="right")
                    count = hi - lo
                    for k in range(int(count.max(initial=0))):
                        sel = np.nonzero(count > k)[0]
                        p = self.points[self.order[lo[sel] + k]]
                        dist = np.linalg.norm(p - query[sel], axis=1)
                        best[sel] = np.minimum(best[sel], dist)
        best[best > cutoff] = np.inf
        return best


def lattice_block(block: FluidBlock, spacing: float, region=None) -> np.ndarray:
    """Lattice points [m] of one fluid block, clipped to ``region`` = (lo, hi) or None.

    Centres at lo + s d/2 + k s d (s = block.spacing_scale) from the corner lo of the clipped
    bounding box, k = 0 .. floor(extent / (s d)) - 1 per axis; where a side was clipped and the
    extent is not a multiple of s d, the lattice is pushed against the clipped side (centred when
    both were). A sphere keeps the points whose centre lies inside it, a mesh those inside it
    (``meshes.lattice_inside``).
    """
    step = block.spacing_scale * spacing
    lo, hi = (np.asarray(x, dtype=np.float64) for x in block.bounds())
    clip_lo = clip_hi = np.zeros(3, dtype=bool)
    if region is not None:
        clip_lo, clip_hi = region[0] > lo, region[1] < hi
        lo = np.maximum(lo, region[0])
        hi = np.minimum(hi, region[1])
    n = np.floor((hi - lo) / step + _EPS).astype(np.int64)
    if np.any(n <= 0):
        return np.zeros((0, 3))
    # what the lattice leaves over goes to the unclipped side (both clipped: split evenly), so a
    # block between two walls has the same gap at both
    leftover = np.maximum(hi - lo - n * step, 0.0)
    shift = np.where(clip_lo & clip_hi, 0.5 * leftover, np.where(clip_hi & ~clip_lo, leftover, 0.0))
    lo = lo + shift
    axes = [lo[i] + 0.5 * step + step * np.arange(n[i]) for i in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    if block.lattice == "fcc":
        touch = (region[0] >= lo - shift - _EPS * step, region[1] <= hi + _EPS * step) if region is not None else (
            clip_lo, clip_hi)  # fcc never fits a box exactly: a side given flush with a wall counts as clipped
        pts = _fcc_points(lo - shift, hi, clip_lo | touch[0], clip_hi | touch[1], step)
    if block.shape == "sphere":
        r = np.linalg.norm(pts - np.asarray(block.center), axis=1)
        pts = pts[r <= block.radius * (1.0 + _EPS)]
    elif block.shape == "mesh" and block.lattice == "fcc":
        pts = pts[points_inside(block.mesh(), pts)]
    elif block.shape == "mesh":
        pts = pts[lattice_inside(block.mesh(), *axes).reshape(-1)]
    return pts


def _fcc_points(lo: np.ndarray, hi: np.ndarray, clip_lo: np.ndarray, clip_hi: np.ndarray, step: float) -> np.ndarray:
    """FCC start in the box [lo, hi] [m] (``fluid[].lattice = "fcc"``, nearest neighbours ``step`` apart): the points
    of the cubic grid of spacing step / sqrt 2 from lo + step / 2 (a wall's gap, as the cubic lattice's first layer)
    to hi - step / 2 whose indices sum to an even number. Every face of the box is then a (100) plane of the FCC
    lattice: a square net of spacing step (turned 45 degrees), as many particles per area as a wall's square layer,
    and each particle sits in the hollow of four of the plane below. The leftover goes where the cubic lattice's does."""
    c = step / np.sqrt(2.0)
    n = np.floor((hi - lo - step) / c + _EPS).astype(np.int64) + 1
    if np.any(hi - lo < step * (1.0 - _EPS)):
        return np.zeros((0, 3))
    leftover = np.maximum(hi - lo - step - (n - 1) * c, 0.0)
    lo = lo + np.where(clip_lo & clip_hi, 0.5 * leftover, np.where(clip_hi & ~clip_lo, leftover, 0.0))
    k = np.stack(np.meshgrid(*(np.arange(m) for m in n), indexing="ij"), axis=-1).reshape(-1, 3)
    k = k[k.sum(axis=1) % 2 == 0]
    return lo + 0.5 * step + c * k


def _fcc_walls(scene, d: float, gap: float, p: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The container's faces for an fcc start (``fluid[].lattice = "fcc"``): each closed face a (100) net of the
    first block's fcc lattice, the points of its grid (spacing d / sqrt 2) on the face plane whose indices, with the
    nearest fluid plane's index plus one, sum to an even number (the hollows of that plane), so wall and fluid
    layers register as the fluid's own planes do; same particles per area as the square wall layer. Where two closed
    faces meet, both nets hold the same lattice row, between the fluid's first planes: it lies on the edge, pushed
    out of the fluid by the gap along both faces' normals as each net is along its own (as ``box_surface`` puts its
    edge points), once. (Kept in one net at its own plane, 0.34 d from the other's, it left the fcc tank's corner
    particle 5.9 % over rest density and its edges 2.3 %; on the edge: 0.7 %, the flat wall's second layer -1.1 %.)
    Falls back to the square faces ``p``, ``n`` when the first block samples nothing."""
    block = scene.fluid[0]
    c = scene.container
    lo, hi = np.asarray(c.min, dtype=np.float64), np.asarray(c.max, dtype=np.float64)
    shrink = gap - 0.5 * block.spacing_scale * d
    fluid = lattice_block(block, d, (lo + shrink, hi - shrink))
    if not len(fluid):
        return p, n
    step = block.spacing_scale * d / np.sqrt(2.0)
    o = fluid[0]
    first, last = np.round((fluid.min(axis=0) - o) / step), np.round((fluid.max(axis=0) - o) / step)
    opened = open_faces(scene)
    pts, nrm = [], []
    for axis in range(3):
        a, b = [x for x in range(3) if x != axis]
        ja, jb = (np.arange(np.ceil((lo[i] - o[i]) / step - _EPS), np.floor((hi[i] - o[i]) / step + _EPS) + 1)
                  for i in (a, b))
        ga, gb = (g.ravel() for g in np.meshgrid(ja, jb, indexing="ij"))
        for side, (plane, beyond) in enumerate(((lo[axis], first[axis] - 1), (hi[axis], last[axis] + 1))):
            if (axis, side) in opened:
                continue
            keep = (ga + gb + beyond) % 2 == 0
            q = np.zeros((int(keep.sum()), 3))
            q[:, axis] = plane
            q[:, a] = o[a] + step * ga[keep]
            q[:, b] = o[b] + step * gb[keep]
            for k in (a, b):  # an edge row: on the edge, where its copy in the other face's net is (docstring)
                for edge, end in ((lo[k], 0), (hi[k], 1)):
                    near = np.abs(q[:, k] - edge) < DUPLICATE_DISTANCE * d
                    q[near & ((k, end) not in opened), k] = edge
            q = q[_append_unique(pts, q, DUPLICATE_DISTANCE * d)]
            normal = np.zeros(3)
            normal[axis] = 1.0 if side == 0 else -1.0
            pts.append(q), nrm.append(np.broadcast_to(normal, q.shape))
    return np.concatenate(pts), np.ascontiguousarray(np.concatenate(nrm))


def _append_unique(existing: list[np.ndarray], new: np.ndarray, min_distance: float) -> np.ndarray:
    """Mask of ``new`` points at least ``min_distance`` away from every point in ``existing``."""
    if not existing or len(new) == 0:
        return np.ones(len(new), dtype=bool)
    grid = PointGrid(np.concatenate(existing), min_distance)
    return grid.nearest_distance(new, min_distance) >= min_distance


def jitter_blocks(blocks, x: np.ndarray, block: np.ndarray, d: float) -> np.ndarray:
    """``x`` [m] with each block's ``jitter`` applied: every coordinate of its particles moved by a uniform draw in
    [-jitter d, +jitter d] from ``numpy.random.default_rng(seed)`` (after the gap tests, so a seed changes no
    particle count); blocks without jitter keep their positions bit for bit."""
    x = np.array(x, dtype=np.float64)
    for i, b in enumerate(blocks):
        amp = float(getattr(b, "jitter", 0.0) or 0.0)
        mask = block == i
        if amp > 0.0 and mask.any():
            rng = np.random.default_rng(int(b.seed))
            x[mask] += rng.uniform(-amp * d, amp * d, size=(int(mask.sum()), 3))
    return x


def sample_scene(scene: Scene) -> SampledScene:
    """Sample the fluid blocks, container walls and obstacles of ``scene`` (rules in the module doc).

    Raises SceneError when no fluid particle is left.
    """
    r = scene.particle_radius
    d = scene.spacing
    gap = scene.wall_gap

    # boundary: container walls, then obstacles
    bx, bn, bo = [], [], []
    c = scene.container
    if c is not None:
        p, n = box_surface(c.min, c.max, d, inward=True, open_faces=open_faces(scene))  # (open: an outflow)
        if scene.fluid and getattr(scene.fluid[0], "lattice", "cubic") == "fcc":
            p, n = _fcc_walls(scene, d, gap, p, n)
        bx.append(p), bn.append(n), bo.append(np.full(len(p), -1, dtype=np.int32))
    inside_tests = []
    for i, ob in enumerate(scene.obstacles):
        if ob.animated:  # moving boundary particles (``rigid.colliders``), sampled below
            continue
        if ob.shape == "box":
            p, n = box_surface(ob.min, ob.max, d, inward=False)
            lo, hi = np.asarray(ob.min), np.asarray(ob.max)
            inside_tests.append(lambda x, lo=lo, hi=hi: np.all((x >= lo) & (x <= hi), axis=1))
        elif ob.shape == "sphere":
            p, n = sphere_surface(ob, d)
            inside_tests.append(lambda x, ob=ob: sphere_inside(ob, x))
        else:
            mesh = load_triangle_mesh(ob.file).transformed(ob.scale, ob.translate)
            p, n = sample_surface(mesh, d)
            inside_tests.append(lambda x, mesh=mesh: points_inside(mesh, x))
        keep = _append_unique(bx, p, DUPLICATE_DISTANCE * d)
        bx.append(p[keep]), bn.append(n[keep]), bo.append(np.full(int(keep.sum()), i, dtype=np.int32))
    boundary_x = np.concatenate(bx) if bx else np.zeros((0, 3))
    boundary_n = np.concatenate(bn) if bn else np.zeros((0, 3))
    boundary_o = np.concatenate(bo) if bo else np.zeros(0, dtype=np.int32)

    # one lattice for every fluid block
    lattices = sorted({str(b.lattice) for b in scene.fluid})
    if len(lattices) > 1 or (lattices == ["fcc"] and scene.emitters):
        raise SceneError(f"{scene.source}: fluid[].lattice: {' and '.join(lattices)} in one scene; expected one "
                         "lattice for every fluid block (the particle mass is calibrated on it), and cubic with "
                         "emitters")
    # fluid blocks
    fx, fv, fb = [], [], []
    for i, block in enumerate(scene.fluid):
        region = None
        if c is not None:
            shrink = gap - 0.5 * block.spacing_scale * d
            region = (np.asarray(c.min) + shrink, np.asarray(c.max) - shrink)
        p = lattice_block(block, d, region)
        if block.shape == "mesh" and len(p) == 0:
            raise SceneError(f"{scene.source}: fluid[{i}].file: mesh {block.file!r} holds no lattice point inside "
                             f"the container at spacing {block.spacing_scale * d:g} m; scale it up, move it inside "
                             "or lower particle_radius")
        p = p[_append_unique(fx, p, DUPLICATE_DISTANCE * d)]
        fx.append(p)
        fv.append(np.broadcast_to(np.asarray(block.velocity, dtype=np.float64), p.shape))
        fb.append(np.full(len(p), i, dtype=np.int32))
    fluid_x = np.concatenate(fx) if fx else np.zeros((0, 3))  # none: a scene that starts empty (emitters)
    fluid_v = np.concatenate(fv) if fv else np.zeros((0, 3))
    fluid_b = np.concatenate(fb) if fb else np.zeros(0, dtype=np.int32)

    keep = np.ones(len(fluid_x), dtype=bool)
    for test in inside_tests:
        keep &= ~test(fluid_x)
    if len(boundary_x):
        grid = PointGrid(boundary_x, gap)
        keep &= grid.nearest_distance(fluid_x, gap) >= gap * (1.0 - _EPS)
    body_geometries, body_samples, body_x = [], [], np.zeros((0, 3))
    if scene.bodies:  # moving bodies: fluid inside them, or within the gap of their (inset) particles, goes
        from ..rigid.spec import inside_body
        from ..rigid.sampling import sample_scene_bodies

        body_geometries, body_samples, body_x = sample_scene_bodies(scene)
        for geo, body in zip(body_geometries, scene.bodies):
            keep &= ~inside_body(geo, body, fluid_x, 0.0)
        keep &= PointGrid(body_x, gap).nearest_distance(fluid_x, gap) >= gap * (1.0 - _EPS)
    colliders, collider_x = [], np.zeros((0, 3))
    if any(ob.animated for ob in scene.obstacles):  # animated obstacles: fluid inside them or within the gap at t = 0
        from ..rigid.colliders import sample_colliders

        colliders, collider_x = sample_colliders(scene)
        for col in colliders:
            keep &= ~col.inside(fluid_x, 0.0)
        keep &= PointGrid(collider_x, gap).nearest_distance(fluid_x, gap) >= gap * (1.0 - _EPS)
    fluid_x, fluid_v, fluid_b = fluid_x[keep], fluid_v[keep], fluid_b[keep]
    fluid_x = jitter_blocks(scene.fluid, fluid_x, fluid_b, d)
    if len(fluid_x) == 0 and scene.fluid:  # (a scene of emitters alone starts empty)
        raise SceneError(
            f"{scene.source}: fluid: no fluid particle left after sampling at spacing d = {d:g} m "
            f"(blocks smaller than d, inside obstacles, or within boundary_gap of the walls)"
        )
    return SampledScene(
        fluid_x=np.ascontiguousarray(fluid_x, dtype=np.float64),
        fluid_v=np.ascontiguousarray(fluid_v, dtype=np.float32),
        fluid_block=fluid_b,
        boundary_x=np.ascontiguousarray(boundary_x, dtype=np.float64),
        boundary_normals=np.ascontiguousarray(boundary_n, dtype=np.float32),
        boundary_object=boundary_o.astype(np.int32),
        particle_radius=r,
        spacing=d,
        container_min=tuple(c.min) if c is not None else None,
        container_max=tuple(c.max) if c is not None else None,
        body_geometries=body_geometries,
        body_samples=body_samples,
        body_x=np.ascontiguousarray(body_x, dtype=np.float64),
        colliders=colliders,
        collider_x=np.ascontiguousarray(collider_x, dtype=np.float64),
    )
