"""Preloaded into every worker process of the embedded cluster (``distributed.worker.preload``).

Ctrl-C in a terminal reaches the whole process group; only the runner should act on it (by closing the
cluster), so workers ignore SIGINT, also those a nanny starts again after a worker died.

Dask imports this file by its path (:mod:`.cluster`), not as part of the package: it must import
nothing from ``seed2gs_inverse``, so that a worker starts without loading the pipeline.
"""

import signal
import threading


def dask_setup(worker):  # noqa: ARG001 - dask's preload hook
    """Ignore SIGINT in this worker process (signals can be set only from the main thread)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
