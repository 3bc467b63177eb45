"""Segmentation scores: 2D IoU and boundary IoU, 3D membership scores, alpha-weighted scores over views.

2D scores follow the Gaussian Grouping LERF-Mask evaluation protocol:
per view and target, ``iou`` and ``boundary_iou`` of binary masks; the mean
over a target's views, then over a scene's targets, then over scenes
(:func:`protocol_mean`).

Boundary IoU (Cheng et al. 2021, as that evaluator computes it): with the
image diagonal ``diag = sqrt(H^2 + W^2)`` the band width is
``d = max(1, round(0.02 diag))``; the mask is padded by one zero pixel on
every side (so the image border counts as boundary), eroded ``d`` times
with a 3x3 square kernel, cropped back, and the boundary is the mask minus
its erosion. Boundary IoU is the IoU of the two boundaries.

Convention for empty masks (the reference code divides by zero there):
when both masks (or both boundaries) are empty the score is 1.0, a perfect
agreement.

The per-pixel rule ``W(c) 1_sel > 1/2`` cannot see what never dominates a
pixel (inner and back layers, translucent shells). :func:`alpha_scores`
counts every Gaussian by the compositing weight it has in the views, and
:func:`remainder_share` measures, without a truth, how much of the
object's alpha the Gaussians of its region that the selection left in the
remainder keep at its place.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .errors import ValidationError
from .operators import as_stack

__all__ = ["iou", "boundary_iou", "known_iou", "known_boundary_iou", "mask_boundary", "boundary_width",
           "protocol_mean", "membership_scores", "alpha_scores", "remainder_share", "object_region",
           "nearby_remainder"]


def _pair(pred, truth, name: str = "masks") -> tuple:
    p = np.asarray(pred)
    t = np.asarray(truth)
    if p.shape != t.shape:
        raise ValidationError(f"{name}: prediction shape {p.shape} differs from truth shape {t.shape}")
    for label, a in (("prediction", p), ("truth", t)):
        if a.dtype != bool and (a.dtype.kind not in "uif" or (a.size and np.any(np.isnan(a)))):
            raise ValidationError(f"{name}: {label} must be a boolean (or 0/1, 0/255) mask without NaN")
        # Grey levels would count as object wherever they are nonzero; the protocol reads its
        # ground truth as grey > 128, so the two would disagree on soft edges without a word.
        if a.dtype != bool and a.size and not np.all((a == 0) | (a == 1) | (a == 255)):
            raise ValidationError(f"{name}: {label} holds values other than 0 and 1 (or 255); pass a boolean "
                                  f"mask (grey-level ground truth is object where grey > 128 in the LERF-Mask "
                                  f"protocol: seed2gs_inverse.evaluation.read_gt_mask reads it so)")
    return p.astype(bool), t.astype(bool)


def iou(pred, truth) -> float:
    """Intersection over union of two binary masks of any shape.

    ``|pred & truth| / |pred | truth|``; 1.0 when both are empty. Numeric
    masks may hold 0 and 1, or 0 and 255 (nonzero = True); grey levels are
    refused (threshold them first: the protocol's ground truth is grey > 128).
    """
    p, t = _pair(pred, truth, "iou")
    union = np.count_nonzero(p | t)
    return 1.0 if union == 0 else np.count_nonzero(p & t) / union


def boundary_width(shape, dilation_ratio: float = 0.02) -> int:
    """``d = max(1, round(dilation_ratio * sqrt(H^2 + W^2)))``."""
    h, w = shape
    return max(1, int(round(dilation_ratio * np.sqrt(h * h + w * w))))


def mask_boundary(mask, dilation_ratio: float = 0.02) -> np.ndarray:
    """Bool (H, W) inner boundary band of a 2-D binary mask (see module docstring)."""
    import cv2

    m = np.asarray(mask)
    if m.ndim != 2:
        raise ValidationError(f"mask_boundary: mask must be 2-D, got shape {m.shape}")
    m = (m != 0).astype(np.uint8)
    h, w = m.shape
    padded = cv2.copyMakeBorder(m, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    eroded = cv2.erode(padded, np.ones((3, 3), np.uint8), iterations=boundary_width((h, w), dilation_ratio))
    return (m - eroded[1:h + 1, 1:w + 1]) > 0


def boundary_iou(pred, truth, dilation_ratio: float = 0.02) -> float:
    """Boundary IoU of two 2-D binary masks (LERF-Mask protocol, band ratio 0.02)."""
    p, t = _pair(pred, truth, "boundary_iou")
    if p.ndim != 2:
        raise ValidationError(f"boundary_iou: masks must be 2-D, got shape {p.shape}")
    return iou(mask_boundary(p, dilation_ratio), mask_boundary(t, dilation_ratio))


def _known(pred, mask, name: str) -> tuple:
    """``(pred, object, known)`` bool arrays of a prediction and a mask with unknown (NaN) pixels."""
    m = np.asarray(mask)
    if m.dtype.kind != "f":
        p, t = _pair(pred, m, name)
        return p, t, np.ones(t.shape, bool)
    known = ~np.isnan(m)
    vals = m[known]
    if vals.size and not (np.all(np.isfinite(vals)) and vals.min() >= 0 and vals.max() <= 1):
        raise ValidationError(f"{name}: mask values must lie in [0, 1] with NaN for unknown pixels")
    p, _ = _pair(pred, known, name)
    return p, known & (np.where(known, m, 0) > 0.5), known


def known_iou(pred, mask) -> float:
    """IoU of ``pred`` against a mask with unknown pixels, over the pixels the mask knows.

    Parameters
    ----------
    pred : bool array (or 0/1, 0/255)
    mask : array of ``pred``'s shape
        Floats in [0, 1] with NaN for unknown pixels, object where above
        0.5 (a supervision mask ``Y(c)``); a bool or integer mask knows
        every pixel (then this is :func:`iou`).

    Returns
    -------
    float
        ``|pred & obj| / |pred | obj|`` over the known pixels; 1.0 when both
        are empty there, NaN when the mask knows no pixel.

    Raises
    ------
    ValidationError
        Shapes differ, or values out of range.
    """
    p, t, known = _known(pred, mask, "known_iou")
    if not known.any():
        return float("nan")
    return iou(p[known], t[known])


def known_boundary_iou(pred, mask, dilation_ratio: float = 0.02) -> float:
    """Boundary IoU of 2-D ``pred`` against a mask with unknown pixels, over the pixels the mask knows.

    The mask's unknown pixels take ``pred``'s values before its boundary
    band is taken (:func:`mask_boundary`), so an unknown region draws no
    band of its own; the two bands are then compared on the known pixels
    only. A ``pred`` that agrees with every known pixel scores 1.0.

    Returns
    -------
    float
        NaN when the mask knows no pixel.

    Raises
    ------
    ValidationError
        Shapes differ, masks are not 2-D, or values out of range.
    """
    p, t, known = _known(pred, mask, "known_boundary_iou")
    if p.ndim != 2:
        raise ValidationError(f"known_boundary_iou: masks must be 2-D, got shape {p.shape}")
    if not known.any():
        return float("nan")
    filled = np.where(known, t, p)
    return iou(mask_boundary(p, dilation_ratio)[known], mask_boundary(filled, dilation_ratio)[known])


def protocol_mean(scores) -> tuple:
    """Average per-view scores as the LERF-Mask evaluator does.

    Parameters
    ----------
    scores : mapping scene -> mapping target -> sequence of per-view floats

    Returns
    -------
    (overall, per_scene, per_target)
        ``per_target[scene][target]`` is the mean over that target's views,
        ``per_scene[scene]`` the mean over its targets, ``overall`` the mean
        over scenes (scenes weigh equally).
    """
    if not scores:
        raise ValidationError("protocol_mean: no scenes given")
    per_target, per_scene = {}, {}
    for scene, targets in scores.items():
        if not targets:
            raise ValidationError(f"protocol_mean: scene {scene!r} has no targets")
        per_target[scene] = {}
        for target, values in targets.items():
            v = np.asarray(list(values), dtype=np.float64)
            if v.size == 0:
                raise ValidationError(f"protocol_mean: scene {scene!r}, target {target!r} has no views")
            per_target[scene][target] = float(v.mean())
        per_scene[scene] = float(np.mean(list(per_target[scene].values())))
    return float(np.mean(list(per_scene.values()))), per_scene, per_target


def membership_scores(q_or_selected, labels, weights=None, threshold: float = 0.5) -> dict:
    """3D scores of a per-Gaussian membership against ground-truth labels.

    Parameters
    ----------
    q_or_selected : (N,) bool selection or float q (selected where ``q > threshold``)
    labels : (N,) bool ground truth
    weights : (N,) non-negative, optional
        How much each Gaussian is seen (e.g. its summed compositing weight
        over the views); adds visibility-weighted scores, which ignore
        Gaussians nobody can see.
    threshold : float, default 0.5

    Returns
    -------
    dict with ``precision = TP / (TP + FP)``, ``recall = TP / (TP + FN)``,
    ``iou = TP / (TP + FP + FN)`` (1.0 for 0/0), counts ``tp, fp, fn``, and
    with ``weights`` the same three ratios with every Gaussian counted by its
    weight (``weighted_precision`` ...).
    """
    s = np.asarray(q_or_selected)
    t = np.asarray(labels)
    if s.ndim != 1 or t.shape != s.shape:
        raise ValidationError(f"membership_scores: selection {s.shape} and labels {t.shape} must be equal 1-D shapes")
    if t.dtype != bool:
        raise ValidationError(f"membership_scores: labels must be bool, got {t.dtype}")
    if s.dtype != bool:
        if s.dtype.kind not in "uif" or np.any(np.isnan(s)):
            raise ValidationError("membership_scores: q must be numeric without NaN")
        s = s > threshold

    def ratios(w):
        tp = float(np.sum(w * (s & t)))
        fp = float(np.sum(w * (s & ~t)))
        fn = float(np.sum(w * (~s & t)))

        def div(a, b):
            return 1.0 if b == 0 else a / b

        return tp, fp, fn, div(tp, tp + fp), div(tp, tp + fn), div(tp, tp + fp + fn)

    tp, fp, fn, p, r, i = ratios(np.ones(s.shape))
    out = {"precision": p, "recall": r, "iou": i, "tp": int(tp), "fp": int(fp), "fn": int(fn)}
    if weights is not None:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != s.shape or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValidationError("membership_scores: weights must be finite, non-negative and of shape "
                                  f"{s.shape}, got {w.shape}")
        _, _, _, wp, wr, wi = ratios(w)
        out.update(weighted_precision=wp, weighted_recall=wr, weighted_iou=wi)
    return out


def _membership(name: str, what: str, value, n: int) -> np.ndarray:
    """``value`` as a bool (N,) array, or a ValidationError naming ``name`` and ``what``."""
    a = np.asarray(value)
    if a.dtype != bool or a.shape != (n,):
        raise ValidationError(f"{name}: {what} must be a bool array of shape ({n},) (one entry per Gaussian "
                              f"of the operators), got {a.dtype} {a.shape}")
    return a


def alpha_scores(operators, selected, truth) -> dict:
    """Recall, precision and IoU of a selection, every Gaussian counted by its compositing weight in the views.

    Parameters
    ----------
    operators : OperatorStack or sequence of views
        The views ``W(c)`` (anything :func:`~seed2gs_inverse.operators.as_stack`
        accepts): rows are pixels, columns Gaussians,
        ``W(c)[u, i] = alpha_i(u) T_i(u)``.
    selected, truth : (N,) bool
        The selection and the true object.

    Returns
    -------
    dict
        ``recall``, ``precision``, ``iou`` and the weights they are made of:
        ``object_weight`` ``w(truth)``, ``selection_weight`` ``w(sel)``,
        ``overlap_weight`` ``w(sel & truth)``, ``union_weight``
        ``w(sel | truth)``.

    Raises
    ------
    ValidationError
        ``selected`` or ``truth`` not bool of shape (N,), or operators
        :func:`~seed2gs_inverse.operators.as_stack` refuses.

    Notes
    -----
    The weight of a set ``X`` of Gaussians is what it composites into the
    views, summed over views and pixels:

    .. math::

        w(X) = \\sum_c \\sum_u (W(c) 1_X)(u) = \\sum_{i \\in X} \\sum_c \\sum_u W(c)[u, i]

    and the scores are

    .. math::

        recall = w(S \\cap T) / w(T),\\quad precision = w(S \\cap T) / w(S),\\quad
        IoU = w(S \\cap T) / w(S \\cup T)

    with ``S`` the selection and ``T`` the truth; a ratio 0/0 is 1.0 (as in
    :func:`membership_scores`). Recall is the share of the object's
    compositing weight that the selection holds, so an object whose
    selected front layers cover its silhouette while its inner layers stay
    behind scores below 1 wherever those layers are seen. Gaussians no view
    sees weigh nothing.
    """
    stack = as_stack(operators)
    n = stack.n_gaussians
    s = _membership("alpha_scores", "selected", selected, n)
    t = _membership("alpha_scores", "truth", truth, n)
    c = np.asarray(stack.column_sums(), np.float64)
    w_t, w_s = float(c[t].sum()), float(c[s].sum())
    w_st, w_u = float(c[s & t].sum()), float(c[s | t].sum())

    def div(a, b):
        return 1.0 if b == 0 else a / b

    return {"recall": div(w_st, w_t), "precision": div(w_st, w_s), "iou": div(w_st, w_u),
            "object_weight": w_t, "selection_weight": w_s, "overlap_weight": w_st, "union_weight": w_u}


def object_region(means, selected, quantile: float = 0.02, margin: float = 0.1) -> np.ndarray:
    """Bool (N,): the Gaussians whose means lie in the selection's robust oriented bounding box.

    Parameters
    ----------
    means : (N, 3) array
        Gaussian centres.
    selected : (N,) bool
        The selection (at least one Gaussian).
    quantile : float in [0, 0.5)
        The box spans the ``quantile`` to ``1 - quantile`` quantiles of the
        selected means along each principal axis, so a few stray selected
        Gaussians do not stretch it.
    margin : float >= 0
        Grows the box by ``margin * L`` on every side, ``L`` its longest
        side, so a thin part (a panel, a leg) still holds its own layers.

    Notes
    -----
    With ``mu`` the selected means' centroid and ``E`` their principal
    axes, ``p_i = E^T (x_i - mu)``; ``lo_k, hi_k`` are the quantiles of
    ``p_{i,k}`` over the selection, ``L = max_k (hi_k - lo_k)``, and ``i``
    is in the region when ``lo_k - margin L <= p_{i,k} <= hi_k + margin L``
    on all three axes.
    """
    x = np.asarray(means, np.float64)
    sel = np.asarray(selected, bool)
    if x.ndim != 2 or x.shape[1] != 3 or sel.shape != (x.shape[0],):
        raise ValidationError(f"object_region: means must be (N, 3) and selected bool (N,), got {x.shape} and "
                              f"{sel.shape}")
    if not 0 <= quantile < 0.5 or margin < 0:
        raise ValidationError(f"object_region: quantile must be in [0, 0.5) and margin >= 0, got {quantile} "
                              f"and {margin}")
    return _Box(x, sel, quantile, margin).inside(0.0)


class _Box:
    """:func:`object_region`'s box of ``sel`` over the points ``x``: ``inside(extra)`` grows it by ``extra`` more."""

    def __init__(self, x: np.ndarray, sel: np.ndarray, quantile: float, margin: float):
        pts = x[sel]
        self.empty = pts.shape[0] == 0
        if self.empty:
            self.n = x.shape[0]
            return
        mu = pts.mean(0)
        d = pts - mu
        _, axes = np.linalg.eigh(d.T @ d)
        c = x - mu
        # column by column: a (N, 3) x (3, 3) product through BLAS costs far more for tall N
        self.proj = c[:, :1] * axes[0] + c[:, 1:2] * axes[1] + c[:, 2:] * axes[2]
        self.lo = np.quantile(self.proj[sel], quantile, axis=0)
        self.hi = np.quantile(self.proj[sel], 1.0 - quantile, axis=0)
        self.pad = margin * float(np.max(self.hi - self.lo))

    def inside(self, extra: float) -> np.ndarray:
        if self.empty:
            return np.zeros(self.n, bool)
        p = self.pad + extra
        return np.all((self.proj >= self.lo - p) & (self.proj <= self.hi + p), axis=1)


def _spacing(points: np.ndarray, n_probe: int = 4096) -> float:
    """Median distance from (up to ``n_probe`` evenly picked) points to their nearest other point."""
    if points.shape[0] < 2:
        return 0.0
    probe = points[:: max(1, points.shape[0] // n_probe)]
    d = cKDTree(points).query(probe, k=2)[0][:, 1]
    return float(np.median(d))


def nearby_remainder(means, selected, quantile: float = 0.02, margin: float = 0.1, reach: float = 2.0) -> np.ndarray:
    """Bool (N,): unselected Gaussians in the object's region that the rest of the scene does not continue into.

    Parameters
    ----------
    means : (N, 3) array
    selected : (N,) bool
    quantile, margin : float
        The object's region (:func:`object_region`).
    reach : float > 0
        Two Gaussians are linked when their means lie within ``reach``
        times the typical spacing (below).

    Notes
    -----
    ``C`` = the unselected Gaussians of the region ``B``
    (:func:`object_region`); ``O`` = the unselected Gaussians outside
    ``B`` but within ``r`` of it (the box grown by ``r``). With ``h`` the
    larger of the median nearest-neighbour distances within the selection
    and within ``C`` and ``O``, ``r = reach h``; Gaussians of ``C`` and
    ``O`` closer than ``r`` are linked, and a Gaussian of ``C`` belongs to
    the nearby remainder when its linked component holds no Gaussian of
    ``O``. The ground under the object and a wall it stands against run
    on beyond the region and stay out; inner layers, shells and parts left
    inside it, and not touching the rest of the scene, are in.
    """
    x = np.asarray(means, np.float64)
    sel = np.asarray(selected, bool)
    if x.ndim != 2 or x.shape[1] != 3 or sel.shape != (x.shape[0],):
        raise ValidationError(f"nearby_remainder: means must be (N, 3) and selected bool (N,), got {x.shape} "
                              f"and {sel.shape}")
    if not 0 <= quantile < 0.5 or margin < 0 or not reach > 0:
        raise ValidationError(f"nearby_remainder: quantile must be in [0, 0.5), margin >= 0 and reach > 0, got "
                              f"{quantile}, {margin} and {reach}")
    box = _Box(x, sel, quantile, margin)
    cand = box.inside(0.0) & ~sel
    if not cand.any():
        return cand
    h0 = _spacing(x[sel])
    h = max(h0, _spacing(x[box.inside(reach * h0) & ~sel]))
    r = reach * h
    ring = box.inside(r) & ~sel & ~cand
    idx = np.flatnonzero(cand | ring)
    pairs = cKDTree(x[idx]).query_pairs(r, output_type="ndarray")
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(idx.size, idx.size))
    _, comp = connected_components(graph, directed=False)
    outside = np.zeros(comp.max() + 1, bool)
    outside[comp[ring[idx]]] = True
    out = np.zeros(x.shape[0], bool)
    out[idx[cand[idx] & ~outside[comp]]] = True
    return out


def _alone_alphas(W, camera, means: np.ndarray, rows: np.ndarray, selected: np.ndarray,
                  nearby: np.ndarray) -> tuple:
    """``(alpha_R, alpha_S+R)`` at ``rows``: the nearby remainder and the object's region rendered alone, from ``W``.

    Each pixel's Gaussians are taken front to back by the view depth of
    their means in ``camera``. See :func:`remainder_share`'s Notes.
    """
    sub = W[rows]
    present = np.zeros(W.shape[1], bool)
    present[sub.indices] = True
    cols = np.flatnonzero(present)
    front_to_back = cols[np.argsort(camera.world_to_view(means[cols])[:, 2], kind="stable")]
    rank = np.zeros(W.shape[1], sub.indices.dtype)
    rank[front_to_back] = np.arange(front_to_back.size)
    # each row's entries in depth order: columns renamed by depth rank, then sorted row by row
    ordered = sp.csr_matrix((sub.data, rank[sub.indices], sub.indptr), shape=(len(rows), front_to_back.size))
    ordered.has_sorted_indices = False
    ordered.sort_indices()
    counts = np.diff(ordered.indptr)
    pix = np.repeat(np.arange(len(rows)), counts)
    cols = front_to_back[ordered.indices]
    w = np.asarray(ordered.data, np.float64)
    run = np.cumsum(w)
    before = np.concatenate([[0.0], run])[ordered.indptr[:-1]]  # the weight in front of each row's first entry
    t = 1.0 - (run - w - np.repeat(before, counts))  # transmittance in front of each entry
    log_keep = np.log1p(-np.clip(w / np.maximum(t, 1e-12), 0.0, 0.99))
    ghost = nearby[cols]
    n = len(rows)
    alpha_r = 1.0 - np.exp(np.bincount(pix, weights=log_keep * ghost, minlength=n))
    alpha_sr = 1.0 - np.exp(np.bincount(pix, weights=log_keep * (ghost | selected[cols]), minlength=n))
    return alpha_r, alpha_sr


def remainder_share(operators, selected, means, *, footprint: float = 0.25, quantile: float = 0.02,
                    margin: float = 0.1, reach: float = 2.0) -> dict:
    """The share of the object's alpha that the remainder keeps at the object's place: ghosts left behind.

    Needs no truth: it reads the views an extraction rendered (their
    weights and cameras) and the selection it made, and renders nothing.

    Parameters
    ----------
    operators : OperatorStack or sequence of views
        The views ``W(c)`` (anything :func:`~seed2gs_inverse.operators.as_stack`
        accepts), each with its camera (for the depth order).
    selected : (N,) bool
        The selection (the object); the rest is the remainder.
    means : (N, 3) array
        Gaussian centres: the object's region (:func:`object_region`) and
        the depth order.
    footprint : float in (0, 1]
        A pixel is in the object's footprint where the selection's
        weight ``W(c) 1_S`` is at least this.
    quantile, margin, reach : float
        The nearby remainder (:func:`nearby_remainder`).

    Returns
    -------
    dict
        ``share`` (over all views), ``worst_view`` (the largest share of
        one view), ``per_view`` (NaN for a view without footprint),
        ``n_nearby`` ``|R|`` and ``footprint_pixels`` (summed over views).
        Both shares are NaN when no view has a footprint pixel.

    Raises
    ------
    ValidationError
        Bad shapes or parameters, a view without a camera, or operators
        :func:`~seed2gs_inverse.operators.as_stack` refuses.

    Notes
    -----
    With ``S`` the selection and ``R`` the nearby remainder
    (:func:`nearby_remainder`: unselected Gaussians in the selection's
    robust bounding box that the rest of the scene does not continue
    into), each view's footprint is
    ``F(c) = {u : (W(c) 1_S)(u) >= footprint}``. At a pixel, with its
    Gaussians ordered front to back by the depth of their means (the
    rasterizer's order), every Gaussian's own alpha follows from the
    weights:

    .. math::

        \\alpha_i(u) = W[u, i] / T_i(u), \\quad
        T_i(u) = 1 - \\sum_{j \\text{ in front of } i} W[u, j],

    and a set ``X`` rendered alone has the alpha
    ``alpha_X(u) = 1 - prod_{i in X} (1 - alpha_i(u))``. The share is

    .. math::

        share = \\sum_c \\sum_{u \\in F(c)} \\alpha_R(u) \\Big/
                \\sum_c \\sum_{u \\in F(c)} \\alpha_{S \\cup R}(u)

    (a view's share: the same sums over that view): how opaque what stays
    at the object's place is once the object is removed, next to the
    object's region rendered alone. The region keeps out what stands
    apart from the object (an occluder in front of it), the continuity
    what runs on beyond it (the ground under its base, a wall it stands
    against): they show where the object was after its removal and are
    no ghosts. The figure is an estimate, not a bound, and errs both ways:
    a Gaussian the rasterizer did not reach (behind a pixel whose
    transmittance fell below its cut-off, as behind an opaque selected front
    layer) has no weight there and counts for nothing at that pixel,
    although it shows once the object is removed (weights an operator
    dropped, its ``min_weight``, are missing from the transmittance too);
    and scene Gaussians inside the object's region that the continuity test
    does not link to the rest of the scene (sparse ground right under the
    object, clutter touching it) count although they are no part of it,
    most in views that graze the ground. ``benchmarks/bench_extract.py``
    prints it beside the truth's alpha-weighted recall, which measures what
    the remainder really keeps.
    """
    stack = as_stack(operators)
    n = stack.n_gaussians
    s = _membership("remainder_share", "selected", selected, n)
    x = np.asarray(means, np.float64)
    if x.shape != (n, 3):
        raise ValidationError(f"remainder_share: means must have shape ({n}, 3), got {x.shape}")
    if not 0 < footprint <= 1:
        raise ValidationError(f"remainder_share: footprint must be in (0, 1], got {footprint}")
    for i, v in enumerate(stack):
        if v.camera is None:
            raise ValidationError(f"remainder_share: view {i} has no camera; the depth order of its "
                                  f"Gaussians needs one (operators from build_operator carry theirs)")
    r = nearby_remainder(x, s, quantile, margin, reach)
    ghost, whole, per_view, n_px = 0.0, 0.0, [], 0
    for v in stack:
        rows = np.flatnonzero(np.asarray(v.W @ s.astype(np.float32)) >= footprint)
        n_px += rows.size
        if rows.size == 0:
            per_view.append(float("nan"))
            continue
        a_g, a_sg = _alone_alphas(v.W, v.camera, x, rows, s, r)
        g, o = float(a_g.sum()), float(a_sg.sum())
        ghost, whole = ghost + g, whole + o
        per_view.append(g / o if o > 0 else float("nan"))
    seen = [p for p in per_view if not np.isnan(p)]
    return {"share": ghost / whole if whole > 0 else float("nan"),
            "worst_view": max(seen) if seen else float("nan"), "per_view": per_view,
            "n_nearby": int(r.sum()), "footprint_pixels": n_px}
