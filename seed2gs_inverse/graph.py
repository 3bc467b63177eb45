r"""A k-nearest-neighbour affinity graph over the Gaussians of a scene.

Model-free extraction has to decide Gaussians that no labelled view saw (the
back and the underside of an object). Nearby Gaussians of one surface have
similar positions, colours and orientations; across the contact line of an
object and its support, or across a depth gap, at least one of the three
changes. :func:`gaussian_graph` encodes this as a sparse symmetric weight
matrix ``G`` that the graph-Laplacian regulariser
(:mod:`seed2gs_inverse.solvers.smoothing`) and the 3D label completion
(:mod:`seed2gs_inverse.pipeline.completion`) use.

Edges: each node ``i`` (a Gaussian of ``subset``) is joined to its ``k``
nearest means; the union is symmetrised (``G = max(G, G^T)``). Weights

.. math::

    w_{ij} = \exp\!\Big(-\frac{\lVert x_i - x_j\rVert^2}{\rho_i \rho_j}\Big)
             \exp\!\Big(-\frac{\lVert c_i - c_j\rVert^2}{2\sigma_c^2}\Big)
             \exp\!\Big(-\frac{1 - |n_i \cdot n_j|}{\sigma_n}\, f_i f_j\Big),

with

* :math:`\rho_i` the distance from ``i`` to its ``k``-th neighbour (the
  self-tuning local scale of Zelnik-Manor and Perona, 2004): the graph
  adapts to the sampling density, which varies by orders of magnitude in a
  trained scene. Where ``k + 1`` or more means coincide (duplicated or
  quantised splats) that distance is 0, floored at a tiny fraction of the
  median: edges into such a group from outside it underflow to 0, and a
  node whose neighbours all lie in the group can be left without an edge.
  Keep ``k`` above the size of the largest group of coincident means;
* :math:`c_i` the view-independent colour ``0.5 + C_0 \cdot SH_{DC}``
  (clipped to [0, 1]);
* :math:`n_i` the axis of the smallest scale (the normal of a flat splat)
  and :math:`f_i = \max(0, 1 - s_{min}/s_{mid})` its flatness in [0, 1]: the
  normal term only acts between flat Gaussians, whose normal means something.

Only numpy and scipy (``cKDTree``): solvers can import this module without
the rasterizer or Numba.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ._selection import support_indices
from ._threads import n_threads
from .errors import ValidationError
from .scene import GaussianScene, quat_to_rotmat
from .sh import SH_C0

__all__ = ["gaussian_graph", "graph_laplacian", "check_graph", "graph_on_nodes", "region_subset", "follow_matrix",
           "check_follow", "apply_follow"]

#: Means per block of :func:`region_subset`'s scan.
_BLOCK = 1 << 18


def region_subset(scene: GaussianScene, center, radius: float, rows=None) -> np.ndarray:
    """Ascending indices of the Gaussians whose means lie within ``radius`` of ``center`` (boundary included).

    The graph is only needed around the object: this keeps its cost
    independent of the scene's size.

    Parameters
    ----------
    scene : GaussianScene
    center : (3,) float
        A finite point.
    radius : float
        A finite distance >= 0.
    rows : (M,) int array, optional
        Ascending candidate indices (a superset of the answer, e.g. from a
        spatial index); only they are tested. Default: every Gaussian.

    Returns
    -------
    (K,) int64
        The indices ``i`` with ``sum_k (means[i, k] - center[k])^2 <= radius^2`` in float64.
    """
    if not isinstance(scene, GaussianScene):
        raise ValidationError(f"scene must be a GaussianScene, got {type(scene).__name__}")
    c = np.asarray(center, np.float64)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise ValidationError(f"center must be a finite 3-vector, got {np.asarray(center).tolist()}")
    if isinstance(radius, bool) or not isinstance(radius, (int, float, np.integer, np.floating)) \
            or not (np.isfinite(radius) and radius >= 0):
        raise ValidationError(f"radius must be a finite number >= 0, got {radius!r}")
    r2 = float(radius) ** 2
    if rows is not None:
        rows = np.asarray(rows, np.int64)
        return rows[np.sum((scene.means[rows].astype(np.float64) - c) ** 2, axis=1) <= r2]
    # a block of means at a time: the temporaries stay a few MB whatever the scene's size
    means = scene.means
    out = [np.flatnonzero(np.sum((means[i:i + _BLOCK].astype(np.float64) - c) ** 2, axis=1) <= r2) + i
           for i in range(0, len(means), _BLOCK)]
    return np.concatenate(out).astype(np.int64, copy=False) if out else np.zeros(0, np.int64)


def gaussian_graph(scene: GaussianScene, k: int = 10, *, subset=None, sigma_color: float | None = 0.1,
                   sigma_normal: float | None = 0.2, min_opacity: float = 0.0) -> sp.csr_matrix:
    r"""Symmetric kNN affinity matrix of the Gaussians (see the module docstring).

    Parameters
    ----------
    scene : GaussianScene
    k : int
        Neighbours per node (>= 1); the symmetrised graph has about ``k`` to
        ``2k`` edges per node.
    subset : (N,) bool or int indices, optional
        Build the graph among these Gaussians only (e.g. :func:`region_subset`
        around the object); the others are isolated nodes (no edges). Default:
        all.
    sigma_color : float or None
        :math:`\sigma_c` in RGB units; None drops the colour term.
    sigma_normal : float or None
        :math:`\sigma_n`; None drops the normal term.
    min_opacity : float
        Gaussians with activated opacity below this are left out of the graph
        (nearly transparent splats carry no surface).

    Returns
    -------
    scipy.sparse.csr_matrix (N, N) float64
        Symmetric, non-negative, zero diagonal; ``N = len(scene)``.
    """
    if not isinstance(scene, GaussianScene):
        raise ValidationError(f"scene must be a GaussianScene, got {type(scene).__name__}")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or int(k) < 1:
        raise ValidationError(f"k must be a positive integer, got {k!r}")
    for name, v in (("sigma_color", sigma_color), ("sigma_normal", sigma_normal)):
        if v is not None and not (np.isfinite(v) and v > 0):
            raise ValidationError(f"{name} must be positive or None, got {v!r}")
    if not (np.isfinite(min_opacity) and 0 <= min_opacity < 1):
        raise ValidationError(f"min_opacity must be in [0, 1), got {min_opacity!r}")
    n = len(scene)
    idx = support_indices(subset, n, "subset")  # integer 0/1 labels are refused
    if min_opacity > 0 and idx.size:
        idx = idx[scene.opacities_at(idx) >= min_opacity]
    m = idx.size
    kk = min(int(k), m - 1)
    if kk < 1:
        return sp.csr_matrix((n, n), dtype=np.float64)
    x = scene.means[idx].astype(np.float64)
    # (scipy's default median splits: another tree picks other neighbours among tied distances, which
    # the fixed-point means of SPZ and compressed scenes have, and the graph would change)
    dist, nb = cKDTree(x).query(x, k=kk + 1, workers=n_threads())  # independent queries: any thread count
    dist, nb = dist[:, 1:], nb[:, 1:]  # drop self
    # Self-tuning scale: distance to the k-th neighbour (floored so that
    # coincident means do not divide by zero).
    rho = np.maximum(dist[:, -1], 1e-12 + 1e-6 * float(np.median(dist[:, -1])))
    # log w_ij for each node i (row) and its neighbours nb[i] (columns), built in place in one
    # (m, kk) buffer with one scratch buffer: with millions of edges every temporary is tens of MB
    # of fresh pages, which cost more than the arithmetic (benchmarks/bench_graph.py).
    logw = np.square(dist, out=dist)
    logw /= rho[:, None]
    scratch = np.take(rho, nb)
    logw /= scratch
    np.negative(logw, out=logw)

    def pair_sum(a, op):
        """``sum_ch op(a[i, ch], a[nb[i, j], ch])`` (m, kk), channel by channel on 1D gathers."""
        total = None
        for ch in range(a.shape[1]):
            col = np.ascontiguousarray(a[:, ch])
            op(col[:, None], np.take(col, nb, out=scratch), out=scratch)
            total = scratch.copy() if total is None else np.add(total, scratch, out=total)
        return total

    if sigma_color is not None:
        rgb = np.clip(0.5 + SH_C0 * scene.sh[idx, 0, :].astype(np.float64), 0.0, 1.0)
        dc = pair_sum(rgb, lambda a, b, out: np.square(np.subtract(a, b, out=out), out=out))
        dc /= 2.0 * float(sigma_color) ** 2
        logw -= dc
    if sigma_normal is not None:
        s = np.sort(scene.scales_at(idx).astype(np.float64), axis=1)
        flat = np.clip(1.0 - s[:, 0] / np.maximum(s[:, 1], 1e-30), 0.0, 1.0)
        rot = quat_to_rotmat(scene.quats[idx])
        axis = np.argmin(scene.log_scales[idx], axis=1)
        normal = rot[np.arange(m), :, axis]  # column of the smallest scale
        dn = pair_sum(normal, np.multiply)
        np.abs(dn, out=dn)  # |n_i . n_j|
        np.subtract(1.0, dn, out=dn)
        dn /= float(sigma_normal)
        dn *= flat[:, None]
        dn *= np.take(flat, nb, out=scratch)
        logw -= dn
    w = np.exp(logw, out=logw)
    # One row per node of the subset (CSR built directly); an edge to itself (a coincident mean
    # listed before the node) is left out.
    keep = nb != np.arange(m)[:, None]
    indptr = np.zeros(n + 1, np.int64)
    indptr[idx + 1] = np.count_nonzero(keep, axis=1)
    np.cumsum(indptr, out=indptr)
    g = sp.csr_matrix((w[keep], idx[nb[keep]], indptr), shape=(n, n))
    g = g.maximum(g.T).tocsr()
    g.sort_indices()  # canonical, as callers may expect
    g.eliminate_zeros()  # weights that underflowed to 0
    return g


def check_graph(graph, n: int | None = None, name: str = "graph") -> sp.csr_matrix:
    """Validate a weight matrix: square, (N, N) when ``n`` is given, symmetric, finite, >= 0.

    Returns it as CSR float64 without stored zeros (a stored 0 is no edge: it
    must not join two components); ``graph`` itself is not modified.
    """
    if not sp.issparse(graph):
        raise ValidationError(f"{name} must be a scipy.sparse matrix (see gaussian_graph), "
                              f"got {type(graph).__name__}")
    g = sp.csr_matrix(graph, dtype=np.float64)
    if g.shape[0] != g.shape[1]:
        raise ValidationError(f"{name} must be square, got shape {g.shape}")
    if n is not None and g.shape[0] != n:
        raise ValidationError(f"{name} has {g.shape[0]} nodes but there are {n} Gaussians; "
                              "build it from the same scene")
    if g.nnz and (not np.all(np.isfinite(g.data)) or g.data.min() < 0):
        raise ValidationError(f"{name} weights must be finite and non-negative")
    # tested among the nodes with an entry (marked, not sorted out of the entries: ascending and
    # unique all the same): the same entries, without the transpose's and the difference's (N + 1,)
    # row pointers (the data are >= 0: their largest is abs(g).max())
    nodes = g.indptr[1:] != g.indptr[:-1]
    nodes[g.indices] = True
    sub = graph_on_nodes(g, np.flatnonzero(nodes))
    asym = abs(sub - sub.T)
    if asym.nnz and asym.max() > 1e-9 * max(float(g.data.max(initial=0.0)), 1e-300):
        raise ValidationError(f"{name} must be symmetric (w_ij = w_ji); symmetrise it with g.maximum(g.T)")
    if g.nnz and not np.all(g.data):
        g = g.copy()  # (csr_matrix may share the caller's arrays)
        g.eliminate_zeros()
    return g


def graph_on_nodes(graph: sp.csr_matrix, nodes) -> sp.csr_matrix:
    """A square CSR ``graph`` among ``nodes`` alone: row and column ``j`` are ``nodes[j]``'s.

    Parameters
    ----------
    graph : (N, N) scipy.sparse.csr_matrix
    nodes : (M,) int array
        Strictly ascending node indices holding both ends of every stored
        entry.

    Returns
    -------
    (M, M) csr_matrix
        The same entries, each row's in the same order, with int64
        row pointers; costs the M + 1 row pointers and the entries.

    Raises
    ------
    ValidationError
        ``graph`` is not a square CSR matrix, ``nodes`` not strictly
        ascending integers in ``[0, N)``, or an entry with an end outside
        ``nodes``.
    """
    if not sp.isspmatrix_csr(graph) or graph.shape[0] != graph.shape[1]:
        raise ValidationError(f"graph_on_nodes: graph must be a square CSR matrix, got "
                              f"{type(graph).__name__} {getattr(graph, 'shape', None)}")
    nodes = np.asarray(nodes)
    n = graph.shape[0]
    if nodes.ndim != 1 or (nodes.size and nodes.dtype.kind not in "ui"):
        raise ValidationError(f"graph_on_nodes: nodes must be a 1-D integer array, got {nodes.dtype} {nodes.shape}")
    nodes = nodes.astype(np.int64)
    if nodes.size and (nodes[0] < 0 or nodes[-1] >= n or np.any(nodes[1:] <= nodes[:-1])):
        raise ValidationError(f"graph_on_nodes: nodes must be strictly ascending indices in [0, {n})")
    start, stop = graph.indptr[nodes], graph.indptr[nodes + 1]
    counts = stop - start
    indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    take = np.repeat(start - indptr[:-1], counts) + np.arange(indptr[-1])
    ends = graph.indices[take]
    local = np.searchsorted(nodes, ends)
    if indptr[-1] != graph.nnz or (ends.size and not np.array_equal(nodes[np.minimum(local, nodes.size - 1)], ends)):
        raise ValidationError("graph_on_nodes: nodes must hold both ends of every stored entry of the graph")
    return sp.csr_matrix((graph.data[take], local, indptr), shape=(nodes.size, nodes.size))


def follow_matrix(scene: GaussianScene, k: int = 4, *, subset=None, min_opacity: float = 0.05) -> sp.csr_matrix:
    r"""Rows that average each faint Gaussian's ``k`` nearest opaque neighbours (applied by :func:`apply_follow`).

    Parameters
    ----------
    scene : GaussianScene
    k : int
        Opaque neighbours per faint Gaussian, >= 1.
    subset : (N,) bool or int indices, optional
        The Gaussians considered (faint ones and their neighbours); default all.
    min_opacity : float in (0, 1)
        A Gaussian of ``subset`` with activated opacity below this is faint.

    Returns
    -------
    scipy.sparse.csr_matrix (N, N) float64
        Row ``i`` of a faint Gaussian holds the weights

        .. math::

            F_{ij} = \frac{1 / (d_{ij} + \epsilon)}{\sum_{l \in N_k(i)} 1 / (d_{il} + \epsilon)},
            \quad j \in N_k(i),

        over its ``k`` nearest opaque Gaussians :math:`N_k(i)` of
        ``subset`` (:math:`d` between means, :math:`\epsilon` a hundredth of
        the median of those distances), so it sums to 1; every other row is
        empty. Empty when ``subset`` has no faint or no opaque Gaussian.

    Raises
    ------
    ValidationError
        A bad argument (named).
    """
    if not isinstance(scene, GaussianScene):
        raise ValidationError(f"scene must be a GaussianScene, got {type(scene).__name__}")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or int(k) < 1:
        raise ValidationError(f"k must be a positive integer, got {k!r}")
    if not (np.isfinite(min_opacity) and 0 < min_opacity < 1):
        raise ValidationError(f"min_opacity must be in (0, 1), got {min_opacity!r}")
    n = len(scene)
    idx = support_indices(subset, n, "subset")
    faint = scene.opacities_at(idx) < min_opacity
    opaque, faint = idx[~faint], idx[faint]
    if faint.size == 0 or opaque.size == 0:
        return sp.csr_matrix((n, n), dtype=np.float64)
    r, c, w = _nearest_entries(scene.means, faint, opaque, int(k))
    return sp.csr_matrix((w, (r, c)), shape=(n, n))


def _nearest_entries(means: np.ndarray, rows: np.ndarray, anchors: np.ndarray, k: int) -> tuple:
    """``(row, col, weight)``: each of ``rows`` averages its ``k`` nearest ``anchors`` by inverse distance.

    ``means`` (N, 3); ``rows`` and ``anchors`` non-empty int indices (checked
    by the callers); scene indices, ``k`` entries per row, nearest first. The
    weights are :func:`follow_matrix`'s (its Returns).
    """
    kk = min(k, anchors.size)
    d, nb = cKDTree(means[anchors].astype(np.float64)).query(
        means[rows].astype(np.float64), k=kk, workers=n_threads())
    d, nb = d.reshape(rows.size, kk), nb.reshape(rows.size, kk)
    w = 1.0 / (d + 1e-2 * float(np.median(d)) + 1e-30)
    w /= w.sum(axis=1, keepdims=True)
    return np.repeat(rows, kk), anchors[nb].ravel(), w.ravel()


def check_follow(follow, n: int | None = None, name: str = "follow") -> sp.csr_matrix:
    """Validate a follow matrix (:func:`follow_matrix`): (N, N), finite, >= 0, each row summing to 0 or 1.

    Returns it as CSR float64.
    """
    if not sp.issparse(follow):
        raise ValidationError(f"{name} must be a scipy.sparse matrix (see follow_matrix), got "
                              f"{type(follow).__name__}")
    f = sp.csr_matrix(follow, dtype=np.float64)
    if f.shape[0] != f.shape[1] or (n is not None and f.shape[0] != n):
        raise ValidationError(f"{name} must be ({n or 'N'}, {n or 'N'}) for the scene's Gaussians, got shape "
                              f"{f.shape}")
    if f.nnz and (not np.all(np.isfinite(f.data)) or f.data.min() < 0):
        raise ValidationError(f"{name} weights must be finite and non-negative")
    # each row's sum from its entries (CSR keeps rows in order): nothing of length N is made
    row = f.tocoo().row
    sums = np.add.reduceat(f.data, np.flatnonzero(np.r_[True, row[1:] != row[:-1]])) if f.nnz else f.data
    if np.any(np.abs(sums - 1.0) > 1e-6):
        raise ValidationError(f"{name}: every row that holds weights must sum to 1 (an average of neighbours)")
    return f


def apply_follow(q, follow) -> np.ndarray:
    """``q`` (N,) as float32 with each row ``i`` of ``follow`` that holds weights replaced by ``(follow @ q)[i]``.

    Raises
    ------
    ValidationError
        ``follow`` is not a follow matrix for ``q``'s length (:func:`check_follow`).
    """
    q = np.asarray(q, np.float32).ravel()
    f = check_follow(follow, q.size)
    rows = np.flatnonzero(np.diff(f.indptr) > 0)
    out = q.copy()
    if rows.size:
        out[rows] = _followed(f, rows, q)
    return out


def _followed(follow: sp.csr_matrix, rows: np.ndarray, q: np.ndarray) -> np.ndarray:
    """float32 ``(follow @ q)`` at ``rows``, summed in float64: the one computation of every follow rule's values.

    A rule that sets ``q`` at its rows this way is reproduced exactly by
    :func:`apply_follow` on the matrix it saved.
    """
    return (follow[rows] @ np.asarray(q).astype(np.float64)).astype(np.float32)


def graph_laplacian(graph) -> sp.csr_matrix:
    r"""Combinatorial Laplacian :math:`L = D - G`, :math:`D = \mathrm{diag}(G 1)`.

    Symmetric positive semi-definite for a symmetric non-negative ``G``:
    :math:`q^T L q = \tfrac12 \sum_{ij} w_{ij} (q_i - q_j)^2 \ge 0`.
    """
    return laplacian_of_checked(check_graph(graph))


def laplacian_of_checked(g: sp.csr_matrix) -> sp.csr_matrix:
    """:func:`graph_laplacian` of a graph :func:`check_graph` returned (not checked again)."""
    d = g.diagonal()
    if d.any():  # self-loops do not change q^T L q (gaussian_graph has none: no subtraction then)
        g = g - sp.diags(d)
    deg = np.asarray(g.sum(axis=1)).ravel()
    return (sp.diags(deg) - g).tocsr()
