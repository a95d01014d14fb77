"""Weakly compressible SPH (Becker & Teschner 2007): equation of state and accelerations.

Pressure acceleration (report eq. 10), the boundary method's terms (``kernels/boundary.py``: Akinci
2012 pressure eq. 16 and friction eq. 22-24, or the penalty force eq. 12), artificial viscosity, the
accelerations of the scene's explicit forces (``force_acceleration``, summed before), gravity; and the
delta-SPH density diffusion (Molteni & Colagrossi 2009, in the hydrostatic-corrected form of Fourtakas
et al. 2019 that DualSPHysics uses), integrated into a per-particle density correction.
"""
import functools

import warp as wp

from .density import NEIGHBOR_TYPES
from .neighbors import NeighborList, NoBoundaryParams, neighbor_count, particle_in_cell_order
from .pbf_pairs import PairCache
from .smoothing import SMOOTHING_FUNCTIONS


@wp.func
def artificial_viscosity_acceleration(alpha_h_c: float, particle_mass: float, rho_i: float, rho_j: float,
                                      v_ij: wp.vec3, x_ij: wp.vec3, eps_h2: float, grad: wp.vec3) -> wp.vec3:
    """Artificial viscosity of pair ij [m/s^2] (Monaghan 1992; Becker & Teschner 2007): -m Pi_ij grad W_ij
    with Pi_ij = -nu min(v_ij . x_ij, 0) / (|x_ij|^2 + 0.01 h^2), nu = 2 alpha h c_s / (rho_i + rho_j);
    alpha_h_c = alpha h c_s [m^2/s]. Only approaching pairs: it dissipates compression (impacts), not shear."""
    vx = wp.dot(v_ij, x_ij)
    if vx >= 0.0:
        return wp.vec3(0.0)
    nu = 2.0 * alpha_h_c / (rho_i + rho_j)
    return (particle_mass * nu * vx / (wp.dot(x_ij, x_ij) + eps_h2)) * grad


@wp.func
def density_diffusion_pair(coefficient: float, hydrostatic_density: wp.vec3, rho_i: float, rho_j: float,
                           x_ij: wp.vec3, grad: wp.vec3, eps_h2: float, volume_j: float) -> float:
    """delta-SPH density diffusion of i due to fluid neighbour j [kg/(m^3 s)] (Molteni & Colagrossi 2009;
    Fourtakas et al. 2019): 2 delta h c_s (rho_j - rho_i - rho^H_ji) (x_ji . grad_i W_ij) / (|x_ij|^2 + 0.01 h^2) V_j,
    coefficient = 2 delta h c_s [m^2/s], V_j = m / rho_j. rho^H_ji = rho0 g . x_ji / c_s^2 (hydrostatic_density =
    rho0 g / c_s^2 [kg/m^4]) is the density difference of a fluid at hydrostatic rest, so that state is not
    diffused away. (rho_j - rho_i - rho^H_ji) is antisymmetric in ij and the rest symmetric: sum_i V_i D_i = 0."""
    x_ji = -x_ij
    rho_h = wp.dot(hydrostatic_density, x_ji)
    return coefficient * (rho_j - rho_i - rho_h) * wp.dot(x_ji, grad) / (wp.dot(x_ij, x_ij) + eps_h2) * volume_j


@wp.func
def touches_wall(boundary_neighbors: NeighborList, boundary_x: wp.array(dtype=wp.vec3), x: wp.vec3, i: int,
                 support_radius: float) -> bool:
    """Whether fluid particle i (at x) has a boundary particle within the support (the neighbour list's)."""
    k_end = int(neighbor_count(boundary_neighbors, i))
    for k in range(k_end):
        if wp.length(x - boundary_x[boundary_neighbors.index[i, k]]) < support_radius:
            return True
    return False


