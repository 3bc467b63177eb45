"""The stages of Algorithm 1, each a function with explicit inputs and outputs, and their records.

:func:`~seed2gs_inverse.pipeline.extract.extract` runs them in this order;
each can be run, tested and timed on its own::

    render_reference   reference canvas I_r                       -> Rendering
    seed_from_prompt   seed mask m* (prompt / grounder; a point
                       prompt grows to the whole object in 3D, a
                       box prompt is cleaned to its main object)   -> (seed, prompt_info)
    reference_view     W(c_r) around the seed, at the lift size    -> ReferenceView
    lift_seed          seed lift (G0, o, extent)                   -> SeedLift
    orbit_views        orbit axis (orbit_axis: support plane, ...)
                       then VAAS: flat orbit + visibility-adaptive
                       ascending spiral, each frame with its W(c)  -> OrbitViews
    support_band       the support surface under the object, for
                       a tracker that takes a support plane        -> (SupportSurface or None, report)
    track_clips        the tracker propagates m* over both clips   -> list of (ClipFrame, mask)
    evidence_graph     Gaussian kNN graph around the object (when
                       smoothness > 0 or completion is on)         -> sparse (N, N) or None
    complete_masks     3D label completion of the unknown pixels
                       (completion="reference" / "tracked")        -> list of masks
    stack_operators    the supervision views' operators            -> OperatorStack
    solve_selection    solver (initialised from G0, graph-Laplacian
                       regulariser when smoothness > 0), faint
                       Gaussians follow their opaque neighbours,
                       threshold, kept where connected to G0 in 3D  -> Selection

The trackers are reached only through the protocols of
:mod:`seed2gs_inverse.frontend.base` (``Tracker``, and the optional
``SupportPlaneTracker`` and ``LabelFiller``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Sequence

import cv2
import numpy as np
import scipy.sparse as sp

from ..errors import ValidationError
from ..frontend.base import SupportPlaneTracker
from ..frontend.prompts import BoxPrompt, PointPrompt, seed_mask_from_prompt
from ..graph import _followed, apply_follow
from ..operators import OperatorStack, as_stack
from ..raster import FrozenScene, Renderer
from ..solvers import solve
from ..solvers._common import normalize_mask
from .box_object import box_object_mask
from .completion import (GRAPH_DEFAULTS, _enclosed_rows, _replace_rows, _weak_entries, complete_membership,
                         faint_follow_matrix, fill_unknown, follow_enclosed, follow_weak, object_graph,
                         tracked_membership)
from .point_object import point_object_mask
from .islands import seed_connected
from .local import Neighbourhood, neighbourhood
from .seed_lift import seed_lift
from .support import SUPPORT_DEFAULTS, support_surface
from .up_axis import WEAK_CONFIDENCE, camera_list, estimate_up, estimate_up_axis, flat_normals
from .vaas import ClipFrame, run_vaas

if TYPE_CHECKING:
    from ..camera import Camera
    from ..frontend.base import LabelFiller, Tracker
    from ..operators import Rendering, ViewOperator
    from ..progress import Progress
    from ..scene import GaussianScene
    from ..solvers import SolveResult
    from .seed_lift import SeedLift
    from .settings import ExtractSettings
    from .support import SupportSurface
    from .vaas import VAASPlan

__all__ = ["ReferenceView", "OrbitViews", "Selection", "render_reference", "seed_from_prompt", "reference_view",
           "lift_seed", "orbit_axis", "orbit_views", "support_band", "track_clips", "evidence_graph",
           "complete_masks", "stack_operators", "solve_selection", "view_caps"]


# -- stage records ------------------------------------------------------------------------------
@dataclass
class ReferenceView:
    """The reference view at the lift resolution: frame 0 of both clips and the first supervision view.

    Attributes
    ----------
    camera : Camera
        ``c_r`` scaled by ``scale`` (the camera itself when ``scale == 1``).
    scale : float
        Reference resolution relative to the camera (``max_reference_pixels`` cap).
    seed : (h, w) bool
        ``m*`` at that resolution.
    operator : ViewOperator
        ``W(c_r)`` composited in a box around the seed, with its rendering.
    """

    camera: Camera
    scale: float
    seed: np.ndarray
    operator: ViewOperator


@dataclass
class OrbitViews:
    """The VAAS clips, rendered: every frame carries its operator (``frame.operator``).

    Attributes
    ----------
    plan : VAASPlan
    flat, spiral : list of ClipFrame
        ``spiral`` is empty when the spiral is skipped. Frame 0 of each clip
        is the reference view (:class:`ReferenceView`).
    view_scale : float
        Orbit view resolution relative to the camera.
    up : (3,) float64
        The orbit axis used.
    up_info : dict
        :func:`orbit_axis`'s report: ``axis``, ``method``, ``confidence``, ``details``.
    size : (int, int) or None
        ``(width, height)`` of the orbit views (frame 0 of each clip, the
        reference view, has its own).
    """

    plan: VAASPlan
    flat: list
    spiral: list
    view_scale: float
    up: np.ndarray
    up_info: dict = field(default_factory=dict)
    size: tuple | None = None

    def clips(self) -> list:
        """``[("flat", frames), ("spiral", frames)]`` (no spiral entry when it was skipped)."""
        return [("flat", self.flat)] + ([("spiral", self.spiral)] if self.spiral else [])


@dataclass
class Selection:
    """The solve: its ``result``, the threshold tau and the selection.

    Attributes
    ----------
    result : SolveResult
        The solver's result; its ``q`` already carries the ``min_evidence``
        reset or the regulariser.
    q : (N,) float32
        ``result.q``, its faint Gaussians near the object set to their
        opaque neighbours' membership and the Gaussians the selection
        encloses to their nearest selected one's (with
        ``settings.follow_faint``), its unselected weak Gaussians to their
        strong neighbours' (with ``settings.follow_weak``), and
        set to 0 on the ``n_disconnected`` Gaussians of islands apart from
        G0 (with ``settings.seed_connected``).
    threshold : float
        tau.
    selected : (N,) bool
        ``q > tau``.
    n_disconnected : int
        Gaussians above tau in islands apart from G0, set to 0.
    follow : (N, N) sparse or None
        The faint Gaussians' rows (:func:`~.completion.faint_follow_matrix`)
        and the enclosed Gaussians' rows (:func:`~.completion.enclosed_by_selection`:
        weight 1 on the nearest selected Gaussian whose ``q`` the solver
        decided), applied to ``result.q`` (with ``settings.follow_faint``),
        and the weak Gaussians' rows (:func:`~.completion.follow_weak`, with
        ``settings.follow_weak``).
    """

    result: SolveResult
    q: np.ndarray
    threshold: float
    selected: np.ndarray
    n_disconnected: int = 0
    follow: sp.csr_matrix | None = None

    @property
    def n_weak_evidence(self) -> int:
        """Gaussians without real evidence (reset to the prior or decided by the regulariser)."""
        return int(self.result.info.get("n_weak_evidence", 0))


# -- pixel boxes and resolutions ----------------------------------------------------------------
def _resize_mask(mask: np.ndarray, shape: tuple) -> np.ndarray:
    """Area-average a boolean mask to ``shape`` (H, W) and threshold at 0.5."""
    h, w = shape
    if mask.shape == (h, w):
        return mask.astype(bool)
    m = cv2.resize(mask.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    return m > 0.5


def _view_scale(camera: Camera, scale: float, max_pixels: int | None) -> float:
    """``scale``, lowered so that ``camera.scaled(scale)`` has about ``max_pixels`` pixels (None: no cap).

    ``Camera.scaled`` rounds each side to whole pixels, so the count may pass
    ``max_pixels`` by up to a row and a column. Both are validated by
    :class:`~seed2gs_inverse.pipeline.settings.ExtractSettings`.
    """
    s = float(scale)
    if max_pixels is not None:
        s = min(s, np.sqrt(int(max_pixels) / (camera.width * camera.height)))
    return s


def view_caps(settings: ExtractSettings, camera: Camera, ref: ReferenceView, orbits: OrbitViews) -> dict:
    """``resolved["caps"]``: each view size that a pixel cap set below what was asked (JSON-ready).

    ``"orbit_views"`` when ``max_view_pixels`` lowered ``orbit_scale``,
    ``"reference_view"`` when ``max_reference_pixels`` lowered the camera's
    resolution; each ``{"size": [w, h], "scale", "asked", "cap", "limit"}``:
    the size and scale used, the scale asked for (``orbit_scale``; 1, the
    camera's resolution, for the reference view, which also gives the
    camera's ``camera_size``), the setting that capped it and its value.
    Empty when nothing was capped.
    """
    caps = {}
    if orbits.view_scale < settings.orbit_scale:
        caps["orbit_views"] = {"size": None if orbits.size is None else [int(v) for v in orbits.size],
                               "scale": float(orbits.view_scale),
                               "asked": float(settings.orbit_scale), "cap": "max_view_pixels",
                               "limit": settings.max_view_pixels}
    if ref.scale < 1.0:
        caps["reference_view"] = {"size": [ref.camera.width, ref.camera.height], "scale": float(ref.scale),
                                  "asked": 1.0, "camera_size": [camera.width, camera.height],
                                  "cap": "max_reference_pixels", "limit": settings.max_reference_pixels}
    return caps


def _mask_roi(mask: np.ndarray, margin: float = 0.25, pad: int = 8) -> tuple:
    """Box (x0, y0, x1, y1) around a mask, grown by ``margin`` of its size plus ``pad`` px."""
    ys, xs = np.nonzero(mask)
    h, w = mask.shape
    mx = int(margin * (xs.max() - xs.min() + 1)) + pad
    my = int(margin * (ys.max() - ys.min() + 1)) + pad
    return (max(int(xs.min()) - mx, 0), max(int(ys.min()) - my, 0),
            min(int(xs.max()) + 1 + mx, w), min(int(ys.max()) + 1 + my, h))


def _roi_box(camera: Camera, center: np.ndarray, radius: float, margin: float | None) -> tuple | None:
    """Pixel box (x0, y0, x1, y1) holding the projection of the sphere (center, margin * radius).

    The sphere is sampled densely (400 points) and the box grown by 2 px;
    None (the whole image) when ``margin`` is None or the camera is inside
    or near the sphere.
    """
    if margin is None:
        return None
    r = float(margin) * float(radius)
    c = np.asarray(center, dtype=np.float64)
    if camera.world_to_view(c[None])[0, 2] - r <= camera.near:
        return None
    k = np.arange(400) + 0.5
    phi = np.arccos(1 - 2 * k / 400)
    th = np.pi * (1 + 5 ** 0.5) * k
    pts = c + r * np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1)
    uv, _ = camera.project(pts)
    x0 = int(np.clip(np.floor(uv[:, 0].min()) - 2, 0, camera.width))
    x1 = int(np.clip(np.ceil(uv[:, 0].max()) + 2, 0, camera.width))
    y0 = int(np.clip(np.floor(uv[:, 1].min()) - 2, 0, camera.height))
    y1 = int(np.clip(np.ceil(uv[:, 1].max()) + 2, 0, camera.height))
    if x1 <= x0 or y1 <= y0:
        return (0, 0, 1, 1)
    return (x0, y0, x1, y1)


# -- the stages ---------------------------------------------------------------------------------
def render_reference(renderer: Renderer, camera: Camera) -> Rendering:
    """Stage 1: the reference canvas ``I_r`` (the full-resolution rendering of ``camera``).

    Raises
    ------
    ValidationError
        The camera sees (almost) nothing: max alpha < 0.05.
    """
    ref = renderer.render(camera)
    if float(ref.alpha.max()) < 0.05:
        raise ValidationError(
            f"the reference camera sees nothing of the scene (max rendered alpha "
            f"{float(ref.alpha.max()):.3g}); check the camera pose and the scene's coordinates")
    return ref


def seed_from_prompt(prompt: Any, reference: Rendering, grounder=None, *, point_mode: str = "region",
                     scene: GaussianScene | None = None, camera: Camera | None = None,
                     mode: str = "classic") -> tuple[np.ndarray, dict]:
    """Stage 2: the seed mask ``m*`` (H, W) bool of ``prompt`` on the reference canvas, and the prompt info.

    See :func:`~seed2gs_inverse.frontend.prompts.seed_mask_from_prompt`; text
    prompts need ``grounder``. With ``point_mode="object"`` a
    :class:`~seed2gs_inverse.frontend.prompts.PointPrompt` returns the whole
    clicked object instead of its colour region: the region is lifted,
    grown in 3D down to the support plane and projected back
    (:func:`~seed2gs_inverse.pipeline.point_object.point_object_mask`, which
    needs the ``scene``, the reference ``camera`` and the rasterization
    ``mode``); ``prompt_info`` then carries its growth facts. Given the
    ``scene`` and ``camera``, a
    :class:`~seed2gs_inverse.frontend.prompts.BoxPrompt`'s GrabCut seed is
    cleaned to the box's main object: the pixels of other objects and of the
    ground away from it leave the seed, those of the main object join it
    (:func:`~seed2gs_inverse.pipeline.box_object.box_object_mask`;
    ``prompt_info`` gains ``n_dropped_pixels``, ``n_added_pixels`` (the
    pixels of the main object GrabCut left out) and the cleaning's facts).

    Raises
    ------
    ValidationError
        The seed covers only empty space (rendered alpha <= 0.05), or
        ``point_mode`` is not ``"object"`` or ``"region"``.
    """
    if point_mode == "object" and isinstance(prompt, PointPrompt):
        if scene is None or camera is None:
            raise ValidationError("seed_from_prompt: point_mode='object' needs the scene and the reference camera")
        po = point_object_mask(scene, camera, prompt.points, prompt.labels, rendering=reference, mode=mode,
                               region=prompt)
        seed, info = po.mask, po.info
    elif point_mode not in ("object", "region"):
        raise ValidationError(f"point_mode must be 'object' or 'region', got {point_mode!r}")
    else:
        seed, info = seed_mask_from_prompt(prompt, reference.rgb, depth=reference.depth, alpha=reference.alpha,
                                           grounder=grounder)
        if isinstance(prompt, BoxPrompt) and scene is not None and camera is not None:
            box = box_object_mask(scene, camera, seed, reference.depth, prompt.box, mode=mode)
            seed, info = box.mask, {**info, **box.info}
    if not (seed & (reference.alpha > 0.05)).any():
        raise ValidationError("the seed mask covers only empty space in the reference view: "
                              "it does not touch the scene")
    return seed, info


def reference_view(renderer: Renderer, camera: Camera, seed: np.ndarray,
                   max_reference_pixels: int | None) -> ReferenceView:
    """Stage 3: ``W(c_r)`` at the camera's resolution capped at ``max_reference_pixels``.

    The seed is area-averaged to that resolution (threshold 0.5) and the
    operator composited only in its box grown by a quarter of its size plus
    8 px (:func:`_mask_roi`): the lift needs no more, and the same operator
    is frame 0 of both clips.

    Raises
    ------
    ValidationError
        The seed vanishes at that resolution.
    """
    scale = _view_scale(camera, 1.0, max_reference_pixels)
    cam = camera if scale == 1.0 else camera.scaled(scale)
    seed_ref = _resize_mask(seed, cam.image_shape)
    if not seed_ref.any():
        raise ValidationError(
            f"the seed mask ({int(seed.sum())} px) vanishes at the lift resolution "
            f"{cam.width}x{cam.height}; raise max_reference_pixels or give a larger mask")
    return ReferenceView(cam, scale, seed_ref, renderer.operator(cam, roi=_mask_roi(seed_ref)))


def lift_seed(scene: GaussianScene, ref: ReferenceView, lift_options: dict | None = None) -> SeedLift:
    """Stage 4: the seed lift (support G0, centre ``o``, extent) from the reference view's W and depth."""
    op = ref.operator
    return seed_lift(scene, ref.camera, ref.seed, op.rendering.depth, op.W, **dict(lift_options or {}))


def orbit_axis(up, scene: GaussianScene | FrozenScene, base: Camera, ref: ReferenceView, lift: SeedLift,
               up_cameras: Sequence[Camera] | None = None) -> dict:
    """The VAAS axis of the ``up`` setting, as a report dict ``{axis, method, confidence, details}``.

    ``"auto"``: :func:`~seed2gs_inverse.pipeline.up_axis.estimate_up_axis`
    (support plane under the lift's G0, scene plane, the no-roll prior of
    ``base`` and the capture cameras ``up_cameras``); a weak estimate warns,
    naming ``--up``. ``"level"``: the image-up of ``base`` with its pitch
    removed, weighted by the reference view's operator
    (:func:`~seed2gs_inverse.pipeline.up_axis.estimate_up`); ``"camera"``: the
    image-up itself; a vector: that vector, normalised. ``confidence`` is
    None unless estimated. A frozen ``scene`` lets ``"auto"`` find the
    Gaussians about the object through its spatial index. The warnings name
    the caller of :func:`orbit_views` (``stacklevel=4``).
    """
    if isinstance(up, str) and up == "auto":
        if up_cameras is not None:
            up_cameras = camera_list(up_cameras, "up_cameras")  # read once: a generator too
        est = estimate_up_axis(scene, base, support=lift.g0, center=lift.center, radius=lift.radius,
                               cameras=up_cameras)
        if est.weak:
            warnings.warn(est.warning(), stacklevel=4)
        return {**est.summary(), "warning": est.warning()}
    if isinstance(up, str) and up == "level":
        plain = getattr(scene, "scene", scene)  # a FrozenScene's GaussianScene
        axis = estimate_up(plain, base, weights=np.asarray(ref.operator.W.sum(axis=0)).ravel())
        return {"axis": np.asarray(axis, float).tolist(), "method": "level", "confidence": None, "details": {}}
    if isinstance(up, str) and up == "camera":
        return {"axis": base.up.tolist(), "method": "camera", "confidence": None, "details": {}}
    axis = np.asarray(up, dtype=np.float64)  # validated by ExtractSettings
    axis = axis / np.linalg.norm(axis)
    if axis @ base.up < -0.5:
        # y-up against y-down (OpenGL against OpenCV/COLMAP) is an easy mistake, and a support
        # "below" an upside-down object would be looked for above it. (From a camera looking
        # straight down the true up is across the image: hence more than 120 degrees, not 90.)
        warnings.warn(f"up {np.round(axis, 3).tolist()} points down in the reference view; the orbits "
                      f"and the support surface take it as given (negate it if the scene's up is the "
                      f"other way)", stacklevel=4)
    return {"axis": axis.tolist(), "method": "user", "confidence": None, "details": {}}


def _clip_frame(op: ViewOperator, clip: str, index: int) -> ClipFrame:
    r = op.rendering
    return ClipFrame(r.rgb, r.depth, r.alpha, op.camera, clip, index, operator=op)


def _level(frozen: FrozenScene, up: np.ndarray, center: np.ndarray, reach: float) -> np.ndarray:
    """(N,) bool: the flat, level Gaussians of ``frozen``'s scene about ``up`` within ``reach`` of ``center``.

    Flat and level as :func:`~.support.support_surface` takes them
    (:func:`~.up_axis.flat_normals`, ``|n . up|`` at least its default
    ``min_alignment``): the ground, table tops and seats that the orbit
    views' near cut leaves in place. Only those within ``reach`` of the
    object are looked at (:func:`~.local.neighbourhood`): the near cut of a
    view at distance ``D`` from the object removes Gaussians in front of
    the object inside the view's cone, which lie within ``2 D`` of it.
    """
    scene = frozen.scene
    idx = neighbourhood(frozen, center, reach)  # through the frozen scene's spatial index
    normals, flat = flat_normals(scene, idx)
    out = np.zeros(len(scene), bool)
    out[idx] = flat & (np.abs(normals @ up) >= SUPPORT_DEFAULTS["min_alignment"])
    return out


def orbit_views(renderer: Renderer, camera: Camera, ref: ReferenceView, lift: SeedLift,
                settings: ExtractSettings, progress: Progress | None = None,
                up_cameras: Sequence[Camera] | None = None) -> OrbitViews:
    """Stage 5: the orbit axis (:func:`orbit_axis`), then VAAS (flat orbit, visibility, ascending spiral).

    Each view is rendered with its operator. The orbit views have the
    camera's geometry at ``view_scale`` (``orbit_scale`` capped at
    ``max_view_pixels``), zoomed to ``zoom_margin * extent`` about ``o``,
    composited only inside the projected sphere of ``roi_margin * extent``
    and, with ``cull``, rasterized from the Gaussians of that cone (cut at
    ``cull_far * extent`` behind ``o``, and with ``near_margin`` at
    ``near_margin * extent`` before it). Frame 0 of each clip is the
    reference view itself (``ref``, at its own resolution). ``progress``
    counts one step per view rendered.
    """
    s = settings
    scene = renderer.scene
    view_scale = _view_scale(camera, s.orbit_scale, s.max_view_pixels)
    base = camera.scaled(view_scale)  # the orbits' base camera (geometry + view resolution)
    up_info = orbit_axis(s.up, renderer.frozen, base, ref, lift, up_cameras)
    up = np.asarray(up_info["axis"], dtype=np.float64)

    # The near cut leaves level surfaces in place: the ground cut in front of the object shows its
    # edge at the object's depth next to the object's base, where the tracker takes it for the object.
    # Not only those below the object's centre: an axis given upside down would cut the ground.
    spare = None
    if s.cull and s.near_margin is not None:
        # every orbit camera keeps the reference's distance to o (vaas.orbit_cameras)
        spare = _level(renderer.frozen, up, lift.center, 2.0 * float(np.linalg.norm(base.center - lift.center)))

    def view(cam: Camera, clip: str, k: int) -> ClipFrame:
        if cam is base:
            op = ref.operator  # frame 0 is the reference view itself, at the lift resolution
        else:
            roi = _roi_box(cam, lift.center, lift.radius, s.roi_margin)
            dist = float(np.linalg.norm(cam.center - lift.center))
            far = None if not s.cull or s.cull_far is None else dist + s.cull_far * lift.radius
            near = None if not s.cull or s.near_margin is None else dist - s.near_margin * lift.radius
            op = renderer.operator(cam, roi=roi, min_weight=s.min_weight, cull=s.cull, far=far, near=near,
                                   spare=spare)
        if progress is not None:
            progress.update()
        return _clip_frame(op, clip, k)

    g0 = np.flatnonzero(lift.g0)  # one pass over the mask; the arrays are then read at G0's rows only
    sigma = scene.subset(g0).scales.max(axis=1)  # G0's own: the scene's activations cost O(N)
    plan, flat, spiral = run_vaas(
        scene.means[g0], sigma, base, lift.center, view, n_views=s.n_views, a_max_deg=s.a_max_deg,
        gamma=s.gamma, skip_deg=s.skip_deg, profile=s.profile, max_elevation_deg=s.max_elevation_deg,
        fit_radius=None if s.zoom_margin is None else s.zoom_margin * lift.radius, up=up)
    return OrbitViews(plan, flat, spiral, view_scale, up, up_info, (base.width, base.height))


def support_band(scene: GaussianScene, lift: SeedLift, orbits: OrbitViews, settings: ExtractSettings,
                 tracker: Tracker | None = None,
                 local: Neighbourhood | None = None) -> tuple[SupportSurface | None, dict]:
    """Stage 5b: the support surface under the object, for a tracker's ``support_plane``.

    :func:`~.support.support_surface` about the orbit axis, when
    ``settings.support_background`` is on, ``tracker`` takes a support plane
    (:class:`~seed2gs_inverse.frontend.base.SupportPlaneTracker`, as the
    model-free tracker does; any other tracker: None) and has none of its
    own, and the axis is trusted (the user's vector, or an estimate with
    confidence >= :data:`~.up_axis.WEAK_CONFIDENCE`). Returns
    ``(surface or None, report)`` with ``report`` the JSON-ready
    ``resolved["support"]``: the surface's fields and ``used: True``, or
    ``used: False`` and the reason. Given the object's neighbourhood
    ``local`` (:func:`~.local.object_neighbourhood`, holding the ball of
    :func:`~.local.support_reach`), the surface is found among its Gaussians
    alone: the same surface.

    Raises
    ------
    ValidationError
        ``local`` is not a neighbourhood of ``scene``.
    """
    info = orbits.up_info or {}
    if not settings.support_background:
        reason = "support_background is off"
    elif not isinstance(tracker, SupportPlaneTracker):
        reason = "not the model-free tracker"
    elif tracker.support_plane is not None:
        reason = "the tracker has its own support_plane"
    elif info.get("method") != "user" and (info.get("confidence") or 0.0) < WEAK_CONFIDENCE:
        reason = f"the orbit axis is not trusted (method {info.get('method')}, confidence {info.get('confidence')})"
    else:
        _check_local(scene, local)
        where, g0 = (scene, lift.g0) if local is None else (local.scene, local.local(lift.g0))
        surface = support_surface(where, g0, lift.center, lift.radius, orbits.up, **SUPPORT_DEFAULTS)
        if surface is not None:
            return surface, {"used": True, **surface.summary()}
        reason = "no level surface below the object"
    return None, {"used": False, "reason": reason}


def track_clips(tracker: Tracker, orbits: OrbitViews, seed: np.ndarray, progress: Progress | None = None) -> list:
    """Stage 6: the tracker propagates ``seed`` (frame 0) along each clip.

    ``tracker.track(frames, seed, references=labelled)`` receives the views
    labelled so far (the flat clip when tracking the spiral). Returns the
    supervision views as ``(ClipFrame, mask)`` pairs: the flat clip, then
    the spiral without its frame 0 (the reference view again); masks are
    float32 at the frame's resolution, NaN = unknown. ``progress`` counts
    one step per clip.

    Raises
    ------
    ValidationError
        The tracker breaks its protocol: ``track`` does not accept
        ``references``, returns no sequence, or the wrong number or shape of masks.
    """
    labelled = []
    for name, frames in orbits.clips():
        try:
            res = tracker.track(frames, seed, references=tuple(labelled))
        except TypeError as e:
            if "references" not in str(e):
                raise
            raise ValidationError(f"tracker {type(tracker).__name__}: track() must accept references=() "
                                  f"(the Tracker protocol, seed2gs_inverse.frontend.base); got: {e}") from None
        try:
            out = list(res)
        except TypeError:
            raise ValidationError(f"tracker {type(tracker).__name__}: track() returned {type(res).__name__}; it "
                                  f"must return one (H, W) mask per frame (the Tracker protocol, "
                                  f"seed2gs_inverse.frontend.base)") from None
        if len(out) != len(frames):
            raise ValidationError(f"tracker returned {len(out)} masks for a {name} clip of {len(frames)} frames")
        for k, (f, m) in enumerate(zip(frames, out)):
            if not _supervises(name, k):
                continue  # the reference view is already the flat clip's frame 0
            m = np.asarray(m, dtype=np.float32)
            if m.shape != f.camera.image_shape:
                raise ValidationError(f"tracker mask {k} of the {name} clip has shape {m.shape}, "
                                      f"expected {f.camera.image_shape}")
            labelled.append((f, m))
        if progress is not None:
            progress.update()
    return labelled


def evidence_graph(scene: GaussianScene, lift: SeedLift, settings: ExtractSettings,
                   smoothness: float, local: Neighbourhood | None = None) -> sp.csr_matrix | None:
    """Stage 6b: the Gaussian affinity graph around the object, or None when nothing needs it.

    :func:`~seed2gs_inverse.pipeline.completion.object_graph` about the
    lift's centre (``region`` lift radii, :data:`~.completion.GRAPH_DEFAULTS`
    updated by ``settings.graph_options``), built when the regulariser is on
    (``smoothness > 0``, resolved) or ``settings.completion`` is set. Given
    the object's neighbourhood ``local`` (holding the graph's region), it is
    built among its Gaussians and renumbered to the scene's: the same graph.

    Raises
    ------
    ValidationError
        ``local`` is not a neighbourhood of ``scene``.
    """
    if not (smoothness > 0 or settings.completion):
        return None
    opts = {**GRAPH_DEFAULTS, **settings.graph_options}
    _check_local(scene, local)
    if local is None:
        return object_graph(scene, lift.center, lift.radius, **opts)
    return local.expand(object_graph(local.scene, lift.center, lift.radius, **opts))


def complete_masks(graph: sp.csr_matrix | None, labelled: list, lift: SeedLift, ref: ReferenceView,
                   completion: str | None, filler: LabelFiller | None = None) -> list:
    """Stage 6c: the supervision masks, their unknown pixels filled by 3D label completion.

    ``completion=None``: the tracker's masks as they are. ``"reference"``:
    random-walker labels on ``graph`` seeded by the reference's labels alone
    (:func:`~.completion.complete_membership` from G0, the reference
    operator's column sums and the lift's membership); ``"tracked"``: seeded
    by every pixel the tracker decided (:func:`~.completion.tracked_membership`,
    prior G0). Either is rendered into each view and decides the unknown
    pixels it is sure of (:func:`~.completion.fill_unknown`). ``filler``
    (a :class:`~seed2gs_inverse.frontend.base.LabelFiller`) then decides
    what is still unknown with its 2D fill. Returns float32 masks, one per
    ``(frame, mask)`` of ``labelled``.

    Raises
    ------
    ValidationError
        ``completion`` is not None, ``"reference"`` or ``"tracked"``.
    """
    masks = [m for _, m in labelled]
    if not completion:
        return masks
    ops = [f.operator for f, _ in labelled]
    if completion == "reference":
        q_c = complete_membership(graph, lift.g0, np.asarray(ref.operator.W.sum(axis=0)).ravel(),
                                  lift.membership)
    elif completion == "tracked":
        q_c = tracked_membership(graph, ops, masks, prior=lift.g0.astype(np.float64))
    else:
        raise ValidationError(f"completion must be None, 'reference' or 'tracked', got {completion!r}")
    masks = fill_unknown(ops, masks, q_c)
    if filler is not None:
        masks = [m if not np.isnan(m).any() else
                 filler.fill_labels(op.rendering.rgb, op.rendering.depth, m).astype(np.float32)
                 for op, m in zip(ops, masks)]
    return masks


def stack_operators(labelled: list, scene: GaussianScene, built: OperatorStack | None = None) -> OperatorStack:
    """Stage 7: the ``OperatorStack`` of the supervision views (``frame.operator`` of each pair).

    Its ``fingerprint`` (:func:`~seed2gs_inverse.operators.scene_fingerprint`
    of ``scene``) is computed when first read (saving the operators reads it).
    ``built``, a stack made before of these very operators in this order, is
    returned as it is (with what it has cached, such as its columns);
    otherwise a new stack is made.
    """
    ops = [f.operator for f, _ in labelled]
    if built is not None and len(built) == len(ops) and all(a is b for a, b in zip(built.views, ops)):
        return built
    return OperatorStack(ops, scene=scene)


def supervision_frames(orbits: OrbitViews) -> list:
    """The orbit frames :func:`track_clips` labels, in its order: the flat clip, then the spiral without its frame 0."""
    return [f for name, frames in orbits.clips() for k, f in enumerate(frames) if _supervises(name, k)]


def _supervises(clip: str, k: int) -> bool:
    """Whether frame ``k`` of ``clip`` is a supervision view (the spiral's frame 0 is the reference view again)."""
    return not (clip == "spiral" and k == 0)


def solve_selection(stack, masks, lift: SeedLift, settings: ExtractSettings, progress=None, *,
                    graph: sp.csr_matrix | None = None, smoothness: float = 0.0,
                    scene: GaussianScene | None = None, local: Neighbourhood | None = None,
                    up=None) -> Selection:
    """Stage 8: ``q`` from the solver initialised from G0, and ``selected = q > tau``.

    Parameters
    ----------
    stack : OperatorStack or sequence of ViewOperator
        The supervision views.
    masks : iterable of (h, w) arrays
        One mask per view (read twice, so a generator is fine too).
    lift : SeedLift
    settings : ExtractSettings
    progress : callable, optional
        The solver's per-iteration hook (``solve(..., progress=)``).
    graph : (N, N) sparse, optional
        :func:`evidence_graph`'s graph, for the regulariser.
    smoothness : float
        The resolved regulariser weight lambda (0: off).
    scene : GaussianScene, optional
        The scene of the operators; needed with ``settings.seed_connected``
        or ``settings.follow_faint``.
    local : Neighbourhood, optional
        The object's neighbourhood in ``scene``
        (:func:`~.local.object_neighbourhood`: every column of the stack,
        G0 and the graph's region): the faint Gaussians' rule and the
        islands then run on its Gaussians alone, with the same result.
    up : (3,) array, optional
        The orbit axis: the enclosed and the weak Gaussians' rules keep out
        what lies below the selection's base (the ground under it). None:
        no such bound.

    Returns
    -------
    Selection

    Raises
    ------
    ValidationError
        ``settings.seed_connected``, ``settings.follow_faint`` or ``settings.follow_weak`` without ``scene``, or a
        ``local`` that is not a neighbourhood of ``scene``.

    Notes
    -----
    ``solve(stack, masks, method, init=G0, min_evidence=settings.min_evidence,
    min_vote=settings.min_vote, smoothness=smoothness, graph=graph,
    **settings.solver_kwargs())``:
    Gaussians seen (almost) only on unknown pixels carry no evidence (an
    unregularised fit could drive their logits anywhere on a trace of
    weight), so the solver gives them the prior (G0 membership), or, with
    ``smoothness > 0``, the harmonic extension of their neighbours on the
    graph; a Gaussian outside G0 whose masks call it object on less than
    ``settings.min_vote`` of its known weight ends at 0. With
    ``settings.follow_faint`` (default) the Gaussians of the
    graph's region below its ``min_opacity`` then take the membership of
    their nearest opaque neighbours
    (:func:`~.completion.faint_follow_matrix`): their own evidence is a trace.
    Then the unselected Gaussians whose centres every supervision view
    shows inside the selection's footprint, at or above its base along
    ``up`` (:func:`~.completion.follow_enclosed`: inside the object or
    behind it from every side), take the ``q`` of their nearest selected
    Gaussian that has no faint row: their evidence comes from the parts of
    their splats that reach past the silhouette, on background pixels.
    With ``settings.follow_weak`` (default) the unselected Gaussians of the
    graph's region whose stored weights stay below
    :data:`~.completion.WEAK_DEFAULTS` ``["max_weight"]`` in every view then
    take the inverse-distance mean ``q`` of their nearest Gaussians that
    reach it and have no row, at or above the selection's base along ``up``
    and within reach of those (:func:`~.completion.follow_weak`, with the
    scene's scales): they dominate no pixel, so their
    pixels' labels are other Gaussians'. With both rules the enclosed
    rule then runs once more, on the selection the weak rule grew.
    ``tau`` is ``settings.threshold`` or the solver's own. With
    ``settings.seed_connected`` (default) the Gaussians above ``tau`` in
    islands apart from G0 that the masks do not call object
    (:func:`~.islands.seed_connected` with the masks' votes) get ``q = 0``,
    the prior of Gaussians outside G0 (``result.q`` keeps the solver's
    values).
    """
    masks = list(masks)  # read twice (the solve, the islands' votes): a generator too
    stack = as_stack(stack, masks)
    result = solve(stack, masks, method=settings.method, init=lift.g0, min_evidence=settings.min_evidence,
                   min_vote=settings.min_vote, progress=progress, smoothness=smoothness, graph=graph,
                   **settings.solver_kwargs())
    q = np.asarray(result.q, dtype=np.float32)
    tau = result.threshold if settings.threshold is None else float(settings.threshold)
    if (settings.seed_connected or settings.follow_faint or settings.follow_weak) and scene is None:
        raise ValidationError("solve_selection: settings.seed_connected, follow_faint and follow_weak need the "
                              "scene (scene=); pass it or set them to False")
    if scene is not None:
        _check_local(scene, local)
    follow = None
    if settings.follow_faint or settings.follow_weak:
        follow, q = _follow_rules(scene, lift, stack, q, tau, settings, local, up)
    n_removed = 0
    if settings.seed_connected:
        graph_kw = {k: settings.lift_options[k] for k in ("k_neighbors", "link_factor") if k in settings.lift_options}
        island = _islands(scene, lift, q > tau, stack, masks, graph_kw, local)
        # islands hold no G0 Gaussian: they take the prior of the Gaussians outside G0 (0); set in
        # place, in q's own copy (result.q keeps the solver's values)
        if np.shares_memory(q, result.q):
            q = q.copy()
        q[island] = np.float32(0)
        n_removed = int(island.sum())
    selected = q > tau
    return Selection(result, q, tau, selected, n_removed, follow)


def _check_local(scene: GaussianScene, local) -> None:
    """Raise a ValidationError unless ``local`` is None or a :class:`~.local.Neighbourhood` of ``scene``'s size."""
    if local is not None and (not isinstance(local, Neighbourhood) or local.n != len(scene)):
        raise ValidationError(f"local must be None or a Neighbourhood of the scene's {len(scene)} Gaussians "
                              f"(pipeline.local.object_neighbourhood), got {type(local).__name__}"
                              + (f" of {local.n}" if isinstance(local, Neighbourhood) else ""))


def _follow_rules(scene: GaussianScene, lift: SeedLift, stack: OperatorStack, q: np.ndarray, tau: float,
                  settings: ExtractSettings, local: Neighbourhood | None, up) -> tuple[sp.csr_matrix, np.ndarray]:
    """``(follow (N, N), q after it)``: the follow rules of ``settings``, in order, applied to ``q``.

    With ``settings.follow_faint``: :func:`~.completion.faint_follow_matrix`
    applied to ``q``, then :func:`~.completion.follow_enclosed`; with
    ``settings.follow_weak``, then :func:`~.completion.follow_weak` over the
    Gaussians within the graph's region (and, with both, the enclosed rule
    again). With ``local`` (holding that
    region) the rows are built among the neighbourhood's Gaussians while
    every row and column lies in it, ``q`` is changed in one copy of it, and
    the (N, N) matrix is made once, at the end: the same matrix and ``q``.
    """
    opts = {**GRAPH_DEFAULTS, **settings.graph_options}
    region = opts["region"] * lift.radius
    kw = {"region": opts["region"], "min_opacity": opts["min_opacity"]}
    if local is None:
        n = len(scene)
        follow = sp.csr_matrix((n, n))
        if settings.follow_faint:
            follow = faint_follow_matrix(scene, lift.center, lift.radius, **kw)
            follow, q = follow_enclosed(stack, scene.means, apply_follow(q, follow), tau, follow, up=up)
        if settings.follow_weak:
            candidates = neighbourhood(scene, lift.center, region)
            follow, q = follow_weak(stack, scene.means, q, tau, follow, candidates, up=up,
                                   scales=scene.scales)
            if settings.follow_faint:  # the selection the weak rule grew encloses more
                follow, q = follow_enclosed(stack, scene.means, q, tau, follow, up=up)
        return follow, q
    m = len(local)
    rules = _LocalRows(local, faint_follow_matrix(local.scene, lift.center, lift.radius, **kw)
                       if settings.follow_faint else sp.csr_matrix((m, m)))
    out = np.array(q, dtype=np.float32)  # q's own copy: result.q keeps the solver's values
    out[local.index] = apply_follow(out[local.index], rules.follow)

    def enclose():
        rows, cols = _enclosed_rows(stack, scene.means, out, tau, rules.has_row, up=up)
        out[rows] = out[cols]
        rules.replace(rows, rows, cols, np.ones(rows.size))

    if settings.follow_faint:
        enclose()
    if settings.follow_weak:
        candidates = local.index[neighbourhood(local.scene, lift.center, region)]
        rows, entries = _weak_entries(stack, scene.means, out, tau, rules.has_row, candidates, up=up,
                                      scales_at=scene.scales_at)
        rules.replace(rows, *entries)
        out[rows] = rules.averages(rows, out)
        if settings.follow_faint:  # the selection the weak rule grew encloses more
            enclose()
    return rules.expanded(), out


class _LocalRows:
    """A follow matrix kept on a neighbourhood's Gaussians while its rows and columns lie there, else (N, N).

    Every index given and returned is the scene's; :meth:`expanded` is the
    (N, N) matrix.
    """

    def __init__(self, local: Neighbourhood, follow: sp.csr_matrix):
        self.local, self.follow, self.on_local = local, follow, True

    def has_row(self, i: np.ndarray) -> np.ndarray:
        """Bool over scene indices ``i``: which have a row."""
        if not self.on_local:
            return self.follow.indptr[i + 1] > self.follow.indptr[i]
        at, inside = self.local.find(i)
        if not len(self.local):
            return inside
        return inside & (self.follow.indptr[at + 1] > self.follow.indptr[at])

    def replace(self, rows: np.ndarray, new_rows: np.ndarray, new_cols: np.ndarray, data: np.ndarray) -> None:
        """Replace ``rows`` by the entries ``(new_rows, new_cols, data)`` (:func:`~.completion._replace_rows`)."""
        if rows.size == 0:
            return
        if self.on_local:
            (at_r, in_r), (at_n, _), (at_c, in_c) = (self.local.find(v) for v in (rows, new_rows, new_cols))
            if in_r.all() and in_c.all():
                self.follow = _replace_rows(self.follow, at_r, at_n, at_c, data)
                return
            self.follow, self.on_local = self.local.expand(self.follow), False
        self.follow = _replace_rows(self.follow, rows, new_rows, new_cols, data)

    def averages(self, rows: np.ndarray, q: np.ndarray) -> np.ndarray:
        """float32 ``(F q)`` at ``rows``, as :func:`~seed2gs_inverse.graph.apply_follow` computes it."""
        if rows.size == 0:
            return np.zeros(0, np.float32)
        if self.on_local:
            at, _ = self.local.find(rows)
            return _followed(self.follow, at, q[self.local.index])
        return _followed(self.follow, rows, q)

    def expanded(self) -> sp.csr_matrix:
        """The (N, N) follow matrix."""
        return self.local.expand(self.follow) if self.on_local else self.follow


def _islands(scene: GaussianScene, lift: SeedLift, above: np.ndarray, stack: OperatorStack, masks: list,
             graph_kw: dict, local: Neighbourhood | None) -> np.ndarray:
    """(N,) bool: the Gaussians of ``above`` (``q > tau``) in islands apart from G0 (:func:`~.islands.seed_connected`).

    The votes are the masks' (:func:`_votes`). With ``local``, on its
    Gaussians alone when it holds all of ``above`` (outside it ``q`` is the
    prior, 0 away from G0).
    """
    if local is not None:
        above_l = local.local(above)
        if int(above_l.sum()) == int(np.count_nonzero(above)):
            kept = seed_connected(local.scene.means, above_l, local.local(lift.g0),
                                  votes=_votes(stack, masks, local.local), **graph_kw)
            return local.scatter(above_l & ~kept, False)
    votes = _votes(stack, masks)
    return above & ~seed_connected(scene.means, above, lift.g0, votes=votes, **graph_kw)  # the lift's graph


def _votes(stack: OperatorStack, masks: list, take=None) -> tuple[np.ndarray, np.ndarray]:
    """``(A^T (k y), A^T k)``: each Gaussian's weight on object pixels and on decided pixels (two passes).

    The masks are read by the solver's rule (uint8 0/255 is 0/1, NaN unknown).
    ``take`` (e.g. :meth:`~.local.Neighbourhood.local`) keeps part of each
    (N,) product as soon as it is made, so that the two are not held at once.
    """
    take = (lambda v: v) if take is None else take
    y = np.concatenate([normalize_mask(m, v.image_shape, f"view {i}").ravel()
                        for i, (v, m) in enumerate(zip(stack, masks))])
    decided = ~np.isnan(y)
    return (take(stack.rmatvec(np.where(decided, y, np.float32(0)))),
            take(stack.rmatvec(decided.astype(np.float32))))
