"""Many extractions at once: jobs files and the Dask batch runner.

::

    import seed2gs_inverse as sgi
    jobs = sgi.read_jobs("jobs.toml")
    results = sgi.extract_many(jobs, output="results/")        # the faster layout for this machine
    results = sgi.extract_many(jobs, "tcp://head:8786", output="results/")  # a cluster

See :mod:`.jobs` for the jobs file, :mod:`.runner` for scheduling, failures,
retries and resume, :mod:`.cluster` for where jobs run, :mod:`.summary` for
the results directory, and :mod:`.worker` for what runs on a worker.
"""

from .cluster import Layout, batch_client, choose_layout, open_layout, resolve_layout
from .jobs import Job, extract_option_names, jobs_from_table, read_jobs
from .runner import extract_many
from .summary import SUMMARY_COLUMNS
from .worker import JobResult, run_job

__all__ = ["Job", "JobResult", "read_jobs", "jobs_from_table", "extract_option_names", "extract_many",
           "batch_client", "Layout", "choose_layout", "resolve_layout", "open_layout", "run_job", "SUMMARY_COLUMNS"]
