r"""Seed lift: the reference seed mask m* becomes G0, a conservative 3D set of the object's Gaussians.

Algorithm 1, line 3 of the paper (Section 3.4, "Seed lift"): Gaussians
projected into the reference view are kept when they satisfy a *mask*
constraint and a *depth* constraint; connected components of a 3D
neighbour graph over the kept Gaussians then remove projection outliers.
G0 (the lifted set) gives the object centre ``o`` and extent that
parameterise the VAAS orbits, and initialises the membership logits. (The
support *surface*, the ground the object rests on, is
:mod:`seed2gs_inverse.pipeline.support`.)

:func:`seed_lift` runs the steps in order: :func:`_examined` (``K``, the
only Gaussians that can pass the constraints: the lift's time and memory
follow the reference view, not the scene's size), then on them
:func:`_centre_tests` (the paper's two constraints at the projected
centre), :func:`_contribution` (the same judged over every pixel a
Gaussian renders to, when ``W`` is given), :func:`_candidates`,
:func:`_keep_components` (over :func:`neighbour_components`) and
:func:`_extent`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .._threads import n_threads
from ..errors import ValidationError
from ..raster import FrozenScene
from ..scene import GaussianScene

if TYPE_CHECKING:
    from ..camera import Camera

__all__ = ["SeedLift", "seed_lift", "neighbour_components"]


@dataclass
class SeedLift:
    """Result of :func:`seed_lift`.

    The constraints are judged only on the Gaussians ``index`` (``K``): the
    columns of the reference operator ``W`` when it is given, else those whose
    centre may project into the reference image in front of its near plane.
    No other Gaussian can pass them (it has no weight in the view, or its
    centre is outside it), so it is in neither G0 nor the candidates.

    Attributes
    ----------
    g0 : (N,) bool
        G0, the lifted set: the Gaussians of the object the reference shows.
    center : (3,) float64
        Object centre ``o``: the midpoint of the robust (2nd-98th percentile)
        bounding box of G0's means.
    radius : float
        Extent: half the diagonal of that box (at least the largest G0
        Gaussian's 3-sigma size), in world units.
    bbox : (2, 3) float64
        The robust bounding box ``[min, max]``.
    candidates : (N,) bool
        Gaussians passing the mask and depth constraints, before components.
    n_components : int
        Connected components among the candidates.
    kept_components : int
        Components retained in G0.
    mode : str
        ``"contribution"`` (W given) or ``"center"``.
    index : (K,) int64
        Ascending scene indices of the Gaussians examined.
    local_membership : (K,) float32 or None
        :attr:`membership` at ``index``.
    local_eps_depth : (K,) float32
        :attr:`eps_depth` at ``index``.
    n : int
        The scene's size N.
    """

    g0: np.ndarray
    center: np.ndarray
    radius: float
    bbox: np.ndarray
    candidates: np.ndarray
    n_components: int
    kept_components: int
    mode: str
    index: np.ndarray
    local_membership: np.ndarray | None
    local_eps_depth: np.ndarray
    n: int

    @property
    def membership(self) -> np.ndarray | None:
        """(N,) float32 or None: the contribution-weighted mask membership ``(W^T m) / (W^T 1)``.

        None when the reference operator was not given. 0 outside
        ``index``, as the ratio's rule gives a Gaussian without weight in
        the view. Built on each access from :attr:`local_membership`.
        """
        if self.local_membership is None:
            return None
        out = np.zeros(self.n, np.float32)
        out[self.index] = self.local_membership
        return out

    @property
    def eps_depth(self) -> np.ndarray:
        """(N,) float32: the per-Gaussian depth tolerance used; NaN outside ``index`` (never needed there).

        Built on each access from :attr:`local_eps_depth`.
        """
        out = np.full(self.n, np.nan, np.float32)
        out[self.index] = self.local_eps_depth
        return out

    @property
    def n_g0(self) -> int:
        """How many Gaussians G0 holds."""
        return int(self.g0.sum())

    @property
    def support(self) -> np.ndarray:
        """Deprecated alias of :attr:`g0` (read-only): "support" names the ground surface elsewhere."""
        warnings.warn("SeedLift.support is deprecated; use SeedLift.g0", DeprecationWarning, stacklevel=2)
        return self.g0

    @property
    def n_support(self) -> int:
        """Deprecated alias of :attr:`n_g0` (read-only)."""
        warnings.warn("SeedLift.n_support is deprecated; use SeedLift.n_g0", DeprecationWarning, stacklevel=2)
        return self.n_g0

    def summary(self) -> dict:
        """JSON-ready facts (``report.json``; G0's size under the key ``"n_support"``)."""
        return {"n_support": self.n_g0, "n_candidates": int(self.candidates.sum()),
                "n_components": self.n_components, "kept_components": self.kept_components,
                "center": self.center.tolist(), "radius": float(self.radius), "mode": self.mode}


class _Contribution(NamedTuple):
    """Per-Gaussian sums over the pixels it renders to in the reference view, all (K,) float64."""

    weight: np.ndarray      # sum_u w_ui
    inside: np.ndarray      # sum_u w_ui m*_u
    membership: np.ndarray  # inside / weight (0 where the weight is 0)
    residual: np.ndarray    # weight-averaged |z_i - D_r(u)| (inf where the weight is 0)


def _check_image(name: str, arr, shape: tuple[int, int]) -> np.ndarray:
    """``arr`` as an array of the reference view's ``shape``, or a ValidationError naming ``name``."""
    a = np.asarray(arr)
    if a.shape != shape:
        raise ValidationError(f"seed lift: {name} has shape {a.shape}, expected {shape} (H, W) of the reference view")
    return a


def _seed_pixels(mask, shape: tuple[int, int]) -> np.ndarray:
    """The seed mask as (H, W) bool: values > 0.5 (NaN counts as not); refuses an empty or non-numeric mask."""
    m = _check_image("mask", mask, shape)
    if m.dtype.kind not in "biuf":
        raise ValidationError(f"seed lift: mask must be boolean or numeric, got dtype {m.dtype}")
    m = np.nan_to_num(m.astype(np.float64), nan=0.0) > 0.5
    if not m.any():
        raise ValidationError("seed mask is empty: mark at least one pixel of the object")
    return m


def _examined(scene: GaussianScene, frozen: FrozenScene | None, camera: Camera,
              W) -> tuple[np.ndarray, sp.csr_matrix | None]:
    """``K``, the Gaussians that can pass the constraints, and ``W`` on their columns (None without ``W``).

    With ``W``: its stored columns (a Gaussian without weight in the view
    passes neither rule), ``W`` keeping its rows, entries and their order,
    its columns renumbered ``0..K-1``. Without: the Gaussians whose centre
    may lie in the image in front of the near plane, from ``frozen``'s
    spatial index (a superset), else every Gaussian.

    Raises
    ------
    ValidationError
        ``W`` is not a sparse (H*W, N) matrix.
    """
    n = len(scene)
    h, w = camera.image_shape
    if W is None:
        if frozen is not None:
            return frozen.spatial.view_candidates(camera), None
        return np.arange(n, dtype=np.int64), None
    if not sp.issparse(W) or W.shape != (h * w, n):
        raise ValidationError(f"seed lift: W must be a sparse ({h * w}, {n}) matrix, got "
                              f"{type(W).__name__} {getattr(W, 'shape', None)}")
    W = sp.csr_matrix(W)
    # Marks, then each column's new number, in one array of W's index type: no sort of the stored
    # entries, and only the memory pages that hold a column are ever written.
    number = np.zeros(n, W.indices.dtype)
    number[W.indices] = 1
    index = np.flatnonzero(number)
    number[index] = np.arange(index.size)
    return index, sp.csr_matrix((W.data, number[W.indices], W.indptr), shape=(h * w, index.size))


def _centre_tests(camera: Camera, uv: np.ndarray, z: np.ndarray, eps: np.ndarray, m: np.ndarray,
                  d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""The paper's two constraints at the projected centre :math:`\pi_i`: ``(depth_ok, centre_in_mask)``, (K,) bool.

    ``uv`` (K, 2) and ``z`` (K,) are the projected centres and view depths,
    ``eps`` (K,) the depth tolerances, ``m`` the (H, W) seed and ``d`` the
    (H, W) rendered depth. A centre outside the image or nearer than the near
    plane fails both.
    """
    n = len(z)
    h, w = m.shape
    ok = np.isfinite(uv).all(axis=1) & (z > camera.near)
    px = np.floor(np.where(ok, uv[:, 0], -1)).astype(np.int64)
    py = np.floor(np.where(ok, uv[:, 1], -1)).astype(np.int64)
    ok &= (px >= 0) & (px < w) & (py >= 0) & (py < h)
    idx = np.nonzero(ok)[0]
    dd = d[py[idx], px[idx]]
    depth_ok = np.zeros(n, bool)
    depth_ok[idx] = (dd > 0) & (np.abs(z[idx] - dd) <= eps[idx])
    centre_in_mask = np.zeros(n, bool)
    centre_in_mask[idx] = m[py[idx], px[idx]]
    return depth_ok, centre_in_mask


def _contribution(W: sp.csr_matrix, m: np.ndarray, z: np.ndarray, d: np.ndarray) -> _Contribution:
    r"""The contribution rule's per-Gaussian sums over the pixels it renders to (:func:`seed_lift`'s Notes).

    :math:`\sum_u w_{u,i}`, :math:`\sum_u w_{u,i} m^\star_u`, :math:`\mu_i`
    and :math:`r_i`, from the reference operator ``W`` (H*W, K) on the
    examined Gaussians' columns (:func:`_examined`), the (H, W) seed ``m``,
    their view depths ``z`` (K,) and the rendered depth ``d`` (H, W).
    """
    h, w = m.shape
    n = W.shape[1]
    colsum = np.asarray(W.sum(axis=0)).ravel().astype(np.float64)
    inside = np.asarray(W.T @ m.ravel().astype(np.float64)).ravel()
    rows = np.repeat(np.arange(h * w), np.diff(W.indptr))
    cols = W.indices
    resid = np.bincount(cols, weights=W.data * np.abs(z[cols] - d.ravel()[rows]), minlength=n)
    safe = np.maximum(colsum, 1e-30)
    membership = np.where(colsum > 0, inside / safe, 0.0)
    resid = np.where(colsum > 0, resid / safe, np.inf)
    return _Contribution(colsum, inside, membership, resid)


def _candidates(depth_ok: np.ndarray, centre_in_mask: np.ndarray, contrib: _Contribution | None,
                eps: np.ndarray, sigma: np.ndarray, *, min_membership: float, min_weight: float,
                max_size_ratio: float | None) -> tuple[np.ndarray, np.ndarray]:
    """The Gaussians that pass the constraints, ``(candidates (K,) bool, score (K,) float)``.

    The contribution rule when ``contrib`` is given (score: the mask-weighted
    contribution), else the centre rule (score 1 each); then the size cut
    ``max_size_ratio`` (see :func:`seed_lift`).
    """
    if contrib is not None:
        cand = ((contrib.weight >= min_weight) & (contrib.membership >= min_membership) & depth_ok
                & (contrib.residual <= eps))
        score = contrib.inside
    else:
        cand = centre_in_mask & depth_ok
        score = np.ones(len(depth_ok))
    if cand.any() and max_size_ratio is not None:
        # Splats far bigger than the typical candidate are background
        # (ground, walls) whose big footprint passes the mask and depth
        # tests near the object; their own size also widens eps_d.
        typical = float(np.median(sigma[cand]))
        cand &= sigma <= max_size_ratio * typical
    return cand, score


def _no_candidate_error(m: np.ndarray, depth_ok: np.ndarray, contrib: _Contribution | None, eps: np.ndarray,
                        *, min_membership: float, min_weight: float) -> ValidationError:
    """Why no Gaussian passed: a seed smaller than the splats that render in it, or a seed on nothing."""
    if contrib is not None and np.any((contrib.inside > 0) & depth_ok & (contrib.weight >= min_weight)
                                      & (contrib.residual <= eps)):
        # Gaussians do render inside the seed and pass every test but membership: mostly outside it,
        # a seed smaller than the splats
        return ValidationError(
            f"the seed mask ({int(m.sum())} px) is smaller than the footprint of the Gaussians that render "
            f"inside it: none has {min_membership:.0%} of its weight in the seed (min_membership); give a "
            f"larger seed (the whole object, or a box), or a camera closer to it")
    return ValidationError(
        "the seed mask touches no Gaussian of the scene in the reference view (no Gaussian "
        "renders inside it at a consistent depth); check the mask, camera and scene match")


def _keep_components(means: np.ndarray, cand: np.ndarray, score: np.ndarray, *, k_neighbors: int,
                     link_factor: float, keep_fraction: float) -> tuple[np.ndarray, int, int]:
    """G0: the candidates' best components, ``(g0 (K,) bool, n_components, kept_components)``.

    Components of :func:`neighbour_components` over the candidates, scored
    by the sum of ``score``; the best is kept with every component scoring
    at least ``keep_fraction`` of it.
    """
    idx = np.nonzero(cand)[0]
    labels, ncomp = neighbour_components(means[idx], k_neighbors, link_factor)
    comp_score = np.bincount(labels, weights=score[idx], minlength=ncomp)
    keep = comp_score >= keep_fraction * comp_score.max()
    keep[np.argmax(comp_score)] = True
    g0 = np.zeros(len(cand), bool)
    g0[idx[keep[labels]]] = True
    return g0, int(ncomp), int(keep.sum())


def _extent(means: np.ndarray, g0: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """``(center, radius, bbox)`` of G0: the robust (2nd-98th percentile) box, its midpoint and half-diagonal.

    The radius is at least the largest G0 Gaussian's 3-sigma size (and
    1e-6); with fewer than 10 Gaussians the box is their full extent.
    """
    pts = means[g0]
    lo, hi = np.percentile(pts, [2, 98], axis=0) if len(pts) >= 10 else (pts.min(0), pts.max(0))
    center = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 3.0 * float(sigma[g0].max()), 1e-6)
    return center, radius, np.stack([lo, hi])


def seed_lift(scene: GaussianScene | FrozenScene, camera: Camera, mask, depth, W=None, *, eps_rel: float = 0.02,
              eps_sigma: float = 2.0, min_membership: float = 0.5, min_weight: float = 1e-3,
              k_neighbors: int = 8, link_factor: float = 3.0, keep_fraction: float = 0.2,
              max_size_ratio: float | None = 4.0) -> SeedLift:
    r"""Lift the seed mask of the reference view to G0, a set of the scene's Gaussians.

    Parameters
    ----------
    scene : GaussianScene or FrozenScene
        Without ``W``, a :class:`~seed2gs_inverse.raster.FrozenScene` finds
        the Gaussians whose centre may lie in the view through its spatial
        index; a plain scene examines every Gaussian. The result is the same.
    camera : Camera
        The reference camera ``c_r`` at the resolution of ``mask``/``depth``.
    mask : (H, W) bool or float array
        Seed mask ``m*`` (values > 0.5 are the object; NaN counts as not).
    depth : (H, W) float array
        Rendered expected depth ``D_r`` of the reference view (0 where empty).
    W : scipy.sparse matrix (H*W, N), optional
        Compositing weights ``W(c_r)`` of the same view. When given, the
        *contribution* rule below is used; otherwise the *centre* rule.
    eps_rel, eps_sigma : float
        Depth tolerance :math:`\epsilon_{d,i} = \epsilon_{rel} z_i + \epsilon_\sigma s_i`
        with :math:`s_i` the Gaussian's largest standard deviation: relative
        to depth because the expected depth of a rendered surface is blurred
        in proportion to distance, plus the Gaussian's own size because a big
        flat splat's centre sits off the blended surface by up to a few sigma.
    min_membership : float
        Contribution rule: minimum fraction of a Gaussian's weight inside m*.
    min_weight : float
        Contribution rule: Gaussians with total weight :math:`\sum_u w_{u,i}`
        below this are invisible in the reference view and never candidates.
    k_neighbors, link_factor : int, float
        3D graph: each candidate is linked to its ``k_neighbors`` nearest
        candidates closer than ``link_factor`` times the median distance to
        the 4th-nearest candidate (a density-adaptive radius,
        :func:`neighbour_components`).
    max_size_ratio : float or None
        Candidates whose largest standard deviation exceeds this multiple of
        the candidates' median are dropped (default 4): on real scenes large
        ground or wall splats next to the object pass the mask and depth
        tests (their size widens the tolerance) and would otherwise seed
        the background. None keeps all.
    keep_fraction : float
        Components are scored by their mask-weighted contribution
        (:math:`\sum_i (W^T m)_i`, or candidate count under the centre rule);
        the best one is kept, together with every component scoring at least
        ``keep_fraction`` of it (objects split by a thin occluder stay whole).

    Returns
    -------
    SeedLift

    Raises
    ------
    ValidationError
        ``scene`` not a GaussianScene or FrozenScene, ``mask`` or ``depth``
        not of the camera's (H, W), a non-numeric or empty mask, an empty
        scene, ``W`` not a sparse (H*W, N) matrix, or no Gaussian passing
        the constraints (the message says which case).

    Notes
    -----
    Constraints (paper): keep :math:`g_i` with :math:`m^\star(\pi_i) = 1` and
    :math:`|z_i - D_r(\pi_i)| \le \epsilon_d`, where :math:`\pi_i, z_i` are the
    projected centre and view depth.

    **Choice: contribution-weighted membership when W is given.** The centre
    rule judges a Gaussian by one pixel. A large background splat whose centre
    falls just inside the mask boundary passes it, and an object splat whose
    centre falls just outside fails it; both are common at silhouettes. The
    contribution rule uses every pixel a Gaussian actually renders to:

    .. math::

        \mu_i = \frac{\sum_u w_{u,i} m^\star_u}{\sum_u w_{u,i}}, \qquad
        r_i = \frac{\sum_u w_{u,i} |z_i - D_r(u)|}{\sum_u w_{u,i}},

    and keeps :math:`\mu_i \ge` ``min_membership``, :math:`r_i \le \epsilon_{d,i}`
    and :math:`\sum_u w_{u,i} \ge` ``min_weight``, together with the paper's
    depth constraint at the centre, :math:`|z_i - D_r(\pi_i)| \le \epsilon_{d,i}`
    (without it, a background Gaussian mostly hidden behind the object but
    peeking out inside a loose mask would count as inside). It is sharper
    at the silhouette: big splats count by where they actually render. Both
    rules are conservative: Gaussians on the hidden side of the object are
    not in G0; the orbits and the solver recover them.
    """
    if not isinstance(scene, (GaussianScene, FrozenScene)):
        raise ValidationError(f"seed lift: scene must be a GaussianScene or FrozenScene, got {type(scene).__name__}")
    frozen = scene if isinstance(scene, FrozenScene) else None
    scene = scene.scene if frozen is not None else scene
    n = len(scene)
    shape = camera.image_shape
    m = _seed_pixels(mask, shape)
    d = _check_image("depth", depth, shape).astype(np.float64)
    if n == 0:
        raise ValidationError("seed lift: the scene has no Gaussians")
    index, W = _examined(scene, frozen, camera, W)
    # Everything below is over the examined Gaussians K, in the scene's order.
    means = scene.means[index].astype(np.float64)
    uv, z = camera.project(means)
    sigma = scene.scales_at(index).max(axis=1).astype(np.float64)
    eps = eps_rel * np.abs(z) + eps_sigma * sigma
    depth_ok, centre_in_mask = _centre_tests(camera, uv, z, eps, m, d)
    contrib = None if W is None else _contribution(W, m, z, d)
    rules = dict(min_membership=min_membership, min_weight=min_weight)
    cand, score = _candidates(depth_ok, centre_in_mask, contrib, eps, sigma, max_size_ratio=max_size_ratio, **rules)
    if not cand.any():
        raise _no_candidate_error(m, depth_ok, contrib, eps, **rules)
    g0, ncomp, kept = _keep_components(means, cand, score, k_neighbors=k_neighbors, link_factor=link_factor,
                                       keep_fraction=keep_fraction)
    center, radius, bbox = _extent(means, g0, sigma)
    membership = None if contrib is None else contrib.membership.astype(np.float32)
    return SeedLift(_scatter(n, index, g0), center, radius, bbox, _scatter(n, index, cand), ncomp, kept,
                    "center" if contrib is None else "contribution", index, membership, eps.astype(np.float32), n)


def _scatter(n: int, index: np.ndarray, local: np.ndarray) -> np.ndarray:
    """(n,) bool: ``local`` (K,) bool at ``index``, False elsewhere."""
    out = np.zeros(n, bool)
    out[index[local]] = True
    return out


def neighbour_components(points: np.ndarray, k: int, link_factor: float) -> tuple[np.ndarray, int]:
    """Connected components of a kNN graph with a density-adaptive cut-off radius.

    Each point is linked to its ``k`` nearest neighbours (at most M - 1)
    closer than ``link_factor`` times the median distance of a point to its
    4th nearest neighbour (its ``k``-th when ``k < 4``); a zero cut-off
    (duplicate points) falls back to the smallest non-zero distance.

    Parameters
    ----------
    points : (M, 3) float array
        M >= 1.
    k : int
    link_factor : float

    Returns
    -------
    labels : (M,) int
        Component of each point, in 0..n-1.
    n : int
        Number of components.
    """
    m = len(points)
    if m == 1:
        return np.zeros(1, np.int64), 1
    k = int(min(max(k, 1), m - 1))
    tree = cKDTree(points)
    dist, nbr = tree.query(points, k=k + 1, workers=n_threads())
    dist, nbr = dist[:, 1:], nbr[:, 1:]
    ref = dist[:, min(3, k - 1)]
    cutoff = link_factor * float(np.median(ref))
    if cutoff <= 0:
        cutoff = float(dist[dist > 0].min()) if np.any(dist > 0) else 1.0
    keep = dist <= cutoff
    rows = np.repeat(np.arange(m), k)[keep.ravel()]
    cols = nbr.ravel()[keep.ravel()]
    graph = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(m, m))
    ncomp, labels = connected_components(graph, directed=False)
    return labels, int(ncomp)
