"""Moving rigid bodies as Akinci 2012 boundary particles (two-way coupling); launched by
``warp_sph.rigid.coupling``.

Poses come from the rigid-body engine (Newton) in its own layout: ``body_q[k]`` is the pose of body
k's origin (p [m], q xyzw), ``body_qd[k]`` = (v of the centre of mass [m/s], omega [rad/s]), both in
the world frame, and ``body_com[k]`` is the centre of mass in the body frame [m]. Positions are in
the simulation's local frame (the Model's origin subtracted), the same frame Newton steps in.

Forces on bodies are reduced in a fixed order (chunks of consecutive particles summed in index
order, then each body's chunks in order), so the wrench is bitwise the same for any thread count.

The fluid's force on each moving particle (``body_particle_force_kernel``) mirrors the boundary
method's terms pair by pair (equal and opposite), so momentum passes between fluid and bodies exactly.
"""
import functools

import warp as wp

from .neighbors import cell_rows, row_points
from .smoothing import SMOOTHING_FUNCTIONS


@wp.kernel(enable_backward=False)
def place_body_particles(
    tid_offset: int,
    # Model:
    body_particle_start: int,
    particle_body: wp.array(dtype=int),
    particle_local_x: wp.array(dtype=wp.vec3),
    body_com: wp.array(dtype=wp.vec3),
    # State in:
    body_q: wp.array(dtype=wp.transform),
    body_qd: wp.array(dtype=wp.spatial_vector),
    # Out:
    boundary_x_out: wp.array(dtype=wp.vec3),
    boundary_v_out: wp.array(dtype=wp.vec3),
):
    """Moving boundary particle i (stored at boundary index body_particle_start + i):
    x = R x_local + p [m], v = v_com + omega x (x - x_com) [m/s], x_com = R com + p."""
    i = wp.tid() + tid_offset
    k = particle_body[i]
    pose = body_q[k]
    x = wp.transform_point(pose, particle_local_x[i])
    x_com = wp.transform_point(pose, body_com[k])
    twist = body_qd[k]
    boundary_x_out[body_particle_start + i] = x
    boundary_v_out[body_particle_start + i] = wp.spatial_top(twist) + wp.cross(wp.spatial_bottom(twist), x - x_com)


@wp.kernel(enable_backward=False)
def body_wrench_chunks(
    # Model:
    body_particle_start: int,
    chunk_start: wp.array(dtype=int),
    chunk_end: wp.array(dtype=int),
    chunk_body: wp.array(dtype=int),
    body_com: wp.array(dtype=wp.vec3),
    # State in:
    body_q: wp.array(dtype=wp.transform),
    boundary_x: wp.array(dtype=wp.vec3),
    body_particle_force: wp.array(dtype=wp.vec3),
    # Out:
    chunk_wrench_out: wp.array(dtype=wp.spatial_vector),
):
    """Per chunk c of one body's moving particles i in [chunk_start[c], chunk_end[c]) (force
    body_particle_force[i], position boundary_x[body_particle_start + i]): F_c = sum_i F_i [N],
    tau_c = sum_i (x_i - x_com) x F_i [N m], summed in index order."""
    c = wp.tid()
    k = chunk_body[c]
    x_com = wp.transform_point(body_q[k], body_com[k])
    force = wp.vec3(0.0)
    torque = wp.vec3(0.0)
    i = chunk_start[c]
    end = chunk_end[c]
    while i < end:
        f = body_particle_force[i]
        force += f
        torque += wp.cross(boundary_x[body_particle_start + i] - x_com, f)
        i += 1
    chunk_wrench_out[c] = wp.spatial_vector(force, torque)


@wp.kernel(enable_backward=False)
def sum_body_wrench(
    # Model:
    body_chunk_start: wp.array(dtype=int),
    body_chunk_end: wp.array(dtype=int),
    # In:
    chunk_wrench: wp.array(dtype=wp.spatial_vector),
    # Out:
    body_f_out: wp.array(dtype=wp.spatial_vector),
):
    """Per body k: (F, tau) = sum of its chunks' wrenches in chunk order [N, N m]; world frame, torque
    about the centre of mass (Newton's ``State.body_f`` layout)."""
    k = wp.tid()
    total = wp.spatial_vector()
    c = body_chunk_start[k]
    end = body_chunk_end[k]
    while c < end:
        total += chunk_wrench[c]
        c += 1
    body_f_out[k] = total


