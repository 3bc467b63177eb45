"""The report files of an evaluation: per-query and per-scene tables, and the grid figure.

:func:`report_tables` averages the per-frame scores as
:func:`~seed2gs_inverse.metrics.protocol_mean` does (views -> query -> scene
-> overall); :func:`csv_table` writes a table; :func:`grid_png` draws truth
against prediction for every query and test frame; :func:`remove_stale_masks`
keeps ``masks/`` to this run's predictions.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np

from ..metrics import protocol_mean

__all__ = ["QUERY_COLUMNS", "report_tables", "csv_table", "grid_png", "remove_stale_masks"]


#: Columns of ``per_query.csv``. ``prompt`` is the query text or ``gt-mask``;
#: ``grounded_by`` / ``grounding_score`` name the source (and its selector
#: score) of the candidate that became the seed of a text query.
QUERY_COLUMNS = ("scene", "query", "miou", "mbiou", "miou_heldout", "n_frames", "seed_frame", "prompt",
                 "grounded_by", "grounding_score", "n_selected", "status", "error")


def _grounding(result) -> tuple:
    """(source, score) of the seed candidate of a done text job, from its report.json."""
    if not result.ok or result.outdir is None:
        return None, None
    try:
        with open(Path(result.outdir) / "report.json") as fh:
            cands = json.load(fh).get("prompt", {}).get("candidates") or []
    except (OSError, ValueError):
        return None, None
    if not cands:
        return None, None
    return cands[0].get("source"), cands[0].get("score")


def report_tables(dataset, job_of, by_name, per_frame, oracle_seed: bool = True) -> dict:
    """The ``overall``, ``scenes`` and ``queries`` records of ``report.json``.

    Parameters
    ----------
    dataset : list of LerfScene
    job_of : dict (scene, query) -> Job
    by_name : dict job name -> JobResult
    per_frame : dict (scene, query) -> {frame: (iou, biou)}
        The scores of the frames with ground truth.
    oracle_seed : bool
        Whether the queries were seeded by their ground-truth masks (else text).

    Returns
    -------
    dict
        ``overall`` (miou, mbiou), ``scenes`` (one record per scene) and
        ``queries`` (one record per query, with per-frame scores). A failed
        query scores 0 in each frame where it has ground truth.
    """
    queries, iou_in, biou_in = [], {}, {}
    for sc in dataset:
        for q in sc.queries:
            r = by_name[job_of[(sc.name, q)].name]
            frames = per_frame.get((sc.name, q), {})
            seed = sc.reference_frame(q, oracle_seed)
            source, score = (None, None) if oracle_seed else _grounding(r)
            row = {"scene": sc.name, "query": q, "job": r.name, "status": r.status, "error": r.error,
                   "seed_frame": seed, "prompt": "gt-mask" if oracle_seed else q,
                   "grounded_by": source, "grounding_score": score,
                   "n_selected": r.n_selected, "n_frames": len(frames),
                   "frames": {f: {"iou": v[0], "biou": v[1]} for f, v in frames.items()}}
            if r.ok and frames:
                row["miou"] = float(np.mean([v[0] for v in frames.values()]))
                row["mbiou"] = float(np.mean([v[1] for v in frames.values()]))
                held = [v[0] for f, v in frames.items() if f != seed]
                row["miou_heldout"] = float(np.mean(held)) if held else None
            else:
                # A failed query scores 0 on each of its frames, as an empty
                # prediction would, so failures cannot raise the mean.
                n = sum((f, q) in sc.gt for f in sc.frames)
                row["miou"] = row["mbiou"] = 0.0
                row["miou_heldout"] = None
                frames = {f: (0.0, 0.0) for f in sc.frames if (f, q) in sc.gt}
                row["n_frames"] = n
            iou_in.setdefault(sc.name, {})[q] = [v[0] for v in frames.values()]
            biou_in.setdefault(sc.name, {})[q] = [v[1] for v in frames.values()]
            queries.append(row)
    miou, miou_scene, _ = protocol_mean(iou_in)
    mbiou, mbiou_scene, _ = protocol_mean(biou_in)
    scenes = [{"scene": sc.name, "miou": miou_scene[sc.name], "mbiou": mbiou_scene[sc.name],
               "n_queries": len(sc.queries),
               "n_failed": sum(not by_name[job_of[(sc.name, q)].name].ok for q in sc.queries)}
              for sc in dataset]
    return {"overall": {"miou": miou, "mbiou": mbiou}, "scenes": scenes, "queries": queries}


def csv_table(rows, cols) -> bytes:
    """UTF-8 CSV of the ``cols`` of ``rows`` (dicts): floats with six decimals, None as an empty cell."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow([("" if r.get(c) is None else (f"{r[c]:.6f}" if isinstance(r[c], float) else r[c]))
                    for c in cols])
    return buf.getvalue().encode("utf-8")


