r"""A tracker that needs no model: rendered geometry plus edge-aware filling.

The views of a VAAS clip are *rendered*, so two things come for free that a
video tracker has to estimate: the depth of every pixel and the exact camera
motion between views. :class:`GeometricTracker` propagates the seed mask
with them (2D propagation, as the paper requires: the masks are never read
off a 3D membership, so they add evidence beyond the seed lift).

For frame ``k`` and each pixel ``p`` with rendered alpha above ``alpha_min``:

1. unproject ``p`` with the rendered expected depth :math:`D_k(p)` to a world
   point ``X`` and project ``X`` into a source frame ``j`` (``p' = \pi_j(X)``,
   depth ``z'``);
2. ``X`` is *seen* in frame ``j`` when ``p'`` is in the image, frame ``j`` is
   opaque there and ``z'`` lies within :math:`\tau_{rel} z'` of the range of
   :math:`D_j` at the nearest pixel, or of the range of :math:`D_j` over the
   2x2 pixel centres around ``p'`` where that range is smooth (a z-test: if
   something else is in front, ``X`` was occluded in ``j``; the 2x2 range
   keeps oblique surfaces, whose depth changes a lot within a pixel, and is
   not used across silhouettes, where it would span foreground and
   background), and the colours of ``p`` and ``p'`` agree within
   ``color_tol`` (surfaces that meet at equal depth, like an object standing
   on the ground, differ in colour);
3. the label is copied from the first source that sees ``X`` and has a
   label there that is not within ``boundary_band`` pixels of a 0/1 edge,
   trying the seed frame 0 first (no drift where the reference saw the
   surface), then the already labelled views nearest to frame ``k``
   (earlier frames of the clip, plus labelled ``references`` such as the
   flat clip when the spiral is tracked): a surface hidden for a few frames
   behind an occluder gets its label back from a view that saw it.

**The support surface (``support_plane``).** An object rests on something,
and at the contact line (table legs in grass, the shadowed ground between
them) copies and fills can carry the object's label onto the support; the
next view copies the error and grows it. Given the support band
:math:`\{x : n \cdot (x - x_s) \le 0\}` (``support_plane = (n, x_s)``,
from :func:`~seed2gs_inverse.pipeline.support.support_surface`), a pixel of
frame ``k`` >= 1 whose surface point ``X`` lies in the band and whose surface
faces along ``n``,

.. math::

    n \cdot (X - x_s) \le 0 \quad\text{and}\quad |n \cdot \nu(p)| \ge
    \text{support\_alignment},

with :math:`\nu` the unit normal of the rendered surface (the cross product
of the world points' differences between the pixel's horizontal and its
vertical neighbours), is labelled 0, like empty space, unless the warp from
the seed frame labelled it 1 (what the reference saw of the object stays
object). The object's own walls near the ground face sideways and keep their
labels.

**The contact zone (``contact_zone``).** Just above the band the object's
base and the support meet: the z-test cannot separate them (the ground
behind the base lies within the depth tolerance), and a shadowed base is
often of the ground's colour, so the photometric check passes too. A 0
copied there onto the base is then copied on by the next view, and the
lower body is eaten band by band around the orbit. So in frame ``k`` >= 1 a
pixel whose surface point lies in the zone, a slab of height :math:`h_c`
above the band within the radius :math:`\rho` of the axis through
:math:`x_s` (the object's footprint: clutter further out is not touched),
and does not face along ``n``,

.. math::

    n \cdot (X - x_s) \le h_c, \quad \|(X - x_s) - (n \cdot (X - x_s))\, n\| \le \rho
    \quad\text{and}\quad |n \cdot \nu(p)| < \text{support\_alignment},

takes no 0 from any source but the seed frame: such a copy is held back,
the next source is tried, and a pixel no source labels 1 is left to the
fill (and, where it cannot decide, to the solve's graph regulariser). Only
where it touches the object, though: a held-back pixel whose 8-connected
component of held-back and object-labelled pixels, cut at depth steps of
more than ``fill_depth_jump``, holds no object pixel (clutter near the
footprint, cut off from the object by level ground or standing in front of
it) takes its held-back 0 after all. Level ground in the zone faces along
``n`` and keeps its copied 0; a 1 is copied as everywhere else.

**A seed accurate to a few pixels (``seed_band``).** A mask drawn by hand or
made by a segmenter misses its object's edge by a few pixels. Short of it,
the seed labels the object's own rim background; copied into the next
frames, those labels lie on the object, at its depth and in its colour,
beside its newly revealed surfaces, and the fill spreads them over the far
side, frame after frame. Past it, the ground around the object is labelled
1 and copied on the same way. So the seed's edge is checked against frame
0: for 4-adjacent pixels :math:`p` (labelled 1) and :math:`q` (labelled 0)
it is *backed* where one of them is empty space (alpha below
``alpha_min``) and the other not, or where the depth :math:`D` steps,

.. math::

    |\log D(p) - \log D(q)| > \log(1 + \text{fill\_depth\_jump})

(the object's silhouette), or, with a contact zone, where :math:`q`'s
surface point lies in its slab (within :math:`h_c` above the support band
and :math:`\rho` of its axis, whatever way it faces) and the one-sided mean
colours differ, :math:`\|\bar c_1(p) - \bar c_0(q)\|_\infty >`
``color_tol`` (the base against the support; :math:`\bar c_l` is the mean
over the pixels labelled :math:`l` in the 3x3 window). There the
mask's edge is the scene's: a mask that follows it is right, and a band at
the contact would lose the base. With ``seed_band`` :math:`b`, the seed's
pixels within :math:`b` pixels of an edge pixel that is in no backed pair
(and whose :math:`(2b+1)^2` window holds both labels) are unknown in frame
0: no frame copies a label from them, and the solve reads none there. The
seed's medial pixels keep their label (a pixel labelled 1 whose Chebyshev
distance to the nearest pixel not labelled 1 is no less than its
neighbours'): a part thinner than the band, a leg or a pole, is narrowed
to its middle, not erased. A band that would still take more than half of
the seed's object pixels (a thin object seen whole: a rod, a cable) is
narrowed, :math:`b - 1` and so on, until it does not.

Frames are labelled in the order of :meth:`GeometricTracker._order`: always
the frame nearest to one already labelled, so a closed orbit is walked from
both sides of the reference.

Pixels with alpha below ``alpha_min`` are empty space and get 0 (nothing
there can be the object), but they are no evidence for the fill below
(unless ``fill_from_empty``): an object's translucent fringe, at the depth
of the surface next to it and often of its colour, would otherwise spread 0
over the object's own revealed surfaces (the far side of a scanned object
seen against empty space). Pixels no source sees (newly revealed surfaces,
blended depths at silhouettes) are decided by image evidence: a normalised
edge-aware filter (the recursive domain-transform filter of
``cv2.ximgproc.createDTFilter`` guided by the frame's RGB and log-depth:
positive weights ``k(p, q)`` decaying with the geodesic space + colour +
depth distance) spreads the decided labels along smooth, colour-homogeneous
surfaces,

.. math::

    \hat y(p) = \frac{\sum_q k(p,q)\, c(q)\, y(q)}{\sum_q k(p,q)\, c(q)},

with ``c`` = 1 on decided pixels and 0 elsewhere. A revealed pixel takes 1
when :math:`\hat y \ge 1 - \delta`, 0 when :math:`\hat y \le \delta`, given enough
support :math:`\sum_q k c \ge` ``min_support`` (relative to the kernel mass);
otherwise it stays NaN (unknown): the tracker does not guess.

**More passes of the fill (``fill_passes``, default 1).** A second pass runs
the filter again on the labels the first pass decided (same kernel,
:math:`y^{(t+1)}` = the decision rule applied to :math:`\hat y[y^{(t)}]` on
the pixels still unknown): pixels whose support was too small or too mixed
in the first pass are decided from their newly decided neighbours. More passes spread labels further from any
evidence; the default of one pass was chosen on benchmarks/bench_extract.py.

**Observed labels and fill decisions (``refill``).** A label is *observed*
when it comes from the seed through a chain of warps (steps 1-3), and *filled*
when the filter decided it in some view. Both are copied to later views, but
a filled label copied on as if it were observed turns one view's fill error
into the next view's evidence: at a contact line (a table leg standing in
grass, at low elevation) the filter labels a few foot pixels 0 (or the
ground between the legs 1), the next view copies them, its filter grows
them, and so on around the orbit; the errors then agree across views, so the
solver cannot vote them out. With ``refill`` (off by default) a copied label
remembers where it came from, and the first pass of each view's fill uses
its observed labels alone (:math:`c_{obs}` = 1 on observed pixels, 0
elsewhere),

.. math::

    \hat y_{obs}(p) = \frac{\sum_q k(p,q)\, c_{obs}(q)\, y(q)}{\sum_q k(p,q)\, c_{obs}(q)},

and decides, by the rule above, both the unknown pixels *and* the copied fill
decisions: a copied fill decision that the view's own observations
contradict is overridden, one they leave undecided keeps its label. The
second pass (use ``fill_passes=2`` with it: one pass alone leaves too much
undecided) then runs on every label so decided, so revealed surfaces far
from any observation (an object's far side) still grow band by band
around the orbit. Without ``refill`` copied fill decisions count as
observed. The tracker remembers which labels of the
masks it returned were filled (per frame, by weak reference), so the flat
clip's provenance carries over when it is passed as ``references`` for the
spiral; other references count as observed.
"""

