"""Where a batch runs: the Dask client of a batch, an embedded cluster sized to the machine.

:func:`batch_client` turns the ``client`` argument of
:func:`~seed2gs_inverse.batch.extract_many` into a :class:`distributed.Client`:

``None``
    an embedded :class:`distributed.LocalCluster` sized to this machine:
    one worker process per core (at most one per job), one task thread per
    worker, and ``NUMBA_NUM_THREADS`` = cores / workers in each worker so
    that the rasterizer's parallel loops (and the two-thread numpy/scipy
    parts, :mod:`seed2gs_inverse._threads`) do not oversubscribe the cores
    (BLAS is held to one thread inside ``solve()``; a ``NUMBA_NUM_THREADS``
    set in this environment caps the per-worker value). ``n_workers``
    overrides the count.
``"tcp://HOST:PORT"`` or a :class:`distributed.Client`
    an existing cluster (``dask scheduler`` / ``dask worker``). The workers
    must see the scene, camera and output paths (a shared file system).
``"sequential"``
    no client (None): the runner runs the jobs in this process.

``dask.distributed`` is imported only when a cluster is asked for, so the
sequential runner and ``import seed2gs_inverse.batch`` do not load it.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
from contextlib import contextmanager
from urllib.request import ProxyHandler, build_opener

from .._validation import check_int
from ..errors import ValidationError

__all__ = ["batch_client", "available_cores", "dashboard_address"]

#: Run in every embedded worker process at its (re)start. Given to Dask by file path, so that it is
#: imported on its own: as a module name it would import this package, and with it the pipeline and
#: Numba, before the worker can take its first task.
_WORKER_PRELOAD = os.path.join(os.path.dirname(os.path.abspath(__file__)), "_worker_preload.py")

_SPAWN_HINT = ("If a script calls extract_many at its top level: worker processes start by importing the "
               "script, so each would start the batch again; put that code under "
               "'if __name__ == \"__main__\":', or run with client=\"sequential\"")


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity where the platform has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _has_dashboard() -> bool:
    try:
        import bokeh  # noqa: F401 - an optional package: only whether the dashboard can be served
    except ImportError:
        return False
    return True


@contextmanager
def batch_client(client=None, n_workers: int | None = None, n_jobs: int | None = None,
                 threads_per_worker: int | None = None):
    """Yield a :class:`distributed.Client` for a batch (see the module docstring).

    Parameters
    ----------
    client : None, "sequential", str or distributed.Client
        None starts an embedded ``LocalCluster`` (closed on exit); a
        scheduler address connects to it (the connection is closed on exit);
        a ``Client`` is used as is; ``"sequential"`` yields None.
    n_workers : int, optional
        Worker processes of the embedded cluster (default: one per core, at
        most ``n_jobs``).
    n_jobs : int, optional
        How many jobs the batch has.
    threads_per_worker : int, optional
        ``NUMBA_NUM_THREADS`` of each embedded worker (default: cores //
        workers, capped by a ``NUMBA_NUM_THREADS`` set here).

    Raises
    ------
    ValidationError
        A bad ``client``, an unreachable scheduler, bad counts, or embedded
        workers that cannot start (a script without a ``__main__`` guard).
    """
    if isinstance(client, str) and client == "sequential":
        yield None
        return
    dask, distributed = _dask_distributed()
    Client = distributed.Client
    if isinstance(client, Client):
        yield client
        return
    if isinstance(client, str):
        if not client.startswith(("tcp://", "tls://", "ucx://", "inproc://", "ws://", "wss://")):
            raise ValidationError(f"scheduler address {client!r} must look like tcp://HOST:PORT")
        try:
            c = Client(client, timeout=dask.config.get("distributed.comm.timeouts.connect"))
        except OSError as exc:
            raise ValidationError(f"cannot reach the Dask scheduler at {client} ({exc}); "
                                  f"is 'dask scheduler' running there?") from None
        try:
            yield c
        finally:
            c.close()
        return
    if client is not None:
        raise ValidationError(f"client must be None, 'sequential', a scheduler address or a "
                              f"distributed.Client, got {type(client).__name__}")
    cores = available_cores()
    if n_workers is None:
        n_workers = max(1, min(cores, n_jobs or cores))
    n_workers = check_int("n_workers", int(n_workers), lo=1)
    if threads_per_worker is None:
        threads = max(1, cores // n_workers)
        user_cap = os.environ.get("NUMBA_NUM_THREADS", "").strip()
        if user_cap.isdigit() and int(user_cap) >= 1:
            threads = min(threads, int(user_cap))
    else:
        threads = check_int("threads_per_worker", threads_per_worker, lo=1)
    with _embedded_client(n_workers, threads) as c:
        yield c


def _dask_distributed() -> tuple:
    """The ``dask`` and ``distributed`` modules, imported on first use (see the module docstring)."""
    try:
        import dask
        import distributed
    except ImportError:  # pragma: no cover - a declared dependency
        raise ValidationError("batch extraction needs dask.distributed: pip install 'dask[distributed]'") from None
    return dask, distributed


@contextmanager
def _embedded_client(n_workers: int, threads: int):
    """A client of a new ``LocalCluster`` of ``n_workers`` processes with ``threads`` Numba threads each."""
    dask, distributed = _dask_distributed()
    Client, LocalCluster = distributed.Client, distributed.LocalCluster

    env = {"NUMBA_NUM_THREADS": str(threads), "OMP_NUM_THREADS": str(threads),
           "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
           # Numba's OpenMP threads must not spin between parallel regions
           # on cores that other workers need.
           "OMP_WAIT_POLICY": "PASSIVE"}
    # A dead worker fails its task at once (KilledWorker); extract_many then
    # retries it exactly once itself, the same way as on an external cluster.
    # One task per worker thread at a time (saturation 1.0, with the jobs
    # submitted as one group the scheduler queues itself): no job waits
    # behind a dying one to be counted as its victim.
    # Dask's MALLOC_TRIM_THRESHOLD_ for worker processes also freezes glibc's
    # mmap threshold at 128 KiB, so every large numpy temporary of the solver
    # would be mapped and zeroed afresh, making the solve stage slower in a
    # worker than in the main process. The workers keep glibc's defaults.
    with dask.config.set({"distributed.scheduler.allowed-failures": 0,
                          "distributed.scheduler.worker-saturation": 1.0,
                          "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                          "distributed.worker.daemon": False,
                          # Ctrl-C reaches the whole process group: the workers (also those a nanny
                          # starts again) leave it to this process, which closes the cluster
                          "distributed.worker.preload": [_WORKER_PRELOAD]}):
        if getattr(multiprocessing.current_process(), "_inheriting", False):
            raise ValidationError(_SPAWN_HINT)  # a worker process re-importing the user's script
        try:
            cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                                   dashboard_address=":0",  # a free port: never "8787 is in use"
                                   silence_logs=logging.ERROR, env=env)
        except RuntimeError as exc:
            reason = str(exc).rstrip(".")
            raise ValidationError(f"could not start the embedded Dask workers ({reason}). {_SPAWN_HINT}") from exc
        dask_log = logging.getLogger("distributed")
        level = dask_log.level
        try:
            c = Client(cluster)
            try:
                yield c
            except KeyboardInterrupt:
                # Ctrl-C: the cluster is closed under running tasks; the nannies' reports of the
                # cancelled work are expected, not errors worth a screen of tracebacks.
                dask_log.setLevel(logging.CRITICAL)
                raise
            finally:
                c.close()
        finally:
            cluster.close()
            dask_log.setLevel(level)


def dashboard_address(client) -> str | None:
    """The dashboard's address, when one is being served.

    The scheduler's HTTP server always runs (health, metrics); its dashboard
    pages need bokeh, which for an embedded cluster is this environment's.
    An existing scheduler (``dask scheduler --no-dashboard``, or one without
    bokeh) is asked for the page itself (:func:`_serves`); a link that is
    not an http(s) address (a relative JupyterHub proxy path) is given as
    configured. None when there is no dashboard, or on any error (the
    address is only a courtesy line).
    """
    try:
        info = client.scheduler_info()
        if "dashboard" not in info.get("services", {}):
            return None
        if getattr(client, "cluster", None) is not None:
            return client.dashboard_link if _has_dashboard() else None
        link = client.dashboard_link
        return link if not link.startswith(("http://", "https://")) or _serves(link) else None
    except Exception:  # noqa: BLE001 - only a courtesy line
        return None


def _serves(link: str, seconds: float = 2.0) -> bool:
    """Whether ``link`` answers 200 within ``seconds`` in all (no proxy: it is the cluster's own address).

    Asked on a daemon thread, so a slow server or name lookup cannot hold the batch up longer.
    """
    answer = []

    def ask():
        try:
            with build_opener(ProxyHandler({})).open(link, timeout=seconds) as page:
                answer.append(page.status == 200)
        except Exception:  # noqa: BLE001 - a 404 (no dashboard), a refused connection, a bad certificate
            answer.append(False)

    asker = threading.Thread(target=ask, daemon=True, name="seed2gs-dashboard-probe")
    asker.start()
    asker.join(seconds)
    return bool(answer and answer[0])
