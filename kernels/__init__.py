"""Device code of warp-sph: ``@wp.func`` and ``@wp.kernel`` definitions only.

Installed as ``warp_sph.kernels``. Nothing here imports ``warp_sph``; host launchers live in the
``warp_sph`` module of the same name (``kernels/density.py`` <-> ``warp_sph/density.py`` ...).
"""
