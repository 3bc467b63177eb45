"""build_operator(): W(c) entry by entry against the brute-force reference, identities, options."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from render_reference import random_scene, reference_render
from seed2gs_inverse.camera import Camera
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.operators import ViewOperator
from seed2gs_inverse.operators import dottest
from seed2gs_inverse.raster import FrozenScene, build_operator, cone_cull, project_gaussians, render


def _camera(i):
    if i % 2 == 0:
        return Camera.look_at([0.2, -0.6, -4.0], [0, 0, 0], [0, -1, 0], 48, 52, 41)
    base = Camera.look_at([-1.0, 0.3, -3.6], [0, 0.1, 0], [0, -1, 0], 52, 47, 38)
    return Camera(47, 38, 41.0, 44.0, 25.7, 16.2, base.world_to_camera, near=0.05)


@pytest.fixture(scope="module")
def scene_and_camera():
    cam = _camera(0)
    return random_scene(11, n=150, sh_degree=3, cam=cam), cam


@pytest.mark.parametrize("seed,mode", [(20, "classic"), (21, "classic"), (22, "antialiased")])
def test_W_matches_brute_force_entry_by_entry(seed, mode):
    cam = _camera(seed)
    scene = random_scene(seed, n=90, cam=cam)
    rgb, alpha, depth, W_ref = reference_render(scene, cam, mode)
    op = build_operator(scene, cam, mode=mode)
    assert isinstance(op, ViewOperator)
    W = op.W
    assert W.shape == (cam.height * cam.width, len(scene))
    dense = W.toarray()
    # same sparsity pattern, values to float32 rounding
    np.testing.assert_array_equal(dense != 0, W_ref != 0)
    np.testing.assert_allclose(dense, W_ref, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(op.rendering.rgb, rgb, atol=1e-5)
    np.testing.assert_allclose(op.rendering.alpha, alpha, atol=1e-5)
    np.testing.assert_allclose(op.rendering.depth, depth, atol=1e-5)
    dottest(op, rng=seed)


@pytest.mark.parametrize("i", [0, 1])
def test_identities_and_dot_test(i, rng):
    cam = _camera(i)
    scene = random_scene(30 + i, n=140, cam=cam)
    op = build_operator(scene, cam)
    W, r = op.W, op.rendering
    p = project_gaussians(scene, cam)
    n = len(scene)
    np.testing.assert_allclose(W @ np.ones(n, np.float32), r.alpha.ravel(), atol=2e-6)
    np.testing.assert_allclose(W @ p.colors, r.rgb.reshape(-1, 3), atol=2e-6)
    np.testing.assert_allclose(W @ p.depths, (r.depth * r.alpha).ravel(), rtol=2e-6, atol=2e-6)
    # rendering with a background is W @ colors + (1 - W @ 1) * background
    bg = np.array([0.3, 0.1, 0.7])
    rb = render(scene, cam, background=bg)
    np.testing.assert_allclose((W @ p.colors + (1 - W @ np.ones(n))[:, None] * bg).reshape(rb.rgb.shape),
                               rb.rgb, atol=2e-6)
    for seed in range(3):
        assert dottest(op, rtol=1e-6, rng=seed)  # the ViewOperator's matvec / rmatvec
    assert (W @ np.ones(n)).max() > 0.5


def test_csr_layout(scene_and_camera):
    scene, cam = scene_and_camera
    op = build_operator(scene, cam)
    W = op.W
    assert sp.isspmatrix_csr(W) or W.format == "csr"
    assert W.dtype == np.float32 and W.indices.dtype == np.int32 and W.indptr.dtype == np.int32
    W.check_format(full_check=True)
    assert np.all(W.data > 0) and np.all(W.data <= 0.99 + 1e-7)
    np.testing.assert_array_equal(np.diff(W.indptr), op.rendering.n_contrib.ravel())
    # Rows are in depth order; scipy must not assume sorted columns.
    rows_sorted = all(np.all(np.diff(W.indices[a:b]) > 0) for a, b in zip(W.indptr[:-1], W.indptr[1:]))
    assert not rows_sorted and not W.has_sorted_indices
    Ws = W.sorted_indices()
    np.testing.assert_array_equal(Ws.toarray(), W.toarray())
    # the operator's camera and shape
    assert op.camera is cam and op.image_shape == cam.image_shape


def test_scale_uses_scaled_camera(scene_and_camera):
    scene, cam = scene_and_camera
    op = build_operator(scene, cam, scale=0.5)
    small = cam.scaled(0.5)
    assert op.image_shape == small.image_shape and small.width == 26
    assert op.camera.fx == pytest.approx(small.fx)
    ref = build_operator(scene, small)
    np.testing.assert_array_equal(op.W.toarray(), ref.W.toarray())
    _, alpha, _, W_ref = reference_render(scene, small)
    np.testing.assert_allclose(op.W.toarray(), W_ref, rtol=1e-6, atol=1e-8)


def test_roi_box_and_mask_keep_full_rows(scene_and_camera):
    scene, cam = scene_and_camera
    full = build_operator(scene, cam)
    h, w = cam.image_shape
    box = (5, 7, 33, 30)  # x0, y0, x1, y1, straddling tile borders
    inside = np.zeros((h, w), bool)
    inside[7:30, 5:33] = True
    mask = np.zeros((h, w), bool)
    mask[::3, 1::2] = True
    for roi, sel in ((box, inside), (mask, mask)):
        op = build_operator(scene, cam, roi=roi)
        assert op.W.shape == full.W.shape
        Wd, Fd = op.W.toarray(), full.W.toarray()
        rows = sel.ravel()
        np.testing.assert_array_equal(Wd[rows], Fd[rows])
        assert not Wd[~rows].any() and np.all(np.diff(op.W.indptr).reshape(h, w)[~sel] == 0)
        np.testing.assert_array_equal(op.rendering.alpha[sel], full.rendering.alpha[sel])
        assert not op.rendering.alpha[~sel].any()
        assert op.W.nnz < full.W.nnz


def test_min_weight_drops_small_entries_with_bound(scene_and_camera):
    scene, cam = scene_and_camera
    full = build_operator(scene, cam)
    mw = 0.02
    op = build_operator(scene, cam, min_weight=mw)
    F, Wd = full.W.toarray(), op.W.toarray()
    np.testing.assert_array_equal(Wd, np.where(F >= mw, F, 0))
    assert 0 < op.W.nnz < full.W.nnz
    dropped = ((F > 0) & (F < mw)).sum(axis=1)
    gap = op.rendering.alpha.ravel() - Wd.sum(axis=1)
    assert np.all(gap >= -1e-6) and np.all(gap <= dropped * mw + 1e-6)
    # the rendering of the pass is unaffected by min_weight
    np.testing.assert_array_equal(op.rendering.rgb, full.rendering.rgb)


def test_bad_arguments(scene_and_camera):
    scene, cam = scene_and_camera
    h, w = cam.image_shape
    for roi in [(w, 0, w + 5, h), (-9, -9, 0, 5), (0, h + 1, 5, h + 9), (10, 10, 10, 20), (5, 0, 4, 3),
                (0, 0, 5), (0.5, 0, 5, 5), (0, 0, np.inf, 5), "all"]:
        with pytest.raises(ValidationError, match="roi"):
            build_operator(scene, cam, roi=roi)
    # a box reaching past the border is clipped to the image
    clipped = build_operator(scene, cam, roi=(-5, -3, 12, 9))
    inside = build_operator(scene, cam, roi=(0, 0, 12, 9))
    np.testing.assert_array_equal(clipped.W.toarray(), inside.W.toarray())
    with pytest.raises(ValidationError, match="roi mask"):
        build_operator(scene, cam, roi=np.ones((h + 1, w), bool))
    with pytest.raises(ValidationError, match="roi mask"):
        build_operator(scene, cam, roi=np.ones((h, w), np.float32))
    with pytest.raises(ValidationError, match="roi mask selects no pixel"):  # as a box outside the image
        build_operator(scene, cam, roi=np.zeros((h, w), bool))
    for bg in ("red", [1, "x", 0], {"r": 1}):
        with pytest.raises(ValidationError, match="background"):
            render(scene, cam, background=bg)
    for scale in (0, -1, float("nan"), "half"):
        with pytest.raises(ValidationError, match="scale"):
            build_operator(scene, cam, scale=scale)
    for mw in (-0.1, 2.0, float("nan"), "x"):
        with pytest.raises(ValidationError, match="min_weight"):
            build_operator(scene, cam, min_weight=mw)
    with pytest.raises(ValidationError, match="empty"):
        build_operator(scene.subset(np.zeros(len(scene), bool)), cam)


def test_view_that_sees_nothing(scene_and_camera):
    scene, cam = scene_and_camera
    scene = scene.subset(np.arange(len(scene) - 12))  # only those in front of cam
    away = Camera.look_at(cam.center, 2 * cam.center, [0, -1, 0], 40, 20, 18)  # looks away
    op = build_operator(scene, away)
    assert op.W.nnz == 0 and op.W.shape == (18 * 20, len(scene))
    assert not op.rendering.alpha.any() and not op.rendering.depth.any()
    np.testing.assert_array_equal(render(scene, away, background=[0.1, 0.2, 0.3]).rgb,
                                  np.broadcast_to(np.float32([0.1, 0.2, 0.3]), (18, 20, 3)))


def _same_csr(A, B):
    """Bit-identical CSR arrays (values, column order within rows, pointers)."""
    np.testing.assert_array_equal(A.indptr, B.indptr)
    np.testing.assert_array_equal(A.indices, B.indices)
    np.testing.assert_array_equal(A.data, B.data)
    assert A.shape == B.shape


@pytest.mark.parametrize("per_pair", [0, 20, 256])
def test_logged_fill_equals_second_pass(scene_and_camera, monkeypatch, per_pair):
    """W assembled from the first pass's log (room for all, some or no tiles) is the two-pass W."""
    import importlib

    render_mod = importlib.import_module("seed2gs_inverse.raster.rasterize")
    scene, cam = scene_and_camera
    calls = []
    real_composite = render_mod._kernels.composite

    def spy(tiles, splats, width, height, roi, background, min_weight, fill, *rest):
        if fill:  # the second pass, over these tiles
            calls.append(len(tiles.tile_order))
        return real_composite(tiles, splats, width, height, roi, background, min_weight, fill, *rest)

    monkeypatch.setattr(render_mod._kernels, "composite", spy)
    monkeypatch.setattr(render_mod, "_SCRATCH_PER_PAIR", per_pair)
    for roi in (None, (5, 7, 33, 30)):
        op = build_operator(scene, cam, roi=roi)
        # Independent of the assembly: the brute-force reference, entry by entry.
        _, _, _, W_ref = reference_render(scene, cam)
        if roi is not None:
            keep = np.zeros(cam.image_shape, bool)
            keep[7:30, 5:33] = True
            W_ref = W_ref * keep.ravel()[:, None]
        np.testing.assert_array_equal(op.W.toarray() != 0, W_ref != 0)
        np.testing.assert_allclose(op.W.toarray(), W_ref, rtol=1e-6, atol=1e-8)
        np.testing.assert_array_equal(np.diff(op.W.indptr), op.rendering.n_contrib.ravel())
        op.W.check_format(full_check=True)
    # per_pair 0: every tile with entries takes the second pass; 256 (a pair
    # logs at most 16x16 weights): none does; 20: some do (big splats here).
    n_tiles = 4 * 3  # 52x41 pixels in 16x16 tiles
    if per_pair == 0:
        assert len(calls) == 2 and calls[0] == n_tiles
    elif per_pair == 256:
        assert calls == []
    else:
        assert len(calls) == 2 and 0 < calls[0] < n_tiles
    monkeypatch.setattr(render_mod, "_SCRATCH_PER_PAIR", 0)
    two_pass = build_operator(scene, cam, min_weight=0.01)
    monkeypatch.setattr(render_mod, "_SCRATCH_PER_PAIR", per_pair)
    _same_csr(build_operator(scene, cam, min_weight=0.01).W, two_pass.W)


