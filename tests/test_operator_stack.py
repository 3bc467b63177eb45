"""ViewOperator / OperatorStack: adjointness, stacking, save/load, bad directories."""

from __future__ import annotations

import dataclasses

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from seed2gs_inverse.camera import Camera
from seed2gs_inverse.errors import FormatError, ValidationError
from seed2gs_inverse.operators import OperatorStack, ViewOperator, dottest, scene_fingerprint
from seed2gs_inverse.scene import GaussianScene


def _random_view(rng, n=50, h=6, w=8, density=0.2, name="v", with_camera=True):
    W = sp.random(h * w, n, density=density, random_state=rng, format="csr", dtype=np.float32)
    cam = Camera.from_fov(w, h, 60.0, name=name) if with_camera else None
    return ViewOperator(W, cam, (h, w))


def _scene(rng, n=50):
    return GaussianScene(rng.normal(size=(n, 3)), rng.normal(size=(n, 4)) + [3, 0, 0, 0],
                         rng.normal(size=(n, 3)) - 3, rng.normal(size=n), rng.normal(size=(n, 1, 3)))


def _stack(rng, n=50, views=3):
    return OperatorStack([_random_view(rng, n, 6 + i, 8, name=f"v{i}") for i in range(views)], fingerprint="abc")


# -- ViewOperator ---------------------------------------------------------------
def test_view_matvec_rmatvec_match_dense(rng):
    v = _random_view(rng)
    dense = v.W.toarray().astype(np.float64)
    q = rng.random(v.n_gaussians).astype(np.float32)
    img = rng.random(v.image_shape).astype(np.float32)
    np.testing.assert_allclose(v.matvec(q), dense @ q, rtol=1e-5)
    np.testing.assert_allclose(v.image(q), (dense @ q).reshape(v.image_shape), rtol=1e-5)
    np.testing.assert_allclose(v.rmatvec(img), dense.T @ img.ravel(), rtol=1e-5)
    np.testing.assert_allclose(v.rmatvec(img.ravel()), dense.T @ img.ravel(), rtol=1e-5)
    np.testing.assert_allclose(v.alpha(), dense.sum(1).reshape(v.image_shape), rtol=1e-5)
    np.testing.assert_array_equal(v.observed(), dense.any(0))


def test_view_dot_test():
    """The dot test on an operator of the rasterizer, alone and stacked."""
    from render_reference import random_scene

    from seed2gs_inverse.raster import build_operator

    cam = Camera.look_at([0.2, -0.6, -4.0], [0, 0, 0], [0, -1, 0], 48, 24, 20)
    op = build_operator(random_scene(3, n=80, cam=cam), cam)
    assert dottest(op, rng=0) and dottest(OperatorStack([op, op]), rng=1)


@pytest.mark.parametrize("bad, match", [
    (lambda W: W.tocoo(), "CSR"),
    (lambda W: W.astype(np.float64), "float32"),
    (lambda W: W[:-1], "rows"),
    (lambda W: W.toarray(), "CSR"),
])
def test_view_operator_rejects_bad_W(rng, bad, match):
    v = _random_view(rng)
    with pytest.raises(ValidationError, match=match):
        ViewOperator(bad(v.W), v.camera, v.image_shape)


def _raw_csr(data, indices, indptr, shape):
    """A CSR matrix from its arrays as given: scipy checks none of them here."""
    return sp.csr_matrix((np.float32(data), np.asarray(indices, np.int32), np.asarray(indptr, np.int32)),
                         shape=shape)


@pytest.mark.parametrize("indices, indptr, match", [
    ([7, 0], [0, 1, 2], "column indices"),  # read as garbage by the forward pass
    ([100_000_000, 0], [0, 1, 2], "column indices"),  # the adjoint wrote out of bounds: a segmentation fault
    ([-1, 0], [0, 1, 2], "column indices"),
    ([1, 2], [0, 2, 1], "indptr"),  # decreasing (scipy refuses a wrong start or end itself)
])
def test_view_operator_rejects_broken_csr_arrays(indices, indptr, match):
    W = _raw_csr([0.5, 0.5], indices, indptr, (2, 3))
    with pytest.raises(ValidationError, match=match):
        ViewOperator(W, None, (1, 2))
    from seed2gs_inverse.operators import as_stack

    with pytest.raises(ValidationError, match=match):
        as_stack([W])


