"""Vertical stacks of view operators (:class:`OperatorStack`) and the one input normaliser :func:`as_stack`.

The stack maps ``q`` (N,) to the concatenation of all views' flattened
images, ``[W(1) q; W(2) q; ...]``; its adjoint sums the views' adjoints,
``sum_c W(c)^T r_c`` (PyLops ``VStack``). It saves to and loads from a
directory without pickle (:mod:`.store`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator

from .._selection import index_list
from ..errors import ValidationError
from ..scene import GaussianScene
from . import _passes, store
from .view import ViewOperator, _Transposed, view_label

__all__ = ["OperatorStack", "as_stack"]


class OperatorStack(LinearOperator):
    """A vertical stack of :class:`ViewOperator` sharing the same N Gaussians.

    A ``scipy.sparse.linalg.LinearOperator`` of shape ``(sum of pixels, N)``,
    dtype float32: ``matvec(q) = [W(1) q; W(2) q; ...]`` (flat) and
    ``rmatvec(r) = sum_c W(c)^T r_c``.

    Parameters
    ----------
    views : sequence of ViewOperator
        At least one; all with the same number of columns. Kept as a tuple
        (``.views``): a stack does not change after it is made.
    fingerprint : str, optional
        :func:`scene_fingerprint` of the scene the views were built from.
    scene : GaussianScene, optional
        That scene, when ``fingerprint`` is not given: :attr:`fingerprint` is
        then its :func:`~.store.scene_fingerprint`, computed when first read
        (it hashes every Gaussian of the scene; a stack that is never saved
        or compared never pays for it). The scene must not change meanwhile.
    """

    def __init__(self, views, fingerprint: str | None = None, *, scene: GaussianScene | None = None):
        views = list(views)
        if not views:
            raise ValidationError("operator stack is empty: give at least one view")
        for i, v in enumerate(views):
            if not isinstance(v, ViewOperator):
                raise ValidationError(f"view {i}: expected a ViewOperator, got {type(v).__name__}")
        n = views[0].n_gaussians
        for i, v in enumerate(views):
            if v.n_gaussians != n:
                raise ValidationError(f"{view_label(v.camera, i)} has {v.n_gaussians} Gaussians (columns) but "
                                      f"view 0 has {n}: operators from different scenes cannot be stacked")
        if fingerprint is not None and not isinstance(fingerprint, str):
            raise ValidationError(f"fingerprint must be a string, got {type(fingerprint).__name__}")
        if scene is not None:
            if not isinstance(scene, GaussianScene) or len(scene) != n:
                raise ValidationError(f"scene must be the GaussianScene of the views' {n} Gaussians, got "
                                      f"{type(scene).__name__}"
                                      + (f" of {len(scene)}" if isinstance(scene, GaussianScene) else ""))
        super().__init__(np.float32, (sum(v.n_pixels for v in views), n))
        # A tuple: the shape and the cached stacked matrix depend on the views.
        self.views = tuple(views)
        self._fingerprint = fingerprint
        self._fingerprint_scene = scene if fingerprint is None else None
        self._stacked = None
        self._stacked_T = None
        self._column_sums = None
        self._row_sums = None
        self._offsets = None
        self._columns = None
        self._restricted = None  # (columns, stack) of the last on_columns

    @property
    def fingerprint(self) -> str | None:
        """:func:`~.store.scene_fingerprint` of the views' scene, or None when unknown (computed once, when first read)."""
        if self._fingerprint is None and self._fingerprint_scene is not None:
            self._fingerprint = store.scene_fingerprint(self._fingerprint_scene)
            self._fingerprint_scene = None
        return self._fingerprint

    # -- container protocol ---------------------------------------------------
    def __len__(self) -> int:
        return len(self.views)

    def __iter__(self):
        return iter(self.views)

    def __getitem__(self, i) -> ViewOperator:
        return self.views[i]

    def __repr__(self) -> str:
        return (f"OperatorStack({len(self)} views, n_gaussians={self.n_gaussians}, nnz={self.nnz}, "
                f"fingerprint={self.fingerprint!r})")

    @property
    def n_gaussians(self) -> int:
        return self.views[0].n_gaussians

    @property
    def n_pixels(self) -> int:
        """Total number of rows over all views."""
        return sum(v.n_pixels for v in self.views)

    @property
    def nnz(self) -> int:
        return sum(v.nnz for v in self.views)

    @property
    def image_shapes(self) -> list:
        return [v.image_shape for v in self.views]

    def row_offsets(self) -> np.ndarray:
        """(V+1,) int64: view ``c`` occupies rows ``offsets[c]:offsets[c+1]`` of the stack."""
        if self._offsets is None:
            self._offsets = np.concatenate([[0], np.cumsum([v.n_pixels for v in self.views])]).astype(np.int64)
            self._offsets.setflags(write=False)
        return self._offsets

    def row_sums(self) -> np.ndarray:
        """(sum of pixels,) float32 ``A 1``: the rendered alpha of each row (read-only; cached).

        One forward pass (float32 sums, row by row); cached like :meth:`column_sums`.
        """
        if self._row_sums is None:
            self._row_sums = self._matvec(np.ones(self.n_gaussians, np.float32))
            self._row_sums.setflags(write=False)
        return self._row_sums

    def observed(self) -> np.ndarray:
        """Bool (N,): Gaussians with a nonzero weight in any view."""
        out = np.zeros(self.n_gaussians, dtype=bool)
        for v in self.views:
            out |= v.observed()
        return out

    def column_sums(self) -> np.ndarray:
        """(N,) float64 ``sum_c W(c)^T 1``: how much each Gaussian is seen over all views (read-only; cached).

        The solvers read the same cached array (each Gaussian's known weight when every pixel is
        known), so it cannot be changed in place; ``column_sums().copy()`` to modify it.
        """
        if self._column_sums is None:
            self._column_sums = sum(np.asarray(v.W.T @ np.ones(v.n_pixels, np.float32), dtype=np.float64)
                                    for v in self.views)
            self._column_sums.setflags(write=False)
        return self._column_sums

    def columns(self) -> np.ndarray:
        """(M,) int64, ascending: the columns with a stored weight in some view (read-only; cached).

        One pass over the views' column indices, marking one byte per column.
        """
        if self._columns is None:
            mark = np.zeros(self.n_gaussians, bool)  # set at the stored entries only: no sort of the indices
            for v in self.views:
                mark[v.W.indices] = True
            self._columns = np.flatnonzero(mark)
            self._columns.setflags(write=False)
        return self._columns

    def on_columns(self, columns) -> "OperatorStack":
        """The stack on the columns ``columns`` alone: column ``j`` of the result is column ``columns[j]``.

        Parameters
        ----------
        columns : (M,) int array
            Strictly ascending column indices holding every column of
            :meth:`columns` (the others have no stored weight).

        Returns
        -------
        OperatorStack
            Each view keeps its rows, weights and row pointers; only the
            column indices are renumbered (an order-preserving map), so the
            entries of every row keep their order and every product gives,
            at each kept column or row, the values of this stack's. It has
            no fingerprint (it is no scene's) and no renderings. The last
            one made is kept while this stack lives (its own column
            indices: 4 bytes per stored weight): asking again for the same
            columns returns it.

        Raises
        ------
        ValidationError
            ``columns`` is not a strictly ascending integer array within
            ``[0, N)``, or leaves out a column with a stored weight.
        """
        cols = np.asarray(columns)
        n = self.n_gaussians
        if cols.ndim != 1 or cols.dtype.kind not in "ui":
            raise ValidationError(f"columns must be a 1-D integer array of column indices, got shape {cols.shape} "
                                  f"and dtype {cols.dtype}")
        if cols.size and (cols[0] < 0 or cols[-1] >= n or np.any(cols[1:] <= cols[:-1])):
            raise ValidationError(f"columns must be strictly ascending indices in [0, {n})")
        if self._restricted is not None and np.array_equal(self._restricted[0], cols):
            return self._restricted[1]
        need = self.columns()
        at = np.searchsorted(cols, need)
        if need.size and (at[-1] >= cols.size or np.any(cols[np.minimum(at, cols.size - 1)] != need)):
            raise ValidationError("columns must hold every column with a stored weight (OperatorStack.columns())")
        # int32 when the local indices fit (CSR's own index type): no int64 temporary per stored entry
        remap = np.empty(n, np.int32 if cols.size <= np.iinfo(np.int32).max else np.int64)
        remap[cols] = np.arange(cols.size)  # only the pages of cols are written
        out = OperatorStack([v._renumbered(remap[v.W.indices].astype(v.W.indices.dtype, copy=False), cols.size)
                             for v in self.views])
        kept = cols.astype(np.int64)  # a copy: the caller's array may change
        kept.setflags(write=False)
        self._restricted = (kept, out)
        return out

    def compact(self) -> tuple[np.ndarray, "OperatorStack"]:
        """``(columns, stack)``: this stack on columns that hold every stored weight (shares :meth:`on_columns`' cache).

        The last stack :meth:`on_columns` made, with its columns, when there
        is one; otherwise ``on_columns(columns())``. Either way a product
        ``W x`` of this stack equals the compact one's ``W' x[columns]``
        exactly: each row's entries and their order are the same.
        """
        if self._restricted is None:
            self.on_columns(self.columns())
        return self._restricted

    def subset(self, indices) -> "OperatorStack":
        """A stack of the views ``indices`` (integers, negative from the end, or a bool mask of length
        ``len(self)``), with the same fingerprint."""
        idx = index_list(indices, len(self), "view indices", negative=True)
        return OperatorStack([self.views[int(i)] for i in idx], self._fingerprint, scene=self._fingerprint_scene)

    # -- linear algebra ------------------------------------------------------
    def stacked(self) -> sp.csr_matrix:
        """All views as one CSR matrix (sum of pixels, N), float32: a copy of every weight; cached.

        The stack's own products (``@``, ``matvec``, ``rmatvec``, which the
        solvers use) never build it: they run view by view over the views'
        matrices (the forward pass bit-identical to this matrix's, the
        adjoint summed over two runs of views, see ``_passes``, which only
        rounds differently). Call this only where one
        scipy matrix is needed (it costs a second copy of every weight). The matrix is shared by later
        calls: copy it (``.copy()``) before changing it in place.
        """
        if self._stacked is None:
            self._stacked = sp.vstack([v.W for v in self.views], format="csr", dtype=np.float32)
        return self._stacked

    def stacked_transpose(self) -> sp.csc_matrix:
        """``stacked().T`` (N, sum of pixels) as a CSC matrix: a view of the stacked CSR, no copy; cached.

        Not an explicit CSR transpose: that costs a second copy of every
        weight and time to build, for no faster adjoint product
        (benchmarks/bench_speed.py).
        """
        if self._stacked_T is None:
            self._stacked_T = self.stacked().T
        return self._stacked_T

    def as_linear_operator(self) -> "OperatorStack":
        """The stack itself: it already is a ``scipy.sparse.linalg.LinearOperator`` (float32)."""
        return self

    def matvec(self, x) -> np.ndarray:
        """``[W(1) q; W(2) q; ...]`` flat (sum of pixels,) for ``q`` (N,) (or (N, 1))."""
        x = np.asarray(x)
        if x.shape not in ((self.n_gaussians,), (self.n_gaussians, 1)):
            raise ValidationError(f"q must have shape ({self.n_gaussians},) for this stack, got {x.shape}")
        return super().matvec(x)

    def rmatvec(self, x) -> np.ndarray:
        """``sum_c W(c)^T r_c`` (N,) for the concatenated per-view vectors ``r`` (sum of pixels,)."""
        y = np.asarray(x)
        if y.shape not in ((self.shape[0],), (self.shape[0], 1)):
            raise ValidationError(f"r must have shape ({self.shape[0]},) (all views' pixels, concatenated), "
                                  f"got {y.shape}")
        return super().rmatvec(y)

    # View by view over the views' own matrices, on two threads where two cores are free (no
    # stacked copy; the same results on any number of threads, see ._passes).
    def _mats(self):
        return [v.W for v in self.views]

    def _matvec(self, x):
        return _passes.forward(self._mats(), self.row_offsets(), self.n_gaussians, np.ascontiguousarray(np.ravel(x)))

    def _rmatvec(self, y):
        # the cached columns, when known: the two runs' sums are added there alone
        return _passes.adjoint(self._mats(), self.row_offsets(), self.n_gaussians, np.ascontiguousarray(np.ravel(y)),
                               self._columns)

    def _matmat(self, X):
        return _passes.forward(self._mats(), self.row_offsets(), self.n_gaussians, np.asarray(X))

    def _rmatmat(self, Y):
        return _passes.adjoint(self._mats(), self.row_offsets(), self.n_gaussians, np.ascontiguousarray(Y))

    def _adjoint(self):
        return _Transposed(self)

    _transpose = _adjoint

    # -- persistence ----------------------------------------------------------
    def save(self, directory, overwrite: bool = False) -> Path:
        """Write the stack to ``directory`` (manifest.json + one .npy per array); see :func:`.store.save`."""
        return store.save(self.views, self.fingerprint, directory, overwrite)

    @staticmethod
    def check_target(directory, overwrite: bool = False) -> Path:
        """Raise unless :meth:`save` may write to ``directory``; see :func:`.store.check_target`."""
        return store.check_target(directory, overwrite)

    @classmethod
    def load(cls, directory, mmap: bool = True, scene=None) -> "OperatorStack":
        """Read a stack written by :meth:`save`; see :func:`.store.load` for the validation."""
        views, fingerprint = store.load(directory, mmap=mmap, scene=scene)
        return cls(views, fingerprint)


