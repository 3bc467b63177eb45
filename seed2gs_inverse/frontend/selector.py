"""QD-SAM3 seed selection (Seed2GS Sec. 3.3, Eq. 2-3).

Every localisation cue ``a_k`` (VLM boxes, detector boxes, the prompt itself
for SAM3 text prompting) becomes a mask with **one** mask model,
``m_k = SAM(I_r, a_k)`` (Eq. 2), and the seed is

.. math::

    m^\\star = \\arg\\max_k \\; w_s S_{src}(m_k) + w_c S_{conf}(m_k) + w_t S_{lang}(m_k, p)

(Eq. 3). Here the total is divided by ``w_s + w_c + w_t`` so it stays in
[0, 1] (the argmax is unchanged).

- ``S_src``: a prior per source (:data:`DEFAULT_SOURCE_PRIOR`); the paper's
  ablation finds the VLM the strongest source, then GroundingDINO, then
  SAM3 text.
- ``S_conf``: the source model's own confidence (detector probability, SAM3
  instance score, the VLM's score or 1).
- ``S_lang``: compatibility of the source with the query's semantic type
  from :func:`query_type` — ``"noun"`` (one content word), ``"attribute"``
  (2-4 content words, no relation) or ``"relational"`` (a spatial /
  relational / ordinal cue word, or more than 4 content words) — looked up
  in :data:`DEFAULT_COMPATIBILITY`: relational phrases favour the VLM, short
  nouns favour the detectors and SAM3 text.

Defaults ``w_s, w_c, w_t = 0.25, 0.5, 0.25``: confidence is the strongest
term in the paper's ablation. Ablation switches: ``sources=`` keeps only the
named sources, a zero weight drops a term, and ``weights={"confidence": 1,
"source": 0, "language": 0}`` is the max-confidence baseline.
"""

from __future__ import annotations

import re
from typing import Any, Sequence

import numpy as np

from ..errors import ValidationError
from ._imaging import as_rgb, mask_box
from .base import Candidate

__all__ = ["QDSAM3Selector", "query_type", "DEFAULT_WEIGHTS", "DEFAULT_SOURCE_PRIOR",
           "DEFAULT_COMPATIBILITY"]

DEFAULT_WEIGHTS = {"source": 0.25, "confidence": 0.5, "language": 0.25}
DEFAULT_SOURCE_PRIOR = {"vlm": 1.0, "groundingdino": 0.8, "sam3_text": 0.7, "owlvit": 0.6}
DEFAULT_COMPATIBILITY = {
    "vlm": {"noun": 0.5, "attribute": 0.8, "relational": 1.0},
    "groundingdino": {"noun": 1.0, "attribute": 0.8, "relational": 0.3},
    "sam3_text": {"noun": 1.0, "attribute": 0.7, "relational": 0.2},
    "owlvit": {"noun": 0.9, "attribute": 0.7, "relational": 0.2},
}
_UNKNOWN = 0.5  # prior / compatibility of a source missing from the tables

_ARTICLES = {"a", "an", "the", "some", "this", "that", "these", "those"}
_RELATIONAL = {
    "left", "right", "behind", "front", "under", "underneath", "below", "above", "over", "on", "onto",
    "in", "inside", "into", "within", "between", "beside", "besides", "near", "nearest", "next",
    "closest", "farthest", "furthest", "top", "bottom", "middle", "center", "centre", "with", "without",
    "holding", "containing", "contains", "of", "from", "by", "against", "around", "across", "along",
    "which", "who", "where", "whose", "largest", "smallest", "biggest", "tallest", "shortest",
    "first", "second", "third", "last", "other", "another", "opposite", "facing",
}


def query_type(prompt: str) -> str:
    """Lexical semantic type of a text query: ``noun``, ``attribute`` or ``relational``.

    Words are lower-cased alphanumeric runs; articles/determiners are not
    content words. A query is ``relational`` when it contains a relational,
    spatial, comparative or ordinal cue word (``left``, ``behind``, ``on``,
    ``of``, ``with``, ``largest``, ``second``...) or more than four content
    words; ``noun`` when one content word is left; ``attribute`` otherwise.
    """
    words = re.findall(r"[a-z0-9]+", str(prompt).lower())
    content = [w for w in words if w not in _ARTICLES]
    if not content:
        raise ValidationError("prompt: the text prompt has no words")
    if any(w in _RELATIONAL for w in content) or len(content) > 4:
        return "relational"
    return "noun" if len(content) == 1 else "attribute"


def _has_area(box, shape_hw) -> bool:
    """True when the (x0, y0, x1, y1) box keeps a positive area once clipped to the image."""
    b = np.asarray(box, dtype=np.float64).reshape(-1)
    if b.size != 4 or not np.all(np.isfinite(b)):
        return False
    h, w = shape_hw
    return min(b[2], w) > max(b[0], 0) and min(b[3], h) > max(b[1], 0)


