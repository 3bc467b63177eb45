"""raster.cone_cull: the parallel kernel against the bound in numpy, and what culling guarantees."""

from __future__ import annotations

import numpy as np
import pytest

from seed2gs_inverse.camera import Camera
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.operators import dottest
from seed2gs_inverse.raster import FrozenScene, Renderer, build_operator, cone_cull
from seed2gs_inverse.scene import GaussianScene


def _numpy_cull(scene, camera, roi, smax, far, near=None, spare=None):
    """The footprint bound written out with numpy (the kernel must agree)."""
    h, w = camera.image_shape
    x0, y0, x1, y1 = (0, 0, w, h) if roi is None else roi
    axis = np.array([(0.5 * (x0 + x1) - camera.cx) / camera.fx, (0.5 * (y0 + y1) - camera.cy) / camera.fy, 1.0])
    axis /= np.linalg.norm(axis)
    v = scene.means.astype(np.float64) @ camera.rotation.T + camera.translation
    x, y, z = v.T
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.clip(x / z, -(camera.cx / camera.fx + 0.15 * w / camera.fx),
                     (w - camera.cx) / camera.fx + 0.15 * w / camera.fx)
        ty = np.clip(y / z, -(camera.cy / camera.fy + 0.15 * h / camera.fy),
                     (h - camera.cy) / camera.fy + 0.15 * h / camera.fy)
        J = np.zeros((len(z), 2, 3))
        J[:, 0, 0], J[:, 0, 2] = camera.fx / z, -camera.fx * tx / z
        J[:, 1, 1], J[:, 1, 2] = camera.fy / z, -camera.fy * ty / z
        lmax = np.linalg.eigvalsh(J[z > 0] @ J[z > 0].transpose(0, 2, 1))[:, -1]
        lam = np.full(len(z), np.nan)
        lam[z > 0] = lmax
        r = np.sqrt(2 * np.log(255)) * np.sqrt(lam * smax ** 2 + 0.3) + 2
        mx, my = camera.fx * x / z + camera.cx, camera.fy * y / z + camera.cy
        keep = (z >= camera.near) & (mx + r >= x0) & (mx - r <= x1) & (my + r >= y0) & (my - r <= y1)
    if far is not None:
        keep &= v @ axis - 3 * smax <= far
    if near is not None:
        keep &= (v @ axis >= near) | (spare if spare is not None else False)
    return np.flatnonzero(keep)


@pytest.mark.parametrize("roi,far,near", [(None, None, None), ((10, 5, 40, 30), None, None),
                                          ((0, 0, 20, 48), 4.5, None), ((10, 5, 40, 30), None, 4.0),
                                          ((0, 0, 20, 48), 6.0, 3.5)])
def test_cone_cull_matches_formula(rng, roi, far, near):
    n = 4000
    scene = GaussianScene(rng.normal(0, 2.0, (n, 3)), rng.normal(size=(n, 4)), rng.normal(-2.5, 1.0, (n, 3)),
                          np.zeros(n), rng.normal(size=(n, 1, 3)))
    cam = Camera.look_at([0.5, -1.0, -5.0], [0, 0, 0], [0, -1, 0], 50, 64, 48)
    got = cone_cull(scene, cam, roi, far, near)
    want = _numpy_cull(scene, cam, roi, scene.scales.max(axis=1).astype(np.float64), far, near)
    np.testing.assert_array_equal(got, want)
    assert got.dtype == np.int64 and 0 < got.size < n
    if near is not None:  # the cut is real: some Gaussians of the cone lie in front of it
        assert got.size < cone_cull(scene, cam, roi, far).size
    np.testing.assert_array_equal(cone_cull(FrozenScene(scene), cam, roi, far, near), got)


