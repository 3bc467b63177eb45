"""The results directory of a batch: its summary files, and which job folders are the batch's.

``summary.json`` (``{"meta", "counts", "jobs"}``, one record per job, as
:meth:`~seed2gs_inverse.batch.JobResult.to_dict` writes it) and
``summary.csv`` (:data:`SUMMARY_COLUMNS`, then ``seconds_<stage>``) are
rewritten together, atomically, at the end of a run. While it runs, each
finished job is appended as one JSON line to ``summary.journal``
(:class:`JobJournal`), in time independent of how many jobs came before;
:func:`read_summary` reads the journal on top of the summary, and
:func:`write_summary` folds it in, so a batch killed at any point leaves
a consistent record that the next run completes. :func:`write_summary`
re-reads the records on disk and keeps those of jobs it does not write, so
no job's record is lost to another writer. The summary is also the batch's
claim on the directory: a job folder is replaced only when the summary
lists it as done or its ``report.json`` names the job
(:func:`is_batch_folder`).
"""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from .._atomic import check_writable, write_files
from ..errors import ValidationError

__all__ = ["SUMMARY_COLUMNS", "STAGES", "JOURNAL", "JobJournal", "read_summary", "write_summary", "fold_journal",
           "is_batch_folder", "check_output_dir", "remove_folder", "result_counts"]

#: Columns of ``summary.csv`` (per-stage seconds follow as ``seconds_<stage>``).
SUMMARY_COLUMNS = ("name", "status", "n_gaussians", "n_selected", "n_views", "total_seconds", "worker",
                   "attempts", "scene_cached", "peak_rss_mb", "scene", "prompt", "outdir", "error")
#: The seconds ``summary.csv`` lists, in order: the stages, then the kernels' compilation, which no stage counts.
STAGES = ("read", "camera", "render", "grounding", "lift", "vaas", "tracking", "operators", "solve", "write",
          "compile")
#: The journal of finished jobs not yet folded into the summary (JSON lines, in the results directory).
JOURNAL = "summary.journal"
#: At most this many seconds pass between two fsyncs of the journal (each line is flushed at once).
JOURNAL_SYNC_S = 1.0


def read_summary(output: Path) -> dict:
    """Entries of the batch summary in ``output`` by job name ({} when there is none).

    Every folder a batch wrote has its entry there, so these are the folders the
    runner may replace. A ``summary.json`` that is not a batch summary is an error:
    the directory is someone else's.

    Parameters
    ----------
    output : Path
        The results directory.

    Returns
    -------
    dict
        Job name -> its ``summary.json`` record (entries without a name, or
        whose status is neither ``done`` nor ``failed``, are dropped).

    Raises
    ------
    ValidationError
        ``summary.json`` (or, without it, ``summary.csv``) is not a batch summary,
        or it or ``summary.journal`` is not a regular file (a pipe would block the read).
    """
    entries = _read_doc(output)[1]
    entries.update(_read_journal(output / JOURNAL))
    return entries


def _usable(entries) -> dict:
    # entries the runner can read back (a hand-edited line without them is dropped, not a crash)
    return {d["name"]: d for d in entries if isinstance(d, dict) and isinstance(d.get("name"), str)
            and d.get("status") in ("done", "failed")}


def _read_doc(output: Path) -> tuple:
    """``(meta, entries)`` of ``summary.json`` in ``output`` (``({}, {})`` without one)."""
    p = output / "summary.json"
    if not p.exists():
        _check_summary_csv(output / "summary.csv")
        return {}, {}
    _check_regular(p, "summary")
    try:
        doc = json.loads(p.read_text("utf-8"))
        meta = doc.get("meta")
        return (meta if isinstance(meta, dict) else {}), _usable(doc["jobs"])
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, AttributeError, RecursionError) as exc:
        raise ValidationError(f"{p} is not the summary of a seed2gs batch ({type(exc).__name__}: {exc}); "
                              f"choose another output directory, or move that file away") from None


def _read_journal(path: Path) -> dict:
    """The job records of the journal ``path`` by name, later lines winning; a line that does not
    parse (the last one of a killed writer) is skipped."""
    _check_regular(path, "journal")
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            lines = fh.readlines()
    except FileNotFoundError:
        return {}
    except OSError as exc:
        raise ValidationError(f"{path}: cannot read the batch journal ({exc.strerror or exc}); move it away") \
            from None
    records = []
    for line in lines:
        try:
            records.append(json.loads(line))
        except (ValueError, RecursionError):
            continue
    return _usable(records)


def _check_regular(path: Path, what: str) -> None:
    """ValidationError unless ``path`` is a regular file or missing: opening a pipe blocks for ever, and a
    device such as ``/dev/zero`` never ends."""
    if os.path.exists(path) and not os.path.isfile(path):
        raise ValidationError(f"{path} is not a regular file (a directory, pipe or device), so it cannot be "
                              f"the batch's {what}; move it away, or choose another output directory")


