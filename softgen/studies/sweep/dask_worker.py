"""Preload of the Dask workers a local sweep starts (``--scheduler local``).

A Ctrl-C reaches the whole process group: the worker processes of the LocalCluster got
it too and printed a KeyboardInterrupt traceback each (issue 23: seven on one Ctrl-C).
The sweep's main process owns the interrupt (it keeps the journal and says one line);
the workers leave SIGINT to it, as the process-pool workers do
(:func:`softgen.core.stop.worker_init`), and are closed by the cluster.
"""
from __future__ import annotations

import signal


def dask_setup(worker) -> None:
    """Called by Dask in each worker process as it starts (``preload``)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