from __future__ import annotations

import copy
import numbers
import weakref
from typing import TYPE_CHECKING, Any, Sequence

import cv2
import numpy as np

from .._validation import check_real
from ..errors import ValidationError
from ..geometry import unit_vector

if TYPE_CHECKING:
    from ..camera import Camera

__all__ = ["GeometricTracker", "warp_labels"]


def _pixel_rays(camera: Camera) -> np.ndarray:
    """Camera-frame rays (H, W, 3) with z = 1 through the pixel centres."""
    h, w = camera.image_shape
    x = (np.arange(w) + 0.5 - camera.cx) / camera.fx
    y = (np.arange(h) + 0.5 - camera.cy) / camera.fy
    rays = np.empty((h, w, 3))
    rays[..., 0] = x[None, :]
    rays[..., 1] = y[:, None]
    rays[..., 2] = 1.0
    return rays


def _world_points(camera: Camera, depth: np.ndarray, where: np.ndarray | None = None) -> np.ndarray:
    """World points of the pixels (all (H, W, 3), or (M, 3) at the bool mask ``where``) at rendered ``depth``."""
    d = np.asarray(depth, np.float64)
    if where is None:
        pc = _pixel_rays(camera) * d[..., None]
    else:
        # the rays of the chosen pixels alone (row-major, as a mask selects them): no (H, W, 3) array
        ys, xs = np.nonzero(where)
        pc = np.empty((ys.size, 3))
        pc[:, 0] = (xs + 0.5 - camera.cx) / camera.fx
        pc[:, 1] = (ys + 0.5 - camera.cy) / camera.fy
        pc[:, 2] = 1.0
        pc *= d[ys, xs][:, None]
    return (pc - camera.translation) @ camera.rotation  # R^T (p - t)