class JobJournal:
    """Append-only record of the jobs a run finishes: ``output/summary.journal``, one JSON line each.

    :meth:`append` writes and flushes one line (a killed process loses
    none of the lines written before), and fsyncs at most every
    :data:`JOURNAL_SYNC_S` seconds (and on :meth:`close`); its cost does
    not depend on how many jobs came before. :func:`write_summary` folds
    the journal into the summary and removes it.
    """

    def __init__(self, output: Path):
        self.path = Path(output) / JOURNAL
        self.count = 0
        self._fh = open(self.path, "a", encoding="utf-8")
        if self._fh.tell() > 0:
            self._fh.write("\n")  # after a killed writer's partial line, start a fresh one
        self._synced = time.monotonic()

    def append(self, result) -> None:
        """Record the JobResult ``result``."""
        self._fh.write(json.dumps(result.to_dict(), sort_keys=True) + "\n")
        self._fh.flush()
        self.count += 1
        if time.monotonic() - self._synced > JOURNAL_SYNC_S:
            os.fsync(self._fh.fileno())
            self._synced = time.monotonic()

    def close(self) -> None:
        """Flush, fsync and close the journal (it stays until folded)."""
        if not self._fh.closed:
            self._fh.flush()
            os.fsync(self._fh.fileno())
            self._fh.close()


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


def _written_by_batch(path: Path) -> bool:
    """Whether ``path`` is a job folder a batch wrote (its report.json names the job), listed in the
    summary or not (a worker may finish a job after an interrupted runner stopped recording)."""
    try:
        report = json.loads((path / "report.json").read_text("utf-8"))
        return isinstance(report, dict) and isinstance(report.get("batch"), dict) and \
            report["batch"].get("job") == path.name
    except (OSError, UnicodeDecodeError, ValueError):
        return False


def is_batch_folder(path: Path, summary: dict) -> bool:
    """Whether the job folder ``path`` is the batch's to replace: the summary lists it as done (a failed
    entry has no folder: one there now is someone else's), or its report.json names the job."""
    entry = summary.get(path.name)
    return (entry is not None and entry.get("status") == "done") or _written_by_batch(path)


def check_output_dir(path, what: str = "output") -> Path:
    """``path`` as a Path once a directory can be written there; else a ValidationError naming it.

    The parent must exist (nothing is created above the output), an existing
    ``path`` must be a directory, and a file can be created in it (or in its
    parent, when it does not exist yet): checked by creating and removing a
    probe file, so that ``/proc/x`` or a read-only mount fails before any work.

    Raises
    ------
    ValidationError
        An empty path, a file in the way, a missing parent, or a directory that cannot be written.
    """
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


def remove_folder(path: Path) -> None:
    """Take a job folder out of the results at once (a rename), then delete it."""
    old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
    os.replace(path, old / "previous")
    shutil.rmtree(old, ignore_errors=True)


def write_summary(output: Path, results: list, meta: dict) -> None:
    """Write ``summary.json`` and ``summary.csv`` of ``results`` (JobResults) into ``output``, atomically.

    The records already there (:func:`read_summary`: the summary and the
    journal) of jobs ``results`` does not name follow those of ``results``,
    so no other writer's job is dropped; the journal, folded in, is then
    removed.
    """
    rows = [r.to_dict() for r in results]
    names = {d["name"] for d in rows}
    rows += [d for n, d in read_summary(output).items() if n not in names]
    counts = {"jobs": len(rows), "done": sum(d.get("status") == "done" for d in rows),
              "failed": sum(d.get("status") == "failed" for d in rows),
              "resumed": sum(bool(d.get("resumed")) for d in rows)}
    doc = {"meta": meta, "counts": counts, "jobs": rows}
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*SUMMARY_COLUMNS, *(f"seconds_{s}" for s in STAGES)])
    for d in rows:
        cells = []
        for col in SUMMARY_COLUMNS:
            v = d.get(col)
            cells.append(json.dumps(v, sort_keys=True) if isinstance(v, dict) else ("" if v is None else v))
        seconds = d.get("seconds") if isinstance(d.get("seconds"), dict) else {}
        cells += [_seconds(seconds.get(s)) for s in STAGES]
        w.writerow(cells)
    write_files([(output / "summary.json", json.dumps(doc, indent=1).encode("utf-8")),
                 (output / "summary.csv", buf.getvalue().encode("utf-8"))])
    try:
        os.unlink(output / JOURNAL)
    except FileNotFoundError:
        pass


def _seconds(v) -> str:
    return f"{v:.3f}" if isinstance(v, (int, float)) and not isinstance(v, bool) else ""


def fold_journal(output: Path) -> bool:
    """Fold a journal left in ``output`` (by a killed run) into its summary; whether there was one."""
    if not (Path(output) / JOURNAL).exists():
        return False
    write_summary(Path(output), [], _read_doc(Path(output))[0])
    return True


def result_counts(results) -> dict:
    """``{"jobs", "done", "failed", "resumed"}``: how many of ``results`` are in each state."""
    return {"jobs": len(results), "done": sum(r.status == "done" for r in results),
            "failed": sum(r.status == "failed" for r in results),
            "resumed": sum(bool(r.resumed) for r in results)}