@pytest.mark.parametrize("field, value, match", [
    ("rgb", np.zeros((2, 2, 3), np.float32), "shape"),
    ("rgb", np.zeros((6, 8), np.float32), "shape"),
    ("depth", np.full((6, 8), np.nan, np.float32), "non-finite"),
    ("n_contrib", np.zeros((6, 8), np.float32), "integer"),
    ("alpha", -np.ones((6, 8), np.float32), "lie in"),
])
def test_view_operator_rejects_a_rendering_a_saved_stack_could_not_load(rng, tmp_path, field, value, match):
    """A view accepted in memory saves as a stack that loads: the rendering follows the loader's rules."""
    from seed2gs_inverse.operators import Rendering

    v = _random_view(rng, h=6, w=8)
    with pytest.raises(ValidationError, match=match):
        ViewOperator(v.W, v.camera, v.image_shape, Rendering(**{field: value}))
    ok = Rendering(rgb=np.zeros((6, 8, 3)), depth=np.ones((6, 8), np.float32), n_contrib=np.zeros((6, 8), np.uint16))
    OperatorStack([ViewOperator(v.W, v.camera, v.image_shape, ok)]).save(tmp_path / "ops")
    assert OperatorStack.load(tmp_path / "ops")[0].rendering.n_contrib.dtype == np.uint16


def test_view_operator_rejects_shape_mismatch(rng):
    v = _random_view(rng, h=6, w=8)
    with pytest.raises(ValidationError, match="camera"):
        ViewOperator(v.W, Camera.from_fov(6, 8, 60.0), (6, 8))
    with pytest.raises(ValidationError, match="image_shape"):
        ViewOperator(v.W, None, (6, 0))
    with pytest.raises(ValidationError, match="q must have shape"):
        v.matvec(np.zeros(3))
    with pytest.raises(ValidationError, match="image must have shape"):
        v.rmatvec(np.zeros((2, 2)))