def _support_geometry(frame, normal: np.ndarray, point: np.ndarray, alignment: float):
    """Per pixel: world point ``X`` (H, W, 3); its height ``n . (X - x_s)``, facing along ``n``, rendered (H, W)."""
    world = _world_points(frame.camera, frame.depth)
    dx = np.zeros_like(world)
    dy = np.zeros_like(world)
    dx[:, 1:-1] = world[:, 2:] - world[:, :-2]
    dy[1:-1] = world[2:] - world[:-2]
    nu = np.cross(dx, dy)
    norm = np.linalg.norm(nu, axis=-1)
    facing = (np.abs(nu @ normal) >= alignment * np.maximum(norm, 1e-30)) & (norm > 0)
    return world, (world - point) @ normal, facing, np.asarray(frame.depth) > 0


def _on_support(frame, normal: np.ndarray, point: np.ndarray, alignment: float) -> np.ndarray:
    """(H, W) bool: surface points in the support band that face along ``normal`` (module docstring)."""
    _, height, facing, rendered = _support_geometry(frame, normal, point, alignment)
    return rendered & (height <= 0.0) & facing


def _keep_apart(lab: np.ndarray, held: np.ndarray, depth: np.ndarray, jump: float) -> None:
    """Give ``held`` 0s back to the unknown pixels of ``lab`` not connected to its object labels (in place).

    A pixel whose copied 0 was held back at the contact stays unknown only
    where it touches the object's surface: its 8-connected component of
    held-back unknown and object (> 0.5) pixels, cut where the depth steps
    by more than the relative ``jump`` to a 4-neighbour, holds an object
    pixel. Elsewhere (clutter near the footprint, cut off from the object by
    level ground or standing in front of it) the copy stands.
    """
    back = np.isnan(lab) & ~np.isnan(held)
    if not back.any():
        return
    obj = lab > 0.5
    ld = np.log(np.maximum(np.asarray(depth, np.float64), 1e-12))
    step = np.zeros(ld.shape, bool)
    big = np.log1p(jump)
    step[:, 1:] |= np.abs(np.diff(ld, axis=1)) > big
    step[:, :-1] |= np.abs(np.diff(ld, axis=1)) > big
    step[1:] |= np.abs(np.diff(ld, axis=0)) > big
    step[:-1] |= np.abs(np.diff(ld, axis=0)) > big
    _, comp = cv2.connectedComponents(((back | obj) & ~step).astype(np.uint8), connectivity=8)
    touching = np.zeros(int(comp.max()) + 1, bool)
    touching[np.unique(comp[obj])] = True
    give = back & (~touching[comp] | step)
    lab[give] = held[give]


def _whole(name: str, value, lo: int) -> int:
    """``value`` as an int >= ``lo``: 3.0 is 3; 2.5, True and a value below ``lo`` are refused, not truncated."""
    if (isinstance(value, bool) or not isinstance(value, numbers.Real) or not float(value).is_integer()
            or value < lo):
        raise ValidationError(f"{name} must be a whole number >= {lo}, got {value!r}")
    return int(value)


def _mixed(labels: np.ndarray, band: int) -> np.ndarray:
    """(H, W) bool: the pixels whose (2 ``band`` + 1)^2 window holds both a 0 and a 1 label."""
    k = np.ones((2 * band + 1, 2 * band + 1), np.uint8)
    return (cv2.dilate((labels == 1).astype(np.uint8), k) > 0) & (cv2.dilate((labels == 0).astype(np.uint8), k) > 0)


def _core(labels: np.ndarray, band: int) -> np.ndarray:
    """Labels with a band of ``band`` px on each side of every 0/1 boundary set to NaN."""
    if band <= 0:
        return labels
    out = labels.copy()
    out[_mixed(labels, band)] = np.nan
    return out


def _side_mean(rgb: np.ndarray, side: np.ndarray) -> np.ndarray:
    """(H, W, 3): the mean colour of the ``side`` pixels in the 3x3 window about each pixel (0 where there are none)."""
    k = np.ones((3, 3), np.float32)
    count = cv2.filter2D(side.astype(np.float32), -1, k, borderType=cv2.BORDER_CONSTANT)
    total = cv2.filter2D(np.asarray(rgb, np.float32) * side[..., None], -1, k, borderType=cv2.BORDER_CONSTANT)
    return total / np.maximum(count, 1.0)[..., None]


def _unbacked_edge(labels: np.ndarray, depth: np.ndarray, empty: np.ndarray, rgb: np.ndarray, jump: float,
                   color_tol: float | None, slab: np.ndarray | None) -> np.ndarray:
    """(H, W) bool: the pixels on the labels' 0/1 edge that frame 0 does not back.

    See the module docstring (``seed_band``): a pair of 4-adjacent pixels
    across the edge is backed where one of them is ``empty`` space and the
    other not, by a relative depth step above ``jump``, or in the contact
    ``slab`` (None: none) by a one-sided mean colour difference above
    ``color_tol`` (None: no such rule). A pixel in a backed pair is backed.
    """
    fg, bg = labels == 1, labels == 0
    log_depth = np.log(np.maximum(np.asarray(depth, np.float64), 1e-12))
    step = np.log1p(jump)
    by_colour = slab is not None and color_tol is not None
    if by_colour:
        inner, outer = _side_mean(rgb, fg), _side_mean(rgb, bg)
    backed = np.zeros(labels.shape, bool)
    loose = np.zeros(labels.shape, bool)
    h, w = labels.shape
    for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        # p: a pixel labelled 1; q: its neighbour at (dy, dx), labelled 0
        p = (slice(max(-dy, 0), h - max(dy, 0)), slice(max(-dx, 0), w - max(dx, 0)))
        q = (slice(max(dy, 0), h - max(-dy, 0)), slice(max(dx, 0), w - max(-dx, 0)))
        pair = fg[p] & bg[q]
        ok = (np.abs(log_depth[p] - log_depth[q]) > step) | (empty[p] != empty[q])
        if by_colour:
            ok |= slab[q] & (np.abs(inner[p] - outer[q]).max(axis=-1) > color_tol)
        for side in (p, q):
            backed[side] |= pair & ok
            loose[side] |= pair & ~ok
    return loose & ~backed


