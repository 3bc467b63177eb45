"""Standard 3DGS PLY: reading files written by plyfile, exact round trips, errors."""

from __future__ import annotations

import tracemalloc
import warnings

import numpy as np
import plyfile
import pytest

from _memory import traced
from _io_encoders import random_scene, standard_columns, write_ply_plyfile
from seed2gs_inverse.errors import FormatError, ValidationError
from seed2gs_inverse.io import detect_format, read_scene, write_scene
from seed2gs_inverse.scene import GaussianScene

ARRAYS = ("means", "quats", "log_scales", "opacity_logits", "sh")


def assert_same_scene(a, b):
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert sorted(a.extra) == sorted(b.extra)
    for key in a.extra:
        np.testing.assert_array_equal(a.extra[key], b.extra[key], err_msg=key)
        assert a.extra[key].dtype == b.extra[key].dtype


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("normals", [True, False])
def test_reads_plyfile_written_binary_exactly(tmp_path, rng, degree, normals):
    scene = random_scene(rng, n=37, degree=degree)
    path = tmp_path / "s.ply"
    write_ply_plyfile(path, scene, normals=normals)
    got = read_scene(path)
    assert_same_scene(scene, got)  # zero normals are not kept as extras
    assert got.sh_degree == degree


@pytest.mark.parametrize("degree", [0, 3])
def test_big_endian_and_shuffled_order_and_double(tmp_path, rng, degree):
    scene = random_scene(rng, n=21, degree=degree)
    ncols = len(standard_columns(scene))
    order = list(rng.permutation(ncols))
    path = tmp_path / "be.ply"
    write_ply_plyfile(path, scene, byte_order=">", order=order)
    assert_same_scene(scene, read_scene(path))
    # float64 properties are converted to float32 (exactly, since they came from float32)
    write_ply_plyfile(path, scene, dtype="f8")
    assert_same_scene(scene, read_scene(path))


def test_ascii(tmp_path, rng):
    scene = random_scene(rng, n=15, degree=1, extra={"label": np.arange(15, dtype=np.int32)})
    path = tmp_path / "a.ply"
    write_ply_plyfile(path, scene, text=True)
    got = read_scene(path)
    for name in ARRAYS:  # plyfile writes ASCII floats with enough digits for float32
        np.testing.assert_allclose(getattr(got, name), getattr(scene, name), rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(got.extra["label"], np.arange(15))
    assert got.extra["label"].dtype == np.int32


def test_ascii_rejects_non_integer_in_int_property(tmp_path):
    text = ("ply\nformat ascii 1.0\nelement vertex 1\n"
            + "".join(f"property float {p}\n" for p in
                      ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0",
                       "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
            + "property uchar label\nend_header\n"
            + "0 0 0 0 0 0 0 0 0 0 1 0 0 0 2.5\n")
    path = tmp_path / "bad.ply"
    path.write_text(text)
    with pytest.raises(FormatError, match="label"):
        read_scene(path)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_write_read_round_trip_exact_with_extras(tmp_path, rng, degree):
    n = 30
    extra = {"nx": rng.normal(size=n).astype(np.float32), "ny": np.zeros(n, np.float32),
             "nz": np.ones(n, np.float32), "segment": rng.integers(0, 9, n).astype(np.uint8),
             "weight": rng.normal(size=n)}
    scene = random_scene(rng, n=n, degree=degree, extra=extra)
    path = tmp_path / "rt.ply"
    write_scene(path, scene)
    got = read_scene(path)
    assert_same_scene(scene, got)


def test_written_layout_is_the_trainers(tmp_path, rng):
    scene = random_scene(rng, n=8, degree=2, extra={"tag": np.arange(8, dtype=np.uint16)})
    path = tmp_path / "w.ply"
    write_scene(path, scene)
    ply = plyfile.PlyData.read(str(path))  # independent reader
    assert not ply.text and ply.byte_order == "<"
    assert [e.name for e in ply.elements] == ["vertex"]
    v = ply["vertex"].data
    k = 9
    expected = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
                + [f"f_rest_{i}" for i in range(3 * (k - 1))]
                + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "tag"])
    assert list(v.dtype.names) == expected
    assert all(v.dtype[name] == np.dtype("<f4") for name in expected[:-1])
    assert v.dtype["tag"] == np.dtype("<u2")
    # f_rest is channel-major: f_rest_{c*(K-1)+j} = sh[:, 1+j, c]
    for c in range(3):
        for j in range(k - 1):
            np.testing.assert_array_equal(v[f"f_rest_{c * (k - 1) + j}"], scene.sh[:, 1 + j, c])
    np.testing.assert_array_equal(v["nx"], 0)
    np.testing.assert_array_equal(v["rot_0"], scene.quats[:, 0])


