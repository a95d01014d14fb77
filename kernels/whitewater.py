"""Whitewater: spray, foam and air bubbles as secondary particles (Ihmsen, Akinci, Akinci, Teschner 2012,
"Unified spray, foam and air bubbles for particle-based fluids", The Visual Computer 28(6)).

Per fluid particle i (neighbours j within the support H, W~_ij = 1 - |x_ij| / H):
    trapped air   v_diff_i = sum_j |v_ij| (1 - v^_ij . x^_ij) W~_ij                    [m/s]
    wave crest    kappa_i  = sum_j (1 - n^_i . n^_j) W~_ij  over j with x^_ji . n^_i < 0 (convex),
                  times 1 when v^_i . n^_i >= CREST_ALIGNMENT, else 0; n_i = -sum_j V_j grad W_ij  [-]
    kinetic       E_i      = |v_i|^2 / 2                                                 [J/kg]
each mapped to [0, 1] by clamp(I, lo, hi) = (min(I, hi) - min(I, lo)) / (hi - lo), and
    n_d = I_k (k_ta I_ta + k_wc I_wc) dt
particles generated (stochastic rounding), sampled in the cylinder of radius r and height |v_i| dt
around v_i (velocity v_i plus a radial spread). A secondary particle with fewer than ``spray_n``
fluid neighbours is spray (ballistic), with more than ``bubble_n`` an air bubble (buoyancy -k_b g,
drag k_d toward the fluid), else foam (moves with the fluid's kernel-averaged velocity and ages).
Deterministic: one seeded RNG stream per fluid slot and step, and every write goes to an index fixed
by exclusive scans (no atomics).
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import neighbor_count, particle_in_cell_order
from .smoothing import SMOOTHING_FUNCTIONS
from .whitewater_sample import fluid_sum_func, node_cell, sample_nodes, vec5

#: kinds of a secondary particle (``kind`` arrays)
KIND_SPRAY = wp.constant(1)
KIND_FOAM = wp.constant(2)
KIND_BUBBLE = wp.constant(3)
#: v^ . n^ from which a convex surface counts as a wave crest (Ihmsen et al. 2012, eq. 5)
CREST_ALIGNMENT = wp.constant(0.6)
#: radial velocity of a new particle at the cylinder's rim / |v_i| (Ihmsen's eq. 9 adds the radial offset
#: itself, a length; a fraction of the speed is the same spread at every scale)
SPREAD = wp.constant(0.1)
#: |n| H below which a fluid particle has no surface normal (interior; a flat free surface gives ~1)
NORMAL_MIN = wp.constant(0.25)


@wp.func
def clamp_potential(value: float, lo: float, hi: float) -> float:
    """Ihmsen's Phi(I, tau_min, tau_max) = (min(I, hi) - min(I, lo)) / (hi - lo) in [0, 1]."""
    return (wp.min(value, hi) - wp.min(value, lo)) / (hi - lo)


@wp.func
def classify(neighbors: float, spray_n: int, bubble_n: int) -> int:
    """Spray below ``spray_n`` fluid neighbours, bubble above ``bubble_n``, foam between (a sampled count
    is a real number)."""
    kind = KIND_FOAM
    if neighbors < float(spray_n):
        kind = KIND_SPRAY
    elif neighbors > float(bubble_n):
        kind = KIND_BUBBLE
    return kind


