"""Side-by-side comparison of inverse solvers on one operator stack.

``compare`` fits every method on the same training views and scores it
against ground-truth Gaussian labels:

* 2D, on held-out views (never used for fitting): the exported object
  ``s = q > threshold`` is rendered through each held-out operator and
  thresholded, ``(W s) > render_threshold`` (default 0.5, the opacity at
  which a pixel counts as object), and compared with the truth mask
  ``(W t) > 0.5`` of the labels ``t`` by :func:`~seed2gs_inverse.metrics.iou`
  and :func:`~seed2gs_inverse.metrics.boundary_iou`; mIoU / mBIoU are the
  means over the held-out views (one scene, one target in the LERF-Mask
  averaging). Without labels (``truth=None``: a real capture) the same
  render is compared with the held-out views' own masks, on the pixels
  they know (:func:`~seed2gs_inverse.metrics.known_iou`,
  :func:`~seed2gs_inverse.metrics.known_boundary_iou`; views that know no
  pixel are left out of the means): how well each method predicts masks
  it never saw, as good as those masks are.
* 3D (with labels only): precision, recall and IoU of the selection
  against the labels, also weighted by visibility (each Gaussian's summed
  weight over all views).
* cost: solve seconds, iterations, and peak memory of the solve
  (``tracemalloc``, which sees NumPy/SciPy array allocations). The solve
  runs with ``tracemalloc`` on, which slows its allocations: its seconds
  here are higher than ``solve`` alone reports for the same fit (compare
  methods with each other, not with a ``solve`` run).
"""

from __future__ import annotations

import csv
import io
import json
import tracemalloc
import warnings
from dataclasses import dataclass, field

import numpy as np

from ._selection import index_list
from .errors import ValidationError
from .metrics import boundary_iou, iou, known_boundary_iou, known_iou, membership_scores
from .operators import as_stack
from .solvers import available_methods, solve
from .solvers._common import normalize_mask

__all__ = ["compare", "Comparison", "holdout_views", "COLUMNS", "COLUMNS_3D", "AGAINST"]

COLUMNS = ("method", "miou", "mbiou", "precision", "recall", "iou3d", "weighted_precision", "weighted_recall",
           "weighted_iou3d", "n_selected", "seconds", "iterations", "peak_mb")
#: The 3D columns of :data:`COLUMNS`: None in every row without labels.
COLUMNS_3D = ("precision", "recall", "iou3d", "weighted_precision", "weighted_recall", "weighted_iou3d")
#: What the 2D scores compare with, by :attr:`Comparison.against`.
AGAINST = {"truth": "the truth labels rendered into them",
           "masks": "those views' own masks (known pixels only; no ground truth)"}


def holdout_views(n_views: int, every: int | None) -> np.ndarray:
    """Indices of held-out views: every ``every``-th view (``every-1, 2 every-1, ...``).

    ``None`` or 0 holds nothing out.
    """
    if not every:
        return np.zeros(0, dtype=np.int64)
    if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 2:
        raise ValidationError(f"holdout_every must be an integer >= 2 (or 0 for none), got {every!r}")
    return np.arange(every - 1, n_views, every, dtype=np.int64)


