"""Whitewater potentials (Ihmsen, Akinci, Akinci, Teschner 2012, "Unified spray, foam and air bubbles for
particle-based fluids"): how many secondary particles each fluid particle generates this step.

Per fluid particle i (neighbours j within the support H, W~_ij = 1 - |x_ij| / H):
    trapped air   v_diff_i = sum_j |v_ij| (1 - v^_ij . x^_ij) W~_ij                    [m/s]
    wave crest    kappa_i  = sum_j (1 - n^_i . n^_j) W~_ij  over j with x^_ji . n^_i < 0 (convex),
                  times 1 when v^_i . n^_i >= CREST_ALIGNMENT, else 0; n_i = -sum_j V_j grad W_ij  [-]
                  (only surface particles, |n| H >= NORMAL_MIN, have a normal)
    kinetic       E_i      = |v_i|^2 / 2                                                 [J/kg]
each mapped to [0, 1] by clamp(I, lo, hi) = (min(I, hi) - min(I, lo)) / (hi - lo), and
    n_d = I_k (k_ta I_ta + k_wc I_wc) dt
particles generated (stochastic rounding: one seeded stream per fluid slot and step).

Only a particle with I_k > 0 generates, and only a *crest candidate* (I_k > 0, a surface normal, moving
along it) reads normals, its own and its neighbours'. So the work follows those particles, in three
passes (a slow particle costs a few loads in each):
1. ``fast_pass``: for I_k > 0, one neighbour walk for n_i and v_diff_i together; a crest candidate flags
   its neighbours (``need``: each flag written 1 by any number of threads, no atomics);
2. ``crest_normals``: n_j of the flagged particles the first pass skipped (flags cleared);
3. ``potentials_kernel``: kappa_i of the crest candidates, the potentials and the count to generate.
The sums are those of a single pass over every particle, term for term in the same order.
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import neighbor_count, particle_in_cell_order
from .smoothing import SMOOTHING_FUNCTIONS

#: v^ . n^ from which a convex surface counts as a wave crest (Ihmsen et al. 2012, eq. 5)
CREST_ALIGNMENT = wp.constant(0.6)
#: |n| H below which a fluid particle has no surface normal (interior; a flat free surface gives ~1)
NORMAL_MIN = wp.constant(0.25)
#: ``state`` of a fluid particle after ``fast_pass``: generates nothing / may generate / may also crest
SLOW = wp.constant(wp.uint8(0))
FAST = wp.constant(wp.uint8(1))
CREST = wp.constant(wp.uint8(2))


@wp.func
def clamp_potential(value: float, lo: float, hi: float) -> float:
    """Ihmsen's Phi(I, tau_min, tau_max) = (min(I, hi) - min(I, lo)) / (hi - lo) in [0, 1]."""
    return (wp.min(value, hi) - wp.min(value, lo)) / (hi - lo)


