"""Inverse solvers: recover per-Gaussian foreground probabilities from masks.

Every method solves the same problem: given fixed per-view operators
``W(c)`` (pixels x N) and target masks ``Y(c)``, find ``q in [0, 1]^N`` with
``W(c) q ~ Y(c)`` in every view. One call, interchangeable methods::

    result = solve(operators, masks, method="weighted_bce", init=None, min_evidence=0.0,
                   min_vote=0.0, smoothness=0.0, graph=None, **options)

Methods (one module each, equations in their docstrings):

``voting``          FlashSplat's closed-form vote.
``beta_bernoulli``  B3-Seg's Beta posterior, optional information-gain view order.
``weighted_bce``    Seed2GS reliability-weighted BCE on logits (L-BFGS-B).
``least_squares``   box-constrained least squares, the classical baseline.

Common to every method: ``min_evidence`` (Gaussians without real evidence
keep the prior) or, with ``smoothness > 0`` and a Gaussian ``graph``, the
graph-Laplacian regulariser of :mod:`.smoothing` (they take the harmonic
extension of their neighbours instead), and ``min_vote`` (a Gaussian whose
masks call it object on less than that share of its known weight does not
end above its prior).

New methods register themselves with :func:`register_method` and return a
:class:`MethodResult`; :func:`method_options` lists a method's options.
This package needs only numpy and scipy (never the rasterizer or Numba).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from .._threads import one_blas_thread
from .._validation import as_real
from ..errors import ValidationError
from ..graph import check_graph, graph_on_nodes
from . import beta_bernoulli, least_squares, voting, weighted_bce  # noqa: F401  (importing registers them)
from ._common import (MethodResult, Problem, SolveResult, available_methods, check_options,
                      check_range, get_check, get_method, method_options, prepare,
                      problem_of, register_method, stack_masks)
from ._local import LOCAL_METHODS, SupportPrior, touched_columns
from ._progress import SolveProgress, reporting
from .smoothing import RIDGE, harmonic_extension, laplacian_smooth, smooth_checked
from .weighted_bce import WeightedBCE

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = ["solve", "available_methods", "register_method", "get_method", "method_options", "SolveResult",
           "MethodResult", "Problem", "prepare", "SolveProgress", "COUNT_LIMITS", "check_method_options",
           "laplacian_smooth", "harmonic_extension", "WeightedBCE"]

#: Upper bounds of the count options of every method (``max_iter`` etc.): far
#: above any useful value, low enough that a typo (``max_iter=10**9``) is an
#: error up front instead of a run that never ends.
COUNT_LIMITS = {"max_iter": 100_000, "inner_iters": 100_000, "maxcor": 1_000, "power_iters": 10_000,
                "budget": 1_000_000}


def solve(operators, masks, method: str = "weighted_bce", init=None, min_evidence: float = 0.0,
          progress=None, smoothness: float = 0.0, graph=None, min_vote: float = 0.0, **options) -> SolveResult:
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
        (:attr:`Problem.known_weight`; of the views used, when a method uses
        fewer, ``beta_bernoulli``'s ``budget``), is below this has no real evidence
        and keeps the prior, ``q_i = q0_i`` (an unregularised fit can drive
        such Gaussians anywhere on a trace of weight). ``0`` only gives the
        unobserved Gaussians (``k_i = 0``) the prior.
    smoothness : float, default 0
        Common to every method: ``lambda`` of the graph-Laplacian
        regulariser applied to the method's ``q``
        (:func:`~seed2gs_inverse.solvers.smoothing.laplacian_smooth` with
        evidence ``e_i = k_i``, or the known weight in the views the method
        used when it used fewer (``beta_bernoulli``'s ``budget``), set to 0
        below ``min_evidence`` and where the method reports the Gaussian
        unobserved, and the
        prior): Gaussians without evidence take the harmonic extension of
        their neighbours on ``graph`` instead of the prior, those with
        evidence stay close to the fit. ``0``: off (the ``min_evidence``
        reset above).
    graph : scipy.sparse (N, N), optional
        Symmetric non-negative Gaussian affinities
        (:func:`seed2gs_inverse.graph.gaussian_graph`); needed when
        ``smoothness > 0``.
    min_vote : float in [0, 1], default 0
        Common to every method: a Gaussian with evidence (``k_i >=
        min_evidence``, ``k_i > 0``) whose masks call it object on less than
        this share of its known weight, ``v_i = (A^T y)_i / k_i < min_vote``
        (``y`` 0 at unknown pixels: the closed-form vote), ends no higher
        than its prior: ``q_i = min(q_i, q0_i)``, after the regulariser. A
        per-pixel fit can raise such a Gaussian on the few object pixels it
        shares with an object that cannot fill them (a large splat of the
        ground under an object's base), against most of its own pixels.
        ``info["n_vote_capped"]`` counts the Gaussians it lowered. ``0``: off.
    progress : callable, optional
        ``progress(SolveProgress(iteration, total, loss))`` after every
        iteration of the iterative methods (L-BFGS iterations of
        ``weighted_bce``, FISTA steps of ``least_squares``, views absorbed by
        a sequential ``beta_bernoulli``); ``loss`` is the method's objective.
        Closed forms report nothing.
    **options
        Method options; see each method's documentation.

    Returns
    -------
    SolveResult
        ``q`` (N,) float32 in [0, 1] and the solve's diagnostics.

    Raises
    ------
    ValidationError
        Bad operators, masks, init, min_evidence, min_vote, options, or a ``graph``
        that does not fit (messages name the view or argument), all before
        the method runs.
    """
    fn = _check_request(operators, method, min_evidence, progress, options, smoothness, graph, min_vote)
    t0 = time.perf_counter()
    stack, mask_list = stack_masks(operators, masks)
    n = stack.n_gaussians
    if smoothness > 0:  # before the method runs: a wrong graph must not cost a whole fit
        graph = check_graph(graph, n)
    cols = touched_columns(stack, graph if smoothness > 0 else None) if method in LOCAL_METHODS else None
    if cols is None or cols.size in (0, n):
        problem = problem_of(stack, mask_list, init)
        result = _solve_prepared(fn, problem, method, min_evidence, progress, smoothness, graph, options, min_vote)
    else:
        # The other Gaussians keep the prior whatever the method does (module _local): solve on these.
        prior = SupportPrior(init, n)  # no (N,) float64 prior: the rest's q is spread from its two values
        problem = problem_of(stack.on_columns(cols), mask_list, init, prior.at(cols))
        local = _solve_prepared(fn, problem, method, min_evidence, progress, smoothness,
                                None if graph is None or smoothness == 0 else graph_on_nodes(graph, cols), options,
                                min_vote)
        result = _scattered(local, cols, prior, min_evidence, smoothness)
    result.seconds = time.perf_counter() - t0
    return result


