"""SAM2 on onnxruntime: an image predictor and a memory-bank video tracker.

Image predictor (:class:`SAM2ImagePredictor`), two export layouts, detected
from the input names:

- ``samexporter`` (vietanhdev/samexporter ``export_sam2.py``): encoder
  ``image`` (1, 3, S, S) float32 -> ``high_res_feats_0``, ``high_res_feats_1``,
  ``image_embed``; decoder ``image_embed, high_res_feats_0, high_res_feats_1,
  point_coords (L, P, 2), point_labels (L, P), mask_input (L, 1, S/4, S/4),
  has_mask_input (L,)`` [+ optional ``orig_im_size`` (2,)] -> ``masks``
  (L, M, S/4, S/4) logits, ``iou_predictions`` (L, M).
- ``onnxruntime`` (onnxruntime/python/tools/transformers/models/sam2):
  encoder ``image`` -> ``image_features_0``, ``image_features_1``,
  ``image_embeddings``; decoder ``image_features_0, image_features_1,
  image_embeddings, point_coords (L, P, 2) float32, point_labels (L, P)
  int32, input_masks (L, 1, S/4, S/4), has_input_masks (L,),
  original_image_size (2,) int32`` -> ``masks`` (L, M, H, W) (bool or
  logits), ``iou_predictions`` (L, M) [, ``low_res_masks``].

- ``sam-samexporter``, SAM (v1, segment-anything) through samexporter's
  ``export_encoder`` / ``export_decoder``: encoder ``input_image`` (H', W', 3)
  float32 0..255 resized so the longer side is S (``--use-preprocess``:
  normalisation and padding inside the graph) or (1, 3, S, S) normalised and
  padded -> ``image_embeddings``; decoder segment-anything's ``SamOnnxModel``
  ``image_embeddings, point_coords, point_labels, mask_input, has_mask_input,
  orig_im_size`` -> ``masks`` (L, M, H, W) logits at the original size,
  ``iou_predictions`` [, ``low_res_masks``]; when ``low_res_masks`` is
  there the masks are up-sampled from it here, as ``SamPredictor`` does
  (samexporter's traced graph keeps the crop of its dummy image size in
  its own ``masks``, which are then wrong for other aspect ratios). Pre-processing is SAM's
  ``ResizeLongestSide``: Pillow bilinear on the 8-bit image to
  ``round(S h / max(h, w))`` x ``round(S w / max(h, w))``, prompts scaled by
  the same factors; a box is two corners labelled 2, 3; points alone get
  SAM's padding point (0, 0) labelled -1. With M = 4 (no
  ``--return-single-mask``) the best of masks 1..3 is taken, as
  ``SamPredictor(multimask_output=True)``.

Pre-processing of the SAM2 layouts is SAM2's: the RGB image is resized (bilinear, aspect ratio
*not* kept, no padding; anti-aliased when shrinking, as torchvision's
tensor ``Resize``) to the encoder's S x S input (S read from the file,
1024 for the released models) and normalised with the ImageNet mean/std.
Prompt pixel coordinates scale by (S / W, S / H); a box is the two corner
points with labels 2 and 3. Mask logits are upsampled (bilinear) to the
original size and thresholded at 0; with several masks the one with the
highest predicted IoU wins.

Video tracker (:class:`SAM2VideoTracker`), the memory-bank layout of the
``sam2-onnx-cpp`` export (pagarcia/sam2-onnx-cpp ``export/onnx_export.py``):
``image_encoder`` (``input`` -> ``image_embeddings, high_res_features1,
high_res_features2, current_vision_feat, vision_pos_embed``),
``image_decoder`` (``point_coords, point_labels, image_embed,
high_res_feats_0, high_res_feats_1`` -> ``obj_ptr, mask_for_mem,
pred_mask``), ``memory_attention`` (``current_vision_feat,
current_vision_pos_embed, memory_0, memory_1, memory_pos_embed`` ->
``fused_feat``) and ``memory_encoder`` (``mask_for_mem, pix_feat`` ->
``maskmem_features, maskmem_pos_enc, temporal_code``). The memory bank
(conditioning frame + the most recent frames) lives on the host.
"""

