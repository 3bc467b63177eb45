"""Supervision masks: ground truth from labels, and noise models of tracker failures.

Masks are float arrays in [0, 1] of shape ``(H, W)``; NaN marks unknown
pixels that carry no evidence. Ground-truth masks threshold the rendered
object weight ``W(c) 1_object`` (:func:`masks_from_labels`,
:func:`render_label_masks`); :func:`perturb_masks` corrupts them the way a
2D tracker fails.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from ..errors import ValidationError
from ..operators import as_stack
from ..raster import build_operator

if TYPE_CHECKING:
    from ..scene import GaussianScene

__all__ = ["masks_from_labels", "render_label_masks", "perturb_masks", "NOISE_KINDS"]


def _selection(selected, n: int) -> np.ndarray:
    sel = np.asarray(selected)
    if sel.ndim != 1 or sel.shape[0] != n:
        raise ValidationError(f"'selected' has shape {sel.shape}; expected ({n},), one entry per Gaussian")
    if sel.dtype == bool:
        return sel.astype(np.float32)
    if sel.dtype.kind not in "fiu" or not np.all(np.isfinite(sel)) or sel.min() < 0 or sel.max() > 1:
        raise ValidationError("'selected' must be boolean or numbers in [0, 1] (a membership per Gaussian)")
    return sel.astype(np.float32)


def masks_from_labels(operators, selected, threshold: float | None = 0.5) -> list[np.ndarray]:
    """Ground-truth masks of a set of Gaussians, one per view.

    For view c the object's rendered weight is ``P(c) = W(c) l`` with
    ``l`` the 0/1 (or soft) membership, i.e. the fraction of each pixel's
    colour that the object contributes, occlusions included. The mask is
    ``P(c) > threshold``.

    Parameters
    ----------
    operators : OperatorStack or sequence
        Anything :func:`~seed2gs_inverse.operators.as_stack` accepts:
        ``ViewOperator`` items, sparse matrices or ``(W, (H, W))`` pairs (W
        sparse or dense). Needs only numpy/scipy.
    selected : (N,) bool or float in [0, 1]
        Membership of each Gaussian.
    threshold : float or None
        None returns the soft weight ``P(c)`` itself (float32 in [0, 1]).

    Returns
    -------
    list of (H, W) float32 arrays with values 0/1 (or soft).
    """
    if threshold is not None and not (np.isfinite(threshold) and 0 <= threshold < 1):
        raise ValidationError(f"threshold must be in [0, 1) or None, got {threshold!r}")
    if isinstance(operators, (list, tuple)) and not operators:
        raise ValidationError("masks_from_labels needs at least one view")
    stack = as_stack(operators)
    sel = _selection(selected, stack.n_gaussians)
    out = []
    for view in stack:
        p = np.asarray(view.W @ sel, dtype=np.float32).reshape(view.image_shape)
        out.append(np.clip(p, 0, 1) if threshold is None else (p > threshold).astype(np.float32))
    return out


def render_label_masks(scene: GaussianScene, cameras, selected,
                       threshold: float | None = 0.5) -> list[np.ndarray]:
    """Ground-truth masks of ``selected`` Gaussians seen by ``cameras``.

    Builds each view's operator with
    :func:`seed2gs_inverse.raster.build_operator` and applies
    :func:`masks_from_labels`. Use the operators directly when you have
    them already (building is the expensive part).
    """
    cams = list(cameras)
    if not cams:
        raise ValidationError("render_label_masks needs at least one camera")
    _selection(selected, len(scene))
    return masks_from_labels([build_operator(scene, c) for c in cams], selected, threshold)


NOISE_KINDS = ("dilate", "erode", "drift", "drop", "identity_switch", "salt")
_DEFAULT_FRACTION = {"dilate": 1.0, "erode": 1.0, "drift": 1.0, "salt": 1.0,
                     "drop": 0.25, "identity_switch": 0.25}


def _check_masks(masks, what="masks") -> list[np.ndarray]:
    if isinstance(masks, np.ndarray) and masks.ndim == 2:
        raise ValidationError(f"'{what}' must be a list of (H, W) masks (or an (V, H, W) array), "
                              "got a single 2-D array")
    out = []
    for v, m in enumerate(masks):
        a = np.asarray(m)
        if a.ndim != 2:
            raise ValidationError(f"{what}[{v}] has shape {a.shape}; a mask must be (H, W)")
        if a.dtype.kind not in "biuf":
            raise ValidationError(f"{what}[{v}] has dtype {a.dtype}; expected bool or float")
        a = a.astype(np.float32)
        known = a[~np.isnan(a)]
        if known.size and (np.any(~np.isfinite(known)) or known.min() < 0 or known.max() > 1):
            raise ValidationError(f"{what}[{v}] has values outside [0, 1] (NaN is the only "
                                  "allowed non-number, meaning unknown)")
        out.append(a)
    if not out:
        raise ValidationError(f"'{what}' is empty")
    return out


def _disk_footprint(radius: int) -> np.ndarray:
    r = np.arange(-radius, radius + 1)
    return (r[:, None] ** 2 + r[None, :] ** 2) <= radius * radius


def _shift(mask: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """Move the content by (dy, dx) pixels; pixels moving in from outside are 0."""
    h, w = mask.shape
    out = np.zeros_like(mask)
    if abs(dy) >= h or abs(dx) >= w:
        return out
    out[max(dy, 0):h + min(dy, 0), max(dx, 0):w + min(dx, 0)] = \
        mask[max(-dy, 0):h - max(dy, 0), max(-dx, 0):w - max(dx, 0)]
    return out


def perturb_masks(masks, kind: str, rng=None, strength=None, fraction: float | None = None,
                  other_masks=None, views=None, direction=None, growth: str = "linear",
                  return_views: bool = False):
    """Corrupt supervision masks the way a 2D tracker fails.

    Masks are float arrays in [0, 1], NaN = unknown; the input is not
    modified. The views to corrupt are ``views`` if given, else
    ``round(fraction * V)`` views drawn without replacement by ``rng``.

    ==================  ===========================================  ================
    kind                effect on each chosen view                   strength
    ==================  ===========================================  ================
    ``dilate``          grey dilation (max over a disk): the         radius px (2)
                        boundary grows outwards
    ``erode``           grey erosion (min over a disk)               radius px (2)
    ``drift``           content shifted by d px along ``direction``  d px (4)
                        (angle in degrees, or a (dx, dy) vector;
                        random when None). ``growth="linear"``:
                        view i of V moves ``d i / (V-1)`` (the first
                        view is exact, the last off by d, like a
                        tracker drifting along a clip);
                        ``"constant"``: every chosen view moves d.
                        Pixels entering from the border are 0.
    ``drop``            every pixel NaN (the view is lost)           unused
    ``identity_switch`` replaced by ``other_masks[i]`` (the tracker  unused
                        jumped to another object)
    ``salt``            each known pixel flips ``m -> 1 - m`` with   p (0.05)
                        probability p
    ==================  ===========================================  ================

    Dilation and erosion leave NaN pixels NaN and treat them as background
    while filtering, so unknown regions never spread evidence.

    Parameters
    ----------
    masks : sequence of (H, W) arrays
    kind : str
        One of ``NOISE_KINDS``.
    rng : numpy Generator, int seed or None
        Randomness (view choice, salt, random direction). Pass one for
        reproducible results.
    strength : float, optional
        See the table.
    fraction : float, optional
        Fraction of views to corrupt; default 1 for dilate, erode, drift
        and salt, 0.25 for drop and identity_switch.
    other_masks : sequence of (H, W) arrays
        Required for ``identity_switch``: another object's masks, same
        number and shapes.
    views : sequence of int, optional
        Exactly which views to corrupt (overrides ``fraction``).
    direction : float or (2,) array, optional
        Drift direction (degrees from +x towards +y, image axes, or a
        ``(dx, dy)`` vector).
    growth : {"linear", "constant"}
        Drift profile along the clip.
    return_views : bool
        Also return the sorted indices of the corrupted views.

    Returns
    -------
    list of (H, W) float32 masks, and the view indices if ``return_views``.
    """
    if kind not in NOISE_KINDS:
        raise ValidationError(f"unknown noise kind {kind!r}; choose one of {', '.join(NOISE_KINDS)}")
    masks = _check_masks(masks)
    n = len(masks)
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    if views is not None:
        chosen = np.unique(np.asarray(views, dtype=np.int64).ravel())
        if chosen.size and (chosen.min() < -n or chosen.max() >= n):
            raise ValidationError(f"views {np.asarray(views).tolist()} out of range for {n} masks")
        chosen = np.unique(chosen % n)
    else:
        frac = _DEFAULT_FRACTION[kind] if fraction is None else float(fraction)
        if not (np.isfinite(frac) and 0 <= frac <= 1):
            raise ValidationError(f"fraction must be in [0, 1], got {fraction!r}")
        chosen = np.sort(rng.choice(n, size=int(round(frac * n)), replace=False))
    others = None
    if kind == "identity_switch":
        if other_masks is None:
            raise ValidationError("identity_switch needs other_masks: the masks of the object "
                                  "the tracker switches to")
        others = _check_masks(other_masks, "other_masks")
        if len(others) != n:
            raise ValidationError(f"other_masks has {len(others)} masks; masks has {n}")
    defaults = {"dilate": 2, "erode": 2, "drift": 4, "salt": 0.05}
    s = defaults.get(kind) if strength is None else strength
    if kind in ("dilate", "erode"):
        if not (float(s).is_integer() and s >= 0):
            raise ValidationError(f"{kind} strength is a radius in pixels (integer >= 0), got {s!r}")
        foot = _disk_footprint(int(s))
    elif kind == "salt":
        if not (np.isfinite(s) and 0 <= s <= 1):
            raise ValidationError(f"salt strength is a flip probability in [0, 1], got {s!r}")
    elif kind == "drift":
        if not (np.isfinite(s) and s >= 0):
            raise ValidationError(f"drift strength is a distance in pixels (>= 0), got {s!r}")
        if growth not in ("linear", "constant"):
            raise ValidationError(f"growth must be 'linear' or 'constant', got {growth!r}")
        if direction is None:
            direction = rng.uniform(0, 360)
        d = np.asarray(direction, dtype=np.float64)
        if d.ndim == 0:
            d = np.array([np.cos(np.radians(d)), np.sin(np.radians(d))])
        if d.shape != (2,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise ValidationError(f"direction must be an angle in degrees or a non-zero (dx, dy), got {direction!r}")
        d = d / np.linalg.norm(d)

    out = [m.copy() for m in masks]
    for i in chosen:
        m = masks[i]
        unknown = np.isnan(m)
        if kind in ("dilate", "erode"):
            filled = np.where(unknown, 0.0, m).astype(np.float32)
            op = ndimage.grey_dilation if kind == "dilate" else ndimage.grey_erosion
            # Outside the image is background for both, so erosion eats in from the border too.
            r = op(filled, footprint=foot, mode="constant", cval=0.0)
            out[i] = np.where(unknown, np.nan, r).astype(np.float32)
        elif kind == "drift":
            f = (i / (n - 1) if n > 1 else 1.0) if growth == "linear" else 1.0
            dx, dy = np.rint(s * f * d).astype(int)
            out[i] = _shift(m, int(dy), int(dx))
        elif kind == "drop":
            out[i] = np.full_like(m, np.nan)
        elif kind == "identity_switch":
            if others[i].shape != m.shape:
                raise ValidationError(f"other_masks[{i}] has shape {others[i].shape}; masks[{i}] has {m.shape}")
            out[i] = others[i].copy()
        else:  # salt
            flip = (rng.random(m.shape) < s) & ~unknown
            out[i] = np.where(flip, 1.0 - m, m).astype(np.float32)
    return (out, [int(i) for i in chosen]) if return_views else out
