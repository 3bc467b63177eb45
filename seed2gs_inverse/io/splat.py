"""antimatter15 ``.splat`` files (read and write).

No header; 32 bytes per Gaussian, little-endian:

===========  =========  ====================================================
bytes        type       meaning
===========  =========  ====================================================
0-11         3 float32  mean
12-23        3 float32  scales, linear: ``exp(log_scale)``
24-27        4 uint8    colour ``round(255 (0.5 + SH_C0 f_dc))`` for r, g, b
                        and opacity ``round(255 sigmoid(logit))``
28-31        4 uint8    unit quaternion, w first: ``round(128 q + 128)``
===========  =========  ====================================================

The format is lossy: colours, opacities and rotations are 8-bit, and higher
SH bands and extra properties cannot be stored (writing drops them with a
warning). The reference converter also sorts Gaussians by size and opacity;
this writer keeps the scene's order so Gaussian indices stay meaningful.
On reading, opacity bytes 0 and 255 become logits -40 and +40.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from ..errors import FormatError, ValidationError
from ..sh import SH_C0
from ._common import (atomic_write, bounded_gzip, fail, file_size, finish_scene, logit_from_unorm,
                      warn_caller)

if TYPE_CHECKING:
    from ..scene import GaussianScene

__all__ = ["read_splat", "write_splat", "check_splat", "SPLAT_DTYPE"]

SPLAT_DTYPE = np.dtype([("position", "<f4", (3,)), ("scale", "<f4", (3,)),
                        ("rgba", "u1", (4,)), ("rotation", "u1", (4,))])
_MAGICS = {b"ply\n": "a PLY file", b"ply\r": "a PLY file", b"NGSP": "an SPZ file"}


def _is_gzip(path) -> bool:
    """Whether the file starts with a gzip stream that decompresses (SPZ v2/v3 under a .splat name).

    The two magic bytes alone are no proof: they are also the low bytes of
    about one x coordinate in 65,536, and a .splat file has no magic of its own.
    """
    with open(path, "rb") as fh:
        head = fh.read(1 << 16)
    if not head.startswith(b"\x1f\x8b\x08"):  # gzip magic and deflate
        return False
    try:
        bounded_gzip(path, head, header_bytes=4)  # (the SPZ reader's own header peek)
    except FormatError:
        return False
    return True


def check_splat(path) -> int:
    """Number of Gaussians in a ``.splat`` file; FormatError if it cannot be one.

    The format has no magic, so this checks what it can: a non-empty size
    that is a multiple of 32 bytes, and no other format's magic bytes.
    """
    size = file_size(path)
    if size == 0:
        raise fail(path, "file is empty")
    with open(path, "rb") as fh:
        head = fh.read(4)
    what = next((w for magic, w in _MAGICS.items() if head.startswith(magic)), None)
    if what is None and _is_gzip(path):
        what = "a gzip (SPZ) file"
    if what is not None:
        raise fail(path, f"this looks like {what}, not a .splat file; rename it with the right extension")
    if size % SPLAT_DTYPE.itemsize:
        raise fail(path, f"file size {size} is not a multiple of {SPLAT_DTYPE.itemsize} bytes "
                         f"(truncated or not a .splat file)")
    return size // SPLAT_DTYPE.itemsize


_BLOCK = 1 << 16  # Gaussians read and decoded at a time


def read_splat(path, drop_nonfinite: bool = False) -> GaussianScene:
    """Decode a ``.splat`` file (see the module docstring).

    The records are read and decoded one block at a time straight into the
    float32 outputs, so memory is the decoded scene (1.75x the file) plus a
    block.
    """
    n = check_splat(path)
    means = np.empty((n, 3), np.float32)
    log_scales = np.empty((n, 3), np.float32)
    quats = np.empty((n, 4), np.float32)
    opacity = np.empty(n, np.float32)
    sh = np.empty((n, 1, 3), np.float32)
    with open(path, "rb") as fh:
        for a in range(0, n, _BLOCK):
            rec = np.fromfile(fh, dtype=SPLAT_DTYPE, count=min(_BLOCK, n - a))
            b = a + rec.shape[0]
            if b == a:  # pragma: no cover - the size was checked; the file shrank meanwhile
                raise fail(path, "file is truncated (it changed while being read)")
            means[a:b] = rec["position"]
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                log_scales[a:b] = np.log(rec["scale"].astype(np.float64))
            rgba = rec["rgba"].astype(np.float64) / 255.0
            sh[a:b, 0, :] = (rgba[:, :3] - 0.5) / SH_C0
            opacity[a:b] = logit_from_unorm(rgba[:, 3])
            quats[a:b] = (rec["rotation"].astype(np.float32) - 128.0) / 128.0
    return finish_scene(path, means, quats, log_scales, opacity, sh, None, drop_nonfinite,
                        fields={"means": [f"position[{i}]" for i in range(3)],
                                "log_scales": [f"scale[{i}] (log of a non-positive scale)"
                                               for i in range(3)]})


def write_splat(path, scene: GaussianScene) -> None:
    """Write ``scene`` as a ``.splat`` file, atomically (see the module docstring).

    Warns when SH bands above 0 or extra properties are dropped; an empty
    scene is refused, since an empty ``.splat`` file cannot be told from a
    failed write.
    """
    n = len(scene)
    if n == 0:
        raise ValidationError("cannot write an empty scene to .splat (the file would be empty)")
    dropped = []
    if scene.sh_degree > 0:
        dropped.append(f"SH bands 1-{scene.sh_degree}")
    if scene.extra:
        dropped.append(f"extra properties {sorted(scene.extra)}")
    if dropped:
        warn_caller(f"{os.fspath(path)}: the .splat format cannot store "
                    f"{' and '.join(dropped)}; they are dropped")
    rec = np.empty(n, dtype=SPLAT_DTYPE)
    rec["position"] = scene.means
    with np.errstate(over="ignore"):
        rec["scale"] = scene.scales
    rgb = 0.5 + SH_C0 * scene.sh[:, 0, :].astype(np.float64)
    alpha = scene.opacities.astype(np.float64)[:, None]
    rec["rgba"] = np.clip(np.round(255.0 * np.concatenate([rgb, alpha], axis=1)), 0, 255)
    rec["rotation"] = np.clip(np.round(128.0 * scene.rotations.astype(np.float64) + 128.0), 0, 255)
    atomic_write(path, [rec.tobytes()])
