"""Independent encoders that produce test files for the scene readers.

Each encoder is written from the format's reference packer (antimatter15
convert.py, nianticlabs/spz load-spz.cc, PlayCanvas SuperSplat's compressed
PLY writer), one Gaussian at a time with Python integers, so it shares no
code with the vectorised decoders it checks. PLY files come from ``plyfile``.
"""

from __future__ import annotations

import gzip
import math
import struct

import numpy as np
import plyfile

from seed2gs_inverse.scene import GaussianScene

SH_C0 = 0.28209479177387814


def random_scene(rng, n=40, degree=0, extra=None) -> GaussianScene:
    """A plausible random scene (unit-ish quaternions, moderate scales)."""
    k = (degree + 1) ** 2
    return GaussianScene(
        means=rng.normal(0, 2, (n, 3)),
        quats=rng.normal(0, 1, (n, 4)),
        log_scales=rng.uniform(-5, 0, (n, 3)),
        opacity_logits=rng.normal(0, 2, n),
        sh=rng.normal(0, 0.4, (n, k, 3)),
        extra=extra or {})


def standard_columns(scene, normals=True):
    """(name, values) pairs of a 3DGS PLY vertex element, trainer order."""
    n, k = len(scene), scene.sh.shape[1]
    cols = [("x", scene.means[:, 0]), ("y", scene.means[:, 1]), ("z", scene.means[:, 2])]
    if normals:
        cols += [(f"n{a}", np.zeros(n, np.float32)) for a in "xyz"]
    cols += [(f"f_dc_{c}", scene.sh[:, 0, c]) for c in range(3)]
    idx = 0
    for c in range(3):  # channel-major: all R coefficients, then G, then B
        for j in range(1, k):
            cols.append((f"f_rest_{idx}", scene.sh[:, j, c]))
            idx += 1
    cols.append(("opacity", scene.opacity_logits))
    cols += [(f"scale_{i}", scene.log_scales[:, i]) for i in range(3)]
    cols += [(f"rot_{i}", scene.quats[:, i]) for i in range(4)]
    cols += list(scene.extra.items())
    return cols


def write_ply_plyfile(path, scene, text=False, byte_order="<", normals=True, order=None,
                      dtype="f4", extra_elements=()):
    """Write a 3DGS PLY with plyfile (independent of the package's writer)."""
    cols = standard_columns(scene, normals)
    if order is not None:
        cols = [cols[i] for i in order]
    fields = [(name, dtype if name not in scene.extra else np.asarray(vals).dtype.str[1:])
              for name, vals in cols]
    rec = np.empty(len(scene), dtype=fields)
    for name, vals in cols:
        rec[name] = vals
    elements = [plyfile.PlyElement.describe(rec, "vertex")] + list(extra_elements)
    plyfile.PlyData(elements, text=text, byte_order=byte_order).write(str(path))


# ---------------------------------------------------------------------------
# antimatter15 .splat

def encode_splat(scene) -> bytes:
    out = bytearray()
    for i in range(len(scene)):
        pos = [float(v) for v in scene.means[i]]
        scale = [math.exp(float(v)) for v in scene.log_scales[i]]
        rgb = [0.5 + SH_C0 * float(v) for v in scene.sh[i, 0]]
        alpha = 1 / (1 + math.exp(-float(scene.opacity_logits[i])))
        q = [float(v) for v in scene.quats[i]]
        qn = math.sqrt(sum(v * v for v in q))
        color = [min(255, max(0, round(255 * v))) for v in rgb + [alpha]]
        rot = [min(255, max(0, round(128 * v / qn + 128))) for v in q]
        out += struct.pack("<3f3f4B4B", *pos, *scale, *color, *rot)
    return bytes(out)


# ---------------------------------------------------------------------------
# Niantic .spz

def _u8(x):
    return int(min(255, max(0, round(x))))