def _scattered(local: SolveResult, cols: np.ndarray, prior: SupportPrior, min_evidence: float,
               smoothness: float) -> SolveResult:
    """The N-Gaussian result of a solve on the columns ``cols``: the others as :func:`solve` leaves them.

    They are unobserved, so they keep the prior, through the regulariser's
    closed form for an isolated node without evidence when it is on
    (:func:`~.smoothing.smooth_checked`), and they count as weak evidence
    when ``min_evidence > 0``.
    """
    n = prior.n
    if smoothness > 0:
        q = prior.map(lambda p: np.clip((0.0 * p + RIDGE * p) / (0.0 + RIDGE), 0.0, 1.0))
    else:
        q = prior.map(lambda p: p)
    q[cols] = local.q
    unobserved = np.ones(n, bool)
    unobserved[cols] = local.unobserved
    info = dict(local.info)
    if min_evidence > 0:
        info["n_weak_evidence"] = int(info["n_weak_evidence"]) + (n - cols.size)
    return SolveResult(q=q, method=local.method, iterations=local.iterations, history=local.history,
                       view_weights=local.view_weights, unobserved=unobserved, seconds=local.seconds,
                       threshold=local.threshold, info=info)


def _solve_prepared(fn, problem: Problem, method: str, min_evidence: float, progress, smoothness: float, graph,
                    options: dict, min_vote: float = 0.0) -> SolveResult:
    """:func:`solve` on a prepared problem (``graph`` checked, of the problem's columns, when ``smoothness > 0``)."""
    t0 = time.perf_counter()
    # Solvers call BLAS on vectors of length N every iteration; a multi-threaded
    # OpenBLAS beside Numba's threads spends more on thread start-up than on
    # the work.
    with one_blas_thread(), reporting(progress):
        t_method = time.perf_counter()
        out = fn(problem, **options)
        t_method = time.perf_counter() - t_method
    if not isinstance(out, MethodResult):
        raise RuntimeError(f"method '{method}' returned {type(out).__name__}, not a MethodResult")
    q = np.asarray(out.q, dtype=np.float64).reshape(-1)
    if q.shape != (problem.n_gaussians,) or not np.all(np.isfinite(q)):
        raise RuntimeError(f"method '{method}' returned an invalid q (shape {q.shape})")
    # A method that ignores some views (a view budget) reports what it did see.
    observed = np.asarray(problem.observed if out.observed is None else out.observed, dtype=bool)
    unobserved = ~observed
    q = np.where(unobserved, problem.prior, np.clip(q, 0.0, 1.0)).astype(np.float32)
    # The known weight of the views the method used (all, unless a view budget left some out).
    used = problem.known_weight if out.evidence is None else np.asarray(out.evidence, np.float64).reshape(-1)
    if used.shape != (problem.n_gaussians,) or not np.all(np.isfinite(used)) or used.min(initial=0.0) < 0:
        raise RuntimeError(f"method '{method}' returned an invalid evidence (shape {used.shape}; finite, >= 0 "
                           "expected)")
    # Gaussians seen (almost) only on unknown pixels carry no evidence: the
    # prior, or with the regulariser their neighbours' values (weak evidence
    # counts as none).
    weak = used < min_evidence
    t_smooth = time.perf_counter()
    if smoothness > 0:
        # One BLAS thread here too: the factorisation's dense kernels round
        # differently with more threads, and q must not depend on the machine's
        # thread settings (a Dask worker runs with one BLAS thread).
        with one_blas_thread():
            # evidence only where the method fitted q (not where it left the prior: views beyond a
            # budget, weighted_bce's pixels below alpha_min), and only from the views it used
            q = smooth_checked(q.astype(np.float64), np.where(weak | unobserved, 0.0, used),
                               graph, float(smoothness), problem.prior).astype(np.float32)
    else:
        q[weak] = problem.prior[weak].astype(np.float32)
    t_smooth = time.perf_counter() - t_smooth
    n_capped = 0
    if min_vote > 0:
        # against its masks: the vote (A^T y) / k below min_vote, on a Gaussian with evidence
        against = ~weak & ~unobserved & (problem.AT @ problem.y < min_vote * problem.known_weight)
        capped = against & (q > problem.prior)
        q[capped] = problem.prior[capped].astype(np.float32)
        n_capped = int(capped.sum())
    weights = np.ones(problem.n_views) if out.view_weights is None else np.asarray(out.view_weights, np.float64)
    info = dict(out.info)
    info.update(min_evidence=float(min_evidence), n_weak_evidence=int(weak.sum()), smoothness=float(smoothness),
                min_vote=float(min_vote), n_vote_capped=n_capped, seconds_method=t_method, seconds_smoothing=t_smooth)
    return SolveResult(q=q, method=method, iterations=int(out.iterations), history=list(out.history),
                       view_weights=weights, unobserved=unobserved, seconds=time.perf_counter() - t0,
                       threshold=float(out.threshold), info=info)


