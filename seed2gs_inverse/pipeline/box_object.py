r"""Box prompts that return one object: the GrabCut seed cleaned to the box's main object in 3D.

GrabCut (:class:`~seed2gs_inverse.frontend.prompts.BoxPrompt`) separates
the box's content by colour alone. What the box also covers and what looks
alike (the stones of a fire pit behind a white table, the ground seen
between a chair's slats) ends in the seed, is lifted to G0 and propagated
to every orbit view. The box is about one object, and in 3D the object is
apart from those. The seed is cleaned in five steps:

1. **Lift.** The GrabCut pixels are lifted to Gaussians with the seed
   lift's centre rule (:func:`~seed2gs_inverse.pipeline.seed_lift.seed_lift`
   without ``W``): projected centre in the mask at a consistent depth. These
   are the Gaussians the seed shows.
2. **Ground.** The support plane under them (the ground the object stands
   on, as a point prompt finds it), when the up-axis estimate behind it is
   trusted (confidence at least
   :data:`~seed2gs_inverse.pipeline.up_axis.WEAK_CONFIDENCE`; an object
   scanned alone has no ground, and a plane fitted to it would cut its own
   base off), takes its band out: Gaussians with
   :math:`n \cdot (x - p) <` the band are ground, which links everything
   standing on it in 3D.
3. **Components.** The remaining lifted Gaussians are split into the
   connected components of a point prompt's growth graph
   (:func:`~seed2gs_inverse.pipeline.point_object.linked_components`: kNN
   links within ``link_factor`` times the sampling distance, or where the
   1-sigma ellipsoids touch). Each seed pixel belongs to the
   component (or the ground) that holds most of its compositing weight,
   from the reference operator ``W`` over the box of the mask. The *main*
   component is the one that owns the most seed pixels: the box is drawn
   around the object it is about, which fills most of it; things seen
   through gaps or past its edge fill the rest. The box holds its object,
   so another component is dropped only when the box's edge cuts it (it
   goes on beyond the box: it owns seed pixels within two pixels of the
   edge, or, since GrabCut often stops short of the edge where the
   neighbour's colour changes, it belongs to a component that renders
   there with weight above one half in a wider graph: every Gaussian that
   renders in the box, less the ground's band, joined to the lifted ones
   by the same link rule, a component that does not hold the main one)
   and it stays farther than ``gap`` times the main component's radius
   from it. The distance is taken along the ground (across the
   support plane's normal) when there is one: what stands under or over
   the main part (a table's legs, hidden where they meet the top) is the
   same object; without a plane it is taken in 3D. A 1-sigma ellipsoid's
   reach counts (a big splat on a grazing face is far by its centre
   only). Parts of one object the graph leaves apart (a piece split off
   by a thin occluder in front, sparse splats at a thin part, a floater)
   stay within the box or near the main part. Ground
   Gaussians stay when they come within the link distance of a kept one
   (the object's own base in the ground's band).
4. **Drop.** Gaussians that render in the seed without being lifted (a
   neighbour's big or half-hidden splats) follow their nearest lifted one.
   The seed pixels whose weight lies more on the dropped Gaussians than on
   the kept ones leave the seed; pixels neither renders to stay as GrabCut
   gave them.
5. **Take back.** GrabCut also leaves out parts of the object that look
   like what is around them: the shadowed foot of a stone wall beside the
   gravel, the part of the object seen between an occluder's arm and its
   back. In 3D they are linked to the main component through the wider
   graph of step 3 (the ground's band left out, so the ground links
   nothing). Every pixel of the box where the main component's wider
   component holds more than half of the compositing weight is in the
   seed, whatever GrabCut or step 4 said of it. Only with a ground plane
   (step 2): without one the ground stays in the wider graph and links the
   object to everything around it (the gardens and the street around a
   house seen from above).

A thin object keeps its parts: its slats, legs and arms are linked in 3D
through the frame that holds them, and a part split off by an occluder lies
within ``gap`` or inside the box. What the box holds whole and apart from
the object (a stone lying beside it) stays in the seed. When nothing can be lifted, or the cleaning would leave
nothing, the GrabCut seed is kept as it is (``info["cleaned"]`` says why).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..camera import Camera
from .._validation import check_vector
from ..errors import ValidationError
from ..raster import build_operator, cone_cull
from ..scene import GaussianScene
from .point_object import POINT_OBJECT_DEFAULTS
from .point_object import _support_plane as support_plane
from .point_object import linked_components
from .seed_lift import seed_lift
from .up_axis import WEAK_CONFIDENCE

__all__ = ["BoxObject", "box_object_mask", "BOX_OBJECT_DEFAULTS"]

#: Defaults of :func:`box_object_mask`. ``gap``: how close (in radii of the
#: main component) another component must come to stay; ``min_band``: the
#: ground band's least thickness in radii; ``k_neighbors``, ``link_factor``
#: and ``overlap``: the link rule of :func:`~.point_object.linked_components`
#: (all as in :func:`~.point_object.point_object_mask`).
BOX_OBJECT_DEFAULTS = {"gap": 0.1, "min_band": 0.03, "k_neighbors": 10, "link_factor": 2.0, "overlap": 1.0}


@dataclass
class BoxObject:
    """Result of :func:`box_object_mask`.

    Attributes
    ----------
    mask : (H, W) bool
        The cleaned seed: the GrabCut seed less the dropped pixels, plus the
        box's pixels that the main object holds (module docstring, step 5).
    kept : (N,) bool
        The lifted Gaussians of the main object.
    dropped : (N,) bool
        The lifted Gaussians of the other components and of the ground away from the object.
    info : dict
        JSON-ready: ``cleaned`` (True, or why not), ``n_dropped_pixels``,
        ``n_added_pixels`` (taken back from outside the GrabCut seed),
        ``n_seed_pixels`` (before), the component counts and the plane used.
    """

    mask: np.ndarray
    kept: np.ndarray
    dropped: np.ndarray
    info: dict = field(default_factory=dict)


def _mask_box(mask: np.ndarray, pad: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) around the mask's pixels, grown by ``pad`` and clipped to the image."""
    ys, xs = np.nonzero(mask)
    h, w = mask.shape
    return (max(int(xs.min()) - pad, 0), max(int(ys.min()) - pad, 0),
            min(int(xs.max()) + 1 + pad, w), min(int(ys.max()) + 1 + pad, h))


