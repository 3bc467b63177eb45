"""Per-pixel part of the weighted-BCE objective in numpy (no Numba: solvers never need it).

The work is restricted to the pixels with a nonzero weight, ordered once per
weight vector so that the targets 1, 0 and soft form three contiguous blocks:
binary targets then need one logarithm each and every step is an in-place
ufunc on preallocated buffers (``out=``), with no pixel-sized temporaries.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PixelBCE", "bce_pixels"]


class _Rows:
    """The pixels of one weight vector ``w`` (w != 0), ordered targets 1 | 0 | soft, and buffers."""

    def __init__(self, w, y, inv_alpha, dtype):
        rows = np.flatnonzero(w)
        yr = y[rows]
        one, zero = yr == 1.0, yr == 0.0
        order = np.concatenate([np.flatnonzero(one), np.flatnonzero(zero), np.flatnonzero(~(one | zero))])
        self.rows = rows[order]
        self.n1, self.n10 = int(one.sum()), int(one.sum() + zero.sum())
        self.y = y[self.rows]
        self.w = np.asarray(w, dtype=np.float64)[self.rows]
        self.inv = inv_alpha[self.rows] if inv_alpha.size else None
        m = self.rows.size
        self.p, self.t, self.d, self.b = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
        self.out_lo, self.out_hi = np.empty(m, bool), np.empty(m, bool)
        # Full-length outputs, zero outside ``rows`` (written only at rows, so they stay zero).
        self.bce = np.zeros(w.size)
        self.g = np.zeros(w.size, dtype)


class PixelBCE:
    """Per-pixel BCE ``b`` and pixel gradient ``g`` from the prediction ``A q``.

    .. math::

        p_u = \\mathrm{clip}(\\mathrm{pred}_u / a_u, \\epsilon, 1 - \\epsilon), \\quad
        b_u = -(y_u \\log p_u + (1 - y_u) \\log(1 - p_u)), \\quad
        g_u = w_u \\frac{p_u - y_u}{p_u (1 - p_u)} \\frac{[\\epsilon < p_u < 1 - \\epsilon]}{a_u},

    with ``a_u = 1 / inv_alpha_u`` (``a_u = 1`` when ``inv_alpha`` is
    empty); ``b_u = g_u = 0`` where ``w_u = 0`` (pixels without evidence).
    ``sum_u b_u w_u`` is the loss and ``A^T g`` its gradient in ``q``.
    For ``y_u = 1`` only ``-log p_u`` and for ``y_u = 0`` only
    ``-log1p(-p_u)`` is evaluated.

    Parameters
    ----------
    y : (P,) float64
        Targets in [0, 1].
    inv_alpha : (P,) float64, or (0,) for the literal ``p = A q``
    eps : float
        Clip, in (0, 0.5).
    dtype : numpy dtype
        Dtype of ``g`` (that of ``A``, for the adjoint product).

    Notes
    -----
    The returned arrays are buffers owned by this object (one pair per
    weight vector, for the last two weight vectors seen): valid until the
    next call with the same ``w``.
    """

    def __init__(self, y, inv_alpha, eps: float, dtype=np.float64):
        self.y = np.asarray(y, dtype=np.float64)
        self.inv_alpha = np.asarray(inv_alpha, dtype=np.float64)
        self.eps = float(eps)
        self.dtype = np.dtype(dtype)
        self._cache = {}  # id(w) -> (w, _Rows); w is kept alive so the id stays unique

    def _rows(self, w) -> _Rows:
        hit = self._cache.get(id(w))
        if hit is not None and hit[0] is w:
            return hit[1]
        if len(self._cache) >= 2:
            self._cache.pop(next(iter(self._cache)))
        r = _Rows(w, self.y, self.inv_alpha, self.dtype)
        self._cache[id(w)] = (w, r)
        return r

    def __call__(self, pred, w) -> tuple:
        """``(b (P,) float64, g (P,) dtype)`` at the prediction ``pred = A q`` (P,) and weights ``w`` (P,)."""
        r = self._evaluate(pred, w)
        r.bce[r.rows] = r.b
        return r.bce, r.g

    def loss_grad(self, pred, w) -> tuple:
        """``(sum_u w_u b_u, g (P,) dtype)``: the loss without the per-pixel BCE written out.

        The loss is summed over the pixels with ``w_u != 0`` only (the others
        contribute 0), which saves a scatter and a dot product over all P
        pixels per evaluation.
        """
        r = self._evaluate(pred, w)
        return float(np.dot(r.w, r.b)), r.g

    def _evaluate(self, pred, w) -> _Rows:
        """Fill ``r.b`` (BCE of the pixels ``r.rows``) and ``r.g`` (all P) for weights ``w``; return ``r``."""
        r = self._rows(w)
        p, t, d, b = r.p, r.t, r.d, r.b
        eps = self.eps
        p[:] = np.asarray(pred).reshape(-1)[r.rows]
        if r.inv is not None:
            np.multiply(p, r.inv, out=p)
        np.less_equal(p, eps, out=r.out_lo)
        np.greater_equal(p, 1.0 - eps, out=r.out_hi)
        np.logical_or(r.out_lo, r.out_hi, out=r.out_lo)  # outside (eps, 1 - eps): no gradient
        np.clip(p, eps, 1.0 - eps, out=p)
        n1, n10 = r.n1, r.n10
        # y = 1: -log p;  y = 0: -log1p(-p);  soft: -(y log p + (1 - y) log1p(-p)).
        np.log(p[:n1], out=b[:n1])
        np.negative(p[n1:], out=t[n1:])
        np.log1p(t[n1:], out=t[n1:])
        np.copyto(b[n1:n10], t[n1:n10])
        if n10 < p.size:
            ys = r.y[n10:]
            np.log(p[n10:], out=d[n10:])
            np.multiply(ys, d[n10:], out=d[n10:])
            np.multiply(1.0 - ys, t[n10:], out=t[n10:])
            np.add(d[n10:], t[n10:], out=b[n10:])
        np.negative(b, out=b)
        # g = w (p - y) / (p (1 - p)) [/ a], 0 where clipped.
        np.subtract(p, r.y, out=t)
        np.multiply(r.w, t, out=t)
        np.subtract(1.0, p, out=d)
        np.multiply(p, d, out=d)
        np.divide(t, d, out=t)
        if r.inv is not None:
            np.multiply(t, r.inv, out=t)
        t[r.out_lo] = 0.0
        r.g[r.rows] = t
        return r


def bce_pixels(pred, y, w, inv_alpha, eps) -> tuple:
    """:class:`PixelBCE` for one call: ``(b (P,) float64, g (P,) of pred's dtype)`` (fresh arrays)."""
    pred = np.asarray(pred)
    bce, g = PixelBCE(y, inv_alpha, eps, pred.dtype)(pred, np.asarray(w, dtype=np.float64))
    return bce.copy(), g.copy()
