"""antimatter15 .splat: known bytes, files from an independent encoder, round trips, errors."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from _memory import traced
from _io_encoders import SH_C0, encode_splat, random_scene
from seed2gs_inverse.errors import FormatError, ValidationError
from seed2gs_inverse.io import detect_format, read_scene, write_scene


def test_known_record(tmp_path):
    # one Gaussian written by hand: position (1, -2, 3), scales (0.5, 1, 2),
    # colour (255, 0, 128), alpha 64, rotation bytes w=255 (x, y, z = 128 -> 0)
    rec = struct.pack("<3f3f4B4B", 1, -2, 3, 0.5, 1, 2, 255, 0, 128, 64, 255, 128, 128, 128)
    path = tmp_path / "one.splat"
    path.write_bytes(rec)
    s = read_scene(path)
    assert len(s) == 1 and s.sh_degree == 0
    np.testing.assert_array_equal(s.means[0], [1, -2, 3])
    np.testing.assert_allclose(s.log_scales[0], np.log([0.5, 1, 2]), rtol=1e-6)
    np.testing.assert_allclose(s.sh[0, 0], [(1 - 0.5) / SH_C0, (0 - 0.5) / SH_C0,
                                            (128 / 255 - 0.5) / SH_C0], rtol=1e-6)
    np.testing.assert_allclose(s.opacity_logits[0], np.log((64 / 255) / (1 - 64 / 255)), rtol=1e-6)
    np.testing.assert_allclose(s.quats[0], [127 / 128, 0, 0, 0])
    np.testing.assert_allclose(s.rotations[0], [1, 0, 0, 0], atol=1e-7)


def test_opacity_extremes_map_to_plus_minus_40(tmp_path):
    rec = b"".join(struct.pack("<3f3f4B4B", 0, 0, 0, 1, 1, 1, 0, 0, 0, a, 255, 128, 128, 128)
                   for a in (0, 255))
    path = tmp_path / "ext.splat"
    path.write_bytes(rec)
    np.testing.assert_array_equal(read_scene(path).opacity_logits, [-40, 40])


def test_reads_independent_encoder_within_quantisation(tmp_path, rng):
    scene = random_scene(rng, n=50)
    path = tmp_path / "e.splat"
    path.write_bytes(encode_splat(scene))
    assert detect_format(path) == "splat"
    got = read_scene(path)
    np.testing.assert_array_equal(got.means, scene.means)  # float32 stored as is
    np.testing.assert_allclose(got.log_scales, scene.log_scales, atol=1e-6)
    # colours and opacities are 8-bit: half a step of 1/255 in colour space
    np.testing.assert_allclose(got.sh[:, 0] * SH_C0 + 0.5,
                               np.clip(scene.sh[:, 0] * SH_C0 + 0.5, 0, 1), atol=0.5 / 255 + 1e-7)
    np.testing.assert_allclose(got.opacities, scene.opacities, atol=0.5 / 255 + 1e-6)
    # rotations: compare rotation matrices (q and -q are the same rotation)
    dots = np.abs(np.sum(got.rotations * scene.rotations, axis=1))
    assert dots.min() > 1 - 2e-4


def test_write_then_read_round_trip_and_bytes_match_encoder(tmp_path, rng):
    scene = random_scene(rng, n=40, degree=2, extra={"t": np.arange(40, dtype=np.int32)})
    path = tmp_path / "w.splat"
    with pytest.warns(UserWarning, match=r"SH bands 1-2 and extra properties \['t'\]"):
        write_scene(path, scene)
    data = path.read_bytes()
    assert len(data) == 32 * 40
    ref = np.frombuffer(encode_splat(scene), np.uint8).reshape(40, 32)
    mine = np.frombuffer(data, np.uint8).reshape(40, 32)
    np.testing.assert_array_equal(mine[:, :12], ref[:, :12])
    np.testing.assert_allclose(np.frombuffer(mine[:, 12:24].tobytes(), "<f4"),
                               np.frombuffer(ref[:, 12:24].tobytes(), "<f4"), rtol=1e-6)
    # 8-bit fields may differ by one where float rounding straddles .5
    assert np.abs(mine[:, 24:].astype(int) - ref[:, 24:]).max() <= 1
    again = read_scene(path)
    write_scene(tmp_path / "again.splat", again)
    twice = np.frombuffer((tmp_path / "again.splat").read_bytes(), np.uint8).reshape(40, 32)
    # decode/encode is idempotent except rotations, which are renormalised (one step at most)
    np.testing.assert_array_equal(twice[:, :28], mine[:, :28])
    assert np.abs(twice[:, 28:].astype(int) - mine[:, 28:]).max() <= 1


@pytest.mark.parametrize("content, match", [
    (b"", "empty"),
    (b"\0" * 33, "not a multiple of 32"),
    (b"ply\n" + b"\0" * 60, "looks like a PLY file"),
    (b"NGSP" + b"\0" * 28, "looks like an SPZ file"),
])
def test_bad_files(tmp_path, content, match):
    path = tmp_path / "bad.splat"
    path.write_bytes(content)
    with pytest.raises(FormatError, match=match) as err:
        read_scene(path)
    assert "bad.splat" in str(err.value)


def test_gzip_magic_in_a_coordinate_is_not_gzip(tmp_path):
    """A .splat has no magic: x = 2.5085 starts with the gzip bytes 1f 8b and is still read (it was
    refused as SPZ); a real gzip stream under a .splat name is refused."""
    import gzip

    x = struct.unpack("<f", b"\x1f\x8b\x20\x40")[0]
    rec = struct.pack("<3f3f4B4B", x, 0, 0, 1, 1, 1, 9, 9, 9, 200, 255, 128, 128, 128)
    path = tmp_path / "s.splat"
    path.write_bytes(rec)
    assert read_scene(path).means[0, 0] == np.float32(x)
    x8 = struct.unpack("<f", b"\x1f\x8b\x08\x40")[0]  # also the deflate byte: still no gzip stream
    path.write_bytes(struct.pack("<3f3f4B4B", x8, 0, 0, 1, 1, 1, 9, 9, 9, 200, 255, 128, 128, 128))
    assert read_scene(path).means[0, 0] == np.float32(x8)
    payload = gzip.compress(b"NGSP" + b"\0" * 60)
    path.write_bytes(payload + b"\0" * (-len(payload) % 32))  # even a size that fits 32-byte records
    with pytest.raises(FormatError, match="looks like a gzip"):
        read_scene(path)


def test_nonpositive_scale_is_nonfinite(tmp_path):
    rec = b"".join(struct.pack("<3f3f4B4B", i, 0, 0, s, 1, 1, 9, 9, 9, 200, 255, 128, 128, 128)
                   for i, s in enumerate((1.0, 0.0, -1.0)))
    path = tmp_path / "s.splat"
    path.write_bytes(rec)
    with pytest.raises(FormatError, match="2 of 3 Gaussians"):
        read_scene(path)
    with pytest.warns(UserWarning, match="dropped 2 of 3"):
        assert len(read_scene(path, drop_nonfinite=True)) == 1


def test_empty_scene_is_not_written(tmp_path, rng):
    with pytest.raises(ValidationError, match="empty"):
        write_scene(tmp_path / "e.splat", random_scene(rng, n=3).subset(np.zeros(3, bool)))
    assert not (tmp_path / "e.splat").exists()


def test_detect_format_checks_content(tmp_path):
    path = tmp_path / "x.splat"
    path.write_bytes(b"ply\n" + b"\0" * 28)
    with pytest.raises(FormatError, match="looks like a PLY file"):
        detect_format(path)
    path.write_bytes(b"\0" * 31)
    with pytest.raises(FormatError, match="multiple of 32"):
        detect_format(path)


def test_memory_within_3x_the_file(tmp_path):
    from seed2gs_inverse.io.splat import SPLAT_DTYPE

    n = 500_000
    rng = np.random.default_rng(2)
    rec = np.empty(n, SPLAT_DTYPE)
    rec["position"] = rng.normal(size=(n, 3))
    rec["scale"] = rng.uniform(0.01, 1, (n, 3))
    rec["rgba"] = rng.integers(0, 256, (n, 4))
    rec["rotation"] = rng.integers(0, 256, (n, 4))
    rec["rotation"][:, 0] = 255  # never a zero quaternion
    path = tmp_path / "big.splat"
    rec.tofile(path)
    scene, peak = traced(read_scene, path)
    assert peak < 3 * path.stat().st_size, peak
    np.testing.assert_array_equal(scene.means, rec["position"])
    np.testing.assert_allclose(scene.opacities, rec["rgba"][:, 3] / 255.0, atol=1e-6)
