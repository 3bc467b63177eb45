"""Where a batch runs: one process, an embedded cluster sized to the machine, or an existing cluster.

:func:`resolve_layout` turns the ``client`` argument of
:func:`~seed2gs_inverse.batch.extract_many` into a :class:`Layout`, and
:func:`open_layout` starts what it needs:

``None``
    the faster layout for this machine (:func:`choose_layout`): either
    ``"sequential"`` (below), or an embedded :class:`distributed.LocalCluster`:
    one worker process per core (at most one per job), one task thread per
    worker, and ``NUMBA_NUM_THREADS`` = cores / workers in each worker so
    that the rasterizer's parallel loops (and the two-thread numpy/scipy
    parts, :mod:`seed2gs_inverse._threads`) do not oversubscribe the cores
    (BLAS is held to one thread inside ``solve()``; a ``NUMBA_NUM_THREADS``
    set in this environment caps the per-worker value). ``n_workers`` or
    ``threads_per_worker`` ask for the embedded cluster whatever the rule says.
``"tcp://HOST:PORT"`` or a :class:`distributed.Client`
    an existing cluster (``dask scheduler`` / ``dask worker``). The workers
    must see the scene, camera and output paths (a shared file system).
``"sequential"``
    no cluster: the runner runs the jobs one after the other in this
    process, whose Numba kernels use every core.

The embedded cluster's workers keep their scratch files in a folder the
cluster creates in the temporary folder and removes when it closes, so a
batch leaves the temporary folder as it found it. ``dask.distributed`` (the
``batch`` extra) is imported only when a cluster is asked for or chosen, so
the sequential layout and ``import seed2gs_inverse.batch`` do not need it;
when the rule would choose workers and the extra is not installed, the
batch runs sequentially and says so.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import shutil
import tempfile
import threading
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from urllib.request import ProxyHandler, build_opener

from .._extras import MissingExtraError, install_command, missing_extra
from .._validation import check_int
from ..errors import ValidationError

__all__ = ["batch_client", "available_cores", "dashboard_address", "Layout", "choose_layout", "resolve_layout",
           "open_layout", "MIN_JOBS_FOR_WORKERS", "SMALL_MACHINE_CORES", "SMALL_MACHINE_MIN_JOBS"]

#: The layout rule of :func:`choose_layout`: several worker processes only for a batch of at least
#: this many jobs ...
MIN_JOBS_FOR_WORKERS = 4
#: ... and, on a machine of at most this many cores, where one process already keeps every core
#: busy (Numba kernels on every core, the numpy/scipy passes on two threads) ...
SMALL_MACHINE_CORES = 2
#: ... of at least this many: there, two one-thread workers gain little over one process even on a
#: long batch, and the cluster's start (worker processes, their imports, each worker's own scene
#: reads) costs more than a short batch wins back (the timings: README, "Many objects, many scenes").
SMALL_MACHINE_MIN_JOBS = 16

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


def _numba_threads(cores: int) -> int:
    """Numba threads of one process given ``cores``: all of them, capped by a ``NUMBA_NUM_THREADS`` set here."""
    user_cap = os.environ.get("NUMBA_NUM_THREADS", "").strip()
    return max(1, min(cores, int(user_cap))) if user_cap.isdigit() and int(user_cap) >= 1 else max(1, cores)


def choose_layout(n_jobs: int, cores: int) -> str:
    """The faster layout for ``n_jobs`` jobs on ``cores`` cores: ``"sequential"`` or ``"workers"``.

    The rule: one process with every core's threads (``"sequential"``)
    unless there are at least two cores and the batch has at least
    :data:`MIN_JOBS_FOR_WORKERS` jobs, or :data:`SMALL_MACHINE_MIN_JOBS`
    on a machine of at most :data:`SMALL_MACHINE_CORES` cores; then one
    worker process per core (``"workers"``).

    Parameters
    ----------
    n_jobs : int
        Jobs left to run (at least 0).
    cores : int
        Cores this process may use (at least 1).

    Raises
    ------
    ValidationError
        A count that is not an int in range.
    """
    n_jobs = check_int("n_jobs", n_jobs, lo=0)
    cores = check_int("cores", cores, lo=1)
    return "workers" if cores >= 2 and n_jobs >= _min_jobs_for_workers(cores) else "sequential"


def _min_jobs_for_workers(cores: int) -> int:
    """The fewest jobs for which :func:`choose_layout` starts workers on ``cores`` (>= 2) cores."""
    return SMALL_MACHINE_MIN_JOBS if cores <= SMALL_MACHINE_CORES else MIN_JOBS_FOR_WORKERS


@dataclass(frozen=True)
class Layout:
    """Where a batch runs, and why (:func:`resolve_layout`; :func:`open_layout` sets ``client``).

    Attributes
    ----------
    kind : {"sequential", "workers", "cluster"}
        This process; an embedded cluster of ``workers`` processes; an existing cluster.
    cores : int
        Cores of this machine (its CPU affinity).
    workers : int or None
        Processes that run jobs (1 for ``"sequential"``; None for an existing cluster).
    threads : int or None
        Numba threads of each of those processes (None for an existing cluster).
    chosen : bool
        True when :func:`choose_layout` chose it, False when the caller asked for it.
    why : str
        Why this layout, in words (empty when asked for).
    address : str or None
        The existing cluster's scheduler address (once open for a ``Client``).
    client : distributed.Client or None
        Set by :func:`open_layout` for ``"workers"`` and ``"cluster"``.
    target : str or distributed.Client or None
        The scheduler address or ``Client`` asked for (``"cluster"`` only).
    """

    kind: str
    cores: int
    workers: int | None = 1
    threads: int | None = 1
    chosen: bool = False
    why: str = ""
    address: str | None = None
    client: object = field(default=None, repr=False, compare=False)
    target: object = field(default=None, repr=False, compare=False)  # the address or Client asked for

    def describe(self, n_jobs: int) -> str:
        """One line for the user: ``"batch: 3 jobs, sequential in one process with 2 threads (...)"``."""
        jobs = f"{n_jobs} job{'' if n_jobs == 1 else 's'}"
        if self.kind == "sequential":
            where = f"sequential in one process with {self.threads} thread{'' if self.threads == 1 else 's'}"
        elif self.kind == "workers":
            where = (f"{self.workers} Dask worker process{'' if self.workers == 1 else 'es'} of {self.threads} "
                     f"thread{'' if self.threads == 1 else 's'} each")
        else:
            n = None if self.client is None else len(self.client.scheduler_info().get("workers", {}))
            where = f"on the Dask cluster at {self.address}" + ("" if n is None else f" ({n} workers)")
        return f"batch: {jobs}, {where} ({self.cores} core{'' if self.cores == 1 else 's'}; {self.why or 'asked for'})"

    def record(self) -> dict:
        """The layout for ``summary.json``'s ``meta``: kind, cores, workers, threads, chosen, why, address."""
        return {"kind": self.kind, "cores": self.cores, "workers": self.workers, "threads": self.threads,
                "chosen": self.chosen, "why": self.why, "address": self.address}