from __future__ import annotations

import hashlib
from collections import deque
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..errors import ValidationError
from ._imaging import IMAGENET_MEAN, IMAGENET_STD, as_box, as_rgb, normalize, resample, resize_map
from ._onnx import Layout, OnnxModel, Port

__all__ = ["SAM2ImagePredictor", "SAM2VideoTracker", "MaskPrediction",
           "SAM2_ENCODER_LAYOUTS", "SAM2_DECODER_LAYOUTS", "SAM2_VIDEO_LAYOUTS"]

_F = ("float32",)
_LABEL = ("float32", "int32", "int64")
_SIZE = ("float32", "int32", "int64")

SAM2_ENCODER_LAYOUTS = (
    Layout("samexporter", (Port("image", _F, 4, (1, 3, None, None)),),
           (Port("high_res_feats_0", _F, 4), Port("high_res_feats_1", _F, 4),
            Port("image_embed", _F, 4))),
    Layout("onnxruntime", (Port("image", _F, 4, (None, 3, None, None)),),
           (Port("image_features_0", _F, 4), Port("image_features_1", _F, 4),
            Port("image_embeddings", _F, 4))),
    Layout("sam-samexporter", (Port("input_image", _F, None),), (Port("image_embeddings", _F, 4),)),
)

_SAMEXP_DEC_IN = (Port("image_embed", _F, 4), Port("high_res_feats_0", _F, 4),
                  Port("high_res_feats_1", _F, 4), Port("point_coords", _F, 3, (None, None, 2)),
                  Port("point_labels", _LABEL, 2), Port("mask_input", _F, 4),
                  Port("has_mask_input", _F, 1), Port("orig_im_size", _SIZE, 1, (2,), optional=True))
SAM2_DECODER_LAYOUTS = (
    Layout("samexporter", _SAMEXP_DEC_IN,
           (Port("masks", _F, 4), Port("iou_predictions", _F, 2))),
    Layout("samexporter-scores", _SAMEXP_DEC_IN,
           (Port("masks", _F, 4), Port("scores", _F, 2))),
    Layout("onnxruntime",
           (Port("image_features_0", _F, 4), Port("image_features_1", _F, 4),
            Port("image_embeddings", _F, 4), Port("point_coords", _F, 3, (None, None, 2)),
            Port("point_labels", _LABEL, 2), Port("input_masks", _F, 4),
            Port("has_input_masks", _F, 1), Port("original_image_size", _SIZE, 1, (2,))),
           (Port("masks", ("bool", "float32"), 4), Port("iou_predictions", _F, 2),
            Port("low_res_masks", _F, 4, optional=True))),
    Layout("sam-samexporter",
           (Port("image_embeddings", _F, 4), Port("point_coords", _F, 3, (None, None, 2)),
            Port("point_labels", _LABEL, 2), Port("mask_input", _F, 4), Port("has_mask_input", _F, 1),
            Port("orig_im_size", _SIZE, 1, (2,))),
           (Port("masks", _F, 4), Port("iou_predictions", _F, 2), Port("low_res_masks", _F, 4, optional=True))),
)

SAM2_VIDEO_LAYOUTS = {
    "image_encoder": (Layout("sam2-onnx-cpp", (Port("input", _F, 4, (1, 3, None, None)),),
                             (Port("image_embeddings", _F, 4), Port("high_res_features1", _F, 4),
                              Port("high_res_features2", _F, 4), Port("current_vision_feat", _F, 4),
                              Port("vision_pos_embed", _F, 3))),),
    "image_decoder": (Layout("sam2-onnx-cpp",
                             (Port("point_coords", _F, 3, (None, None, 2)), Port("point_labels", _LABEL, 2),
                              Port("image_embed", _F, 4), Port("high_res_feats_0", _F, 4),
                              Port("high_res_feats_1", _F, 4)),
                             (Port("obj_ptr", _F, None, optional=True), Port("mask_for_mem", _F, 4),
                              Port("pred_mask", _F, 4))),),
    "memory_attention": (Layout("sam2-onnx-cpp",
                                (Port("current_vision_feat", _F, 4), Port("current_vision_pos_embed", _F, 3),
                                 Port("memory_0", _F, 2, optional=True), Port("memory_1", _F, 4),
                                 Port("memory_pos_embed", _F, 3)),
                                (Port("fused_feat", _F, 4),)),),
    "memory_encoder": (Layout("sam2-onnx-cpp",
                              (Port("mask_for_mem", _F, 4), Port("pix_feat", _F, 4)),
                              (Port("maskmem_features", _F, 4), Port("maskmem_pos_enc", _F, 3),
                               Port("temporal_code", _F, None, optional=True))),),
}


