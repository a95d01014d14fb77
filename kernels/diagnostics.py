"""Per-frame diagnostics and the watchdog's checks, reduced on the device: one small host read per frame."""
import warp as wp

# slots of the statistics array (float)
STAT_MAX_SPEED = 0          # max |v| [m/s]
STAT_SUM_COMPRESSION = 1    # sum max(rho/rho0 - 1, 0) [-]
STAT_MAX_DENSITY_ERROR = 2  # max (rho/rho0 - 1) [-]
STAT_MIN_DENSITY_ERROR = 3  # min (rho/rho0 - 1) [-]
STAT_KINETIC_ENERGY = 4     # sum 1/2 m |v|^2 [J]
STAT_POTENTIAL_ENERGY = 5   # sum -m g.x [J]
STAT_MAX_ACCELERATION = 6   # max |a| [m/s^2]
STAT_COUNT = 7

# slots of the watch array (int): counts of particles breaking a watchdog rule and the smallest
# index of one of them (INDEX_NONE when none); exact for any particle count, unlike float slots.
WATCH_NON_FINITE = 0
WATCH_FIRST_NON_FINITE = 1
WATCH_OUTSIDE = 2
WATCH_FIRST_OUTSIDE = 3
WATCH_FAST = 4
WATCH_FIRST_FAST = 5
WATCH_DENSE = 6
WATCH_FIRST_DENSE = 7
WATCH_COUNT = 8
INDEX_NONE = 2147483647


