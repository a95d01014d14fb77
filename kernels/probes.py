"""Probe kernels: kernel-weighted fluid values at fixed points, and the probe readings made from them.

At a point x_k, with rest volumes V = m / rho0 of the fluid particles j:
    fill      F_k = sum_j V W(x_k - x_j)                          (the simulation's kernel)  [-]  (1 in the bulk)
    pressure  p_k = sum_j V K (p_j + rho0 g . (x_p - x_j)) / sum_j V K   (K the gauge kernel)    [Pa]
The pressure is Shepard-normalised (as SPHERIC studies and DualSPHysics' gauges and MeasureTool ``-kcorr``
sample it) and carries each neighbour's pressure to the probe point x_p with the hydrostatic term of Adami, Hu &
Adams 2012 (eq. 27 with a static wall), so a probe at rest reads rho0 |g| depth at x_p. K is DualSPHysics'
interpolation kernel: Wendland C2 with h_g = coefh sqrt(3) d at coefh = 1 (its 3D smoothing length; support
2 h_g = 3.46 d), not the simulation's cubic spline of support 2 d: the particle pressures of a lattice carry a
mode alternating from plane to plane that exerts no force (docs/validation-notes.md), and a kernel of 2 d gives the
nearest plane half the weight and reads the mode (+5 % at the fcc tank's mid-depth), where 3.46 d averages it
out. The kernel is centred at x_k, which the host moves off the container's walls to where the first fluid
layer lies (DualSPHysics measures 1.5 h inside the fluid for the same reason). Heights and fronts walk the fill
along a line (step ``line_step``): the free surface is where F falls through 1/2 (DualSPHysics' mass-limit rule
with the limit half the bulk value), linearly interpolated between the two points around the crossing.
"""
import functools

import warp as wp

from .smoothing import SMOOTHING_FUNCTIONS

#: probe kinds as the device sees them
KIND_PRESSURE = wp.constant(0)
KIND_HEIGHT = wp.constant(1)
KIND_FRONT = wp.constant(2)
#: the fill at the free surface of a height or front line [-]
SURFACE_FILL = wp.constant(0.5)


@wp.func
def wendland_c2_value(r: float, h: float) -> float:
    """Wendland C2 kernel in 3D (Wendland 1995; DualSPHysics' kernel), support 2h:
    W = 21 / (16 pi h^3) (1 - q/2)^4 (2q + 1), q = r / h [1/m^3]."""
    q = r / h
    if q >= 2.0:
        return 0.0
    t = 1.0 - 0.5 * q
    return 21.0 / (16.0 * wp.pi * h * h * h) * t * t * t * t * (2.0 * q + 1.0)


@functools.cache
def point_values_kernel(smoothing: str, with_pressure: bool):
    """Kernel: fill (the simulation's kernel, ``smoothing_length``) and (``with_pressure``) Shepard pressure with
    the gauge kernel (Wendland C2, ``gauge_smoothing_length``) at each point ``point_x``, the pressure carried
    hydrostatically to ``point_target`` (the probe's point, where the evaluation point was moved off a wall);
    one thread per point."""
    value, _ = SMOOTHING_FUNCTIONS[smoothing]

    @wp.kernel(enable_backward=False, module="unique")
    def probe_point_values(
        # Model:
        particle_volume: float,
        rest_density: float,
        gravity: wp.vec3,
        smoothing_length: float,
        support_radius: float,
        gauge_smoothing_length: float,
        # In:
        fluid_grid: wp.uint64,
        particle_x: wp.array(dtype=wp.vec3),
        particle_pressure: wp.array(dtype=float),
        point_x: wp.array(dtype=wp.vec3),
        point_target: wp.array(dtype=wp.vec3),
        # Out:
        point_fill_out: wp.array(dtype=float),
        point_pressure_out: wp.array(dtype=float),
    ):
        k = wp.tid()
        xk = point_x[k]
        target = point_target[k]
        fill = float(0.0)
        gauge_fill = float(0.0)
        weighted = float(0.0)
        reach = support_radius
        if wp.static(with_pressure):
            reach = wp.max(support_radius, 2.0 * gauge_smoothing_length)
        query = wp.hash_grid_query(fluid_grid, xk, reach)
        j = int(0)
        while wp.hash_grid_query_next(query, j):
            d = xk - particle_x[j]
            r = wp.length(d)
            if r < support_radius:
                fill += particle_volume * wp.static(value)(r, smoothing_length)
            if wp.static(with_pressure):
                w = particle_volume * wendland_c2_value(r, gauge_smoothing_length)
                gauge_fill += w
                weighted += w * (particle_pressure[j] + rest_density * wp.dot(gravity, target - particle_x[j]))
        point_fill_out[k] = fill
        if wp.static(with_pressure):
            p = float(0.0)
            if gauge_fill > 0.0:
                p = weighted / gauge_fill
            point_pressure_out[k] = p

    return probe_point_values


