"""PlayCanvas compressed PLY: hand-made bytes, an independent encoder, errors."""

from __future__ import annotations

import math

import numpy as np
import plyfile
import pytest

from _memory import traced
from _io_encoders import SH_C0, encode_compressed_ply, random_scene
from seed2gs_inverse.errors import FormatError
from seed2gs_inverse.io import detect_format, read_scene

CHUNK = ["min_x", "min_y", "min_z", "max_x", "max_y", "max_z",
         "min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y", "max_scale_z"]
COLOR = ["min_r", "min_g", "min_b", "max_r", "max_g", "max_b"]
PACKED = ["packed_position", "packed_rotation", "packed_scale", "packed_color"]


def _write(path, chunk_rows, vertex_rows, chunk_names=CHUNK, sh=None):
    chunk = np.array([tuple(r) for r in chunk_rows], dtype=[(n, "<f4") for n in chunk_names])
    vertex = np.array([tuple(r) for r in vertex_rows], dtype=[(n, "<u4") for n in PACKED])
    els = [plyfile.PlyElement.describe(chunk, "chunk"), plyfile.PlyElement.describe(vertex, "vertex")]
    if sh is not None:
        els.append(plyfile.PlyElement.describe(sh, "sh"))
    plyfile.PlyData(els).write(str(path))


def test_known_vertex(tmp_path):
    chunk = [0, -1, 10, 2, 1, 20, -5, -4, -3, -1, 0, 1] + [0, 0, 0, 1, 0.5, 2]
    pos = (2047 << 21) | (0 << 11) | 1023          # x = max, y = min, z = 1023/2047 of the way
    scl = (0 << 21) | (1023 << 11) | 2047          # log scales min, max, max
    rot = (1 << 30) | (1023 << 20) | (512 << 10) | 512   # largest component at slot 1 (x)
    col = (255 << 24) | (0 << 16) | (51 << 8) | 204      # r, g, b, opacity bytes
    path = tmp_path / "one.compressed.ply"
    _write(path, [chunk], [(pos, rot, scl, col)], CHUNK + COLOR)
    assert detect_format(path) == "compressed_ply"
    s = read_scene(path)
    np.testing.assert_allclose(s.means[0], [2, -1, 10 + 10 * 1023 / 2047], rtol=1e-6)
    np.testing.assert_allclose(s.log_scales[0], [-5, 0, 1], atol=1e-6)
    a = (1023 / 1023 - 0.5) * math.sqrt(2)
    b = (512 / 1023 - 0.5) * math.sqrt(2)
    big = math.sqrt(1 - a * a - 2 * b * b)
    np.testing.assert_allclose(s.quats[0], [a, big, b, b], rtol=1e-5, atol=1e-7)  # w-first slots
    rgb = np.array([0 + 1 * 1.0, 0 + 0.5 * 0.0, 0 + 2 * 51 / 255])  # lerp through the chunk colour range
    np.testing.assert_allclose(s.sh[0, 0], (rgb - 0.5) / SH_C0, rtol=1e-6)
    np.testing.assert_allclose(s.opacity_logits[0], math.log((204 / 255) / (1 - 204 / 255)), rtol=1e-6)


def test_no_chunk_colour_and_sh_and_opacity_extremes(tmp_path):
    chunk = [0] * 6 + [0] * 6
    sh = np.zeros(2, dtype=[(f"f_rest_{i}", "u1") for i in range(9)])
    sh["f_rest_0"] = [0, 255]      # coefficient 1 of red: -4 and +4
    sh["f_rest_3"] = [51, 102]     # coefficient 1 of green: 51*8/255 - 4 = -2.4
    verts = [(0, 3 << 30, 0, (255 << 24) | 0), (0, 3 << 30, 0, (0 << 24) | 255)]
    path = tmp_path / "sh.compressed.ply"
    _write(path, [chunk], verts, sh=sh)
    s = read_scene(path)
    assert s.sh_degree == 1
    np.testing.assert_allclose(s.sh[:, 0, 0], [(1 - 0.5) / SH_C0, (0 - 0.5) / SH_C0], rtol=1e-6)
    np.testing.assert_allclose(s.sh[:, 1, 0], [-4, 4], rtol=1e-6)
    np.testing.assert_allclose(s.sh[:, 1, 1], [51 * 8 / 255 - 4, 102 * 8 / 255 - 4], rtol=1e-6)
    np.testing.assert_array_equal(s.opacity_logits, [-40, 40])


