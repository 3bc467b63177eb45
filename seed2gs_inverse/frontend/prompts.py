"""Prompts that need no model: masks, boxes and clicks in the reference view.

A prompt turns the rendered reference canvas into the seed mask ``m*`` of
Algorithm 1. Three kinds work without any learned model:

``MaskPrompt``
    the mask itself, as an array or a PNG file (non-zero = object; floats
    above 0.5).
``BoxPrompt``
    a box ``x0, y0, x1, y1`` in pixels (exclusive max, like ``Candidate.box``),
    turned into a mask with OpenCV GrabCut on the rendered reference.
``PointPrompt``
    positive/negative clicks, turned into a mask with GrabCut started from a
    colour- and depth-consistent region grown around the positive clicks.

``TextPrompt`` needs a grounding model (``Grounder``); without one,
:func:`seed_mask_from_prompt` fails with a message listing the model-free
alternatives. Plain strings are read as text prompts.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .._validation import check_int, check_real, check_vector
from ..camera import MAX_IMAGE_SIDE
from ..errors import FormatError, ValidationError
from ..io.images import read_image
from ._imaging import opencv
from .base import Candidate, Grounder

__all__ = ["MaskPrompt", "BoxPrompt", "PointPrompt", "TextPrompt", "as_prompt",
           "seed_mask_from_prompt", "TEXT_NEEDS_GROUNDER"]

TEXT_NEEDS_GROUNDER = (
    "a text prompt needs a grounding model (configure one with --models FILE or "
    "extract(..., grounder=...)); without models use a mask, box or point prompt "
    "(--mask PNG, --box X0 Y0 X1 Y1, --point X Y)")


def _to_uint8(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) RGB in [0, 1] as the contiguous BGR uint8 image OpenCV works on."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValidationError(f"reference image must be (H, W, 3) RGB, got shape {img.shape}")
    # OpenCV works on BGR uint8; GrabCut's colour models only see relative colours.
    return np.ascontiguousarray((np.clip(np.nan_to_num(img), 0, 1) * 255 + 0.5).astype(np.uint8)[..., ::-1])


def _grabcut(image: np.ndarray, init: np.ndarray, iterations: int) -> np.ndarray:
    """GrabCut from a label image of cv2.GC_{BGD,FGD,PR_BGD,PR_FGD}; returns bool fg."""
    cv2 = opencv()
    labels = np.ascontiguousarray(init.astype(np.uint8))
    fg_any = np.isin(labels, (cv2.GC_FGD, cv2.GC_PR_FGD)).any()
    bg_any = np.isin(labels, (cv2.GC_BGD, cv2.GC_PR_BGD)).any()
    if not (fg_any and bg_any):
        # GrabCut needs samples of both colour models; without background
        # samples the initial labelling is the only evidence there is.
        return np.isin(labels, (cv2.GC_FGD, cv2.GC_PR_FGD))
    bgd = np.zeros((1, 65), np.float64)
    fgd = np.zeros((1, 65), np.float64)
    img = _to_uint8(image)
    _run_seeded(lambda: cv2.grabCut(img, labels, None, bgd, fgd, int(iterations), cv2.GC_INIT_WITH_MASK))
    return np.isin(labels, (cv2.GC_FGD, cv2.GC_PR_FGD))


#: Most GrabCut rounds a prompt may ask for. GrabCut settles within a few
#: rounds (the default is 5) and each round is a full graph cut of the
#: reference image, so the cap keeps a mistyped count from running for hours.
GRABCUT_MAX_ITERATIONS = 100


def _check_grabcut(prompt: str, iterations, alpha_min) -> None:
    """ValidationError naming the argument unless ``iterations`` is in 1..GRABCUT_MAX_ITERATIONS and
    ``alpha_min`` in [0, 1]."""
    check_int(f"{prompt}(iterations=)", iterations, lo=1, hi=GRABCUT_MAX_ITERATIONS)
    check_real(f"{prompt}(alpha_min=)", alpha_min, lo=0.0, hi=1.0)


#: Seed of OpenCV's random generator for GrabCut (see :func:`_run_seeded`): -1
#: puts ``cv::RNG`` in its default state (``RNG((uint64)-1)``, the state of
#: every new thread), so each GrabCut gives exactly what the first GrabCut of
#: a fresh process gives.
GRABCUT_SEED = -1


def _run_seeded(fn):
    """Run ``fn()`` in a fresh thread whose OpenCV RNG is seeded with :data:`GRABCUT_SEED`.

    GrabCut initialises its colour GMMs with k-means++ (``KMEANS_PP_CENTERS``),
    which draws from ``cv::theRNG()``. That generator is per thread and
    advances with every call, so without a fixed seed two identical box
    prompts in one process could give seeds differing by a few pixels (and
    extractions by a few Gaussians). ``cv2.setRNGSeed`` fixes the draws but
    only for the calling thread's generator; calling it in a short-lived
    thread of our own makes every GrabCut identical for identical input
    *and* leaves the caller's OpenCV RNG (and any user code relying on it)
    untouched.

    Repeatable is not robust: the k-means++ start still decides the result,
    and other seeds can give a markedly different mask for a point prompt
    (less so for a box prompt).
    """
    cv2 = opencv()
    out = {}

    def target():
        try:
            cv2.setRNGSeed(GRABCUT_SEED)
            out["value"] = fn()
        except BaseException as exc:  # re-raised in the caller's thread
            out["error"] = exc

    t = threading.Thread(target=target, name="seed2gs-grabcut", daemon=True)
    t.start()
    t.join()
    if "error" in out:
        raise out["error"]
    return out.get("value")


@dataclass
class MaskPrompt:
    """The seed mask given directly.

    Parameters
    ----------
    mask : (H, W) array or str or os.PathLike
        A boolean or numeric array, or a lossless image file (PNG). Which
        pixels are the object (see :func:`object_pixels`): for booleans and
        integers, every non-zero value (so 0/1 and 0/255 masks both work);
        for floats, values above 0.5 (a mask of probabilities in [0, 1]; NaN
        is background). An 8- or 16-bit image file follows the integer rule
        on its grey (or, in colour, its largest channel) value; an image
        with transparency uses its alpha channel instead (non-zero alpha is
        the object), and a 32-bit float image the float rule. The file's
        header is checked against the reference view's size and the image
        limits of :func:`~seed2gs_inverse.io.images.read_image` before its
        pixels are decoded.
    """

    mask: Any

    def to_mask(self, image: np.ndarray, **_) -> np.ndarray:
        """(H, W) bool seed mask, checked against the reference ``image``'s size and non-empty."""
        h, w = np.asarray(image).shape[:2]
        if isinstance(self.mask, (str, os.PathLike)):
            arr = read_mask_image(self.mask, (h, w))
            name = f"mask file {os.fspath(self.mask)}"
        else:
            arr = np.asarray(self.mask)
            name = "mask"
            if arr.dtype.kind not in "biuf":
                raise ValidationError(f"{name} must be a boolean or numeric array, got dtype {arr.dtype}")
            arr = object_pixels(arr)
        if arr.shape != (h, w):
            raise _mask_shape_error(name, arr.shape, h, w)
        if not arr.any():
            raise ValidationError(f"{name} is empty: mark the object with non-zero pixels (values above 0.5 "
                                  f"in a float mask)")
        return arr


