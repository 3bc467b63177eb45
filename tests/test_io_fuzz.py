"""Fuzzing the file readers: corrupted and truncated files give Seed2GSError, in bounded memory.

Valid small files of every format -- scenes (PLY little/big-endian/ASCII,
.splat, .spz v2-v4, .compressed.ply) and cameras (cameras.json,
transforms.json, COLMAP text and binary) -- are mutated: truncated, bytes
overwritten, inserted, deleted or duplicated, bits flipped, integers
replaced by extreme values, numbers in text replaced by absurd ones, and for
gzip-compressed .spz the decompressed payload is mutated and recompressed.

Across every mutated input:

* reading either succeeds (a scene no larger than the file could hold) or
  raises a ``Seed2GSError`` naming the file -- from one of the readers' own
  checks, not the last-resort "cannot decode" net;
* the peak memory traced by ``tracemalloc`` stays below 3x the file size
  plus 64 MB.

``SEED2GS_FUZZ_N`` (default 300) sets the number of mutated inputs per
format; ``SEED2GS_FUZZ_N=10000`` is the long run. Failures print the format,
the seed and the mutations so they can be replayed.
"""

from __future__ import annotations

import io
import tracemalloc
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from _io_encoders import (encode_compressed_ply, encode_spz, encode_splat, random_scene,
                          write_ply_plyfile)
from seed2gs_inverse.errors import FormatError
from seed2gs_inverse.io import read_scene
from seed2gs_inverse.scene import GaussianScene


def _ply_bytes(tmp, **kw):
    rng = np.random.default_rng(3)
    scene = random_scene(rng, n=6, degree=1, extra={"tag": np.arange(6, dtype=np.uint8)})
    path = tmp / "seed.ply"
    write_ply_plyfile(path, scene, **kw)
    return path.read_bytes()


@pytest.fixture(scope="module")
def samples(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fuzz_seeds")
    rng = np.random.default_rng(7)
    s1 = random_scene(rng, n=5, degree=1)
    s0 = random_scene(rng, n=7)
    return {
        "le.ply": _ply_bytes(tmp),
        "be.ply": _ply_bytes(tmp, byte_order=">"),
        "ascii.ply": _ply_bytes(tmp, text=True),
        "x.splat": encode_splat(s0),
        "v2.spz": encode_spz(s1, version=2),
        "v3.spz": encode_spz(s1, version=3),
        "v4.spz": encode_spz(s1, version=4),
        "x.compressed.ply": encode_compressed_ply(s1),
    }


NAMES = ["le.ply", "be.ply", "ascii.ply", "x.splat", "v2.spz", "v3.spz", "v4.spz", "x.compressed.ply"]

mutation = st.one_of(
    st.tuples(st.just("truncate"), st.floats(0, 1)),
    st.tuples(st.just("overwrite"), st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)),
                                             min_size=1, max_size=8)),
    st.tuples(st.just("insert"), st.floats(0, 1), st.binary(min_size=1, max_size=16)),
    st.tuples(st.just("delete"), st.floats(0, 1), st.integers(1, 16)),
)


def _mutate(data: bytes, m) -> bytes:
    kind = m[0]
    n = len(data)
    if kind == "truncate":
        return data[: int(m[1] * (n - 1))]
    if kind == "overwrite":
        out = bytearray(data)
        for where, value in m[1]:
            out[min(n - 1, int(where * n))] = value
        return bytes(out)
    if kind == "insert":
        i = int(m[1] * n)
        return data[:i] + m[2] + data[i:]
    i = int(m[1] * n)
    return data[:i] + data[i + m[2]:]


def _check(tmp, name, blob):
    path = tmp / name
    path.write_bytes(blob)
    tracemalloc.reset_peak()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            scene = read_scene(path)
        except FormatError as exc:
            msg = str(exc)
            assert msg.startswith(str(path)), msg
            assert "cannot decode the file" not in msg, msg
        else:
            assert isinstance(scene, GaussianScene)
            assert len(scene) <= max(len(blob), 1) * 2  # a few bytes per Gaussian at the least
    _, peak = tracemalloc.get_traced_memory()
    assert peak < 30_000_000, f"{name}: peak memory {peak} bytes"


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    tracemalloc.start()
    yield tmp_path_factory.mktemp("fuzz")
    tracemalloc.stop()


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(m=mutation)
def test_mutated_files(samples, fuzz_dir, name, m):
    _check(fuzz_dir, name, _mutate(samples[name], m))


