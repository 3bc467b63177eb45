"""SAM3 on onnxruntime: text prompting and box prompts (samexporter layout).

Three files, as exported by vietanhdev/samexporter (``export_sam3.py``,
read by its ``sam3_onnx.py``):

- image encoder: one input ``image`` (3, S, S) uint8 (normalisation inside
  the graph) or float32 (``(x - 0.5) / 0.5`` applied here), S = 1008 for the
  released model; six float32 outputs read **by position** as
  ``vision_pos_enc_0..2, backbone_fpn_0..2``.
- language encoder: input ``tokens`` (1, 32) int64 (CLIP BPE ids, padded
  with 0); three outputs read by position as ``language_mask`` (1, 32) bool,
  ``language_features`` (32, 1, 256), ``language_embeds`` (32, 1, 1024).
- decoder: inputs ``original_height``, ``original_width`` (int64 scalars),
  ``vision_pos_enc_0..2`` (optional), ``backbone_fpn_0..2``,
  ``language_mask``, ``language_features``, ``language_embeds`` (optional),
  ``box_coords`` (K, 1, 4) float32 normalised (cx, cy, w, h),
  ``box_labels`` (K, 1) int64, ``box_masks`` (1, K) bool (True = padding
  slot) -> either raw ``pred_logits`` (1, Q, 1), ``pred_boxes`` (1, Q, 4)
  normalised cxcywh, ``pred_masks`` (1, Q, h, w) logits,
  ``presence_logit_dec`` (1, 1) — scored ``sigmoid(logit) *
  sigmoid(presence)`` as the official ``Sam3Processor`` — or the already
  filtered ``boxes`` (N, 4) pixels, ``scores`` (N,), ``masks`` (N, 1, H, W).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import FormatError, ValidationError
from ._imaging import as_box, as_rgb, box_iou, cxcywh_to_xyxy, opencv, resize_map
from ._onnx import Layout, OnnxModel, Port
from .tokenizer import ClipTokenizer

__all__ = ["SAM3", "Segment", "SAM3_LAYOUTS"]

_F = ("float32",)
_DEC_IN = (Port("original_height", ("int64", "int32"), 0), Port("original_width", ("int64", "int32"), 0),
           Port("vision_pos_enc_0", _F, optional=True), Port("vision_pos_enc_1", _F, optional=True),
           Port("vision_pos_enc_2", _F, optional=True), Port("backbone_fpn_0", _F, optional=True),
           Port("backbone_fpn_1", _F, optional=True), Port("backbone_fpn_2", _F),
           Port("language_mask", ("bool",), 2), Port("language_features", _F, 3),
           Port("language_embeds", _F, 3, optional=True),
           Port("box_coords", _F, 3, (None, 1, 4)), Port("box_labels", ("int64", "int32"), 2),
           Port("box_masks", ("bool",), 2))
SAM3_LAYOUTS = {
    "image_encoder": (Layout("samexporter", (Port("image", ("uint8", "float32"), None),), ()),),
    "language_encoder": (Layout("samexporter", (Port("tokens", ("int64", "int32"), 2),), ()),),
    "decoder": (Layout("samexporter-raw", _DEC_IN,
                       (Port("pred_logits", _F, 3), Port("pred_boxes", _F, 3), Port("pred_masks", _F, 4),
                        Port("presence_logit_dec", _F, None))),
                Layout("samexporter-filtered", _DEC_IN,
                       (Port("boxes", _F, 2), Port("scores", _F, 1), Port("masks", ("bool", "float32"), 4)))),
}
_ENC_NAMES = ("vision_pos_enc_0", "vision_pos_enc_1", "vision_pos_enc_2",
              "backbone_fpn_0", "backbone_fpn_1", "backbone_fpn_2")
_LANG_NAMES = ("language_mask", "language_features", "language_embeds")


@dataclass
class Segment:
    """One SAM3 instance: ``mask`` (H, W) bool, pixel ``box`` (x0, y0, x1, y1), ``score``."""

    mask: np.ndarray
    box: np.ndarray
    score: float


def _sigmoid(x):
    """Logistic function, with the argument clipped to [-80, 80] so that exp cannot overflow."""
    return 1.0 / (1.0 + np.exp(-np.clip(x, -80, 80)))


class SAM3:
    """SAM3 concept segmentation over the samexporter ONNX files.

    Parameters
    ----------
    image_encoder, decoder : path
    language_encoder : path, optional
        Needed for text prompts; geometry-only prompts then use the text
        ``"visual"`` (SAM3's convention), or zero language inputs without it.
    tokenizer : path or ClipTokenizer, optional
        CLIP ``tokenizer.json``; required with a language encoder.
    threshold : float
        Keep instances scoring above it (0.5, as ``Sam3Processor``).
    """

    source = "sam3_text"

    def __init__(self, image_encoder, decoder, language_encoder=None, tokenizer=None,
                 threshold: float = 0.5, providers=None):
        self.encoder = OnnxModel(image_encoder, "sam3.image_encoder", SAM3_LAYOUTS["image_encoder"], providers)
        n_out = len(self.encoder.session.get_outputs())
        if n_out != 6:
            raise FormatError(f"{self.encoder.path}: sam3.image_encoder must have 6 outputs "
                              f"({', '.join(_ENC_NAMES)}), found {n_out}")
        self.decoder = OnnxModel(decoder, "sam3.decoder", SAM3_LAYOUTS["decoder"], providers)
        self.language = None
        self.tokenizer = None
        if language_encoder is not None:
            self.language = OnnxModel(language_encoder, "sam3.language_encoder",
                                      SAM3_LAYOUTS["language_encoder"], providers)
            if len(self.language.session.get_outputs()) != 3:
                raise FormatError(f"{self.language.path}: sam3.language_encoder must have 3 outputs "
                                  f"({', '.join(_LANG_NAMES)})")
            if tokenizer is None:
                raise ValidationError("sam3.tokenizer: a CLIP tokenizer.json is needed with a language encoder")
            self.tokenizer = tokenizer if isinstance(tokenizer, ClipTokenizer) else ClipTokenizer.from_file(tokenizer)
        self.threshold = float(threshold)
        shape = self.encoder.session.get_inputs()[0].shape
        dims = [d if isinstance(d, int) and d > 0 else None for d in (shape or [])][-2:]
        self.input_size = (dims[0] or 1008, dims[1] or dims[0] or 1008) if len(dims) == 2 else (1008, 1008)
        self._batched = shape is not None and len(shape) == 4
        self._cache = (None, None)

    def preprocess(self, image) -> np.ndarray:
        """(3, S, S) uint8 or normalised float32 tensor (batched if the file is)."""
        img = as_rgb(image)
        h, w = self.input_size
        cv2 = opencv()
        res = cv2.resize(img, (w, h), interpolation=cv2.INTER_LINEAR).transpose(2, 0, 1)
        if self.encoder.input_dtype("image") == np.uint8:
            t = np.clip(np.round(res * 255.0), 0, 255).astype(np.uint8)
        else:
            t = ((res - 0.5) / 0.5).astype(np.float32)
        return t[None] if self._batched else t

    def _features(self, img):
        """Image-encoder outputs of ``img`` by name, cached for the last image (box cues reuse them)."""
        key = (img.shape, hash(img.tobytes()))
        if self._cache[0] != key:
            vals = self.encoder.session.get_outputs()
            out = self.encoder.run({"image": self.preprocess(img)})
            self._cache = (key, {n: out[v.name] for n, v in zip(_ENC_NAMES, vals)})
        return self._cache[1]

    def _language(self, text: str) -> dict:
        """Decoder language inputs for ``text``; zeros of the decoder's shapes without a language encoder."""
        if self.language is None:
            n = self.decoder.input_dim("language_mask", 1, 32)
            return {"language_mask": np.zeros((1, n), bool),
                    "language_features": np.zeros((n, 1, self.decoder.input_dim("language_features", 2, 256)), np.float32),
                    "language_embeds": np.zeros((n, 1, self.decoder.input_dim("language_embeds", 2, 1024)
                                                  if self.decoder.has_input("language_embeds") else 1024), np.float32)}
        ctx = self.language.input_dim("tokens", 1, 32)
        ids, _ = self.tokenizer.encode(text, context_length=ctx)
        out = self.language.run({"tokens": ids[None]})
        return {n: out[v.name] for n, v in zip(_LANG_NAMES, self.language.session.get_outputs())}

    def _run(self, img, text: str, boxes=()) -> list[Segment]:
        """Decode the instances of ``text`` (and the box cues ``boxes``, pixel xyxy) in ``img`` at its own size."""
        h, w = img.shape[:2]
        cap = self.decoder.input_dim("box_coords", 0)
        k = cap or max(1, len(boxes))
        if len(boxes) > k:
            raise ValidationError(f"{self.decoder.path}: the SAM3 decoder takes at most {k} boxes")
        coords = np.zeros((k, 1, 4), np.float32)
        masks = np.ones((1, k), bool)
        for i, b in enumerate(boxes):
            coords[i, 0] = [(b[0] + b[2]) / 2 / w, (b[1] + b[3]) / 2 / h, (b[2] - b[0]) / w, (b[3] - b[1]) / h]
            masks[0, i] = False
        feeds = dict(self._features(img), **self._language(text),
                     original_height=np.array(h), original_width=np.array(w),
                     box_coords=coords, box_labels=np.ones((k, 1), np.int64), box_masks=masks)
        out = self.decoder.run(feeds)
        if "pred_logits" in out:
            scores = _sigmoid(np.asarray(out["pred_logits"], np.float64)[0].reshape(-1))
            scores = scores * _sigmoid(float(np.asarray(out["presence_logit_dec"]).reshape(-1)[0]))
            bx = cxcywh_to_xyxy(np.asarray(out["pred_boxes"])[0], w, h)
            raw = np.asarray(out["pred_masks"])[0]
            return [Segment(resize_map(raw[i], (h, w)) > 0.0, bx[i], float(scores[i]))
                    for i in range(len(scores))]
        bx = np.asarray(out["boxes"], np.float64).reshape(-1, 4)
        sc = np.asarray(out["scores"], np.float64).reshape(-1)
        mk = np.asarray(out["masks"])
        mk = mk.reshape(mk.shape[0], *mk.shape[-2:])
        return [Segment(resize_map(mk[i].astype(np.float32) - 0.5, (h, w)) > 0, bx[i], float(sc[i]))
                for i in range(len(sc))]

    def segment_text(self, image, text: str) -> list[Segment]:
        """Instances of the concept ``text`` scoring above ``threshold``, best first."""
        if self.language is None:
            raise ValidationError("sam3: text prompts need [sam3] language_encoder and tokenizer")
        if not str(text).strip():
            raise ValidationError("prompt: the text prompt is empty")
        segs = [s for s in self._run(as_rgb(image), str(text).strip()) if s.score > self.threshold]
        return sorted(segs, key=lambda s: -s.score)

    def segment_box(self, image, box):
        """Mask for a box cue: the instance whose box overlaps the cue most.

        Returns ``(mask (H, W) bool, score)``; instances below ``threshold``
        are used only when none passes it.
        """
        img = as_rgb(image)
        b = as_box(box, img.shape[:2])
        segs = self._run(img, "visual", [b])
        if not segs:
            return np.zeros(img.shape[:2], bool), 0.0
        good = [s for s in segs if s.score > self.threshold] or segs
        best = max(good, key=lambda s: (box_iou(s.box, b), s.score))
        return best.mask, best.score