def _smallest_three(q_xyzw):
    """Pack a unit quaternion (x, y, z, w) as in packQuaternionSmallestThree."""
    norm = math.sqrt(sum(v * v for v in q_xyzw))
    q = [v / norm for v in q_xyzw]
    largest = max(range(4), key=lambda i: abs(q[i]))
    negate = q[largest] < 0
    comp = largest
    for i in range(4):
        if i != largest:
            negbit = int((q[i] < 0) ^ negate)
            mag = int(511 * (abs(q[i]) / math.sqrt(0.5)) + 0.5)
            comp = (comp << 10) | (negbit << 9) | mag
    return struct.pack("<I", comp)


def spz_arrays(scene, version, fractional_bits=12, sh_degree=None):
    """The six attribute byte strings of an SPZ file."""
    n = len(scene)
    deg = scene.sh_degree if sh_degree is None else sh_degree
    dim = (deg + 1) ** 2 - 1
    pos, alpha, color, scale, rot, sh = (bytearray() for _ in range(6))
    for i in range(n):
        for v in scene.means[i]:
            fixed = int(round(float(v) * (1 << fractional_bits)))
            pos += struct.pack("<i", fixed)[:3]
        alpha.append(_u8(255 / (1 + math.exp(-float(scene.opacity_logits[i])))))
        for v in scene.sh[i, 0]:
            color.append(_u8(float(v) * 0.15 * 255 + 0.5 * 255))
        for v in scene.log_scales[i]:
            scale.append(_u8((float(v) + 10) * 16))
        w, x, y, z = (float(v) for v in scene.quats[i])
        if version == 2:
            norm = math.sqrt(w * w + x * x + y * y + z * z)
            s = 1 if w >= 0 else -1
            rot += bytes(_u8(s * v / norm * 127.5 + 127.5) for v in (x, y, z))
        else:
            rot += _smallest_three([x, y, z, w])
        for j in range(dim):
            for c in range(3):
                coeff = float(scene.sh[i, 1 + j, c]) if 1 + j < scene.sh.shape[1] else 0.0
                sh.append(_u8(coeff * 128 + 128))
    return [bytes(a) for a in (pos, alpha, color, scale, rot, sh)]


def encode_spz(scene, version=3, fractional_bits=12, flags=0, extension=b"", sh_degree=None):
    """An .spz file: gzip (v2, v3) or the v4 container with zstd streams."""
    import zstandard

    deg = scene.sh_degree if sh_degree is None else sh_degree
    arrays = spz_arrays(scene, version, fractional_bits, deg)
    if version in (2, 3):
        head = struct.pack("<IIIBBBB", 0x5053474E, version, len(scene), deg, fractional_bits,
                           flags, 0)
        return gzip.compress(head + extension + b"".join(arrays))
    streams = [zstandard.ZstdCompressor().compress(a) for a in arrays if a]
    sizes = [len(a) for a in arrays if a]
    toc = 32 + len(extension)
    head = struct.pack("<IIIBBBBI12x", 0x5053474E, 4, len(scene), deg, fractional_bits, flags,
                       len(streams), toc)
    table = b"".join(struct.pack("<QQ", len(c), u) for c, u in zip(streams, sizes))
    return head + extension + table + b"".join(streams)


# ---------------------------------------------------------------------------
# PlayCanvas compressed PLY

def _unorm(value, lo, hi, bits):
    top = (1 << bits) - 1
    t = 0.0 if hi == lo else (value - lo) / (hi - lo)
    return int(min(top, max(0, math.floor(t * top + 0.5))))