def test_empty_scene_round_trip(tmp_path):
    empty = GaussianScene(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0),
                          np.zeros((0, 1, 3)))
    write_scene(tmp_path / "e.ply", empty)
    assert len(read_scene(tmp_path / "e.ply")) == 0


def test_detect_format(tmp_path, rng):
    path = tmp_path / "s.ply"
    write_scene(path, random_scene(rng, n=3))
    assert detect_format(path) == "ply"
    with pytest.raises(FormatError, match="unknown scene format"):
        detect_format(tmp_path / "s.obj")
    with pytest.raises(FileNotFoundError):
        read_scene(tmp_path / "missing.ply")


# --------------------------------------------------------------------------
# errors

def _header(count, props=None, fmt="binary_little_endian"):
    props = props or ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0",
                      "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    return (f"ply\nformat {fmt} 1.0\nelement vertex {count}\n"
            + "".join(f"property float {p}\n" for p in props) + "end_header\n").encode()


def test_missing_required_property(tmp_path):
    props = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
             "scale_2", "rot_0", "rot_1", "rot_2"]
    path = tmp_path / "m.ply"
    path.write_bytes(_header(1, props) + b"\0" * 4 * len(props))
    with pytest.raises(FormatError, match=r"m\.ply.*lacks.*rot_3"):
        read_scene(path)


def test_wrong_number_of_f_rest(tmp_path, rng):
    scene = random_scene(rng, n=4, degree=1)
    cols = [c for c in standard_columns(scene) if c[0] != "f_rest_8"]
    rec = np.empty(4, dtype=[(n, "f4") for n, _ in cols])
    for n, vals in cols:
        rec[n] = vals
    path = tmp_path / "r.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(rec, "vertex")]).write(str(path))
    with pytest.raises(FormatError, match="f_rest"):
        read_scene(path)


def test_truncated_body(tmp_path, rng):
    path = tmp_path / "t.ply"
    write_scene(path, random_scene(rng, n=10))
    data = path.read_bytes()
    path.write_bytes(data[:-7])
    with pytest.raises(FormatError, match=r"t\.ply.*truncated"):
        read_scene(path)


def test_huge_count_is_rejected_before_allocating(tmp_path):
    path = tmp_path / "huge.ply"
    path.write_bytes(_header(10**12) + b"\0" * 4096)
    tracemalloc.start()
    try:
        with pytest.raises(FormatError, match="truncated"):
            read_scene(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 2_000_000
    ascii_path = tmp_path / "huge_ascii.ply"
    ascii_path.write_bytes(_header(10**12, fmt="ascii") + b"0 " * 14 + b"\n")
    with pytest.raises(FormatError, match="truncated"):
        read_scene(ascii_path)


@pytest.mark.parametrize("content, match", [
    (b"plx\nformat ascii 1.0\n", "not a PLY file"),
    (b"ply\nformat binary_middle_endian 1.0\nend_header\n", "unsupported PLY format"),
    (b"ply\nformat ascii 1.0\nelement vertex -3\nend_header\n", "malformed PLY element"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n", "unknown PLY property type"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float x\nend_header\n", "twice"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "end_header"),
    (b"ply\nelement vertex 0\nend_header\n", "no 'format' line"),
    (b"ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n", "no 'vertex' element"),
])
def test_bad_headers(tmp_path, content, match):
    path = tmp_path / "h.ply"
    path.write_bytes(content)
    with pytest.raises(FormatError, match=match) as err:
        read_scene(path)
    assert "h.ply" in str(err.value)


def test_list_property_in_vertex_is_rejected(tmp_path):
    path = tmp_path / "l.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n"
                     b"property list uchar float x\nend_header\n\x01\0\0\0\0")
    with pytest.raises(FormatError):
        read_scene(path)


