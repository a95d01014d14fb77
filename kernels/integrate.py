"""Time integration: semi-implicit Euler and velocity increments."""
import warp as wp


@wp.kernel(enable_backward=False)
def integrate_symplectic_euler(
    tid_offset: int,
    # State in:
    particle_acceleration: wp.array(dtype=wp.vec3),
    dt: float,
    # State in/out:
    particle_v: wp.array(dtype=wp.vec3),
    particle_x: wp.array(dtype=wp.vec3),
):
    """Semi-implicit Euler (report eq. 11): v += dt a; x += dt v [m, m/s]."""
    i = wp.tid() + tid_offset
    v = particle_v[i] + dt * particle_acceleration[i]
    particle_v[i] = v
    particle_x[i] = particle_x[i] + dt * v


@wp.kernel(enable_backward=False)
def add_velocity_correction(
    tid_offset: int,
    # In:
    velocity_correction: wp.array(dtype=wp.vec3),
    # State in/out:
    particle_v: wp.array(dtype=wp.vec3),
):
    """v_i += dv_i [m/s]."""
    i = wp.tid() + tid_offset
    particle_v[i] = particle_v[i] + velocity_correction[i]


@wp.kernel(enable_backward=False)
def kick(
    tid_offset: int,
    # State in:
    particle_acceleration: wp.array(dtype=wp.vec3),
    dt: float,
    # State in/out:
    particle_v: wp.array(dtype=wp.vec3),
):
    """The velocity half of ``integrate_symplectic_euler``: v += dt a [m/s]."""
    i = wp.tid() + tid_offset
    particle_v[i] = particle_v[i] + dt * particle_acceleration[i]


@wp.kernel(enable_backward=False)
def drift(
    tid_offset: int,
    dt: float,
    # State in:
    particle_v: wp.array(dtype=wp.vec3),
    # State in/out:
    particle_x: wp.array(dtype=wp.vec3),
):
    """The position half of ``integrate_symplectic_euler``: x += dt v [m]."""
    i = wp.tid() + tid_offset
    particle_x[i] = particle_x[i] + dt * particle_v[i]
