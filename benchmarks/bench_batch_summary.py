"""Batch bookkeeping time against the number of jobs: the summary rewritten after every job vs the journal.

For each size N, N simulated job records (as a batch of real extraction jobs
writes them: every stage's seconds, a prompt, a camera) are recorded in a
fresh results directory in two ways:

* ``rewrite``: ``summary.json`` and ``summary.csv`` rewritten, atomically,
  after every job (the bookkeeping of earlier versions): the cost of job i
  grows with i, so the total grows with N squared. Above ``--full-max``
  jobs it is estimated from ``--samples`` rewrites at sizes spread over
  1..N (trapezoid rule) and marked ``(est.)``;
* ``journal``: one line appended to ``summary.journal`` per job
  (:class:`~seed2gs_inverse.batch.summary.JobJournal`), and the summary
  written once at the end (:func:`~seed2gs_inverse.batch.summary.write_summary`).

Usage::

    python benchmarks/bench_batch_summary.py [--sizes 100,1000,10000] [--full-max 1000] [--samples 12]

The machine's load is printed with the results: the times are wall
seconds, and another process's work slows them.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import load_average  # noqa: E402

from seed2gs_inverse._atomic import write_files  # noqa: E402
from seed2gs_inverse.batch.summary import (STAGES, SUMMARY_COLUMNS, JobJournal, result_counts,  # noqa: E402
                                           write_summary)
from seed2gs_inverse.batch.worker import JobResult  # noqa: E402


def _record(i: int) -> JobResult:
    return JobResult(name=f"job-{i:06d}", status="done", scene=f"/data/scenes/scene_{i % 17}.ply",
                     camera=f"/data/scenes/cams_{i % 17}.json:{i % 40}",
                     prompt={"kind": "box", "box": [10, 20, 300, 400], "iterations": 5},
                     n_gaussians=1_200_000, n_selected=35_000 + i, n_views=24,
                     seconds={s: 0.5 + (i % 7) * 0.1 for s in STAGES}, total_seconds=12.3,
                     worker="tcp://127.0.0.1:40000", attempts=1, peak_rss_mb=2048.0,
                     outdir=f"/results/job-{i:06d}", fingerprint=f"{i:064x}")


def _rewrite_once(out: Path, results: list, meta: dict) -> None:
    """The summary as earlier versions rewrote it after each job: every record, both files."""
    rows = [r.to_dict() for r in results]
    doc = {"meta": meta, "counts": result_counts(results), "jobs": rows}
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*SUMMARY_COLUMNS, *(f"seconds_{s}" for s in STAGES)])
    for d in rows:
        cells = [json.dumps(d.get(c), sort_keys=True) if isinstance(d.get(c), dict) else
                 ("" if d.get(c) is None else d.get(c)) for c in SUMMARY_COLUMNS]
        cells += [f"{d['seconds'][s]:.3f}" if s in d["seconds"] else "" for s in STAGES]
        w.writerow(cells)
    write_files([(out / "summary.json", json.dumps(doc, indent=1).encode("utf-8")),
                 (out / "summary.csv", buf.getvalue().encode("utf-8"))])


def rewrite_seconds(records: list, full_max: int, samples: int) -> tuple:
    """``(seconds, estimated)`` of rewriting the summary after each of ``records``."""
    n = len(records)
    meta = {"n_jobs": n}
    with tempfile.TemporaryDirectory() as d:
        out = Path(d)
        if n <= full_max:
            t0 = time.perf_counter()
            for i in range(1, n + 1):
                _rewrite_once(out, records[:i], meta)
            return time.perf_counter() - t0, False
        sizes = sorted({max(1, round(n * k / (samples - 1))) for k in range(samples)})
        cost = []
        for i in sizes:
            t0 = time.perf_counter()
            _rewrite_once(out, records[:i], meta)
            cost.append(time.perf_counter() - t0)
        total = sum((b - a) * (ca + cb) / 2 for a, b, ca, cb in zip(sizes, sizes[1:], cost, cost[1:]))
        return total + cost[0], True


def journal_seconds(records: list) -> tuple:
    """``(seconds of the appends, seconds of the final summary)`` for ``records``."""
    with tempfile.TemporaryDirectory() as d:
        out = Path(d)
        t0 = time.perf_counter()
        journal = JobJournal(out)
        for r in records:
            journal.append(r)
        journal.close()
        t1 = time.perf_counter()
        write_summary(out, records, {"n_jobs": len(records)})
        return t1 - t0, time.perf_counter() - t1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="100,1000,10000", help="job counts, comma-separated")
    ap.add_argument("--full-max", type=int, default=1000,
                    help="largest size whose per-job rewrites are all timed (above: estimated)")
    ap.add_argument("--samples", type=int, default=12, help="rewrites timed to estimate a larger size")
    args = ap.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    print(f"load average (1 min) at start: {load_average():.2f}")
    print(f"{'jobs':>7} {'rewrite per job (s)':>22} {'journal appends (s)':>20} {'final summary (s)':>18} "
          f"{'per job, journal (ms)':>22}")
    for n in sizes:
        records = [_record(i) for i in range(n)]
        rewrite, est = rewrite_seconds(records, args.full_max, args.samples)
        appends, final = journal_seconds(records)
        label = f"{rewrite:.2f}" + (" (est.)" if est else "")
        print(f"{n:>7} {label:>22} {appends:>20.3f} {final:>18.3f} {1e3 * appends / n:>22.3f}")
    print(f"load average (1 min) at end: {load_average():.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
