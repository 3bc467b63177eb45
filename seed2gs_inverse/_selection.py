"""Selections given as a boolean mask or as integer indices: Gaussians (``init=``, edit selections)
and views (``OperatorStack.subset``, ``compare(holdout=)``)."""

from __future__ import annotations

import numpy as np

from .errors import ValidationError

__all__ = ["support_mask", "index_list"]


def support_mask(values, n: int, name: str) -> np.ndarray:
    """Bool (n,) from a bool (n,) mask or 1-D integer indices in [0, n); ``name`` heads the errors.

    An integer array of ``n`` > 2 entries that holds only 0 and 1 is refused:
    it reads as a 0/1 mask but would select Gaussians 0 and 1 only.
    """
    a = np.asarray(values)
    if a.dtype == bool:
        if a.shape != (n,):
            raise ValidationError(f"{name}: a bool mask must have shape ({n},), got {a.shape}")
        return a.copy()
    if a.shape == (0,) and a.dtype.kind in "iuf":  # an empty list (numpy makes it float64): none
        return np.zeros(n, bool)
    if a.dtype.kind not in "iu" or a.ndim != 1:
        raise ValidationError(f"{name} must be a bool mask of length {n} or 1-D integer indices, "
                              f"got dtype {a.dtype} shape {a.shape}")
    if a.size and (int(a.min()) < 0 or int(a.max()) >= n):
        raise ValidationError(f"{name}: indices must lie in [0, {n}), got range [{int(a.min())}, {int(a.max())}]")
    if a.shape == (n,) and n > 2 and np.all((a == 0) | (a == 1)):
        raise ValidationError(f"{name}: {n} integers that are all 0 or 1 look like a 0/1 mask, but integers are "
                              f"Gaussian indices (this would select Gaussians 0 and 1 only); pass a bool mask, "
                              f"e.g. labels.astype(bool)")
    out = np.zeros(n, bool)
    out[a] = True
    return out


def support_indices(values, n: int, name: str) -> np.ndarray:
    """Ascending unique int64 indices of the selection ``values`` by :func:`support_mask`'s rule (None: all)."""
    if values is None:
        return np.arange(n, dtype=np.int64)
    return np.flatnonzero(support_mask(values, n, name)).astype(np.int64)


def index_list(values, n: int, name: str, negative: bool = False) -> np.ndarray:
    """int64 indices into ``n`` items from integer indices or a bool mask of length ``n``.

    Anything else (floats such as 1.7, a bool mask of another length) is a
    ValidationError headed by ``name``; ``negative`` allows Python's
    counting from the end.
    """
    a = np.atleast_1d(np.asarray(values))
    if a.dtype == bool:
        if a.shape != (n,):
            raise ValidationError(f"{name}: a bool mask must have shape ({n},), got {a.shape}")
        return np.flatnonzero(a).astype(np.int64)
    if a.size and a.dtype.kind not in "iu":
        raise ValidationError(f"{name} must be integer indices or a bool mask of length {n}, got dtype {a.dtype}")
    a = a.astype(np.int64).reshape(-1)
    lo = -n if negative else 0
    bad = a[(a < lo) | (a >= n)]
    if bad.size:
        raise ValidationError(f"{name}: index {int(bad[0])} is out of range for {n} items")
    return a
