"""Transducer probes: the fluid's normal force on the wall particles inside a sensor's face, per unit area,
integrated over each substep (host side: ``warp_sph/run/probe_sensors.py``).

The walls push fluid particle i with the force F_i [N] (``boundary_force``: the sum over the wall particles b
of the pair terms, Akinci et al. 2012: f_ib = -m term_i V_b grad_i W_ib, parallel to V_b grad_i W_ib). F_i is
split back into its pairs by that direction:
    G_i = sum_b V_b grad_i W(x_i - x_b),   s_i = F_i . G_i / |G_i|^2,   f_ib = s_i V_b grad_i W(x_i - x_b)
(exact when F_i is the pressure term alone; the least-squares share otherwise). The fluid pushes wall
particle b back with -f_ib, whose component into the wall (-n, n the face's normal into the fluid) is
f_ib . n. A sensor's reading is the area-weighted mean of its face particles' pressures,
    p = sum_b w_b (sum_i f_ib . n) / A_b                                                [Pa]
(w_b: the fraction of the sensor's face inside the wall cell of b, A_b: that cell's area), and what is
accumulated is p dt over each substep: the host divides by the elapsed time at each sample.
"""
import functools

import warp as wp

from .smoothing import SMOOTHING_FUNCTIONS


@functools.cache
def sensor_impulse_kernel(smoothing: str):
    """Kernel: impulse_out[s] += dt sum_b w_b / A_b sum_i f_ib . n over the face entries ``start[s]`` ..
    ``end[s] - 1`` of sensor s (wall particle ``entry_b``, weight ``entry_weight`` = w_b / A_b [1/m^2]); one
    thread per sensor, summed in a fixed order (no atomics)."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.kernel(enable_backward=False, module="unique")
    def sensor_impulse(
        # Model:
        smoothing_length: float,
        support_radius: float,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # Sensors:
        sensor_normal: wp.array(dtype=wp.vec3),
        sensor_start: wp.array(dtype=int),
        sensor_end: wp.array(dtype=int),
        entry_b: wp.array(dtype=int),
        entry_weight: wp.array(dtype=float),
        dt: float,
        # In:
        fluid_grid: wp.uint64,
        boundary_grid: wp.uint64,
        particle_x: wp.array(dtype=wp.vec3),
        boundary_force: wp.array(dtype=wp.vec3),
        # In/out:
        impulse: wp.array(dtype=float),
    ):
        s = wp.tid()
        n = sensor_normal[s]
        h = smoothing_length
        r2 = support_radius * support_radius
        total = float(0.0)
        for e in range(sensor_start[s], sensor_end[s]):
            b = entry_b[e]
            xb = boundary_x[b]
            vb = boundary_volume[b]
            load = float(0.0)
            query = wp.hash_grid_query(fluid_grid, xb, support_radius)
            i = int(0)
            while wp.hash_grid_query_next(query, i):
                xi = particle_x[i]
                x_ib = xi - xb
                if wp.dot(x_ib, x_ib) < r2:
                    g = wp.vec3(0.0)
                    bq = wp.hash_grid_query(boundary_grid, xi, support_radius)
                    c = int(0)
                    while wp.hash_grid_query_next(bq, c):
                        x_ic = xi - boundary_x[c]
                        if wp.dot(x_ic, x_ic) < r2:
                            g += boundary_volume[c] * wp.static(gradient)(x_ic, h)
                    gg = wp.dot(g, g)
                    if gg > 0.0:
                        share = wp.dot(boundary_force[i], g) / gg
                        load += share * vb * wp.dot(wp.static(gradient)(x_ib, h), n)
            total += entry_weight[e] * load
        impulse[s] = impulse[s] + dt * total

    return sensor_impulse


@wp.kernel(enable_backward=False)
def sensor_readings(
    sensor_column: wp.array(dtype=int),
    row: int,
    inv_elapsed: float,
    # In/out:
    impulse: wp.array(dtype=float),
    # Out:
    value_out: wp.array2d(dtype=float),
):
    """Row ``row`` of the samples, one thread per sensor: the mean pressure since the last sample [Pa]
    (impulse per area / elapsed time); the accumulator is zeroed for the next interval."""
    s = wp.tid()
    value_out[row, sensor_column[s]] = impulse[s] * inv_elapsed
    impulse[s] = 0.0
