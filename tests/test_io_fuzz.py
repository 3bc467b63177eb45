"""Property-based tests: corrupted and truncated files give FormatError or a plausible scene.

Valid small files of every format are mutated (truncated, bytes overwritten,
bytes inserted or deleted). Reading must either succeed with a scene no
larger than the file could hold, or raise FormatError naming the file from
one of the readers' own checks (not the last-resort "cannot decode" net),
and the peak memory must stay small.
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