def encode_compressed_ply(scene, chunk_colors=True, with_sh=True) -> bytes:
    """A PlayCanvas compressed PLY (chunk/vertex/sh elements) of ``scene``."""
    n = len(scene)
    k = scene.sh.shape[1]
    n_chunks = -(-n // 256)
    chunk_rows, vertex_rows = [], []
    for c in range(n_chunks):
        sl = slice(256 * c, min(n, 256 * (c + 1)))
        means = scene.means[sl].astype(np.float64)
        scales = scene.log_scales[sl].astype(np.float64)
        rgb = 0.5 + SH_C0 * scene.sh[sl, 0, :].astype(np.float64)
        row = list(means.min(0)) + list(means.max(0)) + list(scales.min(0)) + list(scales.max(0))
        if chunk_colors:
            row += list(rgb.min(0)) + list(rgb.max(0))
        chunk_rows.append([np.float32(v) for v in row])
        lo_p, hi_p = [float(np.float32(v)) for v in row[0:3]], [float(np.float32(v)) for v in row[3:6]]
        lo_s, hi_s = [float(np.float32(v)) for v in row[6:9]], [float(np.float32(v)) for v in row[9:12]]
        for i in range(sl.start, sl.stop):
            p = [float(v) for v in scene.means[i]]
            s = [float(v) for v in scene.log_scales[i]]
            pp = (_unorm(p[0], lo_p[0], hi_p[0], 11) << 21) | (_unorm(p[1], lo_p[1], hi_p[1], 10) << 11) \
                | _unorm(p[2], lo_p[2], hi_p[2], 11)
            ps = (_unorm(s[0], lo_s[0], hi_s[0], 11) << 21) | (_unorm(s[1], lo_s[1], hi_s[1], 10) << 11) \
                | _unorm(s[2], lo_s[2], hi_s[2], 11)
            q = [float(v) for v in scene.quats[i]]
            qn = math.sqrt(sum(v * v for v in q))
            q = [v / qn for v in q]
            largest = max(range(4), key=lambda j: abs(q[j]))
            if q[largest] < 0:
                q = [-v for v in q]
            pr = largest
            for j in range(4):
                if j != largest:
                    pr = (pr << 10) | _unorm(q[j] * math.sqrt(0.5) + 0.5, 0.0, 1.0, 10)
            col = [0.5 + SH_C0 * float(v) for v in scene.sh[i, 0]]
            if chunk_colors:
                col = [_unorm(v, float(row[12 + a]), float(row[15 + a]), 8) for a, v in enumerate(col)]
            else:
                col = [_unorm(v, 0.0, 1.0, 8) for v in col]
            alpha = _unorm(1 / (1 + math.exp(-float(scene.opacity_logits[i]))), 0.0, 1.0, 8)
            pc = (col[0] << 24) | (col[1] << 16) | (col[2] << 8) | alpha
            vertex_rows.append((pp, pr, ps, pc))
    names = ["min_x", "min_y", "min_z", "max_x", "max_y", "max_z",
             "min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y", "max_scale_z"]
    if chunk_colors:
        names += ["min_r", "min_g", "min_b", "max_r", "max_g", "max_b"]
    chunk = np.array([tuple(r) for r in chunk_rows], dtype=[(nm, "<f4") for nm in names])
    vertex = np.array(vertex_rows, dtype=[(nm, "<u4") for nm in
                                          ("packed_position", "packed_rotation", "packed_scale",
                                           "packed_color")])
    elements = [plyfile.PlyElement.describe(chunk, "chunk"), plyfile.PlyElement.describe(vertex, "vertex")]
    if with_sh and k > 1:
        m = 3 * (k - 1)
        sh = np.empty(n, dtype=[(f"f_rest_{j}", "u1") for j in range(m)])
        for c in range(3):
            for j in range(1, k):
                v = scene.sh[:, j, c].astype(np.float64)
                sh[f"f_rest_{c * (k - 1) + j - 1}"] = np.clip(np.round((v + 4) * 255 / 8), 0, 255)
        elements.append(plyfile.PlyElement.describe(sh, "sh"))
    import io
    buf = io.BytesIO()
    plyfile.PlyData(elements, byte_order="<").write(buf)
    return buf.getvalue()