def check_method_options(method, options) -> Callable[..., MethodResult]:
    """The method ``method``, after checking its name and ``options`` (a dict); raises ValidationError.

    The name must be a registered method, every option one the method takes
    (the message lists them), each value of its default's kind (true/false
    for a flag, a whole number for a count, a finite number for a real, a
    string for a choice), the count options (:data:`COUNT_LIMITS`) within
    their bounds, and the values acceptable to the method's registered
    check (ranges, choices; :func:`register_method`).
    """
    if not isinstance(method, str):
        raise ValidationError(f"method must be a method name (str), got {method!r}; "
                              f"available: {', '.join(available_methods())}")
    fn = get_method(method)
    check_options(method, fn, options)
    defaults = method_options(method)
    for name, v in options.items():
        if name in defaults:  # (a method taking **kwargs accepts names it does not list)
            _check_kind(method, name, v, defaults[name])
    for name, hi in COUNT_LIMITS.items():
        v = options.get(name)
        if isinstance(v, (int, np.integer)) and not isinstance(v, bool) and not 1 <= v <= hi:
            raise ValidationError(f"method '{method}': {name} must be in 1..{hi:,}, got {v!r}")
    check = get_check(method)
    if check is not None:
        check({**defaults, **options})
    return fn


def _check_kind(method: str, name: str, value, default) -> None:
    """Raise unless ``value`` is of the kind of the option's ``default`` (None allowed where it is the default)."""
    where = f"method '{method}': option {name}"
    flag = isinstance(value, (bool, np.bool_))
    if value is None and default is None:
        return
    if isinstance(default, bool):
        if not flag:
            raise ValidationError(f"{where} must be true or false, got {value!r}")
    elif name in COUNT_LIMITS:
        if flag or not isinstance(value, (int, np.integer)):
            raise ValidationError(f"{where} must be a whole number, got {value!r}")
    elif isinstance(default, (int, float, np.integer, np.floating)):
        if as_real(value) is None:  # (an int default may well take a fraction: only counts are whole)
            raise ValidationError(f"{where} must be a finite number, got {value!r}")
    elif isinstance(default, str) and not isinstance(value, str):
        raise ValidationError(f"{where} must be a string, got {value!r}")


