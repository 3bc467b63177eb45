"""Segmentation scores: 2D IoU and boundary IoU, 3D membership scores.

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
"""

from __future__ import annotations

import numpy as np

from .errors import ValidationError

__all__ = ["iou", "boundary_iou", "mask_boundary", "boundary_width", "protocol_mean", "membership_scores"]


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
