"""``extract()``: Algorithm 1 of the paper end to end, as a short sequence of named stages.

The stages and their records live in :mod:`seed2gs_inverse.pipeline.stages`
(one function each: render the reference, seed, reference view, lift, orbit
views, support band, tracking, evidence graph, mask completion, operators,
solve); the result is an :class:`~seed2gs_inverse.pipeline.extraction.Extraction`
(:mod:`seed2gs_inverse.pipeline.extraction`). This module resolves the
settings and the tracker, runs the stages in order, times them
(:class:`~seed2gs_inverse.progress.StageTimer`, leaving out the kernels'
compilation) and says how far it is as ``settings.progress`` asks
(:class:`~seed2gs_inverse.progress.Feedback`: bars, stage lines, or
nothing). Every rendering and operator comes from one
:class:`~seed2gs_inverse.raster.Renderer` of the scene.

All options live in one frozen :class:`~seed2gs_inverse.pipeline.settings.ExtractSettings`.
"""

from __future__ import annotations

import math
import warnings
from typing import TYPE_CHECKING, Any, Sequence

from .._threads import one_blas_thread, run_both
from ..camera import Camera
from ..errors import ValidationError
from ..frontend.base import ContactZoneTracker, SeedBandTracker, wants_regularizer
from ..frontend.model_free import GeometricTracker
from ..progress import Feedback, Progress, StageTimer
from ..operators import OperatorStack
from ..raster import FrozenScene, Renderer, compile_seconds
from ..scene import GaussianScene
from .completion import GRAPH_DEFAULTS
from .extraction import STAGES, Extraction, result_warnings
from .local import Neighbourhood, object_neighbourhood, support_reach
from .settings import MODEL_FREE_SMOOTHNESS, SOLVER_DEFAULTS, ExtractSettings
from .support import SUPPORT_DEFAULTS
from .stages import (OrbitViews, ReferenceView, Selection, complete_masks, evidence_graph, lift_seed, orbit_axis,
                     orbit_views, reference_view, render_reference, seed_from_prompt, solve_selection,
                     stack_operators, supervision_frames, support_band, track_clips, view_caps)

if TYPE_CHECKING:
    import scipy.sparse as sp

    from ..frontend.base import Grounder, LabelFiller, Tracker
    from .seed_lift import SeedLift

__all__ = ["Extraction", "extract", "Renderer", "ExtractSettings", "EXTRACT_DEFAULTS", "SOLVER_DEFAULTS", "STAGES",
           "MODEL_FREE_SMOOTHNESS", "ReferenceView", "OrbitViews", "Selection", "render_reference",
           "seed_from_prompt", "reference_view", "lift_seed", "orbit_axis", "orbit_views", "support_band",
           "track_clips", "evidence_graph", "complete_masks", "stack_operators", "solve_selection"]

#: Defaults of :func:`extract` beyond the VAAS ones (those of :class:`ExtractSettings`).
EXTRACT_DEFAULTS = {k: getattr(ExtractSettings, k) for k in (
    "orbit_scale", "max_view_pixels", "max_reference_pixels", "roi_margin", "zoom_margin", "min_weight",
    "cull_far", "min_evidence", "min_vote", "threshold", "smoothness", "completion")}


def _settings(settings: ExtractSettings | str | None, overrides: dict) -> ExtractSettings:
    """The settings of a call: ``settings`` (default ``ExtractSettings()``) with ``overrides`` replaced.

    A string in the place of ``settings`` is the solver method, as in
    ``extract(scene, camera, prompt, grounder, tracker, "voting")``.
    """
    if isinstance(settings, str):
        overrides = {"method": settings, **overrides}
        settings = None
    if settings is None:
        return ExtractSettings.from_dict(overrides) if overrides else ExtractSettings()
    if not isinstance(settings, ExtractSettings):
        raise ValidationError(f"settings must be an ExtractSettings (or None), got {type(settings).__name__}")
    return settings.replace(**overrides) if overrides else settings


def _check_inputs(scene: GaussianScene, camera: Camera) -> None:
    if not isinstance(scene, GaussianScene):
        raise ValidationError(f"scene must be a GaussianScene or FrozenScene, got {type(scene).__name__}")
    if len(scene) == 0:
        raise ValidationError("the scene has no Gaussians")
    if not isinstance(camera, Camera):
        raise ValidationError(f"camera must be a Camera, got {type(camera).__name__}")


