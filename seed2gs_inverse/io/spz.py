"""Niantic ``.spz`` files (read only), versions 2, 3 and 4.

Versions 2 and 3 are one gzip stream holding a 16-byte header, optional
extension records, then the attribute arrays. Version 4 starts with a plain
32-byte header, optional extension records up to ``tocByteOffset``, a table
of ``numStreams`` entries ``(uint64 compressed, uint64 uncompressed)`` and one
zstd frame per non-empty attribute array, in the same order.

Header (little-endian): ``uint32 magic = 0x5053474e ("NGSP")``, ``uint32
version``, ``uint32 numPoints``, ``uint8 shDegree`` (0-4), ``uint8
fractionalBits``, ``uint8 flags`` (0x1 antialiased, 0x2 extensions),
``uint8`` reserved (v2/v3) or ``numStreams`` (v4); v4 adds ``uint32
tocByteOffset`` and 12 reserved bytes.

Attribute arrays, for N points and D = 0, 3, 8, 15, 24 SH coefficients for
degrees 0-4:

==========  ==========  ========================================================
array       bytes       decoding
==========  ==========  ========================================================
positions   9 N         three 24-bit signed little-endian fixed-point values,
                        ``value / 2**fractionalBits``
alphas      N           ``logit(byte / 255)`` (0 and 255 map to -40 and +40)
colors      3 N         SH DC ``(byte / 255 - 0.5) / 0.15``
scales      3 N         log scale ``byte / 16 - 10``
rotations   3 N (v2)    x, y, z as ``byte / 127.5 - 1``; ``w = sqrt(1 - |xyz|^2)``
            4 N (v3+)   "smallest three": a little-endian uint32 whose top 2 bits
                        give the index (in x, y, z, w order) of the largest
                        component; the others, from last to first, take 10 bits
                        each: 9-bit magnitude ``m / 511 / sqrt(2)`` and a sign bit
sh          3 D N       per point, coefficient-major with the colour channel
                        fastest; ``(byte - 128) / 128``
==========  ==========  ========================================================

Coordinates are returned as stored (no axis conversion). Extension records
(vendor metadata) are skipped. SH degree 4, which this toolkit does not
represent, is truncated to degree 3 with a warning.
"""

from __future__ import annotations

import os
import struct
from typing import TYPE_CHECKING

import numpy as np

from ._common import (bounded_gzip, check_compression_ratio, fail, finish_scene, gzip_into,
                      logit_from_unorm, warn_caller, warn_trailing, zstd_into)

if TYPE_CHECKING:
    from ..scene import GaussianScene

__all__ = ["read_spz", "check_spz", "SPZ_MAGIC"]

SPZ_MAGIC = 0x5053474E
_SH_DIM = (0, 3, 8, 15, 24)
_COLOR_SCALE = 0.15
_FLAG_EXTENSIONS = 0x2
_MAX_EXTENSION_BYTES = 1 << 20  # room for vendor records; bounds the decompressed size


def _sizes(n: int, sh_degree: int, version: int) -> list:
    """Byte sizes of positions, alphas, colors, scales, rotations, sh."""
    rot = 3 if version == 2 else 4
    return [9 * n, n, 3 * n, 3 * n, rot * n, 3 * _SH_DIM[sh_degree] * n]


def _check_header(path, version, sh_degree):
    if version == 1:
        raise fail(path, "SPZ version 1 (float16 positions, never released) is not supported")
    if version not in (2, 3, 4):
        raise fail(path, f"unsupported SPZ version {version} (supported: 2, 3, 4)")
    if sh_degree > 4:
        raise fail(path, f"SPZ header has SH degree {sh_degree}; the format allows 0-4")


def check_spz(path) -> str:
    """``"gzip"`` (versions 2-3) or ``"v4"`` from the magic bytes; FormatError otherwise."""
    with open(path, "rb") as fh:
        head = fh.read(4)
    if head[:2] == b"\x1f\x8b":
        return "gzip"
    if len(head) == 4 and struct.unpack("<I", head)[0] == SPZ_MAGIC:
        return "v4"
    raise fail(path, "not an SPZ file (neither a gzip stream nor the 'NGSP' magic)")


