"""``extract()``: Algorithm 1 of the paper end to end, as a short sequence of stages.

Each stage is a documented module-level function with explicit inputs and
outputs, so it can be run, tested and timed on its own::

    render_reference   reference canvas I_r                       -> Rendering
    seed_from_prompt   seed mask m* (prompt / grounder; a point
                       prompt grows to the whole object in 3D)     -> (seed, prompt_info)
    reference_view     W(c_r) around the seed, at the lift size    -> ReferenceView
    lift_seed          seed lift (G0, o, extent)                   -> SeedLift
    orbit_views        orbit axis (orbit_axis: support plane, ...)
                       then VAAS: flat orbit + visibility-adaptive
                       ascending spiral, each frame with its W(c)  -> OrbitViews
    support_band       the support surface under the object, for
                       the model-free tracker                      -> (SupportSurface or None, report)
    track_clips        the tracker propagates m* over both clips   -> list of (ClipFrame, mask)
    evidence_graph     Gaussian kNN graph around the object (when
                       smoothness > 0 or completion is on)         -> sparse (N, N) or None
    complete_masks     3D label completion of the unknown pixels
                       (completion="reference" / "tracked")        -> list of masks
    stack_operators    the supervision views' operators            -> OperatorStack
    solve_selection    solver (initialised from G0, graph-Laplacian
                       regulariser when smoothness > 0) + threshold,
                       kept where connected to G0 in 3D             -> Selection

All options live in one frozen :class:`~seed2gs_inverse.pipeline.settings.ExtractSettings`.
Every intermediate is returned in an :class:`Extraction` so users can see
what happened.
"""

from __future__ import annotations

import contextlib
import sys
import warnings
import time
from dataclasses import dataclass, field

import numpy as np

from .._threads import run_both
from ..camera import Camera
from ..errors import ValidationError
from ..scene import GaussianScene
from .seed_lift import SeedLift, seed_lift
from .settings import MODEL_FREE_SMOOTHNESS, SOLVER_DEFAULTS, ExtractSettings
from .up_axis import estimate_up
from .vaas import ClipFrame, VAASPlan, run_vaas

__all__ = ["Extraction", "extract", "Renderer", "ExtractSettings", "EXTRACT_DEFAULTS", "SOLVER_DEFAULTS", "STAGES",
           "MODEL_FREE_SMOOTHNESS", "ReferenceView", "OrbitViews", "Selection", "render_reference",
           "seed_from_prompt", "reference_view", "lift_seed", "orbit_axis", "orbit_views", "support_band",
           "track_clips", "evidence_graph", "complete_masks", "stack_operators", "solve_selection"]

#: Defaults of :func:`extract` beyond the VAAS ones (those of :class:`ExtractSettings`).
EXTRACT_DEFAULTS = {k: getattr(ExtractSettings, k) for k in (
    "orbit_scale", "max_view_pixels", "max_reference_pixels", "roi_margin", "zoom_margin", "min_weight",
    "cull_far", "min_evidence", "threshold", "smoothness", "completion")}

STAGES = ("render", "grounding", "lift", "vaas", "tracking", "operators", "solve")


