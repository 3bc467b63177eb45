"""The object's neighbourhood: the Gaussians the stages after the orbit views work on.

Once the orbit views are rendered, the stages of
:func:`~seed2gs_inverse.pipeline.extract.extract` need only the Gaussians
that can reach the object's views and those the 3D rules look at around the
object. :func:`object_neighbourhood` gathers them, ``L`` (ascending scene
indices):

* every column of a supervision view's operator (what any view sees);
* the lift's G0;
* the Gaussians within ``reach * R`` of the lift's centre ``o`` (``R`` the
  lift's radius): the region of the evidence graph and of the faint
  Gaussians' rule (:data:`~.completion.GRAPH_DEFAULTS` ``region``) and the
  support surface's annulus (:func:`support_reach`). They hold Gaussians no
  view sees (inner layers, the hidden ground under the object), which
  those rules decide.

A :class:`Neighbourhood` holds ``L`` and the sub-scene ``scene.subset(L)``;
the support surface, the evidence graph, the faint Gaussians' rule and the
islands then run on the sub-scene, and their results are put back in the
scene's numbering (:meth:`Neighbourhood.expand`, :meth:`Neighbourhood.scatter`).
As ``L`` keeps the scene's order, each rule sees the same Gaussians in the
same order as on the whole scene and gives the same result. Memory and time
after the orbit views follow the neighbourhood, not the scene's size N; the
N-length results are the extraction's own (``q``, ``selected``).

Every lookup of "the Gaussians whose centre lies near the object" goes
through :func:`neighbourhood`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from .._validation import as_real
from ..errors import ValidationError
from ..graph import region_subset
from ..operators import OperatorStack
from ..raster import FrozenScene
from ..scene import GaussianScene

if TYPE_CHECKING:
    from .seed_lift import SeedLift

__all__ = ["neighbourhood", "Neighbourhood", "object_neighbourhood", "support_reach"]

def neighbourhood(scene: GaussianScene | FrozenScene, center, radius: float) -> np.ndarray:
    """Ascending indices of the Gaussians whose means lie within ``radius`` of ``center`` (boundary included).

    Parameters
    ----------
    scene : GaussianScene or FrozenScene
        A :class:`~seed2gs_inverse.raster.FrozenScene` tests only the
        Gaussians of the chunks its spatial index finds near the ball
        (:meth:`~seed2gs_inverse.raster.spatial.SpatialIndex.ball`, a
        superset); the same Gaussians are returned.
    center : (3,) float
        A finite point.
    radius : float
        A finite distance >= 0.

    Returns
    -------
    (M,) int64

    Raises
    ------
    ValidationError
        ``scene`` is not a GaussianScene, ``center`` not a finite 3-vector
        or ``radius`` not a finite number >= 0.
    """
    if not isinstance(scene, (GaussianScene, FrozenScene)):
        raise ValidationError(f"neighbourhood: scene must be a GaussianScene or FrozenScene, "
                              f"got {type(scene).__name__}")
    c = np.asarray(center, np.float64)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise ValidationError(f"neighbourhood: center must be a finite 3-vector, got {np.asarray(center).tolist()}")
    r = as_real(radius)
    if r is None or not r >= 0:
        raise ValidationError(f"neighbourhood: radius must be a finite number >= 0, got {radius!r}")
    if isinstance(scene, FrozenScene):
        # the index's ball, loosened a little, is a superset; region_subset decides as its scan does
        return region_subset(scene.scene, c, r, rows=scene.spatial.ball(c, r * (1.0 + 1e-6) + 1e-12))
    return region_subset(scene, c, r)


def support_reach(inner: float, outer: float) -> float:
    """Radius, in lift radii, of the ball about ``o`` holding :func:`~.support.support_surface`'s annulus.

    Its splats lie within ``outer`` ``R`` of the axis and ``2 R`` of ``o``
    along it (``inner`` is not needed: the annulus lies inside the ball either way).
    """
    del inner
    return float(np.hypot(outer, 2.0))


@dataclass(frozen=True)
class Neighbourhood:
    """The Gaussians ``index`` of a scene of ``n`` Gaussians, and their sub-scene.

    Attributes
    ----------
    index : (M,) int64
        Ascending scene indices, ``L``.
    scene : GaussianScene
        ``parent.subset(index)``: Gaussian ``j`` of it is ``index[j]`` of the parent.
    n : int
        The parent scene's size N.
    """

    index: np.ndarray
    scene: GaussianScene
    n: int

    @classmethod
    def of(cls, scene: GaussianScene, index) -> "Neighbourhood":
        """The neighbourhood of ``scene`` made of ``index`` (scene indices; sorted and made unique here)."""
        idx = np.asarray(index, dtype=np.int64).reshape(-1)
        if idx.size > 1 and not np.all(idx[1:] > idx[:-1]):
            idx = np.unique(idx)
        if idx.size and (idx[0] < 0 or idx[-1] >= len(scene)):
            raise ValidationError(f"neighbourhood indices must lie in 0..{len(scene) - 1}")
        return cls(idx, scene.subset(idx), len(scene))

    def __len__(self) -> int:
        return int(self.index.size)

    def local(self, values: np.ndarray) -> np.ndarray:
        """``values`` (N, ...) of the parent scene restricted to the neighbourhood (M, ...)."""
        return np.asarray(values)[self.index]

    def find(self, indices) -> tuple[np.ndarray, np.ndarray]:
        """``(at, inside)`` for scene indices ``indices``: whether each is in the neighbourhood, and its position there (0 if not)."""
        i = np.asarray(indices, dtype=np.int64)
        at = np.searchsorted(self.index, i)
        inside = at < self.index.size
        inside[inside] = self.index[at[inside]] == i[inside]
        return np.where(inside, at, 0), inside

    def scatter(self, values, fill=0) -> np.ndarray:
        """(N,) array: ``values`` (M,) at the neighbourhood's Gaussians, ``fill`` elsewhere (same dtype)."""
        v = np.asarray(values)
        out = np.full(self.n, fill, dtype=v.dtype)
        out[self.index] = v
        return out

    def expand(self, matrix: sp.spmatrix) -> sp.csr_matrix:
        """An (M, M) sparse matrix of the neighbourhood as the parent's (N, N) CSR (rows and columns renumbered).

        Costs the N + 1 row pointers and the entries: the order of each
        row's entries is kept (the renumbering is increasing). The indices
        are int32 where the size and the entries allow (scipy's own choice).
        """
        m = sp.csr_matrix(matrix)
        # built in the index type scipy would convert to, and summed in place: one (N + 1,) array
        dtype = np.int32 if max(self.n, m.nnz) <= np.iinfo(np.int32).max else np.int64
        indptr = np.zeros(self.n + 1, dtype)
        indptr[self.index + 1] = np.diff(m.indptr)
        np.cumsum(indptr, out=indptr)
        return sp.csr_matrix((m.data, self.index.astype(dtype)[m.indices], indptr), shape=(self.n, self.n))