def _check_request(operators, method, min_evidence, progress, options, smoothness=0.0, graph=None, min_vote=0.0):
    """Validate what :func:`solve` can check before preparing the problem; returns the method.

    Catches, with a ValidationError naming the argument or view: a method
    name that is not a string, unknown options, count options outside
    :data:`COUNT_LIMITS`, a bad ``min_evidence``, ``min_vote``,
    ``smoothness`` (or one without ``graph``) or ``progress``, operators
    without columns (no Gaussians). (Weights outside [0, 1] are refused when the operators are made.)
    """
    fn = check_method_options(method, options)
    check_range("min_evidence", min_evidence, "a finite number >= 0", lo=0.0)
    check_range("min_vote", min_vote, "a number in [0, 1]", lo=0.0, hi=1.0)
    check_range("smoothness", smoothness, "a finite number >= 0", lo=0.0)
    if smoothness > 0 and graph is None:
        raise ValidationError("smoothness > 0 needs graph=: the Gaussians' affinity matrix "
                              "(seed2gs_inverse.graph.gaussian_graph)")
    if progress is not None and not callable(progress):
        raise ValidationError(f"progress must be a callable or None, got {type(progress).__name__}")
    views = getattr(operators, "views", operators)
    if isinstance(views, (list, tuple)):
        for i, op in enumerate(views):
            W = getattr(op, "W", op)
            shape = getattr(W, "shape", None)
            if shape is not None and len(shape) == 2 and shape[1] == 0:
                raise ValidationError(f"view {i}: the operator has no columns (0 Gaussians); "
                                      f"build the operators from a non-empty scene")
    return fn