def _reference_weights(scene: GaussianScene, camera: Camera, mask: np.ndarray, mode: str,
                       box: tuple[int, int, int, int] | None = None) -> sp.csr_matrix:
    """The reference operator's ``W`` (H*W, N) over the box of the mask's pixels and ``box`` (zero rows elsewhere)."""
    roi = _mask_box(mask, 2)
    if box is not None:
        roi = (min(roi[0], box[0]), min(roi[1], box[1]), max(roi[2], box[2]), max(roi[3], box[3]))
    op = build_operator(scene, camera, roi=roi, mode=mode, subset=cone_cull(scene, camera, roi))
    return sp.csr_matrix(op.W)


def _owners(W: sp.csr_matrix, mask: np.ndarray, label: np.ndarray, n_labels: int) -> np.ndarray:
    """(H, W) int: the label (0..n_labels-1) holding most of each seed pixel's weight; -1 where none renders.

    ``label`` (N,) gives each lifted Gaussian its label, -1 for the others.
    """
    h, w = mask.shape
    cols = np.flatnonzero(label >= 0)
    onehot = sp.csr_matrix((np.ones(len(cols)), (cols, label[cols])), shape=(len(label), n_labels))
    weight = (W @ onehot).toarray().reshape(h, w, n_labels)
    owner = np.argmax(weight, axis=2)
    owner[weight.max(axis=2) <= 0] = -1
    owner[~mask] = -1
    return owner