def remove_stale_masks(masks_dir: Path, dataset, preds) -> None:
    """Delete the predicted masks an earlier run left for this run's scenes that this run did not write.

    A query that failed in this run, or that is not in the dataset, must
    not leave an earlier prediction for a scorer reading ``masks/``. Masks
    of scenes outside this run stay, as their job folders do.

    Parameters
    ----------
    masks_dir : Path
        ``<report>/masks``.
    dataset : list of LerfScene
    preds : dict (scene, frame, query) -> (H, W) bool
        The predictions of this run.
    """
    for sc in dataset:
        root = masks_dir / sc.name
        if not root.is_dir():
            continue
        for frame_dir in [d for d in root.iterdir() if d.is_dir()]:
            for png in frame_dir.glob("*.png"):
                if (sc.name, frame_dir.name, png.stem) not in preds:
                    png.unlink()
            if not any(frame_dir.iterdir()):
                frame_dir.rmdir()


def grid_png(dataset, preds, per_frame, failed=frozenset()) -> bytes | None:
    """PNG bytes: one row per query, one column per test frame; truth vs prediction.

    Each cell overlays the two masks: green = both, red = predicted only,
    blue = missed (truth only); the title gives the frame's IoU, or says that
    the query failed (``failed``: its ``(scene, query)`` pairs; scored 0
    where it has truth). None when there is no query or no frame.
    """
    from matplotlib.figure import Figure  # deferred: matplotlib is only needed to plot

    rows = [(sc, q) for sc in dataset for q in sc.queries]
    n_cols = max((len(sc.frames) for sc in dataset), default=0)
    if not rows or not n_cols:
        return None
    fig = Figure(figsize=(2.4 * n_cols, 2.0 * len(rows)))
    axes = fig.subplots(len(rows), n_cols, squeeze=False)
    for i, (sc, q) in enumerate(rows):
        for j in range(n_cols):
            ax = axes[i, j]
            ax.set_xticks([])
            ax.set_yticks([])
            if j >= len(sc.frames):
                ax.axis("off")
                continue
            f = sc.frames[j]
            pred = preds.get((sc.name, f, q))
            gt = sc.read_gt(f, q) if (f, q) in sc.gt else None
            shape = (pred if pred is not None else gt).shape if (pred is not None or gt is not None) else (8, 8)
            img = np.full((*shape, 3), 0.12, np.float32)
            p = pred if pred is not None else np.zeros(shape, bool)
            g = gt if gt is not None else np.zeros(shape, bool)
            img[p & g] = (0.2, 0.8, 0.2)
            img[p & ~g] = (0.9, 0.2, 0.2)
            img[~p & g] = (0.2, 0.4, 0.9)
            ax.imshow(img, interpolation="nearest")
            s = per_frame.get((sc.name, q), {}).get(f)
            if (sc.name, q) in failed:
                title = "failed" + (", IoU 0" if gt is not None else "")
            else:
                title = "no truth" if s is None else f"IoU {s[0]:.2f}"
            ax.set_title(f"{f}: {title}", fontsize=7)
            if j == 0:
                ax.set_ylabel(f"{sc.name}\n{q}", fontsize=7)
    fig.suptitle("green: both, red: predicted only, blue: missed", fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    return buf.getvalue()