def resolve_layout(client=None, n_workers: int | None = None, n_jobs: int | None = None,
                   threads_per_worker: int | None = None, cores: int | None = None) -> Layout:
    """The :class:`Layout` that ``client`` and the counts ask for (see the module docstring); starts nothing.

    Parameters
    ----------
    client : None, "sequential", str or distributed.Client
        None: the layout :func:`choose_layout` picks for ``n_jobs`` on this
        machine, or the embedded cluster when ``n_workers`` or
        ``threads_per_worker`` is given.
    n_workers : int, optional
        Worker processes of the embedded cluster (default: one per core, at
        most ``n_jobs``).
    n_jobs : int, optional
        How many jobs the batch has (default: as many as cores).
    threads_per_worker : int, optional
        ``NUMBA_NUM_THREADS`` of each embedded worker (default: cores //
        workers, capped by a ``NUMBA_NUM_THREADS`` set here).
    cores : int, optional
        The machine's cores (default :func:`available_cores`).

    Raises
    ------
    ValidationError
        A bad ``client`` or scheduler address, or bad counts.
    """
    cores = available_cores() if cores is None else check_int("cores", cores, lo=1)
    check_int("n_workers", n_workers, lo=1, optional=True)
    check_int("threads_per_worker", threads_per_worker, lo=1, optional=True)
    check_int("n_jobs", n_jobs, lo=0, optional=True)
    n_jobs = cores if n_jobs is None else n_jobs
    asked_workers = n_workers is not None or threads_per_worker is not None
    if isinstance(client, str) and client == "sequential":
        return Layout("sequential", cores, 1, _numba_threads(cores))
    if isinstance(client, str):
        if not client.startswith(("tcp://", "tls://", "ucx://", "inproc://", "ws://", "wss://")):
            raise ValidationError(f"scheduler address {client!r} must look like tcp://HOST:PORT")
        return Layout("cluster", cores, None, None, address=client, target=client)
    if client is not None:
        _dask, distributed = _dask_distributed()
        if not isinstance(client, distributed.Client):
            raise ValidationError(f"client must be None, 'sequential', a scheduler address or a "
                                  f"distributed.Client, got {type(client).__name__}")
        return Layout("cluster", cores, None, None, address=client.scheduler.address, target=client)
    chosen, why = False, ""
    if not asked_workers:
        chosen = True
        need = _min_jobs_for_workers(cores)
        if choose_layout(n_jobs, cores) == "sequential":
            why = ("chosen: one core" if cores < 2 else
                   f"chosen: worker processes pay off from {need} jobs on {cores} cores")
            return Layout("sequential", cores, 1, _numba_threads(cores), chosen=True, why=why)
        why = f"chosen: {n_jobs} jobs, at least {need} on {cores} cores"
        try:
            _dask_distributed()
        except MissingExtraError:
            return Layout("sequential", cores, 1, _numba_threads(cores), chosen=True,
                          why=f"worker processes would suit {n_jobs} jobs on {cores} cores, but the 'batch' "
                              f"extra is not installed: {install_command('batch')}")
    if n_workers is None:
        n_workers = max(1, min(cores, n_jobs or cores))
    if threads_per_worker is None:
        threads_per_worker = max(1, min(cores // n_workers, _numba_threads(cores)))
    return Layout("workers", cores, n_workers, threads_per_worker, chosen=chosen, why=why)


@contextmanager
def open_layout(layout: Layout):
    """Yield ``layout`` with its ``client`` set: None for ``"sequential"``, else a :class:`distributed.Client`.

    An embedded cluster is started (and closed on exit, its scratch folder
    removed); a scheduler address is connected to (the connection closed on
    exit); a given ``Client`` is used as is.

    Raises
    ------
    ValidationError
        An unreachable scheduler, or embedded workers that cannot start (a
        script without a ``__main__`` guard).
    MissingExtraError
        A cluster is asked for and ``dask.distributed`` is not installed.
    """
    if layout.kind == "sequential":
        yield layout
        return
    dask, distributed = _dask_distributed()
    if layout.kind == "workers":
        with _embedded_client(layout.workers, layout.threads) as c:
            yield replace(layout, client=c)
        return
    if isinstance(layout.target, distributed.Client):
        yield replace(layout, client=layout.target)
        return
    try:
        c = distributed.Client(layout.target, timeout=dask.config.get("distributed.comm.timeouts.connect"))
    except OSError as exc:
        raise ValidationError(f"cannot reach the Dask scheduler at {layout.target} ({exc}); "
                              f"is 'dask scheduler' running there?") from None
    try:
        yield replace(layout, client=c)
    finally:
        c.close()


@contextmanager
def batch_client(client=None, n_workers: int | None = None, n_jobs: int | None = None,
                 threads_per_worker: int | None = None):
    """Yield a :class:`distributed.Client` for a batch, or None where it runs in this process.

    :func:`open_layout` of :func:`resolve_layout` (see the module
    docstring): ``client=None`` without counts may choose the sequential
    layout (None).

    Parameters
    ----------
    client : None, "sequential", str or distributed.Client
        None: the faster layout for this machine, or the embedded
        ``LocalCluster`` (closed on exit) when a count is given; a scheduler
        address connects to it (the connection is closed on exit); a
        ``Client`` is used as is; ``"sequential"`` yields None.
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
    MissingExtraError
        A cluster is asked for and ``dask.distributed`` is not installed.
    """
    with open_layout(resolve_layout(client, n_workers=n_workers, n_jobs=n_jobs,
                                    threads_per_worker=threads_per_worker)) as layout:
        yield layout.client


def _dask_distributed() -> tuple:
    """The ``dask`` and ``distributed`` modules, imported on first use (see the module docstring)."""
    try:
        import dask
        import distributed
    except ImportError as exc:
        raise missing_extra("batch", "running jobs on Dask workers", exc) from None
    return dask, distributed


@contextmanager
def _embedded_client(n_workers: int, threads: int):
    """A client of a new ``LocalCluster`` of ``n_workers`` processes with ``threads`` Numba threads each."""
    dask, distributed = _dask_distributed()
    Client, LocalCluster = distributed.Client, distributed.LocalCluster
    if getattr(multiprocessing.current_process(), "_inheriting", False):
        raise ValidationError(_SPAWN_HINT)  # a worker process re-importing the user's script
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
    # The workers' scratch space (dask-scratch-space/ in the temporary folder by default, which Dask
    # leaves behind) goes into a folder of this cluster's own, removed once the cluster is closed.
    scratch = tempfile.mkdtemp(prefix="seed2gs-batch-")
    try:
        with dask.config.set({"distributed.scheduler.allowed-failures": 0,
                              "distributed.scheduler.worker-saturation": 1.0,
                              "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                              "distributed.worker.daemon": False,
                              "temporary-directory": scratch,
                              # Ctrl-C reaches the whole process group: the workers (also those a nanny
                              # starts again) leave it to this process, which closes the cluster
                              "distributed.worker.preload": [_WORKER_PRELOAD]}):
            try:
                cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                                       dashboard_address=":0",  # a free port: never "8787 is in use"
                                       silence_logs=logging.ERROR, env=env)
            except RuntimeError as exc:
                reason = str(exc).rstrip(".")
                raise ValidationError(f"could not start the embedded Dask workers ({reason}). "
                                      f"{_SPAWN_HINT}") from exc
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
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


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
