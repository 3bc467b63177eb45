"""``extract_many``: run a batch of extraction jobs on Dask (``dask.distributed``).

Where the jobs run (``client``):

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
    one job after the other in this process, without Dask (debugging,
    and the baseline of ``benchmarks/bench_batch.py``).

Jobs are submitted grouped by scene, all at once as one task group that
the scheduler hands out from its own queue as threads come free (so no
worker idles while another holds queued jobs), and each worker process
keeps the scenes it read (:mod:`.worker`), so a scene is read once per
worker, not once per job. With an output directory every job writes its folder
atomically (as ``seed2gs extract -o`` does) and the runner keeps
``summary.csv`` / ``summary.json`` up to date after every job (each
rewritten atomically), so an interrupted batch leaves a consistent record.

Failures: a job that raises is recorded as ``failed`` with its message and
the batch goes on; a job whose worker process dies (killed, out of memory)
is submitted once more, and recorded as failed if that worker dies too.
Resume: a job whose folder exists and whose summary line says ``done`` for
the same job description (:meth:`Job.fingerprint`) is skipped.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import multiprocessing
import os
import sys
import time
from contextlib import contextmanager
from pathlib import Path

from .._atomic import not_an_earlier_output
from ..errors import ValidationError
from .jobs import Job, read_jobs
from .worker import JobResult, clear_scene_cache, run_job

__all__ = ["extract_many", "batch_client", "check_output_dir", "SUMMARY_COLUMNS"]

#: Columns of ``summary.csv`` (per-stage seconds follow as ``seconds_<stage>``).
SUMMARY_COLUMNS = ("name", "status", "n_gaussians", "n_selected", "n_views", "total_seconds", "worker",
                   "attempts", "scene_cached", "peak_rss_mb", "scene", "prompt", "outdir", "error")
_STAGES = ("read", "camera", "render", "grounding", "lift", "vaas", "tracking", "operators", "solve", "write")


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _has_dashboard() -> bool:
    try:
        import bokeh  # noqa: F401 - the dashboard needs it
    except ImportError:
        return False
    return True


_SPAWN_HINT = ("If a script calls extract_many at its top level: worker processes start by importing the "
               "script, so each would start the batch again; put that code under "
               "'if __name__ == \"__main__\":', or run with client=\"sequential\"")


@contextmanager
def batch_client(client=None, n_workers: int | None = None, n_jobs: int | None = None,
                 threads_per_worker: int | None = None):
    """Yield a :class:`distributed.Client` for a batch (see the module docstring).

    ``client`` None starts an embedded ``LocalCluster`` (closed on exit) of
    ``n_workers`` processes (default: one per core, at most ``n_jobs``),
    each with ``NUMBA_NUM_THREADS`` = ``threads_per_worker`` (default: cores
    // workers, capped by a ``NUMBA_NUM_THREADS`` set here); a scheduler
    address connects to it (the connection is closed on exit); a ``Client``
    is used as is. ``"sequential"`` yields None.
    """
    if isinstance(client, str) and client == "sequential":
        yield None
        return
    try:
        import dask
        from distributed import Client, LocalCluster
    except ImportError:  # pragma: no cover - a declared dependency
        raise ValidationError("batch extraction needs dask.distributed: pip install 'dask[distributed]'") from None
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
    cores = _cores()
    if n_workers is None:
        n_workers = max(1, min(cores, n_jobs or cores))
    n_workers = int(n_workers)
    if n_workers < 1:
        raise ValidationError(f"n_workers must be >= 1, got {n_workers}")
    if threads_per_worker is None:
        threads = max(1, cores // n_workers)
        user_cap = os.environ.get("NUMBA_NUM_THREADS", "").strip()
        if user_cap.isdigit() and int(user_cap) >= 1:
            threads = min(threads, int(user_cap))
    elif isinstance(threads_per_worker, bool) or not isinstance(threads_per_worker, int) or threads_per_worker < 1:
        raise ValidationError(f"threads_per_worker must be a whole number >= 1, got {threads_per_worker!r}")
    else:
        threads = threads_per_worker
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
    # is mapped and zeroed afresh, and the solve stage was slower in a worker
    # than in the main process. The workers keep glibc's defaults.
    with dask.config.set({"distributed.scheduler.allowed-failures": 0,
                          "distributed.scheduler.worker-saturation": 1.0,
                          "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                          "distributed.worker.daemon": False,
                          # Ctrl-C reaches the whole process group: the workers (also those a nanny
                          # starts again) leave it to this process, which closes the cluster
                          "distributed.worker.preload": ["seed2gs_inverse.batch._worker_preload"]}):
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


def _dashboard(client) -> str | None:
    """The dashboard's address, when one is being served.

    The scheduler's HTTP server always runs (health, metrics); its dashboard
    pages need bokeh, which for an embedded cluster is this environment's.
    An existing scheduler (``dask scheduler --no-dashboard``, or one without
    bokeh) is asked for the page itself (:func:`_serves`); a link that is
    not an http(s) address (a relative JupyterHub proxy path) is given as
    configured.
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
    import threading
    from urllib.request import ProxyHandler, build_opener

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


def _as_jobs(jobs) -> list[Job]:
    if isinstance(jobs, (str, os.PathLike)):
        return read_jobs(jobs)
    out = list(jobs)
    if not out:
        raise ValidationError("extract_many: no jobs given")
    for i, j in enumerate(out):
        if not isinstance(j, Job):
            raise ValidationError(f"extract_many: jobs[{i}] is a {type(j).__name__}, not a Job")
    names = [j.name.casefold() for j in out]  # folder names: one folder on a case-insensitive file system
    dup = sorted({j.name for j in out if names.count(j.name.casefold()) > 1})
    if dup:
        raise ValidationError(f"extract_many: job names must be unique, also ignoring case (they name folders); "
                              f"repeated: {dup}")
    return out


# ---------------------------------------------------------------------------
# summary files
# ---------------------------------------------------------------------------
def _read_summary(output: Path) -> dict:
    """Entries of the batch summary in ``output`` by job name ({} when there is none).

    Every folder a batch wrote has its entry there, so these are the folders the
    runner may replace. A ``summary.json`` that is not a batch summary is an error:
    the directory is someone else's.
    """
    p = output / "summary.json"
    if not p.exists():
        _check_summary_csv(output / "summary.csv")
        return {}
    try:
        doc = json.loads(p.read_text("utf-8"))
        entries = doc["jobs"]
        # entries the runner can read back (a hand-edited line without them is dropped, not a crash)
        return {d["name"]: d for d in entries if isinstance(d, dict) and isinstance(d.get("name"), str)
                and d.get("status") in ("done", "failed")}
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, RecursionError) as exc:
        raise ValidationError(f"{p} is not the summary of a seed2gs batch ({type(exc).__name__}: {exc}); "
                              f"choose another output directory, or move that file away") from None