def _near_edge(edge: np.ndarray, labels: np.ndarray, band: int) -> np.ndarray:
    """(H, W) bool: the pixels within ``band`` px of an ``edge`` pixel and with both labels in their window.

    The window is (2 ``band`` + 1)^2 pixels, as in :func:`_mixed`.
    """
    k = np.ones((2 * band + 1, 2 * band + 1), np.uint8)
    return (cv2.dilate(edge.astype(np.uint8), k) > 0) & _mixed(labels, band)


def _medial(fg: np.ndarray, reach: int) -> np.ndarray:
    """(H, W) bool: the ``fg`` pixels whose Chebyshev distance to the nearest other pixel, capped at ``reach``,
    is no less than their neighbours' (pixels outside the image do not count as other)."""
    inside = np.zeros(fg.shape, np.float32)
    core = fg.astype(np.uint8)
    for _ in range(reach):
        inside += core
        core = cv2.erode(core, np.ones((3, 3), np.uint8))  # the default border: outside counts as fg
    return fg & (inside >= cv2.dilate(inside, np.ones((3, 3), np.uint8)))


def warp_labels(dst, src, src_labels: np.ndarray, *, alpha_min: float = 0.5,
                depth_tol: float = 0.01, color_tol: float | None = None, max_step: float = 0.1,
                pixels=None) -> np.ndarray:
    """Backward-warp labels of frame ``src`` into frame ``dst`` through rendered depth.

    Parameters
    ----------
    dst, src : frames with ``depth`` (H, W), ``alpha`` (H, W), ``camera``
    src_labels : (Hs, Ws) float array, NaN = unknown
    alpha_min, depth_tol : float
        Opacity needed for a pixel to be a surface; relative z-test tolerance.
    max_step : float
        The 2x2 depth range is used only where it spans at most this
        fraction of the depth (a smooth, possibly oblique surface); elsewhere
        (silhouettes) the z-test uses the nearest pixel alone.
    color_tol : float or None
        Photometric check (frames then need ``rgb``): the label is copied only
        when the two pixels' colours differ by at most this much in every
        channel. It separates surfaces that meet at equal depth (an object
        standing on the ground), which the z-test cannot.
    pixels : (H, W) bool, optional
        Warp only these ``dst`` pixels (the others are NaN): the tracker
        asks each further source only for the pixels still unknown.

    Returns
    -------
    (H, W) float64: the label seen at each ``dst`` pixel's surface point in
    ``src`` (nearest pixel), NaN where ``src`` does not see that point or has
    no label.
    """
    cam, scam = dst.camera, src.camera
    h, w = cam.image_shape
    sh, sw = scam.image_shape
    d = np.asarray(dst.depth, np.float64)
    valid = (np.asarray(dst.alpha) >= alpha_min) & (d > 0)
    if pixels is not None:
        valid &= np.asarray(pixels, dtype=bool)
    out = np.full((h, w), np.nan)
    if not valid.any():
        return out
    world = _world_points(cam, d, valid)
    uv, z = scam.project(world)
    ok = np.isfinite(uv[:, 0]) & np.isfinite(uv[:, 1]) & (z > scam.near)
    px = np.floor(np.where(ok, uv[:, 0], -1)).astype(np.int64)
    py = np.floor(np.where(ok, uv[:, 1], -1)).astype(np.int64)
    ok &= (px >= 0) & (px < sw) & (py >= 0) & (py < sh)
    i = np.nonzero(ok)[0]
    # the source images flat, as stored: every lookup below is one gather at a flat pixel index (a
    # gathered float32 widens exactly, so no image-long float64 copy is needed)
    sdep = np.asarray(src.depth).reshape(-1)
    salp = np.asarray(src.alpha).reshape(-1)
    zi = z[i]
    tol = depth_tol * zi
    at = py[i] * sw + px[i]
    surface = salp[at] >= alpha_min
    near = np.abs(zi - sdep[at]) <= tol
    seen = surface & near
    # Where the nearest pixel is a surface at another depth: z-test against
    # the depths of the 2x2 pixel centres around p' (their range brackets the
    # surface at p'); a nearest-pixel test fails in bands on oblique
    # surfaces, where depth changes by a lot within one pixel.
    b = np.flatnonzero(surface & ~near)
    fx = np.floor(uv[i[b], 0] - 0.5).astype(np.int64)
    fy = np.floor(uv[i[b], 1] - 0.5).astype(np.int64)
    lo = np.full(b.size, np.inf)
    hi = np.full(b.size, -np.inf)
    cols = [np.clip(fx + ox, 0, sw - 1) for ox in (0, 1)]
    for oy in (0, 1):
        row = np.clip(fy + oy, 0, sh - 1) * sw
        for qx in cols:
            q = row + qx
            dq = sdep[q]
            good = (salp[q] >= alpha_min) & (dq > 0)
            # a pixel that is no surface leaves the bracket as it is (min with +inf, max with -inf)
            np.minimum(lo, np.where(good, dq, np.inf), out=lo)
            np.maximum(hi, np.where(good, dq, -np.inf), out=hi)
    # The bracket only stands in for the surface where it is smooth: across a
    # silhouette it spans foreground to background and would accept points
    # hidden behind the foreground.
    zb, tb = zi[b], tol[b]
    seen[b] = ((hi - lo) <= max_step * zb) & (zb >= lo - tb) & (zb <= hi + tb)
    if color_tol is not None:
        # compared only where the z-test kept the pixel, one channel at a time (every channel within
        # color_tol is the largest within it), in float64 (exact: the images are float32 or float64)
        j = np.flatnonzero(seen)
        c_dst, c_src = np.asarray(dst.rgb).reshape(-1), np.asarray(src.rgb).reshape(-1)
        p_dst, p_src = 3 * np.flatnonzero(valid)[i[j]], 3 * at[j]
        close = np.ones(j.size, bool)
        for c in range(3):
            close &= np.abs(c_dst[p_dst + c].astype(np.float64) - c_src[p_src + c]) <= color_tol
        seen[j] = close
    vals = np.full(len(z), np.nan)
    vals[i[seen]] = np.asarray(src_labels, np.float64).reshape(-1)[at[seen]]
    out[valid] = vals
    return out


