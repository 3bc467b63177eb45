"""``ExtractSettings``: every option of :func:`~seed2gs_inverse.pipeline.extract`, in one frozen object.

The same object is what the CLI builds from its arguments and what
``report.json`` records (:meth:`ExtractSettings.to_dict`), so a report can be
turned back into the settings that produced it
(:meth:`ExtractSettings.from_dict`).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from ..errors import ValidationError
from .vaas import DEFAULTS as VAAS_DEFAULTS

__all__ = ["ExtractSettings", "SOLVER_DEFAULTS", "MODES", "PROFILES", "LIMITS", "UP_CHOICES", "POINT_MODES",
           "COMPLETIONS", "MODEL_FREE_SMOOTHNESS"]

#: Solver options extract() uses unless told otherwise: the weighted BCE
#: selection settles within a couple of dozen L-BFGS-B iterations when
#: started from G0, and the iterations dominate the solve's time. On
#: benchmarks/bench_extract.py (13 cases, load 1.2-1.4) 20 iterations gave,
#: when chosen, no case's mIoU lower than 30 (mean held-out mIoU / mBIoU / 3D
#: IoU 0.973 / 0.913 / 0.928 against 0.973 / 0.913 / 0.927); the suite gives
#: 0.974 / 0.917 / 0.928 today (load 1.0-1.4). 200 (the solver's own default)
#: scored as 30 on the procedural scenes and the firepit+unicorn benchmark
#: when 30 was chosen.
SOLVER_DEFAULTS = {"weighted_bce": {"max_iter": 20}}

#: Rasterization modes and spiral profiles extract accepts.
MODES = ("classic", "antialiased")
PROFILES = ("linear", "sin")


def _real(name, value, *, lo=None, hi=None, lo_open=False, optional=False) -> float | None:
    """``value`` as a finite float in the given range, or a ValidationError naming ``name``."""
    if value is None and optional:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        kind = "a number or None" if optional else "a number"
        raise ValidationError(f"{name} must be {kind}, got {value!r} ({type(value).__name__})")
    try:
        v = float(value)
    except OverflowError:  # an int beyond float's range (10**400)
        v = math.inf
    if not math.isfinite(v):
        raise ValidationError(f"{name} must be finite, got {value!r}")
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise ValidationError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {value!r}")
    if hi is not None and v > hi:
        raise ValidationError(f"{name} must be <= {hi}, got {value!r}")
    return v


#: Ranges of seed_lift's real-valued options (its docstring says what each means).
_LIFT_RANGES = {"eps_rel": dict(lo=0.0), "eps_sigma": dict(lo=0.0), "min_membership": dict(lo=0.0, hi=1.0),
                "min_weight": dict(lo=0.0), "link_factor": dict(lo=0.0, lo_open=True),
                "keep_fraction": dict(lo=0.0, hi=1.0), "max_size_ratio": dict(lo=0.0, lo_open=True, optional=True)}


def _int(name, value, *, lo, hi, optional=False) -> int | None:
    """``value`` as an int in ``lo..hi``, or a ValidationError naming ``name`` and the range."""
    if value is None and optional:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        kind = "an integer or None" if optional else "an integer"
        raise ValidationError(f"{name} must be {kind} in {lo:,}..{hi:,}, got {value!r} ({type(value).__name__})")
    if not lo <= int(value) <= hi:
        raise ValidationError(f"{name} must be in {lo:,}..{hi:,}, got {value!r}")
    return int(value)


#: Bounds of the count options: far beyond any useful value, but an absurd
#: one (``n_views=10**7``) is refused up front instead of running for hours.
LIMITS = {"n_views": (2, 360), "max_view_pixels": (64, 2 ** 24), "max_reference_pixels": (64, 2 ** 26),
          "k_neighbors": (1, 256), "graph_k": (1, 256)}


def _choice(name, value, choices) -> str:
    if not isinstance(value, str) or value not in choices:
        raise ValidationError(f"{name} must be one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


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
#: tracker is used (measured on benchmarks/bench_extract.py; see its docstring).
MODEL_FREE_SMOOTHNESS = 1.0


def _up(value):
    if isinstance(value, str):
        return _choice("up", value, UP_CHOICES)
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
    """Every option of :func:`~seed2gs_inverse.pipeline.extract` (same names, same defaults).

    Frozen: derive variants with ``dataclasses.replace(settings, n_views=12)``
    or :meth:`replace`. Every field is validated on construction; a bad value
    raises :class:`~seed2gs_inverse.errors.ValidationError` naming the option.

    Attributes
    ----------
    method : str
        Solver (:func:`seed2gs_inverse.solvers.available_methods`), default ``"weighted_bce"``.
    n_views, a_max_deg, gamma, skip_deg, profile, max_elevation_deg
        VAAS settings (:mod:`seed2gs_inverse.pipeline.vaas`): paper defaults
        24 views per clip and 5 degrees; A_max = 60 degrees and gamma = 1 are
        our documented choices. More views are not better with the
        model-free tracker: each frame's labels are warped from the labelled
        views nearest to it, so with many views the far side is reached
        through more hops, and a silhouette loses a little at each (a
        review saw the selection of a small procedural sphere shrink
        steadily as ``n_views`` grew from 6 to 96, at a 96x72 reference).
        Ranges: ``n_views`` in 2..360, ``a_max_deg >= 0``, ``gamma > 0``,
        ``skip_deg >= 0``, ``profile`` ``"linear"`` or ``"sin"``,
        ``0 < max_elevation_deg < 90`` (default 85).
    orbit_scale : float
        Resolution of the orbit views relative to the reference camera,
        default 0.5, in (0, 4] ...
    max_view_pixels : int or None
        ... capped at about this many pixels per view (40k; the sides are
        rounded to whole pixels, which may pass the cap by a row or a
        column: 267x150 = 40,050 for a 960x540 reference). The orbit views
        are object-centric (zoomed), so
        even this resolution puts a few thousand pixels on the object, and
        the operators (non-zeros) dominate time and memory: on the
        firepit + unicorn extraction of benchmarks/bench_speed.py, 160k
        pixels per view (``--set max_view_pixels=160000``, load 0.1-0.5)
        took 7.1 s per extraction with held-out mIoU 0.963, against 3.1 s
        and 0.985 with the default (load 0.4-1.0). None: no cap; else in
        64..2**24.
    max_reference_pixels : int or None
        The reference view (seed lift, frame 0 of both clips, first
        supervision view) keeps the camera's resolution up to about this
        many pixels (1M, rounded as above), composited only in a box around
        the seed. Clip frames
        therefore differ in size between frame 0 and the rest. None: no
        cap; else in 64..2**26.
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
    up : "auto", "level", "camera" or (3,) tuple of float
        Orbit axis. ``"auto"`` (default): world up from the support plane
        under the object, the scene's dominant plane, the reference's
        no-roll prior and the capture cameras passed to extract as
        ``up_cameras`` (:func:`~seed2gs_inverse.pipeline.up_axis.estimate_up_axis`);
        the axis, the method that chose it and its confidence are in
        ``report()["up"]``, and a weak estimate warns (naming ``--up``).
        ``"level"`` (the default before issue 10): the reference camera's
        image-up with its pitch removed
        (:func:`~seed2gs_inverse.pipeline.vaas.estimate_up`); ``"camera"``:
        the image-up itself (literal reading of the paper; the flat orbit
        then tilts by the camera's pitch); or a world vector.
    min_weight : float
        Orbit operators drop compositing weights below this
        (:func:`~seed2gs_inverse.raster.build_operator`): fewer
        non-zeros, faster solves, ``W 1`` short of alpha by at most the
        dropped weights. Default 0.01: most non-zeros are faint tails of
        Gaussians behind or beside the surface a pixel shows (``stack
        nnz`` of benchmarks/bench_speed.py with ``--set min_weight=0``
        against the default), and they blur the selection's boundary.
        benchmarks/bench_extract.py (13 cases) gives mean held-out mIoU /
        mBIoU / 3D IoU 0.974 / 0.917 / 0.928 (load 1.0-1.4) against 0.973
        / 0.908 / 0.923 with 0 (exact operators; ``--set min_weight=0``,
        load 0.9-1.8); the extraction of benchmarks/bench_speed.py takes
        3.1 s (load 0.4-1.0) against 4.2 s with 0 (16.3 M non-zeros
        against 51.4 M; load 0.5-0.9). 0.03 loses on the smallest seed
        (yard-box-55). 0 keeps every weight.
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
        reset to the prior (1 in G0, else 0), or with the regulariser
        (``smoothness`` > 0, the default with the model-free tracker) it is
        decided by its neighbours. Without this, an unregularised
        fit can drive such Gaussians to 1 on a trace of weight. Passed to
        :func:`~seed2gs_inverse.solvers.solve` as its ``min_evidence``.
    threshold : float or None
        ``tau`` of Eq. 9, in [0, 1); None: the solver's own (0.5).
    lift_options : mapping (read-only)
        Keyword arguments of :func:`~seed2gs_inverse.pipeline.seed_lift.seed_lift`
        (``k_neighbors`` in 1..256).
    solver_options : mapping (read-only)
        Keyword arguments of the solver method, on top of
        :data:`SOLVER_DEFAULTS` (``max_iter=20`` for ``weighted_bce``); count
        options within :data:`seed2gs_inverse.solvers.COUNT_LIMITS`.
    mode : {"classic", "antialiased"}
        Rasterization mode of every rendering.
    progress : bool or None
        Progress bars on stderr (orbit views, tracking, and the solve's
        iterations with its current loss); default None: only when stderr is
        a terminal, so logs never fill with bars.
    point_mode : {"object", "region"}
        Point prompts: ``"object"`` (default) grows the clicked region to
        the whole object in 3D, stopping at the support plane
        (:func:`~seed2gs_inverse.pipeline.point_object.point_object_mask`);
        ``"region"``: the colour-and-depth region of the click alone (the
        behaviour before issue 10). Other prompts ignore it.
    smoothness : float or None
        lambda of the graph-Laplacian regulariser of the solve
        (``solve(..., smoothness=, graph=)``,
        :func:`~seed2gs_inverse.solvers.smoothing.laplacian_smooth` on
        :func:`~seed2gs_inverse.pipeline.completion.object_graph`): Gaussians
        without evidence take the harmonic extension of their neighbours
        instead of the prior (replaces the ``min_evidence`` reset). 0: off.
        None (default): :data:`MODEL_FREE_SMOOTHNESS` (1) with the
        model-free tracker (whose 2D fill leaves undecided what is not
        unanimous), 0 with any other tracker (SAM2 & co.: Algorithm 1 with
        its 2D masks as the only evidence, unseen Gaussians keep the prior).
        The value used is ``resolved["smoothness"]`` in the report.
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
        Leave out islands of the selection apart from the seed lift's G0
        (:func:`~seed2gs_inverse.pipeline.seed_lift.seed_connected`: the
        lift's neighbour graph over the selection; components without a G0
        Gaussian holding at least 0.5 % as many Gaussians as those with
        one, unless the masks call them object: 90 % of their weight on
        decided pixels lies on object pixels); their ``q`` becomes 0.
        Default True. A few wrong mask pixels
        below an object's edge can make the solver (and the regulariser
        after it) select a mostly hidden background surface under the
        object, apart from it. The count is ``resolved["n_disconnected"]``.
        False: the solver's selection as it is.
    support_background : bool
        The model-free tracker labels the support surface under the object
        background in every orbit view (default True): pixels in the band
        of :func:`~seed2gs_inverse.pipeline.support.support_surface` (the
        level of the flat, level splats around the object's footprint)
        whose rendered surface is level, unless the reference saw them as
        object (``GeometricTracker(support_plane=)``). Without it, labels
        copied and filled across the contact line (table legs in grass,
        the shadowed ground between them) grew around the orbit, and the
        ground under a table was selected. Used only when the orbit axis
        is trusted (given as a vector, or estimated with confidence >= 0.5)
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
    min_evidence: float = 0.05
    threshold: float | None = None
    lift_options: Mapping = field(default_factory=dict)
    solver_options: Mapping = field(default_factory=dict)
    mode: str = "classic"
    progress: bool | None = None
    point_mode: str = "object"
    smoothness: float | None = None
    completion: str | None = None
    graph_options: Mapping = field(default_factory=dict)
    seed_connected: bool = True
    support_background: bool = True

    def __post_init__(self):
        from ..solvers import available_methods, check_method_options
        from .seed_lift import seed_lift

        set_ = object.__setattr__.__get__(self)
        methods = available_methods()
        if not isinstance(self.method, str) or self.method not in methods:
            raise ValidationError(f"unknown solver method {self.method!r}; available: {', '.join(methods)}")
        n = _int("n_views", self.n_views, lo=LIMITS["n_views"][0], hi=LIMITS["n_views"][1])
        set_("n_views", n)
        set_("a_max_deg", _real("a_max_deg", self.a_max_deg, lo=0.0))
        set_("gamma", _real("gamma", self.gamma, lo=0.0, lo_open=True))
        set_("skip_deg", _real("skip_deg", self.skip_deg, lo=0.0))
        set_("profile", _choice("profile", self.profile, PROFILES))
        me = _real("max_elevation_deg", self.max_elevation_deg, lo=0.0, lo_open=True)
        if me >= 90.0:
            raise ValidationError(f"max_elevation_deg must be < 90, got {self.max_elevation_deg!r}")
        set_("max_elevation_deg", me)
        set_("orbit_scale", _real("orbit_scale", self.orbit_scale, lo=0.0, lo_open=True, hi=4.0))
        for name in ("max_view_pixels", "max_reference_pixels"):
            lo, hi = LIMITS[name]
            set_(name, _int(name, getattr(self, name), lo=lo, hi=hi, optional=True))
        set_("roi_margin", _real("roi_margin", self.roi_margin, lo=0.0, lo_open=True, optional=True))
        set_("zoom_margin", _real("zoom_margin", self.zoom_margin, lo=0.0, lo_open=True, optional=True))
        set_("up", _up(self.up))
        set_("min_weight", _real("min_weight", self.min_weight, lo=0.0, hi=1.0))
        if not isinstance(self.cull, (bool, np.bool_)):
            raise ValidationError(f"cull must be True or False, got {self.cull!r}")
        set_("cull", bool(self.cull))
        set_("cull_far", _real("cull_far", self.cull_far, lo=0.0, lo_open=True, optional=True))
        set_("min_evidence", _real("min_evidence", self.min_evidence, lo=0.0))
        # q lies in [0, 1]: tau outside [0, 1) (or NaN) would select nothing, silently.
        set_("threshold", _real("threshold", self.threshold, lo=0.0, optional=True))
        if self.threshold is not None and not self.threshold < 1.0:
            raise ValidationError(f"threshold must be in [0, 1) (q > threshold is the object), got {self.threshold!r}")
        lift = _options("lift_options", self.lift_options)
        lift_known = [k for k, p in _keyword_only(seed_lift).items()]
        bad = sorted(set(lift) - set(lift_known))
        if bad:
            raise ValidationError(f"lift_options: seed_lift has no option(s) {bad}; its options are {lift_known}")
        if "k_neighbors" in lift:
            _int("lift_options k_neighbors", lift["k_neighbors"], lo=LIMITS["k_neighbors"][0],
                 hi=LIMITS["k_neighbors"][1])
        for name, kw in _LIFT_RANGES.items():  # the others, checked here and not mid-pipeline
            if name in lift:
                _real(f"lift_options {name}", lift[name], **kw)
        set_("lift_options", lift)
        solver = _options("solver_options", self.solver_options)
        check_method_options(self.method, dict(solver))
        set_("solver_options", solver)
        set_("mode", _choice("mode", self.mode, MODES))
        if self.progress is not None and not isinstance(self.progress, (bool, np.bool_)):
            raise ValidationError(f"progress must be True, False or None, got {self.progress!r}")
        set_("progress", None if self.progress is None else bool(self.progress))
        set_("point_mode", _choice("point_mode", self.point_mode, POINT_MODES))
        set_("smoothness", _real("smoothness", self.smoothness, lo=0.0, optional=True))
        if not (self.completion is None or isinstance(self.completion, str)) or self.completion not in COMPLETIONS:
            raise ValidationError(f"completion must be None, 'reference' or 'tracked', got {self.completion!r}")
        set_("graph_options", _graph_options(self.graph_options))
        for name in ("seed_connected", "support_background"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValidationError(f"{name} must be True or False, got {getattr(self, name)!r}")
            set_(name, bool(getattr(self, name)))

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
    from .completion import GRAPH_DEFAULTS

    opts = _options("graph_options", value)
    bad = sorted(set(opts) - set(GRAPH_DEFAULTS))
    if bad:
        raise ValidationError(f"graph_options: object_graph has no option(s) {bad}; its options are "
                              f"{list(GRAPH_DEFAULTS)}")
    if "k" in opts:
        _int("graph_options k", opts["k"], lo=LIMITS["graph_k"][0], hi=LIMITS["graph_k"][1])
    for name in ("sigma_color", "sigma_normal"):
        if name in opts:
            _real(f"graph_options {name}", opts[name], lo=0.0, lo_open=True, optional=True)
    if "region" in opts:
        _real("graph_options region", opts["region"], lo=0.0, lo_open=True)
    if "min_opacity" in opts:
        v = _real("graph_options min_opacity", opts["min_opacity"], lo=0.0)
        if not v < 1.0:
            raise ValidationError(f"graph_options min_opacity must be < 1, got {opts['min_opacity']!r}")
    return opts


def _keyword_only(fn) -> dict:
    import inspect

    return {k: p for k, p in inspect.signature(fn).parameters.items() if p.kind == p.KEYWORD_ONLY}


def _check_names(keys, what: str) -> None:
    valid = ExtractSettings.names()
    bad = sorted(str(k) for k in keys if k not in valid)
    if bad:
        raise ValidationError(f"{what} {bad}; valid names: {', '.join(valid)}")