class QDSAM3Selector:
    """Query-dependent multi-source seed selector (implements ``Grounder``).

    Parameters
    ----------
    mask_model : object
        ``segment_box(image, box) -> (mask (H, W) bool, score)`` — SAM3 (the
        paper's choice) or :class:`~seed2gs_inverse.frontend.sam2.SAM2ImagePredictor`.
    detectors : sequence
        Box sources: objects with ``source`` (name) and ``detect(image,
        prompt) -> list[Detection]`` (GroundingDINO, OWL-ViT, ExternalBoxes).
    text_segmenter : object, optional
        ``segment_text(image, prompt) -> list[Segment]`` (SAM3 text
        prompting, source ``"sam3_text"``).
    weights : dict, optional
        ``{"source": w_s, "confidence": w_c, "language": w_t}``.
    source_prior, compatibility : dict, optional
        Override/extend the tables (module docstring).
    sources : sequence of str, optional
        Only these sources produce candidates (source-removal ablation).
    per_source : int
        Cues taken from each source, best first (1).
    """

    def __init__(self, mask_model, detectors: Sequence[Any] = (), text_segmenter=None,
                 weights: dict | None = None, source_prior: dict | None = None,
                 compatibility: dict | None = None, sources: Sequence[str] | None = None,
                 per_source: int = 1):
        self.mask_model = mask_model
        self.detectors = list(detectors)
        self.text_segmenter = text_segmenter
        w = dict(DEFAULT_WEIGHTS)
        for k, v in (weights or {}).items():
            if k not in w:
                raise ValidationError(f"weights: unknown term {k!r}; use source, confidence, language")
            w[k] = float(v)
        if any(v < 0 or not np.isfinite(v) for v in w.values()) or sum(w.values()) <= 0:
            raise ValidationError("weights: need finite non-negative weights with a positive sum")
        self.weights = w
        self.source_prior = dict(DEFAULT_SOURCE_PRIOR, **(source_prior or {}))
        self.compatibility = {k: dict(v) for k, v in DEFAULT_COMPATIBILITY.items()}
        for k, v in (compatibility or {}).items():
            self.compatibility.setdefault(k, {}).update(v)
        self.sources = None if sources is None else set(sources)
        if per_source < 1:
            raise ValidationError("per_source: take at least one cue per source")
        self.per_source = int(per_source)

    def available_sources(self) -> list[str]:
        """Names of the sources that produce candidates (configured and not filtered out)."""
        names = [d.source for d in self.detectors]
        if self.text_segmenter is not None:
            names.append("sam3_text")
        return [n for n in names if self.sources is None or n in self.sources]

    def terms(self, source: str, confidence: float, qtype: str) -> dict:
        """``S_src``, ``S_conf``, ``S_lang`` and the normalised Eq. 3 total."""
        s_src = float(self.source_prior.get(source, _UNKNOWN))
        s_lang = float(self.compatibility.get(source, {}).get(qtype, _UNKNOWN))
        s_conf = float(np.clip(confidence, 0.0, 1.0))
        w = self.weights
        total = (w["source"] * s_src + w["confidence"] * s_conf + w["language"] * s_lang) / sum(w.values())
        return {"S_src": s_src, "S_conf": s_conf, "S_lang": s_lang, "total": float(total)}

    def rank(self, candidates: Sequence[Candidate], prompt: str) -> list[Candidate]:
        """Score candidates (``score`` = source confidence on input) by Eq. 3, best first.

        Returns new Candidates whose ``score`` is the total and whose
        ``info`` holds the terms, the raw confidence and the query type.
        """
        qtype = query_type(prompt)
        out = []
        for c in candidates:
            if self.sources is not None and c.source not in self.sources:
                continue
            t = self.terms(c.source, c.score, qtype)
            info = dict(c.info, S_src=t["S_src"], S_conf=t["S_conf"], S_lang=t["S_lang"],
                        source=c.source, confidence=float(c.score), query_type=qtype,
                        weights=dict(self.weights))
            out.append(Candidate(mask=c.mask, box=c.box, score=t["total"], source=c.source, info=info))
        # stable: ties keep the order of the sources
        return sorted(out, key=lambda c: -c.score)

    def ground(self, image, prompt: str) -> list[Candidate]:
        """All candidates of all enabled sources for ``prompt``, best first (Eq. 2-3)."""
        if not isinstance(prompt, str) or not prompt.strip():
            raise ValidationError("prompt: QD-SAM3 needs a non-empty text prompt")
        img = as_rgb(image)
        raw: list[Candidate] = []
        for det in self.detectors:
            if self.sources is not None and det.source not in self.sources:
                continue
            # a detector may return boxes with no area inside the image (clipped at an
            # edge, or a collapsed regression); they cannot prompt a mask model, so the
            # source's next box takes their place instead of failing the whole prompt
            usable = [d for d in det.detect(img, prompt) if _has_area(d.box, img.shape[:2])]
            for d in usable[:self.per_source]:
                mask, mscore = self.mask_model.segment_box(img, d.box)
                if not np.any(mask):
                    continue
                raw.append(Candidate(mask=np.asarray(mask, bool), box=np.asarray(d.box, float),
                                     score=float(d.score), source=det.source,
                                     info={"label": d.label, "cue_box": [float(v) for v in d.box],
                                           "mask_score": float(mscore)}))
        if self.text_segmenter is not None and (self.sources is None or "sam3_text" in self.sources):
            for s in self.text_segmenter.segment_text(img, prompt)[:self.per_source]:
                if not np.any(s.mask):
                    continue
                box = mask_box(s.mask)
                raw.append(Candidate(mask=np.asarray(s.mask, bool), box=box, score=float(s.score),
                                     source="sam3_text",
                                     info={"label": prompt, "cue_box": [float(v) for v in s.box],
                                           "mask_score": float(s.score)}))
        return self.rank(raw, prompt)
