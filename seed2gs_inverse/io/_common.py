"""Helpers shared by the scene readers and writers.

Everything here is private: the public entry points are in ``formats.py``
and ``cameras.py``.
"""

from __future__ import annotations

import os
import sys
import warnings
import zlib

import numpy as np
import zstandard

from .._atomic import atomic_path
from ..errors import FormatError, ValidationError
from ..scene import GaussianScene

__all__: list[str] = []

_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep  # .../seed2gs_inverse/


def warn_caller(message: str) -> None:
    """``warnings.warn(message)`` attributed to the first caller outside this package.

    The readers are reached through different call depths (``read_scene``,
    the element readers, the CLI), so a fixed ``stacklevel`` points at a
    line of the package half of the time.
    """
    level, frame = 1, sys._getframe(0)
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, UserWarning, stacklevel=level)


# Opacity logit used for a stored opacity of exactly 0 or 1 (8-bit formats
# store sigmoid(logit) and cannot represent the infinities). Same value as the
# PlayCanvas engine's decoder, so scenes decoded here match it.
OPACITY_LOGIT_LIMIT = 40.0


def npy_header(path, where: str) -> tuple:
    """``(shape, dtype)`` from a ``.npy`` header, checked against the file size before any allocation.

    Errors are FormatErrors starting with ``where``: an unreadable or
    unsupported header, a dtype holding Python objects, or a header that
    promises more data than the file holds (a 128-byte file must not ask
    for 745 GiB).
    """
    fmt = np.lib.format
    try:
        with open(path, "rb") as fh:
            version = fmt.read_magic(fh)
            read = {(1, 0): fmt.read_array_header_1_0, (2, 0): fmt.read_array_header_2_0}.get(version)
            if read is None:
                raise ValueError(f"unsupported .npy version {version}")
            shape, _, dtype = read(fh, max_header_size=10_000)
            offset = fh.tell()
    except (ValueError, OSError, EOFError, SyntaxError) as exc:
        raise FormatError(f"{where}: not a readable .npy array ({exc})") from None
    if dtype.hasobject:
        raise FormatError(f"{where}: holds Python objects, which are never loaded; save a numeric or boolean array")
    need = int(np.prod(shape, dtype=object)) * dtype.itemsize
    have = os.stat(path).st_size - offset
    if need > have:
        raise FormatError(f"{where}: the header promises {need} bytes of data but the file holds {have}; the file "
                          "is truncated or corrupt")
    return shape, dtype


def load_npy(path, label: str | None = None) -> np.ndarray:
    """A numeric array from a ``.npy`` file; never unpickles (numpy's own message would suggest it).

    Errors are FormatErrors that start with ``label`` (default: the path):
    a file that is not ``.npy`` at all (no magic bytes: numpy would call a
    text file "pickled data"), an unreadable one, one holding objects, or
    one whose header promises more data than it holds (:func:`npy_header`).
    """
    where = os.fspath(path) if label is None else label
    try:
        with open(path, "rb") as fh:
            magic = fh.read(6)
    except OSError as exc:
        raise FormatError(f"{where}: cannot read it ({exc.strerror or exc})") from None
    if magic != b"\x93NUMPY":
        raise FormatError(f"{where}: not a .npy file (write the array with numpy.save)")
    npy_header(path, where)
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise FormatError(f"{where}: not a readable .npy array ({exc})") from None
    return arr


def fail(path, message: str) -> FormatError:
    """A FormatError whose message starts with the file name."""
    return FormatError(f"{os.fspath(path)}: {message}")


def check_regular(path, what: str) -> None:
    """FormatError unless ``path`` is a regular file or missing (a missing file is left to ``open``):
    a directory fails to read, and a FIFO or device would block the read for ever."""
    if os.path.exists(path) and not os.path.isfile(path):
        raise fail(path, f"not a regular file (a directory, pipe or device); give the {what} itself")


def file_size(path) -> int:
    return os.stat(path).st_size


