"""What :func:`~seed2gs_inverse.pipeline.extract` returns: the :class:`Extraction` record.

:class:`Extraction` holds every intermediate of a run and
:meth:`Extraction.report` is its JSON-ready summary;
:func:`result_warnings` says why a finished run should not be trusted, if it
should not. :func:`~seed2gs_inverse.pipeline.outputs.save_extraction` writes
an extraction's files.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..metrics import remainder_share

if TYPE_CHECKING:
    import scipy.sparse as sp

    from ..camera import Camera
    from ..operators import OperatorStack, Rendering
    from ..scene import GaussianScene
    from ..solvers import SolveResult
    from .seed_lift import SeedLift
    from .settings import ExtractSettings
    from .stages import ReferenceView, Selection
    from .vaas import VAASPlan

__all__ = ["Extraction", "STAGES", "MIN_SUPPORT", "result_warnings"]

#: The stages timed in ``Extraction.seconds``, in order.
STAGES = ("render", "grounding", "lift", "vaas", "tracking", "operators", "solve")

#: Fewer Gaussians than this in G0: the seed rests on too little of the scene to orbit and label.
MIN_SUPPORT = 10


@dataclass
class Extraction:
    """Everything :func:`~seed2gs_inverse.pipeline.extract` computed.

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
        Wall time per stage (:data:`STAGES`; the orbit views are rendered in
        the same pass as their operators, so that time counts under
        ``operators``), then ``compile``: the time spent compiling the
        rasterizer's kernels (0 unless the on-disk cache was cold), which
        no stage counts.
    settings : ExtractSettings
        The options of the run (``report.json`` holds ``settings.to_dict()``).
    resolved : dict
        JSON-ready facts extract derived from the settings and the inputs:
        ``view_scale``, ``reference_scale``, ``up`` (the orbit axis used),
        ``up_method`` and ``up_confidence`` (how it was chosen, see ``up``),
        ``threshold`` (tau used), ``solver_options`` (with the defaults),
        ``tracker``, ``grounder`` (class names), ``n_weak_evidence``
        (Gaussians without real evidence: reset to the prior by
        ``min_evidence``, or decided by the regulariser), ``n_vote_capped``
        (lowered to the prior against their masks' vote, ``min_vote``),
        ``n_disconnected`` (above the threshold in islands apart from G0, set to 0), ``support``
        (the support surface the tracker labelled background,
        :func:`~seed2gs_inverse.pipeline.stages.support_band`), ``smoothness``
        (the regulariser's lambda used, after ``None`` was resolved),
        ``warnings`` (why a finished run should not be trusted, if it should
        not: :func:`result_warnings`) and ``caps`` (each view whose size a
        pixel cap lowered below the one asked for:
        :func:`~seed2gs_inverse.pipeline.stages.view_caps`).
    up : dict
        The orbit axis (:func:`~seed2gs_inverse.pipeline.stages.orbit_axis`):
        ``axis``, ``method`` (how it was chosen), ``confidence`` in [0, 1]
        (None when the user chose it) and ``details``.
    graph : scipy.sparse (N, N) or None
        The Gaussian affinity graph of the run
        (:func:`~seed2gs_inverse.pipeline.stages.evidence_graph`; None when
        nothing needed it), which the solve's regulariser used when
        ``resolved["smoothness"] > 0``.
    follow : scipy.sparse (N, N) or None
        The faint, the enclosed and the weak Gaussians' rows applied to the solver's ``q``
        (:attr:`~seed2gs_inverse.pipeline.stages.Selection.follow`; None
        without ``settings.follow_faint`` and ``settings.follow_weak``).

    Notes
    -----
    ``report()["remainder_share"]`` (:meth:`remainder_summary`) says how
    much of the object's alpha the remainder keeps at the object's place,
    measured on :attr:`operators` (no render).
    """

    scene: GaussianScene
    q: np.ndarray
    selected: np.ndarray
    threshold: float
    seed_mask: np.ndarray
    prompt_info: dict
    reference_camera: Camera
    reference: Rendering
    lift: SeedLift
    vaas: VAASPlan
    views: list
    clips: list
    masks: list
    operators: OperatorStack
    result: SolveResult
    seconds: dict
    settings: ExtractSettings | None = None
    resolved: dict = field(default_factory=dict)
    up: dict = field(default_factory=dict)
    graph: sp.spmatrix | None = field(default=None, repr=False)
    follow: sp.spmatrix | None = field(default=None, repr=False)
    _remainder: tuple | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def total_seconds(self) -> float:
        """The wall time of every stage together, compilation included."""
        return float(sum(self.seconds.values()))

    def object_scene(self) -> GaussianScene:
        """The selected Gaussians, every property kept."""
        return self.scene.subset(self.selected)

    def remainder_scene(self) -> GaussianScene:
        """The scene with the object removed."""
        return self.scene.subset(~self.selected)

    def remainder_summary(self) -> dict:
        """What the remainder keeps of the object: :func:`~seed2gs_inverse.metrics.remainder_share` on the run's views.

        Computed from :attr:`operators` (one sparse pass per view and the
        footprint's rows) and kept until :attr:`selected` changes.

        Returns
        -------
        dict
            ``share`` (the share of the object's alpha that the remainder
            keeps in its footprint, over all supervision views), ``worst_view`` (the
            largest share of one view), ``n_nearby`` (remainder Gaussians
            in the object's region) and ``footprint_pixels``; the shares
            are None when the selection covers no footprint pixel (an empty
            selection).
        """
        selected = np.asarray(self.selected, bool)
        key = hashlib.sha1(np.packbits(selected).tobytes()).hexdigest()  # a changed selection is recomputed
        if self._remainder is None or self._remainder[0] != key:
            r = remainder_share(self.operators, selected, self.scene.means)
            self._remainder = key, {"share": None if np.isnan(r["share"]) else float(r["share"]),
                               "worst_view": None if np.isnan(r["worst_view"]) else float(r["worst_view"]),
                               "n_nearby": r["n_nearby"], "footprint_pixels": r["footprint_pixels"]}
        return dict(self._remainder[1])

    def report(self) -> dict:
        """JSON-ready summary: counts, timings, settings (and what they resolved to), VAAS and lift facts.

        ``remainder_share`` is :meth:`remainder_summary`.
        """
        n_unknown = [int(np.isnan(m).sum()) for m in self.masks]
        return {
            "n_gaussians": int(len(self.scene)),
            "n_selected": int(self.selected.sum()),
            "remainder_share": self.remainder_summary(),
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


def result_warnings(ref: ReferenceView, lift: SeedLift, masks: list, stack: OperatorStack,
                    sel: Selection) -> list[str]:
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
    if lift.n_g0 < MIN_SUPPORT:
        notes.append(f"the seed lifted to only {lift.n_g0} Gaussian(s) (G0): a seed smaller than the splats "
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