@wp.kernel(enable_backward=False)
def pair_contact_properties(
    # Model:
    contact_frequency: float,
    shape_body: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=float),
    # State in (Newton's contact buffer):
    contact_count: wp.array(dtype=int),
    contact_shape0: wp.array(dtype=int),
    contact_shape1: wp.array(dtype=int),
    # Out:
    contact_stiffness_out: wp.array(dtype=float),
    contact_damping_out: wp.array(dtype=float),
):
    """Per contact point between shapes a and b: k = mu w^2 [N/m], c = mu w [N s/m] with the reduced mass
    mu = 1 / (1/m_a + 1/m_b) [kg] (a static shape adds 0), so every pair vibrates at w and is damped at
    ratio 0.5 whatever the two masses (Newton's own rule averages the shapes' ke, kd)."""
    c = wp.tid()
    if c >= contact_count[0]:
        return
    inv = float(0.0)
    s = contact_shape0[c]
    if s >= 0:
        k = shape_body[s]
        if k >= 0:
            inv += body_inv_mass[k]
    s = contact_shape1[c]
    if s >= 0:
        k = shape_body[s]
        if k >= 0:
            inv += body_inv_mass[k]
    reduced = float(0.0)
    if inv > 0.0:
        reduced = 1.0 / inv
    contact_stiffness_out[c] = reduced * contact_frequency * contact_frequency
    contact_damping_out[c] = reduced * contact_frequency


@functools.cache
def body_particle_force_kernel(smoothing: str, boundary_terms):
    """Force of the fluid on each moving boundary particle b [N], one thread per b, no atomics:

        F_b = -sum_i m [pressure(params, grad_i W_ib, V_b, term_i) + force(params, b, x_ib, v_i - v_b, grad_i W_ib, V_b, rho_i)]

    over the fluid particles i with |x_i - x_b| < H_s: exactly the negative of the boundary terms the
    fluid kernels add to m a_i for the pair (i, b) (``kernels/boundary.py``; the pressure term is
    skipped when the boundary method has none, and so is the force term). term_i is the solver's
    ``boundary_pressure_term`` (``warp_sph.methods.solver``). The fluid is found in the cell grid the
    neighbour lists sorted it into (``CellGrid``), searched within ``search_radius`` (the lists'
    radius, which covers the drift since the sort; the project's one cell walk, ``cell_rows`` /
    ``row_points``) and filtered at the current positions."""
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]
    with_pressure = boundary_terms.pressure is not None
    with_force = boundary_terms.force is not None
    BoundaryParams = boundary_terms.Params
    pressure_term = boundary_terms.pressure
    force_term = boundary_terms.force

    @wp.kernel(enable_backward=False, module="unique")
    def gather_body_particle_force(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        boundary_params: BoundaryParams,
        body_particle_start: int,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_v: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # Fluid cell grid (``CellGrid``):
        grid_lo: wp.vec3,
        inv_cell_size: float,
        grid_dims: wp.vec3i,
        cell_start: wp.array(dtype=wp.int32),
        cell_point: wp.array(dtype=wp.int32),
        search_radius: float,
        # State in:
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        boundary_pressure_term: wp.array(dtype=float),
        # Out:
        body_particle_force_out: wp.array(dtype=wp.vec3),
    ):
        k = wp.tid() + tid_offset
        b = body_particle_start + k
        xb = boundary_x[b]
        vb = boundary_v[b]
        vol = boundary_volume[b]
        h = smoothing_length
        support2 = support_radius * support_radius
        q = (xb - grid_lo) * inv_cell_size
        qr = search_radius * inv_cell_size
        rows = cell_rows(q, qr, grid_dims)
        f = wp.vec3(0.0)
        for z in range(rows[2], rows[3] + 1):
            for y in range(rows[0], rows[1] + 1):
                span = row_points(q, qr, y, z, grid_dims, cell_start)
                s = span[0]
                s_end = span[1]
                while s < s_end:
                    i = cell_point[s]
                    x_ib = particle_x[i] - xb
                    if wp.dot(x_ib, x_ib) < support2:
                        grad = wp.static(gradient)(x_ib, h)
                        a = wp.vec3(0.0)
                        if wp.static(with_pressure):
                            a = wp.static(pressure_term)(boundary_params, grad, vol, boundary_pressure_term[i])
                        if wp.static(with_force):
                            a += wp.static(force_term)(boundary_params, b, x_ib, particle_v[i] - vb, grad, vol,
                                                       particle_density[i])
                        f -= particle_mass * a
                    s += 1
        body_particle_force_out[k] = f

    return gather_body_particle_force