def test_subset_equals_operator_of_the_subset_scene(scene_and_camera):
    """The no-copy subset path gives exactly the W of scene.subset(idx) with columns mapped back."""
    scene, cam = scene_and_camera
    n = len(scene)
    idx = np.flatnonzero(np.random.default_rng(3).random(n) < 0.6)
    plain = build_operator(scene.subset(idx), cam, roi=(3, 2, 40, 35), min_weight=0.003)
    mapped = sp.csr_matrix((plain.W.data, idx[plain.W.indices].astype(np.int32), plain.W.indptr), shape=(
        plain.W.shape[0], n))
    for sel in (idx, np.isin(np.arange(n), idx), idx[::-1].copy(), np.concatenate([idx, idx[:5]])):
        fast = build_operator(scene, cam, roi=(3, 2, 40, 35), min_weight=0.003, subset=sel)
        _same_csr(fast.W, mapped)
        np.testing.assert_array_equal(fast.rendering.rgb, plain.rendering.rgb)
        np.testing.assert_array_equal(fast.rendering.depth, plain.rendering.depth)
    assert not np.asarray(fast.W[:, np.setdiff1d(np.arange(n), idx)].sum(axis=0)).any()
    assert fast.W.nnz > 0
    # the full index set is the plain operator
    _same_csr(build_operator(scene, cam, subset=np.arange(n)).W, build_operator(scene, cam).W)
    # an empty subset renders nothing
    empty = build_operator(scene, cam, subset=np.zeros(0, np.int64))
    assert empty.W.nnz == 0 and not empty.rendering.alpha.any()


