"""Scene files: format detection and the public ``read_scene``/``write_scene``.

==================  ===================  ====  =====  =====
format              extension            read  write  lossy
==================  ===================  ====  =====  =====
``ply``             ``.ply``             yes   yes    no
``compressed_ply``  ``.compressed.ply``  yes   no     yes
``splat``           ``.splat``           yes   yes    yes
``spz``             ``.spz``             yes   no     yes
==================  ===================  ====  =====  =====

The extension chooses the family and the file's magic bytes or header
confirm it (a PLY header with a ``chunk`` element and ``packed_*`` vertex
properties is a compressed PLY, whatever its name). Every problem with a
file raises :class:`~seed2gs_inverse.errors.FormatError` (a ``ValueError``)
whose message starts with the file name.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

from ..errors import FormatError, ValidationError
from ..scene import GaussianScene
from ._common import check_regular, fail
from .compressed_ply import is_compressed_ply, read_compressed_ply
from .ply import read_ply_header, read_standard_ply, write_standard_ply
from .splat import check_splat, read_splat, write_splat
from .spz import check_spz, read_spz

__all__ = ["detect_format", "read_scene", "write_scene", "output_format", "READ_FORMATS",
           "WRITE_FORMATS"]

READ_FORMATS = ("ply", "compressed_ply", "splat", "spz")
WRITE_FORMATS = ("ply", "splat")
_EXTENSIONS = ".ply, .compressed.ply, .splat, .spz"


def _family(path) -> str:
    """The format family by extension, for a regular file (:func:`~._common.check_regular`)."""
    check_regular(path, "scene file")
    name = Path(path).name.lower()
    for ext, fam in ((".ply", "ply"), (".splat", "splat"), (".spz", "spz")):
        if name.endswith(ext):
            return fam
    suffix = Path(path).suffix or "(none)"
    raise fail(path, f"unknown scene format: extension {suffix} (supported: {_EXTENSIONS})")


def detect_format(path) -> str:
    """The format of a scene file: one of ``READ_FORMATS``.

    Chosen by extension and confirmed by content: a ``.ply`` file must start
    with the PLY magic and its header decides between ``ply`` and
    ``compressed_ply``; an ``.spz`` file must start with the gzip or ``NGSP``
    magic; a ``.splat`` file (no magic) must have a size that is a non-zero
    multiple of 32 bytes and no other format's magic. Raises FormatError for
    unknown extensions or content that does not match, OSError when the file
    cannot be opened.
    """
    fam = _family(path)
    if fam == "ply":
        return "compressed_ply" if is_compressed_ply(read_ply_header(path)) else "ply"
    if fam == "splat":
        check_splat(path)
    else:
        check_spz(path)
    return fam


def read_scene(path, drop_nonfinite: bool = False) -> GaussianScene:
    """Read a Gaussian splat scene from any supported file.

    Parameters
    ----------
    path : str or Path
        A ``.ply`` (standard 3DGS, any SH degree 0-3, ASCII or binary of
        either endianness), ``.compressed.ply`` (PlayCanvas), ``.splat``
        (antimatter15) or ``.spz`` (Niantic, versions 2-4) file.
    drop_nonfinite : bool
        Gaussians with NaN/infinite values or a zero-length quaternion are an
        error by default (naming the fields and the first index); with True
        they are dropped and a warning says how many and why. Infinite
        opacity logits are not invalid: ``+-inf`` (some exporters' opacity 1
        or 0) is read as ``+-40``, with a warning.

    Returns
    -------
    GaussianScene
        Raw parameters as stored (float32): means, w-first quaternions,
        log-scales, opacity logits, SH (N, K, 3); unknown PLY vertex
        properties in ``extra``. Coordinates are never re-oriented.

    Raises
    ------
    FormatError
        Unknown format, bad magic/header, truncated data, a header promising
        more data than the file holds (checked before allocating; for the
        compressed ``.spz`` streams, more than ``MAX_COMPRESSION_RATIO`` = 16
        times the file size once decompressed), missing properties,
        non-finite values. The message names the file.
    OSError
        The file cannot be opened.

    Notes
    -----
    Memory is bounded by what the file justifies: headers are checked
    against the file size before anything is allocated or decompressed,
    compressed streams are inflated into one buffer of exactly the promised
    size, and decoding runs in blocks, so the peak is about the decoded scene
    plus the file (``benchmarks/bench_io.py`` prints it for the real scenes;
    the fuzz tests hold every input under 3x its size + 64 MB). The arrays
    of the returned scene are read-only.
    """
    fam = _family(path)
    try:
        if fam == "ply":
            header = read_ply_header(path)
            if is_compressed_ply(header):
                return read_compressed_ply(path, header, drop_nonfinite)
            return read_standard_ply(path, header, drop_nonfinite)
        if fam == "splat":
            return read_splat(path, drop_nonfinite)
        return read_spz(path, drop_nonfinite)
    except (FormatError, OSError):
        raise
    except (ValueError, TypeError, IndexError, OverflowError, struct.error) as exc:
        # Last line of defence: a decoder bug or an unforeseen corruption must
        # still surface as the documented error type, naming the file.
        raise fail(path, f"cannot decode the file ({type(exc).__name__}: {exc})") from exc


def write_scene(path, scene: GaussianScene) -> None:
    """Write a scene; the format follows the extension (``.ply`` or ``.splat``).

    ``.ply`` is lossless and binary little-endian: a scene read from a
    standard PLY keeps that file's properties, order and types while they
    still fit it (:attr:`GaussianScene.layout`), any other scene gets the
    trainer's layout (float32, extras appended); ``.splat`` keeps only SH degree 0, 8-bit colours,
    opacities and rotations and warns about what it drops. The file is
    written to a temporary name in the same directory and renamed at the end,
    so a failure leaves no partial file.
    """
    if not isinstance(scene, GaussianScene):
        raise ValidationError(f"write_scene needs a GaussianScene, got {type(scene).__name__}")
    if output_format(path) == "ply":
        return write_standard_ply(path, scene)
    return write_splat(path, scene)


def output_format(path) -> str:
    """The format ``write_scene`` would write for ``path``: ``"ply"`` or ``"splat"``.

    Raises ValidationError for read-only formats and unknown extensions, so
    callers can check an output path before doing any work.
    """
    name = Path(path).name.lower()
    if name.endswith(".compressed.ply") or name.endswith(".spz"):
        kind = ".compressed.ply (PlayCanvas)" if name.endswith(".compressed.ply") else ".spz"
        raise ValidationError(f"{os.fspath(path)}: writing {kind} is not supported (it is read only); "
                              f"write .ply or .splat")
    if name.endswith(".ply"):
        return "ply"
    if name.endswith(".splat"):
        return "splat"
    raise ValidationError(f"{os.fspath(path)}: cannot choose an output format from the extension "
                          f"'{Path(path).suffix}' (use .ply or .splat)")
