"""Scene edits on a selection of Gaussians: remove, duplicate, move, recolour.

Every function returns a new :class:`~seed2gs_inverse.scene.GaussianScene`;
the input is never modified. Per-Gaussian ``extra`` properties travel with
their Gaussians (copied for duplicates), so writing the result with
:func:`seed2gs_inverse.io.write_scene` keeps every property of the file.
A selection is a boolean mask of length N or an array of indices.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._selection import support_mask
from .errors import ValidationError
from .scene import GaussianScene, quat_to_rotmat
from .sh import SH_C0

__all__ = ["selection_mask", "remove", "duplicate", "move", "recolour", "recolor"]


def selection_mask(scene: GaussianScene, selected) -> np.ndarray:
    """Boolean (N,) mask of a selection given as a bool mask or integer indices."""
    return support_mask(selected, len(scene), "selected")


def _replace(scene: GaussianScene, mask: np.ndarray, part: GaussianScene) -> GaussianScene:
    """``scene`` with the rows of ``mask`` replaced by ``part`` (same order and extras)."""
    # Scene arrays are read-only: edit writeable copies and validate them as a new scene.
    arrays = {}
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        arr = getattr(scene, name).copy()
        arr[mask] = getattr(part, name)
        arrays[name] = arr
    extra = {}
    for k, v in scene.extra.items():
        extra[k] = v.copy()
        extra[k][mask] = part.extra[k]
    return GaussianScene(extra=extra, layout=scene.layout, **arrays)


def _vector(value, name: str, shape) -> np.ndarray:
    """``value`` as a finite float64 array of ``shape`` (a tuple, or a list of accepted shapes)."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    shapes = shape if isinstance(shape, list) else [shape]
    if a is None or a.shape not in shapes or not np.all(np.isfinite(a)):
        want = " or ".join("x".join(map(str, s)) if len(s) > 1 else f"{s[0]}-vector" for s in shapes)
        raise ValidationError(f"{name} must be finite numbers of shape {want}, got {value!r}")
    return a


def _scale(scale) -> float:
    if isinstance(scale, (bool, np.bool_)) or not isinstance(scale, (int, float, np.integer, np.floating)) or not (
            np.isfinite(scale) and scale > 0):
        raise ValidationError(f"scale must be a positive finite number, got {scale!r}")
    return float(scale)


def _rigid(rotation, translation, pivot):
    rot = np.eye(3) if rotation is None else _vector(rotation, "rotation", [(3, 3), (4,)])
    if rot.shape == (4,):  # w-first quaternion
        if not np.linalg.norm(rot) > 0:
            raise ValidationError("rotation: a quaternion must not be zero")
        rot = quat_to_rotmat(rot[None])[0]  # (a 3x3 matrix is checked by GaussianScene.transformed)
    t = np.zeros(3) if translation is None else np.asarray(translation, dtype=np.float64)
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValidationError(f"translation must be a finite 3-vector, got {translation!r}")
    p = np.zeros(3) if pivot is None else np.asarray(pivot, dtype=np.float64)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValidationError(f"pivot must be a finite 3-vector, got {pivot!r}")
    return rot, t, p


def remove(scene: GaussianScene, selected) -> GaussianScene:
    """The scene without the selected Gaussians."""
    return scene.subset(~selection_mask(scene, selected))


def move(scene: GaussianScene, selected, rotation=None, translation=None, pivot=None,
         scale: float = 1.0) -> GaussianScene:
    r"""Move the selected Gaussians by :math:`x \mapsto s R (x - p) + p + t`.

    ``rotation`` is a 3x3 proper rotation or a w-first quaternion; ``pivot``
    ``p`` defaults to the selection's centroid (so a rotation turns the
    object in place), ``scale`` ``s`` > 0. Rotations, scales and SH
    coefficients follow (:meth:`GaussianScene.transformed`), so the moved
    object keeps its view-dependent appearance. Order and count are unchanged.
    """
    mask = selection_mask(scene, selected)
    if not mask.any():
        raise ValidationError("move: the selection is empty")
    if pivot is None:
        pivot = scene.means[mask].astype(np.float64).mean(axis=0)
    rot, t, p = _rigid(rotation, translation, pivot)
    scale = _scale(scale)
    part = scene.subset(mask).transformed(rot, p + t - scale * (rot @ p), scale)
    return _replace(scene, mask, part)