@pytest.mark.parametrize("degree, colors", [(0, True), (1, False), (3, True)])
@pytest.mark.parametrize("block", [None, 256])
def test_independent_encoder_within_quantisation(tmp_path, rng, monkeypatch, degree, colors, block):
    """``block``: decode one chunk at a time (3 blocks), as a large file is decoded block by block."""
    from seed2gs_inverse.io import compressed_ply

    if block is not None:
        monkeypatch.setattr(compressed_ply, "_BLOCK", block)
    n = 600  # three chunks, the last one partial
    scene = random_scene(rng, n=n, degree=degree)
    path = tmp_path / "e.compressed.ply"
    path.write_bytes(encode_compressed_ply(scene, chunk_colors=colors))
    got = read_scene(path)
    assert len(got) == n and got.sh_degree == degree
    for c in range(3):
        sl = slice(256 * c, min(n, 256 * (c + 1)))
        span = scene.means[sl].max(0) - scene.means[sl].min(0)
        step = span / np.array([2047, 1023, 2047])
        assert np.all(np.abs(got.means[sl] - scene.means[sl]) <= 0.5 * step + 1e-5)
        span = scene.log_scales[sl].max(0) - scene.log_scales[sl].min(0)
        step = span / np.array([2047, 1023, 2047])
        assert np.all(np.abs(got.log_scales[sl] - scene.log_scales[sl]) <= 0.5 * step + 1e-5)
    rgb_true = scene.sh[:, 0] * SH_C0 + 0.5
    rgb = got.sh[:, 0] * SH_C0 + 0.5
    if colors:
        np.testing.assert_allclose(rgb, rgb_true, atol=np.ptp(rgb_true) / 255 + 1e-5)
    else:
        np.testing.assert_allclose(rgb, np.clip(rgb_true, 0, 1), atol=0.5 / 255 + 1e-6)
    np.testing.assert_allclose(got.opacities, scene.opacities, atol=0.5 / 255 + 1e-6)
    dots = np.abs(np.sum(got.rotations * scene.rotations, axis=1))
    assert dots.min() > 1 - 1e-5
    if degree:
        np.testing.assert_allclose(got.sh[:, 1:], np.clip(scene.sh[:, 1:], -4, 4), atol=4 / 255 + 1e-5)


@pytest.mark.parametrize("mutate, match", [
    (lambda c, v, s: (c[:1], v, s), "expected 2"),   # 300 Gaussians need 2 chunks
    (lambda c, v, s: (c, v, s[:10]), "SH rows"),
])
def test_inconsistent_elements(tmp_path, mutate, match):
    rows = [[0] * 12] * 2
    verts = [(0, 3 << 30, 0, 0xFFFFFFFF)] * 300
    sh = np.zeros(300, dtype=[(f"f_rest_{i}", "u1") for i in range(9)])
    c, v, s = mutate(rows, verts, sh)
    path = tmp_path / "bad.compressed.ply"
    _write(path, c, v, sh=s)
    with pytest.raises(FormatError, match=match):
        read_scene(path)


