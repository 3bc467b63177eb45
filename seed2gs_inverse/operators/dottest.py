"""The dot test of a linear operator and its adjoint (PyLops ``dottest`` style)."""

from __future__ import annotations

import numpy as np
from scipy.sparse.linalg import LinearOperator

from ..errors import ValidationError

__all__ = ["dottest"]


def dottest(op, rtol: float = 1e-4, rng=None, raise_error: bool = True) -> bool:
    """Check that ``rmatvec`` is the adjoint of ``matvec``: ``<A x, y> == <x, A^T y>``.

    With random ``x`` (N,) and ``y`` (M,) (standard normal, float64; both
    sides are computed from the operator's own ``matvec``/``rmatvec``, which
    may work in float32, and compared in float64)

    .. math::

        |\\langle A x, y \\rangle - \\langle x, A^T y \\rangle|
        \\le \\mathrm{rtol} \\, \\max(|\\langle A x, y \\rangle|, |\\langle x, A^T y \\rangle|, \\epsilon),

    with ``epsilon`` the smallest normal float64 (so a zero operator passes).

    Parameters
    ----------
    op : scipy.sparse.linalg.LinearOperator
        E.g. a :class:`~seed2gs_inverse.operators.ViewOperator` or
        :class:`~seed2gs_inverse.operators.OperatorStack`; anything with
        ``shape``, ``matvec`` and ``rmatvec``.
    rtol : float, default 1e-4
        Relative tolerance (float32 operators reach about 1e-6).
    rng : numpy.random.Generator or int, optional
        Source of ``x`` and ``y`` (default a fresh ``default_rng()``).
    raise_error : bool, default True
        Raise on failure; otherwise return False.

    Returns
    -------
    bool
        True when the test passes.

    Raises
    ------
    ValidationError
        ``op`` is not a linear operator, ``rtol`` is not a positive number,
        or (with ``raise_error``) the test fails; the message names the
        operator and both inner products.
    """
    if not isinstance(op, LinearOperator) and not (hasattr(op, "matvec") and hasattr(op, "rmatvec")
                                                   and hasattr(op, "shape")):
        raise ValidationError(f"dottest needs a LinearOperator (matvec, rmatvec, shape), got {type(op).__name__}")
    if isinstance(rtol, bool) or not isinstance(rtol, (int, float, np.integer, np.floating)) \
            or not np.isfinite(rtol) or rtol <= 0:
        raise ValidationError(f"dottest: rtol must be a positive number, got {rtol!r}")
    try:
        rng = np.random.default_rng(rng)
    except (TypeError, ValueError):
        raise ValidationError(f"dottest: rng must be a numpy Generator, a seed (int) or None, got {rng!r}") from None
    m, n = (int(s) for s in op.shape)
    x = rng.standard_normal(n)
    y = rng.standard_normal(m)
    ax = np.asarray(op.matvec(x), dtype=np.float64).reshape(-1)
    aty = np.asarray(op.rmatvec(y), dtype=np.float64).reshape(-1)
    if ax.shape != (m,) or aty.shape != (n,):
        raise ValidationError(f"dottest: {op!r} returned shapes {ax.shape} and {aty.shape}; "
                              f"expected ({m},) and ({n},)")
    lhs, rhs = float(ax @ y), float(x @ aty)
    scale = max(abs(lhs), abs(rhs), np.finfo(np.float64).tiny)
    ok = abs(lhs - rhs) <= rtol * scale
    if not ok and raise_error:
        raise ValidationError(f"dottest failed for {op!r}: <A x, y> = {lhs:.9g} but <x, A^T y> = {rhs:.9g} "
                              f"(relative difference {abs(lhs - rhs) / scale:.3g} > rtol {rtol:g}); "
                              "rmatvec is not the adjoint of matvec")
    return bool(ok)