def test_nonfinite_error_and_drop(tmp_path, rng):
    scene = random_scene(rng, n=12, degree=1)
    cols = dict(standard_columns(scene))
    cols["x"] = cols["x"].copy()
    cols["x"][3] = np.nan
    cols["f_rest_5"] = cols["f_rest_5"].copy()
    cols["f_rest_5"][7] = np.inf
    cols["rot_0"], cols["rot_1"], cols["rot_2"], cols["rot_3"] = (c.copy() for c in (
        cols["rot_0"], cols["rot_1"], cols["rot_2"], cols["rot_3"]))
    for r in ("rot_0", "rot_1", "rot_2", "rot_3"):
        cols[r][9] = 0.0  # zero-length quaternion: rotation undefined
    rec = np.empty(12, dtype=[(n, "f4") for n in cols])
    for n, vals in cols.items():
        rec[n] = vals
    path = tmp_path / "nf.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(rec, "vertex")]).write(str(path))
    with pytest.raises(FormatError, match=r"nf\.ply: 3 of 12 Gaussians .*first at index 3"):
        read_scene(path)
    with pytest.warns(UserWarning, match="dropped 3 of 12"):
        got = read_scene(path, drop_nonfinite=True)
    keep = np.setdiff1d(np.arange(12), [3, 7, 9])
    np.testing.assert_array_equal(got.means, scene.means[keep])
    np.testing.assert_array_equal(got.sh, scene.sh[keep])


def test_float64_overflow_counts_as_nonfinite(tmp_path, rng):
    scene = random_scene(rng, n=3)
    cols = dict(standard_columns(scene, normals=False))
    rec = np.empty(3, dtype=[(n, "f8") for n in cols])
    for n, vals in cols.items():
        rec[n] = vals
    rec["scale_0"][1] = 1e300  # finite in float64, infinite in float32
    path = tmp_path / "ov.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(rec, "vertex")]).write(str(path))
    with pytest.raises(FormatError, match="1 of 3 Gaussians"):
        read_scene(path)


def test_trailing_bytes_warn(tmp_path, rng):
    path = tmp_path / "tr.ply"
    write_scene(path, random_scene(rng, n=2))
    with open(path, "ab") as fh:
        fh.write(b"junk")
    with pytest.warns(UserWarning, match="ignoring 4 bytes"):
        assert len(read_scene(path)) == 2


def test_write_is_atomic(tmp_path, rng, monkeypatch):
    """A failure half-way through writing leaves the old file and no temporary file."""
    import seed2gs_inverse.io.ply as ply_module

    path = tmp_path / "out.ply"
    path.write_bytes(b"old content")
    real = ply_module.atomic_write
    written = []

    class Boom(Exception):
        pass

    def failing_atomic_write(target, chunks):
        def pieces():
            for piece in chunks:
                written.append(len(piece))
                yield piece
                raise Boom()  # after the header has gone to the temporary file
        real(target, pieces())

    monkeypatch.setattr(ply_module, "atomic_write", failing_atomic_write)
    with pytest.raises(Boom):
        write_scene(path, random_scene(rng, n=5))
    assert written and written[0] > 0
    assert path.read_bytes() == b"old content"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.ply"]


def test_write_rejects_unwritable_extras_and_formats(tmp_path, rng):
    scene = random_scene(rng, n=3, extra={"big": np.arange(3, dtype=np.int64)})
    with pytest.raises(ValidationError, match="big"):
        write_scene(tmp_path / "x.ply", scene)
    assert not (tmp_path / "x.ply").exists()
    for bad_name in ("f_rest_3", "has space", "opacity"):
        with pytest.raises(ValidationError, match="cannot be written"):
            write_scene(tmp_path / "x.ply", random_scene(rng, n=3, extra={bad_name: np.zeros(3)}))
    ok = random_scene(rng, n=3)
    for name in ("x.spz", "x.compressed.ply", "x.obj"):
        with pytest.raises(ValidationError):
            write_scene(tmp_path / name, ok)
    with pytest.raises(ValidationError):
        write_scene(tmp_path / "x.ply", "not a scene")
    assert list(tmp_path.iterdir()) == []


def test_nonzero_normals_are_kept(tmp_path, rng):
    scene = random_scene(rng, n=6)
    cols = dict(standard_columns(scene))
    cols["ny"] = np.linspace(-1, 1, 6).astype(np.float32)
    rec = np.empty(6, dtype=[(n, "f4") for n in cols])
    for n, vals in cols.items():
        rec[n] = vals
    path = tmp_path / "n.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(rec, "vertex")]).write(str(path))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = read_scene(path)
    assert sorted(got.extra) == ["nx", "ny", "nz"]  # kept as a group
    np.testing.assert_array_equal(got.extra["ny"], cols["ny"])