def test_wrong_types_and_missing(tmp_path):
    chunk = np.zeros(1, dtype=[(n, "<f4") for n in CHUNK[:-1]])  # lacks max_scale_z
    vertex = np.zeros(1, dtype=[(n, "<u4") for n in PACKED])
    path = tmp_path / "m.compressed.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(chunk, "chunk"),
                     plyfile.PlyElement.describe(vertex, "vertex")]).write(str(path))
    with pytest.raises(FormatError, match="max_scale_z"):
        read_scene(path)
    chunk = np.zeros(1, dtype=[(n, "<f4") for n in CHUNK])
    vertex = np.zeros(1, dtype=[(n, "<f4") for n in PACKED])  # float, not uint
    plyfile.PlyData([plyfile.PlyElement.describe(chunk, "chunk"),
                     plyfile.PlyElement.describe(vertex, "vertex")]).write(str(path))
    with pytest.raises(FormatError, match="wrong type"):
        read_scene(path)


def test_truncated(tmp_path, rng):
    data = encode_compressed_ply(random_scene(rng, n=40))
    path = tmp_path / "t.compressed.ply"
    path.write_bytes(data[:-9])
    with pytest.raises(FormatError, match="truncated"):
        read_scene(path)


def test_overflowing_chunk_range_is_nonfinite_without_warnings(tmp_path):
    import warnings

    # red range [0, 3e38]: a full red byte decodes to a DC term beyond float32
    chunk = [0] * 12 + [0, 0, 0, 3e38, 1, 1]
    path = tmp_path / "o.compressed.ply"
    _write(path, [chunk], [(0, 3 << 30, 0, 0xFFFFFFFF), (0, 3 << 30, 0, 0x00FFFFFF)], CHUNK + COLOR)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(FormatError, match="1 of 2 Gaussians"):
            read_scene(path)


def test_huge_counts_are_refused_before_allocating(tmp_path):
    # a header claiming 2^32 Gaussians (and the matching chunk count) over a few bytes
    n = 2 ** 32 - 256
    head = (f"ply\nformat binary_little_endian 1.0\nelement chunk {n // 256}\n"
            + "".join(f"property float {p}\n" for p in CHUNK)
            + f"element vertex {n}\n" + "".join(f"property uint {p}\n" for p in PACKED)
            + f"element sh {n}\n" + "".join(f"property uchar f_rest_{i}\n" for i in range(45))
            + "end_header\n").encode()
    path = tmp_path / "huge.compressed.ply"
    path.write_bytes(head + bytes(4096))

    def read():
        with pytest.raises(FormatError, match="huge.compressed.ply: file is truncated"):
            read_scene(path)

    assert traced(read)[1] < 2_000_000


def test_real_compressed_ply_memory(shared_data):
    path = shared_data / "guitar_90k.compressed.ply"
    scene, peak = traced(read_scene, path)
    out = sum(a.nbytes for a in (scene.means, scene.quats, scene.log_scales,
                                 scene.opacity_logits, scene.sh))
    # the decoded scene is ~15x the packed file; beyond it only the records and one block
    assert peak < out + 2 * path.stat().st_size + 16 * 2 ** 20, (peak, out)


def test_partial_colour_ranges_and_extra_vertex_properties(tmp_path):
    """Five of the six chunk colour ranges decoded every colour without ranges, silently; vertex properties
    the format does not have were dropped silently."""
    chunk = [0] * 12 + [0, 0, 0, 1, 1, 1]
    vert = (0, 3 << 30, 0, (255 << 24) | 255)
    path = tmp_path / "c.compressed.ply"
    _write(path, [chunk[:-1]], [vert], CHUNK + COLOR[:-1])
    with pytest.raises(FormatError, match=r"lacks \['max_b'\]; all six or none"):
        read_scene(path)
    chunk_arr = np.array([tuple(chunk)], dtype=[(n, "<f4") for n in CHUNK + COLOR])
    vertex = np.array([vert + (np.nan,)], dtype=[(n, "<u4") for n in PACKED] + [("foo", "<f4")])
    plyfile.PlyData([plyfile.PlyElement.describe(chunk_arr, "chunk"),
                     plyfile.PlyElement.describe(vertex, "vertex")]).write(str(path))
    with pytest.warns(UserWarning, match=r"vertex properties \['foo'\] are not part of the format"):
        assert len(read_scene(path)) == 1
