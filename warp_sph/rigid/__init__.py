"""Moving rigid bodies, two-way coupled with the fluid (Akinci et al. 2012) and stepped by Newton.

- ``spec``: the ``[[bodies]]`` parameters (``Body``, ``BODY_PARAMETERS``, ``check_body``) and each
  body's geometry in its own frame (``body_geometry``);
- ``sampling``: boundary particles of a body in its frame and their Akinci volumes;
- ``coupling``: device launchers that move those particles with the bodies and reduce the fluid's
  forces on them into one wrench per body (``kernels/rigid.py``);
- ``world``: the Newton model, solver and states (``RigidWorld``); Newton is the optional extra
  ``pip install 'warp-sph[rigid]'`` (``pip install -e '.[rigid]'`` in a checkout) and is imported
  only when a world is built.
"""
from .coupling import BodyParticles
from .sampling import BodySamples, sample_body
from .spec import BODY_PARAMETERS, Body, BodyGeometry, body_geometry, check_body
from .world import RigidWorld, StaticCollider, contact_frequency_for, require_newton, static_colliders

__all__ = ["BODY_PARAMETERS", "Body", "BodyGeometry", "BodyParticles", "BodySamples", "RigidWorld",
           "StaticCollider", "body_geometry", "check_body", "contact_frequency_for", "require_newton",
           "sample_body", "static_colliders"]
