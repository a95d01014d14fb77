"""Preview ray tracing: one ray per pixel, shaded with Blinn-Phong (report section 3, eq. 2-6).

Particles are exact spheres. The report draws them as billboard impostors: a fragment at billboard
offset v (|v| <= 1) lies on the sphere at u = (v.x, v.y, sqrt(1 - |v|^2)) (eq. 2-3), with normal
s_n = V^-1 u and position s_p = p + r V^-1 u (eq. 4). Intersecting the pixel's ray with the sphere
gives the same point and normal without the orthographic approximation of the billboard.

Spheres are found through a uniform grid over their bounding boxes (each sphere is listed in every
cell its box overlaps), marched cell by cell along the ray (3D-DDA, Amanatides & Woo 1987). The first
cell whose nearest hit lies inside that cell ends the march, so the hit is exact and a ray into a
dense block of fluid stops after a few cells. The surface mesh is traced with ``wp.mesh_query_ray``.

Host launchers: ``warp_sph/preview.py``.
"""
import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.struct
class RenderCamera:
    """Pinhole camera: position [m], orthonormal basis, vertical field of view, image size [px]."""

    position: wp.vec3
    forward: wp.vec3
    right: wp.vec3
    up: wp.vec3
    tan_half_fov: float  # tan(vertical fov / 2)
    width: int
    height: int


@wp.struct
class RenderLight:
    """Blinn-Phong light (eq. 5-6): directional (``direction`` points to the light) or point."""

    direction: wp.vec3
    position: wp.vec3  # [m], used when is_point != 0
    is_point: int
    ambient: float
    diffuse: float
    specular: float
    shininess: float


@wp.struct
class RenderScenery:
    """Background, and the container drawn faintly: its 12 edges and a translucent gridded floor."""

    background: wp.vec3
    has_container: int
    container_lo: wp.vec3  # [m]
    container_hi: wp.vec3  # [m]
    floor_spacing: float  # floor grid line spacing [m]
    floor_color: wp.vec3
    floor_alpha: float
    edge_color: wp.vec3
    edge_alpha: float  # in front of the fluid; hidden edges use a third of it


@wp.func
def camera_ray(camera: RenderCamera, px: int, py: int):
    """Unit direction of the ray through the centre of pixel (px, py), row 0 at the top."""
    aspect = float(camera.width) / float(camera.height)
    sx = (2.0 * (float(px) + 0.5) / float(camera.width) - 1.0) * camera.tan_half_fov * aspect
    sy = (1.0 - 2.0 * (float(py) + 0.5) / float(camera.height)) * camera.tan_half_fov
    return wp.normalize(camera.forward + sx * camera.right + sy * camera.up)


@wp.func
def ray_sphere(origin: wp.vec3, direction: wp.vec3, center: wp.vec3, radius: float):
    """Distance along a unit ray to the near intersection with a sphere, or -1 when missed."""
    oc = origin - center
    b = wp.dot(oc, direction)
    c = wp.dot(oc, oc) - radius * radius
    disc = b * b - c
    t = float(-1.0)
    if disc >= 0.0:
        t = -b - wp.sqrt(disc)
    return t


@wp.func
def blinn_phong(
    light: RenderLight,
    base_color: wp.vec3,
    surface_position: wp.vec3,
    surface_normal: wp.vec3,
    camera_position: wp.vec3,
):
    """C = C_ambient + Gamma_diff C_diff + Gamma_spec C_spec (report eq. 5-6), white highlights."""
    light_dir = light.direction
    if light.is_point != 0:
        light_dir = wp.normalize(light.position - surface_position)
    view_dir = wp.normalize(camera_position - surface_position)
    n_dot_l = wp.dot(surface_normal, light_dir)
    gamma_diff = wp.max(n_dot_l, 0.0)
    gamma_spec = float(0.0)
    if n_dot_l > 0.0:
        half = wp.normalize(light_dir + view_dir)
        gamma_spec = wp.pow(wp.max(wp.dot(surface_normal, half), 0.0), light.shininess)
    return (light.ambient + light.diffuse * gamma_diff) * base_color + light.specular * gamma_spec * wp.vec3(1.0)