def _check_summary_csv(path: Path) -> None:
    """Raise unless ``path`` is missing or begins with the batch's own header (it is replaced)."""
    if not path.exists():
        return
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            header = next(csv.reader(fh), [])
    except (OSError, UnicodeDecodeError, csv.Error):
        header = []
    if header[:len(SUMMARY_COLUMNS)] != list(SUMMARY_COLUMNS):
        raise ValidationError(f"{path} is not the summary of a seed2gs batch (not its columns); choose another "
                              f"output directory, or move that file away")


def _batch_folder(path: Path) -> bool:
    """Whether ``path`` is a job folder a batch wrote (its report.json names the job), listed in the
    summary or not (a worker may finish a job after an interrupted runner stopped recording)."""
    try:
        report = json.loads((path / "report.json").read_text("utf-8"))
        return isinstance(report, dict) and isinstance(report.get("batch"), dict) and \
            report["batch"].get("job") == path.name
    except (OSError, UnicodeDecodeError, ValueError):
        return False


def _ours(path: Path, summary: dict) -> bool:
    """Whether the job folder ``path`` is the batch's to replace: the summary lists it as done (a failed
    entry has no folder: one there now is someone else's), or its report.json names the job."""
    entry = summary.get(path.name)
    return (entry is not None and entry.get("status") == "done") or _batch_folder(path)


