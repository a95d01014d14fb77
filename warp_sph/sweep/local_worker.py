"""Dask preload of the workers of a sweep's LocalCluster (``DaskExecutor(workers=N)``).

A terminal's Ctrl-C reaches every process of its process group, the LocalCluster's worker
processes too; they ignore it, so that the sweep (the client) alone handles it: it cancels the
cases not finished and closes the cluster, which stops the workers without a traceback. Workers
of an external cluster (``--scheduler``) are left as their owner started them. Warp starts here,
quietly (``warp_sph.core.device.init_warp``), before the first case arrives.
"""
import signal


def dask_setup(worker) -> None:  # noqa: ARG001 - the preload hook's signature
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from ..core.device import init_warp

    init_warp()