def logit_from_unorm(p: np.ndarray) -> np.ndarray:
    """Opacity logits from stored opacities in [0, 1] (float64 in, float32 out).

    ``log(p / (1 - p))``; ``p <= 0`` maps to ``-40`` and ``p >= 1`` to ``+40``
    (a stored 0 or 255 byte would otherwise give an infinite logit).
    """
    p = np.asarray(p, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.log(p / (1.0 - p))
    out = np.where(p <= 0, -OPACITY_LOGIT_LIMIT, out)
    out = np.where(p >= 1, OPACITY_LOGIT_LIMIT, out)
    return out.astype(np.float32)


# Largest decompressed/compressed size ratio accepted for a scene file. Real
# SPZ files compress their quantised arrays by a small factor (about 1.4);
# a degree-3 file whose SH bands are all zero stays below 5x. Zero-filled
# streams reach 1000x (gzip) to 30000x (zstd): a 6 KB file could claim 10
# million Gaussians. Together with the slack this bounds what a reader
# allocates by what the file can justify.
MAX_COMPRESSION_RATIO = 16
COMPRESSION_SLACK = 1 << 20  # tiny files (a handful of Gaussians) compress badly


def check_compression_ratio(path, claimed: int, file_bytes: int, what: str) -> None:
    """Refuse a header whose decompressed size no real file of this size could hold.

    ``claimed`` bytes must not exceed ``MAX_COMPRESSION_RATIO * file_bytes +
    COMPRESSION_SLACK``. Called before anything is decompressed or allocated.
    """
    limit = MAX_COMPRESSION_RATIO * file_bytes + COMPRESSION_SLACK
    if claimed > limit:
        raise fail(path, f"the header claims {what} ({claimed} bytes once decompressed), "
                         f"{claimed / max(file_bytes, 1):.0f} times the file's {file_bytes} bytes; "
                         f"real files compress less than {MAX_COMPRESSION_RATIO}x, so the header "
                         f"is corrupt or the file is a decompression bomb")


def bounded_gzip(path, data: bytes, header_bytes: int) -> bytes:
    """The first ``header_bytes`` decompressed bytes of a gzip stream (FormatError if fewer)."""
    out = np.empty(header_bytes, np.uint8)
    got = gzip_into(path, data, out, stop_when_full=True)
    if got < header_bytes:
        raise fail(path, f"file is truncated: the decompressed header has {got} "
                         f"of {header_bytes} bytes")
    return out.tobytes()


def gzip_into(path, data, out: np.ndarray, stop_when_full: bool = False) -> int:
    """Inflate a gzip stream into the uint8 buffer ``out``; the number of bytes written.

    Never produces more than ``out.size`` bytes, whatever the stream claims:
    more data than fits is a FormatError (unless ``stop_when_full``, for
    reading just a header), as are corrupt or truncated streams.
    """
    d = zlib.decompressobj(16 + zlib.MAX_WBITS)
    cap = out.size
    src = memoryview(data)
    pos = got = 0
    step = 1 << 20
    try:
        while True:
            if d.unconsumed_tail:
                chunk = d.unconsumed_tail
            elif pos < len(src):
                chunk = src[pos:pos + step]
                pos += len(chunk)
            else:
                break
            # ask for one byte more than fits, to tell "exactly full" from "too much"
            piece = d.decompress(chunk, cap + 1 - got)
            if got + len(piece) > cap:
                if stop_when_full:
                    out[got:] = np.frombuffer(piece, np.uint8, cap - got)
                    return cap
                raise fail(path, f"the gzip stream holds more than the {cap} bytes "
                                 f"the header allows")
            out[got:got + len(piece)] = np.frombuffer(piece, np.uint8)
            got += len(piece)
            if d.eof or (stop_when_full and got == cap):
                break
    except zlib.error as exc:
        raise fail(path, f"corrupt gzip stream ({exc})") from None
    if not d.eof and not stop_when_full:
        raise fail(path, f"file is truncated: the gzip stream ends early "
                         f"after {got} decompressed bytes")
    if not stop_when_full:
        warn_trailing(path, len(d.unused_data) + len(src) - pos, "the gzip stream")
    return got


def warn_trailing(path, nbytes: int, what: str) -> None:
    """Warn that ``nbytes`` bytes after ``what`` are ignored (padding, or a sign of a damaged file)."""
    if nbytes > 0:
        warn_caller(f"{os.fspath(path)}: ignoring {nbytes} bytes after {what}")


def zstd_into(path, data, out: np.ndarray, what: str) -> None:
    """Decompress one zstd frame that must fill the uint8 buffer ``out`` exactly.

    Output goes straight into ``out`` and one byte more is asked for only to
    detect a frame that is too long, so a corrupt size field cannot make us
    allocate more than the header promised.
    """
    expected = out.size
    view = memoryview(out)
    got = 0
    try:
        reader = zstandard.ZstdDecompressor().stream_reader(data)
        while got < expected:
            k = reader.readinto(view[got:got + min(expected - got, 1 << 22)])
            if not k:
                break
            got += k
        more = bool(reader.read(1)) if got == expected else False
    except zstandard.ZstdError as exc:
        raise fail(path, f"corrupt zstd stream for {what} ({exc})") from None
    if got != expected or more:
        amount = "more" if more else f"only {got}"
        raise fail(path, f"the {what} stream decompresses to {amount} bytes; "
                         f"the header promises {expected}")


_ARRAYS = ("means", "quats", "log_scales", "opacity_logits", "sh")


def _column_labels(key: str, arr: np.ndarray, fields) -> list:
    """One label per column of ``arr`` (trailing dimensions flattened)."""
    width = int(np.prod(arr.shape[1:], dtype=np.int64))
    given = (fields or {}).get(key)
    if given is not None and len(given) == width:
        return list(given)
    if width == 1:
        return [key]
    return [f"{key}[{j}]" for j in range(width)]


def saturate_opacity(path, opacity_logits: np.ndarray, field: str = "opacity") -> np.ndarray:
    """Opacity logits with +-inf replaced by +-``OPACITY_LOGIT_LIMIT`` (a warning says how many).

    Some exporters (splat-transform among them) write an opacity of exactly
    1 or 0 as an infinite logit. ``sigmoid(+-40)`` is 1 and 4e-18 in float32,
    so the finite logit keeps the rendered opacity and every Gaussian is kept;
    NaN stays NaN and is refused by :func:`finish_scene`.
    """
    inf = np.isinf(opacity_logits)
    if not inf.any():
        return opacity_logits
    n_pos = int(np.count_nonzero(inf & (opacity_logits > 0)))
    n_neg = int(np.count_nonzero(inf)) - n_pos
    out = np.where(inf, np.copysign(OPACITY_LOGIT_LIMIT, opacity_logits), opacity_logits)
    warn_caller(f"{os.fspath(path)}: {n_pos} '{field}' logits are +inf and {n_neg} are -inf; "
                f"read as +-{OPACITY_LOGIT_LIMIT:g} (saturated opacity 1 or 0)")
    return out.astype(opacity_logits.dtype, copy=False)


def finish_scene(path, means, quats, log_scales, opacity_logits, sh, extra=None,
                 drop_nonfinite: bool = False, fields=None, layout=None) -> GaussianScene:
    """Validate decoded arrays and build the scene.

    Infinite opacity logits are read as saturated (:func:`saturate_opacity`).
    Any other NaN or infinite value, or a quaternion of zero length (its
    rotation is undefined), makes the Gaussian *invalid*. By default an invalid
    Gaussian is an error naming the file, the offending fields (``fields``
    maps an array name -- ``"means"``, ``"quats"``, ``"log_scales"``,
    ``"opacity_logits"``, ``"sh"`` or an extra's name -- to the file's names
    of its columns) and the first index; with ``drop_nonfinite=True`` they
    are removed and a warning says how many and why. ``layout`` is the
    file's property list, kept on the scene (see ``GaussianScene.layout``).
    """
    extra = dict(extra or {})
    n = means.shape[0]
    opacity_logits = saturate_opacity(path, opacity_logits,
                                      _column_labels("opacity_logits", opacity_logits, fields)[0])
    named = dict(zip(_ARRAYS, (means, quats, log_scales, opacity_logits, sh)))
    named.update((k, v) for k, v in extra.items() if v.dtype.kind == "f")
    bad = np.zeros(n, dtype=bool)
    problems = []  # (label, count, first index)
    for key, arr in named.items():
        finite = np.isfinite(arr)
        if finite.all():  # the per-column pass is only paid for files with bad values
            continue
        cols = finite.reshape(n, -1)
        for label, col in zip(_column_labels(key, arr, fields), cols.T):
            if not col.all():
                problems.append((f"non-finite '{label}'", int(n - col.sum()), int(np.argmin(col))))
        bad |= ~cols.all(axis=1)
    # quats @ ones would lose tiny components to underflow; compare with zero instead
    zero_rot = ~(quats != 0).any(axis=1)
    if zero_rot.any():
        label = "/".join(_column_labels("quats", quats, fields))
        problems.append((f"zero-length rotation '{label}'", int(zero_rot.sum()),
                         int(np.argmax(zero_rot))))
        bad |= zero_rot
    nbad = int(bad.sum())
    if nbad:
        what = "; ".join(f"{label} in {count} (first at index {first})"
                         for label, count, first in problems[:6])
        if len(problems) > 6:
            what += f"; and {len(problems) - 6} more fields"
        if not drop_nonfinite:
            raise fail(path, f"{nbad} of {n} Gaussians are invalid: {what}. Fix the file, or "
                             f"read with drop_nonfinite=True to drop those Gaussians (on the command "
                             f"line: seed2gs convert --drop-nonfinite IN OUT writes a cleaned copy; the "
                             f"Gaussians after a dropped one move up, so q and labels of the cleaned "
                             f"copy index it, not this file)")
        warn_caller(f"{os.fspath(path)}: dropped {nbad} of {n} invalid Gaussians: {what}")
        keep = ~bad
        means, quats, log_scales = means[keep], quats[keep], log_scales[keep]
        opacity_logits, sh = opacity_logits[keep], sh[keep]
        extra = {k: v[keep] for k, v in extra.items()}
    try:
        return GaussianScene(means, quats, log_scales, opacity_logits, sh, extra, layout)
    except ValidationError as exc:  # pragma: no cover - the checks above should catch everything
        raise fail(path, str(exc)) from None


def atomic_write(path, chunks) -> None:
    """Write an iterable of bytes-like pieces to ``path`` atomically.

    The data goes to a temporary file in the same directory which replaces
    ``path`` only once it is complete, so a failure never leaves a partial
    file behind.
    """
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        for piece in chunks:
            fh.write(piece)