def check_output_dir(path, what: str = "output") -> Path:
    """``path`` as a Path once a directory can be written there; else a ValidationError naming it.

    The parent must exist (nothing is created above the output), an existing
    ``path`` must be a directory, and a file can be created in it (or in its
    parent, when it does not exist yet): checked by creating and removing a
    probe file, so that ``/proc/x`` or a read-only mount fails before any work.
    """
    from .._atomic import check_writable

    out = Path(os.fspath(path))
    if not str(path):
        raise ValidationError(f"{what}: the path is empty")
    if out.exists() and not out.is_dir():
        raise ValidationError(f"{what} {out} exists and is not a directory")
    parent = out.resolve().parent
    if not parent.is_dir():
        raise ValidationError(f"{what} {out}: the directory {parent} does not exist (create it first)")
    check_writable(out if out.is_dir() else parent, f"{what} {out}")
    return out


def _remove_folder(path: Path) -> None:
    """Take a job folder out of the results at once (a rename), then delete it."""
    import shutil
    import tempfile

    old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
    os.replace(path, old / "previous")
    shutil.rmtree(old, ignore_errors=True)


def _write_summary(output: Path, results: list, meta: dict) -> None:
    from .._atomic import write_files

    rows = [r.to_dict() for r in results]
    doc = {"meta": meta, "counts": _counts(results), "jobs": rows}
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*SUMMARY_COLUMNS, *(f"seconds_{s}" for s in _STAGES)])
    for d in rows:
        cells = []
        for col in SUMMARY_COLUMNS:
            v = d.get(col)
            cells.append(json.dumps(v, sort_keys=True) if isinstance(v, dict) else ("" if v is None else v))
        cells += [f"{d['seconds'][s]:.3f}" if s in d["seconds"] else "" for s in _STAGES]
        w.writerow(cells)
    write_files([(output / "summary.json", json.dumps(doc, indent=1).encode("utf-8")),
                 (output / "summary.csv", buf.getvalue().encode("utf-8"))])


def _counts(results) -> dict:
    return {"jobs": len(results), "done": sum(r.status == "done" for r in results),
            "failed": sum(r.status == "failed" for r in results),
            "resumed": sum(bool(r.resumed) for r in results)}