def object_pixels(values: np.ndarray) -> np.ndarray:
    """Which pixels of a mask array are the object: bool of the same shape.

    Booleans and integers: every non-zero value (0/1 and 0/255 masks alike).
    Floats: values above 0.5, the rule for probabilities in [0, 1]; NaN is
    background.
    """
    arr = np.asarray(values)
    if arr.dtype.kind == "f":
        with np.errstate(invalid="ignore"):
            return arr > 0.5
    return arr != 0


def _mask_shape_error(name: str, shape, h: int, w: int) -> ValidationError:
    return ValidationError(f"{name} has shape {tuple(shape)} but the reference view is {h}x{w} (H, W); "
                           f"draw the mask at the reference camera's resolution")


#: Pillow modes read as they are (integer, bool or float pixels); others are converted to RGB first.
_PLAIN_MODES = ("1", "L", "I", "I;16", "I;16L", "I;16B", "I;16N", "F")


def _image_object_pixels(im, name: str, shape) -> np.ndarray:
    """Object pixels of the opened (not yet decoded) mask image ``im`` (see :class:`MaskPrompt`)."""
    if im.format in ("JPEG", "MPO"):
        raise FormatError(f"{name}: a lossy {im.format} image, whose compression turns the background's 0 into "
                          f"other values; save the mask as PNG (0 = background, non-zero = object)")
    if shape is not None and (im.height, im.width) != tuple(shape):
        raise _mask_shape_error(name, (im.height, im.width), *shape)
    if im.mode in ("RGBA", "LA", "PA", "La", "RGBa") or "transparency" in im.info:
        rgba = np.asarray(im.convert("RGBA"))
        if rgba[..., 3].min() < 255:  # a cut-out: the alpha channel is the mask
            return rgba[..., 3] != 0
        return rgba[..., :3].max(axis=2) != 0
    if im.mode in _PLAIN_MODES:
        return object_pixels(np.asarray(im))
    return np.asarray(im.convert("RGB")).max(axis=2) != 0


