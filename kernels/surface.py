"""Device code of surface reconstruction: particle bounds and the splatted colour field.

The field sampled on the grid nodes is the SPH colour (volume-fraction) field of the report,
eq. (25):

    Phi(x) = sum_j (m_j / rho_j) W(|x - x_j|, h)        [dimensionless]

about 1 inside the fluid and 0 outside. It is computed by *splatting*: one thread per particle
adds its term to every grid node within its support radius (``wp.atomic_add``), instead of one
thread per node gathering neighbours (measured 7x faster on the CPU, notes/warp_cpu.md).
Host launcher: ``warp_sph/surface.py``.
"""
import functools

import warp as wp

from .smoothing import SMOOTHING_FUNCTIONS


@wp.kernel(enable_backward=False)
def particle_bounds(
    # State in:
    particle_x: wp.array(dtype=wp.vec3),
    # Out: (lower x, y, z, upper x, y, z) [m], then the count of non-finite positions;
    # pre-filled with (+inf, +inf, +inf, -inf, -inf, -inf, 0) by the host
    bounds_out: wp.array(dtype=float),
):
    """Axis-aligned bounding box of the particle positions [m] by atomic min / max.

    min / max skip NaN, so non-finite positions are counted in bounds_out[6] instead.
    """
    tid = wp.tid()
    x = particle_x[tid]
    if not (wp.isfinite(x[0]) and wp.isfinite(x[1]) and wp.isfinite(x[2])):
        wp.atomic_add(bounds_out, 6, 1.0)
        return
    for a in range(3):
        wp.atomic_min(bounds_out, a, x[a])
        wp.atomic_max(bounds_out, 3 + a, x[a])


@functools.cache
def splat_field_kernel(smoothing: str):
    """Kernel adding each particle's (m / rho) W(|x_node - x_j|, h) to the grid nodes it covers.

    Specialised at compile time on the smoothing kernel ``smoothing`` (value function by
    ``wp.static``), one module per choice.
    """
    value, _gradient = SMOOTHING_FUNCTIONS[smoothing]

    @wp.kernel(enable_backward=False, module="unique")
    def splat_field(
        # Model:
        particle_mass: float,
        h: float,
        support_radius: float,
        # State in:
        particle_x: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        # Grid: node (i, j, k) sits at grid_origin + (i, j, k) * cell_size [m], flat index (i ny + j) nz + k
        grid_origin: wp.vec3,
        cell_size: float,
        grid_nx: int,
        grid_ny: int,
        grid_nz: int,
        # Out: Phi at the nodes, zeroed by the host; the flat view of an (nx, ny, nz) array
        field_out: wp.array(dtype=float),
    ):
        tid = wp.tid()
        rho = particle_density[tid]
        if rho <= 0.0:
            return
        weight = particle_mass / rho
        # particle position in grid units, relative to the origin
        g = (particle_x[tid] - grid_origin) / cell_size
        s = support_radius / cell_size
        s2 = s * s
        i0 = wp.max(int(wp.ceil(g[0] - s)), 0)
        i1 = wp.min(int(wp.floor(g[0] + s)), grid_nx - 1)
        j0 = wp.max(int(wp.ceil(g[1] - s)), 0)
        j1 = wp.min(int(wp.floor(g[1] + s)), grid_ny - 1)
        for i in range(i0, i1 + 1):
            dx = float(i) - g[0]
            for j in range(j0, j1 + 1):
                dy = float(j) - g[1]
                r2_xy = dx * dx + dy * dy
                rest = s2 - r2_xy
                if rest > 0.0:
                    # only the k-range of this (i, j) column that lies inside the support sphere;
                    # a while loop over the flat index is ~15 % faster on the CPU than range(k0, k1)
                    dz_max = wp.sqrt(rest)
                    k0 = wp.max(int(wp.ceil(g[2] - dz_max)), 0)
                    k1 = wp.min(int(wp.floor(g[2] + dz_max)), grid_nz - 1)
                    base = (i * grid_ny + j) * grid_nz
                    node = base + k0
                    last = base + k1
                    dz = float(k0) - g[2]
                    while node <= last:
                        r = wp.sqrt(r2_xy + dz * dz) * cell_size
                        wp.atomic_add(field_out, node, weight * wp.static(value)(r, h))
                        node += 1
                        dz += 1.0

    return splat_field