def _trackers(tracker: Tracker | None, settings: ExtractSettings) -> tuple[Tracker, LabelFiller | None, float]:
    """(tracker, 2D filler or None, resolved smoothness) for the given tracker and settings.

    The default tracker is the model-free
    :class:`~seed2gs_inverse.frontend.model_free.GeometricTracker`.
    ``smoothness=None`` resolves to :data:`MODEL_FREE_SMOOTHNESS` for a
    tracker that declares ``wants_regularizer``
    (:func:`~seed2gs_inverse.frontend.base.wants_regularizer`), 0 for any
    other. ``completion="tracked"`` with the default tracker replaces its 2D
    fill of revealed pixels (which decides them from image neighbours and is
    the main source of wrong labels on an object's far side) by the 3D
    completion; the 2D fill (``filler``) then only decides what the
    completion leaves open.
    """
    filler = None
    if tracker is None and settings.completion == "tracked":
        tracker, filler = GeometricTracker(fill=False), GeometricTracker()
    tracker = GeometricTracker() if tracker is None else tracker
    smoothness = settings.smoothness
    if smoothness is None:
        smoothness = MODEL_FREE_SMOOTHNESS if wants_regularizer(tracker) else 0.0
    if not callable(getattr(tracker, "track", None)):
        raise ValidationError(f"tracker must have a track(frames, seed_mask, references=()) method, "
                              f"got {type(tracker).__name__}")
    return tracker, filler, float(smoothness)


def _neighbourhood(scene: GaussianScene | FrozenScene, lift: SeedLift, orbits: OrbitViews,
                   settings: ExtractSettings, stack: OperatorStack) -> Neighbourhood:
    """The Gaussians the stages after the orbit views work on (:func:`~.local.object_neighbourhood`).

    Every orbit view's columns (``stack``, the supervision views' stack,
    keeps its own for the solve), G0, and the ball holding the region of the
    evidence graph and of the faint Gaussians' rule and the support
    surface's annulus.
    """
    region = float({**GRAPH_DEFAULTS, **settings.graph_options}["region"])
    reach = max(region, support_reach(SUPPORT_DEFAULTS["inner"], SUPPORT_DEFAULTS["outer"]))
    others = [f.operator for _, frames in orbits.clips() for f in frames
              if not any(f.operator is v for v in stack.views)]
    return object_neighbourhood(scene, lift, [stack, *others], reach)


def _with_seed_band(tracker: Tracker, prompt_info: dict, settings: ExtractSettings, ref: ReferenceView) -> Tracker:
    """The tracker with its seed band set from ``mask_tolerance``, unless it has one or takes none.

    Mask and text prompts give masks drawn or made by a segmenter; box and
    point seeds are cut from the scene (band 0). The tolerance is in pixels
    of the reference camera, the band in those of the seed frame (``ref``).
    """
    if not isinstance(tracker, SeedBandTracker) or tracker.seed_band is not None:
        return tracker
    tolerance = settings.mask_tolerance if prompt_info.get("kind") in ("mask", "text") else 0
    return tracker.with_seed_band(math.ceil(tolerance * ref.scale))


def _supervision(scene: GaussianScene, lift: SeedLift, ref: ReferenceView, orbits: OrbitViews,
                 settings: ExtractSettings, tracker: Tracker, filler: LabelFiller | None, smoothness: float,
                 bar: Progress, local: Neighbourhood | None) -> tuple[list, list, sp.csr_matrix | None, dict, Tracker]:
    """The tracking stages: support band, tracking beside the evidence graph, mask completion.

    Returns ``(labelled, masks, graph, support report, tracker used)``. The
    evidence graph needs only the lift, so it is built on a second thread
    while the tracker runs on this one. ``local``: the object's neighbourhood
    the support surface and the graph are found in (None: the whole scene).
    """
    surface, support_info = support_band(scene, lift, orbits, settings, tracker, local)
    if surface is not None:
        tracker = tracker.with_support_plane(surface.axis, surface.point)
        if isinstance(tracker, ContactZoneTracker) and tracker.contact_zone is None:
            tracker = tracker.with_contact_zone(*surface.contact_zone())
    out = {}

    def work(k: int) -> None:
        if k == 0:
            out["labelled"] = track_clips(tracker, orbits, ref.seed, bar)
        else:
            out["graph"] = evidence_graph(scene, lift, settings, smoothness, local)

    run_both(work)
    labelled, graph = out["labelled"], out["graph"]
    masks = complete_masks(graph, labelled, lift, ref, settings.completion, filler)
    return labelled, masks, graph, support_info, tracker


def _resolved(s: ExtractSettings, ref: ReferenceView, orbits: OrbitViews, sel: Selection, support_info: dict,
              smoothness: float, tracker: Tracker, grounder: Grounder | None, notes: list) -> dict:
    """``Extraction.resolved``: what the run derived from its settings and inputs (JSON-ready)."""
    return {"view_scale": float(orbits.view_scale), "reference_scale": float(ref.scale),
            "up": orbits.up.tolist(), "up_method": orbits.up_info.get("method"),
            "up_confidence": orbits.up_info.get("confidence"), "threshold": float(sel.threshold),
            "solver_options": {k: v for k, v in s.solver_kwargs().items()
                               if isinstance(v, (int, float, str, bool))},
            "n_weak_evidence": sel.n_weak_evidence, "n_vote_capped": int(sel.result.info.get("n_vote_capped", 0)),
            "n_disconnected": sel.n_disconnected,
            "support": support_info,
            "smoothness": smoothness, "tracker": type(tracker).__name__,
            "seed_band": getattr(tracker, "seed_band", None),
            "grounder": None if grounder is None else type(grounder).__name__,
            # the orbit axis's warning was given when it was chosen; the report keeps it with the others
            "warnings": [w for w in [orbits.up_info.get("warning")] if w] + notes}