@pytest.mark.parametrize("name", NAMES)
def test_unmutated_samples_read(samples, fuzz_dir, name):
    path = fuzz_dir / name
    path.write_bytes(samples[name])
    assert len(read_scene(path)) > 0


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(blob=st.binary(max_size=300), name=st.sampled_from(NAMES))
def test_random_bytes(fuzz_dir, blob, name):
    _check(fuzz_dir, name, blob)


@settings(max_examples=30, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(count=st.integers(0, 10**15), fmt=st.sampled_from(["ascii", "binary_little_endian"]),
       body=st.binary(max_size=200))
def test_header_counts_never_allocate(fuzz_dir, count, fmt, body):
    props = "".join(f"property float {p}\n" for p in
                    ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
                     "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
    head = f"ply\nformat {fmt} 1.0\nelement vertex {count}\n{props}end_header\n".encode()
    _check(fuzz_dir, "count.ply", head + body)


def test_mutation_helper_changes_bytes():
    data = bytes(range(50))
    assert _mutate(data, ("truncate", 0.5)) == data[:24]
    assert _mutate(data, ("overwrite", [(0.0, 99)]))[0] == 99
    assert _mutate(data, ("insert", 0.1, b"ab"))[5:7] == b"ab"
    assert len(_mutate(data, ("delete", 0.0, 3))) == 47
    assert io.BytesIO(data).read(1) == b"\x00"


# --------------------------------------------------------------------------
# the bounded-size fuzz run over every reader (issue 12, "How it is checked")

import gzip  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import struct  # noqa: E402

from seed2gs_inverse.camera import Camera  # noqa: E402
from seed2gs_inverse.errors import Seed2GSError  # noqa: E402
from seed2gs_inverse.io import read_cameras, write_cameras  # noqa: E402

FUZZ_N = int(os.environ.get("SEED2GS_FUZZ_N", "300"))
MEMORY_SLACK = 64 * 2 ** 20

_EXTREME_INTS = [0, 1, 255, 256, 2 ** 15, 2 ** 16 - 1, 2 ** 31 - 1, 2 ** 31, 2 ** 32 - 1,
                 2 ** 40, 2 ** 63, 2 ** 64 - 1]
_ABSURD_WORDS = [b"0", b"-0", b"-1", b"1e308", b"-1e308", b"1e400", b"nan", b"inf", b"-inf",
                 b"4294967296", b"99999999999999999999999999", b"1" * 500, b"\xc2\xb2", b"0x10",
                 b"", b"1.5", b"[]", b"{}", b"null", b"true", b'"x"', b"1e-320"]


def _fuzz_mutate(data: bytes, rng: np.random.Generator) -> tuple:
    """1-3 random mutations of ``data``; returns (bytes, description)."""
    out = bytearray(data)
    done = []
    for _ in range(int(rng.integers(1, 4))):
        n = len(out)
        kind = int(rng.integers(0, 9))
        i = int(rng.integers(0, n + 1)) if n else 0
        if kind == 0 and n:  # truncate
            del out[i:]
        elif kind == 1 and n:  # overwrite a few bytes
            for _ in range(int(rng.integers(1, 9))):
                out[int(rng.integers(0, n))] = int(rng.integers(0, 256))
        elif kind == 2:  # insert random bytes
            out[i:i] = rng.integers(0, 256, int(rng.integers(1, 17)), dtype=np.uint8).tobytes()
        elif kind == 3 and n:  # delete a range
            del out[i:i + int(rng.integers(1, 33))]
        elif kind == 4 and n:  # duplicate a range
            out[i:i] = out[i:i + int(rng.integers(1, 65))]
        elif kind == 5 and n:  # flip a bit
            j = int(rng.integers(0, n))
            out[j] ^= 1 << int(rng.integers(0, 8))
        elif kind == 6 and n >= 8:  # an integer field set to an extreme value
            j = int(rng.integers(0, n - 7))
            v = _EXTREME_INTS[int(rng.integers(0, len(_EXTREME_INTS)))]
            width = [1, 2, 4, 8][int(rng.integers(0, 4))]
            out[j:j + width] = (v % 2 ** (8 * width)).to_bytes(width, "little")
        elif kind in (7, 8) and n:  # a token of text replaced by an absurd word
            spaces = [k for k in range(n) if out[k] in b" \n\t,:["]
            if spaces:
                a = spaces[int(rng.integers(0, len(spaces)))] + 1
                b = a
                while b < n and out[b] not in b" \n\t,:]}":
                    b += 1
                out[a:b] = _ABSURD_WORDS[int(rng.integers(0, len(_ABSURD_WORDS)))]
        else:
            continue
        done.append(kind)
    return bytes(out), done


def _spz_inner_mutation(data: bytes, rng) -> tuple:
    """Mutate the decompressed payload of a gzip .spz and compress it again."""
    inner, kinds = _fuzz_mutate(gzip.decompress(data), rng)
    return gzip.compress(inner), ["inner"] + kinds


def _cameras():
    out = []
    for i in range(3):
        out.append(Camera.look_at([3.0 * np.cos(i), 1.0, 3.0 * np.sin(i)], [0, 0, 0], [0, 1, 0],
                                  50, 64 + 8 * i, 48, name=f"view_{i}"))
    return out


def _colmap_text_files(cams):
    cam_lines = ["# CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]"]
    img_lines = ["# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"]
    for i, c in enumerate(cams, 1):
        cam_lines.append(f"{i} PINHOLE {c.width} {c.height} {c.fx!r} {c.fy!r} {c.cx!r} {c.cy!r}")
        from seed2gs_inverse.scene import rotmat_to_quat

        q = rotmat_to_quat(c.rotation)
        img_lines.append(" ".join(map(repr, [*q.tolist(), *c.translation.tolist()]))
                         .join([f"{i} ", f" {i} {c.name}.png"]))
        img_lines.append("1.5 2.5 -1")
    return ("\n".join(cam_lines) + "\n").encode(), ("\n".join(img_lines) + "\n").encode()


def _colmap_binary_files(cams):
    from seed2gs_inverse.scene import rotmat_to_quat

    cb = struct.pack("<Q", len(cams))
    ib = struct.pack("<Q", len(cams))
    for i, c in enumerate(cams, 1):
        cb += struct.pack("<iiQQ4d", i, 1, c.width, c.height, c.fx, c.fy, c.cx, c.cy)
        q = rotmat_to_quat(c.rotation)
        ib += struct.pack("<i7di", i, *q, *c.translation, i) + f"{c.name}.png".encode() + b"\0"
        ib += struct.pack("<Q", 1) + struct.pack("<ddq", 1.5, 2.5, -1)
    return cb, ib


@pytest.fixture(scope="module")
def camera_samples(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fuzz_camera_seeds")
    cams = _cameras()
    write_cameras(tmp / "cameras.json", cams)
    frames = [{"file_path": f"images/{c.name}.png", "transform_matrix":
               (c.camera_to_world @ np.diag([1.0, -1.0, -1.0, 1.0])).tolist()} for c in cams]
    transforms = {"camera_model": "OPENCV", "fl_x": 60.0, "fl_y": 61.0, "cx": 32.0, "cy": 24.0,
                  "w": 64, "h": 48, "k1": 0.0, "frames": frames}
    ct, it = _colmap_text_files(cams)
    cb, ib = _colmap_binary_files(cams)
    return {"cameras.json": (tmp / "cameras.json").read_bytes(),
            "transforms.json": json.dumps(transforms).encode(),
            "colmap_txt": {"cameras.txt": ct, "images.txt": it},
            "colmap_bin": {"cameras.bin": cb, "images.bin": ib}}


def _memory_bound(nbytes: int) -> int:
    return 3 * nbytes + MEMORY_SLACK


def _read_traced(read, path, nbytes):
    """Run ``read(path)`` under tracemalloc; (result or exception, peak bytes)."""
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            result = read(path)
        except Exception as exc:  # noqa: BLE001 - the test checks the type below
            result = exc
    return result, tracemalloc.get_traced_memory()[1] - base


SCENE_FORMATS = NAMES + ["v2.spz:inner", "v3.spz:inner"]
CAMERA_FORMATS = ["cameras.json", "transforms.json", "colmap_txt", "colmap_bin"]


@pytest.mark.parametrize("fmt", SCENE_FORMATS + CAMERA_FORMATS)
def test_fuzz_readers(samples, camera_samples, fuzz_dir, fmt):
    """FUZZ_N mutated inputs: only Seed2GSError, memory within 3x the file + 64 MB."""
    rng = np.random.default_rng(list(fmt.encode()))  # a fixed stream per format
    base = fmt.split(":")[0]
    work = fuzz_dir / ("loop-" + fmt.replace(":", "_"))
    work.mkdir(exist_ok=True)
    failures = []
    for k in range(FUZZ_N):
        seed = int(rng.integers(0, 2 ** 32))
        r = np.random.default_rng(seed)
        if base in samples:
            if fmt.endswith(":inner"):
                blob, kinds = _spz_inner_mutation(samples[base], r)
            else:
                blob, kinds = _fuzz_mutate(samples[base], r)
            path = work / base
            path.write_bytes(blob)
            nbytes, read = len(blob), read_scene
        elif base in ("cameras.json", "transforms.json"):
            blob, kinds = _fuzz_mutate(camera_samples[base], r)
            path = work / base
            path.write_bytes(blob)
            nbytes, read = len(blob), read_cameras
        else:  # a COLMAP model: mutate one of its two files
            files = dict(camera_samples[base])
            victim = sorted(files)[int(r.integers(0, 2))]
            files[victim], kinds = _fuzz_mutate(files[victim], r)
            kinds = [victim] + kinds
            for name, data in files.items():
                (work / name).write_bytes(data)
            path, nbytes, read = work, sum(map(len, files.values())), read_cameras
        result, peak = _read_traced(read, path, nbytes)
        problem = None
        if isinstance(result, Seed2GSError):
            msg = str(result)
            if not msg.startswith(str(path)) or "cannot decode" in msg or "cannot read the" in msg:
                problem = f"message {msg!r}"
        elif isinstance(result, BaseException):
            problem = f"{type(result).__name__}: {result}"
        elif base in samples:
            if not (isinstance(result, GaussianScene) and len(result) <= max(nbytes, 1) * 2):
                problem = f"implausible result {result!r}"
        elif not (isinstance(result, list) and all(isinstance(c, Camera) for c in result)):
            problem = f"implausible result {result!r}"
        if peak > _memory_bound(nbytes):
            problem = (problem or "") + f" peak memory {peak} bytes for a {nbytes}-byte input"
        if problem:
            failures.append(f"{fmt} seed={seed} mutations={kinds}: {problem}")
    assert not failures, f"{len(failures)} of {FUZZ_N} inputs failed:\n" + "\n".join(failures[:10])


def test_fuzz_mutator_is_deterministic_and_changes_data():
    data = bytes(range(200))
    a = _fuzz_mutate(data, np.random.default_rng(5))
    assert a == _fuzz_mutate(data, np.random.default_rng(5))
    changed = sum(_fuzz_mutate(data, np.random.default_rng(s))[0] != data for s in range(50))
    assert changed >= 45


def test_pipes_and_directories_are_refused_not_read(tmp_path):
    """A FIFO named like a scene or camera file blocked the reader for ever; a directory gave a raw OS error."""
    import os

    from seed2gs_inverse.io import read_cameras

    for name in ("s.ply", "s.splat", "s.spz"):
        os.mkfifo(tmp_path / name)
        with pytest.raises(FormatError, match=f"{name}: not a regular file"):
            read_scene(tmp_path / name)
    (tmp_path / "d.ply").mkdir()
    with pytest.raises(FormatError, match=r"d\.ply: not a regular file"):
        read_scene(tmp_path / "d.ply")
    os.mkfifo(tmp_path / "c.json")
    with pytest.raises(FormatError, match=r"c\.json: not a regular file"):
        read_cameras(tmp_path / "c.json")


def test_trailing_data_is_named_in_a_warning_by_every_reader(tmp_path):
    """Binary PLY already warned about bytes after its last element; SPZ (gzip and v4) and ASCII PLY
    ignored trailing data silently."""
    import warnings

    from _io_encoders import encode_spz, random_scene

    scene = random_scene(np.random.default_rng(0), n=5)
    for version, what in ((3, "after the gzip stream"), (4, "after the last stream")):
        path = tmp_path / f"t{version}.spz"
        path.write_bytes(encode_spz(scene, version=version) + b"\0" * 7)
        with pytest.warns(UserWarning, match=f"ignoring 7 bytes {what}"):
            read_scene(path)
        path.write_bytes(encode_spz(scene, version=version))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            read_scene(path)
    props = "x y z f_dc_0 f_dc_1 f_dc_2 opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3".split()
    head = "ply\nformat ascii 1.0\nelement vertex 1\n" + "".join(f"property float {q}\n" for q in props)
    row = "0 0 0 0 0 0 0 0 0 0 1 0 0 0\n"
    path = tmp_path / "a.ply"
    path.write_text(head + "end_header\n" + row + row)
    with pytest.warns(UserWarning, match="ignoring the lines after the last PLY element"):
        assert len(read_scene(path)) == 1
    path.write_text(head + "end_header\n" + row + "\n\n")  # blank lines are padding, not data
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_scene(path)