def test_bad_subset(scene_and_camera):
    scene, cam = scene_and_camera
    n = len(scene)
    for bad in (np.array([0, n]), np.array([-1, 2]), np.ones(n + 1, bool), np.zeros((2, 2), np.int64),
                np.array([0.5, 1.0])):
        with pytest.raises(ValidationError, match="subset"):
            build_operator(scene, cam, subset=bad)
    # integer 0/1 labels would be read as the indices {0, 1}
    labels = (np.arange(n) % 2).astype(np.int64)
    with pytest.raises(ValidationError, match="look like a 0/1 mask"):
        build_operator(scene, cam, subset=labels)
    np.testing.assert_array_equal(build_operator(scene, cam, subset=labels.astype(bool)).W.toarray(),
                                  build_operator(scene, cam, subset=np.flatnonzero(labels)).W.toarray())


@pytest.mark.parametrize("sh_degree", [0, 2])
def test_frozen_scene_gives_identical_results(sh_degree):
    """Activations computed once per scene (FrozenScene) or per call: same bits, and the brute-force W."""
    cam = _camera(0)
    scene = random_scene(40 + sh_degree, n=120, sh_degree=sh_degree, cam=cam)
    idx = np.arange(0, len(scene), 2)
    plain = [build_operator(scene, cam, roi=(2, 3, 45, 38)), build_operator(scene, cam, subset=idx),
             build_operator(scene, _camera(1))]
    plain_render = render(scene, cam, mode="antialiased")
    plain_proj = project_gaussians(scene, cam)
    frozen = FrozenScene(scene)
    assert len(frozen) == len(scene) and FrozenScene(frozen).scene is scene
    fast = [build_operator(frozen, cam, roi=(2, 3, 45, 38)), build_operator(frozen, cam, subset=idx),
            build_operator(frozen, _camera(1))]
    fast_render = render(frozen, cam, mode="antialiased")
    fast_proj = project_gaussians(frozen, cam)
    for a, b in zip(plain, fast):
        _same_csr(a.W, b.W)
        np.testing.assert_array_equal(a.rendering.rgb, b.rendering.rgb)
        np.testing.assert_array_equal(a.rendering.depth, b.rendering.depth)
        dottest(b, rng=0)
    np.testing.assert_array_equal(plain_render.rgb, fast_render.rgb)
    for a, b in zip(plain_proj, fast_proj):
        np.testing.assert_array_equal(a, b)
    for roi, far in ((None, None), ((3, 4, 30, 20), 5.0)):
        np.testing.assert_array_equal(cone_cull(scene, cam, roi, far), cone_cull(frozen, cam, roi, far))
    _, _, _, W_ref = reference_render(scene, _camera(1))
    np.testing.assert_allclose(fast[2].W.toarray(), W_ref, rtol=1e-6, atol=1e-8)
    rgb_ref, _, _, _ = reference_render(scene, cam, "antialiased")
    np.testing.assert_allclose(fast_render.rgb, rgb_ref, atol=1e-5)
    # the frozen activations belong to that scene object: another one is computed afresh
    other = dataclasses.replace(scene, opacity_logits=np.full(len(scene), -10.0))
    assert build_operator(other, cam).W.nnz == 0
    with pytest.raises(ValidationError, match="GaussianScene"):
        FrozenScene("scene.ply")
    with pytest.raises(ValidationError, match="GaussianScene or FrozenScene"):
        render("scene.ply", cam)


