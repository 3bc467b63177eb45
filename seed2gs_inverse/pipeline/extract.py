"""``extract()``: Algorithm 1 of the paper end to end.

render reference -> seed mask m* (prompt / grounder) -> seed lift (G0, o,
extent) -> VAAS (flat orbit + visibility-adaptive ascending spiral) ->
tracker propagates m* over both clips -> operators of all views -> solver
(initialised from G0) -> threshold -> object subset.

Every intermediate is returned in an :class:`Extraction` so users can see
what happened.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera
from ..errors import ValidationError
from ..scene import GaussianScene
from .seed_lift import SeedLift, seed_lift
from .vaas import DEFAULTS as VAAS_DEFAULTS, ClipFrame, VAASPlan, estimate_up, run_vaas

__all__ = ["Extraction", "extract", "EXTRACT_DEFAULTS", "SOLVER_DEFAULTS"]

#: Defaults of :func:`extract` beyond the VAAS ones.
EXTRACT_DEFAULTS = {"orbit_scale": 0.5, "max_view_pixels": 40_000, "max_reference_pixels": 1_000_000,
                    "roi_margin": 2.0, "zoom_margin": 2.0, "min_weight": 0.0, "cull_far": 4.0,
                    "min_evidence": 0.05, "threshold": None}

#: Solver options extract() uses unless told otherwise: the weighted BCE
#: selection settles within a few dozen L-BFGS-B iterations when started from
#: G0 (held-out mIoU is the same at 30 and at 200 iterations, the solver's
#: own default, on the procedural scenes and on the firepit+unicorn
#: benchmark), and the iterations dominate time.
SOLVER_DEFAULTS = {"weighted_bce": {"max_iter": 30}}

STAGES = ("render", "grounding", "lift", "vaas", "tracking", "operators", "solve")


@dataclass
class Extraction:
    """Everything :func:`extract` computed.

    Attributes
    ----------
    scene : GaussianScene
        The input scene.
    q : (N,) float32
        Foreground probabilities (the solver's, with Gaussians without
        evidence reset to the prior; ``result.q`` is the solver's own).
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
    settings : dict
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
    settings: dict = field(default_factory=dict)

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
        """JSON-ready summary: counts, timings, settings, VAAS and lift facts."""
        n_unknown = [int(np.isnan(m).sum()) for m in self.masks]
        return {
            "n_gaussians": int(len(self.scene)),
            "n_selected": int(self.selected.sum()),
            "threshold": float(self.threshold),
            "seed_pixels": int(self.seed_mask.sum()),
            "prompt": self.prompt_info,
            "lift": self.lift.summary(),
            "vaas": self.vaas.summary(),
            "n_views": len(self.views),
            "view_shape": list(self.views[0].image_shape),
            "unknown_pixels_per_view": n_unknown,
            "solver": {"method": self.result.method, "iterations": int(self.result.iterations),
                       "n_unobserved": int(np.sum(self.result.unobserved)),
                       "view_weights": [float(w) for w in np.asarray(self.result.view_weights)]},
            "seconds": {k: float(v) for k, v in self.seconds.items()},
            "total_seconds": self.total_seconds,
            "settings": self.settings,
        }


def _progress(iterable, total, desc, enabled):
    if not enabled:
        return iterable
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, leave=False, file=sys.stderr)