# ---------------------------------------------------------------------------
# the runner
# ---------------------------------------------------------------------------
def extract_many(jobs, client=None, *, output=None, n_workers: int | None = None,
                 threads_per_worker: int | None = None, resume: bool = True, progress: bool | None = None,
                 retries: int = 1, log=None) -> list[JobResult]:
    """Run many extractions, on a Dask cluster or in this process.

    Parameters
    ----------
    jobs : sequence of Job, or path of a jobs file
        See :mod:`seed2gs_inverse.batch.jobs` (``read_jobs``).
    client : None, "sequential", str or distributed.Client
        Where to run (module docstring): None starts an embedded
        ``LocalCluster`` sized to the machine.
    output : path, optional
        Results directory (created if its parent exists): one folder per
        job plus ``summary.csv`` / ``summary.json``. None writes nothing and
        keeps each job's ``q`` in its result. The summary keeps the entries
        of earlier runs' jobs that this run does not name. A folder is only
        replaced when a batch wrote it (the summary lists it, or its
        ``report.json`` names the job: a worker may finish a job after an
        interrupted runner stopped recording); any other existing
        ``output/<name>`` is an error, as is a ``summary.json`` that is not
        a batch's. A job that fails leaves no folder (one from an earlier
        run of that name is removed).
    n_workers : int, optional
        Worker processes of the embedded cluster.
    threads_per_worker : int, optional
        Numba (and numpy/scipy pass) threads per worker of the embedded
        cluster; default: the cores shared out, so nothing oversubscribes.
    resume : bool
        Skip jobs already done in ``output`` (same description); False runs
        every job again, replacing its folder.
    progress : bool, optional
        One overall progress bar on stderr; default: only when stderr is a
        terminal.
    retries : int
        Extra attempts for a job whose worker process died (default 1).
    log : callable, optional
        ``log(str)`` for the dashboard address and similar notes (default:
        print to stderr when ``progress``).

    Returns
    -------
    list of JobResult
        In the order of ``jobs``. Failed jobs carry their error; no job
        error raises.
    """
    jobs = _as_jobs(jobs)
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ValidationError(f"retries must be a whole number >= 0, got {retries!r}")
    if n_workers is not None and (isinstance(n_workers, bool) or not isinstance(n_workers, int) or n_workers < 1):
        raise ValidationError(f"n_workers must be a whole number >= 1, got {n_workers!r}")
    if n_workers is not None and client is not None:
        raise ValidationError("n_workers sizes the embedded cluster; it does not go with a client, "
                              "a scheduler address or 'sequential'")
    if progress is None:
        progress = bool(getattr(sys.stderr, "isatty", lambda: False)())
    if log is None:
        def log(msg):
            if progress:
                print(msg, file=sys.stderr)

    out = None
    owned = {}  # summary entries of earlier runs
    created = False
    if output is not None:
        out = check_output_dir(output)
        created = not out.exists()
        out = out.resolve()  # workers may run elsewhere: give them an absolute path
        owned = _read_summary(out)
        foreign = [j.name for j in jobs if (out / j.name).exists() and not _ours(out / j.name, owned)]
        if foreign:
            raise ValidationError(
                f"output {out} already holds {', '.join(foreign)}, which no earlier batch there wrote "
                f"(not in its summary.json): move {'it' if len(foreign) == 1 else 'them'} away, rename the "
                f"job{'' if len(foreign) == 1 else 's'}, or choose another output directory")
        out.mkdir(exist_ok=True)
    previous = owned if resume else {}

    results: dict = {}
    todo = []
    for job in jobs:
        prev = previous.get(job.name)
        if (prev is not None and prev.get("status") == "done" and prev.get("fingerprint") == job.fingerprint()
                and (out / job.name / "report.json").is_file()):
            r = JobResult.from_dict(prev)
            r.resumed = True
            r.outdir = os.fspath(out / job.name)  # here, also when the directory was moved or copied since
            results[job.name] = r
        else:
            todo.append(job)
    if out is not None:  # a folder this run rewrites must hold nothing but a job's output (user files stay)
        mixed = {j.name: why for j in todo if (out / j.name).is_dir()
                 and (why := not_an_earlier_output(out / j.name, "extract")) is not None}
        if mixed:
            raise ValidationError(f"output {out}: the job folder{'s' if len(mixed) > 1 else ''} "
                                  + "; ".join(f"{n} ({why})" for n, why in mixed.items())
                                  + f" would be replaced by this run: move those files away, rename the "
                                  f"job{'s' if len(mixed) > 1 else ''}, or choose another output directory")
    names = {j.name for j in jobs}
    kept = [JobResult.from_dict(d) for n, d in owned.items() if n not in names]  # jobs this run does not name
    for r in kept:
        if r.outdir is not None:
            r.outdir = os.fspath(out / r.name)
    # Grouped by scene, first-seen order: each worker then meets each scene once.
    order = {}
    for job in todo:
        order.setdefault(job.scene, len(order))
    todo.sort(key=lambda j: order[j.scene])

    meta = {"n_jobs": len(jobs), "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "where": None}

    def summary():
        _write_summary(out, [results[j.name] for j in jobs if j.name in results] + kept, meta)

    def record(res: JobResult):
        results[res.name] = res
        if bar is not None:
            bar.update(1)
            n_failed = sum(r.status == "failed" for r in results.values())
            if n_failed:
                bar.set_postfix(failed=n_failed)
        if out is not None:
            if res.status != "done" and (out / res.name).is_dir() and _ours(out / res.name, owned):
                _remove_folder(out / res.name)  # an earlier run's result for another description
            summary()

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(jobs), initial=len(results), desc="jobs", unit="job", file=sys.stderr)
    try:
        # every job resumed: nothing to run, so no cluster is started for it
        with batch_client(client if todo else "sequential", n_workers=n_workers, n_jobs=len(todo),
                          threads_per_worker=threads_per_worker) as c:
            if not todo:
                meta["where"] = "nothing to run (every job resumed)"
            elif c is None:
                meta["where"] = "sequential"
                try:
                    for job in todo:
                        record(run_job(job, out))
                finally:
                    clear_scene_cache()
            else:
                meta["where"] = f"dask {c.scheduler.address} ({len(c.scheduler_info()['workers'])} workers)"
                link = _dashboard(c)
                if link:
                    log(f"Dask dashboard: {link}")
                _run_on_dask(c, todo, out, retries, record)
    except BaseException:
        # Nothing ran (no cluster, no scheduler): leave no empty results directory behind.
        if created and out is not None and not any(out.iterdir()):
            out.rmdir()
        raise
    finally:
        if bar is not None:
            bar.close()
    if out is not None and not todo:
        summary()
    return [results[j.name] for j in jobs]