@functools.cache
def normal_func(smoothing: str):
    """wp.func n_i = -sum_j (m / rho_j) grad_i W_ij [1/m] over i's neighbour list (minus the colour field's
    gradient; a surface particle's is outward, an interior particle's near 0)."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]
    NeighborList = NEIGHBOR_TYPES["list"]

    @wp.func
    def normal_of(i: int, particle_mass: float, smoothing_length: float, support_radius: float,
                  fluid_neighbors: NeighborList, particle_x: wp.array(dtype=wp.vec3),
                  particle_density: wp.array(dtype=float)) -> wp.vec3:
        xi = particle_x[i]
        n = wp.vec3(0.0)
        for k in range(int(neighbor_count(fluid_neighbors, i))):
            j = fluid_neighbors.index[i, k]
            r = xi - particle_x[j]
            if wp.length(r) < support_radius:
                n -= (particle_mass / particle_density[j]) * wp.static(gradient)(r, smoothing_length)
        return n

    return normal_of


@functools.cache
def fast_pass_kernel(smoothing: str):
    """Pass 1 (module docstring): n_i and v_diff_i of every particle with I_k > 0 (0 elsewhere), its
    ``state`` (SLOW, FAST, CREST), and ``need`` = 1 on the neighbours of a crest candidate."""
    _, gradient = SMOOTHING_FUNCTIONS[smoothing]
    NeighborList = NEIGHBOR_TYPES["list"]

    @wp.kernel(enable_backward=False, module="unique")
    def whitewater_fast_pass(
        tid_offset: int,
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        kinetic_range: wp.vec2,
        fluid_neighbors: NeighborList,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        normal_out: wp.array(dtype=wp.vec3),
        trapped_out: wp.array(dtype=float),
        state_out: wp.array(dtype=wp.uint8),
        need_out: wp.array(dtype=wp.uint8),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        vi = particle_v[i]
        speed_i = wp.length(vi)
        if clamp_potential(0.5 * speed_i * speed_i, kinetic_range[0], kinetic_range[1]) <= 0.0:
            normal_out[i] = wp.vec3(0.0)  # generates nothing; crest_normals fills it in if a neighbour reads it
            state_out[i] = SLOW
            return
        xi = particle_x[i]
        n = wp.vec3(0.0)
        trapped = float(0.0)
        k_end = int(neighbor_count(fluid_neighbors, i))
        for k in range(k_end):
            j = fluid_neighbors.index[i, k]
            x_ij = xi - particle_x[j]
            d = wp.length(x_ij)
            if d < support_radius:
                n -= (particle_mass / particle_density[j]) * wp.static(gradient)(x_ij, smoothing_length)
                if d > 0.0:
                    v_ij = vi - particle_v[j]
                    speed = wp.length(v_ij)
                    if speed > 0.0:
                        trapped += speed * (1.0 - wp.dot(v_ij / speed, x_ij / d)) * (1.0 - d / support_radius)
        normal_out[i] = n
        trapped_out[i] = trapped
        state = FAST
        if wp.length(n) * support_radius >= NORMAL_MIN and speed_i > 0.0:
            if wp.dot(vi / speed_i, wp.normalize(n)) >= CREST_ALIGNMENT:
                state = CREST
                for k in range(k_end):  # their normals are read by potentials_kernel
                    need_out[fluid_neighbors.index[i, k]] = wp.uint8(1)
        state_out[i] = state

    return whitewater_fast_pass


@functools.cache
def crest_normals_kernel(smoothing: str):
    """Pass 2: n_j of every flagged particle that ``fast_pass`` left at 0 (SLOW); the flags are cleared."""
    normal_of = normal_func(smoothing)
    NeighborList = NEIGHBOR_TYPES["list"]

    @wp.kernel(enable_backward=False, module="unique")
    def whitewater_crest_normals(
        tid_offset: int,
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        fluid_neighbors: NeighborList,
        particle_x: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        state: wp.array(dtype=wp.uint8),
        need: wp.array(dtype=wp.uint8),
        normal_out: wp.array(dtype=wp.vec3),
    ):
        i = particle_in_cell_order(fluid_neighbors, wp.tid() + tid_offset)
        if need[i] == wp.uint8(0):
            return
        need[i] = wp.uint8(0)
        if state[i] == SLOW:
            normal_out[i] = normal_of(i, particle_mass, smoothing_length, support_radius, fluid_neighbors,
                                      particle_x, particle_density)

    return whitewater_crest_normals


@functools.cache
def potentials_kernel():
    """Pass 3: potentials (I_ta, I_wc, I_k) in [0, 1] and the number of particles to generate this step."""
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
        trapped: wp.array(dtype=float),
        state: wp.array(dtype=wp.uint8),
        potential_out: wp.array(dtype=wp.vec3),
        generate_out: wp.array(dtype=wp.int32),
    ):
        i = wp.tid() + tid_offset
        s = state[i]
        if s == SLOW:  # generates nothing (most particles of a calm flow)
            potential_out[i] = wp.vec3(0.0)
            generate_out[i] = 0
            return
        vi = particle_v[i]
        speed_i = wp.length(vi)
        i_k = clamp_potential(0.5 * speed_i * speed_i, kinetic_range[0], kinetic_range[1])
        curvature = float(0.0)
        if s == CREST:
            xi = particle_x[i]
            nhat_i = wp.normalize(normal[i])
            for k in range(int(neighbor_count(fluid_neighbors, i))):
                j = fluid_neighbors.index[i, k]
                x_ij = xi - particle_x[j]
                d = wp.length(x_ij)
                if d < support_radius and d > 0.0:
                    nj = normal[j]
                    if wp.length(nj) * support_radius >= NORMAL_MIN:
                        if wp.dot(-x_ij, nhat_i) < 0.0:  # x^_ji . n^_i < 0: a convex neighbourhood
                            curvature += (1.0 - wp.dot(nhat_i, wp.normalize(nj))) * (1.0 - d / support_radius)
        i_ta = clamp_potential(trapped[i], trapped_air_range[0], trapped_air_range[1])
        i_wc = clamp_potential(curvature, wave_crest_range[0], wave_crest_range[1])
        potential_out[i] = wp.vec3(i_ta, i_wc, i_k)
        expected = i_k * (rate_ta * i_ta + rate_wc * i_wc) * dt
        count = int(0)
        if expected > 0.0:
            state_rng = wp.rand_init(seed, i)
            count = int(wp.floor(expected + wp.randf(state_rng)))  # stochastic rounding
        generate_out[i] = count

    return whitewater_potentials
