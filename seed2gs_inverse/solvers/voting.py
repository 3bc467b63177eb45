"""Closed-form voting (FlashSplat, Shen et al. 2024).

Every view votes for every Gaussian with its compositing weights. With
``Y(c)`` the mask of view ``c`` and ``K(c)`` its known (non-NaN) pixels,

    A1_i = sum_c sum_{u in K(c)} W(c)[u, i] Y(c)_u          (foreground votes)
    A0_i = sum_c sum_{u in K(c)} W(c)[u, i] (1 - Y(c)_u)    (background votes)

``A1 = A^T (k y)`` is one transposed pass over the stacked operator (``k``
the known-pixel indicator; the problem's ``y`` is already 0 at unknown
pixels, so the pass takes ``y`` itself); ``A0 = A^T k - A1`` reuses the
known weight every solve computes to find the observed Gaussians. FlashSplat normalises the pair per Gaussian,
``[Â0, Â1] = [A0, A1] / ||[A0, A1]||_2``, and labels a Gaussian foreground
when

    Â1 - Â0 > bias.

The returned soft score is ``q = A1 / (A0 + A1)``. Since
``Â1 - Â0 = (2q - 1) / sqrt(q^2 + (1-q)^2)`` is increasing in ``q``, the bias
rule equals ``q > tau(bias)`` with

    tau(bias) = (1 + bias / sqrt(2 - bias^2)) / 2,

which the result carries as its default threshold, so
``result.selected()`` applies FlashSplat's rule (``bias = 0`` gives
``tau = 0.5``, a plain majority of weight), up to the rounding of ``q`` to
float32 in :func:`~seed2gs_inverse.solvers.solve`: a Gaussian whose vote
lies within about 6e-8 of ``tau`` may fall on either side.
"""

from __future__ import annotations

import numpy as np

from .._threads import run_both
from .._validation import as_real
from ..errors import ValidationError
from ._common import MethodResult, Problem, register_method

__all__ = ["voting", "vote_counts", "bias_to_threshold"]

#: Below this many Gaussians the arithmetic after the pass runs on the calling thread alone.
PARALLEL_MIN_GAUSSIANS = 100_000


def vote_counts(problem: Problem) -> tuple:
    """``(A0, A1)`` float64 (N,) background and foreground votes (one transposed pass)."""
    a1 = np.asarray(problem.AT @ problem.y, dtype=np.float64)  # y is 0 at unknown pixels: A^T (k y)
    # y in [0, 1], so A0 >= 0 up to float32 rounding of the two passes
    return np.maximum(problem.known_weight - a1, 0.0), a1


def bias_to_threshold(bias: float) -> float:
    """The ``q`` threshold equivalent to FlashSplat's ``Â1 - Â0 > bias``, |bias| < 1."""
    b = as_real(bias)
    if b is None or not -1.0 < b < 1.0:
        raise ValidationError(f"voting: bias must lie in (-1, 1) (the normalised votes differ by at most 1), "
                              f"got {bias!r}")
    return 0.5 * (1.0 + b / np.sqrt(2.0 - b * b))


def voting(problem: Problem, *, bias: float = 0.0) -> MethodResult:
    """FlashSplat closed-form vote; see the module docstring.

    Parameters
    ----------
    problem : Problem
    bias : float, default 0.0
        Background bias on the L2-normalised votes, in (-1, 1); positive
        values demand more foreground evidence.

    Returns
    -------
    MethodResult
        ``q = A1 / (A0 + A1)`` (N,) (0 where no vote), ``threshold =
        tau(bias)`` and ``info`` holding the ``bias`` and ``total_votes``
        (the summed ``A0 + A1``).

    Raises
    ------
    ValidationError
        ``bias`` not a finite number in (-1, 1).
    """
    tau = bias_to_threshold(bias)
    a1 = problem.AT @ problem.y  # float32 (N,): A^T (k y), y being 0 at unknown pixels
    kw = problem.known_weight
    # A0 + A1 = max(A^T k - A1, 0) + A1 = max(A^T k, A1), without forming A0; computed in place
    # into q (float64), as the vote itself is one pass and the rest should cost little beside it:
    # two halves of the Gaussians on two threads where two cores are free (element by element, so
    # q is the same either way; the total is summed half by half on one thread or two alike)
    q = np.empty(kw.size)
    cut = kw.size // 2
    total = [0.0, 0.0]

    def half(k):
        part = slice(0, cut) if k == 0 else slice(cut, kw.size)
        qk = np.maximum(kw[part], a1[part], out=q[part])
        total[k] = float(qk.sum())
        np.maximum(qk, np.finfo(np.float64).tiny, out=qk)  # where A0 + A1 = 0, A1 = 0 and q = 0
        np.divide(a1[part], qk, out=qk)

    run_both(half, kw.size >= PARALLEL_MIN_GAUSSIANS)
    return MethodResult(q=q, threshold=tau, iterations=0,
                        info={"bias": float(bias), "total_votes": total[0] + total[1]})


register_method("voting", voting, check=lambda o: bias_to_threshold(o["bias"]))