def _rendered_at(W: sp.csr_matrix, pixels: np.ndarray, label: np.ndarray, n_labels: int) -> np.ndarray:
    """(n_labels,) bool: the labels whose Gaussians render at one of ``pixels`` (H, W) with weight above 1/2.

    ``label`` (N,) gives each Gaussian its label, -1 (or ``n_labels`` and
    up) for the others.
    """
    rows = np.flatnonzero(np.asarray(pixels).ravel())
    cols = np.flatnonzero((label >= 0) & (label < n_labels))
    if len(rows) == 0 or len(cols) == 0:
        return np.zeros(n_labels, bool)
    onehot = sp.csr_matrix((np.ones(len(cols)), (cols, label[cols])), shape=(len(label), n_labels))
    weight = (W[rows] @ onehot).toarray()
    return (weight > 0.5).any(axis=0)


def _wide_components(scene: GaussianScene, W: sp.csr_matrix, box: tuple[int, int, int, int], shape: tuple[int, int],
                     label: np.ndarray, ncomp: int, plane, opt: dict) -> tuple[np.ndarray, int]:
    """``(wide_label (N,), n_wide)``: the wider graph's components (-1 outside it).

    Every Gaussian that renders inside the box (less the ground's band)
    joins the seed's lifted Gaussians (less the ground's label ``ncomp``),
    linked by the same rule as the seed's components.
    """
    h, w = shape
    x0, y0, x1, y1 = box
    inside = np.zeros((h, w), bool)
    inside[y0:y1, x0:x1] = True
    lifted = (label >= 0) & (label != ncomp)
    wide = (np.asarray(W.T @ inside.ravel().astype(np.float64)).ravel() > 0) | lifted
    if plane is not None:
        pn, pp, band = plane
        wide &= ((scene.means.astype(np.float64) - pp) @ pn >= band) | lifted
    wide_label = np.full(len(label), -1, np.int64)
    idx = np.flatnonzero(wide)
    if len(idx) < 2:
        return wide_label, 0
    wlab, nwide, _ = linked_components(scene, idx, lifted[idx], k_neighbors=opt["k_neighbors"],
                                       link_factor=opt["link_factor"], overlap=opt["overlap"])
    wide_label[idx] = wlab
    return wide_label, int(nwide)


def _cut_beyond_seed(W: sp.csr_matrix, ring: np.ndarray, label: np.ndarray, ncomp: int, main: int,
                     wide_label: np.ndarray, n_wide: int) -> np.ndarray:
    """(ncomp,) bool: the seed's components that the box's edge cuts where the seed does not reach it.

    GrabCut often stops short of the box's edge on the part of a neighbour
    that crosses it (the dark top of a white table behind the object: only
    its white side is in the seed). A component is cut when its component
    in the wider graph (``wide_label``, :func:`_wide_components`) renders
    at the box's ``ring`` with weight above 1/2 and does not hold the
    ``main`` component (what links to the main part is kept as before).
    """
    cut = np.zeros(ncomp, bool)
    if n_wide == 0:
        return cut
    at_edge = _rendered_at(W, ring, wide_label, n_wide)
    at_edge[np.unique(wide_label[label == main])] = False
    li = np.flatnonzero((label >= 0) & (label < ncomp))
    np.logical_or.at(cut, label[li], at_edge[wide_label[li]])
    return cut


def _main_in_box(W: sp.csr_matrix, box: tuple[int, int, int, int], shape: tuple[int, int], label: np.ndarray,
                 main: int, wide_label: np.ndarray) -> np.ndarray:
    """(H, W) bool: the box's pixels where the main component's wider component holds over half the weight.

    GrabCut separates by colour alone, so it leaves out parts of the object
    that look like what is around them (stones of a wall's shadowed foot
    beside the gravel, a part seen through a gap between an occluder's
    parts). In 3D those parts are linked to the main component through the
    wider graph (:func:`_wide_components`, without the ground's band), and
    what renders them in the box belongs to the seed.
    """
    h, w = shape
    out = np.zeros((h, w), bool)
    ids = np.unique(wide_label[label == main])
    ids = ids[ids >= 0]
    if len(ids) == 0:
        return out
    onmain = np.isin(wide_label, ids).astype(np.float64)
    x0, y0, x1, y1 = box
    weight = np.asarray(W @ onmain).ravel().reshape(h, w)
    out[y0:y1, x0:x1] = weight[y0:y1, x0:x1] > 0.5
    return out


