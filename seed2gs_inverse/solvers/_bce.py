"""Per-pixel part of the weighted-BCE objective in numpy (no Numba: solvers never need it).

The work is restricted to the pixels with a nonzero weight, ordered once per
weight vector so that the targets 1, 0 and soft form three contiguous blocks:
binary targets then need one logarithm each and every step is an in-place
ufunc on preallocated buffers (``out=``), with no pixel-sized temporaries.
Those pixels are cut into two halves, each with its own blocks and buffers,
evaluated on two threads where two cores are free (numpy's ufuncs release
the GIL; :mod:`seed2gs_inverse._threads`); the loss is the sum of the two
halves' sums on one thread or two alike, so it never depends on the thread
count.
"""

from __future__ import annotations

import numpy as np

from .._threads import run_both

__all__ = ["PixelBCE", "bce_pixels"]


#: Below this many evidence pixels the halves run on the calling thread alone.
PARALLEL_MIN_PIXELS = 200_000


class _Rows:
    """The pixels ``rows`` of one weight vector ``w`` (w != 0), ordered targets 1 | 0 | soft, and buffers.

    ``g``, ``bce``: full-length outputs shared by the halves of one weight
    vector (each writes only its own rows).
    """

    def __init__(self, rows, w, y, inv_alpha, g, bce):
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
        self.g, self.bce = g, bce

    @staticmethod
    def halves(w, y, inv_alpha, dtype) -> tuple:
        """The two halves of ``w``'s pixels, sharing full-length outputs zero outside them."""
        rows = np.flatnonzero(w)
        g, bce = np.zeros(w.size, dtype), np.zeros(w.size)
        cut = rows.size // 2
        return tuple(_Rows(part, w, y, inv_alpha, g, bce) for part in (rows[:cut], rows[cut:]))

    def evaluate(self, pred, eps: float) -> None:
        """Fill ``b`` (BCE of ``rows``) and ``g`` at ``rows`` for the prediction ``pred`` (P,)."""
        p, t, d, b = self.p, self.t, self.d, self.b
        p[:] = np.asarray(pred).reshape(-1)[self.rows]
        if self.inv is not None:
            np.multiply(p, self.inv, out=p)
        np.less_equal(p, eps, out=self.out_lo)
        np.greater_equal(p, 1.0 - eps, out=self.out_hi)
        np.logical_or(self.out_lo, self.out_hi, out=self.out_lo)  # outside (eps, 1 - eps): no gradient
        np.clip(p, eps, 1.0 - eps, out=p)
        n1, n10 = self.n1, self.n10
        # y = 1: -log p;  y = 0: -log1p(-p);  soft: -(y log p + (1 - y) log1p(-p)).
        np.log(p[:n1], out=b[:n1])
        np.negative(p[n1:], out=t[n1:])
        np.log1p(t[n1:], out=t[n1:])
        np.copyto(b[n1:n10], t[n1:n10])
        if n10 < p.size:
            ys = self.y[n10:]
            np.log(p[n10:], out=d[n10:])
            np.multiply(ys, d[n10:], out=d[n10:])
            np.multiply(1.0 - ys, t[n10:], out=t[n10:])
            np.add(d[n10:], t[n10:], out=b[n10:])
        np.negative(b, out=b)
        # g = w (p - y) / (p (1 - p)) [/ a], 0 where clipped.
        np.subtract(p, self.y, out=t)
        np.multiply(self.w, t, out=t)
        np.subtract(1.0, p, out=d)
        np.multiply(p, d, out=d)
        np.divide(t, d, out=t)
        if self.inv is not None:
            np.multiply(t, self.inv, out=t)
        t[self.out_lo] = 0.0
        self.g[self.rows] = t


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
        self._cache = {}  # id(w) -> (w, halves); w is kept alive so the id stays unique

    def _rows(self, w) -> tuple:
        hit = self._cache.get(id(w))
        if hit is not None and hit[0] is w:
            return hit[1]
        if len(self._cache) >= 2:
            self._cache.pop(next(iter(self._cache)))
        parts = _Rows.halves(w, self.y, self.inv_alpha, self.dtype)
        self._cache[id(w)] = (w, parts)
        return parts

    def __call__(self, pred, w) -> tuple:
        """``(b (P,) float64, g (P,) dtype)`` at the prediction ``pred = A q`` (P,) and weights ``w`` (P,)."""
        parts = self._evaluate(pred, w)
        for r in parts:
            r.bce[r.rows] = r.b
        return parts[0].bce, parts[0].g

    def loss_grad(self, pred, w) -> tuple:
        """``(sum_u w_u b_u, g (P,) dtype)``: the loss without the per-pixel BCE written out.

        The loss is summed over the pixels with ``w_u != 0`` only (the others
        contribute 0), which saves a scatter and a dot product over all P
        pixels per evaluation.
        """
        parts = self._evaluate(pred, w)
        return float(np.dot(parts[0].w, parts[0].b)) + float(np.dot(parts[1].w, parts[1].b)), parts[0].g

    def _evaluate(self, pred, w) -> tuple:
        """Both halves of ``w``'s pixels evaluated at ``pred`` (their ``b``, and ``g`` at all P)."""
        parts = self._rows(w)
        run_both(lambda k: parts[k].evaluate(pred, self.eps),
                 parts[0].rows.size + parts[1].rows.size >= PARALLEL_MIN_PIXELS)
        return parts


def bce_pixels(pred, y, w, inv_alpha, eps) -> tuple:
    """:class:`PixelBCE` for one call: ``(b (P,) float64, g (P,) of pred's dtype)`` (fresh arrays)."""
    pred = np.asarray(pred)
    bce, g = PixelBCE(y, inv_alpha, eps, pred.dtype)(pred, np.asarray(w, dtype=np.float64))
    return bce.copy(), g.copy()