def _pair_view(i: int, item) -> ViewOperator:
    """``(W, (H, W))`` -> ViewOperator (W sparse or a dense 2-D array)."""
    W, shape = item
    try:
        shape = tuple(int(s) for s in shape)
    except (TypeError, ValueError):
        raise ValidationError(f"view {i}: image shape must be (H, W) integers, got {shape!r}") from None
    if not sp.issparse(W):
        W = np.asarray(W)
        if W.dtype.kind not in "biuf":
            raise ValidationError(f"view {i}: W must be a sparse matrix or a numeric array, got dtype {W.dtype}")
    if len(shape) != 2 or W.ndim != 2 or W.shape[0] != shape[0] * shape[1]:
        raise ValidationError(f"view {i}: W has shape {W.shape}, which does not match "
                              f"image shape {shape} (rows must be H*W)")
    return _view(i, W, shape)


def _view(i: int, W, shape) -> ViewOperator:
    """View ``i`` of matrix ``W`` (as CSR float32, no copy when it already is): the view checks it (weights
    in [0, 1], rows), and its messages name the view's index."""
    if not (sp.issparse(W) and W.format == "csr" and W.dtype == np.float32):
        W = sp.csr_matrix(W, dtype=np.float32)
    try:
        return ViewOperator(W, None, shape)
    except ValidationError as exc:  # "view: ..." -> "view 3: ..."
        raise ValidationError(f"view {i}: {str(exc).split(': ', 1)[-1]}") from None


