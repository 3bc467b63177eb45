"""Bounded reading of the image files a user hands the toolkit.

Every image decoded from a user's file (per-view mask folders, the seed
mask of a mask prompt, ``seed2gs models --image``, benchmark ground truth)
goes through :func:`read_image`. Pillow opens a file lazily: its header
gives the size before any pixel is decoded, so a small file that declares
an enormous image (a decompression bomb) is refused before it costs memory.
"""

from __future__ import annotations

import os
import warnings
from typing import Callable, TypeVar

from PIL import Image, UnidentifiedImageError

from ..camera import MAX_IMAGE_SIDE
from ..errors import FormatError, Seed2GSError
from ._common import check_regular

__all__ = ["read_image", "image_shape", "MAX_IMAGE_PIXELS", "MAX_IMAGE_SIDE"]

#: Largest pixel count of an image file (2**27, e.g. 16384 x 8192). Each side
#: must also be at most :data:`~seed2gs_inverse.camera.MAX_IMAGE_SIDE`, the
#: camera limit. An 8-bit RGBA image of this size decodes to 512 MiB; it lies
#: below Pillow's own decompression-bomb error threshold, so this limit is
#: the one a user meets, with its message.
MAX_IMAGE_PIXELS = 1 << 27

T = TypeVar("T")


def _bounds_problem(width: int, height: int) -> str | None:
    """Why an image of ``width`` x ``height`` pixels is refused (None when it is within the limits)."""
    if width < 1 or height < 1:
        return f"declares an empty {width}x{height} image"
    if max(width, height) > MAX_IMAGE_SIDE or width * height > MAX_IMAGE_PIXELS:
        return (f"declares a {width}x{height} image, beyond the limit of {MAX_IMAGE_SIDE} pixels a side and "
                f"{MAX_IMAGE_PIXELS} pixels in all (a corrupt file or a decompression bomb)")
    return None


def read_image(path, decode: Callable[[Image.Image], T], what: str = "image") -> T:
    """``decode(im)`` of the image file ``path``, opened by Pillow after its declared size was checked.

    Parameters
    ----------
    path : str or os.PathLike
        The image file.
    decode : callable
        Receives the opened, not yet decoded ``PIL.Image.Image`` (its
        ``size``, ``mode``, ``format`` and ``info`` come from the header)
        and returns what the caller needs; the pixels are decoded only when
        it asks for them, so it may check the size against an expected
        shape first.
    what : str
        What the file is, for the messages (``"mask file"``).

    Returns
    -------
    object
        What ``decode`` returns.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    FormatError
        ``path`` is not a regular file, not an image Pillow reads, is
        truncated, or declares a side above
        :data:`~seed2gs_inverse.camera.MAX_IMAGE_SIDE` or more than
        :data:`MAX_IMAGE_PIXELS` pixels (checked before any pixel is
        decoded). Every message starts with the file name.
    ValidationError, FormatError
        Whatever ``decode`` raises of the toolkit's errors passes through.
    """
    p = os.fspath(path)
    if not os.path.exists(p):
        raise FileNotFoundError(2, "No such file", p)
    check_regular(p, what)
    try:
        with warnings.catch_warnings():
            # Pillow warns from its own, lower threshold while opening; the limits below decide instead
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(p)
    except Image.DecompressionBombError:
        raise FormatError(f"{p}: the {what} declares more than {MAX_IMAGE_PIXELS} pixels, the limit (at most "
                          f"{MAX_IMAGE_SIDE} a side); a corrupt file or a decompression bomb") from None
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as exc:
        raise FormatError(f"{p}: not a readable {what} ({_first_line(exc)})") from None
    with im:
        why = _bounds_problem(*im.size)
        if why:
            raise FormatError(f"{p}: the {what} {why}")
        try:
            return decode(im)
        except Seed2GSError:
            raise
        except (OSError, ValueError, SyntaxError, EOFError) as exc:
            raise FormatError(f"{p}: not a readable {what} ({_first_line(exc)})") from None


def image_shape(path, what: str = "image") -> tuple[int, int]:
    """``(H, W)`` of the image file ``path`` from its header, within the limits of :func:`read_image`.

    Raises
    ------
    FileNotFoundError, FormatError
        As :func:`read_image`; no pixel is decoded.
    """
    return read_image(path, lambda im: (im.height, im.width), what)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
