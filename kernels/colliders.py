"""Animated colliders (``warp_sph.rigid.colliders``): the work their boundary particles do on the fluid.

The particles themselves are placed by ``kernels/rigid.place_body_particles`` (pose and twist per
collider) and the fluid's force on them is ``kernels/rigid.body_particle_force_kernel``.
"""
import warp as wp


@wp.kernel(enable_backward=False)
def collider_work(
    dt: float,
    start: int,
    count: int,
    # State in:
    boundary_v: wp.array(dtype=wp.vec3),
    particle_force: wp.array(dtype=wp.vec3),
    # Out (accumulated):
    work: wp.array(dtype=wp.float64),
):
    """One thread: work += -dt sum_k F_k . v_b [J], F_k the fluid's force on collider particle k [N] and
    v_b = boundary_v[start + k] its velocity [m/s] (the work the colliders do on the fluid over dt [s]),
    summed in index order in float64 (bitwise the same for any launch)."""
    total = wp.float64(0.0)
    for k in range(count):
        total += wp.float64(wp.dot(particle_force[k], boundary_v[start + k]))
    work[0] = work[0] - wp.float64(dt) * total