def read_mask_image(path, shape=None) -> np.ndarray:
    """(H, W) bool object pixels of the mask image file ``path`` (rules in :class:`MaskPrompt`).

    Parameters
    ----------
    path : str or os.PathLike
        A lossless image file (PNG).
    shape : (H, W) or None
        When given, the size the file's header must declare, checked before
        its pixels are decoded.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    FormatError
        Not a regular file, not an image, a lossy JPEG, or an image beyond
        the limits of :func:`~seed2gs_inverse.io.images.read_image`.
    ValidationError
        The image is not of size ``shape``.
    """
    name = f"mask file {os.fspath(path)}"
    return read_image(path, lambda im: _image_object_pixels(im, name, shape), "mask image")


@dataclass
class BoxPrompt:
    """A box ``(x0, y0, x1, y1)`` in pixels, exclusive max, turned into a mask by GrabCut.

    The box is clipped to the image. Pixels outside it are background;
    inside, GrabCut (``iterations`` rounds, 1 to
    :data:`GRABCUT_MAX_ITERATIONS`) separates the object from what the box
    also covers. Where the reference rendering is transparent (alpha <
    ``alpha_min``, in [0, 1]) there is nothing to select, so those pixels
    are fixed to background.

    Raises
    ------
    ValidationError
        When made and when used: a box that is not four finite numbers
        with ``x0 < x1`` and ``y0 < y1``, or ``iterations`` / ``alpha_min``
        out of range; the message names the argument.
    """

    box: Sequence[float]
    iterations: int = 5
    alpha_min: float = 0.05

    def __post_init__(self):
        self._checked()  # when made (a batch job's box fails before any cluster starts) and when used

    def _checked(self) -> np.ndarray:
        """The box as a float64 (4,) array with x0 < x1 and y0 < y1 (parameters checked too), or a ValidationError."""
        _check_grabcut("BoxPrompt", self.iterations, self.alpha_min)
        try:
            b = check_vector("box", self.box, 4)
        except ValidationError:
            raise ValidationError(f"box must be 4 finite numbers x0 y0 x1 y1, got {self.box!r}") from None
        if b[2] <= b[0] or b[3] <= b[1]:
            raise ValidationError(f"box {b.tolist()} is empty: need x0 < x1 and y0 < y1 "
                                  f"([left, top, right, bottom] in pixels)")
        return b

    def to_mask(self, image: np.ndarray, alpha: np.ndarray | None = None, **_) -> np.ndarray:
        """(H, W) bool seed mask of the box on the rendered reference ``image`` (H, W, 3)."""
        cv2 = opencv()
        h, w = np.asarray(image).shape[:2]
        b = self._checked()  # the box may have been changed since (a mutable dataclass)
        x0, y0, x1, y1 = b
        ix0, iy0 = int(np.clip(np.floor(x0), 0, w)), int(np.clip(np.floor(y0), 0, h))
        ix1, iy1 = int(np.clip(np.ceil(x1), 0, w)), int(np.clip(np.ceil(y1), 0, h))
        if ix1 - ix0 < 2 or iy1 - iy0 < 2:
            raise ValidationError(
                f"box {b.tolist()} lies outside the {w}x{h} reference image (or covers < 2 px); "
                f"give pixel coordinates inside the image")
        init = np.full((h, w), cv2.GC_BGD, np.uint8)
        init[iy0:iy1, ix0:ix1] = cv2.GC_PR_FGD
        if alpha is not None:
            init[np.asarray(alpha) < self.alpha_min] = cv2.GC_BGD
        mask = _grabcut(image, init, self.iterations)
        if not mask.any():
            if alpha is not None and not np.any(np.asarray(alpha)[iy0:iy1, ix0:ix1] >= self.alpha_min):
                raise ValidationError(f"box {b.tolist()} selects nothing visible in the reference view")
            # GrabCut's colour models found nothing in the box that differs from around it (a thin
            # object filling a small part of its box, colours alike inside and out)
            raise ValidationError(f"box {b.tolist()}: GrabCut found nothing inside the box that stands out from "
                                  f"its surroundings; click on the object instead (a point prompt), give its "
                                  f"mask, or draw the box a few pixels larger")
        return mask