@wp.func
def touches_wall(boundary_neighbors: wp.uint64, boundary_x: wp.array(dtype=wp.vec3), x: wp.vec3, i: int,
                 support_radius: float) -> bool:
    """Whether fluid particle i (at x) has a boundary particle within the support (a hash-grid query)."""
    query = wp.hash_grid_query(boundary_neighbors, x, support_radius)
    b = int(0)
    while wp.hash_grid_query_next(query, b):
        if wp.length(x - boundary_x[b]) < support_radius:
            return True
    return False


@wp.kernel(enable_backward=False)
def add_density_correction(
    tid_offset: int,
    # In:
    density_correction: wp.array(dtype=float),
    # Out:
    particle_density_out: wp.array(dtype=float),
):
    """rho_i += delta rho_i: the summed density plus the density the delta-SPH diffusion moved [kg/m^3]."""
    i = wp.tid() + tid_offset
    particle_density_out[i] = particle_density_out[i] + density_correction[i]


@wp.kernel(enable_backward=False)
def start_density_correction(
    tid_offset: int,
    rest_density: float,
    # In/out: the summed density in, the start's correction out
    particle_density: wp.array(dtype=float),
    density_correction_out: wp.array(dtype=float),
):
    """The start: delta rho_i = rho0 - sum_j m W_ij, and rho_i = rho0 (the continuity equation's usual
    initial density: the kernel's deficit at a free surface and the walls' excess are not density)."""
    i = wp.tid() + tid_offset
    density_correction_out[i] = rest_density - particle_density[i]
    particle_density[i] = rest_density


@functools.cache
def pressure_kernel(equation_of_state: str):
    """Linear p = max(K (rho/rho0 - 1), 0) (report eq. 9, K = B rho0) or Tait
    p = max(K ((rho/rho0)^7 - 1), 0); K = stiffness [Pa]; and p / rho^2 [m^5/(kg s^2)], the term of
    eq. 10 the force kernel reads per pair (formed once per particle, not once per pair)."""
    tait = equation_of_state == "tait"

    @wp.kernel(enable_backward=False, module="unique")
    def compute_pressure(
        tid_offset: int,
        # Model:
        rest_density: float,
        stiffness: float,
        # State in:
        particle_density: wp.array(dtype=float),
        # Out:
        particle_pressure_out: wp.array(dtype=float),
        pressure_term_out: wp.array(dtype=float),
    ):
        i = wp.tid() + tid_offset
        rho = particle_density[i]
        ratio = rho / rest_density
        p = float(0.0)
        if wp.static(tait):
            r2 = ratio * ratio
            p = stiffness * (r2 * r2 * r2 * ratio - 1.0)
        else:
            p = stiffness * (ratio - 1.0)
        p = wp.max(p, 0.0)
        particle_pressure_out[i] = p
        pressure_term_out[i] = p / (rho * rho)

    return compute_pressure


