"""``extract_many``: run a batch of extraction jobs on Dask (``dask.distributed``) or in this process.

Where the jobs run is the ``client`` argument (:mod:`.cluster`): by default
the faster layout for the machine and the batch (one job after the other in
this process, with every core's threads, or an embedded ``LocalCluster``
sized to the machine), an existing cluster, or either layout asked for.

Jobs are submitted grouped by scene, all at once as one task group that
the scheduler hands out from its own queue as threads come free (so no
worker idles while another holds queued jobs), and each worker process
keeps the scenes it read (:mod:`.worker`), so a scene is read once per
worker, not once per job. With an output directory every job writes its folder
atomically (as ``seed2gs extract -o`` does), the runner appends each finished
job to the directory's journal and folds it into ``summary.csv`` /
``summary.json`` at the end (:mod:`.summary`; a journal left by a killed run
is folded when the next run starts), so an interrupted batch leaves a
consistent record. The runner holds the directory's lock
(:func:`~seed2gs_inverse._atomic.output_lock` on its ``summary.json``) for
the whole run: a second batch into the same directory stops at once with an
error naming the first.

Failures: a job that raises is recorded as ``failed`` with its message and
the batch goes on; a job whose worker process dies (killed, out of memory)
is submitted once more, and recorded as failed if that worker dies too.
Resume: a job whose folder exists and whose summary line says ``done`` for
the same job description (:meth:`Job.fingerprint`) is skipped.
"""

from __future__ import annotations

from collections import Counter

import os
import sys
import time
import uuid
from contextlib import ExitStack
from pathlib import Path

from tqdm import tqdm

from .._atomic import not_an_earlier_output, output_lock
from .._validation import check_int
from ..errors import ValidationError
from ..progress import Feedback
from .cluster import Layout, batch_client, dashboard_address, open_layout, resolve_layout
from .jobs import Job, read_jobs
from .summary import (SUMMARY_COLUMNS, JobJournal, check_output_dir, fold_journal, is_batch_folder, read_summary,
                      remove_folder, write_summary)
from .worker import JobResult, clear_scene_cache, run_job

__all__ = ["extract_many", "batch_client", "check_output_dir", "SUMMARY_COLUMNS"]


def _as_jobs(jobs) -> list[Job]:
    """``jobs`` as a list of Job: read from a jobs file, or checked (not empty, Jobs, unique names)."""
    if isinstance(jobs, (str, os.PathLike)):
        return read_jobs(jobs)
    out = list(jobs)
    if not out:
        raise ValidationError("extract_many: no jobs given")
    for i, j in enumerate(out):
        if not isinstance(j, Job):
            raise ValidationError(f"extract_many: jobs[{i}] is a {type(j).__name__}, not a Job")
    # folder names: one folder on a case-insensitive file system
    counts = Counter(j.name.casefold() for j in out)
    dup = sorted({j.name for j in out if counts[j.name.casefold()] > 1})
    if dup:
        raise ValidationError(f"extract_many: job names must be unique, also ignoring case (they name folders); "
                              f"repeated: {dup}")
    return out


