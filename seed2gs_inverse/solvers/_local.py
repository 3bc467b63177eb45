"""The solve on the Gaussians the problem touches: operators and graph restricted to their columns.

A Gaussian whose column is empty in every view and that has no edge in the
graph takes no part in the solve: it keeps the prior whatever the method
does. :func:`~seed2gs_inverse.solvers.solve` therefore runs the methods of
:data:`LOCAL_METHODS` on the touched columns alone (:func:`touched_columns`,
:meth:`~seed2gs_inverse.operators.OperatorStack.on_columns`,
:func:`~seed2gs_inverse.graph.graph_on_nodes`) and scatters ``q`` back to
the N Gaussians, so that the solve's vectors have the length of the object's
neighbourhood, not of the scene. The columns keep their order, so every
per-Gaussian sum runs over the same terms in the same order: ``q`` is bit
for bit the one of the N-column problem.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..operators import OperatorStack
from ._common import prior_parts

__all__ = ["LOCAL_METHODS", "touched_columns", "SupportPrior"]

#: Methods whose arithmetic on a Gaussian's column never mixes with another column's (each
#: Gaussian's value comes from sums over its own column, the pixels' sums from their own rows):
#: on the touched columns alone they give the N-column problem's ``q`` bit for bit.
#: ``least_squares`` draws a random start vector of length N for its step size and
#: ``beta_bernoulli`` orders views by sums over all Gaussians: they solve over all N.
LOCAL_METHODS = frozenset({"voting", "weighted_bce"})


def touched_columns(stack: OperatorStack, graph: sp.csr_matrix | None = None) -> np.ndarray:
    """Ascending indices of the columns with a weight in some view or an edge in ``graph`` (checked, (N, N)).

    The views' part is the stack's cached :meth:`~.OperatorStack.columns`;
    a graph whose edges all join those columns adds nothing. (``check_graph``
    accepts a graph symmetric within a tolerance, whose stored pattern may
    not be: both ends of every edge are tested.)
    """
    cols = stack.columns()
    if graph is None or not graph.nnz:
        return cols
    if int((graph.indptr[cols + 1] - graph.indptr[cols]).sum()) == graph.nnz:
        # every edge starts at one of cols; it adds nothing if every one also ends there
        at = np.minimum(np.searchsorted(cols, graph.indices), cols.size - 1)
        if np.array_equal(cols[at], graph.indices):
            return cols
    mark = np.zeros(stack.n_gaussians, bool)
    mark[cols] = True
    mark[graph.indices] = True
    mark[np.flatnonzero(np.diff(graph.indptr))] = True  # the rows with an edge, for a pattern not symmetric
    return np.flatnonzero(mark)


class SupportPrior:
    """The prior ``q0`` (N,) of :func:`~._common.prior_from_init`, kept as its support set when ``init`` is one.

    A support set (None, a bool mask or indices) gives 1 on it and 0
    elsewhere: it is kept as the (N,) bool mask instead of an (N,) float64
    array. A float prior is kept as :func:`~._common.prior_from_init` returns
    it. Either way :meth:`at` and :meth:`map` give the values the float64
    array would.

    Raises
    ------
    ValidationError
        ``init`` is not a valid prior (:func:`~._common.prior_from_init`'s checks and messages).
    """

    def __init__(self, init, n: int):
        self.n = int(n)
        self.support, self.values = prior_parts(init, self.n)

    def at(self, cols: np.ndarray) -> np.ndarray:
        """The prior at ``cols``, float64."""
        return self.values[cols] if self.support is None else self.support[cols].astype(np.float64)

    def map(self, fn) -> np.ndarray:
        """(N,) float32: ``fn(q0).astype(float32)`` for an elementwise ``fn`` of float64 arrays.

        On a support set ``fn`` is evaluated on 0 and 1 alone and spread: the
        same values, without an (N,) float64 temporary.
        """
        if self.support is None:
            return np.asarray(fn(self.values), np.float64).astype(np.float32)
        off, on = np.asarray(fn(np.array([0.0, 1.0])), np.float64).astype(np.float32)
        out = np.full(self.n, off, np.float32)
        out[self.support] = on
        return out
