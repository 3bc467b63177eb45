"""Per-pixel part of the weighted-BCE objective in numpy (no Numba: solvers never need it).

The work is restricted to the usable pixels (the support: known, bright
enough), fixed once per objective and given as indices. A binary target needs one logarithm
and one division: with ``r_u = p_u`` where ``y_u = 1`` and ``r_u = 1 - p_u``
where ``y_u = 0`` (``r = sigma p + (1 - y)``, ``sigma = 2y - 1``),

    BCE_u = -log r_u,    dBCE_u/dp_u = -sigma_u / r_u,

so an evaluation is a handful of in-place ufuncs over the support (on
preallocated buffers, ``out=``); the few soft targets (``0 < y < 1``) are
redone with the full formula on their own indices. The per-pixel BCE does
not depend on the pixel weights ``w``, so one evaluation at a prediction
serves both the loss of any ``w`` and the per-view residuals.

The support is cut into two halves, each with its own buffers, evaluated on
two threads where two cores are free (numpy's ufuncs release the GIL;
:mod:`seed2gs_inverse._threads`); every sum is the sum of the two halves'
sums on one thread or two alike, so nothing depends on the thread count.
"""

from __future__ import annotations

import numpy as np

from .._threads import run_both

__all__ = ["PixelBCE", "bce_pixels"]


#: Below this many usable pixels the halves run on the calling thread alone.
PARALLEL_MIN_PIXELS = 200_000


class _Half:
    """One half of the support: its pixels ``rows`` (ascending), constants and buffers.

    After :meth:`evaluate`, ``nb`` holds ``-BCE`` (the log-likelihood) of each pixel.
    """

    def __init__(self, rows, yr, s, inv_alpha, views, n_views, dtype):
        self.rows = rows
        binary = (yr == 0.0) | (yr == 1.0)
        # r = sigma p + (1 - y) for binary targets; r = p for soft ones (redone below)
        self.sigma = np.where(binary, 2.0 * yr - 1.0, 1.0)
        self.shift = np.where(binary, 1.0 - yr, 0.0)
        self.soft = np.flatnonzero(~binary)
        self.y_soft = yr[self.soft]
        self.s = s
        self.inv = inv_alpha if inv_alpha.size else None
        self.views = views
        # views are non-decreasing along the rows: view c is rows[bounds[c]:bounds[c + 1]]
        bounds = np.searchsorted(self.views, np.arange(n_views + 1))
        self.nonempty = bounds[1:] > bounds[:-1]
        self.starts = bounds[:-1][self.nonempty]
        m = rows.size
        self.p = np.empty(m, np.float32)
        self.r, self.rc, self.nb = np.empty(m), np.empty(m), np.empty(m)
        self.g = np.empty(m, dtype)  # computed in float64, stored in the adjoint's dtype
        self.inside = np.empty(m, bool)
        self.w = self.c = None  # pixel weights and -sigma w, per view weights (set_weights)

    def set_weights(self, omega) -> None:
        """``w_u = omega[view(u)] s_u`` and ``c_u = -sigma_u w_u`` (the gradient's numerator)."""
        self.w = omega[self.views] * self.s
        self.c = -self.sigma * self.w
        if self.soft.size:
            self.c[self.soft] = self.w[self.soft]

    def evaluate(self, pred, eps: float) -> None:
        """``nb`` (-BCE), ``rc`` (clipped ``r``) and ``inside`` (not clipped) at the prediction ``pred`` (P,)."""
        if self.p.dtype != pred.dtype:
            self.p = np.empty(self.rows.size, pred.dtype)
        np.take(pred, self.rows, out=self.p)
        r, rc = self.r, self.rc
        if self.inv is not None:
            np.multiply(self.p, self.inv, out=r)
            np.multiply(r, self.sigma, out=r)
        else:
            np.multiply(self.p, self.sigma, out=r)
        np.add(r, self.shift, out=r)
        # clipping r to [eps, 1 - eps] is clipping p; the gradient is 0 where it clips
        np.clip(r, eps, 1.0 - eps, out=rc)
        np.equal(rc, r, out=self.inside)
        np.log(rc, out=self.nb)
        if self.soft.size:
            p, y = rc[self.soft], self.y_soft
            self.nb[self.soft] = y * np.log(p) + (1.0 - y) * np.log1p(-p)

    def gradient(self) -> np.ndarray:
        """``w dBCE/dpred`` at ``rows`` (0 where clipped), in the buffer ``g``."""
        g, rc = self.g, self.rc
        np.divide(self.c, rc, out=g)  # -sigma w / r: w (p - y) / (p (1 - p)) for binary y
        if self.soft.size:
            p = rc[self.soft]
            g[self.soft] = self.c[self.soft] * (p - self.y_soft) / (p * (1.0 - p))
        np.multiply(g, self.inside, out=g)
        if self.inv is not None:
            np.multiply(g, self.inv, out=g)
        return g