@dataclass
class PointPrompt:
    """Clicks ``(x, y)`` in pixels with labels 1 (object) or 0 (not the object).

    Turned into a mask without a model: the pixels reachable from a positive
    click without crossing a colour edge (flood fill with tolerance
    ``color_tol`` on the RGB canvas) or a depth jump (relative depth change
    above ``depth_tol`` between neighbours) form the probable object; the
    pixels reachable from negative clicks and transparent pixels are
    background; GrabCut then refines the result, and only its connected
    regions that hold a positive click are kept (GrabCut's colour model would
    otherwise also claim look-alike objects elsewhere in the view). Discs of
    ``radius`` pixels around the clicks are fixed to their label.

    ``color_tol`` lies in [0, 1], ``depth_tol`` is a finite number >= 0,
    ``radius`` a whole number from 0 to
    :data:`~seed2gs_inverse.camera.MAX_IMAGE_SIDE` (a larger disc covers any
    view), ``iterations`` and ``alpha_min`` as for :class:`BoxPrompt`.

    Raises
    ------
    ValidationError
        When made and when used: a parameter out of range (the message
        names it); when used, clicks that are not finite, outside the
        image, or labels other than 0/1.
    """

    points: Sequence[Sequence[float]]
    labels: Sequence[int] | None = None
    color_tol: float = 0.08
    depth_tol: float = 0.03
    radius: int = 3
    iterations: int = 5
    alpha_min: float = 0.05

    def __post_init__(self):
        self._check_parameters()

    def _check_parameters(self) -> None:
        """ValidationError naming the first parameter out of its range."""
        check_real("PointPrompt(color_tol=)", self.color_tol, lo=0.0, hi=1.0)
        check_real("PointPrompt(depth_tol=)", self.depth_tol, lo=0.0)
        check_int("PointPrompt(radius=)", self.radius, lo=0, hi=MAX_IMAGE_SIDE)
        _check_grabcut("PointPrompt", self.iterations, self.alpha_min)

    def _checked(self, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
        """Clicks as (P, 2) int pixels and labels (P,) 0/1, inside an ``h`` x ``w`` image."""
        self._check_parameters()  # a mutable dataclass: checked when made and when used
        pts = np.asarray(self.points, dtype=np.float64).reshape(-1, 2) if len(self.points) else np.zeros((0, 2))
        if pts.shape[0] == 0 or not np.all(np.isfinite(pts)):
            raise ValidationError("point prompt needs at least one finite click (x, y)")
        labels = np.ones(len(pts), int) if self.labels is None else np.asarray(self.labels, dtype=int).ravel()
        if labels.shape != (len(pts),) or not np.all(np.isin(labels, (0, 1))):
            raise ValidationError(f"point labels must be 0/1, one per click; got {self.labels!r}")
        if not labels.any():
            raise ValidationError("point prompt needs at least one positive click (label 1)")
        outside = (pts[:, 0] < 0) | (pts[:, 0] >= w) | (pts[:, 1] < 0) | (pts[:, 1] >= h)
        if outside.any():
            raise ValidationError(
                f"click {pts[np.argmax(outside)].tolist()} is outside the {w}x{h} reference image")
        return pts.astype(int), labels

    def to_mask(self, image: np.ndarray, depth: np.ndarray | None = None,
                alpha: np.ndarray | None = None, **_) -> np.ndarray:
        """(H, W) bool seed mask grown from the clicks on the rendered reference ``image`` (H, W, 3)."""
        cv2 = opencv()
        img = np.asarray(image, dtype=np.float32)
        h, w = img.shape[:2]
        pts, labels = self._checked(h, w)
        solid = np.ones((h, w), bool) if alpha is None else np.asarray(alpha) >= self.alpha_min
        clicks = [(int(x), int(y)) for (x, y), lab in zip(pts, labels) if lab == 1]
        if not any(solid[y, x] for x, y in clicks):  # else GrabCut's disc alone becomes a seed of nothing
            raise ValidationError(f"point prompt: the click(s) {clicks} fall on empty background (the scene renders "
                                  f"nothing there in the reference view); click on the object")
        # Edges that stop the region growing: depth jumps between 4-neighbours.
        barrier = ~solid
        if depth is not None:
            d = np.where(solid, np.asarray(depth, np.float64), np.nan)
            with np.errstate(invalid="ignore", divide="ignore"):
                gx = np.abs(np.diff(d, axis=1)) / np.minimum(d[:, 1:], d[:, :-1])
                gy = np.abs(np.diff(d, axis=0)) / np.minimum(d[1:, :], d[:-1, :])
            jump = np.zeros((h, w), bool)
            jump[:, 1:] |= gx > self.depth_tol
            jump[1:, :] |= gy > self.depth_tol
            barrier |= jump
        u8 = _to_uint8(img)
        tol = int(round(self.color_tol * 255))

        def grow(x, y):
            ff = np.zeros((h + 2, w + 2), np.uint8)
            ff[1:-1, 1:-1] = barrier
            flags = 4 | cv2.FLOODFILL_MASK_ONLY | cv2.FLOODFILL_FIXED_RANGE | (2 << 8)
            cv2.floodFill(u8.copy(), ff, (int(x), int(y)), (0, 0, 0), (tol,) * 3, (tol,) * 3, flags)
            return ff[1:-1, 1:-1] == 2

        pos = np.zeros((h, w), bool)
        neg = np.zeros((h, w), bool)
        for (x, y), lab in zip(pts, labels):
            if lab == 1 and not barrier[y, x]:
                pos |= grow(x, y)
            elif lab == 0 and not barrier[y, x]:
                neg |= grow(x, y)
        init = np.full((h, w), cv2.GC_PR_BGD, np.uint8)
        init[pos & ~neg] = cv2.GC_PR_FGD
        init[neg | ~solid] = cv2.GC_BGD
        yy, xx = np.mgrid[0:h, 0:w]
        for (x, y), lab in zip(pts, labels):
            disc = (xx - x) ** 2 + (yy - y) ** 2 <= self.radius ** 2
            init[disc] = cv2.GC_FGD if lab == 1 else cv2.GC_BGD
        mask = _grabcut(img, init, self.iterations)
        # GrabCut's colour model also claims look-alikes elsewhere in the image
        # (eight red chairs for a click on one): keep only the connected
        # regions that hold a positive click.
        _, comp = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
        keep = [comp[y, x] for (x, y), lab in zip(pts, labels) if lab == 1 and comp[y, x] > 0]
        mask = np.isin(comp, keep)
        if not mask.any():
            raise ValidationError("point prompt selects nothing visible in the reference view")
        return mask


@dataclass
class TextPrompt:
    """An open-vocabulary description; needs a :class:`~seed2gs_inverse.frontend.base.Grounder`."""

    text: str
    info: dict = field(default_factory=dict)


def as_prompt(prompt) -> MaskPrompt | BoxPrompt | PointPrompt | TextPrompt:
    """Normalise a user prompt: strings become ``TextPrompt``, arrays ``MaskPrompt``."""
    if isinstance(prompt, (MaskPrompt, BoxPrompt, PointPrompt, TextPrompt)):
        return prompt
    if isinstance(prompt, str):
        if not prompt.strip():
            raise ValidationError("text prompt is empty")
        return TextPrompt(prompt)
    if isinstance(prompt, np.ndarray):
        return MaskPrompt(prompt)
    raise ValidationError(
        f"prompt must be a MaskPrompt, BoxPrompt, PointPrompt, TextPrompt, a mask array or a "
        f"string, got {type(prompt).__name__}")


def seed_mask_from_prompt(prompt, image: np.ndarray, depth: np.ndarray | None = None,
                          alpha: np.ndarray | None = None,
                          grounder: Grounder | None = None) -> tuple[np.ndarray, dict]:
    """The seed mask ``m*`` of a prompt on the rendered reference canvas.

    Parameters
    ----------
    prompt : MaskPrompt, BoxPrompt, PointPrompt, TextPrompt, str or (H, W) array
    image : (H, W, 3) float32 RGB in [0, 1], the reference rendering.
    depth, alpha : (H, W) float32, optional
        Rendered expected depth and alpha; used by box and point prompts.
    grounder : Grounder, optional
        Required for text prompts. Its candidates are ranked by ``score`` and
        the best becomes the seed (a QD-SAM3 selector returns the Eq. 3 total
        as ``score``).

    Returns
    -------
    mask : (H, W) bool
    info : dict
        ``kind`` and, for grounded prompts, every candidate's source, score,
        box and info, best first.

    Raises
    ------
    ValidationError
        A text prompt without a grounder, a grounder that breaks the
        ``Grounder`` protocol or finds no candidate, or a prompt whose mask
        is empty, off the image or not of the reference view's size.
    """
    prompt = as_prompt(prompt)
    if isinstance(prompt, TextPrompt):
        if grounder is None:
            raise ValidationError(TEXT_NEEDS_GROUNDER)
        if not callable(getattr(grounder, "ground", None)):
            raise ValidationError(f"grounder must have a ground(image, text) method (the Grounder protocol, "
                                  f"seed2gs_inverse.frontend.base), got {type(grounder).__name__}")
        res = grounder.ground(np.asarray(image, np.float32), prompt.text)
        try:
            cands = list(res)
        except TypeError:
            raise ValidationError(f"grounder {type(grounder).__name__}: ground() returned {type(res).__name__}; "
                                  f"it must return a list of Candidate (empty when nothing is found)") from None
        if not cands:
            raise ValidationError(f"the grounder found no candidate for the prompt {prompt.text!r}; "
                                  f"try another wording or a box/point prompt")
        for c in cands:
            if not isinstance(c, Candidate):
                raise ValidationError(f"grounder returned {type(c).__name__}, expected Candidate")
        order = sorted(range(len(cands)), key=lambda k: -float(cands[k].score))
        best = cands[order[0]]
        mask = MaskPrompt(np.asarray(best.mask, bool)).to_mask(image)
        info = {"kind": "text", "text": prompt.text, "candidates": [
            {"source": cands[k].source, "score": float(cands[k].score),
             "box": None if cands[k].box is None else np.asarray(cands[k].box, float).tolist(),
             "info": {a: b for a, b in cands[k].info.items() if isinstance(b, (int, float, str, bool))}}
            for k in order]}
        return mask, info
    kind = type(prompt).__name__.replace("Prompt", "").lower()
    return prompt.to_mask(image, depth=depth, alpha=alpha), {"kind": kind}