def test_near_cut_spares_what_it_is_told_to(rng):
    """cone_cull(near=, spare=) against the bound in numpy: the spared Gaussians in front of the cut stay."""
    n = 4000
    scene = GaussianScene(rng.normal(0, 2.0, (n, 3)), rng.normal(size=(n, 4)), rng.normal(-2.5, 1.0, (n, 3)),
                          np.zeros(n), rng.normal(size=(n, 1, 3)))
    cam = Camera.look_at([0.5, -1.0, -5.0], [0, 0, 0], [0, -1, 0], 50, 64, 48)
    spare = rng.random(n) < 0.3
    roi = (10, 5, 40, 30)
    got = cone_cull(scene, cam, roi, 6.0, 4.0, spare)
    smax = scene.scales.max(axis=1).astype(np.float64)
    np.testing.assert_array_equal(got, _numpy_cull(scene, cam, roi, smax, 6.0, 4.0, spare))
    cut = cone_cull(scene, cam, roi, 6.0, 4.0)
    assert cut.size < got.size and np.all(spare[np.setdiff1d(got, cut)])
    # without a near cut, spare changes nothing
    np.testing.assert_array_equal(cone_cull(scene, cam, roi, 6.0, None, spare), cone_cull(scene, cam, roi, 6.0))


def test_near_cut_operator_is_that_of_the_scene_without_what_was_cut(rng):
    """Renderer.operator(near=, spare=): W of the scene restricted to what stays; the cut columns are empty."""
    n = 1500
    scene = GaussianScene(rng.normal(0, 1.5, (n, 3)), rng.normal(size=(n, 4)), rng.normal(-3.0, 0.7, (n, 3)),
                          rng.normal(1.0, 1.0, n), rng.normal(size=(n, 1, 3)))
    cam = Camera.look_at([0.5, -1.0, -5.0], [0, 0, 0], [0, -1, 0], 50, 64, 48)
    roi = (12, 8, 44, 36)
    spare = np.zeros(n, bool)
    spare[::7] = True
    axis = np.array([(28 - cam.cx) / cam.fx, (22 - cam.cy) / cam.fy, 1.0])
    depth = (scene.means.astype(np.float64) @ cam.rotation.T + cam.translation) @ (axis / np.linalg.norm(axis))
    stay = (depth >= 4.5) | spare
    assert (~stay).sum() > 100
    got = Renderer(scene).operator(cam, roi=roi, cull=True, near=4.5, spare=spare)
    want = build_operator(scene.subset(stay), cam, roi=roi)
    W = got.W.toarray()
    np.testing.assert_allclose(W[:, stay], want.W.toarray(), rtol=1e-6, atol=1e-7)
    assert not W[:, ~stay].any()
    np.testing.assert_allclose(got.rendering.rgb, want.rendering.rgb, rtol=1e-6, atol=1e-6)
    with pytest.raises(ValidationError, match="spare"):
        cone_cull(scene, cam, roi, near=4.5, spare=spare[:10])


def test_culled_subset_gives_the_same_roi_pixels(rng):
    """What culling promises: rasterizing only the kept Gaussians changes no roi pixel (nor W there)."""
    n = 1500
    scene = GaussianScene(rng.normal(0, 1.5, (n, 3)), rng.normal(size=(n, 4)), rng.normal(-3.0, 0.7, (n, 3)),
                          rng.normal(1.0, 1.0, n), rng.normal(size=(n, 1, 3)))
    cam = Camera.look_at([0.5, -1.0, -5.0], [0, 0, 0], [0, -1, 0], 50, 64, 48)
    roi = (12, 8, 44, 36)
    idx = cone_cull(scene, cam, roi)
    assert 0 < idx.size < n
    full = build_operator(scene, cam, roi=roi)
    culled = build_operator(scene, cam, roi=roi, subset=idx)
    np.testing.assert_array_equal(full.W.toarray(), culled.W.toarray())
    np.testing.assert_array_equal(full.rendering.rgb, culled.rendering.rgb)
    dottest(culled, rng=1)


def test_culled_subset_is_exact_for_cameras_inside_the_scene(rng):
    """Gaussians close to the camera and off axis have affine footprints far wider than their 3-sigma
    ball; the bound must keep them (a 3D cone test dropped some). The full rasterization is the reference."""
    n = 800
    scene = GaussianScene(rng.uniform(-2, 2, (n, 3)), rng.normal(size=(n, 4)), rng.normal(-2.2, 0.6, (n, 3)),
                          rng.normal(1.0, 1.0, n), rng.normal(size=(n, 1, 3)))
    kept = []
    for k in range(8):
        eye = rng.uniform(-1.5, 1.5, 3)
        cam = Camera.look_at(eye, eye + rng.normal(size=3), [0, -1, 0], 60, 48, 36)
        for roi in (None, (0, 0, 8, 8), (20, 10, 40, 30)):
            idx = cone_cull(scene, cam, roi)
            full = build_operator(scene, cam, roi=roi)
            culled = build_operator(scene, cam, roi=roi, subset=idx)
            np.testing.assert_array_equal(full.W.toarray(), culled.W.toarray(), err_msg=f"camera {k}, roi {roi}")
            kept.append(idx.size / n)
    assert min(kept) < 0.5  # it still culls