@dataclass
class Extraction:
    """Everything :func:`extract` computed.

    Attributes
    ----------
    scene : GaussianScene
        The input scene.
    q : (N,) float32
        Foreground probabilities: ``result.q``, in which Gaussians without
        evidence (``min_evidence``) took the prior or, with the regulariser
        (``resolved["smoothness"] > 0``, the default with the model-free
        tracker), the harmonic extension of their neighbours; and 0 on
        islands apart from G0 (``settings.seed_connected``, counted in
        ``resolved["n_disconnected"]``).
    selected : (N,) bool
        ``q > threshold``: the object.
    threshold : float
    seed_mask : (H, W) bool
        ``m*`` at the reference camera's resolution.
    prompt_info : dict
        The prompt kind and, for grounded prompts, every candidate.
    reference_camera : Camera
    reference : Rendering
        The reference canvas ``I_r`` at full resolution.
    lift : SeedLift
    vaas : VAASPlan
    views : list of Camera
        The supervision views (flat clip, then the spiral without its frame
        0, which repeats the reference), at the operators' resolution (the
        reference at its own, the orbit views at ``view_scale``).
    clips : list of str
        ``"flat"`` / ``"spiral"`` per view.
    masks : list of (h, w) float32
        Supervision masks ``Y(c)`` (NaN = unknown).
    operators : OperatorStack
    result : SolveResult
    seconds : dict
        Wall time per stage: ``render, grounding, lift, vaas, tracking,
        operators, solve`` (the orbit views are rendered in the same pass as
        their operators, so that time counts under ``operators``).
    settings : ExtractSettings
        The options of the run (``report.json`` holds ``settings.to_dict()``).
    resolved : dict
        JSON-ready facts extract derived from the settings and the inputs:
        ``view_scale``, ``reference_scale``, ``up`` (the orbit axis used),
        ``up_method`` and ``up_confidence`` (how it was chosen, see ``up``),
        ``threshold`` (tau used), ``solver_options`` (with the defaults),
        ``tracker``, ``grounder`` (class names), ``n_weak_evidence``
        (Gaussians without real evidence: reset to the prior by
        ``min_evidence``, or decided by the regulariser), ``n_disconnected``
        (above the threshold in islands apart from G0, set to 0), ``support``
        (the support surface the model-free tracker labelled background,
        :func:`support_band`), ``smoothness``
        (the regulariser's lambda used, after ``None`` was resolved) and
        ``warnings`` (why a finished run should not be trusted, if it should
        not: :func:`result_warnings`).
    up : dict
        The orbit axis (:func:`orbit_axis`): ``axis``, ``method`` (how it
        was chosen), ``confidence`` in [0, 1] (None when the user chose it)
        and ``details``.
    """

    scene: GaussianScene
    q: np.ndarray
    selected: np.ndarray
    threshold: float
    seed_mask: np.ndarray
    prompt_info: dict
    reference_camera: Camera
    reference: object
    lift: SeedLift
    vaas: VAASPlan
    views: list
    clips: list
    masks: list
    operators: object
    result: object
    seconds: dict
    settings: ExtractSettings | None = None
    resolved: dict = field(default_factory=dict)
    up: dict = field(default_factory=dict)

    @property
    def total_seconds(self) -> float:
        return float(sum(self.seconds.values()))

    def object_scene(self) -> GaussianScene:
        """The selected Gaussians, every property kept."""
        return self.scene.subset(self.selected)

    def remainder_scene(self) -> GaussianScene:
        """The scene with the object removed."""
        return self.scene.subset(~self.selected)

    def report(self) -> dict:
        """JSON-ready summary: counts, timings, settings (and what they resolved to), VAAS and lift facts."""
        n_unknown = [int(np.isnan(m).sum()) for m in self.masks]
        return {
            "n_gaussians": int(len(self.scene)),
            "n_selected": int(self.selected.sum()),
            "threshold": float(self.threshold),
            "seed_pixels": int(self.seed_mask.sum()),
            "prompt": self.prompt_info,
            "lift": self.lift.summary(),
            "vaas": self.vaas.summary(),
            "n_views": len(self.views),  # supervision views: the reference and both clips' other frames
            "reference_shape": list(self.views[0].image_shape),
            "view_shape": list(self.views[min(1, len(self.views) - 1)].image_shape),  # the orbit views
            "unknown_pixels_per_view": n_unknown,
            "solver": {"method": self.result.method, "iterations": int(self.result.iterations),
                       "n_unobserved": int(np.sum(self.result.unobserved)),
                       "view_weights": [float(w) for w in np.asarray(self.result.view_weights)]},
            "seconds": {k: float(v) for k, v in self.seconds.items()},
            "total_seconds": self.total_seconds,
            "settings": None if self.settings is None else self.settings.to_dict(),
            "resolved": self.resolved,
            "up": self.up,
        }