def object_neighbourhood(scene: GaussianScene | FrozenScene, lift: SeedLift, operators,
                         reach: float) -> Neighbourhood:
    """The neighbourhood ``L`` of the module docstring: the operators' columns, G0, and the ball of ``reach * R``.

    Parameters
    ----------
    scene : GaussianScene or FrozenScene
        A frozen scene finds the ball through its spatial index (:func:`neighbourhood`).
    lift : SeedLift
        The seed lift (G0, centre ``o``, radius ``R``).
    operators : iterable of OperatorStack, ViewOperator or sparse matrices
        The supervision views (N columns each); a stack's columns are its
        cached :meth:`~seed2gs_inverse.operators.OperatorStack.columns`.
    reach : float
        The ball's radius in lift radii (> 0).

    Returns
    -------
    Neighbourhood

    Raises
    ------
    ValidationError
        ``reach`` is not a positive number, or an operator without N columns.
    """
    r = as_real(reach)
    if r is None or not r > 0:
        raise ValidationError(f"object_neighbourhood: reach must be a positive number, got {reach!r}")
    base = scene.scene if isinstance(scene, FrozenScene) else scene
    n = len(base)
    mark = np.zeros(n, bool)  # one byte per Gaussian, set at the stored entries: no sort of the indices
    mark[lift.g0] = True
    mark[neighbourhood(scene, lift.center, r * float(lift.radius))] = True
    for i, op in enumerate(operators):
        cols = op.n_gaussians if isinstance(op, OperatorStack) else getattr(op, "W", op).shape[1]
        if cols != n:
            raise ValidationError(f"object_neighbourhood: view {i} has {cols} columns, the scene {n} Gaussians")
        # a stack's columns are marked once and kept (its solve reads them again)
        mark[op.columns() if isinstance(op, OperatorStack) else getattr(op, "W", op).indices] = True
    return Neighbourhood.of(base, np.flatnonzero(mark))
