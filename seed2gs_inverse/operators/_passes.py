"""The stack's sparse passes, view by view, without a stacked copy of the weights.

``A q`` writes each view's rows ``W(c) q`` into its slice of one output and
``A^T r`` accumulates ``W(c)^T r_c`` into one (N,) output. For float32
vectors both call scipy's own CSR kernels (``csr_matvec``: ``y += W x`` row
by row; ``csc_matvec`` on the arrays of ``W(c)`` read as ``W(c)^T`` in CSC:
``y[col] += w r_row``), the same loops scipy runs for ``W @ x`` and
``W.T @ r``. Row after row, view after view, is exactly the order of the
stacked matrix's pass, so the results are bit-identical to the passes over
``OperatorStack.stacked()`` while no weight is copied (a stacked copy of
the firepit's 47 views is 0.46 GB and 1.3-1.9 s of page faults).

Other dtypes (float64 right-hand sides, which make scipy accumulate in
float64), blocks of vectors, and a scipy without the private kernels take
the public ``W @ x`` per view instead (one (N,) temporary per view for the
adjoint).
"""

from __future__ import annotations

import numpy as np

try:  # scipy's compiled CSR/CSC kernels; private, hence the public fallback below
    from scipy.sparse import _sparsetools as _st

    _KERNELS = hasattr(_st, "csr_matvec") and hasattr(_st, "csc_matvec")
except ImportError:  # pragma: no cover - depends on the scipy build
    _st, _KERNELS = None, False

__all__ = ["forward", "adjoint"]


def _direct(W, v) -> bool:
    """Whether ``W`` and the vector ``v`` can go straight to scipy's kernels (no cast, no copy)."""
    return (_KERNELS and v.ndim == 1 and v.dtype == W.dtype == np.float32 and v.flags.c_contiguous
            and W.indptr.dtype == W.indices.dtype)


def forward(mats, offsets, n_cols: int, x: np.ndarray) -> np.ndarray:
    """``[W(1) x; W(2) x; ...]``: (P,) for ``x`` (N,), or (P, K) for ``x`` (N, K).

    ``mats``: the views' CSR matrices; ``offsets``: (V+1,) row offsets.
    The result dtype is scipy's (``result_type(float32, x.dtype)``).
    """
    dtype = np.result_type(np.float32, x.dtype)
    out = np.zeros((int(offsets[-1]),) + x.shape[1:], dtype=dtype)
    for W, lo, hi in zip(mats, offsets[:-1], offsets[1:]):
        if _direct(W, x):
            _st.csr_matvec(W.shape[0], n_cols, W.indptr, W.indices, W.data, x, out[lo:hi])
        else:
            out[lo:hi] = W @ x
    return out


def adjoint(mats, offsets, n_cols: int, y: np.ndarray) -> np.ndarray:
    """``sum_c W(c)^T y_c``: (N,) for ``y`` (P,), or (N, K) for ``y`` (P, K)."""
    dtype = np.result_type(np.float32, y.dtype)
    out = np.zeros((n_cols,) + y.shape[1:], dtype=dtype)
    for W, lo, hi in zip(mats, offsets[:-1], offsets[1:]):
        yc = y[lo:hi]
        if _direct(W, yc):
            _st.csc_matvec(n_cols, W.shape[0], W.indptr, W.indices, W.data, yc, out)
        else:
            out += W.T @ yc
    return out
