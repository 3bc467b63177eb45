"""The results directory of a batch: its summary files, and which job folders are the batch's.

``summary.json`` (``{"meta", "counts", "jobs"}``, one record per job, as
:meth:`~seed2gs_inverse.batch.JobResult.to_dict` writes it) and
``summary.csv`` (:data:`SUMMARY_COLUMNS`, then ``seconds_<stage>``) are
rewritten together, atomically, after every job, so an interrupted batch
leaves a consistent record. The summary is also the batch's claim on the
directory: a job folder is replaced only when the summary lists it as done
or its ``report.json`` names the job (:func:`is_batch_folder`).
"""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import tempfile
from pathlib import Path

from .._atomic import check_writable, write_files
from ..errors import ValidationError

__all__ = ["SUMMARY_COLUMNS", "STAGES", "read_summary", "write_summary", "is_batch_folder", "check_output_dir",
           "remove_folder", "result_counts"]

#: Columns of ``summary.csv`` (per-stage seconds follow as ``seconds_<stage>``).
SUMMARY_COLUMNS = ("name", "status", "n_gaussians", "n_selected", "n_views", "total_seconds", "worker",
                   "attempts", "scene_cached", "peak_rss_mb", "scene", "prompt", "outdir", "error")
#: The stages whose seconds ``summary.csv`` lists, in order.
STAGES = ("read", "camera", "render", "grounding", "lift", "vaas", "tracking", "operators", "solve", "write")


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
        ``summary.json`` (or, without it, ``summary.csv``) is not a batch summary.
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
    """Write ``summary.json`` and ``summary.csv`` of ``results`` (JobResults) into ``output``, atomically."""
    rows = [r.to_dict() for r in results]
    doc = {"meta": meta, "counts": result_counts(results), "jobs": rows}
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*SUMMARY_COLUMNS, *(f"seconds_{s}" for s in STAGES)])
    for d in rows:
        cells = []
        for col in SUMMARY_COLUMNS:
            v = d.get(col)
            cells.append(json.dumps(v, sort_keys=True) if isinstance(v, dict) else ("" if v is None else v))
        cells += [f"{d['seconds'][s]:.3f}" if s in d["seconds"] else "" for s in STAGES]
        w.writerow(cells)
    write_files([(output / "summary.json", json.dumps(doc, indent=1).encode("utf-8")),
                 (output / "summary.csv", buf.getvalue().encode("utf-8"))])


def result_counts(results) -> dict:
    """``{"jobs", "done", "failed", "resumed"}``: how many of ``results`` are in each state."""
    return {"jobs": len(results), "done": sum(r.status == "done" for r in results),
            "failed": sum(r.status == "failed" for r in results),
            "resumed": sum(bool(r.resumed) for r in results)}