def _resize_mask(mask: np.ndarray, shape: tuple) -> np.ndarray:
    """Area-average a boolean mask to ``shape`` (H, W) and threshold at 0.5."""
    import cv2

    h, w = shape
    if mask.shape == (h, w):
        return mask.astype(bool)
    m = cv2.resize(mask.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    return m > 0.5


def _view_scale(camera: Camera, orbit_scale: float, max_pixels: int | None) -> float:
    s = float(orbit_scale)
    if not (np.isfinite(s) and 0 < s <= 4):
        raise ValidationError(f"orbit_scale must be in (0, 4], got {orbit_scale!r}")
    if max_pixels is not None:
        if int(max_pixels) < 64:
            raise ValidationError(f"max_view_pixels must be >= 64, got {max_pixels!r}")
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


def extract(scene: GaussianScene, camera: Camera, prompt, grounder=None, tracker=None,
            method: str = "weighted_bce", *, n_views: int = VAAS_DEFAULTS["n_views"],
            a_max_deg: float = VAAS_DEFAULTS["a_max_deg"], gamma: float = VAAS_DEFAULTS["gamma"],
            skip_deg: float = VAAS_DEFAULTS["skip_deg"], profile: str = VAAS_DEFAULTS["profile"],
            max_elevation_deg: float = VAAS_DEFAULTS["max_elevation_deg"],
            orbit_scale: float = EXTRACT_DEFAULTS["orbit_scale"],
            max_view_pixels: int | None = EXTRACT_DEFAULTS["max_view_pixels"],
            max_reference_pixels: int | None = EXTRACT_DEFAULTS["max_reference_pixels"],
            roi_margin: float | None = EXTRACT_DEFAULTS["roi_margin"],
            zoom_margin: float | None = EXTRACT_DEFAULTS["zoom_margin"], up="level",
            min_weight: float = EXTRACT_DEFAULTS["min_weight"], cull: bool = True,
            cull_far: float | None = EXTRACT_DEFAULTS["cull_far"],
            min_evidence: float = EXTRACT_DEFAULTS["min_evidence"],
            threshold: float | None = None, lift_options: dict | None = None,
            solver_options: dict | None = None, mode: str = "classic",
            progress: bool | None = None) -> Extraction:
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
        Propagates the seed along each clip; default
        :class:`~seed2gs_inverse.frontend.model_free.GeometricTracker`.
    method : str
        Solver (:func:`seed2gs_inverse.solvers.available_methods`).
    n_views, a_max_deg, gamma, skip_deg, profile, max_elevation_deg
        VAAS settings (:mod:`seed2gs_inverse.pipeline.vaas`): paper defaults
        24 views per clip and 5 degrees; A_max = 60 degrees and gamma = 1 are
        our documented choices.
    orbit_scale : float
        Resolution of the orbit views relative to the reference camera,
        default 0.5 ...
    max_view_pixels : int or None
        ... capped at this many pixels per view (40k, e.g. 267x150 for a
        960x540 reference). The orbit views are object-centric (zoomed), so
        even this resolution puts a few thousand pixels on the object, and
        the operators (non-zeros) dominate time and memory: on the
        firepit+unicorn benchmark 160k pixels per view cost 3x the time for
        the same accuracy (mIoU 0.900 vs 0.894 on pose 0). None: no cap.
    max_reference_pixels : int or None
        The reference view (seed lift, frame 0 of both clips, first
        supervision view) keeps the camera's resolution up to this many
        pixels (1M), composited only in a box around the seed. Clip frames
        therefore differ in size between frame 0 and the rest.
    roi_margin : float or None
        Orbit views composite only the pixel box around the projected sphere
        of radius ``roi_margin * extent`` about ``o`` (default 2: the lift
        sees the front of the object only, so its extent is conservative);
        pixels outside have empty operator rows and label 0. None: full views.
    zoom_margin : float or None
        Object-centric views: the orbit views (not the reference) zoom so
        that the sphere of radius ``zoom_margin * extent`` about ``o`` fits
        the image (default 2, for the same reason as ``roi_margin``). None
        keeps the reference's field of view.
    up : "level", "camera" or (3,) array
        Orbit axis. ``"level"`` (default): the reference camera's image-up
        with its pitch removed (:func:`~seed2gs_inverse.pipeline.vaas.estimate_up`);
        ``"camera"``: the image-up itself (literal reading of the paper; the
        flat orbit then tilts by the camera's pitch); or a world vector.
    min_weight : float
        Orbit operators drop compositing weights below this
        (:func:`~seed2gs_inverse.raster.build_operator`): fewer
        non-zeros, faster solves, ``W 1`` short of alpha by at most the
        dropped weights.
    cull : bool
        Rasterize each orbit view from only the Gaussians inside the cone of
        its roi (widened by their 3-sigma size) and map the operator's
        columns back; the operator is the same, the time scales with what
        the view can see instead of with the scene.
    cull_far : float or None
        With ``cull``, orbit views also leave out what lies farther than
        ``cull_far * extent`` behind ``o`` (default 4, twice the roi sphere):
        far background contributes nothing but compositing work and pixels
        that can only be background. Such pixels render empty (label 0,
        empty operator rows), and those Gaussians stay unobserved (prior 0)
        unless a nearer view sees them. None keeps everything (exact
        operators).
    min_evidence : float
        A Gaussian whose summed compositing weight over the *decided*
        (non-NaN) pixels of all views is below this (default 0.05, a
        twentieth of one opaque pixel) has no real evidence: its ``q`` is
        reset to the prior (1 in G0, else 0). Without this, an unregularised
        fit can drive such Gaussians to 1 on a trace of weight.
    threshold : float, optional
        ``tau`` of Eq. 9; default: the solver's own (0.5).
    lift_options : dict, optional
        Keyword arguments of :func:`~seed2gs_inverse.pipeline.seed_lift.seed_lift`.
    solver_options : dict, optional
        Keyword arguments of the solver method, on top of
        :data:`SOLVER_DEFAULTS` (``max_iter=30`` for ``weighted_bce``).
    mode : {"classic", "antialiased"}
        Rasterization mode of every rendering.
    progress : bool, optional
        Progress bars on stderr; default: only when stderr is a terminal.

    Returns
    -------
    Extraction
    """
    from ..frontend.model_free import GeometricTracker
    from ..frontend.prompts import seed_mask_from_prompt

    from ..operators import OperatorStack, scene_fingerprint
    from ..raster import FrozenScene, build_operator, cone_cull, render
    from ..solvers import solve

    if not isinstance(scene, GaussianScene):
        raise ValidationError(f"scene must be a GaussianScene, got {type(scene).__name__}")
    if len(scene) == 0:
        raise ValidationError("the scene has no Gaussians")
    if not isinstance(camera, Camera):
        raise ValidationError(f"camera must be a Camera, got {type(camera).__name__}")
    # extract() renders the same unchanged scene for ~50 views: the covariance
    # factors, opacities, SH-0 colours and 3-sigma sizes are computed once.
    frozen = FrozenScene(scene)
    from ..solvers import available_methods

    if method not in available_methods():
        raise ValidationError(f"unknown solver method {method!r}; available: {', '.join(available_methods())}")
    if progress is None:
        progress = bool(getattr(sys.stderr, "isatty", lambda: False)())
    tracker = GeometricTracker() if tracker is None else tracker
    if not callable(getattr(tracker, "track", None)):
        raise ValidationError(f"tracker must have a track(frames, seed_mask) method, got {type(tracker).__name__}")
    seconds = dict.fromkeys(STAGES, 0.0)

    # 1. Reference canvas I_r.
    t0 = time.perf_counter()
    ref = render(frozen, camera, mode=mode)
    seconds["render"] = time.perf_counter() - t0
    if float(ref.alpha.max()) < 0.05:
        raise ValidationError(
            f"the reference camera sees nothing of the scene (max rendered alpha "
            f"{float(ref.alpha.max()):.3g}); check the camera pose and the scene's coordinates")

    # 2. Seed mask m*.
    t0 = time.perf_counter()
    seed, prompt_info = seed_mask_from_prompt(prompt, ref.rgb, depth=ref.depth, alpha=ref.alpha,
                                              grounder=grounder)
    if not (seed & (ref.alpha > 0.05)).any():
        raise ValidationError("the seed mask covers only empty space in the reference view: "
                              "it does not touch the scene")
    seconds["grounding"] = time.perf_counter() - t0

    # 3. Seed lift with W(c_r) at the reference resolution (capped), composited
    #    only around the seed; the same operator is frame 0 of both clips.
    t0 = time.perf_counter()
    scale = _view_scale(camera, orbit_scale, max_view_pixels)
    ref_scale = _view_scale(camera, 1.0, max_reference_pixels)
    ref_cam = camera if ref_scale == 1.0 else camera.scaled(ref_scale)
    seed_ref = _resize_mask(seed, ref_cam.image_shape)
    if not seed_ref.any():
        raise ValidationError(
            f"the seed mask ({int(seed.sum())} px) vanishes at the lift resolution "
            f"{ref_cam.width}x{ref_cam.height}; raise max_reference_pixels or give a larger mask")
    op_ref = build_operator(frozen, ref_cam, roi=_mask_roi(seed_ref), mode=mode)
    t_op = time.perf_counter() - t0
    t1 = time.perf_counter()
    lift = seed_lift(scene, ref_cam, seed_ref, op_ref.rendering.depth, op_ref.W, **(lift_options or {}))
    seconds["lift"] = time.perf_counter() - t1
    seconds["operators"] += t_op
    ref_small = camera.scaled(scale)  # the orbits' base camera (geometry + view resolution)

    # 4. VAAS: flat orbit, visibility, spiral; each view's operator built in the rendering pass.
    if isinstance(up, str) and up == "level":
        up_axis = estimate_up(scene, ref_small, weights=np.asarray(op_ref.W.sum(axis=0)).ravel())
    elif isinstance(up, str) and up == "camera":
        up_axis = ref_small.up
    else:
        up_axis = np.asarray(up, dtype=np.float64)
        if up_axis.shape != (3,) or not np.all(np.isfinite(up_axis)) or np.linalg.norm(up_axis) == 0:
            raise ValidationError(f"up must be 'level', 'camera' or a non-zero 3-vector, got {up!r}")
    ops_by_view = {}
    sigma = scene.scales.max(axis=1)[lift.support]
    bar = [None]

    def view(cam, clip, k):
        if cam is ref_small:
            op = op_ref  # frame 0 is the reference view itself, at the lift resolution
        else:
            ts = time.perf_counter()
            roi = _roi_box(cam, lift.center, lift.radius, roi_margin)
            if cull:
                # Rasterize only what can reach the roi (no scene copy; W's
                # columns are scene indices): same W, far less work.
                far = None if cull_far is None else float(
                    np.linalg.norm(cam.center - lift.center) + cull_far * lift.radius)
                idx = cone_cull(frozen, cam, roi, far)
                op = build_operator(frozen, cam, roi=roi, min_weight=min_weight, mode=mode, subset=idx)
            else:
                op = build_operator(frozen, cam, roi=roi, min_weight=min_weight, mode=mode)
            seconds["operators"] += time.perf_counter() - ts
        ops_by_view[(clip, k)] = op
        if bar[0] is not None:
            bar[0].update(1)
        r = op.rendering
        return ClipFrame(r.rgb, r.depth, r.alpha, op.camera, clip, k)

    t0 = time.perf_counter()
    if progress:
        from tqdm import tqdm

        bar[0] = tqdm(total=None, desc="VAAS views", leave=False, file=sys.stderr)
    try:
        plan, flat_frames, spiral_frames = run_vaas(
            scene.means[lift.support], sigma, ref_small, lift.center, view, n_views=n_views,
            a_max_deg=a_max_deg, gamma=gamma, skip_deg=skip_deg, profile=profile,
            max_elevation_deg=max_elevation_deg,
            fit_radius=None if zoom_margin is None else zoom_margin * lift.radius, up=up_axis)
    finally:
        if bar[0] is not None:
            bar[0].close()
    seconds["vaas"] = time.perf_counter() - t0 - (seconds["operators"] - t_op)

    # 5. Tracking: propagate m* along each clip (frame 0 is the reference).
    t0 = time.perf_counter()
    views, clips, masks, ops = [], [], [], []
    clip_list = [("flat", flat_frames)] + ([("spiral", spiral_frames)] if spiral_frames else [])
    import inspect

    try:
        takes_refs = "references" in inspect.signature(tracker.track).parameters
    except (TypeError, ValueError):
        takes_refs = False
    labelled = []
    for name, frames in _progress(clip_list, len(clip_list), "tracking", progress):
        # Trackers that accept already labelled views (the model-free one)
        # get the flat clip as extra sources for the spiral.
        out = list(tracker.track(frames, seed_ref, references=labelled) if takes_refs
                   else tracker.track(frames, seed_ref))
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
            views.append(f.camera)
            clips.append(name)
            masks.append(m)
            ops.append(ops_by_view[(name, k)])
    seconds["tracking"] = time.perf_counter() - t0

    # 6. Solve for q, initialised from G0.
    t0 = time.perf_counter()
    stack = OperatorStack(ops, fingerprint=scene_fingerprint(scene))
    opts = dict(SOLVER_DEFAULTS.get(method, {}))
    opts.update(solver_options or {})
    result = solve(stack, masks, method=method, init=lift.support, **opts)
    # Gaussians seen (almost) only on unknown pixels carry no evidence; an
    # unregularised fit can still drive their logits anywhere on a trace of
    # weight, so they keep the prior (G0 membership) instead.
    q = np.asarray(result.q, dtype=np.float32).copy()
    evidence = np.zeros(len(scene))
    for op, m in zip(ops, masks):
        evidence += np.asarray(op.W.T @ (~np.isnan(m)).ravel().astype(np.float32), dtype=np.float64)
    weak = evidence < min_evidence
    q[weak] = lift.support[weak].astype(np.float32)
    tau = result.threshold if threshold is None else float(threshold)
    selected = q > tau
    seconds["solve"] = time.perf_counter() - t0

    settings = {"method": method, "n_views": int(n_views), "a_max_deg": float(a_max_deg),
                "gamma": float(gamma), "skip_deg": float(skip_deg), "profile": profile,
                "max_elevation_deg": float(max_elevation_deg), "orbit_scale": float(orbit_scale),
                "view_scale": float(scale), "max_view_pixels": max_view_pixels,
                "reference_scale": float(ref_scale), "max_reference_pixels": max_reference_pixels,
                "roi_margin": roi_margin, "min_weight": float(min_weight), "cull": bool(cull), "cull_far": cull_far,
                "min_evidence": float(min_evidence), "n_weak_evidence": int(weak.sum()), "zoom_margin": zoom_margin,
                "up": np.asarray(up_axis, float).tolist(), "threshold": float(tau), "mode": mode,
                "tracker": type(tracker).__name__,
                "grounder": None if grounder is None else type(grounder).__name__,
                "lift_options": dict(lift_options or {}), "solver_options": {
                    k: v for k, v in opts.items() if isinstance(v, (int, float, str, bool))}}
    return Extraction(scene, q, selected, tau, seed, prompt_info, camera, ref, lift, plan, views,
                      clips, masks, stack, result, seconds, settings)