@dataclass
class Comparison:
    """The result of :func:`compare`.

    Attributes
    ----------
    rows : list of dict
        One row per method with the keys of ``COLUMNS``.
    per_view : dict
        method -> {"iou": [...], "biou": [...]} over the held-out views.
    holdout : list of int
        Held-out view indices (empty: scores are on the fitting views).
    results : dict
        method -> SolveResult.
    against : {"truth", "masks"}
        What the 2D scores compare with: the labels rendered into each
        view, or (without labels) the view's own mask on its known pixels;
        the 3D columns (:data:`COLUMNS_3D`) are None with ``"masks"``.
    """

    rows: list
    per_view: dict
    holdout: list
    results: dict = field(default_factory=dict)
    against: str = "truth"

    def format(self) -> str:
        """A fixed-width text table."""
        head = ["method", "mIoU", "mBIoU", "P3d", "R3d", "IoU3d", "wIoU3d", "selected", "seconds", "iters",
                "peak MB"]
        keys = ["method", "miou", "mbiou", "precision", "recall", "iou3d", "weighted_iou3d", "n_selected",
                "seconds", "iterations", "peak_mb"]
        if self.against != "truth":  # no labels: no 3D columns
            head, keys = zip(*[(h, k) for h, k in zip(head, keys) if k not in COLUMNS_3D])
        lines = [list(head)]
        for r in self.rows:
            cells = []
            for k in keys:
                v = r[k]
                if isinstance(v, float):
                    cells.append("nan" if not np.isfinite(v) else (f"{v:.4f}" if k not in ("seconds", "peak_mb")
                                                                  else f"{v:.3f}" if k == "seconds" else f"{v:.1f}"))
                else:
                    cells.append(str(v))
            lines.append(cells)
        widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
        out = ["  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(line, widths)))
               for line in lines]
        k = len(self.holdout)
        where = f"{k} held-out view{'s' if k != 1 else ''}" if self.holdout else "the fitting views (none held out)"
        return "\n".join(out) + f"\n2D scores on {where}, against {AGAINST.get(self.against, self.against)}."

    def to_csv(self) -> str:
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=list(COLUMNS), lineterminator="\n")
        w.writeheader()
        for r in self.rows:
            w.writerow({k: r[k] for k in COLUMNS})
        return buf.getvalue()

    def to_json(self) -> str:
        return json.dumps({"against": self.against, "holdout": self.holdout, "rows": self.rows,
                           "per_view": self.per_view}, indent=1, default=float)

    def plot(self, path) -> None:
        """Bar chart of mIoU, mBIoU and 3D IoU per method (PNG)."""
        from matplotlib.figure import Figure  # deferred: matplotlib is only needed to plot

        names = [r["method"] for r in self.rows]
        metrics = [("miou", "2D mIoU"), ("mbiou", "2D mBIoU")] + ([("iou3d", "3D IoU")] if self.against == "truth"
                                                                 else [])
        x = np.arange(len(names))
        fig = Figure(figsize=(1.6 + 1.5 * len(names), 3.4))
        ax = fig.subplots()
        width = 0.8 / len(metrics)
        for j, (key, label) in enumerate(metrics):
            ax.bar(x + (j - (len(metrics) - 1) / 2) * width, [r[key] for r in self.rows], width, label=label)
        ax.set_xticks(x, names)
        ax.set_ylim(0, 1.05)
        ax.set_ylabel("score")
        ax.legend(loc="lower right", fontsize=8)
        ax.set_title("solver comparison" if self.against == "truth" else "solver comparison (against held-out masks)")
        fig.tight_layout()
        fig.savefig(path, format="png", dpi=100)


def compare(operators, masks, truth=None, methods=None, holdout_every: int | None = 4, holdout=None, init=None,
            options=None, threshold: float | None = None, render_threshold: float = 0.5,
            progress=None) -> Comparison:
    """Fit several solvers on the same views and score them on held-out views.

    Parameters
    ----------
    operators : OperatorStack or sequence of ViewOperator / sparse matrices
    masks : sequence of (H, W) masks, one per view (what the solvers fit)
    truth : (N,) bool, optional
        Ground-truth object membership. Without it the 2D scores compare
        with the held-out views' own masks on their known pixels, and the
        3D columns are None (:attr:`Comparison.against`).
    methods : sequence of str, optional
        Default: all :func:`~seed2gs_inverse.solvers.available_methods`.
    holdout_every : int or None, default 4
        Hold out every k-th view from fitting (see :func:`holdout_views`).
    holdout : sequence of int or bool (V,), optional
        Explicit held-out views, as indices or a mask (overrides ``holdout_every``).
    init : optional
        Passed to every solver.
    options : dict, optional
        method -> dict of that method's options.
    threshold : float, optional
        Selection threshold; default each result's own (0.5, or voting's bias threshold).
    render_threshold : float, default 0.5
        Opacity above which a rendered pixel of the selection counts as object.
    progress : callable, optional
        ``progress(method, k, n, step)`` while fitting: ``step`` is the
        solver's :class:`~seed2gs_inverse.solvers.SolveProgress` during the
        solve of the ``k``-th of ``n`` methods (0-based), and None once that
        method is fitted and scored.

    Returns
    -------
    Comparison

    Raises
    ------
    ValidationError
        Bad operators, masks, labels, methods, options, held-out views or
        thresholds (named), before any solve.
    """
    try:
        masks = list(masks)
    except TypeError:
        raise ValidationError("operators and masks must be sequences (or an OperatorStack)") from None
    stack = as_stack(operators, masks)
    V = len(stack)
    if len(masks) != V:
        raise ValidationError(f"got {len(masks)} masks for {V} views; give one mask per view")
    t = None if truth is None else _check_truth(truth, stack.n_gaussians)
    methods = _check_methods(methods)
    options = dict(options or {})
    stray = sorted(set(options) - set(methods))
    if stray:
        raise ValidationError(f"options: {stray} {'is' if len(stray) == 1 else 'are'} not among the compared "
                              f"methods {methods}; options are keyed by method name")
    if not (np.isfinite(render_threshold) and 0.0 <= render_threshold < 1.0):
        raise ValidationError(f"render_threshold must be in [0, 1) (a rendered opacity), got {render_threshold!r}")
    if holdout is None:
        held = holdout_views(V, holdout_every)
        if holdout_every and not held.size:
            warnings.warn(f"holdout_every={holdout_every} holds out no view of {V}: the scores are on the "
                          f"views the methods were fitted on", UserWarning, stacklevel=2)
    else:
        held = np.unique(index_list(holdout, V, "holdout"))
    train = np.setdiff1d(np.arange(V), held)
    if train.size == 0:
        raise ValidationError("every view is held out; keep at least one view for fitting")
    if progress is not None and not callable(progress):
        raise ValidationError(f"progress must be a callable or None, got {type(progress).__name__}")
    fit_stack = stack.subset(train)
    fit_masks = [masks[i] for i in train]
    eval_idx = held if held.size else train
    if t is None:  # the views' own masks, NaN where unknown
        targets = [normalize_mask(masks[i], stack[i].image_shape, f"view {i}").reshape(stack[i].image_shape)
                   for i in eval_idx]
    else:
        tf = t.astype(np.float32)
        targets = [stack[i].image(tf) > 0.5 for i in eval_idx]
    visibility = None if t is None else stack.column_sums()  # how much each Gaussian is seen over all views
    rows, per_view, results = [], {}, {}
    for j, m in enumerate(methods):
        step = None if progress is None else (lambda p, m=m, j=j: progress(m, j, len(methods), p))
        tracemalloc.start()
        try:
            res = solve(fit_stack, fit_masks, method=m, init=init, progress=step, **options.get(m, {}))
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        sel = res.selected(threshold)
        ious, bious = _view_scores(stack, sel, eval_idx, targets, render_threshold, known=t is None)
        rows.append({"method": m, "miou": _mean(ious), "mbiou": _mean(bious), **_scores_3d(sel, t, visibility),
                     "n_selected": int(sel.sum()), "seconds": float(res.seconds), "iterations": int(res.iterations),
                     "peak_mb": peak / 2**20})
        per_view[m] = {"views": [int(i) for i in eval_idx], "iou": ious, "biou": bious}
        results[m] = res
        if progress is not None:
            progress(m, j, len(methods), None)
    return Comparison(rows=rows, per_view=per_view, holdout=[int(i) for i in held], results=results,
                      against="truth" if t is not None else "masks")


