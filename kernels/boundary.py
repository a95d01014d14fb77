"""The device side of a boundary method: ``wp.func`` terms that solver kernels inline at compile time.

A boundary method (Akinci 2012 particles, a penalty force, ...) is one ``BoundaryTerms`` object in
its own kernels module (``kernels/akinci2012.py``, ``kernels/penalty.py``). Solver kernel factories
take it as a compile-time choice (``functools.cache`` key, ``wp.static(terms.density)`` inside the
neighbour loop), so no kernel branches on a boundary name and a term that is None costs nothing
(``wp.static(terms.density is not None)`` removes the loop). Every term sees one fluid particle i
and one boundary particle b; ``params`` is the method's own ``wp.struct`` of constants.

    density(params, w_ib, volume_b) -> float
        contribution of b to rho_i / rho0 [-] (w_ib = W(|x_ib|, h) [1/m^3], volume_b [m^3]).
    gradient(params, grad_ib, volume_b) -> vec3
        contribution of b to grad_i (rho_i / rho0) [1/m] (grad_ib = grad_i W_ib [1/m^4]): PBF's
        grad_i C_i and DFSPH's factor and divergence use it; the wall's pressure acceleration of an
        implicit solver is -scalar_i * gradient (the wall mirrors particle i's own pressure).
    pressure(params, grad_ib, volume_b, p_rho2) -> vec3
        pressure acceleration of i from b [m/s^2] in the symmetric SPH form, given the wall's
        p/rho^2 [m^5/(kg s^2)] (WCSPH: report eq. 16, or mirrored).
    force(params, b, x_ib, v_ib, grad_ib, volume_b, rho_i) -> vec3
        non-pressure acceleration of i from b [m/s^2] (friction, a penalty force); b the boundary
        particle's index (per-particle constants in ``params``, e.g. a moving body's own friction),
        x_ib = x_i - x_b [m], v_ib = v_i - v_b [m/s], rho_i [kg/m^3].

``dissipative``: the force only removes relative motion, so an explicit integrator may clamp it so
that it never reverses a particle's velocity (friction); a penalty force is not dissipative.
"""
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, eq=False)
class BoundaryTerms:
    """Compile-time description of a boundary method for the solver kernels (see the module docstring).
    Hashed by identity: each object is one specialisation of every kernel that takes it."""

    name: str
    Params: Any                 # wp.struct type of the method's constants
    density: Any = None
    gradient: Any = None
    pressure: Any = None
    force: Any = None
    dissipative: bool = True
