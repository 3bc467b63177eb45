"""Protocols of the front end, so that models are swappable and optional.

A ``Grounder`` turns a reference image and a prompt into candidate masks; a
``Tracker`` propagates the seed mask along a rendered clip. Implementations
are either model-free (OpenCV and the known geometry of rendered views) or run
user-supplied ONNX files; nothing downloads weights.

A tracker may offer more than ``track``; the pipeline asks for each of these
through this module, never by the tracker's class:

* ``wants_regularizer`` (bool attribute, default False,
  :func:`wants_regularizer`): the tracker leaves what it cannot decide
  unknown and counts on the solve's graph regulariser;
* :class:`SupportPlaneTracker`: it can label the support surface under the
  object as background (``support_plane``, ``with_support_plane``);
* :class:`ContactZoneTracker`: it can distrust the background labels it
  copies onto the object's base just above that surface (``contact_zone``,
  ``with_contact_zone``);
* :class:`SeedBandTracker`: it can leave the seed's labels near an edge
  the scene does not back out of what it copies (``seed_band``,
  ``with_seed_band``);
* :class:`LabelFiller`: it can decide the unknown pixels of one labelled
  frame from the frame's image (``fill_labels``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, Sequence, runtime_checkable

import numpy as np

__all__ = ["Candidate", "Detection", "Grounder", "Tracker", "SupportPlaneTracker", "ContactZoneTracker",
           "SeedBandTracker", "LabelFiller", "wants_regularizer"]


@dataclass
class Candidate:
    """One grounding candidate in the reference view.

    Attributes
    ----------
    mask : (H, W) bool array
        The candidate's mask in the reference image.
    box : (4,) float array or None
        ``x0, y0, x1, y1`` in pixels (exclusive max), the cue or the mask's box.
    score : float
        The source model's confidence in [0, 1].
    source : str
        Which localisation cue produced it (e.g. ``"vlm"``, ``"groundingdino"``,
        ``"sam3_text"``, ``"box"``, ``"mask"``).
    info : dict
        Anything else worth recording in the report (selector terms, label).
    """

    mask: np.ndarray
    box: np.ndarray | None
    score: float
    source: str
    info: dict = field(default_factory=dict)


@dataclass
class Detection:
    """One detected box: pixel ``box`` (x0, y0, x1, y1), ``score`` in [0, 1], ``label``.

    What every box detector returns (GroundingDINO, OWL-ViT, ExternalBoxes);
    the selector turns detections into :class:`Candidate` masks.
    """

    box: np.ndarray
    score: float
    label: str


@runtime_checkable
class Grounder(Protocol):
    """Turns ``image`` (H, W, 3) float32 RGB in [0, 1] and a prompt into candidates."""

    def ground(self, image: np.ndarray, prompt: Any) -> list[Candidate]:
        ...


@runtime_checkable
class Tracker(Protocol):
    """Propagates the seed mask over a clip whose first frame is the reference.

    ``frames`` are rendered views: objects with at least ``rgb`` (H, W, 3),
    ``depth`` (H, W), ``alpha`` (H, W) and ``camera`` attributes (see
    :class:`seed2gs_inverse.pipeline.vaas.ClipFrame`). Returns one float32
    mask per frame, values in [0, 1], NaN where the tracker cannot decide.
    The first returned mask is the seed itself.

    ``references`` are views already labelled, as ``(frame, mask)`` pairs
    (the pipeline passes the tracked flat clip when it tracks the spiral, and
    always passes the argument): a tracker may use them as extra sources or
    ignore them, but must accept the argument.

    Optional: a class attribute ``wants_regularizer = True`` declares that
    the tracker leaves surfaces it cannot decide unknown (NaN) and relies on
    the graph-Laplacian regulariser of the solve to decide the Gaussians only
    those pixels see: ``ExtractSettings(smoothness=None)`` then resolves to
    :data:`~seed2gs_inverse.pipeline.settings.MODEL_FREE_SMOOTHNESS`, and to
    0 for a tracker without it (:func:`wants_regularizer`).
    """

    def track(self, frames: Sequence[Any], seed_mask: np.ndarray,
              references: Sequence[tuple[Any, np.ndarray]] = ()) -> list[np.ndarray]:
        ...


@runtime_checkable
class SupportPlaneTracker(Protocol):
    """A tracker that labels the support band under the object as background.

    ``support_plane`` is ``(normal, point)``, the band
    :math:`\\{x : n \\cdot (x - x_s) \\le 0\\}`, or None when the tracker has
    none; ``with_support_plane(normal, point)`` returns a copy of the
    tracker that uses that band (the tracker itself is left as it is). The
    pipeline hands such a tracker the support surface it finds under the
    object (:func:`~seed2gs_inverse.pipeline.stages.support_band`) unless it
    has a plane of its own.
    """

    support_plane: Any

    def with_support_plane(self, normal: np.ndarray, point: np.ndarray) -> Tracker:
        ...


@runtime_checkable
class ContactZoneTracker(Protocol):
    """A support-plane tracker that distrusts copied background labels at the contact.

    ``contact_zone`` is ``(height, radius)``: within ``radius`` of the axis
    through the support plane's point and up to ``height`` above the support
    band's top (scene units), a background label copied from another view
    onto a surface that does not face along the band's normal (the object's
    base, not the ground) is left unknown; None when unset.
    ``with_contact_zone(height, radius)`` returns a copy of the tracker with
    that zone (the tracker itself is left as it is). The pipeline sets it
    from the support surface it finds
    (:meth:`~seed2gs_inverse.pipeline.support.SupportSurface.contact_zone`)
    unless the tracker has a zone of its own.
    """

    contact_zone: Any

    def with_contact_zone(self, height: float, radius: float) -> Tracker:
        ...


@runtime_checkable
class SeedBandTracker(Protocol):
    """A tracker that copies no seed label from near the seed's edge where the scene does not back it.

    ``seed_band`` is the band's width in pixels of frame 0, or None when
    unset; ``with_seed_band(band)`` returns a copy of the tracker with that
    width (the tracker itself is left as it is). The pipeline sets it from
    ``ExtractSettings.mask_tolerance`` for a mask or text prompt, and to 0
    for a box or point prompt, unless the tracker has a width of its own.
    """

    seed_band: Any

    def with_seed_band(self, band: int) -> Tracker:
        ...


@runtime_checkable
class LabelFiller(Protocol):
    """Decides the unknown pixels of one frame's labels from the frame's image.

    ``fill_labels(rgb, depth, labels)`` takes the frame's ``rgb`` (H, W, 3)
    and ``depth`` (H, W) and its ``labels`` (H, W) float (NaN = unknown) and
    returns new (H, W) labels, NaN where it cannot decide. The pipeline calls
    it on the masks that 3D label completion leaves partly unknown
    (:func:`~seed2gs_inverse.pipeline.stages.complete_masks`).
    """

    def fill_labels(self, rgb: np.ndarray, depth: np.ndarray, labels: np.ndarray) -> np.ndarray:
        ...


def wants_regularizer(tracker: Any) -> bool:
    """Whether ``tracker`` declares ``wants_regularizer`` (see :class:`Tracker`); False when it does not."""
    return bool(getattr(tracker, "wants_regularizer", False))
