"""A limited-memory BFGS minimiser whose curvature memory outlives one call.

:func:`lbfgs` is unconstrained L-BFGS (two-loop recursion) with a line
search that extends short steps and backtracks long ones. The caller owns
the memory of curvature pairs, so an outer loop that changes the loss
mildly between calls (the view reweighting of
:mod:`~seed2gs_inverse.solvers.weighted_bce`) continues with the same
curvature estimate instead of restarting from a steepest-descent step.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections import deque

__all__ = ["lbfgs"]

#: A too-short step is extended by this factor, at most ``_MAX_EXTENSIONS`` times per line
#: search (a factor of about 1e6 in all; Moré and Thuente's search extrapolates to at most 5
#: times its step).
_EXTEND, _MAX_EXTENSIONS = 4.0, 10


def lbfgs(fun, x, max_iter: int, ftol: float, gtol: float, memory: deque, callback=None) -> tuple:
    """Minimise ``fun`` by L-BFGS with a line search that extends short steps and backtracks long ones.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> (f, g)``: the loss (float) and its gradient (same shape as ``x``).
    x : (n,) float64
        Starting point.
    max_iter : int
        Most iterations of this call.
    ftol, gtol : float
        Stopping tolerances, as in scipy's L-BFGS-B (Notes).
    memory : collections.deque
        The curvature pairs ``(s, y, 1 / s.y)``, oldest first; its ``maxlen``
        is the L-BFGS memory. Updated in place, so a later call continues
        with the same curvature estimate; cleared when the line search fails
        or the direction is not one of descent.
    callback : callable, optional
        ``callback(x, f)`` after every iteration; raising ``StopIteration``
        ends the run with status 0.

    Returns
    -------
    x : (n,) float64
        The last accepted point.
    f : float
        The loss at ``x``.
    iterations : int
        Iterations taken in this call.
    status : int
        0 converged (or stopped by the callback), 1 ``max_iter`` reached,
        2 the line search found no decrease.
    message : str
        Why it stopped.

    Notes
    -----
    The direction ``d = -H g`` comes from the two-loop recursion over the
    stored pairs with the initial scaling ``H0 = s.y / y.y`` of the newest
    pair (Nocedal & Wright, Alg. 7.4). A pair is stored only when
    ``s.y > 1e-10 y.y``.

    The trial step ``t`` starts at 1, or without memory at ``1 / ||g||`` (a
    unit-length step ``-g / ||g||``, as in scipy's L-BFGS-B). With
    ``gd = g.d``, a step passes the Armijo rule when

        f(x + t d) <= f + 1e-4 t gd,

    and it is taken when the slope has also flattened,
    ``g(x + t d).d >= 0.9 gd`` (the weak Wolfe conditions: a quasi-Newton
    step of 1 usually passes both, so most iterations cost one evaluation).
    A step that passes Armijo with the slope still steep is too short: it is
    made ``_EXTEND`` times longer, at most ``_MAX_EXTENSIONS`` times; when an
    extension fails Armijo, the step before it is taken. A step that fails
    Armijo before any has passed is shrunk to the minimiser of the quadratic
    through ``f``, ``gd`` and ``f(x + t d)``, kept within ``[0.1 t, 0.5 t]``,
    and the first shrunk step that passes Armijo is taken.

    It stops, like scipy's L-BFGS-B, when

        (f_k - f_{k+1}) / max(|f_k|, |f_{k+1}|, 1) <= ftol

    after a quasi-Newton step (a first steepest-descent step is too short
    to judge convergence by) or when ``max |g| <= gtol`` (status 0), after
    ``max_iter`` iterations (status 1), or when 30 trial steps give no
    decrease (status 2).
    """
    f, g = fun(x)
    if np.max(np.abs(g), initial=0.0) <= gtol:
        return x, f, 0, 0, "gradient below gtol"
    for nit in range(1, max_iter + 1):
        d = -g  # a fresh array, updated in place below
        alphas = []
        for s, y, r in reversed(memory):
            a = r * np.dot(s, d)
            _axpy(-a, y, d)
            alphas.append(a)
        if memory:
            s, y, r = memory[-1]
            d *= 1.0 / (r * np.dot(y, y))
        for (s, y, r), a in zip(memory, reversed(alphas)):
            _axpy(a - r * np.dot(y, d), s, d)
        gd = float(np.dot(g, d))
        if not gd < 0:  # not a descent direction (numerical trouble): restart from steepest descent
            memory.clear()
            d, gd = -g, -float(np.dot(g, g))
        quasi_newton = bool(memory)
        # without memory a unit-length step (-gd = |g|^2; 1 where it underflows to 0)
        t = 1.0 if quasi_newton or gd == 0 else 1.0 / np.sqrt(-gd)
        accepted, bracketed, extensions = None, False, 0  # accepted: the last step that passed Armijo
        for _ in range(30):
            xn = x + t * d
            fn, gn = fun(xn)
            if np.isfinite(fn) and fn <= f + 1e-4 * t * gd:
                accepted = xn, fn, gn
                gdn = float(np.dot(gn, d))
                # taken once the slope has flattened (weak Wolfe; also when it is not a number),
                # after a shrink, or after the last extension allowed
                if bracketed or extensions == _MAX_EXTENSIONS or not gdn < 0.9 * gd:
                    break
                t *= _EXTEND  # still nearly as steep as at the start: the step was too short
                extensions += 1
                continue
            bracketed = True
            if accepted is not None:  # an extension overshot: keep the step before it
                break
            # minimiser of the quadratic through f, the slope gd and fn, kept within [0.1 t, 0.5 t]
            tq = -gd * t * t / (2.0 * (fn - f - gd * t)) if np.isfinite(fn) else 0.1 * t
            t = min(max(tq, 0.1 * t), 0.5 * t)
        if accepted is None:
            memory.clear()  # the pairs gave no descent: the next call starts afresh
            return x, f, nit - 1, 2, "line search failed to decrease the loss"
        xn, fn, gn = accepted
        s, y = xn - x, gn - g
        sy, yy = float(np.dot(s, y)), float(np.dot(y, y))
        if sy > 1e-10 * yy:
            memory.append((s, y, 1.0 / sy))
        f_old, x, f, g = f, xn, fn, gn
        if callback is not None:
            try:
                callback(x, f)
            except StopIteration:
                return x, f, nit, 0, "stopped by the callback"
        if quasi_newton and f_old - f <= ftol * max(abs(f_old), abs(f), 1.0):
            return x, f, nit, 0, "relative reduction of the loss below ftol"
        if np.max(np.abs(g)) <= gtol:
            return x, f, nit, 0, "gradient below gtol"
    return x, f, max_iter, 1, "maximum number of iterations reached"


def _axpy(a, x, y):
    """``y += a x`` in place; returns ``y``."""
    y += a * x
    return y
