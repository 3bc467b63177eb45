"""Image and box helpers shared by the ONNX model wrappers (pre/post-processing)."""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix

from ..errors import ValidationError

__all__ = ["IMAGENET_MEAN", "IMAGENET_STD", "CLIP_MEAN", "CLIP_STD", "as_rgb",
           "resize_normalize", "resample", "normalize", "resize_map", "cxcywh_to_xyxy", "mask_box", "box_iou",
           "as_box", "opencv"]

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)


def opencv():
    """The ``cv2`` module, imported on first use.

    OpenCV is large to load, and the front end is imported by code that
    never calls it (the pipeline, hence ``seed2gs --help``); every function
    of the front end that needs OpenCV gets it here, so that importing
    :mod:`seed2gs_inverse.frontend` does not load it.
    """
    import cv2

    return cv2


def as_rgb(image, name: str = "image") -> np.ndarray:
    """Validate an RGB image and return it as (H, W, 3) float32 in [0, 1].

    uint8 images are divided by 255. Float images are clipped to [0, 1], as
    saving them to 8 bits would: 3DGS colours (SH + 0.5, clamped at 0 only)
    can exceed 1 in renderings.

    Raises
    ------
    ValidationError
        Not (H, W, 3) with H, W >= 1, not a real or uint8 dtype, or holding
        NaN or infinite values; the message starts with ``name``.
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise ValidationError(f"{name}: expected an (H, W, 3) RGB image, got shape {img.shape}")
    if img.dtype == np.uint8:
        return img.astype(np.float32) / 255.0
    if not np.issubdtype(img.dtype, np.number) or np.issubdtype(img.dtype, np.complexfloating):
        raise ValidationError(f"{name}: expected a float or uint8 RGB image, got dtype {img.dtype}")
    img = img.astype(np.float32)
    if not np.all(np.isfinite(img)):
        raise ValidationError(f"{name}: the image has NaN or infinite values")
    return np.clip(img, 0.0, 1.0)


def resize_normalize(image: np.ndarray, size_hw, mean, std) -> np.ndarray:
    """Resize an RGB image (bilinear) and normalise it per channel.

    ``x' = (resize(x) - mean) / std`` with ``x`` in [0, 1]; returns the
    (1, 3, h, w) float32 NCHW tensor most vision exports take.
    """
    h, w = int(size_hw[0]), int(size_hw[1])
    img = np.asarray(image, np.float32)
    if img.shape[:2] != (h, w):
        cv2 = opencv()
        img = cv2.resize(img, (w, h), interpolation=cv2.INTER_LINEAR)
    # per-channel writes straight into the NCHW buffer: one pass, no
    # full-size temporaries (cheaper than broadcasting, then transposing)
    out = np.empty((1, 3, h, w), np.float32)
    for c in range(3):
        np.subtract(img[:, :, c], np.float32(mean[c]), out=out[0, c])
        out[0, c] *= np.float32(1.0 / std[c])
    return out


def _kernel(name: str):
    """(support, f) of PIL's resampling filters (Pillow ``Resample.c``)."""
    if name == "bilinear":
        return 1.0, lambda x: np.clip(1.0 - np.abs(x), 0.0, None)

    def cubic(x, a=-0.5):  # Keys' cubic with a = -0.5, as Pillow and torchvision
        x = np.abs(x)
        return np.where(x < 1.0, ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0,
                        np.where(x < 2.0, (((x - 5.0) * x + 8.0) * x - 4.0) * a, 0.0))
    if name == "bicubic":
        return 2.0, cubic
    raise ValidationError(f"resample: unknown filter {name!r} (bilinear or bicubic)")


def _weights(n_in: int, n_out: int, kernel: str) -> np.ndarray:
    """(n_out, n_in) resampling matrix of Pillow's ``precompute_coeffs``.

    Output pixel ``i`` has centre ``c = (i + 0.5) s`` in input pixels,
    ``s = n_in / n_out``; the filter is stretched by ``max(s, 1)`` when
    shrinking (anti-aliasing), its taps ``f((j + 0.5 - c) / max(s, 1))``
    over ``j`` in the support are normalised to sum 1. When enlarging this
    is plain bilinear/bicubic interpolation with half-pixel centres and
    clamped borders, the same as ``torch.nn.functional.interpolate(...,
    align_corners=False, antialias=True)``.
    """
    support, f = _kernel(kernel)
    scale = n_in / n_out
    fs = max(scale, 1.0)
    centre = (np.arange(n_out) + 0.5) * scale
    lo = np.maximum(np.trunc(centre - support * fs + 0.5), 0).astype(np.int64)
    hi = np.minimum(np.trunc(centre + support * fs + 0.5), n_in).astype(np.int64)
    j = np.arange(n_in)
    w = f((j[None, :] - centre[:, None] + 0.5) / fs)
    w[(j[None, :] < lo[:, None]) | (j[None, :] >= hi[:, None])] = 0.0
    total = w.sum(axis=1, keepdims=True)
    return w / np.where(total == 0.0, 1.0, total)


