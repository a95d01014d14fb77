"""Moving rigid bodies as Akinci 2012 boundary particles (two-way coupling); launched by
``warp_sph.rigid.coupling``.

Poses come from the rigid-body engine (Newton) in its own layout: ``body_q[k]`` is the pose of body
k's origin (p [m], q xyzw), ``body_qd[k]`` = (v of the centre of mass [m/s], omega [rad/s]), both in
the world frame, and ``body_com[k]`` is the centre of mass in the body frame [m]. Positions are in
the simulation's local frame (the Model's origin subtracted), the same frame Newton steps in.

Forces on bodies are reduced in a fixed order (chunks of consecutive particles summed in index
order, then each body's chunks in order), so the wrench is bitwise the same for any thread count.
"""
import warp as wp


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
    boundary_particle_force: wp.array(dtype=wp.vec3),
    # Out:
    chunk_wrench_out: wp.array(dtype=wp.spatial_vector),
):
    """Per chunk c of one body's moving particles i in [chunk_start[c], chunk_end[c]) (boundary
    index body_particle_start + i): F_c = sum_i F_b [N], tau_c = sum_i (x_b - x_com) x F_b [N m],
    summed in index order."""
    c = wp.tid()
    k = chunk_body[c]
    x_com = wp.transform_point(body_q[k], body_com[k])
    force = wp.vec3(0.0)
    torque = wp.vec3(0.0)
    i = chunk_start[c]
    end = chunk_end[c]
    while i < end:
        b = body_particle_start + i
        f = boundary_particle_force[b]
        force += f
        torque += wp.cross(boundary_x[b] - x_com, f)
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