def extract(scene: GaussianScene | FrozenScene, camera: Camera, prompt: Any, grounder: Grounder | None = None,
            tracker: Tracker | None = None, settings: ExtractSettings | None = None, *,
            up_cameras: Sequence[Camera] | None = None, **overrides) -> Extraction:
    """Extract one object from a frozen 3DGS scene (Algorithm 1).

    Parameters
    ----------
    scene : GaussianScene or FrozenScene
        The frozen scene. A :class:`~seed2gs_inverse.raster.FrozenScene`
        keeps the scene's activations and spatial index: pass the same one
        to extract several objects from one scene, and each extraction
        then visits only the Gaussians near its object (the result is the
        same as with the plain scene; ``Extraction.scene`` is the plain one).
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
        ``extract(scene, cam, prompt, method="voting", n_views=12)``.

    Returns
    -------
    Extraction
        ``seconds`` holds the wall time per stage (:data:`STAGES`; the orbit
        views are rendered in the same pass as their operators, so that time
        counts under ``operators``, not ``vaas``), then ``compile``: the
        time spent compiling the rasterizer's kernels (a first run only),
        which no stage counts. ``resolved["caps"]`` names the view sizes
        that a pixel cap lowered (:func:`~.stages.view_caps`).

    Raises
    ------
    ValidationError
        An unknown option name (the message lists the valid ones), an
        invalid scene, camera, prompt or tracker, or a stage that cannot run
        (a camera that sees nothing, a seed on empty space).

    Warns
    -----
    UserWarning
        Why a finished run should not be trusted
        (:func:`~seed2gs_inverse.pipeline.extraction.result_warnings`, also
        in ``resolved["warnings"]``), and a weak or suspicious orbit axis.
    """
    s = _settings(settings, overrides)
    frozen = scene if isinstance(scene, FrozenScene) else None
    scene = scene.scene if frozen is not None else scene
    _check_inputs(scene, camera)
    tracker, filler, smoothness = _trackers(tracker, s)
    feedback = Feedback.of(s.progress)
    timer = StageTimer(STAGES, compile_clock=compile_seconds, feedback=feedback)
    renderer = Renderer(scene if frozen is None else frozen, s.mode)
    # Every stage calls BLAS on small products, view after view: one thread (see one_blas_thread).
    with feedback.active(), one_blas_thread():
        with timer("render"), feedback.bar("render", steps=False):
            reference = render_reference(renderer, camera)
        with timer("grounding"), feedback.bar("grounding", steps=False):
            seed, prompt_info = seed_from_prompt(prompt, reference, grounder, point_mode=s.point_mode, scene=scene,
                                                 camera=camera, mode=s.mode)
        with timer("operators", last=False), feedback.bar("reference view", steps=False):
            ref = reference_view(renderer, camera, seed, s.max_reference_pixels)
        tracker = _with_seed_band(tracker, prompt_info, s, ref)
        with timer("lift"), feedback.bar("lift", steps=False):
            lift = lift_seed(scene, ref, s.lift_options)
        before = renderer.operator_seconds
        with timer("vaas", last=False), feedback.bar("VAAS views", unit="view") as bar:
            orbits = orbit_views(renderer, camera, ref, lift, s, bar, up_cameras=up_cameras)
        # the orbit views are rendered in the pass that builds their operators: that time is the operators'
        timer.move("vaas", "operators", renderer.operator_seconds - before)
        timer.finish("vaas")
        timer.finish("operators")
        with timer("tracking"), feedback.bar("tracking", total=len(orbits.clips()), unit="clip") as bar:
            # the supervision views' stack, made once: the neighbourhood and the solve read its columns
            stack = stack_operators([(f, None) for f in supervision_frames(orbits)], scene)
            local = _neighbourhood(renderer.frozen, lift, orbits, s, stack)
            labelled, masks, graph, support_info, tracker = _supervision(scene, lift, ref, orbits, s, tracker,
                                                                         filler, smoothness, bar, local)
        with timer("solve"), feedback.bar(f"solve ({s.method})") as bar:
            stack = stack_operators(labelled, scene, built=stack)
            sel = solve_selection(stack, masks, lift, s, progress=bar.solve_callback, graph=graph,
                                  smoothness=smoothness, scene=scene, local=local, up=orbits.up)
    notes = result_warnings(ref, lift, masks, stack, sel)
    for note in notes:
        warnings.warn(note, stacklevel=2)
    resolved = _resolved(s, ref, orbits, sel, support_info, smoothness, tracker, grounder, notes)
    resolved["caps"] = view_caps(s, camera, ref, orbits)
    return Extraction(scene, sel.q, sel.selected, sel.threshold, seed, prompt_info, camera, reference, lift,
                      orbits.plan, [f.camera for f, _ in labelled], [f.clip for f, _ in labelled], masks, stack,
                      sel.result, timer.seconds, s, resolved, orbits.up_info, graph, sel.follow)
