"""GroundingDINO on onnxruntime: two export layouts, detected from the names.

- ``groundingdino`` (ONNX export of the original IDEA-Research code):
  inputs ``img`` (1, 3, H, W) float32, ``input_ids`` (1, L) int64,
  ``attention_mask`` (1, L) bool|int64, ``position_ids`` (1, L) int64,
  ``token_type_ids`` (1, L) int64, ``text_token_mask`` (1, L, L) bool.
- ``transformers`` (``GroundingDinoForObjectDetection`` through
  ``torch.onnx.export``, e.g. ``tools/conformance/export_hf.py``): inputs
  ``pixel_values`` (1, 3, H, W) float32, ``input_ids``, ``token_type_ids``,
  ``attention_mask`` (1, L) int64, optional ``pixel_mask`` (1, H, W) int64;
  the graph builds the phrase mask and position ids itself.

Both output ``logits`` (1, Q, 256) (pre-sigmoid, one column per text token,
-inf past the caption) and boxes (``boxes`` or ``pred_boxes``, (1, Q, 4)
normalised (cx, cy, w, h)). Q = 900 for the released models.

Pre-processing follows the original ``groundingdino.util.inference`` and
``GroundingDinoImageProcessor`` (the same): shorter side resized to 800
with the longer side capped at 1333 (or the model's fixed input size when
the file declares one) by Pillow's bilinear filter on the 8-bit image,
ImageNet mean/std; the caption is lower-cased and ends with ``"."``.
Post-processing as both references: a query's score is its highest
``sigmoid(logit)`` over the caption's tokens, kept above ``box_threshold``;
its label is the best phrase's tokens above ``text_threshold``.
"""

from __future__ import annotations

import numpy as np

from ..errors import ValidationError
from ._imaging import IMAGENET_MEAN, IMAGENET_STD, as_rgb, cxcywh_to_xyxy, normalize, resample
from ._onnx import Layout, OnnxModel, Port
from .base import Detection  # shared by every grounder; re-exported as one of this module's names
from .tokenizer import BertTokenizer

__all__ = ["GroundingDINO", "Detection", "GROUNDING_DINO_LAYOUT", "GROUNDING_DINO_LAYOUTS", "preprocess_caption",
           "generate_masks_with_special_tokens_and_transfer_map"]

GROUNDING_DINO_LAYOUT = Layout(
    "groundingdino",
    (Port("img", ("float32",), 4, (1, 3, None, None)), Port("input_ids", ("int64", "int32"), 2),
     Port("attention_mask", ("bool", "int64", "int32"), 2), Port("position_ids", ("int64", "int32"), 2),
     Port("token_type_ids", ("int64", "int32"), 2), Port("text_token_mask", ("bool",), 3)),
    (Port("logits", ("float32",), 3), Port("boxes", ("float32",), 3, (None, None, 4))))
_INT = ("int64", "int32")
GROUNDING_DINO_LAYOUTS = (
    GROUNDING_DINO_LAYOUT,
    Layout("transformers",
           (Port("pixel_values", ("float32",), 4, (1, 3, None, None)), Port("input_ids", _INT, 2),
            Port("token_type_ids", _INT, 2), Port("attention_mask", _INT + ("bool",), 2),
            Port("pixel_mask", _INT + ("bool",), 3, optional=True)),
           (Port("logits", ("float32",), 3), Port("pred_boxes", ("float32",), 3, (None, None, 4)))),
)

MAX_TEXT_LEN = 256


def preprocess_caption(caption: str) -> str:
    """Lower-case, strip, and end with ``"."`` (GroundingDINO's caption convention)."""
    text = str(caption).lower().strip()
    if not text:
        raise ValidationError("prompt: the text prompt is empty")
    return text if text.endswith(".") else text + " ."


def generate_masks_with_special_tokens_and_transfer_map(input_ids, special_ids):
    """Sub-sentence attention mask and position ids of GroundingDINO.

    Special tokens (``[CLS]``, ``[SEP]``, ``.``, ``?``) split the caption
    into phrases. Each phrase (its tokens plus the closing separator)
    attends only within itself and its position ids restart at 0; the first
    and last tokens attend to themselves with position 0.

    Parameters
    ----------
    input_ids : (B, L) int array
    special_ids : iterable of int

    Returns
    -------
    attention_mask : (B, L, L) bool
    position_ids : (B, L) int64
    """
    ids = np.asarray(input_ids)
    b, n = ids.shape
    special = np.isin(ids, list(special_ids))
    mask = np.broadcast_to(np.eye(n, dtype=bool), (b, n, n)).copy()
    pos = np.zeros((b, n), np.int64)
    for row in range(b):
        prev = 0
        for col in np.flatnonzero(special[row]):
            if col == 0 or col == n - 1:
                mask[row, col, col] = True
                pos[row, col] = 0
            else:
                mask[row, prev + 1:col + 1, prev + 1:col + 1] = True
                pos[row, prev + 1:col + 1] = np.arange(col - prev)
            prev = col
    return mask, pos


