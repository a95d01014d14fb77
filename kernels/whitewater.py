"""Whitewater: spray, foam and air bubbles as secondary particles (Ihmsen, Akinci, Akinci, Teschner 2012,
"Unified spray, foam and air bubbles for particle-based fluids", The Visual Computer 28(6)).

The potentials and the count n_d each fluid particle generates are in ``whitewater_potentials``. Here:
the n_d new particles of fluid particle i, sampled in the cylinder of radius r and height |v_i| dt
around v_i (velocity v_i plus a radial spread); the motion: a secondary particle with fewer than
``spray_n`` fluid neighbours is spray (ballistic), with more than ``bubble_n`` an air bubble (buoyancy
-k_b g, drag k_d toward the fluid), else foam (moves with the fluid's kernel-averaged velocity and
ages); the compaction of the survivors. Deterministic: one seeded RNG stream per fluid slot and step,
and every write goes to an index fixed by exclusive scans (no atomics).
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import neighbor_count
from .whitewater_sample import fluid_sum_func, node_cell, sample_nodes, vec5

#: kinds of a secondary particle (``kind`` arrays)
KIND_SPRAY = wp.constant(1)
KIND_FOAM = wp.constant(2)
KIND_BUBBLE = wp.constant(3)
#: radial velocity of a new particle at the cylinder's rim / |v_i| (Ihmsen's eq. 9 adds the radial offset
#: itself, a length; a fraction of the speed is the same spread at every scale)
SPREAD = wp.constant(0.1)


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


@wp.func
def emitting_slot(k: int, fluid_count: int, generate_offset: wp.array(dtype=wp.int32)) -> int:
    """The fluid slot i whose new particles hold new particle k: the largest i with generate_offset[i] <= k
    (exclusive scan of the counts; k < the total, so generate[i] > 0 there). Binary search, log2 n steps."""
    lo = int(0)
    hi = fluid_count - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if generate_offset[mid] <= k:
            lo = mid
        else:
            hi = mid - 1
    return lo


@functools.cache
def emit_kernel():
    """New particle k (one thread each, k < the particles that fit) of fluid slot i (``emitting_slot``), the
    m = k - generate_offset[i]-th of its n_d, at slot start + k: sampled in the cylinder of radius
    ``cylinder_radius`` around x_i along v_i dt (Ihmsen et al. 2012, eq. 8-9). Slot i's stream draws the
    rounding, then 4 values per particle in order: particle m skips the 4 m draws of those before it, so the
    particles are bit for bit those of one thread per fluid slot, and a step that generates few launches few
    threads (not one per fluid particle)."""
    NeighborList = NEIGHBOR_TYPES["list"]

    @wp.kernel(enable_backward=False, module="unique")
    def whitewater_emit(
        tid_offset: int,
        dt: float,
        seed: int,
        start: int,
        fluid_count: int,
        cylinder_radius: float,
        lifetime_min: float,
        lifetime_max: float,
        spray_n: int,
        bubble_n: int,
        fluid_neighbors: NeighborList,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        generate_offset: wp.array(dtype=wp.int32),
        x_out: wp.array(dtype=wp.vec3),
        v_out: wp.array(dtype=wp.vec3),
        age_out: wp.array(dtype=float),
        life_out: wp.array(dtype=float),
        kind_out: wp.array(dtype=wp.int32),
    ):
        k = wp.tid() + tid_offset
        i = emitting_slot(k, fluid_count, generate_offset)
        state = wp.rand_init(seed, i)
        wp.randf(state)  # the draw that rounded the count (potentials kernel)
        for _m in range(4 * (k - generate_offset[i])):  # the draws of slot i's earlier particles
            wp.randf(state)
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
        slot = start + k
        radius = cylinder_radius * wp.sqrt(wp.randf(state))
        theta = 2.0 * wp.pi * wp.randf(state)
        height = wp.randf(state) * speed * dt
        life = lifetime_min + (lifetime_max - lifetime_min) * wp.randf(state)
        radial = radius * wp.cos(theta) * e1 + radius * wp.sin(theta) * e2
        x_out[slot] = xi + radial + height * axis
        v_out[slot] = vi + (SPREAD * speed / cylinder_radius) * radial
        age_out[slot] = 0.0
        life_out[slot] = life
        kind_out[slot] = kind

    return whitewater_emit
