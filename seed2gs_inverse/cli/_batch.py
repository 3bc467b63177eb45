"""``seed2gs batch``: many extractions from a jobs file, on Dask."""

from __future__ import annotations

import sys
from pathlib import Path

from .._validation import check_int
from ..batch import extract_many, read_jobs
from ..batch.cluster import MIN_JOBS_FOR_WORKERS, SMALL_MACHINE_CORES, SMALL_MACHINE_MIN_JOBS
from ..errors import ValidationError
from ._common import add_feedback_arguments, feedback_progress

__all__ = ["register", "add_cluster_arguments", "client_from_args"]


def add_cluster_arguments(p) -> None:
    """--scheduler / --workers / --sequential, shared by ``batch`` and ``eval``."""
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT", default=None,
                       help="run on this Dask cluster ('dask scheduler' + 'dask worker'; the workers must "
                            "see the same paths) instead of an embedded one")
    where.add_argument("--sequential", action="store_true",
                       help="run the jobs one after the other in this process, with every core's threads, "
                            "without Dask")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="run on an embedded Dask cluster of N worker processes. Default: the faster layout "
                        "for this machine, printed when the batch starts: one process with every core's "
                        "threads, or one worker per core once the batch has at least %d jobs (%d on "
                        "%d cores or fewer; workers need the 'batch' extra)"
                        % (MIN_JOBS_FOR_WORKERS, SMALL_MACHINE_MIN_JOBS, SMALL_MACHINE_CORES))


def client_from_args(args):
    """The ``client`` of ``extract_many`` that --scheduler / --workers / --sequential ask for.

    Raises
    ------
    ValidationError
        ``--workers`` below 1, or given with ``--scheduler`` / ``--sequential``.
    """
    check_int("--workers", args.workers, lo=1, optional=True)
    if args.workers is not None and (args.scheduler or args.sequential):
        raise ValidationError("--workers sizes the embedded cluster; it does not go with "
                              "--scheduler or --sequential")
    return "sequential" if args.sequential else args.scheduler


def register(subparsers) -> None:
    """Add ``seed2gs batch`` to the command's subparsers."""
    p = subparsers.add_parser(
        "batch", help="run many extractions from a jobs file (in this process or on Dask)",
        description="Run every job of JOBS (TOML: [defaults] and [[jobs]] with scene, camera, one "
                    "prompt and extract options) and write one folder per job plus summary.csv and "
                    "summary.json into OUTDIR. Failed jobs are recorded and the others go on; "
                    "re-running the command skips the jobs already done.")
    p.add_argument("jobs", help="jobs file (.toml or .json)")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="results directory (created)")
    add_cluster_arguments(p)
    p.add_argument("--no-resume", action="store_true", help="run every job again, replacing its folder")
    add_feedback_arguments(p, "job")
    p.set_defaults(func=run)


def run(args) -> int:
    """Run ``seed2gs batch``: print the counts, and each failed job on stderr; 1 when a job failed."""
    client = client_from_args(args)
    jobs = read_jobs(args.jobs)  # every job checked before anything starts
    progress = feedback_progress(args)
    results = extract_many(jobs, client, output=args.output, n_workers=args.workers,
                           resume=not args.no_resume, progress=progress,
                           log=None if progress is False else (lambda msg: print(msg, file=sys.stderr)))
    failed = [r for r in results if r.status != "done"]
    resumed = sum(r.resumed for r in results)
    done = len(results) - len(failed)
    print(f"{len(results)} jobs: {done} done" + (f" ({resumed} by an earlier run)" if resumed else "")
          + f", {len(failed)} failed -> {Path(args.output) / 'summary.csv'}")
    for r in failed:
        print(f"  {r.name}: {r.error}", file=sys.stderr)
    return 1 if failed else 0
