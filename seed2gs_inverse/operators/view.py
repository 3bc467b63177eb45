"""The linear forward model of one view: :class:`ViewOperator` and :class:`Rendering`.

A frozen 3DGS scene turns every camera view ``c`` into a fixed sparse matrix
``W(c)`` of shape ``(H*W, N)``: entry ``W(c)[u, i] = alpha_i(u) T_i(u)`` is the
compositing weight of Gaussian ``i`` at pixel ``u`` (rows row-major,
``u = y*width + x``). A per-Gaussian quantity ``q`` (N,) renders as

    P(c) = W(c) q,

and the adjoint ``W(c)^T r`` splats a per-pixel quantity back onto the
Gaussians. :class:`ViewOperator` is a ``scipy.sparse.linalg.LinearOperator``
(flat vectors in and out); :meth:`ViewOperator.image` gives the ``(H, W)``
picture. This module needs only numpy and scipy (no rasterizer, no Numba).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator

from ..camera import Camera
from ..errors import ValidationError

__all__ = ["Rendering", "ViewOperator", "view_label"]

# The per-view rendering arrays kept next to W (what the view looked like).
RENDER_FIELDS = ("rgb", "alpha", "depth", "n_contrib")
# What each can hold: its dtype kind ("f" float, "iu" integer) and its range (sums of non-negative
# weights, depths in front of the camera, counts; no upper bound on alpha: a view may hold an
# operator other than the rasterizer's).
_RENDER_KINDS = {"rgb": "f", "alpha": "f", "depth": "f", "n_contrib": "iu"}
_RENDER_RANGES = {"alpha": (0.0, np.inf), "depth": (0.0, np.inf), "n_contrib": (0, np.inf)}


def rendering_problem(key: str, arr, image_shape) -> str | None:
    """What is wrong with the rendering array ``key`` of a view of ``image_shape`` (H, W), or None.

    The one rule for :class:`ViewOperator` and for a saved stack's files, so
    that a view accepted in memory saves as a stack that loads.
    """
    arr = np.asarray(arr)
    want = tuple(image_shape) + ((3,) if key == "rgb" else ())
    if arr.shape != want or arr.dtype.kind not in _RENDER_KINDS[key]:
        kind = "a float" if _RENDER_KINDS[key] == "f" else "an integer"
        return f"rendering '{key}' must be {kind} array of shape {want}, got {arr.dtype} {arr.shape}"
    if key != "n_contrib" and not np.all(np.isfinite(arr)):
        return f"rendering '{key}' holds non-finite values"
    lo, hi = _RENDER_RANGES.get(key, (-np.inf, np.inf))
    if arr.size and (float(arr.min()) < lo or float(arr.max()) > hi):
        return f"rendering '{key}' must lie in [{lo:g}, {hi:g}]"
    return None


@dataclass(eq=False)
class Rendering:
    """The image of one view; every field is optional (``None`` when absent).

    A rasterizer pass fills all four; a saved operator stack loads as a
    ``Rendering`` with whichever arrays were saved (never as a dict).

    Attributes
    ----------
    rgb : (H, W, 3) float32 or None
        Composited colour, background added with the remaining transmittance.
    alpha : (H, W) float32 or None
        Accumulated opacity ``1 - T_final`` in [0, 1].
    depth : (H, W) float32 or None
        Expected view depth ``sum_i w_i z_i / alpha``; 0 where ``alpha == 0``.
    n_contrib : (H, W) int32 or None
        Number of Gaussians that contributed a nonzero weight to the pixel.
    """

    rgb: np.ndarray | None = None
    alpha: np.ndarray | None = None
    depth: np.ndarray | None = None
    n_contrib: np.ndarray | None = None

    @property
    def image_shape(self) -> tuple | None:
        """``(H, W)`` of the first array present, or None when all are absent."""
        for key in RENDER_FIELDS:
            arr = getattr(self, key)
            if arr is not None:
                return tuple(np.shape(arr)[:2])
        return None


def view_label(camera, index=None) -> str:
    """``view 'name'`` / ``view 3 ('name')`` for error messages."""
    name = getattr(camera, "name", "") if camera is not None else ""
    if index is None:
        return f"view '{name}'" if name else "view"
    return f"view {index}" + (f" ('{name}')" if name else "")


def _check_weights(data, label: str) -> None:
    """Raise a ValidationError unless the weights ``data`` are finite and lie in [0, 1].

    Compositing weights ``alpha_i(u) T_i(u)`` always do; anything else (a
    NaN, a negative or a weight above 1) comes from a broken matrix and would
    fail late in a solver, or be saved where :meth:`OperatorStack.load`
    refuses it. Two reductions (NaN propagates through both).
    """
    data = np.asarray(data)
    if data.size == 0:
        return
    lo, hi = data.min(), data.max()
    if not (lo >= 0 and hi <= 1):
        raise ValidationError(f"{label}: the operator's weights must be finite and lie in [0, 1] (compositing "
                              f"weights), got values from {lo} to {hi}; rebuild it from the scene")


def _check_structure(W, label: str) -> None:
    """Raise a ValidationError unless ``W``'s CSR arrays describe a valid matrix.

    scipy does not check them when a matrix is made from ``(data, indices,
    indptr)``, and the passes hand them to its unchecked kernels: a column
    index out of range would give garbage, or a segmentation fault in the adjoint.
    O(rows + nnz), like the weight check.
    """
    indptr, indices = np.asarray(W.indptr), np.asarray(W.indices)
    rows, n = W.shape
    if (indptr.shape != (rows + 1,) or indices.shape != np.shape(W.data) or indptr[0] != 0
            or indptr[-1] != indices.size or np.any(np.diff(indptr) < 0)):
        raise ValidationError(f"{label}: W's indptr must have one entry per row plus one, start at 0, never "
                              "decrease and end at its number of weights; rebuild the matrix (or call "
                              "W.check_format() to see what scipy makes of it)")
    if indices.size and (int(indices.min()) < 0 or int(indices.max()) >= n):
        raise ValidationError(f"{label}: W's column indices must lie in [0, {n}), got values from "
                              f"{int(indices.min())} to {int(indices.max())}")


class ViewOperator(LinearOperator):
    """The linear forward model of one view, ``P = W q``, as a ``LinearOperator``.

    Shape ``(H*W, N)``, dtype float32: ``matvec(q)`` (or ``op @ q``) returns
    the flat ``(H*W,)`` rendering ``W q``, ``rmatvec(y)`` the ``(N,)`` splat
    ``W^T y``, and :meth:`image` the ``(H, W)`` picture of ``W q``.

    Parameters
    ----------
    W : scipy.sparse.csr_matrix or csr_array, shape (H*W, N), float32
        Compositing weights; row ``y*width + x`` is pixel ``(x, y)``, column
        ``i`` is scene Gaussian ``i``. Row sums equal the rendered alpha (<= 1);
        every weight must be finite and lie in [0, 1] (ValidationError otherwise).
    camera : Camera or None
        The view's camera; when given, its ``image_shape`` must equal
        ``image_shape``. ``None`` for operators without geometry (tests,
        matrices from elsewhere).
    image_shape : (int, int), optional
        ``(H, W)`` of the view's image; default the camera's, else
        ``(1, H*W)``.
    rendering : Rendering, optional
        The rendering the operator was built from (``rgb``, ``alpha``,
        ``depth``, ``n_contrib`` arrays, any of them None).
    """

    def __init__(self, W, camera: Camera | None = None, image_shape=None, rendering: Rendering | None = None):
        label = view_label(camera)
        if image_shape is None:
            if isinstance(camera, Camera):
                image_shape = camera.image_shape
            elif sp.issparse(W) and W.ndim == 2:
                image_shape = (1, W.shape[0])
        try:
            shape = tuple(int(s) for s in image_shape)
        except (TypeError, ValueError):
            raise ValidationError(f"{label}: image_shape must be (H, W) integers, got {image_shape!r}") from None
        if len(shape) != 2 or min(shape) <= 0:
            raise ValidationError(f"{label}: image_shape must be two positive integers (H, W), got {shape}")
        if camera is not None:
            if not isinstance(camera, Camera):
                raise ValidationError(f"{label}: camera must be a Camera or None, got {type(camera).__name__}")
            if tuple(camera.image_shape) != shape:
                raise ValidationError(
                    f"{label}: image_shape {shape} differs from the camera's {camera.image_shape}; "
                    "pass the (scaled) camera the operator was built for")
        if not sp.issparse(W) or W.format != "csr":
            kind = W.format if sp.issparse(W) else type(W).__name__
            raise ValidationError(f"{label}: W must be a scipy.sparse CSR matrix, got {kind}; "
                                  "convert with scipy.sparse.csr_matrix(W)")
        if W.dtype != np.float32:
            raise ValidationError(f"{label}: W must be float32, got {W.dtype}; use W.astype(numpy.float32)")
        if W.shape[0] != shape[0] * shape[1]:
            raise ValidationError(f"{label}: W has {W.shape[0]} rows but the image {shape} has "
                                  f"{shape[0] * shape[1]} pixels")
        _check_structure(W, label)
        _check_weights(W.data, label)
        if rendering is not None:
            if not isinstance(rendering, Rendering):
                raise ValidationError(f"{label}: rendering must be a Rendering or None, "
                                      f"got {type(rendering).__name__}")
            for key in RENDER_FIELDS:
                arr = getattr(rendering, key)
                problem = None if arr is None else rendering_problem(key, arr, shape)
                if problem:
                    raise ValidationError(f"{label}: {problem}")
        super().__init__(np.float32, W.shape)
        self.W = W
        self.camera = camera
        self.image_shape = shape
        self.rendering = rendering

    # -- facts -------------------------------------------------------------
    @property
    def n_gaussians(self) -> int:
        """Number of columns of ``W`` (Gaussians in the scene)."""
        return int(self.W.shape[1])

    @property
    def n_pixels(self) -> int:
        return int(self.W.shape[0])

    @property
    def nnz(self) -> int:
        return int(self.W.nnz)

    @property
    def name(self) -> str:
        return self.camera.name if self.camera is not None else ""

    def __repr__(self) -> str:
        return (f"ViewOperator({view_label(self.camera)}, image_shape={self.image_shape}, "
                f"n_gaussians={self.n_gaussians}, nnz={self.nnz})")

    def observed(self) -> np.ndarray:
        """Bool (N,): Gaussians with a nonzero weight at some pixel of this view."""
        out = np.zeros(self.n_gaussians, dtype=bool)
        out[np.asarray(self.W.indices)[np.asarray(self.W.data) != 0]] = True
        return out

    def _renumbered(self, indices: np.ndarray, n_columns: int) -> "ViewOperator":
        """This view with its column indices replaced by ``indices`` (same order, in ``[0, n_columns)``).

        For :meth:`OperatorStack.on_columns`, whose renumbering of checked
        views keeps every index in range: the weights are this view's,
        checked when it was made, so nothing is checked again (a pass over
        every weight). The rendering is not carried.
        """
        W = sp.csr_matrix((self.W.data, indices, self.W.indptr), shape=(self.W.shape[0], int(n_columns)),
                          copy=False)
        out = ViewOperator.__new__(ViewOperator)
        LinearOperator.__init__(out, np.float32, W.shape)
        out.W, out.camera, out.image_shape, out.rendering = W, self.camera, self.image_shape, None
        return out

    def alpha(self) -> np.ndarray:
        """Rendered opacity ``W 1`` as an (H, W) float32 image."""
        return np.asarray(self.W.sum(axis=1), dtype=np.float32).reshape(self.image_shape)

    # -- forward / adjoint --------------------------------------------------
    def matvec(self, x) -> np.ndarray:
        """Render a per-Gaussian quantity: ``W q``, flat (H*W,) (or (H*W, 1) for an (N, 1) input).

        Parameters
        ----------
        x : (N,) or (N, 1) array
        """
        x = np.asarray(x)
        if x.shape not in ((self.n_gaussians,), (self.n_gaussians, 1)):
            raise ValidationError(f"{view_label(self.camera)}: q must have shape ({self.n_gaussians},), "
                                  f"got {x.shape}")
        return super().matvec(x)

    def rmatvec(self, x) -> np.ndarray:
        """Splat a per-pixel quantity onto the Gaussians: ``W^T y``, (N,).

        Parameters
        ----------
        x : (H*W,) or (H*W, 1) array, or an (H, W) image
        """
        y = np.asarray(x)
        if y.shape == self.image_shape and y.shape != (self.n_pixels, 1):
            y = y.reshape(-1)
        if y.shape not in ((self.n_pixels,), (self.n_pixels, 1)):
            raise ValidationError(f"{view_label(self.camera)}: image must have shape {self.image_shape} or "
                                  f"({self.n_pixels},), got {y.shape}")
        return super().rmatvec(y)

    def image(self, q) -> np.ndarray:
        """``W q`` as the (H, W) image of the view.

        Parameters
        ----------
        q : (N,) array
        """
        return self.matvec(q).reshape(self.image_shape)

    def _matvec(self, x):
        return np.asarray(self.W @ np.ravel(x))

    def _rmatvec(self, y):
        return np.asarray(self.W.T @ np.ravel(y))

    def _matmat(self, X):
        return np.asarray(self.W @ X)

    def _rmatmat(self, Y):
        return np.asarray(self.W.T @ Y)

    def _adjoint(self):
        # The transpose as a plain LinearOperator (W is real: adjoint == transpose).
        return _Transposed(self)

    _transpose = _adjoint


class _Transposed(LinearOperator):
    """``W^T`` of a view or stack (real weights: the adjoint is the transpose)."""

    def __init__(self, op):
        super().__init__(op.dtype, (op.shape[1], op.shape[0]))
        self.op = op

    def _matvec(self, y):
        return self.op._rmatvec(y)

    def _rmatvec(self, x):
        return self.op._matvec(x)

    def _matmat(self, Y):
        return self.op._rmatmat(Y)

    def _rmatmat(self, X):
        return self.op._matmat(X)

    def _adjoint(self):
        return self.op

    _transpose = _adjoint