class GeometricTracker:
    r"""Model-free :class:`~seed2gs_inverse.frontend.base.Tracker` for rendered clips.

    It also takes a support plane
    (:class:`~seed2gs_inverse.frontend.base.SupportPlaneTracker`) and the
    contact zone above it
    (:class:`~seed2gs_inverse.frontend.base.ContactZoneTracker`), fills
    one frame's unknown labels on request
    (:class:`~seed2gs_inverse.frontend.base.LabelFiller`) and declares
    ``wants_regularizer``: pixels it cannot decide stay unknown (NaN), for
    the graph regulariser of the solve to decide.

    Parameters
    ----------
    alpha_min : float
        Rendered alpha below which a pixel is empty space (label 0), in (0, 1).
    depth_tol : float
        Relative z-test tolerance of the warp (1 % of depth), > 0.
    fill : bool
        Decide pixels no source sees with the edge-aware filter.
    fill_radius : float
        Spatial sigma of the filter as a fraction of the image diagonal, > 0.
    fill_sigma_color : float
        Colour sigma of the filter (RGB in [0, 1]), > 0.
    fill_depth_jump : float
        Relative depth step that the filter weighs like a colour step of
        ``fill_sigma_color`` (3 %): labels do not spread across silhouettes.
    decisive : float
        :math:`\delta` in [0, 0.5): a revealed pixel is labelled only when the
        filtered value is within :math:`\delta` of 0 or 1. A stricter fill
        leaves more to the 3D graph regulariser of
        :func:`~seed2gs_inverse.pipeline.extract.extract`; 0.2 was chosen on
        benchmarks/bench_extract.py.
    min_support : float
        Minimum normalised weight of decided pixels around a revealed pixel, in [0, 1).
    boundary_band : int
        Source labels within this many pixels of a 0/1 boundary are not
        copied (treated as unknown): a source boundary is only accurate to a
        pixel, and copying it would let errors at silhouettes and contact
        lines grow from view to view; the filter decides those pixels from
        the target frame's own colour edges instead. Default 0 (off): the
        photometric check already stops labels from crossing contact lines,
        and a band removes thin parts of small objects.
    color_tol : float or None
        Photometric consistency of a copied label (max per-channel RGB
        difference, 0.15), see :func:`warp_labels`; None disables it.
    max_sources : int
        Source frames tried per pixel: the seed frame, then the
        ``max_sources - 1`` labelled views with the nearest camera centres
        (earlier frames of the clip and any ``references``).
    refill : bool
        The first fill pass of each view uses its observed labels only and
        re-decides the fill decisions copied from other views (module
        docstring), so fill errors at contact lines do not drift around the
        orbit. Use with ``fill_passes=2``. False (default): copied fill
        decisions count as observed; the support rule (``support_plane``)
        stops the errors at contact lines that refill addresses, and the
        default was chosen on benchmarks/bench_extract.py.
    fill_from_empty : bool
        Let the empty pixels (alpha below ``alpha_min``, label 0) vote in the
        fill, as observed background. False (default): they are no evidence
        for the surfaces beside them (module docstring).
    support_plane : (normal, point) or None
        The support band :math:`n \cdot (x - x_s) \le 0` under the object
        (module docstring): its pixels that face along ``normal`` are
        labelled 0 in every frame but the seed's. None (default): no such
        rule. :func:`~seed2gs_inverse.pipeline.extract.extract` passes the
        band of :func:`~seed2gs_inverse.pipeline.support.support_surface`
        to a tracker without one (``ExtractSettings.support_background``).
    support_alignment : float
        :math:`|n \cdot \nu|` a support pixel needs, in (0, 1] (0.8: the
        surface within about 37 degrees of level).
    fill_passes : int
        Passes of the fill per view (module docstring), >= 1; one pass
        without ``refill`` was chosen on benchmarks/bench_extract.py.
    contact_zone : (height, radius) or None
        :math:`(h_c, \rho)`, the contact zone's height above the support
        band's top and its radius about the axis through the plane's point
        (scene units, both >= 0; module docstring); used only with a
        ``support_plane``. None (default): unset, and
        :func:`~seed2gs_inverse.pipeline.extract.extract` sets it with the
        support plane (:meth:`~seed2gs_inverse.pipeline.support.SupportSurface.contact_zone`);
        a zero height or radius: no contact zone.
    seed_band : int or None
        The seed mask's pixels within this many pixels of an edge that frame
        0 does not back are unknown (NaN) in frame 0, as the first source
        and as frame 0's mask (module docstring), >= 0; 0: the seed as
        given. None (default): unset, which tracks as 0, and
        :func:`~seed2gs_inverse.pipeline.extract.extract` sets it from
        ``ExtractSettings.mask_tolerance`` for a mask or text prompt (a
        mask drawn or made by a segmenter, a few pixels off its object's
        edge) and to 0 for a box or point prompt (a seed cut from the scene).

    Raises
    ------
    ValidationError
        Any parameter out of its range.
    """

    #: Pixels no view decides stay NaN: the solve's graph regulariser decides them
    #: (:func:`~seed2gs_inverse.frontend.base.wants_regularizer`).
    wants_regularizer = True

    def __init__(self, alpha_min: float = 0.5, depth_tol: float = 0.01, fill: bool = True,
                 fill_radius: float = 0.1, fill_sigma_color: float = 0.15, decisive: float = 0.2,
                 min_support: float = 0.02, max_sources: int = 4, boundary_band: int = 0,
                 color_tol: float | None = 0.15, fill_depth_jump: float = 0.03, refill: bool = False,
                 fill_passes: int = 1, support_plane=None, support_alignment: float = 0.8,
                 fill_from_empty: bool = False, contact_zone=None, seed_band: int | None = None):
        # NaN fails every range check: it is refused like any other value out of range.
        self.alpha_min = check_real("alpha_min", alpha_min, lo=0, hi=1, lo_open=True, hi_open=True)
        self.depth_tol = check_real("depth_tol", depth_tol, lo=0, lo_open=True)
        self.decisive = check_real("decisive", decisive, lo=0, hi=0.5, hi_open=True)
        self.fill_radius = check_real("fill_radius", fill_radius, lo=0, lo_open=True)
        self.fill_sigma_color = check_real("fill_sigma_color", fill_sigma_color, lo=0, lo_open=True)
        self.min_support = check_real("min_support", min_support, lo=0, hi=1, hi_open=True)
        self.color_tol = check_real("color_tol", color_tol, lo=0, optional=True)
        self.max_sources = _whole("max_sources", max_sources, 1)
        self.boundary_band = _whole("boundary_band", boundary_band, 0)
        self.seed_band = None if seed_band is None else _whole("seed_band", seed_band, 0)
        self.fill_depth_jump = check_real("fill_depth_jump", fill_depth_jump, lo=0, lo_open=True)
        self.fill_passes = _whole("fill_passes", fill_passes, 1)
        self.support_alignment = check_real("support_alignment", support_alignment, lo=0, hi=1, lo_open=True)
        self.fill = bool(fill)
        self.refill = bool(refill)
        self.fill_from_empty = bool(fill_from_empty)
        self.support_plane = self._plane(support_plane)
        self.contact_zone = None if contact_zone is None else self._zone(contact_zone)
        # id(frame) -> (weak reference to the frame, (H, W) bool: label filled,
        # not observed) for the masks this tracker returned (module docstring).
        self._filled = {}

    def track(self, frames: Sequence[Any], seed_mask: np.ndarray, references: Sequence = ()) -> list:
        """Propagate ``seed_mask`` (frame 0) along ``frames``; float32 masks, NaN = unknown.

        ``references`` are already labelled ``(frame, mask)`` pairs (e.g. the
        flat clip when tracking the spiral): extra sources for step 3, used
        like earlier frames of this clip.
        """
        frames = list(frames)
        if not frames:
            raise ValidationError("tracker: the clip has no frames")
        for k, f in enumerate(frames):
            for attr in ("rgb", "depth", "alpha", "camera"):
                if not hasattr(f, attr):
                    raise ValidationError(f"tracker: frame {k} has no '{attr}'")
            hw = f.camera.image_shape
            if np.asarray(f.depth).shape != hw or np.asarray(f.alpha).shape != hw:
                raise ValidationError(f"tracker: frame {k} depth/alpha do not match its camera {hw}")
        seed = np.asarray(seed_mask, dtype=np.float64)
        if seed.shape != frames[0].camera.image_shape:
            raise ValidationError(f"tracker: seed mask has shape {seed.shape}, frame 0 is "
                                  f"{frames[0].camera.image_shape}")
        pool = []
        for j, (f, m) in enumerate(references):
            m = np.asarray(m, np.float64)
            if m.shape != f.camera.image_shape:
                raise ValidationError(f"tracker: reference {j} mask has shape {m.shape}, its frame is "
                                      f"{f.camera.image_shape}")
            pool.append((f, m))
        # A drawn or segmenter-made mask is accurate to a few pixels only: where the scene does not
        # back its edge, the band is no evidence (a 0 on the object's own rim, copied on, is filled
        # over its revealed far side).
        seed = np.where(np.isnan(seed), np.nan, (seed > 0.5).astype(np.float64))
        if self.seed_band:
            seed[self._seed_band_pixels(frames[0], seed)] = np.nan
        self._filled = {i: e for i, e in self._filled.items() if e[0]() is not None}
        # Labels as warped: 0 / 1 where observed, 0.25 / 0.75 where a fill
        # decided them (their provenance travels with the copy).
        pool = [(f, self._encode(m, self._filled_mask(f))) for f, m in pool]
        masks = [None] * len(frames)
        masks[0] = seed.astype(np.float32)
        coded = [None] * len(frames)
        coded[0] = seed
        centers = np.array([f.camera.center for f in frames])
        done = [0]
        for k in self._order(centers):
            f = frames[k]
            # Sources: the seed frame first (no drift), then the labelled
            # views nearest to this one (best-conditioned warps).
            cands = pool + [(frames[j], coded[j]) for j in done[1:]]
            dist = [np.linalg.norm(g.camera.center - f.camera.center) for g, _ in cands]
            order = np.argsort(dist, kind="stable")[: max(self.max_sources - 1, 0)]
            lab = np.full(f.camera.image_shape, np.nan)
            seen_as_object = None  # the seed frame's 1 labels: never overruled by the support rule
            on, contact, _ = self._support_pixels(f)
            held = None if contact is None else np.full(lab.shape, np.nan)  # the 0s not copied at the contact
            for src, src_mask in [(frames[0], seed)] + [cands[i] for i in order]:
                src_mask = _core(src_mask, self.boundary_band)
                todo = np.isnan(lab)
                if not todo.any():
                    break
                w = warp_labels(f, src, src_mask, alpha_min=self.alpha_min, depth_tol=self.depth_tol,
                                color_tol=self.color_tol, pixels=todo)
                if seen_as_object is not None and contact is not None:
                    bg = contact & (w < 0.5) & np.isnan(held)
                    held[bg] = w[bg]
                    w[contact & (w < 0.5)] = np.nan  # a 0 copied at the contact: not evidence (docstring)
                lab[todo] = w[todo]
                if seen_as_object is None:
                    seen_as_object = w == 1
            if held is not None:
                _keep_apart(lab, held, f.depth, self.fill_depth_jump)
            copied_fill = (lab > 0) & (lab < 1)
            lab = np.where(np.isnan(lab), lab, (lab > 0.5).astype(np.float64))
            void = np.asarray(f.alpha) < self.alpha_min
            empty = void.copy()
            if on is not None:
                empty |= on if seen_as_object is None else on & ~seen_as_object
            lab[empty] = 0.0
            copied_fill &= ~empty
            observed = ~np.isnan(lab) & ~copied_fill
            if self.fill and (np.isnan(lab).any() or copied_fill.any()):
                filt = self._filter(np.asarray(f.rgb, np.float32), np.asarray(f.depth))
                if not self.fill_from_empty:
                    lab[void] = np.nan  # empty space is no evidence for the surfaces beside it
                for i in range(self.fill_passes):
                    if i == 0 and self.refill and copied_fill.any():
                        # pass 1: this view's observations re-decide the copied fill decisions
                        out = self._decide(filt, np.where(copied_fill, np.nan, lab))
                        keep = copied_fill & np.isnan(out)
                        out[keep] = lab[keep]
                        lab = out
                    elif np.isnan(lab).any():
                        lab = self._decide(filt, lab)
                lab[void] = 0.0
            masks[k] = lab.astype(np.float32)
            filled = ~observed & ~np.isnan(lab)
            coded[k] = self._encode(lab, filled if self.refill else None)
            if self.refill:
                try:
                    self._filled[id(f)] = (weakref.ref(f), filled)
                except TypeError:  # a frame type without weak references: its labels count as observed
                    pass
            done.append(k)
        return masks

    def _seed_band_pixels(self, frame, seed: np.ndarray) -> np.ndarray:
        """(H, W) bool: the seed's band in ``frame``, narrowed to keep half its object pixels (module docstring)."""
        edge = _unbacked_edge(seed, frame.depth, np.asarray(frame.alpha) < self.alpha_min, frame.rgb,
                              self.fill_depth_jump, self.color_tol, self._support_pixels(frame)[2])
        n_object = np.count_nonzero(seed == 1)
        for band in range(self.seed_band, 0, -1):
            out = _near_edge(edge, seed, band)
            if np.count_nonzero(out & (seed == 1)) <= n_object / 2:
                return out & ~_medial(seed == 1, band + 1)
        return np.zeros(seed.shape, bool)

    def _support_pixels(self, frame):
        """``(on, contact, slab)``: the frame's support pixels, its contact zone and the zone's slab.

        Each (H, W) bool, or None without a plane (all three) or without a
        contact zone (the last two); the contact zone is the slab's pixels
        that do not face along the plane's normal (module docstring).
        """
        if self.support_plane is None:
            return None, None, None
        normal, point = self.support_plane
        world, height, facing, rendered = _support_geometry(frame, normal, point, self.support_alignment)
        on = rendered & (height <= 0.0) & facing
        if self.contact_zone is None or min(self.contact_zone) <= 0:
            return on, None, None
        h_c, rho = self.contact_zone
        across = np.linalg.norm((world - point) - height[..., None] * normal, axis=-1)
        slab = rendered & (height <= h_c) & (across <= rho)
        return on, slab & ~facing, slab

    @staticmethod
    def _plane(plane):
        if plane is None:
            return None
        try:
            normal, point = plane
            x = np.asarray(point, dtype=np.float64)
        except (TypeError, ValueError):
            x = None
        if x is None or x.shape != (3,) or not np.all(np.isfinite(x)):
            raise ValidationError(f"support_plane must be (normal, point) with a finite 3-vector point, or None; "
                                  f"got {plane!r}")
        return unit_vector("support_plane normal", normal), x

    def _copy(self, **attrs) -> "GeometricTracker":
        """A copy of this tracker with ``attrs`` set and no filled-label record (the frames are another run's)."""
        out = copy.copy(self)
        out.__dict__.update(attrs)
        out._filled = {}
        return out

    def with_support_plane(self, normal, point) -> "GeometricTracker":
        """A copy of this tracker with ``support_plane=(normal, point)`` (this one is left as it is)."""
        return self._copy(support_plane=self._plane((normal, point)))

    def with_seed_band(self, band: int) -> "GeometricTracker":
        """A copy of this tracker with ``seed_band=band`` (this one is left as it is)."""
        return self._copy(seed_band=_whole("seed_band", band, 0))

    @staticmethod
    def _zone(zone) -> tuple:
        try:
            height, radius = zone
        except (TypeError, ValueError):
            raise ValidationError(f"contact_zone must be (height, radius) or None, got {zone!r}") from None
        return (check_real("contact_zone height", height, lo=0), check_real("contact_zone radius", radius, lo=0))

    def with_contact_zone(self, height: float, radius: float) -> "GeometricTracker":
        """A copy of this tracker with ``contact_zone=(height, radius)`` (this one is left as it is)."""
        return self._copy(contact_zone=self._zone((height, radius)))

    def _filled_mask(self, frame):
        """The filled-label mask this tracker recorded for ``frame`` (None: unknown, all observed)."""
        entry = self._filled.get(id(frame))
        if not self.refill or entry is None or entry[0]() is not frame:
            return None
        return entry[1]

    @staticmethod
    def _encode(labels, filled) -> np.ndarray:
        """Labels for warping: observed 0 / 1 as they are, filled ones as 0.25 / 0.75."""
        lab = np.asarray(labels, np.float64)
        if filled is None or np.asarray(filled).shape != lab.shape:
            return lab
        return np.where(filled & ~np.isnan(lab), 0.25 + 0.5 * lab, lab)

    @staticmethod
    def _order(centers: np.ndarray) -> list:
        """Frames 1..n-1 in the order they join the labelled set (Prim's rule).

        Each step labels the frame whose camera centre is nearest to an
        already labelled one, so propagation always takes the shortest hop:
        a closed flat orbit is walked from both sides of the reference (half
        the chain length, half the drift), a rising spiral in sequence.
        """
        n = len(centers)
        if n <= 1:
            return []
        d = np.linalg.norm(centers[:, None] - centers[None], axis=2)
        best = d[0].copy()
        left = set(range(1, n))
        order = []
        while left:
            k = min(left, key=lambda j: (best[j], j))
            order.append(k)
            left.remove(k)
            best = np.minimum(best, d[k])
        return order

    def fill_labels(self, rgb, depth, labels) -> np.ndarray:
        """Decide the NaN pixels of one frame's ``labels`` with ``fill_passes`` passes of the edge-aware filter.

        ``rgb`` (H, W, 3), ``depth`` (H, W) of the frame; returns new labels,
        NaN where the filter is not decisive.
        """
        lab = np.asarray(labels, np.float64)
        if np.asarray(depth).shape != lab.shape or np.asarray(rgb).shape[:2] != lab.shape:
            raise ValidationError(f"fill_labels: rgb {np.asarray(rgb).shape}, depth {np.asarray(depth).shape} and "
                                  f"labels {lab.shape} must share (H, W)")
        return self._fill(np.asarray(rgb, np.float32), np.asarray(depth), lab)

    def _fill(self, rgb: np.ndarray, depth: np.ndarray, lab: np.ndarray) -> np.ndarray:
        if not (~np.isnan(lab)).any():
            return lab
        filt = self._filter(rgb, depth)
        for _ in range(self.fill_passes):
            if not np.isnan(lab).any():
                break
            lab = self._decide(filt, lab)
        return lab

    def _filter(self, rgb: np.ndarray, depth: np.ndarray):
        """The frame's edge-aware filter (built once per frame, used by every pass)."""
        h, w = depth.shape
        sigma_s = max(1.0, self.fill_radius * float(np.hypot(h, w)))
        # Guide: RGB plus log-depth scaled so that a relative depth jump of
        # fill_depth_jump weighs like a colour step of fill_sigma_color; the
        # labels then spread along surfaces, not across silhouettes.
        d = np.asarray(depth, np.float64)
        logd = np.log(np.where(d > 0, d, 1.0))
        far = (logd[d > 0].max() + 1.0) if np.any(d > 0) else 0.0
        logd = np.where(d > 0, logd, far)
        guide = np.dstack([np.clip(rgb, 0, 1), logd * (self.fill_sigma_color / self.fill_depth_jump)])
        # Recursive domain-transform filter: positive weights that decay with
        # the geodesic (space + colour + depth) distance, O(pixels) for any radius.
        return cv2.ximgproc.createDTFilter(np.ascontiguousarray(guide, dtype=np.float32), sigma_s,
                                           self.fill_sigma_color, cv2.ximgproc.DTF_RF, 3)

    def _decide(self, filt, lab: np.ndarray) -> np.ndarray:
        """Decide the NaN pixels of ``lab`` from its decided ones with ``filt`` (module docstring)."""
        known = ~np.isnan(lab)
        if not known.any():
            return lab.copy()
        # numerator and denominator in one two-channel pass
        both = filt.filter(np.dstack([np.where(known, lab, 0.0), known]).astype(np.float32))
        fnum, fden = both[..., 0], both[..., 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            val = fnum / np.maximum(fden, 1e-12)
        # fden is the (space- and colour-weighted) fraction of decided pixels nearby.
        ok = ~known & (fden >= self.min_support)
        out = lab.copy()
        out[ok & (val >= 1 - self.decisive)] = 1.0
        out[ok & (val <= self.decisive)] = 0.0
        return out