def _check_box_inputs(scene, camera, mask, depth, options: dict) -> tuple[dict, np.ndarray, np.ndarray]:
    """:func:`box_object_mask`'s arguments checked: ``(options, mask (H, W) bool, depth (H, W) float64)``."""
    unknown = set(options) - set(BOX_OBJECT_DEFAULTS)
    if unknown:
        raise ValidationError(f"box_object_mask: unknown options {sorted(unknown)}; valid: {sorted(BOX_OBJECT_DEFAULTS)}")
    opt = {**BOX_OBJECT_DEFAULTS, **options}
    for name in ("gap", "min_band", "link_factor", "overlap"):
        v = opt[name]
        if isinstance(v, bool) or not isinstance(v, (int, float, np.number)) or not (np.isfinite(v) and v >= 0):
            raise ValidationError(f"box_object_mask: {name} must be a finite number >= 0, got {v!r}")
    k = opt["k_neighbors"]
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= 256:
        raise ValidationError(f"box_object_mask: k_neighbors must be a whole number in 1..256, got {k!r}")
    if not isinstance(scene, GaussianScene) or len(scene) == 0:
        raise ValidationError("box_object_mask: scene must be a non-empty GaussianScene")
    if not isinstance(camera, Camera):
        raise ValidationError(f"box_object_mask: camera must be a Camera, got {type(camera).__name__}")
    m = np.asarray(mask)
    d = np.asarray(depth)
    if m.dtype != bool or m.shape != camera.image_shape or d.shape != camera.image_shape:
        raise ValidationError(f"box_object_mask: mask must be a boolean and depth a numeric array of the camera's "
                              f"shape {camera.image_shape}, got {m.dtype} {m.shape} and {d.shape}")
    if not m.any():
        raise ValidationError("box_object_mask: the mask is empty")
    return opt, m, np.nan_to_num(d.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)