def read_spz(path, drop_nonfinite: bool = False) -> GaussianScene:
    """Decode an ``.spz`` file (see the module docstring).

    Memory is bounded by what the file can justify: the header's sizes are
    checked against the file (:func:`check_compression_ratio`) before
    anything is decompressed, streams are inflated straight into one buffer
    of exactly that size, and decoding runs in blocks of Gaussians.
    """
    kind = check_spz(path)
    with open(path, "rb") as fh:
        data = fh.read()
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if kind == "gzip":
            return _read_gzip(path, data, drop_nonfinite)
        return _read_v4(path, data, len(data), drop_nonfinite)


def _read_gzip(path, data: bytes, drop_nonfinite: bool) -> GaussianScene:
    head = bounded_gzip(path, data, header_bytes=16)
    magic, version, n, sh_degree, frac, flags, _ = struct.unpack("<IIIBBBB", head)
    if magic != SPZ_MAGIC:
        raise fail(path, "gzip stream does not hold an SPZ header (missing 'NGSP' magic)")
    _check_header(path, version, sh_degree)
    if version == 4:
        raise fail(path, "SPZ version 4 is not gzip-compressed; the file is inconsistent")
    payload = sum(_sizes(n, sh_degree, version))
    check_compression_ratio(path, 16 + payload, len(data), f"{n} Gaussians of SH degree {sh_degree}")
    # Extension records sit between the header and the arrays; their total
    # length is whatever the stream holds beyond the arrays.
    raw = np.empty(16 + payload + _MAX_EXTENSION_BYTES, np.uint8)
    got = gzip_into(path, data, raw)
    extra = got - 16 - payload
    if extra < 0:
        raise fail(path, f"file is truncated: the header promises {n} Gaussians "
                         f"({payload} bytes of arrays) but the stream holds {got - 16}")
    if extra and not flags & _FLAG_EXTENSIONS:
        raise fail(path, f"the stream holds {extra} bytes more than the {n} Gaussians of the "
                         f"header need (wrong point count?)")
    return _decode(path, raw[16 + extra:got], n, sh_degree, frac, version, drop_nonfinite)


_STREAMS = ["positions", "alphas", "colors", "scales", "rotations", "sh"]


def _read_v4(path, data: bytes, size: int, drop_nonfinite: bool) -> GaussianScene:
    if len(data) < 32:
        raise fail(path, f"file is truncated: {len(data)} bytes, less than the 32-byte SPZ header")
    magic, version, n, sh_degree, frac, flags, n_streams, toc = struct.unpack_from("<IIIBBBBI", data)
    _check_header(path, version, sh_degree)
    if version != 4:
        raise fail(path, f"SPZ version {version} files must be gzip-compressed; "
                         f"this one has a plain header")
    expected = [s for s in _sizes(n, sh_degree, version) if s > 0]
    if n_streams != len(expected):
        raise fail(path, f"SPZ header declares {n_streams} streams; {n} Gaussians of SH degree "
                         f"{sh_degree} need {len(expected)}")
    toc_end = toc + 16 * n_streams
    if toc < 32 or toc_end > size:
        raise fail(path, f"SPZ table of contents at byte {toc} lies outside the file ({size} bytes)")
    # Every entry is checked against the header and the file before anything
    # is decompressed or allocated: the first inconsistency stops the read.
    entries = [struct.unpack_from("<QQ", data, toc + 16 * i) for i in range(n_streams)]
    offset = toc_end
    for name, (comp, uncomp), want in zip(_STREAMS, entries, expected):
        if uncomp != want:
            raise fail(path, f"SPZ stream '{name}' is declared as {uncomp} bytes; "
                             f"{n} Gaussians need {want}")
        if offset + comp > size:
            raise fail(path, f"file is truncated: stream '{name}' needs {comp} bytes at "
                             f"offset {offset} but the file has {size}")
        offset += comp
    warn_trailing(path, size - offset, "the last stream")
    total = sum(expected)
    check_compression_ratio(path, total, size, f"{n} Gaussians of SH degree {sh_degree}")
    raw = np.empty(total, np.uint8)
    offset, pos = toc_end, 0
    for name, (comp, _), want in zip(_STREAMS, entries, expected):
        zstd_into(path, memoryview(data)[offset:offset + comp], raw[pos:pos + want], name)
        offset += comp
        pos += want
    return _decode(path, raw, n, sh_degree, frac, version, drop_nonfinite)


