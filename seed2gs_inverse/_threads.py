"""Threads for the numpy / scipy parts (no Numba): how many, and two halves of work on two of them.

The Numba kernels size their own thread pools (``NUMBA_NUM_THREADS``); the
sparse passes, the per-pixel loss, the vote and the neighbour queries use at most two
threads through this module. Dask workers set ``NUMBA_NUM_THREADS=1``
(:func:`~seed2gs_inverse.batch.batch_client`), and this module follows it,
so batch workers never oversubscribe their core.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

__all__ = ["n_threads", "run_both"]

_pool = None
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
