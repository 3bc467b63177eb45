"""raster.cone_cull: the parallel kernel against the formula in numpy, and what culling guarantees."""

from __future__ import annotations

import numpy as np
import pytest

from seed2gs_inverse.camera import Camera
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.operators import dottest
from seed2gs_inverse.raster import FrozenScene, build_operator, cone_cull
from seed2gs_inverse.scene import GaussianScene


def _numpy_cone(scene, camera, roi, sigma3, far):
    """The cone test written out with numpy (the kernel must agree)."""
    h, w = camera.image_shape
    x0, y0, x1, y1 = (0, 0, w, h) if roi is None else roi
    xs = (np.array([x0, x1, x1, x0], float) - camera.cx) / camera.fx
    ys = (np.array([y0, y0, y1, y1], float) - camera.cy) / camera.fy
    axis = np.array([(0.5 * (x0 + x1) - camera.cx) / camera.fx, (0.5 * (y0 + y1) - camera.cy) / camera.fy, 1.0])
    axis /= np.linalg.norm(axis)
    corners = np.stack([xs, ys, np.ones(4)], 1)
    corners /= np.linalg.norm(corners, axis=1, keepdims=True)
    cos_a = float(np.clip((corners @ axis).min(), 1e-3, 1.0))
    tan_a = np.sqrt(max(1.0 - cos_a ** 2, 0.0)) / cos_a
    v = scene.means.astype(np.float64) @ camera.rotation.T + camera.translation
    t = v @ axis
    perp = np.sqrt(np.maximum((v * v).sum(1) - t * t, 0.0))
    keep = (v[:, 2] > camera.near - sigma3) & (perp <= t * tan_a + sigma3 / cos_a + 1e-6)
    if far is not None:
        keep &= t - sigma3 <= far
    return np.flatnonzero(keep)


@pytest.mark.parametrize("roi,far", [(None, None), ((10, 5, 40, 30), None), ((0, 0, 20, 48), 4.5)])
def test_cone_cull_matches_formula(rng, roi, far):
    n = 4000
    scene = GaussianScene(rng.normal(0, 2.0, (n, 3)), rng.normal(size=(n, 4)), rng.normal(-2.5, 1.0, (n, 3)),
                          np.zeros(n), rng.normal(size=(n, 1, 3)))
    cam = Camera.look_at([0.5, -1.0, -5.0], [0, 0, 0], [0, -1, 0], 50, 64, 48)
    sigma3 = 3.0 * scene.scales.max(axis=1).astype(np.float64)
    got = cone_cull(scene, cam, roi, far)
    want = _numpy_cone(scene, cam, roi, sigma3, far)
    np.testing.assert_array_equal(got, want)
    assert got.dtype == np.int64 and 0 < got.size < n
    np.testing.assert_array_equal(cone_cull(FrozenScene(scene), cam, roi, far), got)


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


def test_cone_cull_rejects_bad_input(rng):
    n = 10
    scene = GaussianScene(rng.normal(size=(n, 3)), rng.normal(size=(n, 4)), np.full((n, 3), -2.0),
                          np.zeros(n), rng.normal(size=(n, 1, 3)))
    cam = Camera.look_at([0, 0, -4], [0, 0, 0], [0, -1, 0], 50, 16, 12)
    for bad, match in ((dict(scene="x.ply"), "GaussianScene"), (dict(camera="cam"), "Camera"),
                       (dict(roi=(5, 5, 5, 9)), "empty"), (dict(roi=(1, 2, 3)), "roi"),
                       (dict(far="far"), "far"), (dict(far=float("nan")), "far")):
        kw = dict(scene=scene, camera=cam, roi=None, far=None)
        kw.update(bad)
        with pytest.raises(ValidationError, match=match):
            cone_cull(kw["scene"], kw["camera"], kw["roi"], kw["far"])
