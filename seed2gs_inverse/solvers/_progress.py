"""Per-iteration progress of a solve, without threading a callback through every method.

:func:`~seed2gs_inverse.solvers.solve` installs the caller's ``progress``
callable for the duration of one call (a :mod:`contextvars` variable, so
concurrent solves in other threads or tasks do not see it); the methods
call :func:`report` once per iteration. Without a callback, :func:`report`
costs one context-variable lookup.
"""

from __future__ import annotations

import contextlib
import contextvars
from typing import NamedTuple

__all__ = ["SolveProgress", "report", "reporting"]

_CALLBACK: contextvars.ContextVar = contextvars.ContextVar("seed2gs_solve_progress", default=None)


class SolveProgress(NamedTuple):
    """What a method reports after each iteration.

    Attributes
    ----------
    iteration : int
        Iterations done so far (1-based).
    total : int or None
        The most iterations the method will run (its ``max_iter`` or view
        budget); it may stop earlier on convergence.
    loss : float or None
        The method's current objective: the weighted BCE (``weighted_bce``),
        ``0.5 ||r||^2`` (``least_squares``, FISTA), the summed posterior
        entropy (sequential ``beta_bernoulli``).
    """

    iteration: int
    total: int | None = None
    loss: float | None = None


def report(iteration: int, total: int | None = None, loss: float | None = None) -> None:
    """Called by the methods once per iteration; forwards to the active callback, if any."""
    cb = _CALLBACK.get()
    if cb is not None:
        cb(SolveProgress(int(iteration), None if total is None else int(total),
                         None if loss is None else float(loss)))


@contextlib.contextmanager
def reporting(callback):
    """Make ``callback(SolveProgress)`` receive the reports of the methods run inside the block."""
    token = _CALLBACK.set(callback)
    try:
        yield
    finally:
        _CALLBACK.reset(token)
