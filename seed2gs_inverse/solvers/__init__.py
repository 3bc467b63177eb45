"""Inverse solvers: recover per-Gaussian foreground probabilities from masks.

Every method solves the same problem: given fixed per-view operators
``W(c)`` (pixels x N) and target masks ``Y(c)``, find ``q in [0, 1]^N`` with
``W(c) q ~ Y(c)`` in every view. One call, interchangeable methods::

    result = solve(operators, masks, method="weighted_bce", init=None, min_evidence=0.0, **options)

Methods (one module each, equations in their docstrings):

``voting``          FlashSplat's closed-form vote.
``beta_bernoulli``  B3-Seg's Beta posterior, optional information-gain view order.
``weighted_bce``    Seed2GS reliability-weighted BCE on logits (L-BFGS-B).
``least_squares``   box-constrained least squares, the classical baseline.

New methods register themselves with :func:`register_method` and return a
:class:`MethodResult`; :func:`method_options` lists a method's options.
This package needs only numpy and scipy (never the rasterizer or Numba).
"""

from __future__ import annotations

import time

import numpy as np
from threadpoolctl import threadpool_limits

from ..errors import ValidationError
from ._common import (MethodResult, Problem, SolveResult, available_methods, check_options, get_method,
                      method_options, prepare, register_method)
from . import beta_bernoulli, least_squares, voting, weighted_bce  # noqa: F401  (importing registers them)

__all__ = ["solve", "available_methods", "register_method", "get_method", "method_options", "SolveResult",
           "MethodResult", "Problem", "prepare"]


def solve(operators, masks, method: str = "weighted_bce", init=None, min_evidence: float = 0.0,
          **options) -> SolveResult:
    """Recover per-Gaussian foreground probabilities ``q`` from per-view masks.

    Parameters
    ----------
    operators : OperatorStack or sequence of ViewOperator / scipy.sparse matrices
        One operator per view, each (H*W, N) with the same N. Bare sparse
        matrices take their image shape from the mask.
    masks : sequence of arrays
        One mask per view with the view's image shape (H, W): floats in
        [0, 1] with NaN for unknown pixels, bool, or uint8 0/255.
    method : str
        One of :func:`available_methods`.
    init : None, bool (N,), int indices, or float (N,) in [0, 1]
        Prior: a support set (e.g. the seed lift's G0) or a prior ``q``.
        Gaussians no view sees keep it (default 0); ``weighted_bce`` also
        starts from it.
    min_evidence : float, default 0
        Common to every method: a Gaussian whose summed weight over the
        known (non-NaN) pixels of all views, ``k_i = sum_u A[u, i] [u known]``
        (:attr:`Problem.known_weight`), is below this has no real evidence
        and keeps the prior, ``q_i = q0_i`` (an unregularised fit can drive
        such Gaussians anywhere on a trace of weight). ``0`` only gives the
        unobserved Gaussians (``k_i = 0``) the prior.
    **options
        Method options; see each method's documentation.

    Returns
    -------
    SolveResult
        ``q`` (N,) float32 in [0, 1] and the solve's diagnostics.

    Raises
    ------
    ValidationError
        Bad operators, masks, init, min_evidence or options (messages name
        the view).
    """
    fn = get_method(method)
    check_options(method, fn, options)
    if isinstance(min_evidence, bool) or not isinstance(min_evidence, (int, float, np.integer, np.floating)) \
            or not np.isfinite(min_evidence) or min_evidence < 0:
        raise ValidationError(f"min_evidence must be a finite number >= 0, got {min_evidence!r}")
    t0 = time.perf_counter()
    problem = prepare(operators, masks, init)
    # Solvers call BLAS on vectors of length N every iteration; a multi-threaded
    # OpenBLAS beside Numba's threads spends more on thread start-up than on
    # the work (measured: 51 ms vs 0.5 ms per L-BFGS-B iteration at N = 40k
    # on 2 cores).
    with threadpool_limits(limits=1, user_api="blas"):
        out = fn(problem, **options)
    if not isinstance(out, MethodResult):
        raise RuntimeError(f"method '{method}' returned {type(out).__name__}, not a MethodResult")
    q = np.asarray(out.q, dtype=np.float64).reshape(-1)
    if q.shape != (problem.n_gaussians,) or not np.all(np.isfinite(q)):
        raise RuntimeError(f"method '{method}' returned an invalid q (shape {q.shape})")
    # A method that ignores some views (a view budget) reports what it did see.
    observed = np.asarray(problem.observed if out.observed is None else out.observed, dtype=bool)
    unobserved = ~observed
    q = np.where(unobserved, problem.prior, np.clip(q, 0.0, 1.0)).astype(np.float32)
    # Gaussians seen (almost) only on unknown pixels carry no evidence: the prior.
    weak = problem.known_weight < min_evidence
    q[weak] = problem.prior[weak].astype(np.float32)
    weights = np.ones(problem.n_views) if out.view_weights is None else np.asarray(out.view_weights, np.float64)
    info = dict(out.info)
    info.update(min_evidence=float(min_evidence), n_weak_evidence=int(weak.sum()))
    return SolveResult(q=q, method=method, iterations=int(out.iterations), history=list(out.history),
                       view_weights=weights, unobserved=unobserved, seconds=time.perf_counter() - t0,
                       threshold=float(out.threshold), info=info)