@wp.func
def ray_segment_distance(origin: wp.vec3, direction: wp.vec3, a: wp.vec3, b: wp.vec3):
    """Closest approach of a unit ray and segment ab: vec2(distance [m], ray parameter t [m])."""
    e = b - a
    w0 = origin - a
    ee = wp.dot(e, e)
    de = wp.dot(direction, e)
    denom = ee - de * de
    s = float(0.0)
    if denom > 1.0e-12 * ee:
        s = (wp.dot(e, w0) - de * wp.dot(direction, w0)) / denom
    s = wp.clamp(s, 0.0, 1.0)
    q = a + s * e
    t = wp.dot(q - origin, direction)
    return wp.vec2(wp.length(origin + t * direction - q), t)


@wp.func
def edge_corner(lo: wp.vec3, hi: wp.vec3, axis: int, k: int, s: float):
    """Point at fraction s along box edge number k (0..3) parallel to ``axis``."""
    p = wp.vec3(lo)
    a1 = (axis + 1) % 3
    a2 = (axis + 2) % 3
    if k % 2 == 1:
        p[a1] = hi[a1]
    if k >= 2:
        p[a2] = hi[a2]
    p[axis] = lo[axis] + s * (hi[axis] - lo[axis])
    return p


@wp.func
def composite(
    camera: RenderCamera,
    scenery: RenderScenery,
    origin: wp.vec3,
    direction: wp.vec3,
    hit: int,
    hit_t: float,
    hit_color: wp.vec3,
):
    """Colour of a pixel: the hit (or background), then the translucent floor and container edges."""
    color = scenery.background
    depth = float(1.0e30)
    if hit != 0:
        color = hit_color
        depth = hit_t
    if scenery.has_container != 0:
        lo = scenery.container_lo
        hi = scenery.container_hi
        pixel_angle = 2.0 * camera.tan_half_fov / float(camera.height)
        # floor z = lo.z inside the container's footprint, with grid lines
        if wp.abs(direction[2]) > 1.0e-8:
            t_floor = (lo[2] - origin[2]) / direction[2]
            if t_floor > 0.0 and t_floor < depth:
                p = origin + t_floor * direction
                if p[0] >= lo[0] and p[0] <= hi[0] and p[1] >= lo[1] and p[1] <= hi[1]:
                    alpha = scenery.floor_alpha
                    footprint = pixel_angle * t_floor / wp.max(wp.abs(direction[2]), 0.2)
                    gx = (p[0] - lo[0]) / scenery.floor_spacing
                    gy = (p[1] - lo[1]) / scenery.floor_spacing
                    dx = wp.abs(gx - wp.round(gx)) * scenery.floor_spacing
                    dy = wp.abs(gy - wp.round(gy)) * scenery.floor_spacing
                    if wp.min(dx, dy) < 0.6 * footprint:
                        alpha = wp.min(2.0 * alpha, 1.0)
                    color = (1.0 - alpha) * color + alpha * scenery.floor_color
        # the 12 edges, about one pixel wide; those behind the hit drawn fainter
        for axis in range(3):
            for k in range(4):
                a = edge_corner(lo, hi, axis, k, 0.0)
                b = edge_corner(lo, hi, axis, k, 1.0)
                dt = ray_segment_distance(origin, direction, a, b)
                if dt[1] > 0.0:
                    half_width = 0.7 * pixel_angle * dt[1]
                    if dt[0] < half_width:
                        alpha = scenery.edge_alpha * (1.0 - 0.5 * dt[0] / half_width)
                        if dt[1] > depth:
                            alpha = alpha / 3.0
                        color = (1.0 - alpha) * color + alpha * scenery.edge_color
    return wp.vec3(wp.clamp(color[0], 0.0, 1.0), wp.clamp(color[1], 0.0, 1.0), wp.clamp(color[2], 0.0, 1.0))


@wp.func
def cell_of(p: wp.vec3, grid_lo: wp.vec3, cell_size: float, grid_dims: wp.vec3i):
    """Grid cell holding p, clamped to the grid."""
    c = wp.vec3i(0, 0, 0)
    for d in range(3):
        c[d] = wp.clamp(int(wp.floor((p[d] - grid_lo[d]) / cell_size)), 0, grid_dims[d] - 1)
    return c