# -- OperatorStack ----------------------------------------------------------------
def test_stack_linear_operator_matches_dense_and_passes_dot_test(rng):
    s = _stack(rng)
    dense = np.vstack([v.W.toarray() for v in s]).astype(np.float64)
    L = s.as_linear_operator()
    assert L.shape == (s.n_pixels, 50) == dense.shape
    x = rng.normal(size=50).astype(np.float32)
    y = rng.normal(size=s.n_pixels).astype(np.float32)
    np.testing.assert_allclose(L.matvec(x), dense @ x, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(L.rmatvec(y), dense.T @ y, rtol=1e-4, atol=1e-5)
    lhs = float(np.dot(L.matvec(x).astype(np.float64), y))
    rhs = float(np.dot(x, L.rmatvec(y).astype(np.float64)))
    assert abs(lhs - rhs) <= 1e-4 * max(1.0, abs(lhs))
    np.testing.assert_array_equal(s.observed(), dense.any(0))
    np.testing.assert_allclose(s.row_sums(), dense.sum(1), rtol=1e-5)
    np.testing.assert_allclose(s.column_sums(), dense.sum(0), rtol=1e-5)
    assert s.row_sums().dtype == np.float32 and not s.row_sums().flags.writeable
    # solve() reads the cached column sums: a user's in-place change must not reach it
    assert not s.column_sums().flags.writeable
    assert len(s) == 3 and [v.name for v in s] == ["v0", "v1", "v2"] and s[1].name == "v1"
    np.testing.assert_array_equal(s.row_offsets(), np.cumsum([0, 48, 56, 64]))
    sub = s.subset([2, 0])
    assert [v.name for v in sub] == ["v2", "v0"] and sub.fingerprint == "abc"


def test_stack_rejects_empty_and_mixed_scenes(rng):
    with pytest.raises(ValidationError, match="empty"):
        OperatorStack([])
    with pytest.raises(ValidationError, match="view 1.*different scenes"):
        OperatorStack([_random_view(rng, n=50), _random_view(rng, n=51)])
    with pytest.raises(ValidationError, match="view 0"):
        OperatorStack(["not an operator"])


def _assert_same(a: OperatorStack, b: OperatorStack):
    assert len(a) == len(b) and a.n_gaussians == b.n_gaussians and a.fingerprint == b.fingerprint
    for va, vb in zip(a, b):
        assert va.image_shape == vb.image_shape
        np.testing.assert_array_equal(va.W.indptr, vb.W.indptr)
        np.testing.assert_array_equal(va.W.indices, vb.W.indices)
        np.testing.assert_array_equal(va.W.data, vb.W.data)
        assert vb.W.dtype == np.float32
        if va.camera is None:
            assert vb.camera is None
        else:
            assert va.camera.to_dict() == vb.camera.to_dict()


@pytest.mark.parametrize("mmap", [True, False])
def test_save_load_round_trip_is_exact(rng, tmp_path, mmap):
    s = _stack(rng)
    s = OperatorStack([*s.views, _random_view(rng, name="", with_camera=False)], s.fingerprint)
    s.save(tmp_path / "ops")
    t = OperatorStack.load(tmp_path / "ops", mmap=mmap)
    _assert_same(s, t)
    # memory-mapped arrays are read-only views of the files; read arrays are private copies
    assert t[0].W.data.flags.writeable is (not mmap)
    x = rng.random(50).astype(np.float32)
    np.testing.assert_array_equal(t.as_linear_operator().matvec(x), s.as_linear_operator().matvec(x))
    np.testing.assert_array_equal(t @ x, s @ x)
    dottest(t, rng=2)
    # no pickle anywhere: every file is JSON or a plain .npy
    for f in (tmp_path / "ops").iterdir():
        assert f.suffix in (".json", ".npy")
        if f.suffix == ".npy":
            np.load(f, allow_pickle=False)


def test_save_load_keeps_rendering(rng, tmp_path):
    from seed2gs_inverse.operators import Rendering

    v = _random_view(rng, h=6, w=8)
    r = Rendering(rng.random((6, 8, 3)).astype(np.float32), v.alpha(), rng.random((6, 8)).astype(np.float32),
                  np.arange(48, dtype=np.int32).reshape(6, 8))
    OperatorStack([ViewOperator(v.W, v.camera, v.image_shape, r)]).save(tmp_path / "ops")
    back = OperatorStack.load(tmp_path / "ops", mmap=False)[0].rendering
    assert isinstance(back, Rendering)
    for k in ("rgb", "alpha", "depth", "n_contrib"):
        np.testing.assert_array_equal(getattr(back, k), getattr(r, k))
        assert getattr(back, k).dtype == getattr(r, k).dtype


def test_fingerprint_checks_scene(rng, tmp_path):
    scene = _scene(rng)
    fp = scene_fingerprint(scene)
    assert fp == scene_fingerprint(scene.copy()) and len(fp) == 16
    # scene arrays are read-only: changed copies make new scenes
    means = scene.means.copy()
    means[7, 0] += 1e-3
    moved = dataclasses.replace(scene, means=means)
    assert scene_fingerprint(moved) != fp
    # every array W depends on changes the fingerprint; colours do not
    for field in ("quats", "log_scales", "opacity_logits"):
        arr = getattr(scene, field).copy()
        arr.flat[3] += 1e-3
        assert scene_fingerprint(dataclasses.replace(scene, **{field: arr})) != fp, field
    recoloured = dataclasses.replace(scene, sh=scene.sh + 0.25)
    assert scene_fingerprint(recoloured) == fp
    s = OperatorStack(_stack(rng).views, fingerprint=fp)
    s.save(tmp_path / "ops")
    assert OperatorStack.load(tmp_path / "ops", scene=scene).fingerprint == fp
    with pytest.raises(ValidationError, match="another scene"):
        OperatorStack.load(tmp_path / "ops", scene=moved)
    with pytest.raises(ValidationError, match="Gaussians"):
        OperatorStack.load(tmp_path / "ops", scene=_scene(rng, n=49))
    with pytest.raises(ValidationError, match="GaussianScene or a FrozenScene"):
        OperatorStack.load(tmp_path / "ops", scene=scene.means)


def test_fingerprint_takes_a_frozen_scene(rng, tmp_path):
    """A FrozenScene, accepted wherever the rasterizer takes a scene, is its scene here too."""
    from seed2gs_inverse.raster import FrozenScene

    scene = _scene(rng)
    frozen = FrozenScene(scene)
    assert scene_fingerprint(frozen) == scene_fingerprint(scene)
    OperatorStack(_stack(rng).views, fingerprint=scene_fingerprint(scene)).save(tmp_path / "ops")
    assert OperatorStack.load(tmp_path / "ops", scene=frozen).fingerprint == scene_fingerprint(scene)


def test_save_refuses_a_stack_the_disk_cannot_hold(rng, tmp_path, monkeypatch):
    """Checked before writing: a 22 GB stack (operators build --scale 100) used to fill the disk."""
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    s = _stack(rng)
    need = sum(v.W.data.nbytes + v.W.indices.nbytes + v.W.indptr.nbytes for v in s)
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(2 ** 31, 2 ** 31 - 2 ** 20, 2 ** 20))
    with pytest.raises(ValidationError, match=rf"the operators need {need / 1e3:.0f} kB \(1\.\d MB with room to "
                                              rf"spare\) but .* has 1\.0 MB free"):
        s.save(tmp_path / "ops")
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(2 ** 31, 2 ** 31 - 2 ** 22, 2 ** 22))
    s.save(tmp_path / "ops")  # a small stack fits a small volume: no fixed gigabyte to spare