@dataclass
class MaskPrediction:
    """Result of one SAM prompt.

    Attributes
    ----------
    mask : (H, W) bool
        ``logits > threshold`` of the chosen mask.
    score : float
        Predicted IoU of the chosen mask.
    logits : (H, W) float32
        The chosen mask's logits at the original size (±1 for boolean exports).
    scores : (M,) float32
        Predicted IoU of every output mask.
    index : int
        Which of the M masks was chosen.
    """

    mask: np.ndarray
    score: float
    logits: np.ndarray
    scores: np.ndarray
    index: int


def _fingerprint(img: np.ndarray) -> str:
    """Key of an image's content and shape: the encoder runs again only for a new image."""
    return hashlib.blake2b(np.ascontiguousarray(img).tobytes(), digest_size=16).hexdigest() + str(img.shape)


def _prompt_arrays(shape_hw, input_hw, box=None, points=None, labels=None):
    """SAM prompt tensors: box corners (labels 2, 3) then points, in encoder pixels.

    ``x_in = x * S_w / W``, ``y_in = y * S_h / H`` (SAM2 resizes without padding).
    """
    h, w = shape_hw
    coords, labs = [], []
    if box is not None:
        b = as_box(box, shape_hw)
        coords += [[b[0], b[1]], [b[2], b[3]]]
        labs += [2, 3]
    if points is not None:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        lab = np.ones(len(pts)) if labels is None else np.asarray(labels, dtype=np.float64).reshape(-1)
        if len(lab) != len(pts) or not np.all(np.isin(lab, (0, 1))):
            raise ValidationError("labels: give one label per point, 1 (foreground) or 0 (background)")
        if not np.all(np.isfinite(pts)):
            raise ValidationError("points: coordinates must be finite pixel positions")
        coords += pts.tolist()
        labs += lab.tolist()
    if not coords:
        raise ValidationError("prompt: give a box or at least one point")
    c = np.asarray(coords, dtype=np.float32)[None]
    c[..., 0] *= input_hw[1] / w
    c[..., 1] *= input_hw[0] / h
    return c, np.asarray(labs, dtype=np.float32)[None]