def test_no_gaussian_that_reaches_the_roi_is_culled_where_the_bound_is_tight(rng):
    """Opaque isotropic Gaussians of 2-15 px seen by a 100 degree camera: their footprints come close to
    the bound (a full opacity puts the 1/255 cut-off at its full radius, the wide field of view stretches
    off-axis footprints). Every Gaussian with a weight on a roi pixel in the full rasterization (the
    reference) is kept, and the culled operator is the full one; a bound a little too tight (a smaller
    cut-off radius, the mean instead of the largest eigenvalue) drops some."""
    cam = Camera.from_fov(96, 64, 100.0)
    n = 4000
    kept_share = []
    for roi in [(0, 0, 6, 6), (44, 28, 52, 36), (90, 20, 96, 44)]:
        z = rng.uniform(0.1, 2.0, n)
        u, v = rng.uniform(-60, 156, n), rng.uniform(-60, 124, n)
        x, y = (u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z
        means = (np.stack([x, y, z], 1) - cam.translation) @ cam.rotation
        log_s = np.repeat(np.log(z * rng.uniform(2.0, 15.0, n) / cam.fx)[:, None], 3, 1)
        scene = GaussianScene(means, np.tile([1.0, 0, 0, 0], (n, 1)), log_s, np.full(n, 9.0), np.ones((n, 1, 3)))
        full = build_operator(scene, cam, roi=roi)
        reach = np.flatnonzero(np.asarray((full.W != 0).sum(axis=0)).ravel())
        kept = cone_cull(scene, cam, roi)
        assert reach.size > 20
        np.testing.assert_array_equal(np.setdiff1d(reach, kept), [], err_msg=f"roi {roi}")
        culled = build_operator(scene, cam, roi=roi, subset=kept)
        assert (culled.W != full.W).nnz == 0
        kept_share.append(kept.size / n)
    assert max(kept_share) < 0.7  # it still culls


def test_a_close_gaussian_beside_the_roi_is_kept():
    """One Gaussian 0.1 in front of the camera, off axis: its footprint reaches the corner roi."""
    scene = GaussianScene(np.array([[-0.3, 0.15, 0.1]]), np.array([[1.0, 0, 0, 0]]), np.log(np.full((1, 3), 0.085)),
                          np.array([4.0]), np.full((1, 1, 3), 1.0))
    cam = Camera.from_fov(64, 48, 60.0)
    roi = (0, 0, 8, 8)
    assert build_operator(scene, cam, roi=roi).W.nnz > 0
    np.testing.assert_array_equal(cone_cull(scene, cam, roi), [0])


def test_cone_cull_rejects_bad_input(rng):
    n = 10
    scene = GaussianScene(rng.normal(size=(n, 3)), rng.normal(size=(n, 4)), np.full((n, 3), -2.0),
                          np.zeros(n), rng.normal(size=(n, 1, 3)))
    cam = Camera.look_at([0, 0, -4], [0, 0, 0], [0, -1, 0], 50, 16, 12)
    for bad, match in ((dict(scene="x.ply"), "GaussianScene"), (dict(camera="cam"), "Camera"),
                       (dict(roi=(5, 5, 5, 9)), "empty"), (dict(roi=(1, 2, 3)), "roi"),
                       (dict(far="far"), "far"), (dict(far=float("nan")), "far"),
                       (dict(near=True), "near"), (dict(near=float("nan")), "near")):
        kw = dict(scene=scene, camera=cam, roi=None, far=None, near=None)
        kw.update(bad)
        with pytest.raises(ValidationError, match=match):
            cone_cull(kw["scene"], kw["camera"], kw["roi"], kw["far"], kw["near"])
