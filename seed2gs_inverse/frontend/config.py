"""Model configuration: which ONNX files play which role.

A small TOML (or JSON) file; relative paths are relative to the file. Every
section is optional; a missing file, a wrong signature or an unknown key is
a :class:`~seed2gs_inverse.errors.FormatError` naming the file.

.. code-block:: toml

    [sam2]                      # image predictor (mask model when no SAM3)
    encoder = "sam2.1_hiera_tiny.encoder.onnx"
    decoder = "sam2.1_hiera_tiny.decoder.onnx"

    [sam]                       # segment-anything (v1) pair, samexporter layout
    encoder = "sam_vit_b.encoder.onnx"
    decoder = "sam_vit_b.decoder.onnx"

    [sam2_video]                # tracker (replaces the model-free one)
    image_encoder = "tiny/image_encoder.onnx"
    image_decoder = "tiny/image_decoder.onnx"
    memory_attention = "tiny/memory_attention.onnx"
    memory_encoder = "tiny/memory_encoder.onnx"
    # num_maskmem = 7

    [groundingdino]
    model = "groundingdino_swint_ogc.onnx"
    tokenizer = "bert-base-uncased/tokenizer.json"
    # box_threshold = 0.35, text_threshold = 0.25

    [sam3]                      # mask model for every cue + SAM3-text source
    image_encoder = "sam3_image_encoder.onnx"
    language_encoder = "sam3_language_encoder.onnx"
    decoder = "sam3_decoder.onnx"
    tokenizer = "clip/tokenizer.json"

    [owlvit]
    model = "owlvit-base-patch32.onnx"
    tokenizer = "owlvit-base-patch32/tokenizer.json"

    [external]                  # boxes from a VLM run elsewhere
    boxes = "qwen3vl_boxes.json"

    [selector]
    weights = { source = 0.25, confidence = 0.5, language = 0.25 }
    sources = ["vlm", "groundingdino", "sam3_text"]
    mask_model = "sam3"         # or "sam2"

Found via ``--models FILE``, else the ``SEED2GS_MODELS`` environment
variable (:func:`resolve_models`), or :func:`load_models` from the API.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .._validation import as_real
from ..errors import FormatError, ValidationError
from ..io.tables import read_table
from ._onnx import onnxruntime_module
from .external import ExternalBoxes
from .grounding_dino import GroundingDINO
from .owlvit import OWLViT
from .sam2 import SAM2ImagePredictor, SAM2VideoTracker
from .sam3 import SAM3
from .selector import QDSAM3Selector

__all__ = ["ModelSet", "load_models", "resolve_models", "ENV_VAR", "NO_MODELS_NOTICE"]

ENV_VAR = "SEED2GS_MODELS"
NO_MODELS_NOTICE = ("no ONNX models configured (--models FILE or $SEED2GS_MODELS): using the "
                    "model-free front end (mask, box or point prompts; geometric tracker)")

# section -> {key: kind}; kind "path" keys are resolved against the file's folder
_SCHEMA = {
    "sam2": {"encoder": "path", "decoder": "path", "mask_threshold": float},
    "sam": {"encoder": "path", "decoder": "path", "mask_threshold": float},
    "sam2_video": {"image_encoder": "path", "image_decoder": "path", "memory_attention": "path",
                   "memory_encoder": "path", "num_maskmem": int, "mask_threshold": float},
    "groundingdino": {"model": "path", "tokenizer": "path", "box_threshold": float,
                      "text_threshold": float, "max_detections": int},
    "sam3": {"image_encoder": "path", "decoder": "path", "language_encoder": "path",
             "tokenizer": "path", "threshold": float},
    "owlvit": {"model": "path", "tokenizer": "path", "threshold": float, "max_detections": int},
    "external": {"boxes": "path", "name": str, "coords": str},
    "selector": {"weights": dict, "sources": list, "mask_model": str, "per_source": int,
                 "source_prior": dict, "compatibility": dict},
    "onnxruntime": {"providers": list},
}
_COORDS = ("pixels", "unit", "per-mille")  # the conventions of frontend.external
# (section, key) -> (low, high) inclusive: probability thresholds and counts that the models would
# otherwise take as given (box_threshold = 5 loads and then never finds anything)
_RANGES = {("groundingdino", "box_threshold"): (0.0, 1.0), ("groundingdino", "text_threshold"): (0.0, 1.0),
           ("groundingdino", "max_detections"): (1, 10_000), ("sam3", "threshold"): (0.0, 1.0),
           ("owlvit", "threshold"): (0.0, 1.0), ("owlvit", "max_detections"): (1, 10_000),
           ("sam2_video", "num_maskmem"): (1, 64), ("selector", "per_source"): (1, 100)}
_REQUIRED = {"sam2": ("encoder", "decoder"), "sam": ("encoder", "decoder"),
             "sam2_video": ("image_encoder", "image_decoder", "memory_attention", "memory_encoder"),
             "groundingdino": ("model", "tokenizer"), "sam3": ("image_encoder", "decoder"),
             "owlvit": ("model", "tokenizer"), "external": ("boxes",)}


def _read(path: Path) -> dict:
    """The parsed TOML/JSON table of ``path``; a missing file is a FormatError."""
    try:
        return read_table(path, "models configuration")
    except FileNotFoundError:
        raise FormatError(f"{path}: models configuration file not found") from None


def _sections(path: Path, data: dict) -> dict:
    """``data`` checked against the schema: known sections and keys, types, ranges, required keys.

    Path values are resolved against the configuration's folder; the result
    maps each section to its checked keys.
    """
    out = {}
    for name, body in data.items():
        if name not in _SCHEMA:
            raise FormatError(f"{path}: unknown section [{name}]; known sections: {', '.join(_SCHEMA)}")
        if not isinstance(body, dict):
            raise FormatError(f"{path}: [{name}] must be a table of keys")
        sec = {}
        for key, value in body.items():
            kind = _SCHEMA[name].get(key)
            if kind is None:
                raise FormatError(f"{path}: unknown key {key!r} in [{name}]; known keys: "
                                  f"{', '.join(_SCHEMA[name])}")
            if (name, key) == ("external", "coords") and value not in _COORDS:
                raise FormatError(f"{path}: [external] coords must be one of {', '.join(_COORDS)}, got {value!r}")
            if kind == "path":
                if not isinstance(value, str) or not value:
                    raise FormatError(f"{path}: [{name}] {key} must be a file path string")
                p = Path(os.path.expanduser(value))
                p = p if p.is_absolute() else (path.parent / p)
                if os.path.exists(p) and not os.path.isfile(p):  # a pipe or device would block or never end
                    raise FormatError(f"{path}: [{name}] {key} = {p} is not a regular file (a directory, pipe "
                                      f"or device); name the file itself")
                sec[key] = p
            elif kind in (int, float):
                if isinstance(value, bool) or not isinstance(value, (int, float)) or (kind is int and not isinstance(value, int)):
                    raise FormatError(f"{path}: [{name}] {key} must be a{'n integer' if kind is int else ' number'}")
                lo, hi = _RANGES.get((name, key), (-np.inf, np.inf))
                real = as_real(value)  # None when not finite
                if real is None or not lo <= real <= hi:
                    raise FormatError(f"{path}: [{name}] {key} must be in [{lo:g}, {hi:g}], got {value!r}")
                sec[key] = kind(value)
            elif not isinstance(value, kind):
                raise FormatError(f"{path}: [{name}] {key} must be a {kind.__name__}")
            else:
                sec[key] = value
        for key in _REQUIRED.get(name, ()):
            if key not in sec:
                raise FormatError(f"{path}: [{name}] needs the key {key!r}")
        out[name] = sec
    return out


@dataclass
class ModelSet:
    """The loaded models of one configuration (every member may be None).

    Use :meth:`grounder` for the QD-SAM3 selector and :meth:`tracker` for the
    SAM2 video tracker; both are None when their models are not configured.
    """

    sam2: SAM2ImagePredictor | None = None
    sam: SAM2ImagePredictor | None = None
    sam2_video: SAM2VideoTracker | None = None
    groundingdino: GroundingDINO | None = None
    sam3: SAM3 | None = None
    owlvit: OWLViT | None = None
    external: ExternalBoxes | None = None
    selector_options: dict = field(default_factory=dict)
    path: Path | None = None

    def mask_model(self) -> SAM3 | SAM2ImagePredictor | None:
        """SAM3 when configured (the paper's single mask generator), else SAM2, else SAM."""
        choice = self.selector_options.get("mask_model")
        if choice in ("sam2", "sam3", "sam"):
            return getattr(self, choice)
        return next((m for m in (self.sam3, self.sam2, self.sam) if m is not None), None)

    def grounder(self, external: Callable | str | Path | None = None) -> QDSAM3Selector | None:
        """QD-SAM3 selector over the configured sources, or None when there are none.

        ``external`` adds boxes from elsewhere (a callable ``fn(image,
        prompt)`` or a JSON file) as the ``"vlm"`` source for this grounder.
        """
        detectors = [d for d in (self.groundingdino, self.owlvit) if d is not None]
        ext = self.external if external is None else ExternalBoxes(external)
        if ext is not None:
            detectors.insert(0, ext)
        text = self.sam3 if (self.sam3 is not None and self.sam3.language is not None) else None
        if not detectors and text is None:
            return None
        mask_model = self.mask_model()
        if mask_model is None:
            raise ValidationError("models: box sources need a mask model; configure [sam3], [sam2] or [sam]")
        opts = {k: v for k, v in self.selector_options.items() if k != "mask_model"}
        return QDSAM3Selector(mask_model, detectors, text, **opts)

    def tracker(self) -> SAM2VideoTracker | None:
        """The SAM2 video tracker, or None (the caller uses the model-free tracker)."""
        return self.sam2_video

    def describe(self) -> str:
        """One line per configured role, for reports and ``--verbose`` output."""
        lines = []
        for name in ("sam2", "sam", "sam2_video", "groundingdino", "sam3", "owlvit", "external"):
            obj = getattr(self, name)
            if obj is None:
                continue
            files = sorted({str(m.path) for m in vars(obj).values() if hasattr(m, "session")})
            lines.append(f"{name}: " + (", ".join(files) if files else type(obj).__name__))
        return "\n".join(lines) if lines else "no models configured"


def load_models(path) -> ModelSet:
    """Read a models configuration and open (and signature-check) every file.

    Parameters
    ----------
    path : str or Path
        TOML (``.toml``) or JSON (``.json``) file, format in the module docstring.

    Raises
    ------
    FormatError
        Unreadable configuration, unknown section/key, missing model file or
        a file whose ONNX signature does not match its role.
    """
    path = Path(path)
    cfg = _sections(path, _read(path))
    prov = cfg.get("onnxruntime", {}).get("providers")
    if prov is not None:
        have = onnxruntime_module(f"{path}'s [onnxruntime] section").get_available_providers()
        missing = [p for p in prov if p not in have]
        if missing or not prov:
            raise FormatError(f"{path}: [onnxruntime] providers {missing or prov} not available in this "
                              f"onnxruntime; available: {', '.join(have)}")
    ms = ModelSet(path=path, selector_options=dict(cfg.get("selector", {})))
    if "sam2" in cfg:
        ms.sam2 = SAM2ImagePredictor(providers=prov, **cfg["sam2"])
    if "sam" in cfg:  # segment-anything (v1): same predictor, its layout is detected from the files
        ms.sam = SAM2ImagePredictor(providers=prov, **cfg["sam"])
    if "sam2_video" in cfg:
        ms.sam2_video = SAM2VideoTracker(providers=prov, **cfg["sam2_video"])
    if "groundingdino" in cfg:
        ms.groundingdino = GroundingDINO(providers=prov, **cfg["groundingdino"])
    if "sam3" in cfg:
        ms.sam3 = SAM3(providers=prov, **cfg["sam3"])
    if "owlvit" in cfg:
        ms.owlvit = OWLViT(providers=prov, **cfg["owlvit"])
    if "external" in cfg:
        e = cfg["external"]
        ms.external = ExternalBoxes(e["boxes"], e.get("name", "vlm"), e.get("coords", "pixels"))
    choice = ms.selector_options.get("mask_model")
    if choice not in (None, "sam2", "sam3", "sam"):
        raise FormatError(f"{path}: [selector] mask_model must be 'sam3', 'sam2' or 'sam', got {choice!r}")
    if choice is not None and getattr(ms, choice) is None:
        raise FormatError(f"{path}: [selector] mask_model = {choice!r} but [{choice}] is not configured")
    wanted = ms.selector_options.get("sources")
    if wanted is not None:
        # "vlm": external boxes may also come from Python, models.grounder(external=...)
        have = [d.source for d in (ms.external, ms.groundingdino, ms.owlvit) if d is not None]
        have += [] if "vlm" in have else ["vlm"]
        if ms.sam3 is not None and ms.sam3.language is not None:
            have.append("sam3_text")
        unknown = [w for w in wanted if w not in have]
        if unknown or not wanted:
            raise FormatError(f"{path}: [selector] sources {unknown or wanted} "
                              f"{'name no configured source' if unknown else 'is empty'}; configured sources: "
                              f"{', '.join(have) or 'none'}")
    try:
        ms.grounder()  # validates selector options and the mask-model requirement now
    except ValidationError as exc:
        raise FormatError(f"{path}: {exc}") from None
    return ms


def resolve_models(path_or_none=None) -> ModelSet | None:
    """Models from ``--models`` (the argument), else ``$SEED2GS_MODELS``, else None.

    None means no learned models: the caller falls back to the model-free
    front end and should say so (:data:`NO_MODELS_NOTICE`).
    """
    if path_or_none is not None and str(path_or_none) != "":
        return load_models(path_or_none)
    env = os.environ.get(ENV_VAR, "").strip()
    return load_models(env) if env else None