class SAM2ImagePredictor:
    """SAM2 image predictor over an encoder/decoder ONNX pair.

    Parameters
    ----------
    encoder, decoder : str or Path
        ONNX files of one of the two supported layouts (module docstring).
    mask_threshold : float
        Threshold on the mask logits (0 as in SAM2).
    providers : list of str, optional
        onnxruntime execution providers.

    Examples
    --------
    >>> pred = SAM2ImagePredictor("sam2.encoder.onnx", "sam2.decoder.onnx")  # doctest: +SKIP
    >>> out = pred.predict(image, box=[10, 20, 200, 220])                  # doctest: +SKIP
    >>> out.mask.shape, out.score                                          # doctest: +SKIP
    """

    def __init__(self, encoder, decoder, mask_threshold: float = 0.0, providers=None):
        self.encoder = OnnxModel(encoder, "sam2.encoder", SAM2_ENCODER_LAYOUTS, providers)
        self.decoder = OnnxModel(decoder, "sam2.decoder", SAM2_DECODER_LAYOUTS, providers)
        self.layout = self.encoder.layout.name
        if not self.decoder.layout.name.startswith(self.layout):
            raise ValidationError(
                f"sam2: encoder {self.encoder.path} has the {self.layout} layout but decoder "
                f"{self.decoder.path} has the {self.decoder.layout.name} layout; use a matching pair")
        if self.layout == "sam-samexporter":
            shape = self.encoder.session.get_inputs()[0].shape or []
            if len(shape) not in (3, 4):
                raise ValidationError(f"{self.encoder.path}: input_image must be (H, W, 3) or (1, 3, S, S), "
                                      f"found rank {len(shape)}")
            self._in_graph_preprocess = len(shape) == 3
            s = 1024 if self._in_graph_preprocess else self.encoder.input_dim("input_image", 2, 1024)
            self.input_size = (s, s)
        else:
            s = self.encoder.input_dim("image", 2, 1024)
            self.input_size = (s, self.encoder.input_dim("image", 3, s))
        self.mask_threshold = float(mask_threshold)
        self._key = None
        self._features: dict[str, np.ndarray] = {}
        self._shape = None

    @property
    def features(self) -> dict:
        """Encoder outputs of the current image (name -> array)."""
        return dict(self._features)

    def resized_shape(self, shape_hw) -> tuple[int, int]:
        """(h', w') the image is resized to: S x S (SAM2), longer side S (SAM)."""
        if self.layout != "sam-samexporter":
            return self.input_size
        h, w = shape_hw
        scale = self.input_size[0] / max(h, w)
        return int(h * scale + 0.5), int(w * scale + 0.5)

    def preprocess(self, image) -> np.ndarray:
        """The encoder's input tensor.

        SAM2: (1, 3, S, S) float32, bilinear resize to S x S, ImageNet
        normalisation. SAM: the 8-bit Pillow-bilinear resize of the longer
        side to S, as 0..255 floats (H', W', 3) when the graph normalises and
        pads, else normalised and zero-padded to (1, 3, S, S).
        """
        img = as_rgb(image)
        if self.layout != "sam-samexporter":
            return normalize(resample(img, self.input_size), IMAGENET_MEAN, IMAGENET_STD)
        small = resample(img, self.resized_shape(img.shape[:2]), "bilinear", eight_bit=True)
        if self._in_graph_preprocess:
            return np.round(small * 255.0).astype(np.float32)
        out = np.zeros((1, 3) + tuple(self.input_size), np.float32)
        norm = normalize(small, IMAGENET_MEAN, IMAGENET_STD)
        out[:, :, :norm.shape[2], :norm.shape[3]] = norm
        return out

    def set_image(self, image) -> None:
        """Encode ``image`` (H, W, 3) RGB once; later prompts reuse the features."""
        img = as_rgb(image)
        key = _fingerprint(img)
        if key == self._key:
            return
        name = "input_image" if self.layout == "sam-samexporter" else "image"
        self._features = self.encoder.run({name: self.preprocess(img)})
        self._shape = img.shape[:2]
        self._key = key

    def predict(self, image=None, box=None, points=None, labels=None,
                multimask: bool = True) -> MaskPrediction:
        """Segment with a box and/or points.

        Parameters
        ----------
        image : (H, W, 3) array, optional
            Encoded if different from the current image (``set_image``).
        box : (4,) x0, y0, x1, y1 in pixels, optional
        points : (P, 2) x, y in pixels, optional
        labels : (P,) 1 foreground / 0 background, default all 1.
        multimask : bool
            Choose the best of the M output masks by predicted IoU (True) or
            take the first (False).
        """
        if image is not None:
            self.set_image(image)
        if self._shape is None:
            raise ValidationError("image: call set_image(image) or pass image= before predicting")
        h, w = self._shape
        coords, labs = _prompt_arrays(self._shape, self.resized_shape(self._shape), box, points, labels)
        f = self._features
        if self.layout == "sam-samexporter":
            if box is None:  # SAM's prompt encoder pads point-only prompts with a "not a point"
                coords = np.concatenate([coords, np.zeros((1, 1, 2), np.float32)], axis=1)
                labs = np.concatenate([labs, -np.ones((1, 1), np.float32)], axis=1)
            low = self.decoder.input_dim("mask_input", 2, self.input_size[0] // 4)
            feeds = {"image_embeddings": f["image_embeddings"], "point_coords": coords, "point_labels": labs,
                     "mask_input": np.zeros((1, 1, low, self.decoder.input_dim("mask_input", 3, low)), np.float32),
                     "has_mask_input": np.zeros(1, np.float32), "orig_im_size": np.array([h, w])}
            names = ["masks", "iou_predictions"] + (["low_res_masks"] if self.decoder.has_output("low_res_masks") else [])
            out = self.decoder.run(feeds, names)
            ious = out["iou_predictions"]
            if "low_res_masks" in out:
                # SamPredictor's postprocess_masks on the host: the traced in-graph
                # version keeps the crop of the export's dummy image size, so its
                # `masks` are wrong for other aspect ratios
                rh, rw = self.resized_shape((h, w))
                s = self.input_size
                out["masks"] = np.stack([[resize_map(resize_map(m, s)[:rh, :rw], (h, w)) for m in lab]
                                         for lab in np.asarray(out["low_res_masks"], np.float32)])
        elif self.layout == "samexporter":
            low = self.decoder.input_dim("mask_input", 2, self.input_size[0] // 4)
            feeds = {"image_embed": f["image_embed"], "high_res_feats_0": f["high_res_feats_0"],
                     "high_res_feats_1": f["high_res_feats_1"], "point_coords": coords,
                     "point_labels": labs,
                     "mask_input": np.zeros((1, 1, low, self.decoder.input_dim("mask_input", 3, low)), np.float32),
                     "has_mask_input": np.zeros(1, np.float32),
                     "orig_im_size": np.array([h, w])}
            out = self.decoder.run(feeds)
            ious = out.get("iou_predictions", out.get("scores"))
        else:
            low = self.decoder.input_dim("input_masks", 2, self.input_size[0] // 4)
            feeds = {"image_features_0": f["image_features_0"], "image_features_1": f["image_features_1"],
                     "image_embeddings": f["image_embeddings"], "point_coords": coords,
                     "point_labels": labs,
                     "input_masks": np.zeros((1, 1, low, self.decoder.input_dim("input_masks", 3, low)), np.float32),
                     "has_input_masks": np.zeros(1, np.float32),
                     "original_image_size": np.array([h, w])}
            out = self.decoder.run(feeds, ["masks", "iou_predictions"])
            ious = out["iou_predictions"]
        masks = np.asarray(out["masks"])[0]
        ious = np.asarray(ious, dtype=np.float32).reshape(-1)
        if masks.shape[0] != ious.size:
            raise ValidationError(f"{self.decoder.path}: {masks.shape[0]} masks but {ious.size} scores")
        # SAM's 4-mask output: mask 0 is the single-mask token, 1..3 the multimask ones
        first = 1 if (self.layout == "sam-samexporter" and ious.size == 4 and multimask) else 0
        idx = first + int(np.argmax(ious[first:])) if multimask else 0
        chosen = masks[idx]
        if chosen.dtype == np.bool_:
            logits = np.where(chosen, 1.0, -1.0).astype(np.float32)
            if logits.shape != (h, w):
                logits = resize_map(logits, (h, w))
            thr = 0.0
        else:
            logits = resize_map(chosen, (h, w))
            thr = self.mask_threshold
        return MaskPrediction(mask=logits > thr, score=float(ious[idx]), logits=logits,
                              scores=ious, index=idx)

    def segment_box(self, image, box):
        """Mask model protocol of the selector: ``(mask (H, W) bool, score)``."""
        out = self.predict(image, box=box)
        return out.mask, out.score


class _MemoryBank:
    """Host-side SAM2 memory: the conditioning frame plus the latest frames.

    SAM2 attends to ``num_maskmem`` memories: the conditioning (prompted)
    frame with temporal position 0 and the ``num_maskmem - 1`` most recent
    tracked frames with positions t = 1 (previous frame) ... Each memory's
    positional encoding gets ``temporal_code[num_maskmem - t - 1]`` added
    (SAM2's ``maskmem_tpos_enc`` indexing). Older frames fall out.
    """

    def __init__(self, num_maskmem: int):
        if num_maskmem < 1:
            raise ValidationError("num_maskmem: need at least 1 memory (the conditioning frame)")
        self.num_maskmem = int(num_maskmem)
        self.conditioning = None
        self.recent: deque = deque(maxlen=self.num_maskmem - 1)

    def set_conditioning(self, frame: int, features, pos_enc, temporal_code=None):
        """Make ``frame`` the conditioning memory and empty the recent frames."""
        self.conditioning = (frame, features, pos_enc, temporal_code)
        self.recent.clear()

    def push(self, frame: int, features, pos_enc, temporal_code=None):
        """Add ``frame``'s memory as the newest; the oldest falls out when the bank is full."""
        if self.recent.maxlen:
            self.recent.append((frame, features, pos_enc, temporal_code))

    def assemble(self):
        """``memory_1`` (F, C, h, w), ``memory_pos_embed`` (F*h*w, 1, C), frame ids.

        Order: conditioning frame, then recent frames from the newest (t=1)
        to the oldest.
        """
        if self.conditioning is None:
            raise ValidationError("memory bank: no conditioning frame")
        entries = [(0, self.conditioning)] + [(t + 1, e) for t, e in enumerate(reversed(self.recent))]
        feats, pos, frames = [], [], []
        for t, (frame, f, p, code) in entries:
            enc = np.asarray(p, np.float32)
            if code is not None:
                code = np.asarray(code, np.float32)
                k = code.shape[0]
                enc = enc + code[max(0, min(k - 1, self.num_maskmem - t - 1))].reshape(1, 1, -1)
            feats.append(np.asarray(f, np.float32))
            pos.append(enc)
            frames.append(frame)
        return np.concatenate(feats, axis=0), np.concatenate(pos, axis=0), frames


class SAM2VideoTracker:
    """SAM2 video propagation over the four memory-bank ONNX modules.

    Parameters
    ----------
    image_encoder, image_decoder, memory_attention, memory_encoder : path
        The ``sam2-onnx-cpp`` files (module docstring).
    num_maskmem : int, optional
        Memories attended to (conditioning + recent). Default: the length of
        the memory encoder's ``temporal_code`` output, else 7 (SAM2).
    mem_scale, mem_bias : float
        SAM2's ``sigmoid_scale_for_mem_enc`` / ``sigmoid_bias_for_mem_enc``
        (20, -10), which turn the seed mask into the decoder's
        ``mask_for_mem`` form: ``sigmoid(20 m - 10) * scale + bias`` (SAM2's
        mask-as-output path for a mask prompt).
    mask_threshold : float
        Threshold on the upsampled ``pred_mask`` logits.

    Notes
    -----
    Frame 0 is the conditioning frame: its memory is encoded from the seed
    mask itself, and the first returned mask is the seed. Every later frame
    is memory-conditioned (``fused_feat``) and decoded with no prompt (one
    padding point, label -1), then its own memory joins the bank. Object
    pointers are not used (``memory_0`` is empty), as in the export's own
    reference video demo. ``bank_history`` records, for every frame, which
    frame indices were in the memory.
    """

    def __init__(self, image_encoder, image_decoder, memory_attention, memory_encoder,
                 num_maskmem: int | None = None, mem_scale: float = 20.0, mem_bias: float = -10.0,
                 mask_threshold: float = 0.0, providers=None):
        L = SAM2_VIDEO_LAYOUTS
        self.encoder = OnnxModel(image_encoder, "sam2_video.image_encoder", L["image_encoder"], providers)
        self.decoder = OnnxModel(image_decoder, "sam2_video.image_decoder", L["image_decoder"], providers)
        self.attention = OnnxModel(memory_attention, "sam2_video.memory_attention", L["memory_attention"], providers)
        self.memory_encoder = OnnxModel(memory_encoder, "sam2_video.memory_encoder", L["memory_encoder"], providers)
        s = self.encoder.input_dim("input", 2, 1024)
        self.input_size = (s, self.encoder.input_dim("input", 3, s))
        self.num_maskmem = num_maskmem
        self.mem_scale, self.mem_bias = float(mem_scale), float(mem_bias)
        self.mask_threshold = float(mask_threshold)
        self.bank_history: list[list[int]] = []

    def _encode(self, rgb):
        """Image-encoder outputs of an (H, W, 3) RGB frame, resized to S x S and ImageNet-normalised."""
        return self.encoder.run({"input": normalize(resample(rgb, self.input_size), IMAGENET_MEAN, IMAGENET_STD)})

    def _memory(self, mask_for_mem, pix_feat):
        """``(maskmem_features, maskmem_pos_enc, temporal_code or None)`` of one frame's mask and features."""
        out = self.memory_encoder.run({"mask_for_mem": mask_for_mem, "pix_feat": pix_feat})
        return out["maskmem_features"], out["maskmem_pos_enc"], out.get("temporal_code")

    def track(self, frames: Sequence[Any], seed_mask, references: Sequence = ()) -> list[np.ndarray]:
        """Propagate ``seed_mask`` over ``frames`` (first frame = reference).

        Parameters
        ----------
        frames : sequence
            Objects with an ``rgb`` (H_k, W_k, 3) float attribute in [0, 1],
            or the arrays themselves. Sizes may differ between frames (the
            pipeline renders the reference at full and the orbit at reduced
            resolution): every frame is resized to the encoder's S x S.
        seed_mask : (H_0, W_0) array
            Seed in the first frame, values in [0, 1] (NaN counts as 0).
        references : sequence of (frame, mask), optional
            Views labelled elsewhere (the :class:`~seed2gs_inverse.frontend.base.Tracker`
            protocol). Not used: SAM2 propagates from the seed frame's memory
            only, so that every clip is tracked from the user's own view.

        Returns
        -------
        list of (H_k, W_k) float32
            1 inside / 0 outside the tracked object, one per frame at that
            frame's size; the first is the seed (binarised at 0.5).
        """
        if len(frames) == 0:
            raise ValidationError("frames: the clip is empty")
        imgs = [as_rgb(getattr(f, "rgb", f), f"frames[{i}]") for i, f in enumerate(frames)]
        h, w = imgs[0].shape[:2]
        seed = np.asarray(seed_mask, dtype=np.float32)
        if seed.shape != (h, w):
            raise ValidationError(f"seed_mask: shape {seed.shape} does not match the first frame's {(h, w)}")
        seed = (np.nan_to_num(seed, nan=0.0) > 0.5).astype(np.float32)

        feats = self._encode(imgs[0])
        logits = resize_map(seed * 20.0 - 10.0, self.input_size)
        mask_for_mem = (1.0 / (1.0 + np.exp(-logits)) * self.mem_scale + self.mem_bias)[None, None].astype(np.float32)
        mf, mp, code = self._memory(mask_for_mem, feats["image_embeddings"])
        n = self.num_maskmem or (int(np.asarray(code).shape[0]) if code is not None else 7)
        bank = _MemoryBank(n)
        bank.set_conditioning(0, mf, mp, code)
        self.bank_history = [[]]
        out = [seed.copy()]
        ptr_dim = self.attention.input_dim("memory_0", 1, 256) if self.attention.has_input("memory_0") else 0
        for i in range(1, len(imgs)):
            feats = self._encode(imgs[i])
            memory_1, memory_pos, ids = bank.assemble()
            self.bank_history.append(ids)
            fused = self.attention.run({
                "current_vision_feat": feats["current_vision_feat"],
                "current_vision_pos_embed": feats["vision_pos_embed"],
                "memory_0": np.zeros((0, ptr_dim), np.float32),
                "memory_1": memory_1, "memory_pos_embed": memory_pos})["fused_feat"]
            dec = self.decoder.run({
                "point_coords": np.zeros((1, 1, 2), np.float32),
                "point_labels": -np.ones((1, 1), np.float32),
                "image_embed": fused, "high_res_feats_0": feats["high_res_features1"],
                "high_res_feats_1": feats["high_res_features2"]}, ["mask_for_mem", "pred_mask"])
            pred = np.asarray(dec["pred_mask"])[0, 0]
            out.append((resize_map(pred, imgs[i].shape[:2]) > self.mask_threshold).astype(np.float32))
            mf, mp, code = self._memory(np.asarray(dec["mask_for_mem"])[:, :1], feats["image_embeddings"])
            bank.push(i, mf, mp, code)
        return out
