"""Reading a directory of per-view supervision masks.

A masks directory holds one file per view, in view order: ``view_000.png``
(8-bit greyscale; 0/255 become 0/1 in the solvers, opaque colour images are
converted to grey; a transparent cut-out is refused, since its mask would be
the alpha channel) or ``view_000.npy`` (float in [0, 1] with NaN for
unknown pixels, bool or integer 0/1, uint8 0/255). Views may use different
formats (a PNG where the mask is binary, an .npy where it has unknown
pixels), but each view has exactly one file.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import FormatError, ValidationError
from ._common import load_npy
from .images import read_image

__all__ = ["read_masks", "MASK_NAME"]

#: File names of the masks: ``view_<index>.png`` or ``view_<index>.npy``.
MASK_NAME = re.compile(r"^view_(\d+)\.(png|npy)\Z", re.IGNORECASE)


def _mask_files(d: Path, n_views: int | None = None) -> list[Path]:
    """The mask files of ``d`` in view order, after checking names, numbering (against ``n_views``
    views when given) and format."""
    if not d.is_dir():
        raise FormatError(f"{d}: not a directory of masks (view_000.png|npy, ...)")
    found = {}
    for f in d.iterdir():
        m = MASK_NAME.match(f.name)
        if m:
            k = int(m.group(1))
            if k in found:
                raise FormatError(f"{d}: two masks for view {k} ({found[k].name}, {f.name}); keep one")
            found[k] = f
    if not found:
        raise FormatError(f"{d}: no masks named view_000.png / view_000.npy")
    extra = sorted(k for k in found if n_views is not None and k >= n_views)
    if extra:
        names = ", ".join(found[k].name for k in extra[:3]) + (", ..." if len(extra) > 3 else "")
        raise ValidationError(f"{d}: {names} {'names a view' if len(extra) == 1 else 'name views'} beyond the "
                              f"{n_views} operator views (view_000 .. view_{n_views - 1:03d}); remove or "
                              f"renumber {'it' if len(extra) == 1 else 'them'}")
    if sorted(found) != list(range(len(found))):
        # (a few beyond the file count at most, never up to the largest number: one view_99999999 must
        # not cost gigabytes)
        missing = [k for k in range(min(max(found), len(found) + 5)) if k not in found]
        raise FormatError(f"{d}: mask files must be numbered from view_000 without gaps; view(s) "
                          f"{', '.join(map(str, missing[:5]))}{', ...' if len(missing) > 5 else ''} missing "
                          f"below {found[max(found)].name}")
    return [found[k] for k in range(len(found))]


def _read_one(f: Path, shape=None, k: int = 0) -> np.ndarray:
    """Mask file ``f`` of view ``k``; ``shape`` (H, W), when known, is checked before a PNG is decoded."""
    if f.suffix.lower() == ".npy":
        arr = load_npy(f)
        if arr.dtype.kind not in "buif":
            raise FormatError(f"{f}: mask dtype {arr.dtype} is not supported; use bool, uint8 or float")
        return arr
    return read_image(f, lambda im: _png_grey(im, f, shape, k), "PNG")


def _png_grey(im, f: Path, shape, k: int) -> np.ndarray:
    """(H, W) uint8 grey values of the opened PNG ``im``, after the format and shape checks."""
    if im.format != "PNG":
        raise FormatError(f"{f}: a {im.format} image under a .png name; masks are lossless PNG "
                          "(a lossy format blurs 0/255 into other values)")
    if shape is not None and im.size != (shape[1], shape[0]):
        raise _wrong_shape(f, (im.size[1], im.size[0]), shape, k)
    grey = np.asarray(im.convert("L"))
    if im.mode in ("RGBA", "LA", "PA") or "transparency" in im.info:
        # A cut-out keeps its mask in the alpha channel, which converting to grey drops: refused
        # unless the grey values mark the same pixels as the alpha (a mask saved with a
        # transparent background)
        alpha = np.asarray(im.convert("RGBA").getchannel("A"))
        if alpha.min() < 255 and np.any((grey > 0) != (alpha > 0)):
            raise FormatError(f"{f}: the PNG's transparency marks other pixels than its grey values "
                              f"(mode {im.mode}: a cut-out?); save the mask itself as 8-bit greyscale "
                              "(0 = background, 255 = object)")
    return grey


def _wrong_shape(f: Path, got, shape, k: int) -> ValidationError:
    return ValidationError(f"{f}: mask has shape {tuple(got)} but view {k} is {tuple(shape)} (H, W); masks must "
                           "be at the operator's resolution")


def _count(value, name: str) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValidationError(f"read_masks: {name} must be a positive whole number or None, got {value!r}")
    return int(value)


def read_masks(directory, n_views: int | None = None, image_shapes=None) -> list[np.ndarray]:
    """Masks ``view_000.png|npy ...`` of a directory, in view order.

    Parameters
    ----------
    directory : path
        Directory with one file ``view_<k>.png`` or ``view_<k>.npy`` per
        view, ``k`` running ``0..V-1`` without gaps (any zero
        padding). Other files are ignored.
    n_views : int or None
        When given, ``V`` must equal it (one mask per operator view).
    image_shapes : sequence of (H, W) or None
        When given, mask ``k`` must have shape ``image_shapes[k]`` or its
        flat ``(H*W,)`` (e.g. ``OperatorStack.image_shapes``).

    Returns
    -------
    list of ndarray
        One array per view: uint8 (H, W) from PNG, as stored from .npy
        ((H, W) or the flat (H*W,) pixels, as the solvers accept). Values
        are normalised (and their range checked) by the solvers.

    Raises
    ------
    FormatError
        Not a directory, no masks, gaps in the numbering, two files for one
        view (e.g. ``view_000.png`` and ``view_000.npy``), an unreadable file, a mask that is neither
        (H, W) nor flat, or of an unsupported dtype, a ``.png`` that is not a
        PNG, or a PNG that is transparent anywhere (a cut-out, whose mask
        would be its alpha), or a PNG that declares more pixels than
        :data:`~seed2gs_inverse.io.images.MAX_IMAGE_PIXELS` or a side above
        :data:`~seed2gs_inverse.camera.MAX_IMAGE_SIDE` (checked from its
        header, before any pixel is decoded). The message names the file.
    ValidationError
        Bad ``n_views`` / ``image_shapes``, wrong number of masks, or a mask
        whose shape differs from its view's image (naming the file and the
        expected shape; a PNG is checked before it is decoded).
    """
    d = Path(directory)
    n_views = _count(n_views, "n_views")
    if image_shapes is not None:
        try:
            image_shapes = [tuple(int(s) for s in shape) for shape in image_shapes]
        except (TypeError, ValueError):
            image_shapes = None
        if image_shapes is None or any(len(s) != 2 or min(s) < 1 for s in image_shapes):
            raise ValidationError("read_masks: image_shapes must be a sequence of (H, W) pairs of positive "
                                  "whole numbers (e.g. OperatorStack.image_shapes)")
    files = _mask_files(d, n_views)
    if n_views is not None and len(files) != n_views:
        raise ValidationError(f"{d}: {len(files)} masks for {n_views} operator views; give one mask per view")
    if image_shapes is not None:
        if len(image_shapes) != len(files):
            raise ValidationError(f"{d}: {len(files)} masks for {len(image_shapes)} image shapes; "
                                  "give one mask per view")
    masks = []
    for k, f in enumerate(files):
        shape = None if image_shapes is None else image_shapes[k]
        arr = _read_one(f, shape, k)
        if arr.ndim not in (1, 2) or arr.size == 0:
            raise FormatError(f"{f}: a mask must be an (H, W) image (or its flat (H*W,) pixels), "
                              f"got shape {arr.shape}")
        if shape is not None and arr.shape not in (shape, (shape[0] * shape[1],)):
            raise _wrong_shape(f, arr.shape, shape, k)
        masks.append(arr)
    return masks