def _run_on_dask(client, todo, out, retries, record) -> None:
    """Submit every job at once as one task group; collect results as they finish, resubmit jobs of dead workers.

    Dask places a task on a worker as soon as it arrives, by an estimate of
    its duration, unless it belongs to a large group of tasks without
    dependencies ("root-ish": more tasks than twice the cluster's threads),
    which the scheduler keeps in its own queue and hands out, in submission
    order, as threads come free. Extraction jobs take from a second to a
    minute, so placing them early let a worker sit idle while another held
    queued jobs behind a long one (``benchmarks/bench_batch.py`` showed
    workers idle for about a second per job that way). So every job's key
    starts with the same name (``("seed2gs-extract", job name, attempt,
    token)``) and all are submitted in one call: one group from the start. The scheduler sees
    the whole batch, so an adaptive cluster scales to it.
    """
    import uuid

    from distributed import as_completed

    where = None if out is None else str(out)

    def key(job, attempt):
        return ("seed2gs-extract", job.name, attempt, uuid.uuid4().hex[:8])

    first = client.map(run_job, todo, [where] * len(todo), [1] * len(todo), key=[key(j, 1) for j in todo],
                       pure=False, retries=0)
    futures = {f: (job, 1) for f, job in zip(first, todo)}
    ac = as_completed(first)
    for fut in ac:
        job, attempt = futures.pop(fut)
        if fut.status == "finished":
            res = fut.result()
        else:
            # run_job catches every job error, so this is the infrastructure:
            # the worker process died under the task (KilledWorker) or the
            # connection to it was lost.
            exc = fut.exception()
            if attempt <= retries:
                new = client.submit(run_job, job, where, attempt + 1, key=key(job, attempt + 1), pure=False,
                                    retries=0)
                futures[new] = (job, attempt + 1)
                ac.add(new)
                fut.release()
                continue
            res = JobResult(name=job.name, status="failed", scene=job.scene, fingerprint=job.fingerprint(),
                            camera=job.to_dict()["camera"], prompt=job.to_dict()["prompt"],
                            attempts=attempt, worker="?",
                            error=f"{type(exc).__name__}: the worker died running this job "
                                  f"{attempt} time(s) ({str(exc).strip().splitlines()[0] if str(exc).strip() else ''})")
        fut.release()
        record(res)
