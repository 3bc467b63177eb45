"""Metrics against hand-counted values."""

from __future__ import annotations

import numpy as np
import pytest

from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.metrics import (boundary_iou, boundary_width, iou, mask_boundary, membership_scores,
                                     protocol_mean)


def _square(shape, r0, r1, c0, c1):
    m = np.zeros(shape, bool)
    m[r0:r1, c0:c1] = True
    return m


def test_iou_hand_counted():
    a = _square((10, 10), 2, 6, 2, 6)   # 16 px
    b = _square((10, 10), 2, 6, 3, 7)   # 16 px, 12 shared
    assert iou(a, b) == pytest.approx(12 / 20)
    assert iou(a, a) == 1.0 and iou(a, ~a) == 0.0
    assert iou(np.zeros((3, 3)), np.zeros((3, 3))) == 1.0
    assert iou(a.astype(np.uint8) * 255, b) == pytest.approx(0.6)


def test_boundary_width_formula():
    assert boundary_width((10, 10)) == 1          # 0.28 -> at least 1
    assert boundary_width((60, 60)) == 2          # 1.70 -> 2
    assert boundary_width((540, 960)) == 22       # 22.03
    assert boundary_width((1000, 1000)) == 28     # 28.28


def test_boundary_of_square_is_its_ring():
    # 4x4 square, one erosion (d = 1): the inner 2x2 survives, the 12-pixel ring is the boundary
    a = _square((10, 10), 2, 6, 2, 6)
    ring = a & ~_square((10, 10), 3, 5, 3, 5)
    np.testing.assert_array_equal(mask_boundary(a), ring)
    # d = 2 on a 60x60 image: a 10x10 square keeps its inner 6x6
    big = _square((60, 60), 10, 20, 10, 20)
    assert mask_boundary(big).sum() == 100 - 36
    # the image border counts as boundary (zero padding): a full 5x5 mask has a 16-pixel ring
    assert mask_boundary(np.ones((5, 5), bool)).sum() == 16


def test_boundary_iou_hand_counted():
    a = _square((10, 10), 2, 6, 2, 6)
    b = _square((10, 10), 2, 6, 3, 7)
    # rings of 12 pixels each; in the shared 4x3 block the 6 pixels inner to either square drop out
    assert boundary_iou(a, b) == pytest.approx(6 / 18)
    assert boundary_iou(a, a) == 1.0
    assert boundary_iou(np.zeros((4, 4)), np.zeros((4, 4))) == 1.0
    with pytest.raises(ValidationError, match="shape"):
        boundary_iou(a, a[:5])
    with pytest.raises(ValidationError, match="2-D"):
        boundary_iou(a.ravel(), a.ravel())


def test_protocol_mean_averages_views_then_targets_then_scenes():
    overall, per_scene, per_target = protocol_mean({"A": {"t1": [1.0, 0.5], "t2": [0.0]}, "B": {"t": [1.0]}})
    assert per_target["A"] == {"t1": 0.75, "t2": 0.0}
    assert per_scene == {"A": 0.375, "B": 1.0}
    assert overall == pytest.approx(0.6875)
    with pytest.raises(ValidationError, match="no views"):
        protocol_mean({"A": {"t": []}})


def test_membership_scores_hand_counted():
    truth = np.array([1, 1, 1, 0, 0, 0], bool)
    sel = np.array([1, 1, 0, 1, 0, 0], bool)   # TP 2, FN 1, FP 1
    s = membership_scores(sel, truth)
    assert (s["tp"], s["fp"], s["fn"]) == (2, 1, 1)
    assert s["precision"] == pytest.approx(2 / 3) and s["recall"] == pytest.approx(2 / 3)
    assert s["iou"] == pytest.approx(0.5) and "weighted_iou" not in s
    w = np.array([1.0, 3.0, 0.0, 2.0, 5.0, 0.0])   # TP 4, FP 2, FN 0
    s = membership_scores(sel.astype(np.float32) * 0.9, truth, weights=w)
    assert s["weighted_precision"] == pytest.approx(4 / 6) and s["weighted_recall"] == 1.0
    assert s["weighted_iou"] == pytest.approx(4 / 6)
    assert membership_scores(np.array([0.4, 0.6]), np.array([True, True]), threshold=0.3)["recall"] == 1.0
    # q exactly at the threshold (an unobserved Gaussian started at 0.5) is not selected
    tie = membership_scores(np.array([0.5, 0.5, 0.7]), np.array([True, False, True]))
    assert (tie["tp"], tie["fp"], tie["fn"]) == (1, 0, 1)
    # nothing selected and nothing true: 0/0 counts as a perfect score
    none = membership_scores(np.zeros(3, bool), np.zeros(3, bool))
    assert none["iou"] == 1.0 and (none["tp"], none["fp"], none["fn"]) == (0, 0, 0)
    with pytest.raises(ValidationError, match="labels must be bool"):
        membership_scores(sel, truth.astype(int))
    with pytest.raises(ValidationError, match="weights"):
        membership_scores(sel, truth, weights=-w)


def test_boundary_iou_default_width_on_a_larger_image():
    """On 100x80 the default boundary is d = round(0.02 x 128.1) = 3 pixels wide (on the small images above
    any ratio gives 1): the score equals the reference written from the definition."""
    from _mask_scores import biou_reference

    yy, xx = np.mgrid[0:80, 0:100]
    a = (xx - 45) ** 2 + (yy - 40) ** 2 < 25 ** 2
    b = (np.abs(xx - 52) < 22) & (np.abs(yy - 38) < 20)
    assert boundary_iou(a, b) == pytest.approx(biou_reference(a, b), abs=1e-12)
    assert boundary_iou(a, b) != pytest.approx(boundary_iou(a, b, dilation_ratio=0.01), abs=1e-3)


def test_grey_level_masks_are_refused_not_read_as_nonzero():
    """A raw 0..255 mask counted every nonzero grey as object; the protocol's ground truth is grey > 128."""
    grey = np.array([[0, 100, 255], [0, 200, 0]], np.uint8)
    for fn in (iou, boundary_iou):
        with pytest.raises(ValidationError, match=r"values other than 0 and 1 \(or 255\).*grey > 128"):
            fn(grey, grey > 128)
        with pytest.raises(ValidationError, match="truth holds values other than 0 and 1"):
            fn(grey > 128, grey.astype(np.float32) / 255)
    assert iou(np.array([[0, 1, 1]], np.uint8), np.array([[0.0, 1.0, 0.0]])) == 0.5  # 0/1 numbers are masks