def extract_many(jobs, client=None, *, output=None, n_workers: int | None = None,
                 threads_per_worker: int | None = None, resume: bool = True, progress: bool | str | None = None,
                 retries: int = 1, log=None) -> list[JobResult]:
    """Run many extractions, on a Dask cluster or in this process.

    Parameters
    ----------
    jobs : sequence of Job, or path of a jobs file
        See :mod:`seed2gs_inverse.batch.jobs` (``read_jobs``).
    client : None, "sequential", str, distributed.Client or Layout
        Where to run (:mod:`.cluster`): None runs the faster layout for
        this machine and batch (:func:`~.cluster.choose_layout`: one
        process with every core's threads, or an embedded ``LocalCluster``
        of one worker per core), or the embedded cluster when
        ``n_workers`` or ``threads_per_worker`` is given; a
        :class:`~.cluster.Layout` yielded by :func:`~.cluster.open_layout`
        runs there. The layout is printed with ``log`` and recorded in
        ``summary.json``'s ``meta.layout``.
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
        run of that name is removed). Another batch running into
        ``output`` is an error that names its process.
    n_workers : int, optional
        Worker processes of the embedded cluster.
    threads_per_worker : int, optional
        Numba (and numpy/scipy pass) threads per worker of the embedded
        cluster; default: the cores shared out, so nothing oversubscribes.
    resume : bool
        Skip jobs already done in ``output`` (same description); False runs
        every job again, replacing its folder.
    progress : None, bool, "bars" or "lines"
        What the batch says on stderr while it runs
        (:meth:`~seed2gs_inverse.progress.Feedback.of`): ``"bars"`` (or
        True) one overall progress bar; ``"lines"`` one line per finished
        job with its status, seconds and counts (or its error); False
        nothing. Default None: the bar when stderr is a terminal, else
        nothing. The jobs themselves run quietly (``progress=False``).
    retries : int
        Extra attempts for a job whose worker process died (default 1).
    log : callable, optional
        ``log(str)`` for the layout, the dashboard address and similar
        notes (default: print to stderr with bars or lines).

    Returns
    -------
    list of JobResult
        In the order of ``jobs``. Failed jobs carry their error; no job
        error raises.

    Raises
    ------
    ValidationError
        Bad jobs or arguments, an output directory the batch may not write
        (see ``output``), or a cluster that cannot be reached or started.
    """
    jobs = _as_jobs(jobs)
    check_int("retries", retries, lo=0)
    check_int("n_workers", n_workers, lo=1, optional=True)
    if (n_workers is not None or threads_per_worker is not None) and client is not None:
        raise ValidationError(f"{'n_workers' if n_workers is not None else 'threads_per_worker'} sizes the "
                              f"embedded cluster; it does not go with a client, a scheduler address, a layout "
                              f"or 'sequential'")
    if isinstance(client, Layout) and client.kind != "sequential" and client.client is None:
        raise ValidationError("client: a Layout of Dask workers must be opened first (with open_layout)")
    feedback = Feedback.of(progress)
    if log is None:
        def log(msg):
            if feedback.bars or feedback.lines:
                print(msg, file=sys.stderr)

    created = False
    try:
        with ExitStack() as held:
            out, owned, created = _open_output(output, jobs, held)
            return _extract_many(jobs, client, out, owned, resume=resume, n_workers=n_workers,
                                 threads_per_worker=threads_per_worker, feedback=feedback, retries=retries, log=log)
    except BaseException:
        # Nothing ran (no cluster, no scheduler): leave no empty results directory behind.
        if created and not any(out.iterdir()):
            out.rmdir()
        raise


def _extract_many(jobs, client, out, owned, *, resume, n_workers, threads_per_worker, feedback, retries,
                  log) -> list:
    """:func:`extract_many` once the results directory (if any) is open and locked."""
    results, todo = _split_resumed(jobs, out, owned if resume else {})
    if out is not None:
        _check_rewrites(out, todo)
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
        write_summary(out, [results[j.name] for j in jobs if j.name in results] + kept, meta)

    def record(res: JobResult):
        results[res.name] = res
        if feedback.lines:
            feedback.step(_job_line(res, len(results), len(jobs)))
        if bar is not None:
            bar.update(1)
            n_failed = sum(r.status == "failed" for r in results.values())
            if n_failed:
                bar.set_postfix(failed=n_failed)
        if out is not None:
            if res.status != "done" and (out / res.name).is_dir() and is_batch_folder(out / res.name, owned):
                remove_folder(out / res.name)  # an earlier run's result for another description
            journal.append(res)  # the summary is written once, at the end (or by the next run after a kill)

    bar = (tqdm(total=len(jobs), initial=len(results), desc="jobs", unit="job", file=sys.stderr) if feedback.bars
           else None)
    journal = None if out is None else JobJournal(out)
    finished = False
    try:
        _run_jobs(todo, client, out, record, meta, n_workers=n_workers, threads_per_worker=threads_per_worker,
                  retries=retries, log=log)
        finished = True
    finally:
        if bar is not None:
            bar.close()
        if journal is not None:
            journal.close()
            if finished or journal.count:
                summary()  # also when interrupted: the jobs finished so far
            else:
                journal.path.unlink(missing_ok=True)  # nothing recorded
    return [results[j.name] for j in jobs]


def _job_line(res: JobResult, k: int, n: int) -> str:
    """``[k/n] job NAME: done in 12.3 s (412 of 50,000 Gaussians, 25 views)``, or ``failed ...: ERROR``."""
    head = f"[{k}/{n}] job {res.name}: "
    if res.status != "done":
        return head + f"failed after {res.total_seconds:.1f} s: {res.error}"
    facts = []  # what the result holds (a result from elsewhere may lack them)
    if res.n_selected is not None and res.n_gaussians is not None:
        facts.append(f"{res.n_selected:,} of {res.n_gaussians:,} Gaussians")
    if res.n_views is not None:
        facts.append(f"{res.n_views} views")
    compiled = float((res.seconds or {}).get("compile", 0.0))
    tail = ", ".join(facts) + (f"; {compiled:.1f} s compiling the kernels" if compiled > 0 else "")
    return head + f"done in {res.total_seconds:.1f} s" + (f" ({tail})" if tail else "")


