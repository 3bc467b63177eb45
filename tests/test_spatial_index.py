"""raster.spatial: the index's view candidates contain cone_cull's full pass, and culling, rendering and operators
of a FrozenScene through the index equal the pass over every Gaussian; ball against a brute-force distance test."""

from __future__ import annotations

import numpy as np
import pytest

from seed2gs_inverse.camera import Camera
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.raster import FrozenScene, Renderer, build_operator, cone_cull, render, spatial
from seed2gs_inverse.raster.spatial import SpatialIndex
from seed2gs_inverse.scene import GaussianScene

W_IMG, H_IMG = 64, 48
ROIS = [None, (10, 5, 40, 30), (-8, -8, 6, 6), (58, 40, 80, 60), (0, 0, W_IMG, 1), (63, 0, 64, 48)]
FARS = [None, 4.0, 1.5, np.inf]


@pytest.fixture(autouse=True)
def small_chunks(monkeypatch):
    """Chunks of 4 Gaussians, so that small scenes have many chunks whose tests decide something."""
    monkeypatch.setattr(spatial, "_CHUNK", 4)


def _cameras():
    out = Camera.look_at([0.5, -1.0, -5.0], [0, 0, 0], [0, -1, 0], 50, W_IMG, H_IMG)
    inside = Camera.look_at([0.2, 0.1, 0.3], [3.0, 1.0, 2.0], [0, -1, 0], 70, W_IMG, H_IMG)
    # An off-centre principal point and unequal focal lengths: the clamp limits differ per side.
    pp = Camera(W_IMG, H_IMG, 40.0, 70.0, 10.0, 40.0, out.world_to_camera)
    return {"outside": out, "inside": inside, "off_centre": pp}


def _in_camera_frame(cam, v):
    """World points whose view-frame coordinates are ``v``."""
    return (np.asarray(v, np.float64) - cam.translation) @ cam.rotation


def _adversarial_scene(rng, cams):
    """A cloud around the origin plus Gaussians that stress the bound (see the comments)."""
    parts = [(rng.normal(0, 2.0, (1500, 3)), rng.normal(-2.5, 1.0, (1500, 3)))]
    for cam in cams.values():
        # Huge Gaussians whose centres lie far outside the view; their footprints reach into it.
        lat = rng.uniform(8, 30, (80, 1)) * rng.choice([-1, 1], (80, 2))
        v = np.column_stack([lat, rng.uniform(2, 10, 80)])
        parts.append((_in_camera_frame(cam, v), np.log(rng.uniform(1, 15, (80, 3)))))
        # Centres at, just in front of and just behind the near plane, and behind the camera.
        v = np.column_stack([rng.normal(0, 0.3, (120, 2)),
                             np.r_[np.full(40, cam.near), cam.near + rng.uniform(-1e-3, 1e-3, 40),
                                   rng.uniform(-3, 0, 40)]])
        parts.append((_in_camera_frame(cam, v), rng.normal(-1.0, 1.5, (120, 3))))
        # Off-screen centres at wide angles (the Jacobian is evaluated at the clamp).
        ang = rng.uniform(1.5, 12, (100, 2)) * rng.choice([-1, 1], (100, 2))
        z = rng.uniform(0.05, 6, (100, 1))
        parts.append((_in_camera_frame(cam, np.column_stack([ang * z, z])), rng.normal(-0.5, 1.0, (100, 3))))
    means = np.concatenate([p[0] for p in parts])
    log_scales = np.concatenate([p[1] for p in parts])
    n = len(means)
    return GaussianScene(means, rng.normal(size=(n, 4)), log_scales, rng.normal(1.0, 1.5, n),
                         rng.normal(size=(n, 1, 3)))


@pytest.fixture(scope="module")
def adversarial():
    cams = _cameras()
    return _adversarial_scene(np.random.default_rng(7), cams), cams