@pytest.mark.parametrize("per_pair", [0, 20])
def test_results_do_not_depend_on_the_thread_schedule(per_pair, monkeypatch):
    """Tiles claimed dynamically (``_kernels._fetch_add``) give the bits of one thread taking them all.

    One worker visits the tiles in order; as many workers as threads
    interleave them as the machine happens to schedule. A tile that wrote
    another's outputs, or a tile claimed twice or never, would show as a
    difference (and the brute-force tests above check the values).
    """
    import importlib

    import numba

    render_mod = importlib.import_module("seed2gs_inverse.raster.rasterize")
    monkeypatch.setattr(render_mod, "_SCRATCH_PER_PAIR", per_pair)  # 0: every tile takes the second pass
    cam = Camera.look_at([0.2, -0.6, -4.0], [0, 0, 0], [0, -1, 0], 48, 160, 120)
    scene = random_scene(31, n=1500, sh_degree=1, cam=cam)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = build_operator(scene, cam)
    finally:
        numba.set_num_threads(threads)
    for _ in range(3):
        many = build_operator(scene, cam)
        _same_csr(one.W, many.W)
        for name in ("rgb", "alpha", "depth", "n_contrib"):
            np.testing.assert_array_equal(getattr(one.rendering, name), getattr(many.rendering, name))
    assert one.W.nnz > 1000 and (120 // 16 + 1) * (160 // 16) > threads


def test_fetch_add_hands_out_every_index_once():
    """The atomic counter of the dynamic schedule: n claims over all threads give 0..n-1 exactly once."""
    from numba import njit, prange

    from seed2gs_inverse.raster import _kernels

    @njit(parallel=True)
    def claim_all(n, n_workers):
        counter = np.zeros(1, np.int64)
        seen = np.zeros(n, np.int64)
        for _w in prange(n_workers):
            while True:
                i = _kernels._fetch_add(counter, 1)
                if i >= n:
                    break
                seen[i] += 1
        return seen, _kernels._fetch_add(counter, 0)  # read through the atomic too

    seen, final = claim_all(100_000, _kernels.workers(100_000))
    assert np.all(seen == 1)
    assert final == 100_000 + _kernels.workers(100_000)  # each worker's last claim overshoots once
