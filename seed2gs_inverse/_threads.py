"""Threads for the numpy / scipy parts (no Numba): how many, two halves of work on two of them, one BLAS thread.

The Numba kernels size their own thread pools (``NUMBA_NUM_THREADS``); the
sparse passes, the per-pixel loss, the vote and the neighbour queries use at most two
threads through this module. Dask workers set ``NUMBA_NUM_THREADS=1``
(:func:`~seed2gs_inverse.batch.batch_client`), and this module follows it,
so batch workers never oversubscribe their core. BLAS is held to one
thread (:func:`one_blas_thread`) wherever the package calls it in a loop.
"""

from __future__ import annotations

import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor

from threadpoolctl import ThreadpoolController

__all__ = ["n_threads", "run_both", "one_blas_thread"]

_pool = None
_controller, _modules_seen = None, -1
_inside = threading.local()  # .active: this thread is the pool's, running a second half


def _forget_pool() -> None:
    global _pool
    _pool = None


# A forked child has none of the parent's threads: it must start its own pool.
os.register_at_fork(after_in_child=_forget_pool)


def n_threads() -> int:
    """2, or 1 where ``NUMBA_NUM_THREADS`` (as Dask workers set it) or the CPU count says one core."""
    env = os.environ.get("NUMBA_NUM_THREADS", "").strip()
    n = int(env) if env.isdigit() and int(env) >= 1 else (os.cpu_count() or 1)
    return 2 if n >= 2 else 1


def run_both(fn, parallel: bool = True) -> None:
    """``fn(0)`` and ``fn(1)``: on two threads when ``parallel`` and :func:`n_threads` allow, else in turn.

    ``fn`` must give the same results either way (work on disjoint data);
    its exceptions propagate. Called from within a second half (nested) it
    runs in turn: the pool's one thread is busy with the caller.
    """
    global _pool
    if not parallel or n_threads() < 2 or getattr(_inside, "active", False):
        fn(0)
        fn(1)
        return
    if _pool is None:
        _pool = ThreadPoolExecutor(1, thread_name_prefix="seed2gs")

    def second():
        _inside.active = True
        try:
            fn(1)
        finally:
            _inside.active = False

    other = _pool.submit(second)
    try:
        fn(0)
    finally:
        other.result()


def one_blas_thread():
    """A context in which BLAS runs on one thread.

    The package calls BLAS on small problems many times over (``(n, 3) @
    (3, 3)`` products per view, vectors of length N per solver iteration):
    a multi-threaded BLAS beside Numba's threads spends more on waking and
    joining its threads than on the work, and much more when other work
    shares the cores. One thread also makes BLAS's reductions independent of
    the machine's thread settings.

    The loaded libraries are inspected again only when a module was imported
    since the last look (a new BLAS comes with a new extension module):
    ``threadpool_limits`` inspects them on every call, and a controller kept
    for the whole process would leave a BLAS loaded after the first call
    unlimited.
    """
    global _controller, _modules_seen
    if _controller is None or len(sys.modules) != _modules_seen:
        _controller, _modules_seen = ThreadpoolController(), len(sys.modules)
    return _controller.limit(limits=1, user_api="blas")