@wp.func
def cell_index(c: wp.vec3i, grid_dims: wp.vec3i):
    return (c[2] * grid_dims[1] + c[1]) * grid_dims[0] + c[0]


@wp.kernel
def count_sphere_cells(
    particle_x: wp.array(dtype=wp.vec3),
    particle_radius: float,
    grid_lo: wp.vec3,
    cell_size: float,
    grid_dims: wp.vec3i,
    # Out:
    cell_count_out: wp.array(dtype=wp.int32),
):
    """Count, per cell, the spheres whose bounding box overlaps it (cell_size >= 2 r: <= 8 cells each)."""
    i = wp.tid()
    x = particle_x[i]
    c0 = cell_of(x - wp.vec3(particle_radius), grid_lo, cell_size, grid_dims)
    c1 = cell_of(x + wp.vec3(particle_radius), grid_lo, cell_size, grid_dims)
    for k in range(c0[2], wp.min(c1[2], c0[2] + 1) + 1):
        for j in range(c0[1], wp.min(c1[1], c0[1] + 1) + 1):
            for ii in range(c0[0], wp.min(c1[0], c0[0] + 1) + 1):
                wp.atomic_add(cell_count_out, cell_index(wp.vec3i(ii, j, k), grid_dims), 1)


@wp.kernel
def fill_sphere_cells(
    particle_x: wp.array(dtype=wp.vec3),
    particle_radius: float,
    grid_lo: wp.vec3,
    cell_size: float,
    grid_dims: wp.vec3i,
    cell_start: wp.array(dtype=wp.int32),
    # Out:
    cell_fill_out: wp.array(dtype=wp.int32),
    cell_particles_out: wp.array(dtype=wp.int32),
):
    """List each sphere in the cells its bounding box overlaps (slots from the exclusive scan)."""
    i = wp.tid()
    x = particle_x[i]
    c0 = cell_of(x - wp.vec3(particle_radius), grid_lo, cell_size, grid_dims)
    c1 = cell_of(x + wp.vec3(particle_radius), grid_lo, cell_size, grid_dims)
    for k in range(c0[2], wp.min(c1[2], c0[2] + 1) + 1):
        for j in range(c0[1], wp.min(c1[1], c0[1] + 1) + 1):
            for ii in range(c0[0], wp.min(c1[0], c0[0] + 1) + 1):
                cell = cell_index(wp.vec3i(ii, j, k), grid_dims)
                slot = cell_start[cell] + wp.atomic_add(cell_fill_out, cell, 1)
                cell_particles_out[slot] = i


