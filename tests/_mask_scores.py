"""Reference mask scores written out from their definitions, independent of metrics.py.

IoU = |P & G| / |P | G|. Boundary IoU (Cheng et al. 2021, the LERF-Mask
evaluator's): a mask's boundary is the mask minus its erosion by
d = max(1, round(0.02 * image diagonal)) pixels with a 3x3 structuring
element and a zero border; the score is the IoU of the two boundaries.
"""

from __future__ import annotations

import numpy as np


def iou_reference(pred: np.ndarray, gt: np.ndarray) -> float:
    return (pred & gt).sum() / (pred | gt).sum()


def erode_reference(mask: np.ndarray, d: int) -> np.ndarray:
    """A pixel survives d 3x3 erosions of the zero-padded mask iff its (2d+1)^2 window
    lies inside the image and is all object (chessboard distance)."""
    h, w = mask.shape
    out = np.zeros_like(mask)
    for y in range(h):
        for x in range(w):
            if y - d < 0 or x - d < 0 or y + d >= h or x + d >= w:
                continue
            out[y, x] = mask[y - d:y + d + 1, x - d:x + d + 1].all()
    return out


def biou_reference(a: np.ndarray, b: np.ndarray) -> float:
    h, w = a.shape
    d = max(1, int(round(0.02 * np.hypot(h, w))))
    ba, bb = a & ~erode_reference(a, d), b & ~erode_reference(b, d)
    return (ba & bb).sum() / (ba | bb).sum()