def as_stack(operators, masks=None) -> OperatorStack:
    """The one normaliser of "operators" inputs: anything accepted becomes an :class:`OperatorStack`.

    Parameters
    ----------
    operators : OperatorStack, or a sequence whose items are
        a :class:`ViewOperator`; a 2-D ``scipy.sparse`` matrix (converted to
        CSR float32); or a pair ``(W, (H, W))`` with ``W`` sparse or a dense
        2-D array. A bare matrix takes its image shape from the matching
        mask when ``masks`` is given (a 2-D mask gives ``(H, W)``, any other
        ``(1, size)``), else ``(1, rows)``.
    masks : sequence of arrays, optional
        Only used for the image shapes of bare matrices.

    Returns
    -------
    OperatorStack
        ``operators`` itself when it already is one.

    Raises
    ------
    ValidationError
        A single operator instead of a sequence ("wrap it in a list"), an
        unsupported item or a mask whose pixel count differs from its
        matrix's rows (messages name the view), an empty sequence, or views
        with different Gaussian counts.
    """
    if isinstance(operators, OperatorStack):
        return operators
    if isinstance(operators, (ViewOperator, LinearOperator)) or sp.issparse(operators) \
            or (isinstance(operators, np.ndarray) and operators.ndim == 2):
        raise ValidationError("operators must be an OperatorStack or a sequence of views, "
                              "not a single operator; wrap it in a list")
    try:
        items = list(operators)
    except TypeError:
        raise ValidationError(f"operators must be an OperatorStack or a sequence of ViewOperator / "
                              f"sparse matrices, got {type(operators).__name__}") from None
    mask_list = None
    if masks is not None:
        try:
            mask_list = list(masks)
        except TypeError:
            raise ValidationError("masks must be a sequence with one array per view") from None
    views = []
    for i, v in enumerate(items):
        if isinstance(v, ViewOperator):
            views.append(v)
        elif sp.issparse(v):
            if v.ndim != 2:
                raise ValidationError(f"view {i}: operator must be 2-D, got shape {v.shape}")
            shape = (1, int(v.shape[0]))
            if mask_list is not None and i < len(mask_list):
                ma = np.asarray(mask_list[i])
                shape = ma.shape if ma.ndim == 2 else (1, ma.size)
                if shape[0] * shape[1] != v.shape[0]:
                    raise ValidationError(f"view {i}: mask has {ma.size} pixels (shape {ma.shape}) but the "
                                          f"operator has {v.shape[0]} rows")
            views.append(_view(i, v, shape))
        elif isinstance(v, (tuple, list)) and len(v) == 2:
            views.append(_pair_view(i, v))
        else:
            raise ValidationError(f"view {i}: expected a ViewOperator, a scipy.sparse matrix or a "
                                  f"(W, (H, W)) pair, got {type(v).__name__}")
    return OperatorStack(views)
