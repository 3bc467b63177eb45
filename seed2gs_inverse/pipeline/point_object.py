r"""Point prompts that return the whole object.

A click on the top of a table should return the table, not the colour-
homogeneous patch under the cursor. Without a learned model the object is
found from geometry, in four steps:

1. **Seed region in the reference view.** The click's colour-and-depth
   region of :class:`~seed2gs_inverse.frontend.prompts.PointPrompt` (a
   flood fill that stops at colour edges and depth jumps, refined by
   GrabCut): the clicked face of the object (a table top), nothing more.
   When it is empty, the *smooth surface patch* stands in
   (:func:`surface_patch`): back-project the rendered expected depth
   :math:`D` to camera-frame points
   :math:`P(u) = D(u)\, K^{-1} (u + \tfrac12, 1)^\top`, normals
   :math:`n(u) \propto \partial_x P \times \partial_y P` (central
   differences) turned towards the camera; two 4-neighbours ``u, v`` are
   separated by a *depth jump* when
   :math:`|D(u) - D(v)| > \delta \min(D(u), D(v))` (``depth_tol``) and by a
   *crease* when :math:`\angle(n(u), n(v)) >` ``normal_tol_deg``; the patch
   is the 4-connected set of solid pixels reached from the click without
   crossing either. The colour region comes first because rendered depth
   is noisy on real scans, so the patch may shrink to the click or leak to
   the surroundings through noise; colour only seeds, the 3D growth
   decides the object.
2. **Lift.** The patch is lifted to Gaussians with the seed lift's centre
   rule (:func:`~seed2gs_inverse.pipeline.seed_lift.seed_lift` without
   ``W``): projected centre in the patch at a consistent depth.
3. **Grow in 3D.** Over the Gaussians within ``growth_factor`` times the
   patch's radius :math:`R_0` of its centre (opacity >= ``min_opacity``),
   build a kNN graph (``k_neighbors``) whose edge :math:`(i, j)` is kept when

   .. math::

       \|x_i - x_j\| \le \max\big(\lambda \rho_0,\; \kappa (s_i + s_j)\big),

   with :math:`\rho_0` the median distance of a seed Gaussian to its 4th
   nearest neighbour (the object's own sampling density; :math:`\lambda` =
   ``link_factor``) and :math:`s_i` the largest standard deviation
   (:math:`\kappa` = ``overlap``: the 1-sigma ellipsoids touch). Trained
   splats are dense and small on well-seen faces (a table top) and sparse
   and big on grazing ones (its skirt); the second term links those, the
   first keeps gaps wider than the splats from being bridged. Gaussians of the *support
   plane* :math:`(n, p)` under the object (the ground), found by
   :func:`~seed2gs_inverse.pipeline.up_axis.estimate_up_axis` (a plane
   with solid Gaussians under the seed, such as a chair's seat under a
   click on its backrest, is passed over for one without: the ground has
   nothing under it), are removed
   first: those with :math:`n \cdot (x - p) <` ``band`` (3 times the plane
   fit's inlier distance, at least ``min_band`` :math:`R_0`), so the object
   does not grow into the floor it stands on, and neither does anything
   below it. The object is the union of the graph's connected components
   holding at least ``keep_fraction`` of the best component's seeds.
   Creases are crossed in 3D (a table's top and skirt meet at a right
   angle); only the support plane and spatial gaps stop the growth.
   Faint Gaussians (opacity below ``min_opacity``) are no nodes, since
   they would bridge the gaps between objects (a tree's haze), but each
   in the growth region follows its nearest node when that lies within
   the link rule's reach: where a capture is soft (an aerial capture's
   walls), they carry much of a surface's colour.
   Negative clicks are lifted the same way and their Gaussians removed
   from the graph. The click's region may be a small part of the object
   (a chair's backrest): while the grown object reaches the edge of the
   growth region (a node of its graph, not a faint splat, beyond 0.9 of its radius), the radius doubles,
   at most ``max_expansions`` times; an object that still reaches the edge
   after the last doubling is leaking into the scene, and the first growth
   is kept.
4. **Project back.** The mask is where the grown Gaussians render with
   weight above one half: :math:`(W \mathbf 1_{obj})(u) > 0.5` with the
   reference operator ``W`` over the box of their projection, so occlusion
   is exact.

If no support plane is found the growth is bounded by the radius only; if
the growth yields nothing the patch itself is the mask.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..camera import Camera
from ..errors import ValidationError
from ..frontend.prompts import PointPrompt
from ..raster import build_operator, cone_cull, render
from ..scene import GaussianScene
from .seed_lift import seed_lift
from .up_axis import estimate_up_axis

if TYPE_CHECKING:
    from ..operators import Rendering

__all__ = ["PointObject", "point_object_mask", "surface_patch", "depth_normals", "grow_object", "linked_components",
           "POINT_OBJECT_DEFAULTS"]

#: Defaults of :func:`point_object_mask`.
POINT_OBJECT_DEFAULTS = {"depth_tol": 0.03, "normal_tol_deg": 30.0, "alpha_min": 0.5,
                         "growth_factor": 2.0, "k_neighbors": 10, "link_factor": 2.0, "overlap": 1.0,
                         "keep_fraction": 0.2, "min_band": 0.03, "min_opacity": 0.2, "max_expansions": 3}

#: The grown object "reaches the edge" of its growth region when a Gaussian lies beyond this share of
#: the region's radius.
_EDGE = 0.9


@dataclass
class PointObject:
    """Result of :func:`point_object_mask`.

    Attributes
    ----------
    mask : (H, W) bool
        The object in the reference view (the seed mask ``m*``).
    selected : (N,) bool
        The grown Gaussians.
    patch : (H, W) bool
        The smooth surface patch around the positive clicks (step 1).
    seeds : (N,) bool
        Its lifted Gaussians (step 2).
    info : dict
        JSON-ready: counts, the support plane used, the link distance.
    """

    mask: np.ndarray
    selected: np.ndarray
    patch: np.ndarray
    seeds: np.ndarray
    info: dict = field(default_factory=dict)


def _check_depth(camera: Camera, depth, name="depth") -> np.ndarray:
    d = np.asarray(depth, dtype=np.float64)
    if d.shape != camera.image_shape:
        raise ValidationError(f"{name} has shape {d.shape}; camera {camera.name!r} is {camera.image_shape}")
    return np.nan_to_num(d, nan=0.0, posinf=0.0, neginf=0.0)


def depth_normals(camera: Camera, depth) -> np.ndarray:
    r"""Camera-frame unit normals (H, W, 3) of a depth map, turned towards the camera.

    :math:`n \propto \partial_x P \times \partial_y P` with :math:`P` the
    back-projected points (central differences inside the image, one-sided
    at its border); 0 where the depth is 0 or the cross product vanishes.
    """
    d = _check_depth(camera, depth)
    h, w = d.shape
    xs = (np.arange(w) + 0.5 - camera.cx) / camera.fx
    ys = (np.arange(h) + 0.5 - camera.cy) / camera.fy
    p = np.stack([d * xs[None, :], d * ys[:, None], d], axis=-1)
    dx = np.gradient(p, axis=1)
    dy = np.gradient(p, axis=0)
    n = np.cross(dx, dy)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(norm > 1e-12, n / np.maximum(norm, 1e-30), 0.0)
    flip = np.sum(n * p, axis=-1) > 0  # must face the camera: n . P < 0
    n[flip] *= -1
    n[d <= 0] = 0.0
    return n


def surface_patch(camera: Camera, depth, alpha, click, *, depth_tol: float = 0.03,
                  normal_tol_deg: float = 30.0, alpha_min: float = 0.5) -> np.ndarray:
    """Pixels reached from ``click = (x, y)`` without crossing a depth jump or a crease.

    See step 1 of the module docstring. Returns (H, W) bool (empty when the
    clicked pixel is not solid).
    """
    d = _check_depth(camera, depth)
    a = np.asarray(alpha, dtype=np.float64)
    if a.shape != d.shape:
        raise ValidationError(f"alpha has shape {a.shape}; depth has {d.shape}")
    x, y = (int(v) for v in click)
    h, w = d.shape
    if not (0 <= x < w and 0 <= y < h):
        raise ValidationError(f"click ({x}, {y}) is outside the {w}x{h} reference image")
    solid = (a >= alpha_min) & (d > 0)
    if not solid[y, x]:
        return np.zeros((h, w), bool)
    n = depth_normals(camera, d)
    cos_tol = np.cos(np.radians(normal_tol_deg))
    with np.errstate(invalid="ignore", divide="ignore"):
        jump_x = np.abs(np.diff(d, axis=1)) > depth_tol * np.minimum(d[:, 1:], d[:, :-1])
        jump_y = np.abs(np.diff(d, axis=0)) > depth_tol * np.minimum(d[1:, :], d[:-1, :])
    crease_x = np.sum(n[:, 1:] * n[:, :-1], axis=-1) < cos_tol
    crease_y = np.sum(n[1:, :] * n[:-1, :], axis=-1) < cos_tol
    # A separating edge makes both of its pixels barriers (4-connectivity
    # could otherwise step around a one-pixel-wide edge), except the click.
    barrier = ~solid
    cut_x = jump_x | crease_x
    cut_y = jump_y | crease_y
    barrier[:, 1:] |= cut_x
    barrier[:, :-1] |= cut_x
    barrier[1:, :] |= cut_y
    barrier[:-1, :] |= cut_y
    open_ = ~barrier
    open_[y, x] = True
    lab, _ = ndimage.label(open_)
    patch = lab == lab[y, x]
    if patch.sum() < 4:
        # The click sits on an edge or a noisy surface: a small disc of
        # solid pixels at a consistent depth stands in for the patch.
        yy, xx = np.mgrid[0:h, 0:w]
        patch = ((xx - x) ** 2 + (yy - y) ** 2 <= 9) & solid & (np.abs(d - d[y, x]) <= depth_tol * d[y, x])
    return patch


def grow_object(scene, seeds, *, center, radius: float, plane=None, blocked=None,
                k_neighbors: int = 10, link_factor: float = 2.0, overlap: float = 1.0,
                keep_fraction: float = 0.2, min_opacity: float = 0.2) -> tuple[np.ndarray, dict]:
    """Grow seed Gaussians over a kNN graph of the means (step 3 of the module docstring).

    Parameters
    ----------
    scene : GaussianScene
    seeds : (N,) bool
    center, radius
        Only Gaussians within ``radius`` of ``center`` take part.
    plane : (normal (3,), point (3,), band float) or None
        Support plane: Gaussians with ``normal . (x - point) < band`` are removed.
    blocked : (N,) bool or None
        Gaussians that may not be reached (negative clicks).

    Returns
    -------
    selected : (N,) bool
    info : dict
    """
    n_all = len(scene)
    seeds = np.asarray(seeds, bool)
    if seeds.shape != (n_all,):
        raise ValidationError(f"seeds must be a boolean array of shape ({n_all},), got {seeds.shape}")
    means = scene.means.astype(np.float64)
    c = np.asarray(center, dtype=np.float64)
    ball = np.linalg.norm(means - c, axis=1) <= float(radius)
    node = ball & (scene.opacities >= min_opacity)
    node |= seeds
    info = {"radius": float(radius)}
    if plane is not None:
        pn, pp, band = plane
        pn = np.asarray(pn, float) / np.linalg.norm(pn)
        above = (means - np.asarray(pp, float)) @ pn >= float(band)
        info.update(plane_normal=pn.tolist(), plane_point=np.asarray(pp, float).tolist(), band=float(band))
        # A support plane holds the object up: one that leaves most of the clicked Gaussians below it
        # cuts through the click (a wrong fit), and would leave nothing to grow from.
        if np.count_nonzero(above & seeds) >= 0.5 * np.count_nonzero(seeds):
            node &= above
            ball &= above
        else:
            info["plane_rejected"] = "it cuts through the clicked Gaussians"
    if blocked is not None:
        node &= ~np.asarray(blocked, bool)
        ball &= ~np.asarray(blocked, bool)
    idx = np.flatnonzero(node)
    sel = np.zeros(n_all, bool)
    seed_nodes = seeds[idx]
    if not seed_nodes.any():
        info.update(n_nodes=int(len(idx)), n_selected=0)
        return sel, info
    if len(idx) < 2:
        sel[idx] = True
        return sel, info
    lab, ncomp, cutoff = linked_components(scene, idx, seed_nodes, k_neighbors=k_neighbors,
                                           link_factor=link_factor, overlap=overlap)
    score = np.bincount(lab[seed_nodes], minlength=ncomp).astype(float)
    good = score >= keep_fraction * score.max()
    good &= score > 0
    sel[idx[good[lab]]] = True
    sel |= seeds & node  # the lifted click region is the object by definition
    n_faint = _attach_faint(scene, idx, ball & ~node, sel, cutoff, overlap)
    info.update(n_nodes=int(len(idx)), link_distance=cutoff, n_components=int(ncomp),
                kept_components=int(good.sum()), n_faint=n_faint, n_selected=int(sel.sum()))
    return sel, info


def _attach_faint(scene: GaussianScene, idx: np.ndarray, faint: np.ndarray, sel: np.ndarray, cutoff: float,
                  overlap: float) -> int:
    r"""Let the faint Gaussians (below ``min_opacity``) follow their nearest node of the growth graph; in place.

    A Gaussian of the (N,) bool ``faint`` whose nearest node ``j`` among
    ``idx`` lies within the link rule's reach
    (:math:`\max(\lambda \rho_0, \kappa (s_i + s_j))`, ``cutoff`` and
    ``overlap``) takes ``sel[j]``. Faint splats are no links (they would
    bridge the gaps between objects: a tree's haze), but they carry much of
    a surface's colour where a capture is soft (an aerial capture's walls).
    Returns how many joined the selection.
    """
    f_idx = np.flatnonzero(faint)
    if len(f_idx) == 0 or len(idx) == 0:
        return 0
    dist, j = cKDTree(scene.means[idx].astype(np.float64)).query(scene.means[f_idx].astype(np.float64), k=1)
    sig = scene.scales.max(axis=1).astype(np.float64)
    join = (dist <= np.maximum(cutoff, overlap * (sig[f_idx] + sig[idx[j]]))) & sel[idx[j]]
    sel[f_idx[join]] = True
    return int(join.sum())


def linked_components(scene: GaussianScene, idx: np.ndarray, ref_nodes: np.ndarray, *, k_neighbors: int = 10,
                      link_factor: float = 2.0, overlap: float = 1.0) -> tuple[np.ndarray, int, float]:
    r"""Connected components of the Gaussians ``idx`` under the growth's link rule (step 3 of the module docstring).

    Each Gaussian is linked to those of its ``k_neighbors`` nearest (among
    ``idx``) within :math:`\max(\lambda \rho_0, \kappa (s_i + s_j))`, with
    :math:`\rho_0` the median distance of the ``ref_nodes`` to their 4th
    nearest neighbour.

    Parameters
    ----------
    scene : GaussianScene
    idx : (M,) int
        The Gaussians taking part, M >= 2.
    ref_nodes : (M,) bool
        Which of them set the sampling density :math:`\rho_0` (at least one).

    Returns
    -------
    labels : (M,) int
        Component of each, in 0..n-1.
    n : int
        Number of components.
    link_distance : float
        :math:`\lambda \rho_0`.

    Raises
    ------
    ValidationError
        ``idx`` not at least two indices of the scene, or ``ref_nodes`` not
        a boolean (M,) mask with at least one True.
    """
    idx = np.asarray(idx)
    ref_nodes = np.asarray(ref_nodes)
    if idx.ndim != 1 or idx.dtype.kind not in "iu" or len(idx) < 2 or idx.min() < 0 or idx.max() >= len(scene):
        raise ValidationError(f"linked_components: idx must be at least two indices into the scene's {len(scene)} "
                              f"Gaussians, got {idx.dtype} {idx.shape}")
    if ref_nodes.dtype != bool or ref_nodes.shape != idx.shape or not ref_nodes.any():
        raise ValidationError(f"linked_components: ref_nodes must be a boolean {idx.shape} mask with a True, got "
                              f"{ref_nodes.dtype} {ref_nodes.shape}")
    means = scene.means[idx].astype(np.float64)
    tree = cKDTree(means)
    k = int(min(k_neighbors, len(idx) - 1))
    dist, nbr = tree.query(means, k=k + 1)
    dist, nbr = dist[:, 1:], nbr[:, 1:]
    ref = dist[np.asarray(ref_nodes, bool), min(3, k - 1)]
    cutoff = float(link_factor) * float(np.median(ref))
    # Two Gaussians are linked when they are as close as the seed's own
    # sampling (link_factor x its 4th-neighbour distance) or when their
    # 1-sigma ellipsoids reach each other (sigma = largest std): trained
    # splats are denser on well-seen surfaces (a table top) than on grazing
    # ones (its skirt), and bigger where sparser.
    sig = scene.scales_at(idx).max(axis=1).astype(np.float64)
    reach = np.maximum(cutoff, overlap * (sig[:, None] + sig[nbr]))
    keep = dist <= reach
    rows = np.repeat(np.arange(len(idx)), k)[keep.ravel()]
    cols = nbr.ravel()[keep.ravel()]
    graph = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(len(idx), len(idx)))
    ncomp, lab = connected_components(graph, directed=False)
    return lab, int(ncomp), cutoff


#: A plane with more than this share of the solid Gaussians in the column under the seed below it
#: (:func:`_below_share`) is passed over for one with at most this share: the ground has nothing under it,
#: a chair's seat has its legs and the floor.
MAX_BELOW_SHARE = 0.1


def _below_share(means: np.ndarray, opacities: np.ndarray, normal: np.ndarray, point: np.ndarray, threshold: float,
                 center: np.ndarray, radius: float, min_opacity: float) -> float:
    r"""Share of the solid Gaussians in the column under ``center`` that lie below the plane ``(normal, point)``.

    The column holds the Gaussians of opacity at least ``min_opacity``
    (the growth's) within ``radius`` of ``center`` across the normal and within
    ``2 radius`` along it; a Gaussian is below when
    :math:`n \cdot (x - p) < -3 \tau` (``threshold`` :math:`\tau`, the
    plane fit's inlier distance). 0 when the column is empty.
    """
    rel = means - center
    along = rel @ normal
    across = np.linalg.norm(rel - np.outer(along, normal), axis=1)
    col = (across <= radius) & (np.abs(along) <= 2.0 * radius) & (opacities >= min_opacity)
    if not col.any():
        return 0.0
    return float(np.mean((means[col] - point) @ normal < -3.0 * threshold))


def _support_plane(scene: GaussianScene, camera: Camera, seeds: np.ndarray, center: np.ndarray, radius: float,
                   min_band: float, min_opacity: float) -> tuple[tuple[np.ndarray, np.ndarray, float] | None, dict]:
    """The support plane under the grown object (the ground) for :func:`grow_object`, and what it came from.

    The support or scene plane of
    :func:`~seed2gs_inverse.pipeline.up_axis.estimate_up_axis` (with the
    click's lifted Gaussians as G0) that has the object above it, in that
    order, as ``(normal, point, band)`` with band
    ``max(3 tau, min_band * radius)``; None when neither qualifies. The
    first is passed over when more than :data:`MAX_BELOW_SHARE` of the
    solid Gaussians under the seed lie below it (:func:`_below_share`) and
    the other has at most that share: a flat part of the object or of what
    it stands on (a chair's seat under a click on its backrest) is no
    ground. The info then says so (``passed_over``).
    """
    est = estimate_up_axis(scene, camera, support=seeds, center=center, radius=radius)
    means, opacities = scene.means.astype(np.float64), scene.opacities  # once for both planes
    found = []
    for key in ("support_plane", "scene_plane"):
        p = est.details.get(key)
        if p is None:
            continue
        normal = np.asarray(p["normal"], float)
        point = np.asarray(p["point"], float)
        if normal @ (center - point) <= 0:
            continue  # the object must be above its support
        below = _below_share(means, opacities, normal, point, float(p["threshold"]), center, radius, min_opacity)
        found.append((key, normal, point, max(3.0 * float(p["threshold"]), min_band * radius), below))
    info = {"method": est.method, "confidence": float(est.confidence)}
    if not found:
        return None, {"source": None, **info}
    best = found[0]
    if best[4] > MAX_BELOW_SHARE and len(found) > 1 and found[1][4] <= MAX_BELOW_SHARE:
        info["passed_over"] = {best[0]: f"{best[4]:.0%} of the solid Gaussians under the seed lie below it"}
        best = found[1]
    key, normal, point, band, _ = best
    return (normal, point, band), {"source": key, **info}


def _check_point_inputs(scene, camera, points, labels, region, options: dict):
    """:func:`point_object_mask`'s arguments checked: ``(opt, clicks (K, 2) float64, labels (K,) int, region)``.

    Raises
    ------
    ValidationError
        An unknown option, ``max_expansions`` not in 0..10, an empty scene,
        no finite click, labels that are not 0/1 (one per click, at least
        one 1), a click outside the image, or a ``region`` that is not a
        PointPrompt.
    """
    unknown = set(options) - set(POINT_OBJECT_DEFAULTS)
    if unknown:
        raise ValidationError(f"point_object_mask: unknown options {sorted(unknown)}; "
                              f"valid: {sorted(POINT_OBJECT_DEFAULTS)}")
    opt = {**POINT_OBJECT_DEFAULTS, **options}
    m = opt["max_expansions"]
    if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or not 0 <= m <= 10:
        raise ValidationError(f"point_object_mask: max_expansions must be a whole number in 0..10, got {m!r}")
    if not isinstance(scene, GaussianScene) or len(scene) == 0:
        raise ValidationError("point_object_mask: scene must be a non-empty GaussianScene")
    if not isinstance(camera, Camera):
        raise ValidationError(f"camera must be a Camera, got {type(camera).__name__}")
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2) if np.size(points) else np.zeros((0, 2))
    if len(pts) == 0 or not np.all(np.isfinite(pts)):
        raise ValidationError("point prompt needs at least one finite click (x, y)")
    labs = np.ones(len(pts), int) if labels is None else np.asarray(labels, int).ravel()
    if labs.shape != (len(pts),) or not np.all(np.isin(labs, (0, 1))) or not labs.any():
        raise ValidationError(f"point labels must be 0/1, one per click, with at least one 1; got {labels!r}")
    h, w = camera.image_shape
    out = (pts[:, 0] < 0) | (pts[:, 0] >= w) | (pts[:, 1] < 0) | (pts[:, 1] >= h)
    if out.any():
        raise ValidationError(f"click {pts[np.argmax(out)].tolist()} is outside the {w}x{h} reference image")
    if region is None:
        region = PointPrompt([(0, 0)])
    elif not isinstance(region, PointPrompt):
        raise ValidationError(f"point_object_mask: region must be a PointPrompt or None, got {type(region).__name__}")
    return opt, pts, labs, region


def _click_region(camera: Camera, ref: Rendering, depth: np.ndarray, alpha: np.ndarray, click,
                  region: PointPrompt, patch_kw: dict) -> tuple[np.ndarray, str]:
    """Step 1 for one click: ``(mask (H, W) bool, how)``.

    The colour-and-depth region of ``region`` at the click (``how`` is
    ``"region"``); the smooth surface patch (:func:`surface_patch`, keywords
    ``patch_kw``) when that is empty (``"surface-patch"``).
    """
    x, y = int(click[0]), int(click[1])
    try:
        m = replace(region, points=[(x, y)], labels=[1]).to_mask(ref.rgb, depth=depth, alpha=alpha)
        how = "region"
    except ValidationError:
        m = np.zeros(camera.image_shape, bool)
    if not m.any():
        m = surface_patch(camera, depth, alpha, (x, y), **patch_kw)
        how = "surface-patch"
    return m, how


def _grow_with_expansions(scene: GaussianScene, seeds: np.ndarray, center: np.ndarray, radius: float, plane,
                          blocked: np.ndarray | None, opt: dict) -> tuple[np.ndarray, dict]:
    """Step 3: :func:`grow_object` from ``growth_factor`` times ``radius``, doubling while the object reaches the edge.

    The click's region may be a small part of the object (a chair's
    backrest): while the grown object reaches the edge of the growth region
    (a node of its graph, not a faint splat, beyond :data:`_EDGE` of its radius), the region doubles, at
    most ``max_expansions`` times. An object the growth closes around stops
    short of the edge; one that still reaches it after every doubling leaks
    into the scene, and the first growth is kept (``info["expansion"]`` says so).
    """
    radius = opt["growth_factor"] * radius
    first = None
    for expansions in range(int(opt["max_expansions"]) + 1):
        selected, grow_info = grow_object(
            scene, seeds, center=center, radius=radius, plane=plane,
            blocked=blocked, k_neighbors=opt["k_neighbors"], link_factor=opt["link_factor"], overlap=opt["overlap"],
            keep_fraction=opt["keep_fraction"], min_opacity=opt["min_opacity"])
        if expansions == 0:
            first = selected, grow_info
        # the graph's own nodes decide whether the object closes: faint splats hang about every surface
        solid = selected & ((scene.opacities >= opt["min_opacity"]) | seeds)
        reach = np.linalg.norm(scene.means[solid].astype(np.float64) - center, axis=1).max(initial=0.0)
        if reach < _EDGE * radius:
            grow_info["expansions"] = expansions
            return selected, grow_info
        radius *= 2.0
    selected, grow_info = first
    grow_info["expansions"] = 0
    if opt["max_expansions"]:
        grow_info["expansion"] = (f"still at the edge of the growth region after {int(opt['max_expansions'])} "
                                  "doublings (leaking into the scene): the first growth is kept")
    return selected, grow_info


def _render_mask(scene: GaussianScene, camera: Camera, selected: np.ndarray, mode: str) -> np.ndarray:
    """Step 4: ``(W 1_selected)(u) > 0.5`` as (H, W) bool, rendered over the box of the selection's projection."""
    h, w = camera.image_shape
    mask = np.zeros((h, w), bool)
    if not selected.any():
        return mask
    uv, z = camera.project(scene.means[selected])
    sig = 3.0 * scene.scales_at(selected).max(axis=1).astype(np.float64)
    ok = np.isfinite(uv).all(axis=1) & (z > camera.near)
    if ok.any():
        rad = sig[ok] * max(camera.fx, camera.fy) / z[ok]
        x0 = int(np.clip(np.floor((uv[ok, 0] - rad).min()) - 2, 0, w))
        x1 = int(np.clip(np.ceil((uv[ok, 0] + rad).max()) + 2, 0, w))
        y0 = int(np.clip(np.floor((uv[ok, 1] - rad).min()) - 2, 0, h))
        y1 = int(np.clip(np.ceil((uv[ok, 1] + rad).max()) + 2, 0, h))
        if x1 > x0 and y1 > y0:
            roi = (x0, y0, x1, y1)
            op = build_operator(scene, camera, roi=roi, mode=mode, subset=cone_cull(scene, camera, roi))
            mask = (op.W @ selected.astype(np.float32)).reshape(h, w) > 0.5
    return mask


def point_object_mask(scene: GaussianScene, camera: Camera, points, labels=None, rendering: Rendering | None = None,
                      *, mode: str = "classic", region: PointPrompt | None = None, **options) -> PointObject:
    """The object under positive clicks, as a seed mask (see the module docstring).

    Parameters
    ----------
    scene : GaussianScene
    camera : Camera
        Reference view; clicks are its pixel coordinates ``(x, y)``.
    points : (K, 2) array
    labels : (K,) 0/1 or None (all positive)
    rendering : Rendering or None
        The reference rendering (``depth``, ``alpha``); rendered when None.
    mode : str
        Rasterization mode.
    region : PointPrompt or None
        Its colour-and-depth region settings (``color_tol``, ``depth_tol``,
        ``radius``, ``iterations``, ``alpha_min``) grow each click's region;
        None: :class:`~seed2gs_inverse.frontend.prompts.PointPrompt`'s
        defaults. Its clicks are not read (``points`` and ``labels`` are).
    **options
        Any of :data:`POINT_OBJECT_DEFAULTS`.

    Returns
    -------
    PointObject

    Raises
    ------
    ValidationError
        Bad arguments (see :func:`_check_point_inputs`), or positive clicks
        that hit only empty space.

    Warns
    -----
    UserWarning
        The growth yields no mask: the seed is the clicked region alone.
    """
    opt, pts, labs, region = _check_point_inputs(scene, camera, points, labels, region, options)
    h, w = camera.image_shape
    ref = render(scene, camera, mode=mode) if rendering is None else rendering
    depth = _check_depth(camera, ref.depth, "rendering depth")
    alpha = np.asarray(ref.alpha)
    patch_kw = {k: opt[k] for k in ("depth_tol", "normal_tol_deg", "alpha_min")}
    patch = np.zeros((h, w), bool)
    neg_patch = np.zeros((h, w), bool)
    sources = []
    for click, lab in zip(pts, labs):
        m, how = _click_region(camera, ref, depth, alpha, click, region, patch_kw)
        if lab == 1:
            patch |= m
            sources.append(how)
        else:
            neg_patch |= m
    if not patch.any():
        raise ValidationError("the positive clicks hit only empty space in the reference view")
    neg_patch &= ~patch
    lift = seed_lift(scene, camera, patch, depth)
    seeds = lift.g0
    blocked = None
    if neg_patch.any():
        try:
            blocked = seed_lift(scene, camera, neg_patch, depth).g0 & ~seeds
        except ValidationError:
            blocked = None
    plane, plane_info = _support_plane(scene, camera, seeds, lift.center, lift.radius, opt["min_band"],
                                       opt["min_opacity"])
    selected, grow_info = _grow_with_expansions(scene, seeds, lift.center, lift.radius, plane, blocked, opt)
    mask = _render_mask(scene, camera, selected, mode)
    fallback = not mask.any()
    if fallback:
        mask = patch.copy()
        warnings.warn("point prompt: the click could not be grown to a whole object; the seed is the clicked "
                      f"region alone ({int(patch.sum())} px). Click nearer the object's middle, or give a box "
                      "or a mask", stacklevel=2)
    info = {"kind": "point", "mode": "object", "n_clicks": int(len(pts)), "patch_pixels": int(patch.sum()),
            "patch_sources": sources,
            "n_seeds": int(seeds.sum()), "support": plane_info, "growth": grow_info,
            "fallback_to_patch": bool(fallback)}
    return PointObject(mask, selected, patch, seeds, info)
