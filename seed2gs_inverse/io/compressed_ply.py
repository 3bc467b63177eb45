"""PlayCanvas / SuperSplat ``.compressed.ply`` files (read only).

The file is a binary PLY with three elements:

``chunk`` (one per 256 Gaussians, float32)
    ``min_x min_y min_z max_x max_y max_z`` position range,
    ``min_scale_x .. max_scale_z`` log-scale range and, optionally,
    ``min_r min_g min_b max_r max_g max_b`` colour range.
``vertex`` (one per Gaussian, uint32)
    ``packed_position``, ``packed_scale``: 11-10-11 bit unsigned fractions
    ``t`` (x in the top 11 bits), decoded as ``lo + t (hi - lo)`` with the
    chunk's range; ``packed_rotation``: 2 bits for the index of the largest
    quaternion component (w-first order) and three 10-bit values
    ``a = (u / 1023 - 0.5) sqrt(2)`` for the others in order, the largest
    being ``sqrt(1 - a^2 - b^2 - c^2)``; ``packed_color``: 8-8-8-8 bits
    r g b opacity as fractions of 255 (r, g, b mapped through the chunk's
    colour range when present).
``sh`` (optional, one per Gaussian, uint8)
    ``f_rest_0..M-1`` (M = 9, 24 or 45) in the standard channel-major order,
    decoded as ``byte * 8 / 255 - 4``.

Colours become SH DC coefficients ``(colour - 0.5) / SH_C0``; opacities
become logits, with 0 and 1 mapped to -40 and +40. These decoding rules are
those of the PlayCanvas engine (``gsplat-compressed-data.js``).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from ..sh import SH_C0
from ._common import fail, finish_scene, logit_from_unorm, warn_caller
from .ply import columns, read_ply_elements

if TYPE_CHECKING:
    from ..scene import GaussianScene
    from .ply import PlyHeader

__all__ = ["is_compressed_ply", "read_compressed_ply"]

CHUNK_SIZE = 256
_CHUNK_BASE = ["min_x", "min_y", "min_z", "max_x", "max_y", "max_z",
               "min_scale_x", "min_scale_y", "min_scale_z",
               "max_scale_x", "max_scale_y", "max_scale_z"]
_CHUNK_COLOR = ["min_r", "min_g", "min_b", "max_r", "max_g", "max_b"]
_PACKED = ["packed_position", "packed_rotation", "packed_scale", "packed_color"]


def is_compressed_ply(header: PlyHeader) -> bool:
    """Whether a PLY header has the compressed layout (a ``chunk`` element and packed vertices)."""
    vertex = header.element("vertex")
    return (header.element("chunk") is not None and vertex is not None
            and any(name in vertex.names for name in _PACKED))


def _unorm(bits: np.ndarray, shift: int, width: int) -> np.ndarray:
    return ((bits >> np.uint32(shift)) & np.uint32((1 << width) - 1)).astype(np.float64) / ((1 << width) - 1)


def _unpack_11_10_11(bits: np.ndarray) -> np.ndarray:
    return np.stack([_unorm(bits, 21, 11), _unorm(bits, 11, 10), _unorm(bits, 0, 11)], axis=1)


def _lerp(lo: np.ndarray, hi: np.ndarray, t: np.ndarray) -> np.ndarray:
    return lo * (1 - t) + hi * t


def read_compressed_ply(path, header: PlyHeader, drop_nonfinite: bool = False) -> GaussianScene:
    """Decode a PlayCanvas compressed PLY file (see the module docstring)."""
    if header.format != "binary_little_endian":
        raise fail(path, f"compressed PLY must be binary_little_endian, not {header.format}")
    chunk_el, vertex_el, sh_el = header.element("chunk"), header.element("vertex"), header.element("sh")
    missing = [p for p in _PACKED if p not in vertex_el.names]
    missing += [p for p in _CHUNK_BASE if p not in chunk_el.names]
    if missing:
        raise fail(path, f"compressed PLY lacks the properties {missing}")
    bad_types = [n for n, c in vertex_el.properties if n in _PACKED and c != "u4"]
    bad_types += [n for n, c in chunk_el.properties if c != "f4"]
    if bad_types:
        raise fail(path, f"compressed PLY properties {bad_types} have the wrong type "
                         f"(packed_* must be uint, chunk ranges float)")
    color_props = [p for p in _CHUNK_COLOR if p in chunk_el.names]
    has_color = len(color_props) == len(_CHUNK_COLOR)
    if color_props and not has_color:  # decoding without the ranges would shift every colour silently
        raise fail(path, f"compressed PLY chunk element has the colour ranges {color_props} but lacks "
                         f"{[p for p in _CHUNK_COLOR if p not in chunk_el.names]}; all six or none")
    n = vertex_el.count
    n_chunks = -(-n // CHUNK_SIZE)
    if chunk_el.count != n_chunks:
        raise fail(path, f"compressed PLY has {chunk_el.count} chunks for {n} Gaussians; "
                         f"expected {n_chunks} (one per {CHUNK_SIZE})")
    rest_names = []
    if sh_el is not None:
        m = len(sh_el.properties)
        rest_names = [f"f_rest_{i}" for i in range(m)]
        if m not in (9, 24, 45) or sh_el.names != rest_names \
                or any(c != "u1" for _, c in sh_el.properties):
            raise fail(path, f"compressed PLY 'sh' element must hold uchar f_rest_0..M-1 with "
                             f"M = 9, 24 or 45; found {sh_el.names[:4]}... ({m} properties)")
        if sh_el.count != n:
            raise fail(path, f"compressed PLY has {sh_el.count} SH rows for {n} Gaussians")
    extra = [p for p in vertex_el.names if p not in _PACKED]
    if extra:  # the format holds no per-Gaussian extras: they are not decoded
        warn_caller(f"{os.fspath(path)}: compressed PLY vertex properties {extra[:5]}"
                    f"{'...' if len(extra) > 5 else ''} are not part of the format and are ignored")
    wanted = ["chunk", "vertex"] + (["sh"] if sh_el is not None else [])
    data = read_ply_elements(path, header, wanted)
    # Corrupt chunk ranges may overflow float32; such Gaussians are reported
    # as non-finite by finish_scene, so the floating-point warnings are noise.
    with np.errstate(over="ignore", invalid="ignore"):
        return _decode(path, data, n, has_color, rest_names, drop_nonfinite)


_BLOCK = CHUNK_SIZE * 64  # Gaussians decoded at a time: bounds the float64 temporaries


def _decode(path, data, n, has_color, rest_names, drop_nonfinite) -> GaussianScene:
    names = _CHUNK_BASE + (_CHUNK_COLOR if has_color else [])
    chunks = columns(data["chunk"], names).astype(np.float64)
    packed = data["vertex"]
    k = 1 + len(rest_names) // 3
    means = np.empty((n, 3), np.float32)
    quats = np.empty((n, 4), np.float32)
    log_scales = np.empty((n, 3), np.float32)
    opacity = np.empty(n, np.float32)
    sh = np.empty((n, k, 3), np.float32)
    for a in range(0, n, _BLOCK):
        b = min(n, a + _BLOCK)
        # chunk values for each Gaussian of the block (a is a multiple of CHUNK_SIZE)
        per = np.repeat(chunks[a // CHUNK_SIZE:-(-b // CHUNK_SIZE)], CHUNK_SIZE, axis=0)[:b - a]
        block = packed[a:b]
        means[a:b] = _lerp(per[:, 0:3], per[:, 3:6], _unpack_11_10_11(block["packed_position"]))
        log_scales[a:b] = _lerp(per[:, 6:9], per[:, 9:12], _unpack_11_10_11(block["packed_scale"]))
        quats[a:b] = _rotations(block["packed_rotation"])
        col = block["packed_color"]
        rgb = np.stack([_unorm(col, s, 8) for s in (24, 16, 8)], axis=1)
        if has_color:
            rgb = _lerp(per[:, 12:15], per[:, 15:18], rgb)
        sh[a:b, 0, :] = (rgb - 0.5) / SH_C0
        opacity[a:b] = logit_from_unorm(_unorm(col, 0, 8))
        if rest_names:
            rest = columns(data["sh"][a:b], rest_names).astype(np.float64) * (8.0 / 255.0) - 4.0
            sh[a:b, 1:, :] = rest.reshape(b - a, 3, k - 1).transpose(0, 2, 1)
    return finish_scene(path, means, quats, log_scales, opacity, sh, None, drop_nonfinite)


def _rotations(rot: np.ndarray) -> np.ndarray:
    """w-first quaternions (m, 4) float64 from packed_rotation words."""
    m = rot.shape[0]
    norm = np.sqrt(2.0)  # the three small components lie in [-1/sqrt(2), 1/sqrt(2)]
    small = np.stack([(_unorm(rot, s, 10) - 0.5) * norm for s in (20, 10, 0)], axis=1)
    largest = np.sqrt(np.maximum(0.0, 1.0 - (small ** 2).sum(axis=1)))
    which = (rot >> np.uint32(30)).astype(np.int64)
    quats = np.empty((m, 4))
    # The small components fill the slots other than `which`, in order.
    slot = np.arange(4)[None, :]
    rank = slot - (slot > which[:, None])
    quats[:] = np.take_along_axis(small, np.clip(rank, 0, 2), axis=1)
    quats[np.arange(m), which] = largest
    return quats