@functools.cache
def normals_kernel(smoothing: str):
    """Unnormalised outward normal n_i = -sum_j (m / rho_j) grad_i W_ij [1/m] (minus the colour field's
    gradient), computed where it is read: for particles faster than sqrt(min_speed2) and their
    neighbours (0 elsewhere)."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]
    NeighborList = NEIGHBOR_TYPES["list"]

    @wp.kernel(enable_backward=False, module="unique")
    def whitewater_normals(
        tid_offset: int,
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        min_speed2: float,
        fluid_neighbors: NeighborList,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        normal_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        xi = particle_x[i]
        n = wp.vec3(0.0)
        k = int(0)
        k_end = int(neighbor_count(fluid_neighbors, i))
        # only particles that generate (|v|^2 > min_speed2) read normals, their own and their neighbours'
        needed = wp.dot(particle_v[i], particle_v[i]) > min_speed2
        while k < k_end and not needed:
            vj = particle_v[fluid_neighbors.index[i, k]]
            needed = wp.dot(vj, vj) > min_speed2
            k += 1
        if not needed:
            k_end = 0
        k = int(0)
        while k < k_end:
            j = fluid_neighbors.index[i, k]
            r = xi - particle_x[j]
            if wp.length(r) < support_radius:
                n -= (particle_mass / particle_density[j]) * wp.static(gradient)(r, smoothing_length)
            k += 1
        normal_out[i] = n

    return whitewater_normals


@functools.cache
def potentials_kernel():
    """Potentials (I_ta, I_wc, I_k) in [0, 1] and the number of particles to generate this step."""
    NeighborList = NEIGHBOR_TYPES["list"]

    @wp.kernel(enable_backward=False, module="unique")
    def whitewater_potentials(
        tid_offset: int,
        support_radius: float,
        dt: float,
        seed: int,
        trapped_air_range: wp.vec2,
        wave_crest_range: wp.vec2,
        kinetic_range: wp.vec2,
        rate_ta: float,
        rate_wc: float,
        fluid_neighbors: NeighborList,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        normal: wp.array(dtype=wp.vec3),
        potential_out: wp.array(dtype=wp.vec3),
        generate_out: wp.array(dtype=wp.int32),
    ):
        i = wp.tid() + tid_offset
        xi = particle_x[i]
        vi = particle_v[i]
        speed_i = wp.length(vi)
        i_k = clamp_potential(0.5 * speed_i * speed_i, kinetic_range[0], kinetic_range[1])
        if i_k <= 0.0:  # generates nothing: no neighbour loop (most particles of a calm flow)
            potential_out[i] = wp.vec3(0.0)
            generate_out[i] = 0
            return
        ni = normal[i]
        surface_i = wp.length(ni) * support_radius >= NORMAL_MIN
        nhat_i = wp.normalize(ni)
        trapped = float(0.0)
        curvature = float(0.0)
        k = int(0)
        k_end = int(neighbor_count(fluid_neighbors, i))
        while k < k_end:
            j = fluid_neighbors.index[i, k]
            x_ij = xi - particle_x[j]
            d = wp.length(x_ij)
            if d < support_radius and d > 0.0:
                w = 1.0 - d / support_radius
                v_ij = vi - particle_v[j]
                speed = wp.length(v_ij)
                if speed > 0.0:
                    trapped += speed * (1.0 - wp.dot(v_ij / speed, x_ij / d)) * w
                nj = normal[j]
                if surface_i and wp.length(nj) * support_radius >= NORMAL_MIN:
                    if wp.dot(-x_ij, nhat_i) < 0.0:  # x^_ji . n^_i < 0: a convex neighbourhood
                        curvature += (1.0 - wp.dot(nhat_i, wp.normalize(nj))) * w
            k += 1
        if not surface_i or speed_i <= 0.0 or wp.dot(vi / speed_i, nhat_i) < CREST_ALIGNMENT:
            curvature = 0.0
        i_ta = clamp_potential(trapped, trapped_air_range[0], trapped_air_range[1])
        i_wc = clamp_potential(curvature, wave_crest_range[0], wave_crest_range[1])
        potential_out[i] = wp.vec3(i_ta, i_wc, i_k)
        expected = i_k * (rate_ta * i_ta + rate_wc * i_wc) * dt
        count = int(0)
        if expected > 0.0:
            state = wp.rand_init(seed, i)
            count = int(wp.floor(expected + wp.randf(state)))  # stochastic rounding
        generate_out[i] = count

    return whitewater_potentials


@functools.cache
def advect_kernel(smoothing: str):
    """Classify each secondary particle by its fluid neighbours and move it one step (module docstring);
    alive_out = 0 for a foam particle past its lifetime or any particle outside the bounds. The fluid's
    velocity and neighbour count are sampled from the node grid (``whitewater_sample``) when
    ``use_nodes`` is 1 and the particle lies inside it, else walked exactly (``fluid_sum``)."""
    fluid_sum = fluid_sum_func(smoothing)

    @wp.kernel(enable_backward=False, module="unique")
    def whitewater_advect(
        tid_offset: int,
        smoothing_length: float,
        support_radius: float,
        dt: float,
        gravity: wp.vec3,
        buoyancy: float,
        drag: float,
        spray_n: int,
        bubble_n: int,
        use_bounds: int,
        bounds_lo: wp.vec3,
        bounds_hi: wp.vec3,
        # fluid cell grid (``CellGrid``) and state
        grid_lo: wp.vec3,
        inv_cell_size: float,
        grid_dims: wp.vec3i,
        cell_start: wp.array(dtype=wp.int32),
        cell_point: wp.array(dtype=wp.int32),
        search_radius: float,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        # node grid of this step's fluid sums (``node_sums_kernel``)
        use_nodes: int,
        node_lo: wp.vec3,
        inv_spacing: float,
        node_dims: wp.vec3i,
        node: wp.array(dtype=vec5),
        # secondary particles, updated in place
        ww_x: wp.array(dtype=wp.vec3),
        ww_v: wp.array(dtype=wp.vec3),
        ww_age: wp.array(dtype=float),
        ww_life: wp.array(dtype=float),
        ww_kind: wp.array(dtype=wp.int32),
        alive_out: wp.array(dtype=wp.int32),
    ):
        k = wp.tid() + tid_offset
        x = ww_x[k]
        cell = wp.vec4(0.0)
        if use_nodes != 0:
            cell = node_cell(x, node_lo, inv_spacing, node_dims)
        fluid = vec5()
        if cell[3] != 0.0:
            fluid = sample_nodes(x, cell, node_lo, inv_spacing, node_dims, node)
        else:
            fluid = fluid_sum(x, smoothing_length, support_radius, grid_lo, inv_cell_size, grid_dims, cell_start,
                              cell_point, search_radius, particle_x, particle_v)
        kind = classify(fluid[4], spray_n, bubble_n)
        v = ww_v[k]
        v_fluid = v
        if fluid[3] > 0.0:
            v_fluid = wp.vec3(fluid[0], fluid[1], fluid[2]) / fluid[3]
        life = ww_life[k]
        if kind == KIND_SPRAY:
            v = v + dt * gravity
        elif kind == KIND_FOAM:
            v = v_fluid
            life = life - dt
        else:
            v = v - dt * buoyancy * gravity + drag * (v_fluid - v)
        x = x + dt * v
        alive = int(1)
        if life <= 0.0:
            alive = 0
        if use_bounds != 0:
            if x[0] < bounds_lo[0] or x[1] < bounds_lo[1] or x[2] < bounds_lo[2]:
                alive = 0
            if x[0] > bounds_hi[0] or x[1] > bounds_hi[1] or x[2] > bounds_hi[2]:
                alive = 0
        ww_x[k] = x
        ww_v[k] = v
        ww_age[k] = ww_age[k] + dt
        ww_life[k] = life
        ww_kind[k] = kind
        alive_out[k] = alive

    return whitewater_advect


@wp.kernel(enable_backward=False)
def scan_totals(alive: wp.array(dtype=wp.int32), alive_offset: wp.array(dtype=wp.int32), count: int,
                generate: wp.array(dtype=wp.int32), generate_offset: wp.array(dtype=wp.int32), fluid_count: int,
                totals_out: wp.array(dtype=wp.int32)):
    """totals = (survivors, particles to generate) from the exclusive scans (one thread)."""
    survivors = int(0)
    if count > 0:
        survivors = alive_offset[count - 1] + alive[count - 1]
    generated = int(0)
    if fluid_count > 0:
        generated = generate_offset[fluid_count - 1] + generate[fluid_count - 1]
    totals_out[0] = survivors
    totals_out[1] = generated


@wp.kernel(enable_backward=False)
def compact(tid_offset: int, alive: wp.array(dtype=wp.int32), alive_offset: wp.array(dtype=wp.int32),
            x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), age: wp.array(dtype=float),
            life: wp.array(dtype=float), kind: wp.array(dtype=wp.int32),
            x_out: wp.array(dtype=wp.vec3), v_out: wp.array(dtype=wp.vec3), age_out: wp.array(dtype=float),
            life_out: wp.array(dtype=float), kind_out: wp.array(dtype=wp.int32)):
    """Survivors to their scanned slots, order kept."""
    k = wp.tid() + tid_offset
    if alive[k] != 0:
        d = alive_offset[k]
        x_out[d] = x[k]
        v_out[d] = v[k]
        age_out[d] = age[k]
        life_out[d] = life[k]
        kind_out[d] = kind[k]


@functools.cache
def emit_kernel():
    """New particles of fluid slot i at slots start + generate_offset[i] + m (< capacity), sampled in the
    cylinder of radius ``cylinder_radius`` around x_i along v_i dt (Ihmsen et al. 2012, eq. 8-9)."""
    NeighborList = NEIGHBOR_TYPES["list"]

    @wp.kernel(enable_backward=False, module="unique")
    def whitewater_emit(
        tid_offset: int,
        dt: float,
        seed: int,
        start: int,
        capacity: int,
        cylinder_radius: float,
        lifetime_min: float,
        lifetime_max: float,
        spray_n: int,
        bubble_n: int,
        fluid_neighbors: NeighborList,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        generate: wp.array(dtype=wp.int32),
        generate_offset: wp.array(dtype=wp.int32),
        x_out: wp.array(dtype=wp.vec3),
        v_out: wp.array(dtype=wp.vec3),
        age_out: wp.array(dtype=float),
        life_out: wp.array(dtype=float),
        kind_out: wp.array(dtype=wp.int32),
    ):
        i = wp.tid() + tid_offset
        n = generate[i]
        if n == 0:
            return
        state = wp.rand_init(seed, i)
        wp.randf(state)  # the draw that rounded the count (potentials kernel)
        xi = particle_x[i]
        vi = particle_v[i]
        speed = wp.length(vi)
        axis = vi / speed
        helper = wp.vec3(1.0, 0.0, 0.0)
        if wp.abs(axis[0]) > 0.9:
            helper = wp.vec3(0.0, 1.0, 0.0)
        e1 = wp.normalize(wp.cross(axis, helper))
        e2 = wp.cross(axis, e1)
        kind = classify(float(neighbor_count(fluid_neighbors, i)), spray_n, bubble_n)
        base = start + generate_offset[i]
        for m in range(n):
            slot = base + m
            radius = cylinder_radius * wp.sqrt(wp.randf(state))
            theta = 2.0 * wp.pi * wp.randf(state)
            height = wp.randf(state) * speed * dt
            life = lifetime_min + (lifetime_max - lifetime_min) * wp.randf(state)
            if slot < capacity:
                radial = radius * wp.cos(theta) * e1 + radius * wp.sin(theta) * e2
                x_out[slot] = xi + radial + height * axis
                v_out[slot] = vi + (SPREAD * speed / cylinder_radius) * radial
                age_out[slot] = 0.0
                life_out[slot] = life
                kind_out[slot] = kind

    return whitewater_emit
