"""Per-pixel part of the weighted-BCE objective in numpy (no Numba: solvers never need it).

The work is restricted to the usable pixels (known, with enough rendered
opacity), fixed once per objective and given as indices, and grouped by
target: ``y = 1``, ``y = 0`` and the few soft targets ``0 < y < 1``. A
binary group needs one logarithm and one division per pixel,

    y = 1:  BCE = -log p,          dBCE/dp = -1 / p,
    y = 0:  BCE = -log1p(-p),      dBCE/dp = 1 / (1 - p),

so an evaluation is a handful of in-place ufuncs over each group (on
preallocated buffers, ``out=``); soft targets take the full formula. The
arithmetic runs in the prediction's dtype (float32 in the solver, whose
prediction ``A q`` is float32 already: ``log1p`` keeps ``-log(1 - p)``
accurate to float32 rounding for small ``p``, as precise as ``p`` itself),
soft targets in float64; sums (the loss, the per-view residuals) accumulate
in float64. The per-pixel BCE does not depend on the pixel weights ``w``,
so one evaluation at a prediction serves both the loss of any ``w`` and the
per-view residuals.

The usable pixels are cut into two halves, each with its own groups and buffers,
evaluated on two threads where two cores are free (numpy's ufuncs release
the GIL; :mod:`seed2gs_inverse._threads`); every sum is taken group by
group in a fixed order on one thread or two alike, so nothing depends on
the thread count.
"""

from __future__ import annotations

import numpy as np

from .._threads import run_both

__all__ = ["PixelBCE", "bce_pixels"]


#: Below this many usable pixels the halves run on the calling thread alone.
PARALLEL_MIN_PIXELS = 200_000


class _Group:
    """Usable pixels ``rows`` (ascending) with one kind of target: ``"one"``, ``"zero"`` or ``"soft"``.

    After :meth:`evaluate`, ``nb`` holds ``-BCE`` (the log-likelihood) of each pixel.
    """

    def __init__(self, kind, rows, y, s, inv_alpha, offsets, dtype):
        self.kind, self.rows, self.s = kind, rows, s  # s None: every pixel weight is 1
        self.dtype = np.dtype(np.float64 if kind == "soft" else dtype)
        self.y = y.astype(np.float64) if kind == "soft" else None
        self.inv = inv_alpha.astype(self.dtype) if inv_alpha is not None else None
        # view c (pixels offsets[c]:offsets[c + 1]) is rows[bounds[c]:bounds[c + 1]]: rows ascend
        bounds = np.searchsorted(rows, offsets)
        self.counts = np.diff(bounds)
        self.nonempty = self.counts > 0
        self.starts = bounds[:-1][self.nonempty]
        m = rows.size
        self.taken = np.empty(m, dtype)  # the prediction at rows, in its own dtype
        self.pc, self.nb, self.g = (np.empty(m, self.dtype) for _ in range(3))
        self.om = np.empty(m, self.dtype) if kind == "zero" else None  # 1 - p
        self.raw = np.empty(m, self.dtype) if self.inv is not None else None  # pred / alpha, before the clip
        self.inside = np.empty(m, bool)
        self.w = self.c = None  # pixel weights (float64) and the gradient's numerator (set_weights)
        self.loss = 0.0  # sum_u w_u nb_u, with the gradient

    def set_weights(self, omega) -> None:
        """``w_u = omega[view(u)] s_u`` and ``c``: ``-w`` (y = 1), ``w`` (y = 0, soft)."""
        self.w = np.repeat(omega, self.counts)
        if self.s is not None:
            self.w *= self.s
        self.c = (-self.w if self.kind == "one" else self.w).astype(self.dtype)

    def evaluate(self, pred, eps: float) -> None:
        """``nb`` (-BCE), ``pc`` (clipped ``p``) and ``inside`` (not clipped) at the prediction ``pred`` (P,)."""
        if self.taken.dtype != pred.dtype:
            self.taken = np.empty(self.rows.size, pred.dtype)
        p = np.take(pred, self.rows, out=self.taken, mode="wrap")  # rows are valid: no bounds check
        if self.inv is not None:
            p = np.multiply(p, self.inv, out=self.raw)
        elif p.dtype != self.dtype:
            p = p.astype(self.dtype)
        pc, nb = self.pc, self.nb
        # the gradient is 0 where the clip to [eps, 1 - eps] is active
        np.clip(p, eps, 1.0 - eps, out=pc)
        np.equal(pc, p, out=self.inside)
        if self.kind == "one":
            np.log(pc, out=nb)
        elif self.kind == "zero":
            np.negative(pc, out=self.om)
            np.log1p(self.om, out=nb)
            np.add(self.om, 1.0, out=self.om)  # 1 + (-p) == 1 - p exactly
        else:
            nb[:] = self.y * np.log(pc) + (1.0 - self.y) * np.log1p(-pc)

    def gradient(self) -> np.ndarray:
        """``w dBCE/dpred`` at ``rows`` (0 where clipped), in the buffer ``g``."""
        g, pc = self.g, self.pc
        if self.kind == "one":
            np.divide(self.c, pc, out=g)
        elif self.kind == "zero":
            np.divide(self.c, self.om, out=g)
        else:
            g[:] = self.c * (pc - self.y) / (pc * (1.0 - pc))
        np.multiply(g, self.inside, out=g)
        if self.inv is not None:
            np.multiply(g, self.inv, out=g)
        return g


