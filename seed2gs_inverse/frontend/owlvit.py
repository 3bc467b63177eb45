"""OWL-ViT on onnxruntime (HuggingFace ``optimum`` zero-shot-object-detection export).

Layout: inputs ``input_ids`` (Nq, L) int64 (CLIP BPE, padded to L = 16
with id 0), ``pixel_values`` (1, 3, S, S) float32 (S = 768 for
``owlvit-base-patch32``), ``attention_mask`` (Nq, L) int64 -> ``logits``
(1, P, Nq) per-patch class logits and ``pred_boxes`` (1, P, 4) normalised
(cx, cy, w, h); other outputs (``text_embeds``, ``image_embeds``) are
ignored. Pre-processing as ``OwlViTImageProcessor``: Pillow bicubic resize of
the 8-bit image to S x S (aspect ratio not kept), CLIP mean/std; text
padded with the tokenizer's pad token (``"!"``, id 0, for the OWL-ViT
checkpoints) to L. Post-processing as ``post_process_object_detection``:
score = sigmoid of the best query logit, boxes scaled to the image (and
clipped to it here).
"""

from __future__ import annotations

import numpy as np

from ..errors import ValidationError
from ._imaging import CLIP_MEAN, CLIP_STD, as_rgb, cxcywh_to_xyxy, normalize, resample
from ._onnx import Layout, OnnxModel, Port
from .base import Detection
from .tokenizer import ClipTokenizer

__all__ = ["OWLViT", "OWLVIT_LAYOUT"]

OWLVIT_LAYOUT = Layout(
    "optimum",
    (Port("input_ids", ("int64", "int32"), 2), Port("pixel_values", ("float32",), 4, (None, 3, None, None)),
     Port("attention_mask", ("int64", "int32"), 2)),
    (Port("logits", ("float32",), 3), Port("pred_boxes", ("float32",), 3, (None, None, 4))))


class OWLViT:
    """Open-vocabulary detector over an OWL-ViT ONNX export.

    Parameters
    ----------
    model : path
    tokenizer : path or ClipTokenizer
        CLIP ``tokenizer.json`` of the OWL-ViT checkpoint.
    threshold : float
        Minimum ``sigmoid(logit)`` of a kept box (0.1, as HF's post-processing).
    max_detections : int
    """

    source = "owlvit"

    def __init__(self, model, tokenizer, threshold: float = 0.1, max_detections: int = 10, providers=None):
        self.model = OnnxModel(model, "owlvit.model", (OWLVIT_LAYOUT,), providers)
        self.tokenizer = tokenizer if isinstance(tokenizer, ClipTokenizer) else ClipTokenizer.from_file(tokenizer)
        self.threshold, self.max_detections = float(threshold), int(max_detections)
        s = self.model.input_dim("pixel_values", 2, 768)
        self.input_size = (s, self.model.input_dim("pixel_values", 3, s))
        self.context = self.model.input_dim("input_ids", 1, 16)

    def preprocess(self, image) -> np.ndarray:
        """(1, 3, S, S) float32: Pillow-bicubic 8-bit resize, CLIP normalisation."""
        return normalize(resample(as_rgb(image), self.input_size, "bicubic", eight_bit=True), CLIP_MEAN, CLIP_STD)

    def detect(self, image, prompt: str) -> list[Detection]:
        """Boxes for the text query ``prompt``, best first."""
        text = str(prompt).strip()
        if not text:
            raise ValidationError("prompt: the text prompt is empty")
        img = as_rgb(image)
        h, w = img.shape[:2]
        ids, mask = self.tokenizer.encode(text, context_length=self.context)
        out = self.model.run({"input_ids": ids[None], "attention_mask": mask[None],
                              "pixel_values": self.preprocess(img)})
        logits = np.asarray(out["logits"], np.float64)[0][:, 0]
        prob = 1.0 / (1.0 + np.exp(-np.clip(logits, -80.0, 80.0)))
        boxes = cxcywh_to_xyxy(np.asarray(out["pred_boxes"])[0], w, h)
        order = [i for i in np.argsort(-prob, kind="stable") if prob[i] > self.threshold]
        return [Detection(boxes[i], float(prob[i]), text) for i in order[:self.max_detections]]
