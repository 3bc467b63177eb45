"""Argument validators shared by every layer.

Each validator takes the argument's name as the user wrote it (``"n_views"``,
``"method 'voting': option bias"``) and returns the value in canonical form
(a ``float``, an ``int``, a float64 array), or raises
:class:`~seed2gs_inverse.errors.ValidationError` with a one-line message that
names the argument, says what it must be and shows what was given.

Bools are never numbers here: ``True`` is refused where a count or a real
is expected, because it is almost always a misplaced flag.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from .errors import ValidationError

__all__ = ["as_real", "check_real", "check_int", "check_choice", "check_vector"]


def _is_bool(value) -> bool:
    return isinstance(value, (bool, np.bool_))


def as_real(value) -> float | None:
    """``value`` as a float when it is a finite real number (not a bool), else None.

    Safe for any input: a Python int beyond float's range gives None instead of
    ``np.isfinite``'s TypeError or ``float``'s OverflowError.
    """
    if _is_bool(value) or not isinstance(value, (int, float, np.integer, np.floating)):
        return None
    try:
        f = float(value)
    except OverflowError:
        return None
    return f if math.isfinite(f) else None


def check_real(name: str, value, *, lo: float | None = None, hi: float | None = None,
               lo_open: bool = False, hi_open: bool = False, optional: bool = False) -> float | None:
    """``value`` as a finite float in the given range (None passes when ``optional``).

    Parameters
    ----------
    name : str
        The argument as the user knows it; it starts every message.
    value : object
        Any real number except a bool.
    lo, hi : float or None
        Bounds, inclusive unless ``lo_open`` / ``hi_open``.
    optional : bool
        Whether None is accepted (and returned).

    Raises
    ------
    ValidationError
        Not a real number, not finite, or out of range.
    """
    if value is None and optional:
        return None
    if _is_bool(value) or not isinstance(value, numbers.Real):
        kind = "a number or None" if optional else "a number"
        raise ValidationError(f"{name} must be {kind}, got {value!r} ({type(value).__name__})")
    try:
        v = float(value)
    except OverflowError:  # an int beyond float's range (10**400)
        v = math.inf
    if not math.isfinite(v):
        raise ValidationError(f"{name} must be finite, got {value!r}")
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise ValidationError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {value!r}")
    if hi is not None and (v >= hi if hi_open else v > hi):
        raise ValidationError(f"{name} must be {'<' if hi_open else '<='} {hi}, got {value!r}")
    return v


def check_int(name: str, value, *, lo: int, hi: int | None = None, optional: bool = False) -> int | None:
    """``value`` as an int in ``lo..hi`` (no upper bound when ``hi`` is None).

    Integral floats (``3.0``) are refused: a count given as a fraction is
    usually a different option given by mistake.

    Raises
    ------
    ValidationError
        Not an integer (bools included) or out of range; the message gives the range.
    """
    if value is None and optional:
        return None
    span = f"{lo:,}..{hi:,}" if hi is not None else f">= {lo:,}"
    if _is_bool(value) or not isinstance(value, numbers.Integral):
        kind = "an integer or None" if optional else "an integer"
        where = f" in {span}" if hi is not None else f" {span}"
        raise ValidationError(f"{name} must be {kind}{where}, got {value!r} ({type(value).__name__})")
    if int(value) < lo or (hi is not None and int(value) > hi):
        raise ValidationError(f"{name} must be {'in ' if hi is not None else ''}{span}, got {value!r}")
    return int(value)


def check_choice(name: str, value, choices) -> str:
    """``value`` when it is one of the strings ``choices``.

    Raises
    ------
    ValidationError
        Not a string, or not one of ``choices`` (the message lists them).
    """
    if not isinstance(value, str) or value not in choices:
        raise ValidationError(f"{name} must be one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


def check_vector(name: str, value, size: int = 3, *, nonzero: bool = False) -> np.ndarray:
    """``value`` as a finite float64 vector of ``size`` entries (not all zero when ``nonzero``).

    Raises
    ------
    ValidationError
        Not numeric, wrong size, not finite, or zero when ``nonzero``.
    """
    what = f"a finite{' non-zero' if nonzero else ''} {size}-vector"
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValidationError(f"'{name}' must be {what}, got {value!r}") from None
    if v.shape != (size,) or not np.all(np.isfinite(v)) or (nonzero and not np.any(v)):
        raise ValidationError(f"'{name}' must be {what}, got {value!r}")
    return v
