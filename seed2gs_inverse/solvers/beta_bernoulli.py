"""Beta-Bernoulli belief over Gaussian membership (B3-Seg, Kamata et al.).

Each Gaussian's membership is a Bernoulli variable with a Beta prior
``Beta(a0, b0)``. A view contributes weighted evidence: pixel ``u`` with mask
value ``Y_u`` counts ``W[u, i] Y_u`` successes and ``W[u, i] (1 - Y_u)``
failures for Gaussian ``i`` (unknown pixels count nothing). After a set of
views ``S``

    a_i = a0 + sum_{c in S} sum_u W(c)[u, i] Y(c)_u
    b_i = b0 + sum_{c in S} sum_u W(c)[u, i] (1 - Y(c)_u)
    q_i = a_i / (a_i + b_i)                               (posterior mean)

``order="given"`` uses the views in the order given (all of them, or the
first ``budget``); the result does not depend on the order.

Gaussians without evidence in the views used are reported unobserved, and
:func:`~seed2gs_inverse.solvers.solve` gives them the ``init`` prior (0 by
default), not the Beta prior's mean ``a0 / (a0 + b0)``, which a Gaussian
with a trace of weight gets. With ``solve(..., smoothness=)`` the
regulariser's evidence ``e_i`` is the known weight in the views absorbed.

``order="eig"`` picks views greedily by expected information gain under a
view ``budget``. With ``H(a, b)`` the differential entropy of ``Beta(a, b)``,

    H(a, b) = ln B(a, b) - (a-1) psi(a) - (b-1) psi(b) + (a+b-2) psi(a+b),

and ``e_i(c) = sum_{u known} W(c)[u, i]`` the evidence view ``c`` would give
Gaussian ``i``, the gain of ``c`` is the expected drop of the summed entropy
when that evidence arrives with the predictive label ``Bernoulli(q_i)``:

    EIG(c) = sum_i [ H(a_i, b_i) - q_i H(a_i + e_i, b_i) - (1 - q_i) H(a_i, b_i + e_i) ].

(Per-Gaussian approximation: the view's evidence on each Gaussian is treated
as one observation of weight ``e_i``, ignoring that pixels couple Gaussians.)
The best view is absorbed with its actual mask evidence, and the step
repeats. Everything is evaluated in float64 with ``scipy.special``.
"""

from __future__ import annotations

import numpy as np
from scipy.special import betaln, digamma

from ..errors import ValidationError
from ._common import MethodResult, Problem, check_count, check_range, register_method
from ._progress import report as report_progress
from .voting import vote_counts

__all__ = ["beta_bernoulli", "beta_entropy"]


def beta_entropy(a, b) -> np.ndarray:
    """Differential entropy of ``Beta(a, b)`` (float64, elementwise), a, b > 0."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    return betaln(a, b) - (a - 1) * digamma(a) - (b - 1) * digamma(b) + (a + b - 2) * digamma(a + b)


def _view_evidence(problem: Problem, c: int) -> tuple:
    """Columns seen by view ``c`` on known pixels and their (success, total) evidence, float64."""
    rows = problem.view_rows(c)
    Wc = problem.view_matrix(c)
    # float64 right-hand sides make scipy accumulate in float64 (evidence is computed once per view)
    k = problem.known[rows].astype(np.float64)
    total = np.asarray(Wc.T @ k)
    succ = np.asarray(Wc.T @ (problem.y[rows] * k))
    cols = np.flatnonzero(total > 0)
    return cols, succ[cols], total[cols]


def _check(o: dict) -> None:
    """Raise a ValidationError for option values beta_bernoulli cannot take (``o``: every option by name)."""
    for name in ("a0", "b0"):
        check_range(f"beta_bernoulli: {name}", o[name], "a positive finite number", lo=0.0, lo_open=True)
    if o["order"] not in ("given", "eig"):
        raise ValidationError(f"beta_bernoulli: order must be 'given' or 'eig', got {o['order']!r}")
    check_count("beta_bernoulli", "budget", o["budget"], none_ok=True)


def beta_bernoulli(problem: Problem, *, a0: float = 1.0, b0: float = 1.0, order: str = "given",
                   budget: int | None = None) -> MethodResult:
    """B3-Seg Beta posterior; see the module docstring.

    Parameters
    ----------
    problem : Problem
    a0, b0 : float, default 1.0
        Beta prior pseudo-counts (uniform prior), > 0.
    order : {"given", "eig"}, default "given"
        View order: as given, or greedy expected information gain.
    budget : int, optional
        Use at most this many views (default: all).

    Returns
    -------
    MethodResult
        ``q`` (N,) the posterior mean, ``iterations`` the number of views
        used, ``view_weights`` (V,) 1 for used views and 0 otherwise,
        ``history`` one record per absorbed view (``view``, ``eig`` for the
        eig order, ``entropy`` the summed Beta entropy after it; empty when
        every view is used in the given order, which needs only the two vote
        sums) and ``info["order"]``.

    Raises
    ------
    ValidationError
        An option value outside the ranges above.
    """
    _check(dict(a0=a0, b0=b0, order=order, budget=budget))
    a0, b0 = float(a0), float(b0)
    V = problem.n_views
    budget = V if budget is None else min(int(budget), V)
    n = problem.n_gaussians
    if order == "given" and budget == V:
        # All views in any order: the posterior needs only the two vote sums (one transposed pass).
        a_bg, a_fg = vote_counts(problem)
        return MethodResult(q=(a0 + a_fg) / (a0 + b0 + a_fg + a_bg), iterations=V, view_weights=np.ones(V),
                            info={"order": list(range(V)), "budget": V, "a0": a0, "b0": b0})
    a = np.full(n, a0)
    b = np.full(n, b0)
    seen = np.zeros(n, dtype=bool)
    evidence = [_view_evidence(problem, c) for c in range(V)]
    h0 = float(beta_entropy(a0, b0))
    entropy = h0 * n
    remaining = list(range(V))
    chosen, history = [], []
    for _ in range(budget):
        gain = None
        if order == "eig":
            gains = []
            for c in remaining:
                cols, _, e = evidence[c]
                ac, bc = a[cols], b[cols]
                qc = ac / (ac + bc)
                gains.append(float(np.sum(beta_entropy(ac, bc) - qc * beta_entropy(ac + e, bc)
                                          - (1 - qc) * beta_entropy(ac, bc + e))))
            k = int(np.argmax(gains))
            c, gain = remaining[k], gains[k]
        else:
            c = remaining[0]
        remaining.remove(c)
        cols, s, e = evidence[c]
        before = beta_entropy(a[cols], b[cols])
        a[cols] += s
        b[cols] += e - s
        seen[cols] = True
        entropy += float(np.sum(beta_entropy(a[cols], b[cols]) - before))
        chosen.append(c)
        rec = {"step": len(chosen), "view": c, "entropy": entropy}
        if gain is not None:
            rec["eig"] = gain
        history.append(rec)
        report_progress(len(chosen), budget, entropy)
    weights = np.zeros(V)
    weights[chosen] = 1.0
    # the known weight of the views absorbed: a - a0 + b - b0 (the regulariser's evidence)
    return MethodResult(q=a / (a + b), iterations=len(chosen), history=history, view_weights=weights,
                        observed=seen, evidence=(a - a0) + (b - b0),
                        info={"order": chosen, "budget": budget, "a0": a0, "b0": b0})


register_method("beta_bernoulli", beta_bernoulli, check=_check)