def _check_truth(truth, n: int) -> np.ndarray:
    t = np.asarray(truth)
    if t.dtype != bool or t.shape != (n,):
        raise ValidationError(f"truth must be a bool array of shape ({n},), got {t.dtype} {t.shape}")
    if not t.any():  # every score would be 0, or 1 by the empty-set conventions: nothing is compared
        raise ValidationError("truth selects no Gaussian; give the object's labels (True on the object)")
    return t


def _check_methods(methods) -> list:
    if isinstance(methods, str):
        raise ValidationError(f"methods must be a list of method names, got the string {methods!r}; "
                              f"write [{methods!r}]")
    methods = list(available_methods() if methods is None else methods)
    if not methods:
        raise ValidationError("methods: give at least one method")
    for m in methods:
        if m not in available_methods():
            raise ValidationError(f"unknown method {m!r}; available: {', '.join(available_methods())}")
    if len(set(methods)) != len(methods):
        raise ValidationError(f"methods: each method once, got {methods}")
    return methods


def _view_scores(stack, sel, eval_idx, targets, render_threshold: float, known: bool) -> tuple[list, list]:
    """Per-view (IoU, boundary IoU) of the rendered selection against ``targets`` (on known pixels with ``known``)."""
    sf = sel.astype(np.float32)
    ious, bious = [], []
    for k, i in enumerate(eval_idx):
        pred = stack[i].image(sf) > render_threshold
        if known:
            ious.append(known_iou(pred, targets[k]))
            bious.append(known_boundary_iou(pred, targets[k]))
        else:
            ious.append(iou(pred, targets[k]))
            bious.append(boundary_iou(pred, targets[k]))
    return ious, bious


def _mean(values) -> float:
    """The mean of the finite values (views that know no pixel give NaN and are left out); NaN if none."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else float("nan")


def _scores_3d(sel, t, visibility) -> dict:
    """The 3D columns of a row: against the labels, or None each without them."""
    if t is None:
        return dict.fromkeys(COLUMNS_3D)
    s3 = membership_scores(sel, t, weights=visibility)
    return {"precision": s3["precision"], "recall": s3["recall"], "iou3d": s3["iou"],
            "weighted_precision": s3["weighted_precision"], "weighted_recall": s3["weighted_recall"],
            "weighted_iou3d": s3["weighted_iou"]}
