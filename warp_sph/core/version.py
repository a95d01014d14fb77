"""The package's version, ``warp_sph.__version__`` (the ``version`` of pyproject.toml), kept here so that
modules inside the package read it without importing the package root (which imports them)."""

__version__ = "0.1.0"
