"""matplotlib.pyplot on the Agg backend (headless), from the ``plots`` extra: the one import of every figure
warp-sph draws (``warp-sph plot``, the sweep summary's plot, the benchmarks' plots)."""
from __future__ import annotations


def pyplot_or_none():
    """matplotlib.pyplot with the Agg backend selected, or None when matplotlib is not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    return plt


def pyplot():
    """matplotlib.pyplot on the Agg backend, or WarpSphError (one line) naming the extra to install."""
    plt = pyplot_or_none()
    if plt is None:
        from .core.errors import WarpSphError

        raise WarpSphError("plotting needs matplotlib, the 'plots' extra: pip install -e '.[plots]' in the warp-sph "
                           "checkout (into the environment warp-sph runs in, e.g. .venv/bin/pip)")
    return plt