def _same_rendering(a, b):
    for name in ("rgb", "alpha", "depth", "n_contrib"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def _same_operator(a, b):
    assert a.W.shape == b.W.shape
    for name in ("indptr", "indices", "data"):
        np.testing.assert_array_equal(getattr(a.W, name), getattr(b.W, name), err_msg=name)
    _same_rendering(a.rendering, b.rendering)


def test_candidates_contain_the_full_pass_and_cone_cull_through_the_index_equals_it(adversarial):
    scene, cams = adversarial
    frozen = FrozenScene(scene)
    pruned = 0
    for name, cam in cams.items():
        for roi in ROIS:
            for far in FARS:
                full = cone_cull(scene, cam, roi, far)
                cand = frozen.spatial.view_candidates(cam, roi, far)
                assert cand.dtype == np.int64 and np.all(np.diff(cand) > 0)
                missing = np.setdiff1d(full, cand)
                assert missing.size == 0, (name, roi, far, missing[:10])
                np.testing.assert_array_equal(cone_cull(frozen, cam, roi, far), full, err_msg=f"{name} {roi} {far}")
                pruned += cand.size < len(scene)
    assert pruned > len(cams) * len(ROIS)  # the chunk tests do drop Gaussians, in most queries


def test_near_cut_and_spare_through_the_index(adversarial):
    scene, cams = adversarial
    frozen = FrozenScene(scene)
    spare = np.zeros(len(scene), bool)
    spare[::5] = True
    for cam in cams.values():
        for near, far in ((3.0, None), (1.0, 6.0)):
            np.testing.assert_array_equal(cone_cull(frozen, cam, (10, 5, 40, 30), far, near, spare),
                                          cone_cull(scene, cam, (10, 5, 40, 30), far, near, spare))


def test_a_bound_without_the_footprint_misses_gaussians(adversarial, monkeypatch):
    """The test can fail: candidates of centres in the view cone alone miss the huge and off-screen Gaussians."""
    scene, cams = adversarial
    monkeypatch.setattr(spatial, "_K_SUPPORT", 0.0)
    monkeypatch.setattr(spatial, "_PAD_PX", 0.0)
    frozen = FrozenScene(scene)
    cam = cams["outside"]
    full = cone_cull(scene, cam, (10, 5, 40, 30))
    assert np.setdiff1d(full, frozen.spatial.view_candidates(cam, (10, 5, 40, 30))).size > 0


@pytest.mark.parametrize("mode", ["classic", "antialiased"])
def test_render_and_operator_through_the_index_equal_the_full_pass(adversarial, mode):
    scene, cams = adversarial
    frozen = FrozenScene(scene)
    mask = np.zeros((H_IMG, W_IMG), bool)
    mask[3:9, 50:64] = True
    mask[40:, :5] = True
    for cam in cams.values():
        _same_rendering(render(frozen, cam, mode=mode), render(scene, cam, mode=mode))
        for roi in (None, (10, 5, 40, 30), (-8, -8, 6, 6), (58, 40, 80, 60), mask):
            _same_operator(build_operator(frozen, cam, roi=roi, mode=mode), build_operator(scene, cam, roi=roi,
                                                                                            mode=mode))
        _same_operator(build_operator(frozen, cam, scale=0.5, mode=mode), build_operator(scene, cam, scale=0.5,
                                                                                         mode=mode))


def test_a_far_copy_of_the_scene_costs_nothing_per_view():
    """A copy 100 units away: no candidate of it, and the same image and W (its columns empty)."""
    rng = np.random.default_rng(2)
    n = 2000
    means = rng.normal(0, 2.0, (n, 3))
    scene = GaussianScene(means, rng.normal(size=(n, 4)), rng.normal(-2.5, 1.0, (n, 3)), rng.normal(1.0, 1.0, n),
                          rng.normal(size=(n, 1, 3)))
    tiled = GaussianScene(np.concatenate([means, means + [100.0, 0.0, 0.0]]), np.tile(scene.quats, (2, 1)),
                          np.tile(scene.log_scales, (2, 1)), np.tile(scene.opacity_logits, 2),
                          np.tile(scene.sh, (2, 1, 1)))
    cam = _cameras()["outside"]
    frozen = FrozenScene(tiled)
    for roi in (None, (10, 5, 40, 30)):
        cand = frozen.spatial.view_candidates(cam, roi)
        assert cand.size <= n and cand.max() < n
    _same_rendering(render(frozen, cam), render(scene, cam))
    a, b = build_operator(frozen, cam, roi=(10, 5, 40, 30)), build_operator(scene, cam, roi=(10, 5, 40, 30))
    assert a.W.shape == (H_IMG * W_IMG, 2 * n)
    np.testing.assert_array_equal(a.W[:, :n].toarray(), b.W.toarray())
    assert a.W[:, n:].nnz == 0


def test_tiny_and_empty_views():
    rng = np.random.default_rng(3)
    cam = _cameras()["outside"]
    for means in ([[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], [[0.3, 0.1, 0.0], [40.0, 0.0, 0.0]]):
        n = len(means)
        scene = GaussianScene(np.array(means), rng.normal(size=(n, 4)), np.full((n, 3), -1.0), np.ones(n),
                              rng.normal(size=(n, 1, 3)))
        frozen = FrozenScene(scene)
        np.testing.assert_array_equal(cone_cull(frozen, cam), cone_cull(scene, cam))
        _same_rendering(render(frozen, cam), render(scene, cam))
        _same_operator(build_operator(frozen, cam), build_operator(scene, cam))
    # Nothing in view: the camera looks away from every Gaussian.
    away = Camera.look_at([0, 0, -5.0], [0, 0, -10.0], [0, -1, 0], 50, W_IMG, H_IMG)
    assert cone_cull(frozen, away).size == 0 and frozen.spatial.view_candidates(away).size == 0
    _same_rendering(render(frozen, away), render(scene, away))
    op = build_operator(frozen, away)
    assert op.W.nnz == 0 and not op.rendering.alpha.any()


def test_ball_against_brute_force():
    rng = np.random.default_rng(11)
    means = np.concatenate([rng.normal(0, 3.0, (3000, 3)), rng.normal(80.0, 1.0, (500, 3))]).astype(np.float32)
    index = SpatialIndex(means, np.zeros(len(means)), chunk=8)
    cases = [([0, 0, 0], 0.0), ([0, 0, 0], 2.5), ([1.0, -2.0, 0.5], 6.0), ([80, 80, 80], 3.0),
             ([500, 0, 0], 10.0), ([0, 0, 0], 1e6), (means[17], 0.0)]
    for center, radius in cases:
        d = means.astype(np.float64) - np.asarray(center, np.float64)
        want = np.flatnonzero((d * d).sum(axis=1) <= radius * radius)
        got = index.ball(center, radius)
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, want, err_msg=f"{center} {radius}")
    assert index.ball(means[17], 0.0).size >= 1  # a centre on the sphere's boundary counts


def test_index_structure():
    rng = np.random.default_rng(5)
    means = np.concatenate([rng.normal(0, 1.0, (700, 3)), rng.normal(50, 5.0, (300, 3))]).astype(np.float32)
    smax = rng.uniform(0, 2, len(means))
    index = SpatialIndex(means, smax, chunk=16)
    np.testing.assert_array_equal(np.sort(index.perm), np.arange(len(means)))
    sizes = np.diff(index.starts)
    assert index.starts[0] == 0 and index.starts[-1] == len(means) and sizes.min() >= 1 and sizes.max() <= 16
    lo = index.chunks.centre - index.chunks.half
    hi = index.chunks.centre + index.chunks.half
    for c in range(len(sizes)):
        members = index.perm[index.starts[c]:index.starts[c + 1]]
        assert np.all(means[members] >= lo[c] - 1e-5) and np.all(means[members] <= hi[c] + 1e-5)
        assert index.chunks.smax[c] == smax[members].max()
    # No chunk mixes the two clusters 50 units apart.
    far = index.perm >= 700
    assert all(np.unique(far[index.starts[c]:index.starts[c + 1]]).size == 1 for c in range(len(sizes)))


def test_frozen_scene_builds_the_index_once_on_first_use(adversarial):
    scene, cams = adversarial
    frozen = FrozenScene(scene)
    assert frozen._spatial is None
    cone_cull(scene, cams["outside"])  # a plain scene has no index to build
    index = frozen.spatial
    assert isinstance(index, SpatialIndex) and frozen.spatial is index and len(index) == len(scene)
    render(frozen, cams["inside"])
    assert frozen.spatial is index
    # A Renderer made from the frozen scene shares it (activations and index), not a copy.
    renderer = Renderer(frozen)
    assert renderer.frozen is frozen and renderer.scene is scene
    _same_rendering(renderer.render(cams["outside"]), render(scene, cams["outside"]))


def test_bad_input_is_refused():
    means = np.zeros((4, 3), np.float32)
    with pytest.raises(ValidationError, match="means"):
        SpatialIndex(np.zeros((0, 3), np.float32), np.zeros(0))
    with pytest.raises(ValidationError, match="non-finite"):
        SpatialIndex(np.array([[0, 0, np.nan]] * 4, np.float32), np.zeros(4))
    with pytest.raises(ValidationError, match="smax"):
        SpatialIndex(means, -np.ones(4))
    with pytest.raises(ValidationError, match="chunk"):
        SpatialIndex(means, np.zeros(4), chunk=0)
    index = SpatialIndex(means, np.zeros(4))
    cam = _cameras()["outside"]
    with pytest.raises(ValidationError, match="radius"):
        index.ball([0, 0, 0], -1.0)
    with pytest.raises(ValidationError, match="center"):
        index.ball([0, 0], 1.0)
    with pytest.raises(ValidationError, match="roi"):
        index.view_candidates(cam, (5, 5, 5, 9))
    with pytest.raises(ValidationError, match="far"):
        index.view_candidates(cam, None, float("nan"))
    with pytest.raises(ValidationError, match="camera"):
        index.view_candidates("cam")