def duplicate(scene: GaussianScene, selected, translation=None, rotation=None, pivot=None,
              scale: float = 1.0) -> GaussianScene:
    """The scene plus a moved copy of the selected Gaussians, appended at the end.

    The copies follow the scene's order (ascending indices), one per selected
    Gaussian, however the selection is given.

    The copy is placed by :func:`move`'s transform (translation, rotation about
    ``pivot`` = the selection centroid by default, scale); extras are copied.
    """
    mask = selection_mask(scene, selected)
    if not mask.any():
        raise ValidationError("duplicate: the selection is empty")
    part = scene.subset(mask)
    moved = move(part, np.ones(len(part), bool), rotation, translation,
                 part.means.astype(np.float64).mean(axis=0) if pivot is None else pivot, scale)
    return GaussianScene.concat([scene, moved])


def recolour(scene: GaussianScene, selected, rgb, keep_view_dependence: bool = False) -> GaussianScene:
    r"""Give the selected Gaussians a new base colour.

    Parameters
    ----------
    selected : bool (N,) mask or integer indices
        The Gaussians to recolour, each once; row ``k`` of an (M, 3) ``rgb``
        goes to the ``k``-th selected Gaussian (in ascending order for a
        mask, in the given order for indices).
    rgb : (3,) or (M, 3) array in [0, 1], or callable
        The new colour; a callable receives the current base colours (M, 3)
        (``SH_C0 * dc + 0.5``, rows as above) and returns new ones (tinting, hue shifts).
    keep_view_dependence : bool
        False (default): higher SH bands are zeroed, so the object shows
        exactly ``rgb`` from every direction. True: only the DC term
        changes, keeping the view-dependent highlights of the original.

    The DC coefficient is set so that the degree-0 colour is
    ``SH_C0 * dc + 0.5 = rgb`` (3DGS convention).
    """
    mask = selection_mask(scene, selected)  # checks either form
    given = np.asarray(selected)
    # rows of rgb follow the selection: ascending for a mask, in the given order for indices
    idx = np.flatnonzero(mask) if given.dtype == bool else given.astype(np.int64)
    m = idx.size
    if m == 0:
        raise ValidationError("recolour: the selection is empty")
    if m != np.count_nonzero(mask):
        raise ValidationError("recolour: a Gaussian is selected more than once; give each index once")
    base = SH_C0 * scene.sh[idx, 0].astype(np.float64) + 0.5
    new = np.asarray(rgb(base) if callable(rgb) else rgb, dtype=np.float64)
    if new.shape == (3,):
        new = np.broadcast_to(new, (m, 3))
    if new.shape != (m, 3) or not np.all(np.isfinite(new)):
        raise ValidationError(f"recolour: rgb must be finite (3,) or ({m}, 3), got shape {new.shape}")
    if not callable(rgb) and (new.min() < 0.0 or new.max() > 1.0):
        # (a callable maps the current colours, which real scenes hold slightly outside [0, 1] too)
        raise ValidationError(f"recolour: rgb must lie in [0, 1], got values in [{new.min():.3g}, {new.max():.3g}]")
    sh = scene.sh.copy()  # scene arrays are read-only; the new scene validates the copy
    sh[idx, 0] = ((new - 0.5) / SH_C0).astype(np.float32)
    if not keep_view_dependence:
        sh[idx, 1:] = 0.0
    return dataclasses.replace(scene, sh=sh)


recolor = recolour