class GroundingDINO:
    """Open-vocabulary box detector over a GroundingDINO ONNX export.

    Parameters
    ----------
    model : path
        The ONNX file (layout in the module docstring).
    tokenizer : path or BertTokenizer
        ``tokenizer.json`` (or ``vocab.txt``) of ``bert-base-uncased``.
    box_threshold : float
        Keep queries whose best phrase-token probability exceeds it (0.35).
    text_threshold : float
        The tokens of the best phrase above it form the label (0.25), as the
        original ``get_phrases_from_posmap``.
    size, max_size : int
        Shorter-side size and longer-side cap when the model's image size is
        dynamic (800, 1333).
    max_detections : int
        Keep at most this many boxes, best first.
    """

    source = "groundingdino"

    def __init__(self, model, tokenizer, box_threshold: float = 0.35, text_threshold: float = 0.25,
                 size: int = 800, max_size: int = 1333, max_detections: int = 10, providers=None):
        self.model = OnnxModel(model, "groundingdino.model", GROUNDING_DINO_LAYOUTS, providers)
        self.layout = self.model.layout.name
        self._image_input = "img" if self.layout == "groundingdino" else "pixel_values"
        self.tokenizer = tokenizer if isinstance(tokenizer, BertTokenizer) else BertTokenizer.from_file(tokenizer)
        self.box_threshold, self.text_threshold = float(box_threshold), float(text_threshold)
        self.size, self.max_size, self.max_detections = int(size), int(max_size), int(max_detections)
        self.special_ids = [i for i in (self.tokenizer.token_id(t) for t in ("[CLS]", "[SEP]", ".", "?"))
                            if i is not None]

    def input_size(self, shape_hw) -> tuple[int, int]:
        """(h, w) the image is resized to: the model's fixed size, else 800 / 1333."""
        fh, fw = self.model.input_dim(self._image_input, 2), self.model.input_dim(self._image_input, 3)
        if fh and fw:
            return fh, fw
        h, w = shape_hw
        size = self.size
        lo, hi = min(h, w), max(h, w)
        if hi / lo * size > self.max_size:
            size = int(round(self.max_size * lo / hi))
        # (h, w): the shorter side becomes ``size`` (original get_size_with_aspect_ratio)
        return (int(size * h / w), size) if w < h else (size, int(size * w / h))

    def encode_text(self, prompt: str) -> dict:
        """All text inputs of the model for ``prompt`` (numpy arrays, batch 1)."""
        ids = np.asarray([self.tokenizer.encode(preprocess_caption(prompt), MAX_TEXT_LEN)], np.int64)
        mask, pos = generate_masks_with_special_tokens_and_transfer_map(ids, self.special_ids)
        return {"input_ids": ids, "attention_mask": np.ones_like(ids, dtype=bool),
                "position_ids": pos, "token_type_ids": np.zeros_like(ids), "text_token_mask": mask}

    def phrases(self, input_ids) -> list[tuple[str, np.ndarray]]:
        """(phrase, token positions) for each ``.``-separated phrase of the caption."""
        ids = np.asarray(input_ids).reshape(-1)
        special = np.isin(ids, self.special_ids)
        out, cur = [], []
        for i, tid in enumerate(ids):
            if special[i]:
                if cur:
                    toks = self.tokenizer.convert_ids_to_tokens(ids[cur])
                    out.append((" ".join(toks).replace(" ##", ""), np.asarray(cur)))
                cur = []
            else:
                cur.append(i)
        return out

    def preprocess(self, image) -> np.ndarray:
        """(1, 3, h, w) float32: Pillow-bilinear 8-bit resize to :meth:`input_size`, ImageNet."""
        img = as_rgb(image)
        return normalize(resample(img, self.input_size(img.shape[:2]), "bilinear", eight_bit=True),
                         IMAGENET_MEAN, IMAGENET_STD)

    def detect(self, image, prompt: str) -> list[Detection]:
        """Boxes for ``prompt`` in ``image`` (H, W, 3), best first."""
        img = as_rgb(image)
        h, w = img.shape[:2]
        text = self.encode_text(prompt)
        pixels = self.preprocess(img)
        if self.layout == "groundingdino":
            feeds = dict(text, img=pixels)
        else:
            ids = text["input_ids"]
            feeds = {"pixel_values": pixels, "input_ids": ids, "token_type_ids": np.zeros_like(ids),
                     "attention_mask": np.ones_like(ids), "pixel_mask": np.ones((1,) + pixels.shape[2:], np.int64)}
        out = self.model.run(feeds)
        logits = np.asarray(out["logits"], np.float64)[0]
        boxes = np.asarray(out["boxes" if "boxes" in out else "pred_boxes"], np.float64)[0]
        n = min(logits.shape[1], text["input_ids"].shape[1])
        prob = 1.0 / (1.0 + np.exp(-np.clip(logits[:, :n], -80.0, 80.0)))
        phrases = self.phrases(text["input_ids"])
        if not phrases:
            return []
        ids = text["input_ids"][0]
        dets = []
        for q in range(prob.shape[0]):
            # score: best token of the caption (original predict() and transformers' post-processing)
            score = float(prob[q].max())
            if score <= self.box_threshold:
                continue
            # label: the best phrase's tokens above text_threshold (get_phrases_from_posmap)
            _, idx = max(((float(prob[q, i[i < n]].max()) if np.any(i < n) else 0.0, i[i < n])
                          for _, i in phrases), key=lambda t: t[0])
            on = idx[prob[q, idx] > self.text_threshold]
            label = " ".join(self.tokenizer.convert_ids_to_tokens(ids[on if on.size else idx])).replace(" ##", "")
            dets.append(Detection(cxcywh_to_xyxy(boxes[q], w, h)[0], score, label))
        dets.sort(key=lambda d: -d.score)
        return dets[:self.max_detections]
