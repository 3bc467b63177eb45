"""Niantic .spz (v2, v3, v4): hand-made bytes, an independent encoder, errors, bounded memory."""

from __future__ import annotations

import gzip
import math
import struct
import tracemalloc

import numpy as np
import pytest

from _memory import traced
from _io_encoders import encode_spz, random_scene
from seed2gs_inverse.errors import FormatError
from seed2gs_inverse.io import detect_format, read_scene

MAGIC = 0x5053474E


def _v3_file(n, arrays, sh_degree=0, frac=12, version=3, flags=0, ext=b""):
    head = struct.pack("<IIIBBBB", MAGIC, version, n, sh_degree, frac, flags, 0)
    return gzip.compress(head + ext + b"".join(arrays))


def test_known_bytes_v3(tmp_path):
    # x = 4096 / 2^12 = 1, y = -4096 / 2^12 = -1 (two's complement 0xFFF000), z = 2048 / 2^12 = 0.5
    pos = bytes([0x00, 0x10, 0x00, 0x00, 0xF0, 0xFF, 0x00, 0x08, 0x00])
    alpha = bytes([128])
    color = bytes([255, 0, 128])
    scale = bytes([160, 0, 255])  # 160/16 - 10 = 0, -10, 255/16 - 10
    # smallest three: largest = z (index 2), x = y = 0, w magnitude 511 -> w = sqrt(1/2)
    rot = struct.pack("<I", (2 << 30) | 511)
    path = tmp_path / "k.spz"
    path.write_bytes(_v3_file(1, [pos, alpha, color, scale, rot]))
    s = read_scene(path)
    np.testing.assert_array_equal(s.means[0], [1, -1, 0.5])
    np.testing.assert_allclose(s.opacity_logits[0], math.log((128 / 255) / (127 / 255)), rtol=1e-6)
    np.testing.assert_allclose(s.sh[0, 0], [(1 - 0.5) / 0.15, -0.5 / 0.15, (128 / 255 - 0.5) / 0.15],
                               rtol=1e-6)
    np.testing.assert_allclose(s.log_scales[0], [0, -10, 255 / 16 - 10])
    r = math.sqrt(0.5)
    np.testing.assert_allclose(s.quats[0], [r, 0, 0, r], atol=1e-7)  # w-first


def test_known_bytes_v3_signs_and_sh(tmp_path):
    # largest = w (index 3); x, y, z packed first to last with sign bits: x = -m, y = 0, z = +m
    m = 300
    comp = (3 << 30) | ((1 << 9 | m) << 20) | (0 << 10) | m
    sh = bytes([0, 128, 255] + [128] * 6)  # degree 1: coefficient 1 of r, g, b first
    path = tmp_path / "s.spz"
    path.write_bytes(_v3_file(1, [b"\0" * 9, b"\x80", b"\x80" * 3, b"\x80" * 3,
                                  struct.pack("<I", comp), sh], sh_degree=1))
    s = read_scene(path)
    c = math.sqrt(0.5) * m / 511
    np.testing.assert_allclose(s.quats[0], [math.sqrt(1 - 2 * c * c), -c, 0, c], rtol=1e-6)
    np.testing.assert_allclose(s.sh[0, 1], [-1, 0, 127 / 128])
    np.testing.assert_array_equal(s.sh[0, 2:], 0)