def test_save_refuses_foreign_directory_and_overwrites_only_when_asked(rng, tmp_path):
    s = _stack(rng)
    other = tmp_path / "photos"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    with pytest.raises(ValidationError, match="manifest.json is missing or not the toolkit's"):
        s.save(other, overwrite=True)
    assert (other / "keep.txt").read_text() == "mine"
    s.save(tmp_path / "ops")
    (tmp_path / "ops" / "notes.txt").write_text("mine")  # a user's file beside an operator directory
    with pytest.raises(ValidationError, match=r"files that are not part of such an output \(notes.txt\)"):
        s.save(tmp_path / "ops", overwrite=True)
    (tmp_path / "ops" / "notes.txt").unlink()
    with pytest.raises(ValidationError, match="overwrite"):
        s.save(tmp_path / "ops")
    s2 = _stack(np.random.default_rng(7))
    s2.save(tmp_path / "ops", overwrite=True)
    _assert_same(s2, OperatorStack.load(tmp_path / "ops"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ops", "photos"]


def test_failed_save_leaves_nothing(rng, tmp_path, monkeypatch):
    s = _stack(rng)
    calls = {"n": 0}
    real = np.save

    def flaky(*a, **k):
        calls["n"] += 1
        if calls["n"] == 4:
            raise OSError("disk full")
        return real(*a, **k)

    monkeypatch.setattr(np, "save", flaky)
    with pytest.raises(OSError, match="disk full"):
        s.save(tmp_path / "ops")
    assert list(tmp_path.iterdir()) == []


# -- corrupted / foreign directories --------------------------------------------------
def _saved(rng, tmp_path) -> Path:
    d = tmp_path / "ops"
    _stack(rng).save(d)
    return d


def _edit_manifest(d: Path, fn):
    m = json.loads((d / "manifest.json").read_text())
    fn(m)
    (d / "manifest.json").write_text(json.dumps(m))


def _corruptions():
    def arr(name, value):
        return lambda d: np.save(d / name, value)

    return {
        "no manifest": (lambda d: (d / "manifest.json").unlink(), "manifest"),
        "not json": (lambda d: (d / "manifest.json").write_text("{oops"), "JSON"),
        "binary manifest": (lambda d: (d / "manifest.json").write_bytes(b"\xff\xfe\x00"), "JSON"),
        "wrong format": (lambda d: _edit_manifest(d, lambda m: m.update(format="x")), "format"),
        "future version": (lambda d: _edit_manifest(d, lambda m: m.update(version=2)), "version"),
        "bad n": (lambda d: _edit_manifest(d, lambda m: m.update(n_gaussians=-1)), "n_gaussians"),
        "no views": (lambda d: _edit_manifest(d, lambda m: m.update(views=[])), "views"),
        "bad camera": (lambda d: _edit_manifest(d, lambda m: m["views"][0]["camera"].update(fx=-1)), "view 0"),
        "shape vs camera": (lambda d: _edit_manifest(d, lambda m: m["views"][1].update(image_shape=[5, 8])),
                            "view 1"),
        "path traversal": (lambda d: _edit_manifest(
            d, lambda m: m["views"][0]["files"].update(data="../x.npy")), "file name"),
        "missing array": (lambda d: (d / "view_002_indices.npy").unlink(), "missing"),
        "truncated array": (lambda d: (d / "view_000_data.npy").write_bytes(
            (d / "view_000_data.npy").read_bytes()[:100]), "view_000_data"),
        "pickled array": (lambda d: np.save(d / "view_000_data.npy", np.array([{}], dtype=object),
                                            allow_pickle=True), "view_000_data"),
        "float64 data": (lambda d: np.save(d / "view_001_data.npy",
                                           np.load(d / "view_001_data.npy").astype(np.float64)), "float32"),
        "nan weight": (lambda d: np.save(d / "view_001_data.npy", np.full_like(
            np.load(d / "view_001_data.npy"), np.nan)), "finite"),
        "index out of range": (lambda d: np.save(d / "view_000_indices.npy", np.load(
            d / "view_000_indices.npy") + 1000), r"\[0, 50\)"),
        "indptr decreasing": (lambda d: np.save(d / "view_000_indptr.npy", np.load(
            d / "view_000_indptr.npy")[::-1].copy()), "indptr"),
        "indptr short": (lambda d: np.save(d / "view_000_indptr.npy", np.load(
            d / "view_000_indptr.npy")[:-1].copy()), "indptr"),
        "nnz lies": (lambda d: _edit_manifest(d, lambda m: m["views"][0].update(nnz=3)), "nnz"),
        "2-D data": (lambda d: np.save(d / "view_000_data.npy", np.load(d / "view_000_data.npy")[:, None]), "1-D"),
        "index dtype": (arr("view_000_indices.npy", np.zeros(3, np.float32)), "int32"),
        # issue 12: loads that used to succeed on corrupt stacks, or raised outside Seed2GSError
        "version true": (lambda d: _edit_manifest(d, lambda m: m.update(version=True)), "version"),
        "n beyond int32": (lambda d: _edit_manifest(d, lambda m: m.update(n_gaussians=2 ** 31 + 5)), "n_gaussians"),
        "huge json int": (lambda d: (d / "manifest.json").write_text(
            (d / "manifest.json").read_text().replace('"n_gaussians": 50', '"n_gaussians": ' + "9" * 5000)),
            "JSON"),
        "huge camera int": (lambda d: _edit_manifest(d, lambda m: m["views"][0]["camera"].update(width=10 ** 400)),
                            "view 0"),
        "huge image shape": (lambda d: _edit_manifest(d, lambda m: m["views"][0].update(image_shape=[10 ** 30, 2])),
                             "image_shape"),
        "nested manifest": (lambda d: (d / "manifest.json").write_text("[" * 100_000 + "]" * 100_000), "manifest"),
        "npz under npy name": (lambda d: np.savez(open(d / "view_000_data.npy", "wb"), a=np.zeros(3)), "npy"),
        "header claims 2**40": (lambda d: (d / "view_000_data.npy").write_bytes(_npy_header_only((2 ** 40,))),
                                "promises"),
        "weight 1e30": (lambda d: np.save(d / "view_001_data.npy", np.full_like(
            np.load(d / "view_001_data.npy"), 1e30)), r"\[0, 1\]"),
        "duplicate column": (_duplicate_first_column, "same column twice"),
        "rgb as strings": (lambda d: (np.save(d / "view_000_rgb.npy", np.full((6, 8, 3), "x")),
                                      _edit_manifest(d, lambda m: m["views"][0]["files"].update(
                                          rgb="view_000_rgb.npy"))), "rgb"),
        "link outside": (_link_outside, "outside the operator directory"),
        "negative depth": (lambda d: (np.save(d / "view_000_depth.npy", np.full((6, 8), -1.0, np.float32)),
                                      _edit_manifest(d, lambda m: m["views"][0]["files"].update(
                                          depth="view_000_depth.npy"))), r"rendering 'depth' must lie in \[0, inf\]"),
    }


def _npy_header_only(shape):
    """The bytes of a float32 .npy header for ``shape`` with no data after it."""
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f4", "fortran_order": False, "shape": shape})
    return buf.getvalue()


def _duplicate_first_column(d: Path):
    """Make the first row with two entries list its first column twice (nnz unchanged)."""
    ind = np.load(d / "view_000_indices.npy")
    ptr = np.load(d / "view_000_indptr.npy")
    r = int(np.flatnonzero(np.diff(ptr) >= 2)[0])
    ind[ptr[r] + 1] = ind[ptr[r]]
    np.save(d / "view_000_indices.npy", ind)


def _link_outside(d: Path):
    outside = d.parent / "elsewhere.npy"
    np.save(outside, np.load(d / "view_000_data.npy"))
    (d / "view_000_data.npy").unlink()
    (d / "view_000_data.npy").symlink_to(outside)


@pytest.mark.parametrize("name", list(_corruptions()))
@pytest.mark.parametrize("mmap", [True, False])
def test_corrupted_directory_gives_clear_error(rng, tmp_path, name, mmap):
    d = _saved(rng, tmp_path)
    corrupt, match = _corruptions()[name]
    corrupt(d)
    with pytest.raises(FormatError, match=match):
        OperatorStack.load(d, mmap=mmap)


def test_load_of_non_directory(tmp_path):
    with pytest.raises(FormatError, match="not a directory"):
        OperatorStack.load(tmp_path / "nope")
    (tmp_path / "file").write_text("x")
    with pytest.raises(FormatError, match="not a directory"):
        OperatorStack.load(tmp_path / "file")


# -- the stack's passes, view by view -------------------------------------------
def _built_stack():
    from render_reference import random_scene

    from seed2gs_inverse.raster import build_operator

    cams = [Camera.look_at([0.2 + 0.3 * k, -0.6, -4.0], [0, 0, 0], [0, -1, 0], 48, 24 + 4 * k, 20, name=f"c{k}")
            for k in range(3)]
    scene = random_scene(5, n=120, cam=cams[0])
    return OperatorStack([build_operator(scene, c) for c in cams])


@pytest.mark.parametrize("direct", [True, False])
def test_stack_passes_bit_identical_to_the_stacked_matrix(rng, monkeypatch, direct):
    """Products run view by view (no stacked copy) yet equal the stacked matrix's passes bit for bit.

    The adjoint sums two runs of views (see ``_passes``): it equals the stacked pass over
    each run's rows, added. ``direct=False`` forces the public per-view fallback (used when scipy lacks its private kernels):
    the forward pass stays bit-identical (row by row), the adjoint sums per view (close, not equal).
    """
    from seed2gs_inverse.operators import _passes

    if not direct:
        monkeypatch.setattr(_passes, "_KERNELS", False)
    stack = _built_stack()
    q = rng.random(stack.n_gaussians).astype(np.float32)
    r = rng.random(stack.shape[0]).astype(np.float32)
    fwd, adj = stack.matvec(q), stack.rmatvec(r)
    assert stack._stacked is None  # nothing was stacked
    A = stack.stacked()
    assert fwd.dtype == adj.dtype == np.float32
    np.testing.assert_array_equal(fwd, A @ q)
    if direct:
        # the adjoint: the stacked matrix's pass over each of the two runs of views, then their sum
        first, second = _passes._halves([v.W for v in stack])
        cut = int(stack.row_offsets()[second.start])
        want = A[:cut].T @ r[:cut] + A[cut:].T @ r[cut:]
        np.testing.assert_array_equal(adj, want)
        np.testing.assert_array_equal(stack.T @ r, want)
    np.testing.assert_allclose(adj, A.T.astype(np.float64) @ r.astype(np.float64), rtol=1e-5)
    # float64 vectors accumulate in float64, as scipy does for the stacked matrix
    np.testing.assert_array_equal(stack.matvec(q.astype(np.float64)), A @ q.astype(np.float64))
    np.testing.assert_allclose(stack.rmatvec(r.astype(np.float64)), A.T @ r.astype(np.float64), rtol=1e-12)
    # blocks of vectors
    Q = rng.random((stack.n_gaussians, 2)).astype(np.float32)
    R = rng.random((stack.shape[0], 3)).astype(np.float32)
    np.testing.assert_allclose(stack @ Q, A.toarray().astype(np.float64) @ Q, rtol=1e-5)
    np.testing.assert_allclose(stack.T @ R, A.toarray().T.astype(np.float64) @ R, rtol=1e-5)
    # the rendered alpha: the stacked matrix's pass over ones
    np.testing.assert_array_equal(stack.row_sums(), A @ np.ones(stack.n_gaussians, np.float32))


def test_solve_makes_no_stacked_copy(rng):
    from seed2gs_inverse.solvers import available_methods, solve

    stack = _built_stack()
    masks = [rng.random(v.image_shape) > 0.5 for v in stack]
    for m in available_methods():
        solve(stack, masks, method=m)
    assert stack._stacked is None and stack._stacked_T is None


def test_stack_passes_are_the_same_on_one_thread_or_two(rng, monkeypatch):
    """The passes' results do not depend on the threads (Dask workers run one): bit for bit."""
    from seed2gs_inverse.operators import _passes

    stack = _built_stack()
    q = rng.random(stack.n_gaussians).astype(np.float32)
    r = rng.random(stack.shape[0]).astype(np.float32)
    first, second = _passes._halves([v.W for v in stack])
    assert len(first) and len(second)
    got = {}
    from seed2gs_inverse import _threads

    for threads in (1, 2):
        monkeypatch.setattr(_threads, "n_threads", lambda t=threads: t)
        monkeypatch.setattr(_passes, "PARALLEL_MIN_NNZ", 0)  # the small test stack goes parallel too
        got[threads] = (stack.matvec(q), stack.rmatvec(r))
    np.testing.assert_array_equal(got[1][0], got[2][0])
    np.testing.assert_array_equal(got[1][1], got[2][1])
    assert _threads._pool is not None  # the two-thread run used the pool
    monkeypatch.undo()
    monkeypatch.setenv("NUMBA_NUM_THREADS", "1")  # as batch_client sets it in each worker
    assert _threads.n_threads() == 1
    monkeypatch.setenv("NUMBA_NUM_THREADS", "2")
    assert _threads.n_threads() == 2


def _parallel_pass_in_child(conn, stack):
    conn.send(stack.rmatvec(np.ones(stack.shape[0], np.float32)))  # the patched module came with the fork


def test_a_forked_child_starts_its_own_pass_thread(rng, monkeypatch):
    """After a fork the parent's pool thread does not exist in the child: the child must not wait on it."""
    import multiprocessing as mp

    from seed2gs_inverse import _threads
    from seed2gs_inverse.operators import _passes

    monkeypatch.setattr(_threads, "n_threads", lambda: 2)
    monkeypatch.setattr(_passes, "PARALLEL_MIN_NNZ", 0)
    stack = _built_stack()
    want = stack.rmatvec(np.ones(stack.shape[0], np.float32))
    assert _threads._pool is not None
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe()
    p = ctx.Process(target=_parallel_pass_in_child, args=(child, stack))  # forked: nothing pickled
    p.start()
    try:
        assert parent.poll(30), "the child's pass hung"
        np.testing.assert_array_equal(parent.recv(), want)
    finally:
        p.join(5)
        if p.is_alive():
            p.kill()


def test_run_both_nested_in_a_second_half_runs_in_turn(monkeypatch):
    """A second half that itself splits work must not wait on the pool's one (busy) thread."""
    from seed2gs_inverse import _threads

    monkeypatch.setattr(_threads, "n_threads", lambda: 2)
    done = []

    def inner(k):
        done.append(("inner", k))

    def outer(k):
        if k == 1:
            _threads.run_both(inner)  # would deadlock if it queued behind itself
        done.append(("outer", k))

    import threading

    t = threading.Thread(target=_threads.run_both, args=(outer,), daemon=True)
    t.start()
    t.join(30)
    assert not t.is_alive(), "nested run_both hung"
    assert sorted(done) == [("inner", 0), ("inner", 1), ("outer", 0), ("outer", 1)]


def test_columns_and_on_columns_against_the_dense_matrix(rng):
    s = OperatorStack([_random_view(rng, 60, 6 + i, 8, density=0.02) for i in range(3)], fingerprint="abc")
    dense = np.vstack([v.W.toarray() for v in s])
    seen = np.flatnonzero(np.vstack([np.diff(v.W.tocsc().indptr) for v in s]).sum(0) > 0)  # stored columns
    np.testing.assert_array_equal(s.columns(), seen)
    assert s.columns().dtype == np.int64 and not s.columns().flags.writeable
    assert s.columns() is s.columns()  # cached
    # a superset of the stored columns: one column no view stores, kept as an empty column
    extra = np.setdiff1d(np.arange(60), seen)[:1]
    assert extra.size and seen.size > 1
    cols = np.union1d(seen, extra)
    local = s.on_columns(cols)
    assert local.shape == (s.n_pixels, cols.size) and local.fingerprint is None
    np.testing.assert_array_equal(np.vstack([v.W.toarray() for v in local]), dense[:, cols])
    q = rng.random(60).astype(np.float32)
    r = rng.random(s.n_pixels).astype(np.float32)
    np.testing.assert_array_equal(local.matvec(q[cols]), s.matvec(q))  # bit for bit: the rows keep their order
    np.testing.assert_array_equal(local.rmatvec(r), s.rmatvec(r)[cols])
    assert s.on_columns(cols.copy()) is local  # the last restriction is kept
    got_cols, got = s.compact()  # the last restriction, with its columns
    assert got is local and np.array_equal(got_cols, cols)
    assert s.on_columns(np.arange(60)) is not local
    fresh = OperatorStack(list(s.views))  # nothing restricted yet: the stored columns
    cols2, small = fresh.compact()
    np.testing.assert_array_equal(cols2, seen)
    np.testing.assert_array_equal(small.matvec(q[cols2]), s.matvec(q))
    assert fresh.compact()[1] is small
    for bad, match in [(seen[1:], "every column"), (cols[::-1], "ascending"), (np.r_[cols, 60], "ascending"),
                       (cols.astype(float), "integer"), (cols[None], "1-D")]:
        with pytest.raises(ValidationError, match=match):
            s.on_columns(bad)