@wp.kernel(enable_backward=False)
def reset_statistics(stats_out: wp.array(dtype=float), watch_out: wp.array(dtype=int)):
    stats_out[STAT_MAX_SPEED] = 0.0
    stats_out[STAT_SUM_COMPRESSION] = 0.0
    stats_out[STAT_MAX_DENSITY_ERROR] = -1.0e30
    stats_out[STAT_MIN_DENSITY_ERROR] = 1.0e30
    stats_out[STAT_KINETIC_ENERGY] = 0.0
    stats_out[STAT_POTENTIAL_ENERGY] = 0.0
    stats_out[STAT_MAX_ACCELERATION] = 0.0
    for k in range(WATCH_COUNT // 2):
        watch_out[2 * k] = 0
        watch_out[2 * k + 1] = INDEX_NONE


@wp.kernel(enable_backward=False)
def accumulate_statistics(
    # Model:
    particle_mass: float,
    rest_density: float,
    gravity: wp.vec3,
    container_lo: wp.vec3,
    container_hi: wp.vec3,
    check_container: int,
    open_lo: wp.vec3,
    open_hi: wp.vec3,
    top_axis: int,
    top_sign: float,
    top_level: float,
    speed_limit: float,
    density_limit: float,
    # State in:
    particle_x: wp.array(dtype=wp.vec3),
    particle_v: wp.array(dtype=wp.vec3),
    particle_density: wp.array(dtype=float),
    particle_acceleration: wp.array(dtype=wp.vec3),
    # Out:
    stats_out: wp.array(dtype=float),
    watch_out: wp.array(dtype=int),
):
    """Frame statistics plus the watchdog rules: non-finite values, a particle outside the container
    box [m] (unless it is past an open face's plane: x[a] < open_lo[a] or x[a] > open_hi[a] for some axis a,
    leaving or in flight through that face, +-1e30 on the closed sides; or, with an open top (top_axis >= 0,
    top_sign +1 for the face at max), beyond top_level on that axis: over the rim, or spilled down a side
    wall's outside less than a frame's fall below it; never past the floor's plane), |v| > speed_limit [m/s],
    rho/rho0 - 1 > density_limit [-]."""
    i = wp.tid()
    x = particle_x[i]
    v = particle_v[i]
    rho = particle_density[i]
    a = particle_acceleration[i]
    s = wp.dot(x, x) + wp.dot(v, v) + rho + wp.dot(a, a)
    if not wp.isfinite(s):
        wp.atomic_add(watch_out, WATCH_NON_FINITE, 1)
        wp.atomic_min(watch_out, WATCH_FIRST_NON_FINITE, i)
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
        outside = x[0] < container_lo[0] or x[1] < container_lo[1] or x[2] < container_lo[2] or x[0] > container_hi[0] or x[1] > container_hi[1] or x[2] > container_hi[2]
        through_open = x[0] < open_lo[0] or x[1] < open_lo[1] or x[2] < open_lo[2] or x[0] > open_hi[0] or x[1] > open_hi[1] or x[2] > open_hi[2]
        over_rim = False
        if top_axis >= 0:  # (never through the floor under the top, however far below the rim the level lies)
            through_floor = x[top_axis] < container_lo[top_axis]
            if top_sign < 0.0:
                through_floor = x[top_axis] > container_hi[top_axis]
            over_rim = top_sign * (x[top_axis] - top_level) > 0.0 and not through_floor
        if outside and not through_open and not over_rim:
            wp.atomic_add(watch_out, WATCH_OUTSIDE, 1)
            wp.atomic_min(watch_out, WATCH_FIRST_OUTSIDE, i)
    if speed > speed_limit:
        wp.atomic_add(watch_out, WATCH_FAST, 1)
        wp.atomic_min(watch_out, WATCH_FIRST_FAST, i)
    if err > density_limit:
        wp.atomic_add(watch_out, WATCH_DENSE, 1)
        wp.atomic_min(watch_out, WATCH_FIRST_DENSE, i)


@wp.kernel(enable_backward=False)
def reset_count(count_out: wp.array(dtype=int)):
    count_out[0] = 0
    count_out[1] = INDEX_NONE


@wp.kernel(enable_backward=False)
def count_non_finite_float(
    # In:
    values: wp.array(dtype=float),
    # Out:
    count_out: wp.array(dtype=int),
):
    """count_out[0] += number of non-finite values; count_out[1] = smallest such index."""
    i = wp.tid()
    if not wp.isfinite(values[i]):
        wp.atomic_add(count_out, 0, 1)
        wp.atomic_min(count_out, 1, i)


@wp.kernel(enable_backward=False)
def count_non_finite_vec3(
    # In:
    values: wp.array(dtype=wp.vec3),
    # Out:
    count_out: wp.array(dtype=int),
):
    """count_out[0] += number of non-finite vectors; count_out[1] = smallest such index."""
    i = wp.tid()
    v = values[i]
    if not (wp.isfinite(v[0]) and wp.isfinite(v[1]) and wp.isfinite(v[2])):
        wp.atomic_add(count_out, 0, 1)
        wp.atomic_min(count_out, 1, i)


# equations of state whose compression energy ``energy_chunks`` counts
EOS_NONE = 0    # no stored energy (the term is 0)
EOS_LINEAR = 1  # p = K (rho/rho0 - 1), clamped at 0
EOS_TAIT = 2    # p = K ((rho/rho0)^7 - 1), clamped at 0
ENERGY_COUNT = 3  # columns of energy_chunks: kinetic, potential, compression [J]


@wp.func
def compression_energy(eos: int, stiffness_per_density: wp.float64, ratio: wp.float64):
    """Energy per unit mass [J/kg] stored by compressing the fluid from rho0 to rho = ratio rho0 under the
    clamped pressure law ``eos`` (K / rho0 = ``stiffness_per_density`` [m^2/s^2]):
    e = int_rho0^rho p / rho'^2 drho'; linear: (K/rho0)(ln s + 1/s - 1), Tait: (K/rho0)((s^6 - 1)/6 + 1/s - 1);
    0 for s <= 1 (no tension). Both ~ c_s^2 (s - 1)^2 / 2 near rest."""
    s = ratio
    one = wp.float64(1.0)
    if eos == EOS_NONE or s <= one:
        return wp.float64(0.0)
    if eos == EOS_TAIT:
        s2 = s * s
        return stiffness_per_density * ((s2 * s2 * s2 - one) / wp.float64(6.0) + one / s - one)
    return stiffness_per_density * (wp.log(s) + one / s - one)


@wp.kernel(enable_backward=False)
def energy_chunks(
    chunk: int,
    # Model:
    particle_mass: float,
    rest_density: float,
    gravity: wp.vec3,
    eos: int,
    stiffness_per_density: wp.float64,
    # State in:
    particle_x: wp.array(dtype=wp.vec3),
    particle_v: wp.array(dtype=wp.vec3),
    particle_density: wp.array(dtype=float),
    # Out:
    partial_out: wp.array2d(dtype=wp.float64),
):
    """Per chunk of ``chunk`` particles, summed in index order in float64 (bitwise the same for any thread
    count): [k, 0] kinetic sum m |v|^2 / 2, [k, 1] potential sum -m g.x (local coordinates), [k, 2] compression
    energy sum m e(rho/rho0) (``compression_energy``) [J]."""
    k = wp.tid()
    lo = k * chunk
    hi = wp.min(lo + chunk, particle_x.shape[0])
    m = wp.float64(particle_mass)
    g = wp.vec3d(wp.float64(gravity[0]), wp.float64(gravity[1]), wp.float64(gravity[2]))
    rho0 = wp.float64(rest_density)
    ke = wp.float64(0.0)
    pe = wp.float64(0.0)
    u = wp.float64(0.0)
    for i in range(lo, hi):
        x = particle_x[i]
        v = particle_v[i]
        xd = wp.vec3d(wp.float64(x[0]), wp.float64(x[1]), wp.float64(x[2]))
        vd = wp.vec3d(wp.float64(v[0]), wp.float64(v[1]), wp.float64(v[2]))
        ke += wp.float64(0.5) * m * wp.dot(vd, vd)
        pe -= m * wp.dot(g, xd)
        u += m * compression_energy(eos, stiffness_per_density, wp.float64(particle_density[i]) / rho0)
    partial_out[k, 0] = ke
    partial_out[k, 1] = pe
    partial_out[k, 2] = u