@functools.cache
def acceleration_kernel(smoothing: str, boundary_terms, with_forces: bool, mirrored_pressure: bool,
                        neighbors: str = "grid", with_artificial_viscosity: bool = False,
                        write_pressure_term: bool = False, with_density_diffusion: bool = False):
    """a_i = -sum_j m (p_i/rho_i^2 + p_j/rho_j^2) grad W_ij (eq. 10)
             + a_forces,i (``force_acceleration``, with_forces: the scene's explicit forces)
             + sum_b [pressure_b(grad W_ib, V_b, (p/rho^2)_b) + force_b(x_ib, v_ib, ...)] + g    [m/s^2]

    boundary_terms: the boundary method's ``BoundaryTerms`` (``kernels/boundary.py``; None: no walls).
    The wall's p/rho^2 is p_i/rho_i^2 (report eq. 16) or, ``mirrored_pressure``, p_i/rho_i^2 + p_i/rho0^2
    (SPlisHSPlasH). Also writes the force of the boundary on each particle [N] (its negative sums to
    the wall load). neighbors: "grid" or "list" (see ``density.NEIGHBOR_TYPES``).
    write_pressure_term: also write the wall's p/rho^2 of each particle to ``boundary_pressure_term_out``
    [m^5/(kg s^2)] (moving bodies gather their force from it; otherwise the array is not touched).
    with_density_diffusion: also delta rho_i += dt D_i with D_i = sum_j ``density_diffusion_pair`` over the
    fluid neighbours (delta-SPH; ``density_correction`` [kg/m^3], in place: no thread reads another's), except
    the pairs in which i or j has a boundary particle within H_s: the wall's share of those particles' density
    (rho0 sum_b V_b W_ib, Akinci's stand-in for the fluid beyond the wall, whose excess is the wall's push) has
    no fluid neighbour on the far side, so the one-sided sum diffused it into the fluid behind until the first
    layer carried no pressure and crossed the wall (tests/test_wcsph_diffusion.py).
    The density it acts on is particle_density: the summation (eq. 7) plus delta rho, whose rate is then
    sum_j m v_ij . grad W_ij + D_i, the continuity equation with the delta-SPH term.
    neighbors "pairs": lists that hold pairs up to H_s + a skin (``wcsph.search_skin``) and the step's
    ``PairCache`` (``wcsph_lists.density_pairs_kernel``): the fluid pairs and their grad W come from the cache,
    in the lists' order; listed boundary pairs at or beyond H_s are skipped (their terms are zero).
    """
    value, gradient = SMOOTHING_FUNCTIONS[smoothing]
    cached = neighbors == "pairs"
    lists = neighbors in ("list", "pairs")
    Neighbors = NEIGHBOR_TYPES["list" if cached else neighbors]
    pair_x = with_artificial_viscosity or with_density_diffusion  # terms that read x_ij, v_ij or rho_j
    with_pressure = boundary_terms is not None and boundary_terms.pressure is not None
    with_force = boundary_terms is not None and boundary_terms.force is not None
    with_boundary = with_pressure or with_force
    wall_guard = with_density_diffusion and boundary_terms is not None
    BoundaryParams = boundary_terms.Params if boundary_terms is not None else NoBoundaryParams
    pressure_term = boundary_terms.pressure if with_pressure else None
    force_term = boundary_terms.force if with_force else None

    @wp.func(module="unique")
    def fluid_pair(x_ij: wp.vec3, v_ij: wp.vec3, grad: wp.vec3, p_rho2_i: float, p_rho2_j: float, rho_i: float,
                   rho_j: float, particle_mass: float, eps_h2: float, alpha_h_c: float) -> wp.vec3:
        """Pressure (eq. 10) and artificial viscosity acceleration of i due to fluid neighbour j != i;
        grad = grad_i W_ij."""
        a = -particle_mass * (p_rho2_i + p_rho2_j) * grad
        if wp.static(with_artificial_viscosity):
            a += artificial_viscosity_acceleration(alpha_h_c, particle_mass, rho_i, rho_j, v_ij, x_ij, eps_h2, grad)
        return a

    @wp.func(module="unique")
    def boundary_pair(params: BoundaryParams, b: int, x_ib: wp.vec3, v_ib: wp.vec3, volume_b: float, p_rho2_b: float,
                      rho_i: float, h: float) -> wp.vec3:
        """Acceleration of i by boundary particle b: the method's pressure and force terms."""
        grad = wp.static(gradient)(x_ib, h)
        a = wp.vec3(0.0)
        if wp.static(with_pressure):
            a = wp.static(pressure_term)(params, grad, volume_b, p_rho2_b)
        if wp.static(with_force):
            a += wp.static(force_term)(params, b, x_ib, v_ib, grad, volume_b, rho_i)
        return a

    @wp.func(module="unique")
    def diffusion_pair(diffuse_i: bool, boundary_neighbors: Neighbors, boundary_x: wp.array(dtype=wp.vec3),
                       x_j: wp.vec3, j: int, support_radius: float, diffusion_coefficient: float,
                       hydrostatic_density: wp.vec3, rho_i: float, rho_j: float, x_ij: wp.vec3, grad: wp.vec3,
                       eps_h2: float, volume_j: float) -> float:
        """D_ij of the delta-SPH term (``density_diffusion_pair``), 0 when i or, with walls, j touches a wall."""
        diffuse = diffuse_i
        if wp.static(wall_guard):
            if diffuse:
                diffuse = not touches_wall(boundary_neighbors, boundary_x, x_j, j, support_radius)
        d = float(0.0)
        if diffuse:
            d = density_diffusion_pair(diffusion_coefficient, hydrostatic_density, rho_i, rho_j, x_ij, grad, eps_h2,
                                       volume_j)
        return d

    @wp.kernel(enable_backward=False, module="unique")
    def compute_acceleration(
        tid_offset: int,
        # Model:
        particle_mass: float,
        smoothing_length: float,
        support_radius: float,
        rest_density: float,
        gravity: wp.vec3,
        alpha_h_c: float,
        diffusion_coefficient: float,
        hydrostatic_density: wp.vec3,
        dt: float,
        boundary_params: BoundaryParams,
        boundary_neighbors: Neighbors,
        boundary_x: wp.array(dtype=wp.vec3),
        boundary_v: wp.array(dtype=wp.vec3),
        boundary_volume: wp.array(dtype=float),
        # State in:
        fluid_neighbors: Neighbors,
        pairs: PairCache,
        particle_x: wp.array(dtype=wp.vec3),
        particle_v: wp.array(dtype=wp.vec3),
        particle_density: wp.array(dtype=float),
        particle_pressure: wp.array(dtype=float),
        pressure_term: wp.array(dtype=float),
        force_acceleration: wp.array(dtype=wp.vec3),
        # Out:
        particle_acceleration_out: wp.array(dtype=wp.vec3),
        boundary_force_out: wp.array(dtype=wp.vec3),
        boundary_pressure_term_out: wp.array(dtype=float),
        density_correction: wp.array(dtype=float),
    ):
        t = wp.tid() + tid_offset  # the pair cache's row (neighbors "pairs")
        i = particle_in_cell_order(fluid_neighbors, t)
        xi = particle_x[i]
        vi = particle_v[i]
        rho_i = particle_density[i]
        p_rho2_i = pressure_term[i]  # p_i / rho_i^2 (``pressure_kernel``)
        # the wall's p/rho^2: eq. 16 uses p_i/rho_i^2; mirrored (SPlisHSPlasH) gives the wall particle the
        # fluid particle's pressure at rest density: p_i/rho_i^2 + p_i/rho0^2
        p_rho2_b = p_rho2_i
        if wp.static(mirrored_pressure):
            p_rho2_b = p_rho2_i + particle_pressure[i] / (rest_density * rest_density)
        if wp.static(write_pressure_term):
            boundary_pressure_term_out[i] = p_rho2_b
        h = smoothing_length
        eps_h2 = 0.01 * h * h
        support2 = support_radius * support_radius
        a = wp.vec3(0.0)
        drho = float(0.0)
        diffuse_i = True  # the pairs of a particle next to a wall do not diffuse (docstring)
        if wp.static(wall_guard):
            diffuse_i = not touches_wall(boundary_neighbors, boundary_x, xi, i, support_radius)
        if wp.static(cached):
            k = int(0)
            k_end = int(pairs.count[t])
            while k < k_end:
                j = pairs.index[t, k]
                grad = pairs.gradient[t, k]
                x_ij = wp.vec3(0.0)
                v_ij = wp.vec3(0.0)
                rho_j = float(0.0)
                if wp.static(pair_x):
                    x_ij = xi - particle_x[j]
                    v_ij = vi - particle_v[j]
                    rho_j = particle_density[j]
                a += fluid_pair(x_ij, v_ij, grad, p_rho2_i, pressure_term[j], rho_i, rho_j, particle_mass, eps_h2,
                                alpha_h_c)
                if wp.static(with_density_diffusion):
                    drho += diffusion_pair(diffuse_i, boundary_neighbors, boundary_x, particle_x[j], j, support_radius,
                                           diffusion_coefficient, hydrostatic_density, rho_i, rho_j, x_ij, grad,
                                           eps_h2, particle_mass / rho_j)
                k += 1
        elif wp.static(lists):
            k = int(0)
            k_end = int(neighbor_count(fluid_neighbors, i))
            while k < k_end:
                j = fluid_neighbors.index[i, k]
                if j != i:
                    rho_j = particle_density[j]
                    x_ij = xi - particle_x[j]
                    grad = wp.static(gradient)(x_ij, h)
                    a += fluid_pair(x_ij, vi - particle_v[j], grad, p_rho2_i, pressure_term[j],
                                    rho_i, rho_j, particle_mass, eps_h2, alpha_h_c)
                    if wp.static(with_density_diffusion):
                        drho += diffusion_pair(diffuse_i, boundary_neighbors, boundary_x, particle_x[j], j,
                                               support_radius, diffusion_coefficient, hydrostatic_density, rho_i,
                                               rho_j, x_ij, grad, eps_h2, particle_mass / rho_j)
                k += 1
        else:
            query = wp.hash_grid_query(fluid_neighbors, xi, support_radius)
            j = int(0)
            while wp.hash_grid_query_next(query, j):
                if j != i:
                    x_ij = xi - particle_x[j]
                    if wp.length(x_ij) < support_radius:
                        rho_j = particle_density[j]
                        grad = wp.static(gradient)(x_ij, h)
                        a += fluid_pair(x_ij, vi - particle_v[j], grad, p_rho2_i, pressure_term[j],
                                        rho_i, rho_j, particle_mass, eps_h2, alpha_h_c)
                        if wp.static(with_density_diffusion):
                            drho += diffusion_pair(diffuse_i, boundary_neighbors, boundary_x, particle_x[j], j,
                                                   support_radius, diffusion_coefficient, hydrostatic_density, rho_i,
                                                   rho_j, x_ij, grad, eps_h2, particle_mass / rho_j)
        if wp.static(with_density_diffusion):
            density_correction[i] = density_correction[i] + dt * drho
        a_boundary = wp.vec3(0.0)
        if wp.static(with_boundary):
            if wp.static(lists):
                k = int(0)
                k_end = int(neighbor_count(boundary_neighbors, i))
                while k < k_end:
                    b = boundary_neighbors.index[i, k]
                    x_ib = xi - boundary_x[b]
                    if wp.static(cached):
                        if wp.dot(x_ib, x_ib) < support2:
                            a_boundary += boundary_pair(boundary_params, b, x_ib, vi - boundary_v[b],
                                                        boundary_volume[b], p_rho2_b, rho_i, h)
                    else:
                        a_boundary += boundary_pair(boundary_params, b, x_ib, vi - boundary_v[b],
                                                    boundary_volume[b], p_rho2_b, rho_i, h)
                    k += 1
            else:
                bquery = wp.hash_grid_query(boundary_neighbors, xi, support_radius)
                b = int(0)
                while wp.hash_grid_query_next(bquery, b):
                    x_ib = xi - boundary_x[b]
                    if wp.length(x_ib) < support_radius:
                        a_boundary += boundary_pair(boundary_params, b, x_ib, vi - boundary_v[b], boundary_volume[b],
                                                    p_rho2_b, rho_i, h)
        boundary_force_out[i] = particle_mass * a_boundary
        if wp.static(with_forces):
            a += force_acceleration[i]
        particle_acceleration_out[i] = a + a_boundary + gravity

    return compute_acceleration