def resample(image: np.ndarray, size_hw, kernel: str = "bilinear", eight_bit: bool = False) -> np.ndarray:
    """Resize an (H, W, C) image as Pillow does (anti-aliased when shrinking).

    Separable: the horizontal pass, then the vertical one. With
    ``eight_bit`` the image is quantised to 8 bits first and after each pass
    (Pillow resizes uint8 images in 8-bit), which is what the HuggingFace
    image processors and segment-anything's ``ResizeLongestSide`` feed their
    models; without it the passes stay in float, as torchvision's
    anti-aliased tensor resize (SAM2). Values in [0, 1] in and out.
    """
    h, w = int(size_hw[0]), int(size_hw[1])
    img = np.asarray(image, np.float32)
    if img.ndim != 3:
        raise ValidationError(f"image: expected (H, W, C), got shape {img.shape}")
    q = (lambda a: np.clip(np.round(a * 255.0), 0, 255) / 255.0) if eight_bit else (lambda a: a)
    chw = q(np.ascontiguousarray(img.transpose(2, 0, 1)))          # (C, H, W)
    c, hin, win = chw.shape
    # the taps are banded (a few per output pixel): sparse products keep a
    # 4K -> 1024 resize at O(pixels * taps) instead of a dense O(H W w) product
    if win != w:
        wx = csr_matrix(_weights(win, w, kernel).astype(np.float32))
        chw = q(np.asarray(wx @ chw.reshape(c * hin, win).T).T.reshape(c, hin, w))
    if hin != h:
        wy = csr_matrix(_weights(hin, h, kernel).astype(np.float32))
        chw = q(np.stack([np.asarray(wy @ chw[k]) for k in range(c)]))
    return np.ascontiguousarray(chw.transpose(1, 2, 0), dtype=np.float32)


def normalize(image: np.ndarray, mean, std) -> np.ndarray:
    """(1, 3, H, W) float32 NCHW tensor ``(x - mean) / std`` of an (H, W, 3) image."""
    img = np.asarray(image, np.float32)
    out = np.empty((1, 3) + img.shape[:2], np.float32)
    for c in range(3):
        np.subtract(img[:, :, c], np.float32(mean[c]), out=out[0, c])
        out[0, c] *= np.float32(1.0 / std[c])
    return out


def resize_map(values: np.ndarray, size_hw) -> np.ndarray:
    """Bilinear resize of a 2-D float map (mask logits) to ``size_hw`` = (H, W).

    cv2's INTER_LINEAR with half-pixel centres, the same sampling as
    ``torch.nn.functional.interpolate(..., mode="bilinear", align_corners=False)``
    that the reference predictors use.
    """
    h, w = int(size_hw[0]), int(size_hw[1])
    v = np.asarray(values, dtype=np.float32)
    if v.shape == (h, w):
        return v.copy()
    cv2 = opencv()
    return cv2.resize(v, (w, h), interpolation=cv2.INTER_LINEAR)


def cxcywh_to_xyxy(boxes, width: float, height: float) -> np.ndarray:
    """Normalised (cx, cy, w, h) boxes to pixel (x0, y0, x1, y1), clipped to the image."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    out = np.stack([(b[:, 0] - b[:, 2] / 2) * width, (b[:, 1] - b[:, 3] / 2) * height,
                    (b[:, 0] + b[:, 2] / 2) * width, (b[:, 1] + b[:, 3] / 2) * height], axis=1)
    out[:, [0, 2]] = np.clip(out[:, [0, 2]], 0, width)
    out[:, [1, 3]] = np.clip(out[:, [1, 3]], 0, height)
    return out


def mask_box(mask: np.ndarray) -> np.ndarray | None:
    """Tight (x0, y0, x1, y1) pixel box of a boolean mask (exclusive max), None if empty."""
    ys, xs = np.nonzero(mask)
    if xs.size == 0:
        return None
    return np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], dtype=np.float64)


def box_iou(a, b) -> float:
    """Intersection over union of two (x0, y0, x1, y1) boxes."""
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return float(inter / union) if union > 0 else 0.0


def as_box(box, shape_hw, name: str = "box") -> np.ndarray:
    """Validate an (x0, y0, x1, y1) pixel box inside an image of ``shape_hw``.

    Returns
    -------
    (4,) float64
        The box clipped to the image, ``0 <= x0 < x1 <= W``, ``0 <= y0 < y1 <= H``.

    Raises
    ------
    ValidationError
        Not 4 finite numbers, or empty once clipped to the image.
    """
    b = np.asarray(box, dtype=np.float64).reshape(-1)
    if b.size != 4 or not np.all(np.isfinite(b)):
        raise ValidationError(f"{name}: expected 4 finite numbers x0, y0, x1, y1, got {box!r}")
    h, w = shape_hw
    b = np.array([np.clip(b[0], 0, w), np.clip(b[1], 0, h), np.clip(b[2], 0, w), np.clip(b[3], 0, h)])
    if b[2] <= b[0] or b[3] <= b[1]:
        given = np.round(np.asarray(box, dtype=np.float64).reshape(-1), 2).tolist()
        raise ValidationError(f"{name}: box {given} is empty inside the {w}x{h} image; give x0 < x1 and "
                              f"y0 < y1 in pixels")
    return b