def test_known_bytes_v2_rotation(tmp_path):
    rot = bytes([255, 127, 64])  # xyz = b / 127.5 - 1, w = sqrt(1 - |xyz|^2) clamped at 0
    path = tmp_path / "v2.spz"
    path.write_bytes(_v3_file(1, [b"\0" * 9, b"\x80", b"\x80" * 3, b"\x80" * 3, rot], version=2))
    xyz = np.array([255, 127, 64]) / 127.5 - 1
    w = math.sqrt(max(0.0, 1 - float(xyz @ xyz)))
    np.testing.assert_allclose(read_scene(path).quats[0], [w, *xyz], rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("version", [2, 3, 4])
@pytest.mark.parametrize("degree", [0, 1, 3])
@pytest.mark.parametrize("block", [None, 16])
def test_independent_encoder_within_quantisation(tmp_path, rng, monkeypatch, version, degree, block):
    """``block``: decode 16 Gaussians at a time (4 blocks), as a large file is decoded block by block."""
    from seed2gs_inverse.io import spz

    if block is not None:
        monkeypatch.setattr(spz, "_BLOCK", block)
    scene = random_scene(rng, n=60, degree=degree)
    path = tmp_path / "e.spz"
    path.write_bytes(encode_spz(scene, version=version))
    assert detect_format(path) == "spz"
    got = read_scene(path)
    assert got.sh_degree == degree and len(got) == 60
    np.testing.assert_allclose(got.means, scene.means, atol=0.5 / 4096 + 1e-6)
    np.testing.assert_allclose(got.log_scales, scene.log_scales, atol=0.5 / 16 + 1e-6)
    np.testing.assert_allclose(got.opacities, scene.opacities, atol=0.5 / 255 + 1e-6)
    dc = np.clip(scene.sh[:, 0], -0.5 / 0.15, 0.5 / 0.15)  # the 8-bit range of the DC term
    np.testing.assert_allclose(got.sh[:, 0], dc, atol=0.5 / 255 / 0.15 + 1e-5)
    if degree:
        rest = np.clip(scene.sh[:, 1:], -1, 127 / 128)
        np.testing.assert_allclose(got.sh[:, 1:], rest, atol=0.5 / 128 + 1e-6)
    dots = np.abs(np.sum(got.rotations * scene.rotations, axis=1))
    assert dots.min() > (1 - 1e-3 if version == 2 else 1 - 2e-5)


def test_fractional_bits_and_extensions(tmp_path, rng):
    scene = random_scene(rng, n=10)
    ext = struct.pack("<II", 0xADBE0002, 12) + b"\x01" * 12  # a vendor record, skipped
    for version in (3, 4):
        path = tmp_path / f"x{version}.spz"
        path.write_bytes(encode_spz(scene, version=version, fractional_bits=16, flags=0x2, extension=ext))
        got = read_scene(path)
        np.testing.assert_allclose(got.means, scene.means, atol=0.5 / 65536 + 1e-6)


def test_degree_4_is_truncated_with_warning(tmp_path, rng):
    scene = random_scene(rng, n=5, degree=3)
    path = tmp_path / "d4.spz"
    path.write_bytes(encode_spz(scene, version=4, sh_degree=4))
    with pytest.warns(UserWarning, match="degree 4"):
        got = read_scene(path)
    assert got.sh_degree == 3
    np.testing.assert_allclose(got.sh[:, 1:], np.clip(scene.sh[:, 1:], -1, 127 / 128), atol=0.5 / 128 + 1e-6)


def test_empty_v4(tmp_path, rng):
    path = tmp_path / "e.spz"
    path.write_bytes(encode_spz(random_scene(rng, n=1).subset(np.zeros(1, bool)), version=4))
    assert len(read_scene(path)) == 0


@pytest.mark.parametrize("make, match", [
    (lambda s: b"hello world", "not an SPZ file"),
    (lambda s: gzip.compress(b"XXXX" + b"\0" * 12), "missing 'NGSP' magic"),
    (lambda s: gzip.compress(struct.pack("<IIIBBBB", MAGIC, 1, 0, 0, 12, 0, 0)), "version 1"),
    (lambda s: gzip.compress(struct.pack("<IIIBBBB", MAGIC, 9, 0, 0, 12, 0, 0)), "unsupported SPZ version 9"),
    (lambda s: gzip.compress(struct.pack("<IIIBBBB", MAGIC, 3, 0, 7, 12, 0, 0)), "SH degree 7"),
    (lambda s: encode_spz(s, 3)[:-30], "truncated"),
    (lambda s: gzip.compress(gzip.decompress(encode_spz(s, 3))[:-5]), "truncated"),
    (lambda s: gzip.compress(gzip.decompress(encode_spz(s, 3)) + b"\0" * 5), "5 bytes more"),
    (lambda s: encode_spz(s, 4)[:-3], "truncated"),
    (lambda s: encode_spz(s, 4)[:20], "32-byte SPZ header"),
])
def test_bad_files(tmp_path, rng, make, match):
    path = tmp_path / "bad.spz"
    path.write_bytes(make(random_scene(rng, n=20, degree=1)))
    with pytest.raises(FormatError, match=match) as err:
        read_scene(path)
    assert "bad.spz" in str(err.value)


def test_v4_inconsistent_table(tmp_path, rng):
    data = bytearray(encode_spz(random_scene(rng, n=20), version=4))
    bad_count = bytearray(data)
    bad_count[15] = 6  # numStreams
    bad_size = bytearray(data)
    struct.pack_into("<Q", bad_size, 32 + 8, 999)  # uncompressed size of positions
    bad_toc = bytearray(data)
    struct.pack_into("<I", bad_toc, 16, 10**6)
    corrupt = bytearray(data)
    corrupt[32 + 5 * 16 + 6] ^= 0xFF  # inside the first zstd frame
    for blob, match in ((bad_count, "declares 6 streams"), (bad_size, "declared as 999"),
                        (bad_toc, "outside the file"), (corrupt, "positions")):
        path = tmp_path / "v4.spz"
        path.write_bytes(bytes(blob))
        with pytest.raises(FormatError, match=match):
            read_scene(path)


@pytest.mark.parametrize("version", [3, 4])
def test_huge_point_count_uses_bounded_memory(tmp_path, version):
    n = 0xFFFFFFF0  # 4 billion Gaussians: ~80 GB if believed
    if version == 3:
        blob = gzip.compress(struct.pack("<IIIBBBB", MAGIC, 3, n, 0, 12, 0, 0) + b"\0" * 1000)
    else:
        import zstandard
        sizes = [9 * n, n, 3 * n, 3 * n, 4 * n]
        frames = [zstandard.ZstdCompressor().compress(b"\0" * 100) for _ in sizes]
        head = struct.pack("<IIIBBBBI12x", MAGIC, 4, n, 0, 12, 0, 5, 32)
        blob = head + b"".join(struct.pack("<QQ", len(f), s) for f, s in zip(frames, sizes)) + b"".join(frames)
    path = tmp_path / "huge.spz"
    path.write_bytes(blob)
    tracemalloc.start()
    try:
        with pytest.raises(FormatError):
            read_scene(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 20_000_000


def test_detect_format_checks_magic(tmp_path):
    path = tmp_path / "x.spz"
    path.write_bytes(b"PK\x03\x04 not spz")
    with pytest.raises(FormatError, match="not an SPZ file"):
        detect_format(path)
    with pytest.raises(FileNotFoundError):
        detect_format(tmp_path / "missing.spz")


# --------------------------------------------------------------------------
# decompression bombs: consistent headers that no file of that size could justify
# (issue 12, item 1)

def _zero_v4(n, sizes=None, frame_sizes=None):
    """A v4 file of n degree-0 Gaussians whose streams are zstd frames of zeros."""
    import zstandard

    sizes = sizes or [9 * n, n, 3 * n, 3 * n, 4 * n]
    frame_sizes = frame_sizes or sizes
    cctx = zstandard.ZstdCompressor(level=19)
    frames = [cctx.compress(bytes(s)) for s in frame_sizes]
    head = struct.pack("<IIIBBBBI12x", MAGIC, 4, n, 0, 12, 0, len(sizes), 32)
    toc = b"".join(struct.pack("<QQ", len(f), s) for f, s in zip(frames, sizes))
    return head + toc + b"".join(frames)


def test_zstd_bomb_is_refused_before_decompressing(tmp_path):
    # The reproducer of the issue: ~6.3 KB, 10 million Gaussians, every stream
    # consistent with the header, 200 MB of zeros once decompressed (2.5 GB used before).
    blob = _zero_v4(10_000_000)
    assert len(blob) < 7000
    path = tmp_path / "bomb.spz"
    path.write_bytes(blob)

    def read():
        with pytest.raises(FormatError, match=r"bomb\.spz: the header claims 10000000 Gaussians"
                                              r".*decompression bomb"):
            read_scene(path)

    assert traced(read)[1] < 1_000_000


def test_gzip_bomb_is_refused_before_decompressing(tmp_path):
    n = 2_000_000  # 40 MB of zeros in a ~40 KB gzip stream
    blob = gzip.compress(struct.pack("<IIIBBBB", MAGIC, 3, n, 0, 12, 0, 0) + bytes(20 * n))
    path = tmp_path / "bomb.spz"
    path.write_bytes(blob)

    def read():
        with pytest.raises(FormatError, match="decompression bomb"):
            read_scene(path)

    assert traced(read)[1] < 1_000_000


def test_first_inconsistent_stream_stops_the_read(tmp_path):
    # 100,000 Gaussians (a ~2 MB payload, under the ratio limit); the 'rotations'
    # entry is wrong, so nothing may be decompressed or allocated for the others.
    n = 100_000
    good = [9 * n, n, 3 * n, 3 * n, 4 * n]
    blob = _zero_v4(n, sizes=good[:4] + [4 * n + 1], frame_sizes=good)
    path = tmp_path / "inconsistent.spz"
    path.write_bytes(blob)

    def read():
        with pytest.raises(FormatError, match="stream 'rotations' is declared as 400001 bytes"):
            read_scene(path)

    assert traced(read)[1] < 200_000  # far below the 900 KB of the positions stream


def test_stream_longer_than_declared_is_refused(tmp_path):
    n = 1000
    sizes = [9 * n, n, 3 * n, 3 * n, 4 * n]
    blob = _zero_v4(n, sizes=sizes, frame_sizes=sizes[:2] + [3 * n + 7] + sizes[3:])
    path = tmp_path / "long.spz"
    path.write_bytes(blob)
    with pytest.raises(FormatError, match="the colors stream decompresses to more bytes"):
        read_scene(path)


def test_compressible_but_plausible_file_still_reads(tmp_path, rng):
    # zero-valued SH bands compress extremely well, yet the whole file stays far
    # below the ratio limit: a genuine degree-3 file of a degree-0 scene must read
    scene = random_scene(rng, n=3000, degree=3)
    sh = np.zeros_like(scene.sh)
    sh[:, 0] = scene.sh[:, 0]
    import dataclasses

    flat = dataclasses.replace(scene, sh=sh)
    for version in (3, 4):
        path = tmp_path / f"flat{version}.spz"
        path.write_bytes(encode_spz(flat, version=version))
        got = read_scene(path)
        assert len(got) == 3000 and np.all(got.sh[:, 1:] == 0)


def test_real_spz_memory(shared_data):
    path = shared_data / "biker_152k.spz"
    scene, peak = traced(read_scene, path)
    out = sum(a.nbytes for a in (scene.means, scene.quats, scene.log_scales,
                                 scene.opacity_logits, scene.sh))
    # output + decompressed streams + one block of temporaries
    assert peak < out + 2 * path.stat().st_size + 16 * 2 ** 20, (peak, out)


def test_fractional_bits_beyond_the_fixed_point_width(tmp_path):
    """Positions are 24-bit fixed point: 24 fractional bits still decode (x = 2^22 / 2^24 = 0.25), more
    would round every position to 0 and are refused as a corrupt header."""
    pos = bytes([0x00, 0x00, 0x40]) + bytes(6)  # x = 0x400000 = 2^22
    rest = [bytes([128]), bytes([128, 128, 128]), bytes([160, 160, 160]), struct.pack("<I", (3 << 30))]
    path = tmp_path / "f.spz"
    path.write_bytes(_v3_file(1, [pos] + rest, frac=24))
    assert read_scene(path).means[0, 0] == 0.25
    path.write_bytes(_v3_file(1, [pos] + rest, frac=25))
    with pytest.raises(FormatError, match=r"f\.spz: fractionalBits is 25"):
        read_scene(path)