class PixelBCE:
    """Per-pixel BCE ``b`` and pixel gradient ``g`` from the prediction ``A q``.

    .. math::

        p_u = \\mathrm{clip}(\\mathrm{pred}_u / a_u, \\epsilon, 1 - \\epsilon), \\quad
        b_u = -(y_u \\log p_u + (1 - y_u) \\log(1 - p_u)), \\quad
        g_u = w_u \\frac{p_u - y_u}{p_u (1 - p_u)} \\frac{[\\epsilon < p_u < 1 - \\epsilon]}{a_u},

    with ``a_u = 1 / inv_alpha_u`` (``a_u = 1`` when ``inv_alpha`` is
    empty) and pixel weights ``w_u = omega_{c(u)} s_u`` (``c(u)`` the view
    of pixel ``u``), on the usable pixels ``s_u != 0`` (``b_u = g_u = 0``
    elsewhere). ``sum_u w_u b_u`` is the loss and ``A^T g`` its gradient in
    ``q``.

    Use: :meth:`evaluate` at a prediction, then any of :meth:`loss_grad`
    (for view weights ``omega``), :meth:`bce` and :meth:`view_sums`, which
    read that evaluation.

    Parameters
    ----------
    rows : (M,) int
        The usable pixels, ascending; everything else is given at them.
    y : (M,) float
        Targets in [0, 1].
    s : (M,) float
        Pixel weights.
    inv_alpha : (M,) float, or (0,) for the literal ``p = A q``
    eps : float
        Clip, in (0, 0.5).
    n_pixels : int
        ``P``, the length of predictions and of ``g``.
    dtype : numpy dtype
        Dtype of ``g`` (that of ``A``, for the adjoint product).
    views : (M,) int, optional
        View index of every usable pixel, non-decreasing (default: all in view 0).
    n_views : int, default 1

    Notes
    -----
    The returned ``g`` is a buffer owned by this object, valid until the
    next :meth:`loss_grad`.
    """

    def __init__(self, rows, y, s, inv_alpha, eps: float, n_pixels: int, dtype=np.float64, views=None,
                 n_views: int = 1):
        rows = np.asarray(rows)
        y = np.asarray(y, dtype=np.float64)
        s = np.asarray(s, dtype=np.float64)
        inv_alpha = np.asarray(inv_alpha, dtype=np.float64)
        views = np.zeros(rows.size, np.intp) if views is None else np.asarray(views)
        self.eps = float(eps)
        self.n_views = int(n_views)
        cut = rows.size // 2
        self.halves = tuple(
            _Half(rows[part], y[part], s[part], inv_alpha[part] if inv_alpha.size else inv_alpha, views[part],
                  self.n_views, dtype) for part in (slice(0, cut), slice(cut, rows.size)))
        self.parallel = rows.size >= PARALLEL_MIN_PIXELS
        self.g = np.zeros(int(n_pixels), dtype)  # zero outside the usable pixels, for ever
        self._omega = None
        self._g_ready = False  # g holds the gradient of the last evaluation for the view weights _omega

    def _set_weights(self, omega) -> None:
        omega = np.asarray(omega, dtype=np.float64)
        if self._omega is None or not np.array_equal(omega, self._omega):  # once per L-BFGS run
            for h in self.halves:
                h.set_weights(omega)
            self._omega = omega.copy()
            self._g_ready = False

    def _run(self, pred, gradient: bool) -> None:
        def half(k):
            h = self.halves[k]
            if pred is not None:
                h.evaluate(pred, self.eps)
            if gradient:
                self.g[h.rows] = h.gradient()

        run_both(half, self.parallel)

    def evaluate(self, pred, omega=None) -> None:
        """Evaluate the per-pixel BCE at the prediction ``pred = A q`` (P,).

        With ``omega`` also the gradient for those view weights, in the
        same pass over the pixels (what :meth:`loss_grad` then returns).
        """
        if omega is not None:
            self._set_weights(omega)
        self._run(np.asarray(pred).reshape(-1), omega is not None)
        self._g_ready = omega is not None

    def loss_grad(self, omega) -> tuple:
        """``(sum_u w_u b_u, g (P,) dtype)`` at the last evaluation, for the view weights ``omega`` (n_views,)."""
        self._set_weights(omega)
        if not self._g_ready:
            self._run(None, True)
            self._g_ready = True
        first, second = self.halves
        return -(float(np.dot(first.w, first.nb)) + float(np.dot(second.w, second.nb))), self.g

    def bce(self) -> np.ndarray:
        """(P,) float64: the BCE of every usable pixel at the last evaluation, 0 elsewhere (a new array)."""
        out = np.zeros(self.g.size)
        for h in self.halves:
            out[h.rows] = -h.nb
        return out

    def view_sums(self) -> np.ndarray:
        """(n_views,) float64: ``sum_u s_u b_u`` over each view's usable pixels, at the last evaluation."""
        out = np.zeros(self.n_views)
        for h in self.halves:
            if h.starts.size:
                out[h.nonempty] -= np.add.reduceat(h.s * h.nb, h.starts)
        return out


def bce_pixels(pred, y, w, inv_alpha, eps) -> tuple:
    """:class:`PixelBCE` for one call: ``(b (P,) float64, g (P,) of pred's dtype)`` (fresh arrays).

    The usable pixels are ``w != 0``.
    """
    pred = np.asarray(pred).reshape(-1)
    w = np.asarray(w, dtype=np.float64)
    inv_alpha = np.asarray(inv_alpha, dtype=np.float64)
    rows = np.flatnonzero(w)
    pixels = PixelBCE(rows, np.asarray(y)[rows], w[rows], inv_alpha[rows] if inv_alpha.size else inv_alpha, eps,
                      pred.size, pred.dtype)
    pixels.evaluate(pred)
    g = pixels.loss_grad(np.ones(1))[1].copy()
    return pixels.bce(), g