def test_negative_zero_normals_are_kept_bit_for_bit(tmp_path, rng):
    scene = random_scene(rng, n=4)
    cols = dict(standard_columns(scene))
    cols["nx"] = np.array([0.0, -0.0, 0.0, 0.0], np.float32)  # trainers' normals: zeros, some signed
    rec = np.empty(4, dtype=[(n, "f4") for n in cols])
    for n, vals in cols.items():
        rec[n] = vals
    path = tmp_path / "n.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(rec, "vertex")]).write(str(path))
    got = read_scene(path)
    np.testing.assert_array_equal(got.extra["nx"].view(np.uint32), cols["nx"].view(np.uint32))
    write_scene(tmp_path / "out.ply", got)
    back = plyfile.PlyData.read(str(tmp_path / "out.ply"))["vertex"].data
    np.testing.assert_array_equal(back["nx"].view(np.uint32), cols["nx"].view(np.uint32))


def test_doubles_beyond_float32_are_read_rounded_with_a_warning(tmp_path, rng):
    scene = random_scene(rng, n=5)
    path = tmp_path / "d.ply"
    write_ply_plyfile(path, scene, dtype="f8")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # exactly float32 values: nothing to say
        read_scene(path)
    rec = plyfile.PlyData.read(str(path))["vertex"].data.copy()
    rec["x"][0] = 1000000.123456789
    plyfile.PlyData([plyfile.PlyElement.describe(rec, "vertex")]).write(str(path))
    with pytest.warns(UserWarning, match=r"d\.ply: x holds values beyond float32") as caught:
        got = read_scene(path)
    assert got.means[0, 0] == np.float32(1000000.123456789)
    assert caught[0].filename == __file__  # the caller's line, not the reader's
    rec["x"][0] = 0.0
    rec["opacity"][1] = 1e300  # beyond float32's range: non-finite, reported as such, not as rounded
    plyfile.PlyData([plyfile.PlyElement.describe(rec, "vertex")]).write(str(path))
    with pytest.warns(UserWarning) as caught:
        read_scene(path)
    assert not any("beyond float32" in str(w.message) for w in caught)
    rec1 = rec[:1].copy()
    rec1["x"][0] = 0.1  # ASCII writers print float32 data at its shortest: not flagged
    plyfile.PlyData([plyfile.PlyElement.describe(rec1, "vertex")], text=True).write(str(path))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_scene(path)


# --------------------------------------------------------------------------
# ASCII memory (issue 12, item 2)

_PROPS14 = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
            "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]


def test_ascii_memory_within_3x_the_file(tmp_path):
    # Short values ("-0.57") are the worst case for a token-list parser: it used
    # 17x the file (tracemalloc; 30-66x resident) for files like this one.
    n = 400_000
    rng = np.random.default_rng(11)
    vals = np.round(rng.normal(0, 1, (n, 14)), 2)
    vals[:, 10] = np.abs(vals[:, 10]) + 0.5  # non-zero quaternions
    path = tmp_path / "short.ply"
    with open(path, "w") as fh:
        fh.write(f"ply\nformat ascii 1.0\nelement vertex {n}\n"
                 + "".join(f"property float {p}\n" for p in _PROPS14) + "end_header\n")
        np.savetxt(fh, vals, fmt="%.3g")
    size = path.stat().st_size
    assert size > 20_000_000  # large enough that the per-block constant does not hide a ratio
    scene, peak = traced(read_scene, path)
    assert peak < 3 * size, f"peak {peak / 1e6:.1f} MB for a {size / 1e6:.1f} MB file"
    # values as numpy's own formatter wrote them, read back by Python's float()
    expect = np.array([[float(f"{v:.3g}") for v in row] for row in vals[::9973]], np.float32)
    got = np.concatenate([scene.means, scene.sh[:, 0], scene.opacity_logits[:, None],
                          scene.log_scales, scene.quats], axis=1)[::9973]
    np.testing.assert_array_equal(got, expect)


@pytest.mark.parametrize("body, match", [
    ("1 2 3 4 5 6 x 8 9 10 1 0 0 0\n", r"row 1: property 'opacity' is 'x', not a number"),
    ("1 2 3 4 5 6 7 8 9 10 1 0 0\n", r"row 1 has 13 values; each row needs 14"),
    ("1 2 3 4 5 6 7 8 9 10 1 0 0 0 0\n", r"row 1 has 15 values"),
    ("1 2 3 4 5 6 7 8 9 10 1 0 0 0\n", r"needs 3 lines but the file holds only 2"),
])
def test_ascii_row_errors_name_row_and_property(tmp_path, body, match):
    good = "1 2 3 4 5 6 7 8 9 10 1 0 0 0\n"
    count = 2 if "holds only" not in match else 3
    head = (f"ply\nformat ascii 1.0\nelement vertex {count}\n"
            + "".join(f"property float {p}\n" for p in _PROPS14) + "end_header\n")
    path = tmp_path / "rows.ply"
    path.write_text(head + good + body + ("\n" * 60 if "holds only" in match else ""))
    with pytest.raises(FormatError, match=match) as err:
        read_scene(path)
    assert str(err.value).startswith(str(path))


