"""Per-frame diagnostics reduced on the device: one small host read per frame."""
import warp as wp

# slots of the statistics array
STAT_MAX_SPEED = 0          # max |v| [m/s]
STAT_SUM_COMPRESSION = 1    # sum max(rho/rho0 - 1, 0) [-]
STAT_MAX_DENSITY_ERROR = 2  # max (rho/rho0 - 1) [-]
STAT_MIN_DENSITY_ERROR = 3  # min (rho/rho0 - 1) [-]
STAT_NON_FINITE = 4         # particles with a non-finite position, velocity or density
STAT_OUTSIDE = 5            # particles outside the container (grown by a tolerance)
STAT_KINETIC_ENERGY = 6     # sum 1/2 m |v|^2 [J]
STAT_POTENTIAL_ENERGY = 7   # sum -m g.x [J]
STAT_MAX_ACCELERATION = 8   # max |a| [m/s^2]
STAT_FIRST_BAD = 9          # smallest index of a non-finite particle (or -1 stays as count n)
STAT_COUNT = 10


@wp.kernel(enable_backward=False)
def reset_statistics(stats_out: wp.array(dtype=float)):
    stats_out[STAT_MAX_SPEED] = 0.0
    stats_out[STAT_SUM_COMPRESSION] = 0.0
    stats_out[STAT_MAX_DENSITY_ERROR] = -1.0e30
    stats_out[STAT_MIN_DENSITY_ERROR] = 1.0e30
    stats_out[STAT_NON_FINITE] = 0.0
    stats_out[STAT_OUTSIDE] = 0.0
    stats_out[STAT_KINETIC_ENERGY] = 0.0
    stats_out[STAT_POTENTIAL_ENERGY] = 0.0
    stats_out[STAT_MAX_ACCELERATION] = 0.0
    stats_out[STAT_FIRST_BAD] = 1.0e30


@wp.kernel(enable_backward=False)
def accumulate_statistics(
    # Model:
    particle_mass: float,
    rest_density: float,
    gravity: wp.vec3,
    container_lo: wp.vec3,
    container_hi: wp.vec3,
    check_container: int,
    # State in:
    particle_x: wp.array(dtype=wp.vec3),
    particle_v: wp.array(dtype=wp.vec3),
    particle_density: wp.array(dtype=float),
    particle_acceleration: wp.array(dtype=wp.vec3),
    # Out:
    stats_out: wp.array(dtype=float),
):
    i = wp.tid()
    x = particle_x[i]
    v = particle_v[i]
    rho = particle_density[i]
    a = particle_acceleration[i]
    s = wp.dot(x, x) + wp.dot(v, v) + rho + wp.dot(a, a)
    if not wp.isfinite(s):
        wp.atomic_add(stats_out, STAT_NON_FINITE, 1.0)
        wp.atomic_min(stats_out, STAT_FIRST_BAD, float(i))
        return
    speed = wp.length(v)
    err = rho / rest_density - 1.0
    wp.atomic_max(stats_out, STAT_MAX_SPEED, speed)
    wp.atomic_max(stats_out, STAT_MAX_ACCELERATION, wp.length(a))
    wp.atomic_add(stats_out, STAT_SUM_COMPRESSION, wp.max(err, 0.0))
    wp.atomic_max(stats_out, STAT_MAX_DENSITY_ERROR, err)
    wp.atomic_min(stats_out, STAT_MIN_DENSITY_ERROR, err)
    wp.atomic_add(stats_out, STAT_KINETIC_ENERGY, 0.5 * particle_mass * wp.dot(v, v))
    wp.atomic_add(stats_out, STAT_POTENTIAL_ENERGY, -particle_mass * wp.dot(gravity, x))
    if check_container != 0:
        if x[0] < container_lo[0] or x[1] < container_lo[1] or x[2] < container_lo[2] or x[0] > container_hi[0] or x[1] > container_hi[1] or x[2] > container_hi[2]:
            wp.atomic_add(stats_out, STAT_OUTSIDE, 1.0)