def _groups(rows, y, s, inv_alpha, offsets, dtype) -> list:
    """The non-empty target groups of one half of the usable pixels."""
    kinds = (("one", y == 1), ("zero", y == 0), ("soft", (y != 0) & (y != 1)))
    return [_Group(kind, rows[m], y[m], None if s is None else s[m], None if inv_alpha is None else inv_alpha[m],
                   offsets, dtype) for kind, m in kinds if m.any()]


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
    ``q``. Binary targets are computed in ``dtype``, soft ones in float64.

    Use: :meth:`evaluate` at a prediction, then any of :meth:`loss_grad`
    (for view weights ``omega``), :meth:`bce` and :meth:`view_sums`, which
    read that evaluation.

    Parameters
    ----------
    rows : (M,) int
        The usable pixels, ascending; everything else is given at them.
    y : (M,) float
        Targets in [0, 1].
    s : (M,) float, or None
        Pixel weights (None: all 1).
    inv_alpha : (M,) float, or (0,) for the literal ``p = A q``
    eps : float
        Clip, in (0, 0.5).
    n_pixels : int
        ``P``, the length of predictions and of ``g``.
    dtype : numpy dtype
        Dtype of the predictions, of the per-pixel arithmetic and of ``g``
        (that of ``A``, for the adjoint product).
    offsets : (V+1,) int, optional
        The views' pixel ranges: view ``c`` is pixels ``offsets[c]:offsets[c+1]``
        (default: one view of all ``n_pixels``).

    Notes
    -----
    The returned ``g`` is a buffer owned by this object, valid until the
    next :meth:`loss_grad`.
    """

    def __init__(self, rows, y, s, inv_alpha, eps: float, n_pixels: int, dtype=np.float64, offsets=None):
        rows = np.asarray(rows)
        y = np.asarray(y)
        s = None if s is None else np.asarray(s, dtype=np.float64)
        inv_alpha = np.asarray(inv_alpha, dtype=np.float64)
        inv_alpha = inv_alpha if inv_alpha.size else None
        offsets = np.array([0, n_pixels]) if offsets is None else np.asarray(offsets)
        self.eps = float(eps)
        self.n_views = offsets.size - 1
        cut = rows.size // 2
        self.halves = tuple(
            _groups(rows[part], y[part], None if s is None else s[part],
                    None if inv_alpha is None else inv_alpha[part], offsets, dtype)
            for part in (slice(0, cut), slice(cut, rows.size)))
        self.groups = self.halves[0] + self.halves[1]  # the fixed order of every sum
        self.parallel = rows.size >= PARALLEL_MIN_PIXELS
        self.g = np.zeros(int(n_pixels), dtype)  # zero outside the usable pixels, for ever
        self._omega = None
        self._g_ready = False  # g holds the gradient of the last evaluation for the view weights _omega

    def _set_weights(self, omega) -> None:
        omega = np.asarray(omega, dtype=np.float64)
        if self._omega is None or not np.array_equal(omega, self._omega):  # once per L-BFGS run
            for grp in self.groups:
                grp.set_weights(omega)
            self._omega = omega.copy()
            self._g_ready = False

    def _run(self, pred, gradient: bool) -> None:
        def half(k):
            for grp in self.halves[k]:
                if pred is not None:
                    grp.evaluate(pred, self.eps)
                if gradient:
                    self.g[grp.rows] = grp.gradient()
                    grp.loss = float(np.dot(grp.w, grp.nb))  # float64 sum, on this group's thread

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
        return -sum(grp.loss for grp in self.groups), self.g

    def bce(self) -> np.ndarray:
        """(P,) float64: the BCE of every usable pixel at the last evaluation, 0 elsewhere (a new array)."""
        out = np.zeros(self.g.size)
        for grp in self.groups:
            out[grp.rows] = -grp.nb
        return out

    def view_sums(self) -> np.ndarray:
        """(n_views,) float64: ``sum_u s_u b_u`` over each view's usable pixels, at the last evaluation."""
        out = np.zeros(self.n_views)
        for grp in self.groups:
            if grp.starts.size:
                out[grp.nonempty] -= np.add.reduceat(grp.nb if grp.s is None else grp.s * grp.nb, grp.starts,
                                                     dtype=np.float64)
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