def box_object_mask(scene: GaussianScene, camera: Camera, mask, depth, box=None, *, mode: str = "classic",
                    **options) -> BoxObject:
    """The box prompt's GrabCut seed cleaned to the box's main object (see the module docstring).

    Parameters
    ----------
    scene : GaussianScene
    camera : Camera
        The reference view, at the resolution of ``mask``.
    mask : (H, W) bool
        The GrabCut seed of the box.
    depth : (H, W) array
        The reference view's rendered expected depth (0 where empty).
    box : (x0, y0, x1, y1) or None
        The prompt's box in pixels (exclusive max); None: the mask's own
        bounding box. Only components that reach its edge can be dropped.
    mode : str
        Rasterization mode of the reference operator.
    **options
        Any of :data:`BOX_OBJECT_DEFAULTS`.

    Returns
    -------
    BoxObject
        ``mask`` is ``mask`` itself when nothing could be lifted or the
        cleaning would empty it (``info["cleaned"]`` gives the reason).

    Raises
    ------
    ValidationError
        An unknown or out-of-range option, an empty scene, a camera that is
        not a Camera, or a mask / depth not of the camera's shape (or an
        empty mask).
    """
    opt, m, d = _check_box_inputs(scene, camera, mask, depth, options)
    n = len(scene)
    none = np.zeros(n, bool)
    info = {"n_seed_pixels": int(m.sum()), "n_dropped_pixels": 0}
    try:
        lift = seed_lift(scene, camera, m, d)
    except ValidationError as exc:
        return BoxObject(m, none, none, {**info, "cleaned": f"not cleaned: {exc}"})
    cand = lift.candidates
    means = scene.means.astype(np.float64)
    plane, plane_info = support_plane(scene, camera, cand, lift.center, lift.radius, opt["min_band"],
                                       POINT_OBJECT_DEFAULTS["min_opacity"])
    ground = np.zeros(n, bool)
    if plane is not None and plane_info["confidence"] < WEAK_CONFIDENCE:
        # a weak estimate is no ground: on an object scanned alone the "plane" cuts through its own base
        plane, plane_info = None, {**plane_info, "rejected": f"confidence below {WEAK_CONFIDENCE}"}
    if plane is not None:
        pn, pp, band = plane
        ground = cand & ((means - pp) @ pn < band)
        if ground.sum() >= 0.5 * cand.sum():  # a plane through the seed's middle is no ground under it
            ground[:], plane = False, None
            plane_info = {**plane_info, "rejected": "it holds most of the seed"}
    info["support"] = plane_info
    idx = np.flatnonzero(cand & ~ground)
    if len(idx) == 0:
        return BoxObject(m, none, none, {**info, "cleaned": "not cleaned: the seed shows only the ground"})
    if len(idx) == 1:
        labels, ncomp, link = np.zeros(1, np.int64), 1, 0.0
    else:
        labels, ncomp, link = linked_components(scene, idx, np.ones(len(idx), bool), k_neighbors=opt["k_neighbors"],
                                                link_factor=opt["link_factor"], overlap=opt["overlap"])
    label = np.full(n, -1, np.int64)
    label[idx] = labels
    label[ground] = ncomp  # the ground, one more label
    pbox = _pixel_box(box, m)
    W = _reference_weights(scene, camera, m, mode, pbox)
    owner = _owners(W, m, label, ncomp + 1)
    pixels = np.bincount(owner[owner >= 0], minlength=ncomp + 1)
    main = int(np.argmax(pixels[:ncomp]))
    sigma = scene.scales_at(idx).max(axis=1).astype(np.float64)
    pts = means[idx]
    if plane is not None:
        # across the ground only: what stands under or over the main part is the same object
        pts = pts - np.outer(pts @ plane[0], plane[0])
    keep_comp, radius = _near_components(pts, sigma, labels, ncomp, main, float(opt["gap"]))
    # The box holds its object: only what the box's edge cuts continues beyond it and is something else.
    # GrabCut often stops short of the edge, so a component is cut where its seed pixels reach the edge or
    # where it renders there with most of the alpha.
    ring = _box_ring(pbox, m.shape, _BORDER)
    cut = np.bincount(owner[ring & (owner >= 0) & (owner < ncomp)], minlength=ncomp + 1)[:ncomp] > 0
    wide_label, n_wide = _wide_components(scene, W, pbox, m.shape, label, ncomp, plane, opt)
    cut |= _cut_beyond_seed(W, ring, label, ncomp, main, wide_label, n_wide)
    keep_comp |= ~cut
    kept = np.zeros(n, bool)
    kept[idx[keep_comp[labels]]] = True
    if ground.any():
        # The object's own base lies in the ground's band: ground Gaussians within a link of it stay.
        g_idx = np.flatnonzero(ground)
        dist, _ = cKDTree(means[kept]).query(means[g_idx], k=1)
        kept[g_idx[dist <= link]] = True
    dropped = cand & ~kept
    kept, dropped = _attach_unlifted(scene, W, m, cand, kept, dropped, link)
    # Step 5: where the main object, followed over every Gaussian that renders in the box, holds most of
    # the weight, the pixel is the object's; not without a ground plane, whose band would link it to all around.
    main_px = (_main_in_box(W, pbox, m.shape, label, main, wide_label) if plane is not None
               else np.zeros(m.shape, bool))
    # Any other seed pixel leaves when most of its weight is on dropped Gaussians rather than kept ones;
    # pixels that neither renders to stay as GrabCut gave them.
    owner = _owners(W, m, np.where(kept, 0, np.where(dropped, 1, -1)), 2)
    drop_px = (owner == 1) & ~main_px
    info.update(n_lifted=int(cand.sum()), n_components=int(ncomp), kept_components=int(keep_comp.sum()),
                main_pixels=int(pixels[main]), n_kept=int(kept.sum()), n_dropped_gaussians=int(dropped.sum()),
                gap=float(opt["gap"] * radius))
    added = main_px & ~m
    cleaned = (m & ~drop_px) | added
    if not cleaned.any():
        return BoxObject(m, kept, dropped, {**info, "cleaned": "not cleaned: it would leave nothing"})
    info.update(n_dropped_pixels=int(drop_px.sum()), n_added_pixels=int(added.sum()), cleaned=True)
    return BoxObject(cleaned, kept, dropped, info)