@wp.kernel
def trace_particles(
    camera: RenderCamera,
    light: RenderLight,
    scenery: RenderScenery,
    particle_x: wp.array(dtype=wp.vec3),
    particle_color: wp.array(dtype=wp.vec3),
    particle_radius: float,
    grid_lo: wp.vec3,
    cell_size: float,
    grid_dims: wp.vec3i,
    cell_start: wp.array(dtype=wp.int32),
    cell_count: wp.array(dtype=wp.int32),
    cell_particles: wp.array(dtype=wp.int32),
    solid_mesh: wp.uint64,
    has_solid: int,
    solid_face_color: wp.array(dtype=wp.vec3),
    # Out:
    image_out: wp.array2d(dtype=wp.vec3),
):
    """One ray per pixel against the spheres, marched through the grid cells (3D-DDA), and against
    the solid mesh (obstacles and rigid bodies: flat-shaded, two-sided, one colour per triangle) when
    there is one."""
    py, px = wp.tid()
    origin = camera.position
    direction = camera_ray(camera, px, py)

    # ray against the grid's box (slab test)
    grid_hi = grid_lo + cell_size * wp.vec3(float(grid_dims[0]), float(grid_dims[1]), float(grid_dims[2]))
    t_enter = float(0.0)
    t_leave = float(1.0e30)
    for d in range(3):
        if wp.abs(direction[d]) < 1.0e-12:
            if origin[d] < grid_lo[d] or origin[d] > grid_hi[d]:
                t_leave = -1.0
        else:
            ta = (grid_lo[d] - origin[d]) / direction[d]
            tb = (grid_hi[d] - origin[d]) / direction[d]
            t_enter = wp.max(t_enter, wp.min(ta, tb))
            t_leave = wp.min(t_leave, wp.max(ta, tb))

    best_t = float(1.0e30)
    best_i = int(-1)
    if t_enter <= t_leave:
        cell = cell_of(origin + t_enter * direction, grid_lo, cell_size, grid_dims)
        step = wp.vec3i(0, 0, 0)
        t_next = wp.vec3(1.0e30)
        t_delta = wp.vec3(1.0e30)
        for d in range(3):
            if direction[d] > 1.0e-12:
                step[d] = 1
                t_next[d] = (grid_lo[d] + float(cell[d] + 1) * cell_size - origin[d]) / direction[d]
                t_delta[d] = cell_size / direction[d]
            elif direction[d] < -1.0e-12:
                step[d] = -1
                t_next[d] = (grid_lo[d] + float(cell[d]) * cell_size - origin[d]) / direction[d]
                t_delta[d] = -cell_size / direction[d]
        while True:
            c = cell_index(cell, grid_dims)
            start = cell_start[c]
            for s in range(start, start + cell_count[c]):
                j = cell_particles[s]
                t = ray_sphere(origin, direction, particle_x[j], particle_radius)
                if t > 0.0 and t < best_t:
                    best_t = t
                    best_i = j
            # leave the cell along the axis whose boundary comes first
            axis = int(0)
            if t_next[1] < t_next[axis]:
                axis = 1
            if t_next[2] < t_next[axis]:
                axis = 2
            t_exit = t_next[axis]
            if best_t <= t_exit or t_exit > t_leave:
                break
            cell[axis] = cell[axis] + step[axis]
            if cell[axis] < 0 or cell[axis] >= grid_dims[axis]:
                break
            t_next[axis] = t_next[axis] + t_delta[axis]

    hit = int(0)
    color = wp.vec3(0.0)
    if best_i >= 0:
        hit = 1
        p = origin + best_t * direction
        normal = (p - particle_x[best_i]) / particle_radius  # s_n of eq. 4
        color = blinn_phong(light, particle_color[best_i], p, normal, origin)
    if has_solid != 0:
        q = wp.mesh_query_ray(solid_mesh, origin, direction, best_t)
        if q.result and q.t < best_t:
            hit = 1
            best_t = q.t
            n = wp.normalize(q.normal)
            if wp.dot(n, direction) > 0.0:
                n = -n
            color = blinn_phong(light, solid_face_color[q.face], origin + best_t * direction, n, origin)
    image_out[py, px] = composite(camera, scenery, origin, direction, hit, best_t, color)


@wp.kernel
def trace_mesh(
    camera: RenderCamera,
    light: RenderLight,
    scenery: RenderScenery,
    mesh: wp.uint64,
    mesh_indices: wp.array(dtype=wp.int32),
    vertex_normal: wp.array(dtype=wp.vec3),
    has_mesh: int,
    face_color: wp.array(dtype=wp.vec3),
    # Out:
    image_out: wp.array2d(dtype=wp.vec3),
):
    """One ray per pixel against the mesh (fluid surface and obstacles, a colour per triangle);
    smooth vertex normals, shaded two-sided."""
    py, px = wp.tid()
    origin = camera.position
    direction = camera_ray(camera, px, py)
    hit = int(0)
    hit_t = float(0.0)
    color = wp.vec3(0.0)
    if has_mesh != 0:
        q = wp.mesh_query_ray(mesh, origin, direction, 1.0e30)
        if q.result:
            hit = 1
            hit_t = q.t
            f = q.face
            # barycentric weights: u for the face's first vertex, v for the second (wp.mesh_eval_position)
            n = (
                q.u * vertex_normal[mesh_indices[3 * f + 0]]
                + q.v * vertex_normal[mesh_indices[3 * f + 1]]
                + (1.0 - q.u - q.v) * vertex_normal[mesh_indices[3 * f + 2]]
            )
            if wp.length(n) < 1.0e-12:
                n = q.normal
            n = wp.normalize(n)
            if wp.dot(n, direction) > 0.0:  # two-sided: shade the side facing the camera
                n = -n
            p = origin + hit_t * direction
            color = blinn_phong(light, face_color[f], p, n, origin)
    image_out[py, px] = composite(camera, scenery, origin, direction, hit, hit_t, color)
