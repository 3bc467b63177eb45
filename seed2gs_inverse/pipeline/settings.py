"""``ExtractSettings``: every option of :func:`~seed2gs_inverse.pipeline.extract`, in one frozen object.

The same object is what the CLI builds from its arguments and what
``report.json`` records (:meth:`ExtractSettings.to_dict`), so a report can be
turned back into the settings that produced it
(:meth:`ExtractSettings.from_dict`).
"""

from __future__ import annotations

import dataclasses
import inspect
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Callable, Mapping

import numpy as np

from .._validation import check_choice, check_int, check_real
from ..errors import ValidationError
from ..progress import check_progress
from ..solvers import available_methods, check_method_options
from .completion import GRAPH_DEFAULTS
from .seed_lift import seed_lift
from .vaas import DEFAULTS as VAAS_DEFAULTS

__all__ = ["ExtractSettings", "SOLVER_DEFAULTS", "MODES", "PROFILES", "LIMITS", "UP_CHOICES", "POINT_MODES",
           "COMPLETIONS", "MODEL_FREE_SMOOTHNESS"]

#: Solver options extract() uses unless told otherwise: started from G0, the
#: weighted BCE selection settles within a couple of dozen L-BFGS-B
#: iterations, and the iterations dominate the solve's time (chosen on
#: benchmarks/bench_extract.py against the solver's own default).
SOLVER_DEFAULTS = {"weighted_bce": {"max_iter": 20}}

#: Rasterization modes and spiral profiles extract accepts.
MODES = ("classic", "antialiased")
PROFILES = ("linear", "sin")


#: Ranges of seed_lift's real-valued options (its docstring says what each means).
_LIFT_RANGES = {"eps_rel": dict(lo=0.0), "eps_sigma": dict(lo=0.0), "min_membership": dict(lo=0.0, hi=1.0),
                "min_weight": dict(lo=0.0), "link_factor": dict(lo=0.0, lo_open=True),
                "keep_fraction": dict(lo=0.0, hi=1.0), "max_size_ratio": dict(lo=0.0, lo_open=True, optional=True)}


#: Bounds of the count options: far beyond any useful value, but an absurd
#: one (``n_views=10**7``) is refused up front instead of running for hours.
LIMITS = {"n_views": (2, 360), "mask_tolerance": (0, 64), "max_view_pixels": (64, 2 ** 24), "max_reference_pixels": (64, 2 ** 26),
          "k_neighbors": (1, 256), "graph_k": (1, 256)}


def _options(name, value) -> Mapping:
    """A read-only copy of a str-keyed mapping (None -> empty)."""
    if value is None:
        value = {}
    if not isinstance(value, Mapping):
        raise ValidationError(f"{name} must be a dict of keyword arguments, got {type(value).__name__}")
    bad = [k for k in value if not isinstance(k, str)]
    if bad:
        raise ValidationError(f"{name}: keys must be option names (str), got {bad!r}")
    return MappingProxyType(dict(value))


#: The named orbit axes (``up`` may also be a world vector).
UP_CHOICES = ("auto", "level", "camera")
#: What a point prompt seeds: the whole object grown in 3D, or the click's colour region.
POINT_MODES = ("object", "region")
#: Completion of the orbit masks' unknown pixels before the solve (None: off).
COMPLETIONS = (None, "reference", "tracked")
#: lambda of the graph regulariser when ``smoothness=None`` and the model-free
#: tracker is used (chosen on benchmarks/bench_extract.py).
MODEL_FREE_SMOOTHNESS = 1.0


def _up(value):
    if isinstance(value, str):
        return check_choice("up", value, UP_CHOICES)
    try:
        u = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        u = None
    if u is None or u.shape != (3,) or not np.all(np.isfinite(u)) or not np.any(u):
        raise ValidationError(f"up must be 'auto', 'level', 'camera' or a non-zero finite 3-vector, got {value!r}")
    big = float(np.max(np.abs(u)))
    if not 1e-100 < big < 1e100:  # a direction: rescaled where its length would under- or overflow later
        u = u / big
    return tuple(float(x) for x in u)


