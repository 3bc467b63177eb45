"""Box-constrained least squares, the classical baseline.

    min_q  1/2 sum_c || K(c) (W(c) q - b(c)) ||^2   subject to  0 <= q <= 1,

where ``K(c)`` keeps the known (non-NaN) pixels the scene covers
(``alpha > 0``; a pixel with no Gaussian adds a constant). Only observed
Gaussians are free. The right-hand side is ``b = alpha * Y`` by default
(``target="alpha"``): the object's rendered opacity should equal the
pixel's opacity inside the mask and vanish outside, which ``q = labels``
satisfies exactly on pure pixels. ``target="mask"`` uses ``b = Y`` literally;
since ``W q <= alpha``, that pushes every Gaussian of a partly transparent
masked pixel (including background behind the object) towards 1.

``algorithm="fista"`` (default) runs accelerated projected gradient
(FISTA with adaptive restart, O'Donoghue & Candes 2015):

    z = x_k + beta_k (x_k - x_{k-1}),   x_{k+1} = clip(z - A^T (A z - y) / L, 0, 1),

with step ``1/L``, ``L`` 1.05 times a power-iteration estimate of
``||A||_2^2`` (an estimate from below: the margin makes the step safe in
practice, not provably), one ``A`` and one ``A^T`` pass per iteration; it stops when
``max |x_{k+1} - x_k| < tol`` or after ``max_iter`` iterations.
``algorithm="lsq_linear"`` calls ``scipy.optimize.lsq_linear`` (method
"trf") on the known rows and observed columns, to scipy's tolerance ``tol``, 1e-10 by
default (FISTA's 1e-4 would stop it after a few iterations, far from the
minimiser); it builds a sliced copy of the operator: use it for small
problems.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

from ..errors import ValidationError
from ._common import MethodResult, Problem, check_count, check_range, register_method
from ._progress import report as report_progress

__all__ = ["least_squares", "operator_norm_sq"]


def operator_norm_sq(A, AT, rows_weight, n_iter: int = 30, seed: int = 0) -> float:
    """Estimate ``||D A||_2^2`` (D = diag(rows_weight) 0/1) by power iteration on ``A^T D A``."""
    rng = np.random.default_rng(seed)
    v = rng.random(A.shape[1]).astype(A.dtype)
    lam = 0.0
    for _ in range(n_iter):
        w = AT @ ((A @ v) * rows_weight)
        lam = float(np.linalg.norm(w))
        if lam == 0.0:
            return 0.0
        v = (w / lam).astype(A.dtype)
    return lam


def _check(o: dict) -> None:
    """Raise a ValidationError for option values least_squares cannot take (``o``: every option by name)."""
    if o["algorithm"] not in ("fista", "lsq_linear"):
        raise ValidationError(f"least_squares: algorithm must be 'fista' or 'lsq_linear', got {o['algorithm']!r}")
    for name in ("max_iter", "power_iters"):
        check_count("least_squares", name, o[name])
    if o["tol"] is not None:  # (the defaults of DEFAULT_TOL are positive)
        check_range("least_squares: tol", o["tol"], "a positive finite number", lo=0.0, lo_open=True)
    if o["target"] not in ("alpha", "mask"):
        raise ValidationError(f"least_squares: target must be 'alpha' or 'mask', got {o['target']!r}")


#: The tolerance of each algorithm when ``tol`` is None.
DEFAULT_TOL = {"fista": 1e-4, "lsq_linear": 1e-10}


def least_squares(problem: Problem, *, target: str = "alpha", algorithm: str = "fista", max_iter: int = 500,
                  tol: float | None = None, power_iters: int = 30) -> MethodResult:
    """Box-constrained least squares; see the module docstring.

    Parameters
    ----------
    problem : Problem
    target : {"alpha", "mask"}, default "alpha"
        Right-hand side ``alpha * Y`` or the literal mask ``Y`` (see module docstring).
    algorithm : {"fista", "lsq_linear"}, default "fista"
    max_iter : int, default 500
    tol : float, optional
        FISTA: stop when no ``q`` changes by more than this (default 1e-4);
        lsq_linear: scipy's ``tol`` (default 1e-10).
    power_iters : int, default 30
        Power iterations for the step size (FISTA).

    Returns
    -------
    MethodResult
        ``q`` (N,), ``iterations`` and ``history`` (FISTA: ``objective``
        ``0.5 ||r||^2`` at the extrapolated point and ``step``, the max
        change of ``q``, every iteration).

    Raises
    ------
    ValidationError
        An option value outside the ranges above.
    """
    _check(dict(target=target, algorithm=algorithm, max_iter=max_iter, tol=tol, power_iters=power_iters))
    tol = DEFAULT_TOL[algorithm] if tol is None else float(tol)
    A, AT = problem.A, problem.AT
    rows = problem.known & (problem.alpha > 0)
    rhs = problem.y * problem.alpha if target == "alpha" else problem.y
    obs = problem.observed
    if algorithm == "lsq_linear":
        idx = np.flatnonzero(obs)
        sub = problem.matrix()[np.flatnonzero(rows)][:, idx].astype(np.float64)
        res = lsq_linear(sub, rhs[rows].astype(np.float64), bounds=(0.0, 1.0), method="trf",
                         tol=tol, max_iter=max_iter, lsmr_tol="auto")
        q = np.zeros(problem.n_gaussians)
        q[idx] = res.x
        return MethodResult(q=q, iterations=int(res.nit),
                            info={"status": int(res.status), "cost": float(res.cost)})
    d = rows.astype(np.float32)
    yd = rhs * d
    L = 1.05 * operator_norm_sq(A, AT, d, power_iters)
    if L == 0.0:
        return MethodResult(q=np.zeros(problem.n_gaussians), iterations=0)
    start = problem.prior if problem.init_given else np.full(problem.n_gaussians, 0.5)
    unobs = ~obs
    x = np.where(obs, start, 0.0).astype(np.float32)
    z = x.copy()
    t = 1.0
    history = []
    it = 0
    for it in range(1, max_iter + 1):
        r = (A @ z) * d - yd
        x_new = np.clip(z - (AT @ r) / np.float32(L), 0.0, 1.0).astype(np.float32)
        x_new[unobs] = 0.0
        step = float(np.max(np.abs(x_new - x))) if x.size else 0.0
        # Adaptive restart: drop the momentum when it points uphill.
        if float(np.dot(z - x_new, x_new - x)) > 0:
            t = 1.0
        t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
        z = x_new + np.float32((t - 1.0) / t_new) * (x_new - x)
        x, t = x_new, t_new
        history.append({"objective": 0.5 * float(np.dot(r, r)), "step": step})
        report_progress(it, max_iter, history[-1]["objective"])
        if step < tol:
            break
    return MethodResult(q=x, iterations=it, history=history, info={"lipschitz": L})


register_method("least_squares", least_squares, check=_check)