def _resize_mask(mask: np.ndarray, shape: tuple) -> np.ndarray:
    """Area-average a boolean mask to ``shape`` (H, W) and threshold at 0.5."""
    import cv2

    h, w = shape
    if mask.shape == (h, w):
        return mask.astype(bool)
    m = cv2.resize(mask.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    return m > 0.5


def _view_scale(camera: Camera, scale: float, max_pixels: int | None) -> float:
    """``scale``, lowered so that ``camera.scaled(scale)`` has about ``max_pixels`` pixels (None: no cap).

    ``Camera.scaled`` rounds each side to whole pixels, so the count may pass
    ``max_pixels`` by up to a row and a column. Both are validated by
    :class:`ExtractSettings`.
    """
    s = float(scale)
    if max_pixels is not None:
        s = min(s, np.sqrt(int(max_pixels) / (camera.width * camera.height)))
    return s


def _mask_roi(mask: np.ndarray, margin: float = 0.25, pad: int = 8):
    """Box (x0, y0, x1, y1) around a mask, grown by ``margin`` of its size plus ``pad`` px."""
    ys, xs = np.nonzero(mask)
    h, w = mask.shape
    mx = int(margin * (xs.max() - xs.min() + 1)) + pad
    my = int(margin * (ys.max() - ys.min() + 1)) + pad
    return (max(int(xs.min()) - mx, 0), max(int(ys.min()) - my, 0),
            min(int(xs.max()) + 1 + mx, w), min(int(ys.max()) + 1 + my, h))


def _roi_box(camera: Camera, center, radius, margin):
    """Pixel box (x0, y0, x1, y1) holding the projection of the sphere (center, margin * radius).

    The sphere is sampled densely (400 points) and the box grown by 2 px;
    None (the whole image) when the camera is inside or near the sphere.
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


# -- the rasterizer, in one place ---------------------------------------------------------------
class Renderer:
    """The only place extract() calls the rasterizer: renders and operators of one frozen scene.

    Holds a :class:`~seed2gs_inverse.raster.FrozenScene`, so the
    view-independent activations of the scene (covariance factors,
    opacities, SH-0 colours, 3-sigma sizes) are computed once for the ~50
    views of an extraction instead of per view (identical results).
    ``operator_seconds`` accumulates the time spent building operators
    (reported under the ``operators`` stage).
    """

    def __init__(self, scene: GaussianScene, mode: str = "classic"):
        from ..raster import FrozenScene

        self.scene = scene
        self.frozen = FrozenScene(scene)
        self.mode = mode
        self.operator_seconds = 0.0

    def render(self, camera: Camera):
        """The full rendering of ``camera`` (a ``Rendering``)."""
        from ..raster import render

        return render(self.frozen, camera, mode=self.mode)

    def operator(self, camera: Camera, roi=None, min_weight: float = 0.0, cull: bool = False,
                 far: float | None = None):
        """``W(camera)`` (a ``ViewOperator`` with its rendering), composited only in ``roi``.

        ``cull``: rasterize only the Gaussians that can reach the roi pixels
        (:func:`~seed2gs_inverse.raster.cone_cull`, optionally cut at depth
        ``far``); W's columns stay scene indices, and the operator is the
        same when ``far`` is None.
        """
        from ..raster import build_operator, cone_cull

        t0 = time.perf_counter()
        subset = cone_cull(self.frozen, camera, roi, far) if cull else None
        op = build_operator(self.frozen, camera, roi=roi, min_weight=min_weight, mode=self.mode, subset=subset)
        self.operator_seconds += time.perf_counter() - t0
        return op


class _Progress:
    """A progress bar on stderr (tqdm) owned by a ``with`` block; a no-op when disabled.

    ``update(n)`` counts steps; :attr:`solve_callback` is a
    :func:`~seed2gs_inverse.solvers.solve` ``progress`` hook showing the
    iterations (against the method's maximum) and the current loss (None
    when disabled, so the solver skips its reports).
    """

    #: Seconds between redraws (tqdm's ``mininterval``).
    MININTERVAL = 0.1

    def __init__(self, desc: str, enabled: bool, total: int | None = None, unit: str = "it"):
        self.desc, self.enabled, self.total, self.unit = desc, bool(enabled), total, unit
        self._bar = None

    def __enter__(self) -> "_Progress":
        if self.enabled:
            from tqdm import tqdm

            self._bar = tqdm(total=self.total, desc=self.desc, unit=self.unit, leave=False, file=sys.stderr,
                             mininterval=self.MININTERVAL)
        return self

    def update(self, n: int = 1) -> None:
        if self._bar is not None:
            self._bar.update(n)

    @property
    def solve_callback(self):
        return self._solve_step if self._bar is not None else None

    def _solve_step(self, p) -> None:
        if p.total is not None and self._bar.total != p.total:
            self._bar.total = p.total
        self._bar.update(p.iteration - self._bar.n)
        if p.loss is not None:
            self._bar.set_postfix_str(f"loss {p.loss:.5g}", refresh=False)

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class _StageTimer:
    """Wall seconds per stage: ``with timer("lift"): ...`` adds to ``timer.seconds["lift"]``."""

    def __init__(self, stages=STAGES):
        self.seconds = dict.fromkeys(stages, 0.0)

    @contextlib.contextmanager
    def __call__(self, stage: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] += time.perf_counter() - t0

    def move(self, src: str, dst: str, seconds: float) -> None:
        """Count ``seconds`` measured inside stage ``src`` under ``dst`` instead."""
        self.seconds[src] -= seconds
        self.seconds[dst] += seconds


# -- stage outputs ------------------------------------------------------------------------------
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
    operator: object


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
    """

    plan: VAASPlan
    flat: list
    spiral: list
    view_scale: float
    up: np.ndarray
    up_info: dict = field(default_factory=dict)

    def clips(self) -> list:
        """``[("flat", frames), ("spiral", frames)]`` (no spiral entry when it was skipped)."""
        return [("flat", self.flat)] + ([("spiral", self.spiral)] if self.spiral else [])


@dataclass
class Selection:
    """The solve: ``result`` (its ``q`` already carries the ``min_evidence`` reset or the regulariser), tau and the selection.

    ``selected`` is ``q > tau``; with ``settings.seed_connected`` ``q`` is 0
    on the ``n_disconnected`` Gaussians of islands apart from G0.
    """

    result: object
    q: np.ndarray
    threshold: float
    selected: np.ndarray
    n_disconnected: int = 0

    @property
    def n_weak_evidence(self) -> int:
        return int(self.result.info.get("n_weak_evidence", 0))


# -- the stages ---------------------------------------------------------------------------------
def render_reference(renderer: Renderer, camera: Camera):
    """Stage 1: the reference canvas ``I_r`` (full resolution ``Rendering``).

    Raises ValidationError when the camera sees (almost) nothing: max alpha < 0.05.
    """
    ref = renderer.render(camera)
    if float(ref.alpha.max()) < 0.05:
        raise ValidationError(
            f"the reference camera sees nothing of the scene (max rendered alpha "
            f"{float(ref.alpha.max()):.3g}); check the camera pose and the scene's coordinates")
    return ref


def seed_from_prompt(prompt, reference, grounder=None, *, point_mode: str = "region", scene=None,
                     camera: Camera | None = None, mode: str = "classic"):
    """Stage 2: the seed mask ``m*`` (H, W) bool of ``prompt`` on the reference canvas, and the prompt info.

    See :func:`~seed2gs_inverse.frontend.prompts.seed_mask_from_prompt`; text
    prompts need ``grounder``. With ``point_mode="object"`` a
    :class:`~seed2gs_inverse.frontend.prompts.PointPrompt` returns the whole
    clicked object instead of its colour region: the region is lifted,
    grown in 3D down to the support plane and projected back
    (:func:`~seed2gs_inverse.pipeline.point_object.point_object_mask`, which
    needs the ``scene``, the reference ``camera`` and the rasterization
    ``mode``); ``prompt_info`` then carries its growth facts. Raises
    ValidationError when the seed covers only empty space (rendered alpha
    <= 0.05).
    """
    from ..frontend.prompts import PointPrompt, seed_mask_from_prompt

    if point_mode == "object" and isinstance(prompt, PointPrompt):
        from .point_object import point_object_mask

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
    """
    scale = _view_scale(camera, 1.0, max_reference_pixels)
    cam = camera if scale == 1.0 else camera.scaled(scale)
    seed_ref = _resize_mask(seed, cam.image_shape)
    if not seed_ref.any():
        raise ValidationError(
            f"the seed mask ({int(seed.sum())} px) vanishes at the lift resolution "
            f"{cam.width}x{cam.height}; raise max_reference_pixels or give a larger mask")
    return ReferenceView(cam, scale, seed_ref, renderer.operator(cam, roi=_mask_roi(seed_ref)))


def lift_seed(scene: GaussianScene, ref: ReferenceView, lift_options=None) -> SeedLift:
    """Stage 4: the seed lift (support G0, centre ``o``, extent) from the reference view's W and depth."""
    op = ref.operator
    return seed_lift(scene, ref.camera, ref.seed, op.rendering.depth, op.W, **dict(lift_options or {}))


def orbit_axis(up, scene: GaussianScene, base: Camera, ref: ReferenceView, lift: SeedLift,
               up_cameras=None) -> dict:
    """The VAAS axis of the ``up`` setting, as a report dict ``{axis, method, confidence, details}``.

    ``"auto"``: :func:`~seed2gs_inverse.pipeline.up_axis.estimate_up_axis`
    (support plane under the lift's G0, scene plane, the no-roll prior of
    ``base`` and the capture cameras ``up_cameras``); a weak estimate warns,
    naming ``--up``. ``"level"``: the image-up of ``base`` with its pitch
    removed, weighted by the reference view's operator
    (:func:`~seed2gs_inverse.pipeline.vaas.estimate_up`); ``"camera"``: the
    image-up itself; a vector: that vector, normalised. ``confidence`` is
    None unless estimated.
    """
    import warnings

    if isinstance(up, str) and up == "auto":
        from .up_axis import camera_list, estimate_up_axis

        if up_cameras is not None:
            up_cameras = camera_list(up_cameras, "up_cameras")  # read once: a generator too
        est = estimate_up_axis(scene, base, support=lift.support, center=lift.center, radius=lift.radius,
                               cameras=up_cameras)
        if est.weak:
            warnings.warn(est.warning(), stacklevel=4)
        return {**est.summary(), "warning": est.warning()}
    if isinstance(up, str) and up == "level":
        axis = estimate_up(scene, base, weights=np.asarray(ref.operator.W.sum(axis=0)).ravel())
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


def _clip_frame(op, clip: str, index: int) -> ClipFrame:
    r = op.rendering
    return ClipFrame(r.rgb, r.depth, r.alpha, op.camera, clip, index, operator=op)


def orbit_views(renderer: Renderer, camera: Camera, ref: ReferenceView, lift: SeedLift,
                settings: ExtractSettings, progress: _Progress | None = None, up_cameras=None) -> OrbitViews:
    """Stage 5: the orbit axis (:func:`orbit_axis`), then VAAS (flat orbit, visibility, ascending spiral).

    Each view is rendered with its operator.

    The orbit views have the camera's geometry at ``view_scale`` (``orbit_scale``
    capped at ``max_view_pixels``), zoomed to ``zoom_margin * extent`` about
    ``o``, composited only inside the projected sphere of ``roi_margin *
    extent`` and, with ``cull``, rasterized from the Gaussians of that cone
    (cut at ``cull_far * extent`` behind ``o``). Frame 0 of each clip is the
    reference view itself (``ref``, at its own resolution).
    """
    s = settings
    scene = renderer.scene
    view_scale = _view_scale(camera, s.orbit_scale, s.max_view_pixels)
    base = camera.scaled(view_scale)  # the orbits' base camera (geometry + view resolution)
    up_info = orbit_axis(s.up, scene, base, ref, lift, up_cameras)
    up = np.asarray(up_info["axis"], dtype=np.float64)

    def view(cam: Camera, clip: str, k: int) -> ClipFrame:
        if cam is base:
            op = ref.operator  # frame 0 is the reference view itself, at the lift resolution
        else:
            roi = _roi_box(cam, lift.center, lift.radius, s.roi_margin)
            far = None if not s.cull or s.cull_far is None else float(
                np.linalg.norm(cam.center - lift.center) + s.cull_far * lift.radius)
            op = renderer.operator(cam, roi=roi, min_weight=s.min_weight, cull=s.cull, far=far)
        if progress is not None:
            progress.update()
        return _clip_frame(op, clip, k)

    sigma = scene.scales.max(axis=1)[lift.support]
    plan, flat, spiral = run_vaas(
        scene.means[lift.support], sigma, base, lift.center, view, n_views=s.n_views, a_max_deg=s.a_max_deg,
        gamma=s.gamma, skip_deg=s.skip_deg, profile=s.profile, max_elevation_deg=s.max_elevation_deg,
        fit_radius=None if s.zoom_margin is None else s.zoom_margin * lift.radius, up=up)
    return OrbitViews(plan, flat, spiral, view_scale, up, up_info)


def support_band(scene: GaussianScene, lift: SeedLift, orbits: OrbitViews, settings: ExtractSettings,
                 tracker=None) -> tuple:
    """Stage 5b: the support surface under the object for the model-free tracker's ``support_plane``.

    :func:`~.support.support_surface` about the orbit axis, when
    ``settings.support_background`` is on, ``tracker`` is a
    :class:`~seed2gs_inverse.frontend.model_free.GeometricTracker` without a
    ``support_plane`` of its own (any other tracker: None) and the axis is
    trusted (the user's vector, or an estimate with confidence >=
    :data:`~.up_axis.WEAK_CONFIDENCE`). Returns ``(surface or None, report)``
    with ``report`` the JSON-ready ``resolved["support"]``: the surface's
    fields and ``used: True``, or ``used: False`` and the reason.
    """
    from ..frontend.model_free import GeometricTracker
    from .support import SUPPORT_DEFAULTS, support_surface
    from .up_axis import WEAK_CONFIDENCE

    info = orbits.up_info or {}
    if not settings.support_background:
        reason = "support_background is off"
    elif not isinstance(tracker, GeometricTracker):
        reason = "not the model-free tracker"
    elif tracker.support_plane is not None:
        reason = "the tracker has its own support_plane"
    elif info.get("method") != "user" and (info.get("confidence") or 0.0) < WEAK_CONFIDENCE:
        reason = f"the orbit axis is not trusted (method {info.get('method')}, confidence {info.get('confidence')})"
    else:
        surface = support_surface(scene, lift.support, lift.center, lift.radius, orbits.up, **SUPPORT_DEFAULTS)
        if surface is not None:
            return surface, {"used": True, **surface.summary()}
        reason = "no level surface below the object"
    return None, {"used": False, "reason": reason}


def track_clips(tracker, orbits: OrbitViews, seed: np.ndarray, progress: _Progress | None = None) -> list:
    """Stage 6: the tracker propagates ``seed`` (frame 0) along each clip.

    ``tracker.track(frames, seed, references=labelled)`` receives the views
    labelled so far (the flat clip when tracking the spiral). Returns the
    supervision views as ``(ClipFrame, mask)`` pairs: the flat clip, then
    the spiral without its frame 0 (the reference view again); masks are
    float32 at the frame's resolution, NaN = unknown.
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
            if name == "spiral" and k == 0:
                continue  # the reference view is already the flat clip's frame 0
            m = np.asarray(m, dtype=np.float32)
            if m.shape != f.camera.image_shape:
                raise ValidationError(f"tracker mask {k} of the {name} clip has shape {m.shape}, "
                                      f"expected {f.camera.image_shape}")
            labelled.append((f, m))
        if progress is not None:
            progress.update()
    return labelled


def evidence_graph(scene: GaussianScene, lift: SeedLift, settings: ExtractSettings, smoothness: float):
    """Stage 6b: the Gaussian affinity graph around the object, or None when nothing needs it.

    :func:`~seed2gs_inverse.pipeline.completion.object_graph` about the
    lift's centre (``region`` lift radii, :data:`~.completion.GRAPH_DEFAULTS`
    updated by ``settings.graph_options``), built when the regulariser is on
    (``smoothness > 0``, resolved) or ``settings.completion`` is set.
    """
    if not (smoothness > 0 or settings.completion):
        return None
    from .completion import GRAPH_DEFAULTS, object_graph

    return object_graph(scene, lift.center, lift.radius, **{**GRAPH_DEFAULTS, **settings.graph_options})


def complete_masks(graph, labelled, lift: SeedLift, ref: ReferenceView, completion: str | None,
                   filler=None) -> list:
    """Stage 6c: the supervision masks, their unknown pixels filled by 3D label completion.

    ``completion=None``: the tracker's masks as they are. ``"reference"``:
    random-walker labels on ``graph`` seeded by the reference's labels alone
    (:func:`~.completion.complete_membership` from G0, the reference
    operator's column sums and the lift's membership); ``"tracked"``: seeded
    by every pixel the tracker decided (:func:`~.completion.tracked_membership`,
    prior G0). Either is rendered into each view and decides the unknown
    pixels it is sure of (:func:`~.completion.fill_unknown`). ``filler``
    (a :class:`~seed2gs_inverse.frontend.model_free.GeometricTracker`, with
    ``"tracked"``) then decides what is still unknown with its 2D fill
    (:meth:`~seed2gs_inverse.frontend.model_free.GeometricTracker.fill_labels`).
    Returns float32 masks, one per ``(frame, mask)`` of ``labelled``.
    """
    masks = [m for _, m in labelled]
    if not completion:
        return masks
    from .completion import complete_membership, fill_unknown, tracked_membership

    ops = [f.operator for f, _ in labelled]
    if completion == "reference":
        q_c = complete_membership(graph, lift.support, np.asarray(ref.operator.W.sum(axis=0)).ravel(),
                                  lift.membership)
    elif completion == "tracked":
        q_c = tracked_membership(graph, ops, masks, prior=lift.support.astype(np.float64))
    else:
        raise ValidationError(f"completion must be None, 'reference' or 'tracked', got {completion!r}")
    masks = fill_unknown(ops, masks, q_c)
    if filler is not None:
        masks = [m if not np.isnan(m).any() else
                 filler.fill_labels(op.rendering.rgb, op.rendering.depth, m).astype(np.float32)
                 for op, m in zip(ops, masks)]
    return masks


def stack_operators(labelled, scene: GaussianScene):
    """Stage 7: the ``OperatorStack`` of the supervision views (``frame.operator`` of each pair)."""
    from ..operators import OperatorStack, scene_fingerprint

    return OperatorStack([f.operator for f, _ in labelled], fingerprint=scene_fingerprint(scene))


def solve_selection(stack, masks, lift: SeedLift, settings: ExtractSettings, progress=None, *, graph=None,
                    smoothness: float = 0.0, scene: GaussianScene | None = None) -> Selection:
    """Stage 8: ``q`` from the solver initialised from G0, and ``selected = q > tau``.

    ``solve(stack, masks, method, init=G0, min_evidence=settings.min_evidence,
    smoothness=smoothness, graph=graph, **settings.solver_kwargs())``:
    Gaussians seen (almost) only on unknown pixels carry no evidence (an
    unregularised fit could drive their logits anywhere on a trace of
    weight), so the solver gives them the prior (G0 membership), or, with
    ``smoothness > 0`` (the resolved setting; :func:`evidence_graph`'s
    ``graph``), the harmonic extension of their neighbours on the graph.
    ``tau`` is ``settings.threshold`` or the solver's own. ``progress``: the
    solver's per-iteration hook (``solve(..., progress=)``). With
    ``settings.seed_connected`` (default) the Gaussians above ``tau`` in
    islands apart from G0 that the masks do not call object
    (:func:`~.seed_lift.seed_connected` with the masks' votes) get ``q = 0``,
    the prior of Gaussians outside G0 (``result.q`` keeps the solver's
    values). ``scene``: the scene of the operators, needed for that rule
    (its means).
    """
    from ..operators import as_stack
    from ..solvers import solve
    from .islands import seed_connected

    masks = list(masks)  # read twice (the solve, the islands' votes): a generator too
    stack = as_stack(stack, masks)
    result = solve(stack, masks, method=settings.method, init=lift.support, min_evidence=settings.min_evidence,
                   progress=progress, smoothness=smoothness, graph=graph, **settings.solver_kwargs())
    q = np.asarray(result.q, dtype=np.float32)
    tau = result.threshold if settings.threshold is None else float(settings.threshold)
    n_removed = 0
    if settings.seed_connected:
        if scene is None:
            raise ValidationError("solve_selection: settings.seed_connected needs the scene (scene=, for its "
                                  "Gaussian means); pass it or set seed_connected=False")
        graph_kw = {k: settings.lift_options[k] for k in ("k_neighbors", "link_factor") if k in settings.lift_options}
        island = (q > tau) & ~seed_connected(scene.means, q > tau, lift.support, votes=_votes(stack, masks),
                                             **graph_kw)  # the lift's graph
        # islands hold no G0 Gaussian: they take the prior of the Gaussians outside G0 (0)
        q = np.where(island, np.float32(0), q)
        n_removed = int(island.sum())
    selected = q > tau
    return Selection(result, q, tau, selected, n_removed)


def _votes(stack, masks) -> tuple:
    """``(A^T (k y), A^T k)``: each Gaussian's weight on object pixels and on decided pixels (two passes).

    The masks are read by the solver's rule (uint8 0/255 is 0/1, NaN unknown).
    """
    from ..solvers._common import normalize_mask

    y = np.concatenate([normalize_mask(m, v.image_shape, f"view {i}").ravel()
                        for i, (v, m) in enumerate(zip(stack, masks))])
    decided = ~np.isnan(y)
    return (stack.rmatvec(np.where(decided, y, np.float32(0))),
            stack.rmatvec(decided.astype(np.float32)))


# -- Algorithm 1 --------------------------------------------------------------------------------
def _settings(settings, overrides: dict) -> ExtractSettings:
    if isinstance(settings, str):
        # extract(scene, camera, prompt, grounder, tracker, "voting"): the old positional method
        overrides = {"method": settings, **overrides}
        settings = None
    if settings is None:
        return ExtractSettings.from_dict(overrides) if overrides else ExtractSettings()
    if not isinstance(settings, ExtractSettings):
        raise ValidationError(f"settings must be an ExtractSettings (or None), got {type(settings).__name__}")
    return settings.replace(**overrides) if overrides else settings


def _trackers(tracker, settings: ExtractSettings):
    """(tracker, 2D filler or None, resolved smoothness) for the given tracker and settings.

    ``smoothness=None`` resolves to :data:`MODEL_FREE_SMOOTHNESS` with the
    model-free tracker, 0 with any other. ``completion="tracked"`` with the
    default tracker replaces its 2D fill of revealed pixels (which decides
    them from image neighbours and is the main source of wrong labels on an
    object's far side) by the 3D completion; the 2D fill (``filler``) then
    only decides what the completion leaves open.
    """
    from ..frontend.model_free import GeometricTracker

    smoothness = settings.smoothness
    if smoothness is None:
        smoothness = MODEL_FREE_SMOOTHNESS if tracker is None or isinstance(tracker, GeometricTracker) else 0.0
    filler = None
    if tracker is None and settings.completion == "tracked":
        tracker, filler = GeometricTracker(fill=False), GeometricTracker()
    tracker = GeometricTracker() if tracker is None else tracker
    if not callable(getattr(tracker, "track", None)):
        raise ValidationError(f"tracker must have a track(frames, seed_mask, references=()) method, "
                              f"got {type(tracker).__name__}")
    return tracker, filler, float(smoothness)


#: Fewer Gaussians than this in G0: the seed rests on too little of the scene to orbit and label.
MIN_SUPPORT = 10


def result_warnings(ref: ReferenceView, lift: SeedLift, masks, stack, sel) -> list:
    """What makes a finished extraction untrustworthy although every stage ran: one sentence each.

    A seed that touches every border of the reference image (the object may
    go on beyond the view; the lift and the orbit only know what is seen), a
    lift of fewer than :data:`MIN_SUPPORT` Gaussians, orbit views without
    any weight or without a single object pixel (the reference view alone
    decided q), and an empty selection.
    """
    notes = []
    seed = np.asarray(ref.seed, bool)
    if seed.any() and seed[0].any() and seed[-1].any() and seed[:, 0].any() and seed[:, -1].any():
        notes.append("the seed touches every border of the reference image: the object may extend beyond "
                     "the view, and the orbit only covers what is seen; move the camera back")
    if lift.n_support < MIN_SUPPORT:
        notes.append(f"the seed lifted to only {lift.n_support} Gaussian(s) (G0): a seed smaller than the splats "
                     f"it covers, or a camera very close to the surface; the orbit circles a tiny region")
    orbit = range(1, len(stack))
    if len(stack) > 1 and all(stack[i].W.nnz == 0 for i in orbit):
        notes.append("the orbit views hold no weights (orbit_scale, zoom_margin or min_weight leave them "
                     "empty): the reference view alone decided q")
    elif len(masks) > 1 and not any(np.nansum(np.asarray(masks[i]) > 0.5) for i in orbit):
        notes.append("the object was found in none of the orbit views (every tracked mask is background): "
                     "q rests on the reference view; try completion='reference' or a larger seed")
    if not np.any(sel.selected):
        notes.append(f"nothing was selected (the largest q is {float(np.max(sel.q, initial=0.0)):.3f}, the "
                     f"threshold {float(sel.threshold):.3f}): lower the threshold, or check the seed")
    return notes


def extract(scene: GaussianScene, camera: Camera, prompt, grounder=None, tracker=None,
            settings: ExtractSettings | None = None, *, up_cameras=None, **overrides) -> Extraction:
    """Extract one object from a frozen 3DGS scene (Algorithm 1).

    Parameters
    ----------
    scene : GaussianScene
        The frozen scene.
    camera : Camera
        Reference camera ``c_r`` (the user's view). Its resolution is the
        prompt's pixel space.
    prompt : MaskPrompt, BoxPrompt, PointPrompt, TextPrompt, str or (H, W) array
        See :mod:`seed2gs_inverse.frontend.prompts`. Text needs ``grounder``.
    grounder : Grounder, optional
        ``ground(image, prompt) -> list[Candidate]``; the highest ``score`` wins.
    tracker : Tracker, optional
        ``track(frames, seed_mask, references=()) -> list[mask]``
        (:class:`~seed2gs_inverse.frontend.base.Tracker`); default
        :class:`~seed2gs_inverse.frontend.model_free.GeometricTracker`.
    settings : ExtractSettings, optional
        Every option (:class:`~seed2gs_inverse.pipeline.settings.ExtractSettings`,
        where each is documented); default ``ExtractSettings()``.
    up_cameras : sequence of Camera, optional
        Capture cameras of the scene (e.g. its training cameras): with
        ``up="auto"`` they constrain the orbit axis (no-roll cameras are
        level). Run-time data like ``grounder``, not a setting.
    **overrides
        Options replacing those of ``settings`` by name, e.g.
        ``extract(scene, cam, prompt, method="voting", n_views=12)``. An
        unknown name is a ValidationError listing the valid ones.

    Returns
    -------
    Extraction
        ``seconds`` holds the wall time per stage (:data:`STAGES`; the orbit
        views are rendered in the same pass as their operators, so that time
        counts under ``operators``, not ``vaas``).
    """
    s = _settings(settings, overrides)
    if not isinstance(scene, GaussianScene):
        raise ValidationError(f"scene must be a GaussianScene, got {type(scene).__name__}")
    if len(scene) == 0:
        raise ValidationError("the scene has no Gaussians")
    if not isinstance(camera, Camera):
        raise ValidationError(f"camera must be a Camera, got {type(camera).__name__}")
    tracker, filler, smoothness = _trackers(tracker, s)
    progress = bool(getattr(sys.stderr, "isatty", lambda: False)()) if s.progress is None else s.progress
    timer = _StageTimer()
    renderer = Renderer(scene, s.mode)
    with timer("render"):
        reference = render_reference(renderer, camera)
    with timer("grounding"):
        seed, prompt_info = seed_from_prompt(prompt, reference, grounder, point_mode=s.point_mode, scene=scene,
                                             camera=camera, mode=s.mode)
    with timer("operators"):
        ref = reference_view(renderer, camera, seed, s.max_reference_pixels)
    with timer("lift"):
        lift = lift_seed(scene, ref, s.lift_options)
    before = renderer.operator_seconds
    with timer("vaas"), _Progress("VAAS views", progress, unit="view") as bar:
        orbits = orbit_views(renderer, camera, ref, lift, s, bar, up_cameras=up_cameras)
    timer.move("vaas", "operators", renderer.operator_seconds - before)
    with timer("tracking"), _Progress("tracking", progress, total=len(orbits.clips())) as bar:
        surface, support_info = support_band(scene, lift, orbits, s, tracker)
        if surface is not None:
            tracker = tracker.with_support_plane(surface.axis, surface.point)
        # The evidence graph (model-free evidence for surfaces no labelled view
        # saw, pipeline/completion.py) needs only the lift: it is built on a
        # second thread while the tracker runs on this one.
        out = {}

        def work(k):
            if k == 0:
                out["labelled"] = track_clips(tracker, orbits, ref.seed, bar)
            else:
                out["graph"] = evidence_graph(scene, lift, s, smoothness)

        run_both(work)
        labelled, graph = out["labelled"], out["graph"]
        masks = complete_masks(graph, labelled, lift, ref, s.completion, filler)
    with timer("solve"), _Progress(f"solve ({s.method})", progress) as bar:
        stack = stack_operators(labelled, scene)
        sel = solve_selection(stack, masks, lift, s, progress=bar.solve_callback, graph=graph,
                              smoothness=smoothness, scene=scene)
    notes = result_warnings(ref, lift, masks, stack, sel)
    for note in notes:
        warnings.warn(note, stacklevel=2)
    resolved = {"view_scale": float(orbits.view_scale), "reference_scale": float(ref.scale),
                "up": orbits.up.tolist(), "up_method": orbits.up_info.get("method"),
                "up_confidence": orbits.up_info.get("confidence"), "threshold": float(sel.threshold),
                "solver_options": {k: v for k, v in s.solver_kwargs().items()
                                   if isinstance(v, (int, float, str, bool))},
                "n_weak_evidence": sel.n_weak_evidence, "n_disconnected": sel.n_disconnected,
                "support": support_info,
                "smoothness": smoothness, "tracker": type(tracker).__name__,
                "grounder": None if grounder is None else type(grounder).__name__,
                # the orbit axis's warning was given when it was chosen; the report keeps it with the others
                "warnings": [w for w in [orbits.up_info.get("warning")] if w] + notes}
    return Extraction(scene, sel.q, sel.selected, sel.threshold, seed, prompt_info, camera, reference, lift,
                      orbits.plan, [f.camera for f, _ in labelled], [f.clip for f, _ in labelled], masks, stack,
                      sel.result, timer.seconds, s, resolved, orbits.up_info)