_BLOCK = 1 << 14  # Gaussians decoded at a time: bounds the float64 temporaries


def _decode(path, buf: np.ndarray, n: int, sh_degree: int, frac: int, version: int,
            drop_nonfinite: bool) -> GaussianScene:
    """Decode the attribute arrays held in the uint8 buffer ``buf`` (see the module docstring)."""
    if frac > 24:  # 24-bit fixed point: beyond 24 fractional bits every position would round to 0
        raise fail(path, f"fractionalBits is {frac}; positions are 24-bit fixed point, so at most 24 make sense "
                         "(writers use about 12): the header is corrupt")
    sizes = _sizes(n, sh_degree, version)
    starts = np.concatenate([[0], np.cumsum(sizes)])
    pos_b, alpha_b, color_b, scale_b, rot_b, sh_b = (buf[int(o):int(o) + s]
                                                     for s, o in zip(sizes, starts[:-1]))
    pos_b = pos_b.reshape(n, 3, 3)
    color_b, scale_b = color_b.reshape(n, 3), scale_b.reshape(n, 3)
    rot_b = rot_b.reshape(n, 3 if version == 2 else 4)
    dim = _SH_DIM[sh_degree]
    keep = min(dim, 15)
    if dim > 15:
        warn_caller(f"{os.fspath(path)}: SH degree 4 is not supported; "
                    f"the degree-4 band is dropped")
    sh_b = sh_b.reshape(n, dim, 3)

    means = np.empty((n, 3), np.float32)
    quats = np.empty((n, 4), np.float32)
    log_scales = np.empty((n, 3), np.float32)
    opacity = np.empty(n, np.float32)
    sh = np.empty((n, 1 + keep, 3), np.float32)
    for a in range(0, n, _BLOCK):
        b = min(n, a + _BLOCK)
        p = pos_b[a:b].astype(np.int32)
        fixed = p[..., 0] | (p[..., 1] << 8) | (p[..., 2] << 16)
        fixed = np.where(fixed & 0x800000, fixed - (1 << 24), fixed)  # sign-extend 24 bits
        means[a:b] = np.ldexp(fixed.astype(np.float64), -frac)
        log_scales[a:b] = scale_b[a:b].astype(np.float32) / 16.0 - 10.0
        opacity[a:b] = logit_from_unorm(alpha_b[a:b].astype(np.float64) / 255.0)
        quats[a:b] = _rotations(rot_b[a:b], version)[:, [3, 0, 1, 2]]
        sh[a:b, 0, :] = (color_b[a:b].astype(np.float64) / 255.0 - 0.5) / _COLOR_SCALE
        if keep:
            sh[a:b, 1:, :] = (sh_b[a:b, :keep, :].astype(np.float32) - 128.0) / 128.0
    return finish_scene(path, means, quats, log_scales, opacity, sh, None, drop_nonfinite)


def _rotations(rot_b: np.ndarray, version: int) -> np.ndarray:
    """x, y, z, w quaternions (m, 4) float64 from the stored rotation bytes."""
    m = rot_b.shape[0]
    if version == 2:
        xyz = rot_b.astype(np.float64) / 127.5 - 1.0
        w = np.sqrt(np.maximum(0.0, 1.0 - (xyz ** 2).sum(axis=1)))
        return np.concatenate([xyz, w[:, None]], axis=1)
    comp = np.ascontiguousarray(rot_b).view("<u4")[:, 0].astype(np.int64)
    largest = comp >> 30
    xyzw = np.empty((m, 4))
    mask = (1 << 9) - 1
    filled = np.zeros(m)
    # Components are packed from the last to the first, skipping the largest.
    for i in range(3, -1, -1):
        here = largest != i
        mag = (comp & mask) / mask * np.sqrt(0.5)
        val = np.where((comp >> 9) & 1, -mag, mag)
        xyzw[:, i] = np.where(here, val, 0.0)
        filled += np.where(here, val * val, 0.0)
        comp = np.where(here, comp >> 10, comp)
    xyzw[np.arange(m), largest] = np.sqrt(np.maximum(0.0, 1.0 - filled))
    return xyzw