def _open_output(output, jobs: list, held: ExitStack) -> tuple:
    """``(out, owned, created)``: the results directory (absolute; None without ``output``), the
    summary entries of earlier runs there, and whether this run creates the directory.

    The directory's lock is taken on ``held`` (released when it closes), then
    a journal left by a killed run is folded into the summary.

    Raises
    ------
    ValidationError
        The directory cannot be written, another process holds its lock, its
        summary is not a batch's, or it holds a job's folder that no earlier
        batch wrote.
    """
    if output is None:
        return None, {}, False
    out = check_output_dir(output)
    created = not out.exists()
    out = out.resolve()  # workers may run elsewhere: give them an absolute path
    out.mkdir(exist_ok=True)
    try:
        with ExitStack() as lock:
            lock.enter_context(output_lock(out / "summary.json", f"output {out}"))
            fold_journal(out)  # a killed run's finished jobs
            owned = read_summary(out)
            foreign = [j.name for j in jobs if (out / j.name).exists() and not is_batch_folder(out / j.name, owned)]
            if foreign:
                raise ValidationError(
                    f"output {out} already holds {', '.join(foreign)}, which no earlier batch there wrote "
                    f"(not in its summary.json): move {'it' if len(foreign) == 1 else 'them'} away, rename the "
                    f"job{'' if len(foreign) == 1 else 's'}, or choose another output directory")
            held.push(lock.pop_all())
    except BaseException:
        if created and not any(out.iterdir()):
            out.rmdir()
        raise
    return out, owned, created


def _split_resumed(jobs: list, out: Path | None, previous: dict) -> tuple:
    """``(results, todo)``: the results of the jobs done earlier with the same description
    (marked resumed, by name) and the jobs left to run, in the order of ``jobs``."""
    results, todo = {}, []
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
    return results, todo


def _check_rewrites(out: Path, todo: list) -> None:
    """Raise unless every job folder this run rewrites holds nothing but a job's output (user files stay)."""
    mixed = {j.name: why for j in todo if (out / j.name).is_dir()
             and (why := not_an_earlier_output(out / j.name, "extract")) is not None}
    if mixed:
        raise ValidationError(f"output {out}: the job folder{'s' if len(mixed) > 1 else ''} "
                              + "; ".join(f"{n} ({why})" for n, why in mixed.items())
                              + f" would be replaced by this run: move those files away, rename the "
                              f"job{'s' if len(mixed) > 1 else ''}, or choose another output directory")


def _run_jobs(todo: list, client, out: Path | None, record, meta: dict, *, n_workers, threads_per_worker, retries,
              log) -> None:
    """Run ``todo`` where ``client`` says (:func:`~.cluster.resolve_layout`), passing each JobResult to ``record``.

    The layout is printed with ``log``; ``meta["where"]`` and ``meta["layout"]`` record it before the
    first job runs (so every summary written records it).
    """
    if not todo:  # every job resumed: nothing to run, so no cluster is started for it
        meta["where"] = "nothing to run (every job resumed)"
        return
    with ExitStack() as held:
        if isinstance(client, Layout):  # chosen and opened by the caller
            layout = client
        else:
            layout = held.enter_context(open_layout(resolve_layout(
                client, n_workers=n_workers, n_jobs=len(todo), threads_per_worker=threads_per_worker)))
        meta["layout"] = layout.record()
        log(layout.describe(len(todo)))
        c = layout.client
        if c is None:
            meta["where"] = "sequential"
            try:
                for job in todo:
                    record(run_job(job, out))
            finally:
                clear_scene_cache()
        else:
            meta["where"] = f"dask {c.scheduler.address} ({len(c.scheduler_info()['workers'])} workers)"
            link = dashboard_address(c)
            if link:
                log(f"Dask dashboard: {link}")
            _run_on_dask(c, todo, out, retries, record)


def _run_on_dask(client, todo, out, retries, record) -> None:
    """Submit every job at once as one task group; collect results as they finish, resubmit jobs of dead workers.

    Dask places a task on a worker as soon as it arrives, by an estimate of
    its duration, unless it belongs to a large group of tasks without
    dependencies ("root-ish": more tasks than twice the cluster's threads),
    which the scheduler keeps in its own queue and hands out, in submission
    order, as threads come free. Extraction jobs take from a second to a
    minute, so placing them early lets a worker sit idle while another holds
    queued jobs behind a long one (measured by ``benchmarks/bench_batch.py``).
    So every job's key
    starts with the same name (``("seed2gs-extract", job name, attempt,
    token)``) and all are submitted in one call: one group from the start. The scheduler sees
    the whole batch, so an adaptive cluster scales to it.
    """
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