#: Pixels from the box's edge (inside it) that count as its edge.
_BORDER = 2


def _pixel_box(box, mask: np.ndarray) -> tuple[int, int, int, int]:
    """``box`` (x0, y0, x1, y1, exclusive max) as whole pixels clipped to the image; the mask's box when None."""
    if box is None:
        return _mask_box(mask, 0)
    try:
        b = check_vector("box", box, 4)
    except ValidationError:
        raise ValidationError(f"box_object_mask: box must be 4 finite numbers x0 y0 x1 y1, got {box!r}") from None
    h, w = mask.shape
    x0, y0 = int(np.clip(np.floor(b[0]), 0, w)), int(np.clip(np.floor(b[1]), 0, h))
    x1, y1 = int(np.clip(np.ceil(b[2]), 0, w)), int(np.clip(np.ceil(b[3]), 0, h))
    if x1 <= x0 or y1 <= y0:
        raise ValidationError(f"box_object_mask: box {b.tolist()} covers no pixel of the {w}x{h} image")
    return x0, y0, x1, y1


def _box_ring(box: tuple[int, int, int, int], shape: tuple[int, int], width: int) -> np.ndarray:
    """(H, W) bool: the pixels of ``box`` within ``width`` of its edge."""
    x0, y0, x1, y1 = box
    ring = np.zeros(shape, bool)
    ring[y0:y1, x0:x1] = True
    ring[y0 + width:y1 - width, x0 + width:x1 - width] = False
    return ring


def _attach_unlifted(scene: GaussianScene, W: sp.csr_matrix, mask: np.ndarray, lifted: np.ndarray, kept: np.ndarray,
                     dropped: np.ndarray, link: float) -> tuple[np.ndarray, np.ndarray]:
    """``(kept, dropped)`` extended to the Gaussians that render in the seed but were not lifted.

    The lift is strict (mask and depth tests), so a neighbour's big or
    half-hidden splats can fill seed pixels without being lifted. Each such
    Gaussian follows its nearest lifted one when that lies within
    ``max(link, 3 sigma)`` of it (``sigma`` its largest standard deviation);
    the others stay undecided.
    """
    inside = np.asarray(W.T @ mask.ravel().astype(np.float64)).ravel()
    extra = np.flatnonzero((inside > 0) & ~lifted)
    src = np.flatnonzero(lifted)
    if len(extra) == 0 or len(src) == 0:
        return kept, dropped
    means = scene.means.astype(np.float64)
    dist, near = cKDTree(means[src]).query(means[extra], k=1)
    reach = np.maximum(link, 3.0 * scene.scales_at(extra).max(axis=1).astype(np.float64))
    ok = dist <= reach
    kept, dropped = kept.copy(), dropped.copy()
    kept[extra[ok]] = kept[src[near[ok]]]
    dropped[extra[ok]] = dropped[src[near[ok]]]
    return kept, dropped


def _near_components(points: np.ndarray, sigma: np.ndarray, labels: np.ndarray, ncomp: int, main: int,
                     gap: float) -> tuple[np.ndarray, float]:
    """``(keep (ncomp,) bool, radius)``: the components that come within ``gap * radius`` of ``main``.

    A component comes as near as the nearest 1-sigma ellipsoid of its
    Gaussians (centres ``points``, largest standard deviations ``sigma``)
    to a centre of the main component. ``radius`` is the main component's:
    half the diagonal of the robust (2nd-98th percentile) box of its points.
    """
    main_pts = points[labels == main]
    lo, hi = (np.percentile(main_pts, [2, 98], axis=0) if len(main_pts) >= 10
              else (main_pts.min(0), main_pts.max(0)))
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    near, _ = cKDTree(main_pts).query(points, k=1)
    # how near each Gaussian's 1-sigma ellipsoid comes (the link rule's reach): a big splat on a grazing
    # face is far by its centre only
    near = np.maximum(near - sigma, 0.0)
    approach = np.full(ncomp, np.inf)
    np.minimum.at(approach, labels, near)
    keep = approach <= gap * radius
    keep[main] = True
    return keep, radius