@wp.func
def line_crossing(point_fill: wp.array(dtype=float), start: int, end: int, step: float, last: int) -> float:
    """Distance [m] along a line of points (``start`` .. ``end`` - 1, ``step`` apart) to the free surface:
    last = 0: the first fall of the fill through 1/2 after it was >= 1/2 (height: walk up from the floor,
    spray above the first surface ignored); last = 1: the last point with fill >= 1/2 and the fall after
    it (front: the furthest fluid). Linear interpolation between the points around the crossing;
    0 when no point reaches 1/2 (dry), the line's length when the fluid reaches its end."""
    wet = int(-1)
    s = float(0.0)
    found = int(0)
    for k in range(start, end):
        f = point_fill[k]
        if f >= SURFACE_FILL:
            wet = k
            s = float(k - start) * step
            found = 0
        elif wet >= 0 and found == 0:
            f0 = point_fill[k - 1]
            s = (float(k - 1 - start) + (f0 - SURFACE_FILL) / (f0 - f)) * step
            found = 1
            if last == 0:
                return s
    return s


@wp.kernel(enable_backward=False)
def probe_readings(
    # Probes:
    probe_kind: wp.array(dtype=int),
    probe_point_start: wp.array(dtype=int),
    probe_point_end: wp.array(dtype=int),
    probe_offset: wp.array(dtype=float),
    min_fill: float,
    line_step: float,
    row: int,
    # In:
    point_fill: wp.array(dtype=float),
    point_pressure: wp.array(dtype=float),
    # Out:
    value_out: wp.array2d(dtype=float),
    fill_out: wp.array2d(dtype=float),
):
    """Row ``row`` of the samples, one thread per probe: pressure [Pa] (0 where the fill is below
    ``min_fill``: dry), height [m] (world z of the surface: the line's start + the crossing) or front
    [m] (world coordinate along the axis: ``probe_offset`` + the crossing)."""
    q = wp.tid()
    a = probe_point_start[q]
    b = probe_point_end[q]
    kind = probe_kind[q]
    if kind == KIND_PRESSURE:
        f = point_fill[a]
        p = float(0.0)
        if f >= min_fill:
            p = point_pressure[a]
        value_out[row, q] = p
        fill_out[row, q] = f
    else:
        last = int(0)
        if kind == KIND_FRONT:
            last = 1
        value_out[row, q] = probe_offset[q] + line_crossing(point_fill, a, b, line_step, last)
        fill_out[row, q] = point_fill[a]


@wp.func
def wall_kernel_2d(s: float, support: float) -> float:
    """Cubic spline in two dimensions (Liu & Liu: alpha = 15 / (7 pi h^2), h = support / 2) of the
    in-plane distance s [m]: integrates to 1 over the wall plane [1/m^2]."""
    h = 0.5 * support
    q = s / h
    w = float(0.0)
    if q < 1.0:
        w = 2.0 / 3.0 - q * q + 0.5 * q * q * q
    elif q < 2.0:
        t = 2.0 - q
        w = t * t * t / 6.0
    return w * 15.0 / (7.0 * wp.pi * h * h)


@wp.kernel(enable_backward=False)
def probe_wall_loads(
    # Model:
    support_radius: float,
    # In:
    fluid_grid: wp.uint64,
    particle_x: wp.array(dtype=wp.vec3),
    boundary_force: wp.array(dtype=wp.vec3),
    wall_point: wp.array(dtype=wp.vec3),
    wall_normal: wp.array(dtype=wp.vec3),
    wall_inv_coverage: wp.array(dtype=float),
    wall_index: wp.array(dtype=int),
    # Out:
    point_pressure_out: wp.array(dtype=float),
):
    """Pressure on a wall [Pa] at a probe point x_p on it (unit normal n into the fluid): the walls' force on
    the fluid next to it, spread over the wall plane with the 2D kernel K of the in-plane distance s_i,
        p = sum_i K(s_i) F_i . n / C,
    i within H_s of the plane, F_i the boundary force on fluid particle i [N] (the solver's wall reaction,
    whatever its pressure term), C = the integral of K over the part of the wall the fluid can cover
    (1 away from edges; host-computed). At rest sum_i F_i . n is the weight of the water above the wall:
    what a pressure transducer of the kernel's footprint measures. One thread per wall probe."""
    k = wp.tid()
    xp = wall_point[k]
    n = wall_normal[k]
    reach = support_radius * 1.4143
    load = float(0.0)
    query = wp.hash_grid_query(fluid_grid, xp, reach)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        d = particle_x[j] - xp
        dn = wp.dot(d, n)
        if dn < support_radius:
            s = wp.length(d - dn * n)
            if s < support_radius:
                load += wall_kernel_2d(s, support_radius) * wp.dot(boundary_force[j], n)
    point_pressure_out[wall_index[k]] = load * wall_inv_coverage[k]
