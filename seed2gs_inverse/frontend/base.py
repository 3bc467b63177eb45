"""Protocols of the front end, so that models are swappable and optional.

A ``Grounder`` turns a reference image and a prompt into candidate masks; a
``Tracker`` propagates the seed mask along a rendered clip. Implementations
are either model-free (OpenCV and the known geometry of rendered views) or run
user-supplied ONNX files; nothing downloads weights.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, Sequence, runtime_checkable

import numpy as np

__all__ = ["Candidate", "Detection", "Grounder", "Tracker"]


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
    """

    def track(self, frames: Sequence[Any], seed_mask: np.ndarray,
              references: Sequence[tuple[Any, np.ndarray]] = ()) -> list[np.ndarray]:
        ...
