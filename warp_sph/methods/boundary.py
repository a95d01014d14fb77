"""The boundary-method interface: how walls and obstacles act on the fluid.

A boundary method is one host module in ``warp_sph/methods/boundaries/`` with a ``BoundaryMethod``
subclass decorated with ``@register_boundary``, and one kernels module of the same name holding its
``BoundaryTerms`` (``kernels/boundary.py``: its density, gradient, pressure and force terms as
``wp.func``s). The solver kernel factories take those terms with ``wp.static``; no kernel names a
boundary method. The host class provides:

- ``name``, ``title``, ``parameters`` (its scene section, like a solver's);
- ``sample(scene)``: the scene's particles, boundary particles included (default: one layer of
  particles on the container's faces and the obstacles' surfaces, ``scene.sampling``);
- ``terms()``: the compile-time ``BoundaryTerms``; ``params()``: the ``wp.struct`` of its constants;
- ``time_step_bounds(speed)``: bounds of the step its explicit terms need (friction, a penalty force);
- ``refuses_bodies()``: a reason why it cannot couple moving rigid bodies (default: it can).
"""
from __future__ import annotations

from typing import ClassVar

from .solver import MethodBase, TimeStepBound


class BoundaryMethod(MethodBase):
    """Base class of the boundary methods (see the module docstring). ``sim`` is the Simulation."""

    #: True when the method's density term makes the fluid next to a wall read rest density, so the
    #: fluid starts at the gap of ``smoothing.wall_gap`` (physics notes section 7)
    contributes_density: ClassVar[bool] = False
    #: True when the wall's force is a spring that stores energy the energy watchdog does not count
    #: (``warp_sph.run.energy``): the energy rule is then off for the scene, the other rules stay
    stores_energy: ClassVar[bool] = False

    def __init__(self, sim):
        self.sim = sim
        self.model = sim.model
        self.config = sim.scene.sections.get(self.name)

    @classmethod
    def sample(cls, scene):
        """Initial particles of ``scene`` (``warp_sph.scene.sampling.SampledScene``)."""
        from ..scene.sampling import sample_scene

        return sample_scene(scene)

    @classmethod
    def refuses_bodies(cls) -> str | None:
        """A reason why this method cannot couple moving rigid bodies, or None. Bodies see the fluid
        through the method's pressure and force terms (``kernels/rigid.py``), so every method whose
        fluid kernels use only those (and density / gradient terms) can couple."""
        return None

    def terms(self):
        """The ``kernels.boundary.BoundaryTerms`` the solver kernels are specialised with."""
        raise NotImplementedError

    def params(self):
        """An instance of ``terms().Params`` holding this run's constants."""
        raise NotImplementedError

    def time_step_bounds(self, speed: float) -> list[TimeStepBound]:
        """Bounds of the step the method's explicit terms need at flow speed ``speed`` [m/s]."""
        return []

    def summary(self) -> dict:
        """Constants of this method for run.json and ``warp-sph check``."""
        return {}