def _jsonable(v):
    if isinstance(v, Mapping):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (tuple, list, np.ndarray)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    return v


@dataclass(frozen=True)
class ExtractSettings:
    r"""Every option of :func:`~seed2gs_inverse.pipeline.extract` (same names, same defaults).

    Frozen: derive variants with ``dataclasses.replace(settings, n_views=12)``
    or :meth:`replace`. Every field is validated on construction; a bad value
    raises :class:`~seed2gs_inverse.errors.ValidationError` naming the option.
    Where a default was chosen by measurement, the benchmark that chose it is
    named; benchmarks/bench_extract.py scores whole extractions against exact
    truth on held-out views, benchmarks/bench_speed.py times them.

    Attributes
    ----------
    method : str
        Solver (:func:`seed2gs_inverse.solvers.available_methods`), default ``"weighted_bce"``.
    n_views, a_max_deg, gamma, skip_deg, profile, max_elevation_deg
        VAAS settings (:mod:`seed2gs_inverse.pipeline.vaas`): views per clip
        (``n_views`` in 2..360, default 24, the paper's), amplitude
        :math:`A_{max}` (``a_max_deg >= 0``, default 60) and exponent
        :math:`\gamma` (``gamma > 0``, default 1) of Eq. 5, the spiral's skip
        threshold (``skip_deg >= 0``, default 5, the paper's), the spiral's
        ``profile`` (``"linear"`` or ``"sin"``) and its elevation cap
        (``0 < max_elevation_deg < 90``, default 85). More views are not
        better with the model-free tracker: each frame's labels are warped
        from the labelled views nearest to it, so with more views the far
        side is reached through more hops, and a silhouette loses a little at
        each.
    orbit_scale : float
        Resolution of the orbit views relative to the reference camera, in
        (0, 4], default 0.5, ...
    max_view_pixels : int or None
        ... capped at about this many pixels per view (the sides are rounded
        to whole pixels, which may pass the cap by a row or a column); in
        64..2**24, None: no cap. Default 40,000, chosen on
        benchmarks/bench_speed.py: the orbit views are object-centric
        (zoomed), so this puts thousands of pixels on the object, while the
        operators' non-zeros, which grow with the pixels, dominate time and
        memory. When the cap lowers ``orbit_scale``,
        ``Extraction.resolved["caps"]`` says so.
    max_reference_pixels : int or None
        The reference view (seed lift, frame 0 of both clips, first
        supervision view) keeps the camera's resolution up to about this
        many pixels (rounded as above), composited only in a box around the
        seed; clip frames therefore differ in size between frame 0 and the
        rest. In 64..2**26, default 1,000,000; None: no cap. When it lowers
        the camera's resolution, ``Extraction.resolved["caps"]`` says so.
    roi_margin : float or None
        Orbit views composite only the pixel box around the projected sphere
        of radius ``roi_margin * extent`` about ``o`` (> 0, default 2: the
        lift sees the front of the object only, so its extent is
        conservative); pixels outside have empty operator rows and label 0.
        None: full views.
    zoom_margin : float or None
        Object-centric views: the orbit views (not the reference) zoom so
        that the sphere of radius ``zoom_margin * extent`` about ``o`` fits
        the image (> 0, default 2, for the same reason as ``roi_margin``).
        None keeps the reference's field of view.
    up : "auto", "level", "camera" or (3,) tuple of float
        Orbit axis. ``"auto"`` (default): world up from the support plane
        under the object, the scene's dominant plane, the reference's
        no-roll prior and the capture cameras passed to extract as
        ``up_cameras`` (:func:`~seed2gs_inverse.pipeline.up_axis.estimate_up_axis`);
        the axis, the method that chose it and its confidence are in
        ``report()["up"]``, and a weak estimate warns (naming ``--up``).
        ``"level"``: the reference camera's image-up with its pitch removed
        (:func:`~seed2gs_inverse.pipeline.up_axis.estimate_up`); ``"camera"``:
        the image-up itself (literal reading of the paper; the flat orbit
        then tilts by the camera's pitch); or a non-zero finite world vector.
    min_weight : float
        Orbit operators drop compositing weights below this, in [0, 1]
        (:func:`~seed2gs_inverse.raster.build_operator`): fewer non-zeros,
        faster solves, ``W 1`` short of alpha by at most the dropped
        weights; 0 keeps every weight (exact operators). Default 0.01, chosen
        on benchmarks/bench_extract.py and benchmarks/bench_speed.py: most
        non-zeros are faint tails of Gaussians behind or beside the surface
        a pixel shows, and they blur the selection's boundary, while larger
        values lose the smallest seeds.
    cull : bool
        Rasterize each orbit view from only the Gaussians inside the cone of
        its roi (widened by their 3-sigma size) and map the operator's
        columns back; the operator is the same, the time scales with what
        the view can see instead of with the scene. Default True.
    cull_far : float or None
        With ``cull``, orbit views also leave out what lies farther than
        ``cull_far * extent`` behind ``o`` (> 0, default 4, twice the roi
        sphere): far background contributes nothing but compositing work and
        pixels that can only be background. Such pixels render empty (label
        0, empty operator rows), and those Gaussians stay unobserved (prior
        0) unless a nearer view sees them. None keeps everything (exact
        operators).
    near_margin : float or None
        With ``cull``, orbit views also leave out the Gaussians whose
        centres lie in front of the plane ``near_margin * extent`` before
        ``o`` (depth along the roi's axis below ``|c - o| - near_margin *
        extent``; > 0), except the flat, level ones about the orbit axis
        (the ground or table top the object stands on, as the support
        surface takes them, whose cut edge would otherwise show next to the
        object's base). The orbit cameras are virtual: a chair, a post or a plant
        standing between one and the object need not hide the object. Such
        a view is a view of the scene without those Gaussians: their columns
        of its operator are empty, so the view neither labels nor weighs
        them, and the tracker's masks are of the view as rendered. Where
        the object reaches farther than the plane towards the camera, its
        own nearest parts are cut in that view and it shows its inside
        there; other views see those parts. The reference view is never
        cut. Default 1, chosen on benchmarks/bench_extract.py and on posts
        around an object (tests/test_occluded_views.py). None: no near cut.
    min_evidence : float
        A Gaussian whose summed compositing weight over the *decided*
        (non-NaN) pixels of all views is below this (>= 0, default 1, the
        weight of one opaque pixel) has no real evidence: its ``q`` is
        reset to the prior (1 in G0, else 0), or with the regulariser
        (``smoothness`` > 0) it is decided by its neighbours; without this,
        an unregularised fit can drive such Gaussians to 1 on a trace of
        weight. A part of the object that the tracker leaves unknown
        (hidden in the reference, revealed in the orbit views) otherwise
        follows the few Gaussians that a trace of background weight fixed
        at 0 (pixels where an occluder or the ground dominates and the part
        shows only faintly), not the body. Passed to
        :func:`~seed2gs_inverse.solvers.solve` as its ``min_evidence``.
    min_vote : float
        A Gaussian outside G0 with evidence (``min_evidence``) whose masks
        call it object on less than this share of its decided weight (in
        [0, 1], default 0.2) ends at 0, whatever the fit gave it. The
        per-pixel loss otherwise selects large splats of the ground under an
        object's base: the base's few object pixels, which the object alone
        cannot fill, outweigh their many background pixels. Passed to
        :func:`~seed2gs_inverse.solvers.solve` as its ``min_vote``
        (``info["n_vote_capped"]`` counts them). 0: off.
    mask_tolerance : int
        How far, in pixels of the reference camera, a mask prompt (or the
        grounder's mask for a text prompt) may miss its object's edge, in
        0..64 (default 3, chosen on benchmarks/bench_extract.py
        ``--mask-error``). The model-free tracker copies no seed label from
        within that distance of an edge that the reference view does not
        back with a depth step or, at the contact, a colour step
        (``GeometricTracker(seed_band=)``, at the reference's resolution);
        0: the mask is trusted to the pixel. Box and point seeds are
        trusted as they are (they are cut from the scene); a tracker with
        a ``seed_band`` of its own keeps it.
    threshold : float or None
        ``tau`` of Eq. 9, in [0, 1); None (default): the solver's own (0.5).
    lift_options : mapping (read-only)
        Keyword arguments of :func:`~seed2gs_inverse.pipeline.seed_lift.seed_lift`,
        each checked against its range here (``k_neighbors`` in 1..256).
    solver_options : mapping (read-only)
        Keyword arguments of the solver method, on top of
        :data:`SOLVER_DEFAULTS`; count options within
        :data:`seed2gs_inverse.solvers.COUNT_LIMITS`.
    mode : {"classic", "antialiased"}
        Rasterization mode of every rendering, default ``"classic"``.
    progress : None, bool, "bars" or "lines"
        What the run says on stderr while it runs
        (:meth:`seed2gs_inverse.progress.Feedback.of`). ``"bars"`` (or True):
        a progress bar for every stage that lasts over a second (counting
        the orbit views, the tracked clips and the solve's iterations with
        its current loss; the others show their elapsed time); ``"lines"``:
        one line per stage as it ends, with its seconds, for a log or a
        pipe; False: nothing. All but False also say when the rasterizer's
        kernels compile on a first run, and for how long (those seconds are
        counted under ``seconds["compile"]``, not under the stage that
        compiled). Default None: bars when stderr is a terminal, otherwise
        only the compile notices, so that a script's log gets no bars and no
        stage lines it did not ask for. Never affects the result.
    point_mode : {"object", "region"}
        Point prompts: ``"object"`` (default) grows the clicked region to
        the whole object in 3D, stopping at the support plane
        (:func:`~seed2gs_inverse.pipeline.point_object.point_object_mask`);
        ``"region"``: the colour-and-depth region of the click alone. Other
        prompts ignore it.
    smoothness : float or None
        lambda >= 0 of the graph-Laplacian regulariser of the solve
        (``solve(..., smoothness=, graph=)``,
        :func:`~seed2gs_inverse.solvers.smoothing.laplacian_smooth` on
        :func:`~seed2gs_inverse.pipeline.completion.object_graph`): Gaussians
        without evidence take the harmonic extension of their neighbours
        instead of the prior (replaces the ``min_evidence`` reset). 0: off.
        None (default): :data:`MODEL_FREE_SMOOTHNESS` with the model-free
        tracker (whose 2D fill leaves undecided what is not unanimous), 0
        with any other tracker (SAM2 and the like: Algorithm 1 with its 2D
        masks as the only evidence, unseen Gaussians keep the prior). The
        value used is ``resolved["smoothness"]`` in the report.
    completion : {None, "reference", "tracked"}
        Fill the unknown pixels of the orbit masks, before the solve, with a
        random-walker completion on the same graph rendered into each view
        (:func:`~seed2gs_inverse.pipeline.completion.fill_unknown`), seeded by
        the reference's labels alone (``"reference"``,
        :func:`~seed2gs_inverse.pipeline.completion.complete_membership`) or by
        every pixel the tracker decided (``"tracked"``,
        :func:`~seed2gs_inverse.pipeline.completion.tracked_membership`; the
        default tracker then runs without its 2D fill, which instead decides
        only the pixels the 3D completion leaves undecided). None (default): off.
    seed_connected : bool
        Leave out islands of the selection apart from G0 (the lifted set),
        :func:`~seed2gs_inverse.pipeline.islands.seed_connected` with its
        default ``island_fraction`` and ``island_vote`` and the masks' votes;
        their ``q`` becomes 0. Default True: a few wrong mask pixels below an
        object's edge can make the solver (and the regulariser after it)
        select a mostly hidden background surface under the object, apart
        from it. The count is ``resolved["n_disconnected"]``. False: the
        solver's selection as it is.
    follow_faint : bool
        Faint Gaussians near the object (activated opacity below the graph's
        ``min_opacity``, within its ``region``) take the membership of their
        nearest opaque neighbours after the solve
        (:func:`~seed2gs_inverse.pipeline.completion.faint_follow_matrix`).
        Default True: their evidence is a trace, and left to the prior the
        translucent shells and inner layers of an object stay in the
        remainder as a see-through copy of it. Then the unselected
        Gaussians whose centres every supervision view shows inside the
        selection's footprint, at or above its base, take the membership of
        their nearest selected Gaussian
        (:func:`~seed2gs_inverse.pipeline.completion.follow_enclosed`): their
        only weight above ``min_weight`` lies where their splats reach past
        the silhouette, on background pixels. False: the solver's
        membership for both.
    follow_weak : bool
        Unselected Gaussians near the object (within the graph's
        ``region``) whose stored weight reaches
        ``WEAK_DEFAULTS["max_weight"]`` in no view take the inverse-distance
        mean membership of their nearest Gaussians that do, at or above the
        selection's base along the orbit axis
        (:func:`~seed2gs_inverse.pipeline.completion.follow_weak`), after
        the rules of ``follow_faint``, whose enclosed rule then runs once
        more on the selection this one grew. Default True: such a Gaussian never
        dominates a pixel (inner and back layers, splats crossing the
        surface), its pixels' labels are other Gaussians', and left out
        it stays in the remainder as a see-through copy of the object.
        False: the membership as the rules before leave it.
    support_background : bool
        The model-free tracker labels the support surface (the ground under
        the object) background in every orbit view (default True): pixels
        in the band of :func:`~seed2gs_inverse.pipeline.support.support_surface`
        (the level of the flat, level splats around the object's footprint)
        whose rendered surface is level, unless the reference saw them as
        object (``GeometricTracker(support_plane=)``). Labels copied and
        filled across the contact line (table legs in grass, the shadowed
        ground between them) otherwise grow around the orbit. Just above
        the band and within the object's reach (the surface's
        ``contact_zone``), background labels the tracker copies onto
        surfaces that are not level (the object's base) are left unknown
        (``GeometricTracker(contact_zone=)``). Used only when
        the orbit axis is trusted (given as a vector, or estimated with
        confidence >= :data:`~seed2gs_inverse.pipeline.up_axis.WEAK_CONFIDENCE`)
        and the annulus shows a level; ``resolved["support"]`` says whether
        and why not. Other trackers (SAM2) are unaffected.
    graph_options : mapping (read-only)
        Keywords of :func:`~seed2gs_inverse.pipeline.completion.object_graph`
        (``k`` in 1..256, ``sigma_color``, ``sigma_normal`` (positive or
        None), ``region`` (> 0, in lift radii), ``min_opacity`` in [0, 1)),
        on top of :data:`~seed2gs_inverse.pipeline.completion.GRAPH_DEFAULTS`.
    """

    method: str = "weighted_bce"
    n_views: int = VAAS_DEFAULTS["n_views"]
    a_max_deg: float = VAAS_DEFAULTS["a_max_deg"]
    gamma: float = VAAS_DEFAULTS["gamma"]
    skip_deg: float = VAAS_DEFAULTS["skip_deg"]
    profile: str = VAAS_DEFAULTS["profile"]
    max_elevation_deg: float = VAAS_DEFAULTS["max_elevation_deg"]
    orbit_scale: float = 0.5
    max_view_pixels: int | None = 40_000
    max_reference_pixels: int | None = 1_000_000
    roi_margin: float | None = 2.0
    zoom_margin: float | None = 2.0
    up: Any = "auto"
    min_weight: float = 0.01
    cull: bool = True
    cull_far: float | None = 4.0
    min_evidence: float = 1.0
    threshold: float | None = None
    lift_options: Mapping = field(default_factory=dict)
    solver_options: Mapping = field(default_factory=dict)
    mode: str = "classic"
    progress: bool | str | None = None
    point_mode: str = "object"
    smoothness: float | None = None
    completion: str | None = None
    graph_options: Mapping = field(default_factory=dict)
    seed_connected: bool = True
    support_background: bool = True
    follow_faint: bool = True
    near_margin: float | None = 1.0
    follow_weak: bool = True
    min_vote: float = 0.2
    mask_tolerance: int = 3

    def __post_init__(self):
        set_ = object.__setattr__.__get__(self)
        methods = available_methods()
        if not isinstance(self.method, str) or self.method not in methods:
            raise ValidationError(f"unknown solver method {self.method!r}; available: {', '.join(methods)}")
        n = check_int("n_views", self.n_views, lo=LIMITS["n_views"][0], hi=LIMITS["n_views"][1])
        set_("n_views", n)
        set_("a_max_deg", check_real("a_max_deg", self.a_max_deg, lo=0.0))
        set_("gamma", check_real("gamma", self.gamma, lo=0.0, lo_open=True))
        set_("skip_deg", check_real("skip_deg", self.skip_deg, lo=0.0))
        set_("profile", check_choice("profile", self.profile, PROFILES))
        me = check_real("max_elevation_deg", self.max_elevation_deg, lo=0.0, lo_open=True)
        if me >= 90.0:
            raise ValidationError(f"max_elevation_deg must be < 90, got {self.max_elevation_deg!r}")
        set_("max_elevation_deg", me)
        set_("orbit_scale", check_real("orbit_scale", self.orbit_scale, lo=0.0, lo_open=True, hi=4.0))
        for name in ("max_view_pixels", "max_reference_pixels"):
            lo, hi = LIMITS[name]
            set_(name, check_int(name, getattr(self, name), lo=lo, hi=hi, optional=True))
        set_("roi_margin", check_real("roi_margin", self.roi_margin, lo=0.0, lo_open=True, optional=True))
        set_("zoom_margin", check_real("zoom_margin", self.zoom_margin, lo=0.0, lo_open=True, optional=True))
        set_("up", _up(self.up))
        set_("min_weight", check_real("min_weight", self.min_weight, lo=0.0, hi=1.0))
        if not isinstance(self.cull, (bool, np.bool_)):
            raise ValidationError(f"cull must be True or False, got {self.cull!r}")
        set_("cull", bool(self.cull))
        set_("cull_far", check_real("cull_far", self.cull_far, lo=0.0, lo_open=True, optional=True))
        set_("min_evidence", check_real("min_evidence", self.min_evidence, lo=0.0))
        set_("min_vote", check_real("min_vote", self.min_vote, lo=0.0, hi=1.0))
        lo, hi = LIMITS["mask_tolerance"]
        set_("mask_tolerance", check_int("mask_tolerance", self.mask_tolerance, lo=lo, hi=hi))
        # q lies in [0, 1]: tau outside [0, 1) (or NaN) would select nothing, silently.
        set_("threshold", check_real("threshold", self.threshold, lo=0.0, optional=True))
        if self.threshold is not None and not self.threshold < 1.0:
            raise ValidationError(f"threshold must be in [0, 1) (q > threshold is the object), got {self.threshold!r}")
        lift = _options("lift_options", self.lift_options)
        lift_known = [k for k, p in _keyword_only(seed_lift).items()]
        bad = sorted(set(lift) - set(lift_known))
        if bad:
            raise ValidationError(f"lift_options: seed_lift has no option(s) {bad}; its options are {lift_known}")
        if "k_neighbors" in lift:
            check_int("lift_options k_neighbors", lift["k_neighbors"], lo=LIMITS["k_neighbors"][0],
                 hi=LIMITS["k_neighbors"][1])
        for name, kw in _LIFT_RANGES.items():  # the others, checked here and not mid-pipeline
            if name in lift:
                check_real(f"lift_options {name}", lift[name], **kw)
        set_("lift_options", lift)
        solver = _options("solver_options", self.solver_options)
        check_method_options(self.method, dict(solver))
        set_("solver_options", solver)
        set_("mode", check_choice("mode", self.mode, MODES))
        set_("progress", check_progress(self.progress))
        set_("point_mode", check_choice("point_mode", self.point_mode, POINT_MODES))
        set_("smoothness", check_real("smoothness", self.smoothness, lo=0.0, optional=True))
        if not (self.completion is None or isinstance(self.completion, str)) or self.completion not in COMPLETIONS:
            raise ValidationError(f"completion must be None, 'reference' or 'tracked', got {self.completion!r}")
        set_("graph_options", _graph_options(self.graph_options))
        for name in ("seed_connected", "support_background", "follow_faint", "follow_weak"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValidationError(f"{name} must be True or False, got {getattr(self, name)!r}")
            set_(name, bool(getattr(self, name)))
        set_("near_margin", check_real("near_margin", self.near_margin, lo=0.0, lo_open=True, optional=True))

    # -- derived -------------------------------------------------------------
    def solver_kwargs(self) -> dict:
        """The method's options: :data:`SOLVER_DEFAULTS` for the method, then ``solver_options``."""
        opts = dict(SOLVER_DEFAULTS.get(self.method, {}))
        opts.update(self.solver_options)
        return opts

    # -- conversion ----------------------------------------------------------
    @classmethod
    def names(cls) -> list:
        """The option names, in declaration order."""
        return [f.name for f in dataclasses.fields(cls)]

    def replace(self, **changes) -> "ExtractSettings":
        """A copy with ``changes``; unknown names raise a ValidationError listing the valid ones."""
        _check_names(changes, "extract() has no option(s)")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """JSON-ready dict of every option (``up`` a list when it is a vector)."""
        return {name: _jsonable(getattr(self, name)) for name in self.names()}

    @classmethod
    def from_dict(cls, data: Mapping) -> "ExtractSettings":
        """The settings of :meth:`to_dict` (missing keys take their defaults).

        Raises
        ------
        ValidationError
            ``data`` is not a mapping, has unknown keys (the message lists the
            valid ones) or a value that fails validation.
        """
        if not isinstance(data, Mapping):
            raise ValidationError(f"extract settings must be a dict, got {type(data).__name__}")
        _check_names(data, "extract settings have no option(s)")
        return cls(**dict(data))


def _graph_options(value) -> Mapping:
    """``graph_options``: names of object_graph's keywords, each value in its range."""
    opts = _options("graph_options", value)
    bad = sorted(set(opts) - set(GRAPH_DEFAULTS))
    if bad:
        raise ValidationError(f"graph_options: object_graph has no option(s) {bad}; its options are "
                              f"{list(GRAPH_DEFAULTS)}")
    if "k" in opts:
        check_int("graph_options k", opts["k"], lo=LIMITS["graph_k"][0], hi=LIMITS["graph_k"][1])
    for name in ("sigma_color", "sigma_normal"):
        if name in opts:
            check_real(f"graph_options {name}", opts[name], lo=0.0, lo_open=True, optional=True)
    if "region" in opts:
        check_real("graph_options region", opts["region"], lo=0.0, lo_open=True)
    if "min_opacity" in opts:
        v = check_real("graph_options min_opacity", opts["min_opacity"], lo=0.0)
        if not v < 1.0:
            raise ValidationError(f"graph_options min_opacity must be < 1, got {opts['min_opacity']!r}")
    return opts


def _keyword_only(fn: Callable) -> dict:
    """The keyword-only parameters of ``fn``, by name."""
    return {k: p for k, p in inspect.signature(fn).parameters.items() if p.kind == p.KEYWORD_ONLY}


def _check_names(keys, what: str) -> None:
    valid = ExtractSettings.names()
    bad = sorted(str(k) for k in keys if k not in valid)
    if bad:
        raise ValidationError(f"{what} {bad}; valid names: {', '.join(valid)}")
