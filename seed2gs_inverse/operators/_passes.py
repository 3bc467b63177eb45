"""The stack's sparse passes, view by view, without a stacked copy of the weights.

For a stack of views ``W(1), ..., W(V)`` (CSR, (P_c, N) each) with row
offsets ``o`` (``o[0] = 0``, ``o[c] - o[c-1] = P_c``),

    forward:  (A x)[o[c-1]:o[c]] = W(c) x,
    adjoint:  A^T y = sum_c W(c)^T y[o[c-1]:o[c]].

For float32 vectors both call scipy's own CSR kernels (``csr_matvec``:
``y += W x`` row by row; ``csc_matvec`` on the arrays of ``W(c)`` read as
``W(c)^T`` in CSC: ``y[col] += w r_row``), the loops scipy runs for
``W @ x`` and ``W.T @ r``, so each view's result is bit-identical to
scipy's, while no weight is copied: a stacked copy would hold every weight
a second time.

The views are cut into two runs of consecutive views with about equal
non-zeros (:func:`_halves`), and two threads run one run each where two
cores are available (:mod:`seed2gs_inverse._threads`; scipy's kernels
release the GIL) and the stack has at least :data:`PARALLEL_MIN_NNZ`
non-zeros. The forward pass writes disjoint rows, so it is the same either
way. The adjoint accumulates each run into its own (N,) vector and returns
``(sum over run 0) + (sum over run 1)`` on one thread or two alike: the
result never depends on the number of threads, and within each run it is
bit-identical to the stacked matrix's pass over that run's rows.

Other dtypes (float64 right-hand sides, which make scipy accumulate in
float64), blocks of vectors (N, K), and a scipy without the private kernels
take the public ``W @ x`` per view instead (one (N,) temporary per view for
the adjoint).
"""

from __future__ import annotations

import numpy as np

from .. import _threads

try:  # scipy's compiled CSR/CSC kernels; private, hence the public fallback below
    from scipy.sparse import _sparsetools as _st

    _KERNELS = hasattr(_st, "csr_matvec") and hasattr(_st, "csc_matvec")
except ImportError:  # pragma: no cover - depends on the scipy build
    _st, _KERNELS = None, False

__all__ = ["forward", "adjoint"]

#: Below this many non-zeros a pass runs on the calling thread alone (a
#: thread hand-off costs more than it saves).
PARALLEL_MIN_NNZ = 1_000_000


def _halves(mats) -> tuple:
    """Two runs of consecutive view indices with about equal non-zeros (the second empty for one view)."""
    nnz = np.cumsum([W.nnz for W in mats])
    if len(mats) < 2:
        return range(len(mats)), range(len(mats), len(mats))
    cut = int(np.clip(np.searchsorted(nnz, nnz[-1] / 2.0) + 1, 1, len(mats) - 1))
    return range(0, cut), range(cut, len(mats))


def _direct(W, v) -> bool:
    """Whether ``W`` and the vector ``v`` can go straight to scipy's kernels (no cast, no copy)."""
    return (_KERNELS and v.ndim == 1 and v.dtype == W.dtype == np.float32 and v.flags.c_contiguous
            and W.indptr.dtype == W.indices.dtype)


def forward(mats, offsets, n_cols: int, x: np.ndarray) -> np.ndarray:
    """The stacked forward product ``[W(1) x; W(2) x; ...]``.

    Parameters
    ----------
    mats : sequence of scipy.sparse.csr_matrix
        The views' matrices, (P_c, N) each.
    offsets : (V+1,) int64
        Row offsets of the views in the stacked output.
    n_cols : int
        N, the number of columns (Gaussians).
    x : (N,) or (N, K) ndarray

    Returns
    -------
    (P,) or (P, K) ndarray
        In scipy's result dtype, ``result_type(float32, x.dtype)``.
    """
    dtype = np.result_type(np.float32, x.dtype)
    out = np.zeros((int(offsets[-1]),) + x.shape[1:], dtype=dtype)
    halves = _halves(mats)

    def run(k):
        for i in halves[k]:
            W, lo, hi = mats[i], offsets[i], offsets[i + 1]
            if _direct(W, x):
                _st.csr_matvec(W.shape[0], n_cols, W.indptr, W.indices, W.data, x, out[lo:hi])
            else:
                out[lo:hi] = W @ x

    _threads.run_both(run, sum(W.nnz for W in mats) >= PARALLEL_MIN_NNZ and len(halves[1]) > 0)
    return out


def adjoint(mats, offsets, n_cols: int, y: np.ndarray, columns: np.ndarray | None = None) -> np.ndarray:
    """The stacked adjoint product ``sum_c W(c)^T y[offsets[c]:offsets[c+1]]``.

    Parameters
    ----------
    mats : sequence of scipy.sparse.csr_matrix
        The views' matrices, (P_c, N) each.
    offsets : (V+1,) int64
        Row offsets of the views in ``y``.
    n_cols : int
        N, the number of columns (Gaussians).
    y : (P,) or (P, K) ndarray
    columns : (M,) int array, optional
        Ascending indices holding every column with a stored weight in
        ``mats`` (not checked): the two runs' sums are added there alone
        (elsewhere both are 0), so that the rows of the result no weight
        reaches are not written (an (N,) product about a small object then
        costs memory only near its columns).

    Returns
    -------
    (N,) or (N, K) ndarray
        In ``result_type(float32, y.dtype)``; the sum of the two runs'
        partial sums, in that order (module docstring).
    """
    dtype = np.result_type(np.float32, y.dtype)
    halves = _halves(mats)
    out = [np.zeros((n_cols,) + y.shape[1:], dtype=dtype) for _ in halves]

    def run(k):
        acc = out[k]
        for i in halves[k]:
            W, yc = mats[i], y[offsets[i]:offsets[i + 1]]
            if _direct(W, yc):
                _st.csc_matvec(n_cols, W.shape[0], W.indptr, W.indices, W.data, yc, acc)
            else:
                acc += W.T @ yc

    _threads.run_both(run, sum(W.nnz for W in mats) >= PARALLEL_MIN_NNZ and len(halves[1]) > 0)
    if columns is None:
        return np.add(out[0], out[1], out=out[0])
    out[0][columns] += out[1][columns]
    return out[0]