def test_ascii_crlf_tabs_blank_lines(tmp_path):
    head = ("ply\r\nformat ascii 1.0\r\nelement vertex 2\r\n"
            + "".join(f"property float {p}\r\n" for p in _PROPS14) + "end_header\r\n")
    body = "1 2 3 0.1 0.2 0.3 0 -1 -1 -1 1 0 0 0\r\n\r\n 4\t5 6 0.1 0.2 0.3 -0.5 -1 -1 -1 1 0 0 0"
    path = tmp_path / "crlf.ply"
    path.write_bytes((head + body).encode())
    scene = read_scene(path)
    np.testing.assert_array_equal(scene.means, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(scene.opacity_logits, [0, -0.5])


# --------------------------------------------------------------------------
# infinite opacity logits (splat-transform output) and field names (issue 12, item 11)

def _ply_with(tmp_path, scene, changes, name="f.ply", text=False):
    cols = dict(standard_columns(scene))
    for (prop, i), value in changes.items():
        cols[prop] = cols[prop].copy()
        cols[prop][i] = value
    rec = np.empty(len(scene), dtype=[(n, "f4") for n in cols])
    for n, vals in cols.items():
        rec[n] = vals
    path = tmp_path / name
    plyfile.PlyData([plyfile.PlyElement.describe(rec, "vertex")], text=text).write(str(path))
    return path


@pytest.mark.parametrize("text", [False, True])
def test_infinite_opacity_is_saturated_and_kept(tmp_path, rng, text):
    scene = random_scene(rng, n=8, degree=1)
    path = _ply_with(tmp_path, scene, {("opacity", 2): np.inf, ("opacity", 5): -np.inf,
                                       ("opacity", 6): np.inf}, text=text)
    with pytest.warns(UserWarning, match=r"2 'opacity' logits are \+inf and 1 are -inf; read as "
                                         r"\+-40"):
        got = read_scene(path)
    assert len(got) == 8  # nothing dropped
    expect = scene.opacity_logits.copy()
    expect[[2, 6]], expect[5] = 40.0, -40.0
    np.testing.assert_array_equal(got.opacity_logits, expect)
    # sigmoid(+-40) is the saturated opacity in float32: 1 and (practically) 0
    assert got.opacities[2] == np.float32(1.0) and got.opacities[5] < 1e-17
    np.testing.assert_array_equal(got.means, scene.means)
    # --drop-nonfinite no longer deletes the most opaque Gaussians
    with pytest.warns(UserWarning, match="read as"):
        assert len(read_scene(path, drop_nonfinite=True)) == 8


def test_other_nonfinite_values_name_the_field(tmp_path, rng):
    scene = random_scene(rng, n=8, degree=1)
    path = _ply_with(tmp_path, scene, {("opacity", 1): np.nan, ("scale_2", 4): -np.inf,
                                       ("f_rest_7", 6): np.inf, ("opacity", 3): np.inf})
    with pytest.warns(UserWarning, match="read as"):
        with pytest.raises(FormatError) as err:
            read_scene(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: 3 of 8 Gaussians are invalid")
    for part in ("non-finite 'opacity' in 1 (first at index 1)",
                 "non-finite 'scale_2' in 1 (first at index 4)",
                 "non-finite 'f_rest_7' in 1 (first at index 6)", "--drop-nonfinite"):
        assert part in msg, msg
    with pytest.warns(UserWarning) as caught:
        got = read_scene(path, drop_nonfinite=True)
    assert any("dropped 3 of 8 invalid Gaussians: non-finite 'scale_2'" in str(w.message)
               for w in caught)
    assert len(got) == 5 and got.opacity_logits[np.argmax(got.opacity_logits)] == 40.0


@pytest.mark.parametrize("count", ["\u00b2", "1" * 5000, "-1", "1e3"])
def test_element_count_must_be_ascii_digits(tmp_path, count):
    path = tmp_path / "c.ply"
    path.write_bytes(f"ply\nformat ascii 1.0\nelement vertex {count}\nproperty float x\n"
                     f"end_header\n".encode())
    with pytest.raises(FormatError, match="malformed PLY element line|non-ASCII") as err:
        read_scene(path)
    assert "cannot decode" not in str(err.value)


def test_ascii_long_lines_and_blank_runs_stay_bounded(tmp_path):
    head = ("ply\nformat ascii 1.0\nelement vertex 2\n"
            + "".join(f"property float {p}\n" for p in _PROPS14) + "end_header\n")
    row = "1 2 3 0.1 0.2 0.3 0 -1 -1 -1 1 0 0 0\n"
    # 3 MB of blank lines between the rows, and rows padded with 2 MB of spaces
    path = tmp_path / "blank.ply"
    path.write_text(head + row + "\n" * 3_000_000 + " " * 2_000_000 + row)
    scene, peak = traced(read_scene, path)
    assert len(scene) == 2 and peak < 3 * path.stat().st_size
    # one 8 MB line is not a row of 14 numbers
    path = tmp_path / "long.ply"
    path.write_text(head + "1 " * 4_000_000 + "\n" + row)
    with pytest.raises(FormatError, match="line longer than"):
        traced(read_scene, path)


def test_guitar_as_splat_transform_writes_it(shared_data, tmp_path):
    # splat-transform decodes the guitar's opacity byte 255 as logit(1) = +inf and
    # writes it into a standard PLY: those 667 Gaussians used to be refused
    packed = read_scene(shared_data / "guitar_90k.compressed.ply")
    cols = dict(standard_columns(packed, normals=False))
    cols["opacity"] = np.where(packed.opacity_logits == 40.0, np.float32(np.inf),
                               packed.opacity_logits)
    assert np.isinf(cols["opacity"]).sum() == 667
    rec = np.empty(len(packed), dtype=[(n, "f4") for n in cols])
    for n, vals in cols.items():
        rec[n] = vals
    path = tmp_path / "guitar_splat_transform.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(rec, "vertex")]).write(str(path))
    with pytest.warns(UserWarning, match=r"667 'opacity' logits are \+inf and 0 are -inf"):
        got = read_scene(path)
    assert len(got) == len(packed) == 90854
    np.testing.assert_array_equal(got.opacity_logits, packed.opacity_logits)
    np.testing.assert_array_equal(got.means, packed.means)


def test_zero_padded_f_rest_names(tmp_path):
    """f_rest_00 .. f_rest_08 are the f_rest_0 .. f_rest_8 of an exporter that pads; they used to reach the
    reader's catch-all error. f_rest_1 next to f_rest_01 is ambiguous and refused."""
    props = "x y z f_dc_0 f_dc_1 f_dc_2 opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3".split()
    head = "ply\nformat binary_little_endian 1.0\nelement vertex 1\n"

    def write(rest_names):
        row = np.zeros(len(props) + len(rest_names), "<f4")
        row[10] = 1.0
        row[len(props):] = np.arange(len(rest_names)) + 0.5  # f_rest_k = k + 0.5, in file order
        text = head + "".join(f"property float {q}\n" for q in props + rest_names) + "end_header\n"
        (tmp_path / "a.ply").write_bytes(text.encode() + row.tobytes())

    write([f"f_rest_{i:02d}" for i in range(9)])
    sh = read_scene(tmp_path / "a.ply").sh
    # f_rest_k is coefficient 1 + k % 3 of channel k // 3 (the 3DGS layout: channel-major)
    np.testing.assert_array_equal(sh[0, 1:, :].T.ravel(), np.arange(9) + 0.5)
    write([f"f_rest_{i}" for i in range(9)][::-1])  # any order of the properties in the file
    np.testing.assert_array_equal(read_scene(tmp_path / "a.ply").sh[0, 1:, :].T.ravel(), 8.5 - np.arange(9))
    write([f"f_rest_{i}" for i in range(8)] + ["f_rest_01"])
    with pytest.raises(FormatError, match="9 f_rest_\\* properties"):
        read_scene(tmp_path / "a.ply")


def test_an_spz_file_named_ply_is_named(tmp_path):
    import gzip

    path = tmp_path / "biker.ply"
    path.write_bytes(gzip.compress(b"NGSP" + bytes(60)))  # SPZ v2/v3: a gzip stream
    with pytest.raises(FormatError, match="starts like an SPZ file .*: if it is one, rename it .spz"):
        read_scene(path)
    path.write_bytes(b"NGSP" + bytes(60))
    with pytest.raises(FormatError, match="rename it .spz"):
        read_scene(path)
