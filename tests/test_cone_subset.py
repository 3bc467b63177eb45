"""extract's cone culling of orbit views: the parallel kernel against the formula in numpy."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from seed2gs_inverse.camera import Camera
from seed2gs_inverse.scene import GaussianScene

extract_mod = importlib.import_module("seed2gs_inverse.pipeline.extract")


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
def test_cone_subset_matches_formula(rng, roi, far):
    n = 4000
    scene = GaussianScene(rng.normal(0, 2.0, (n, 3)), rng.normal(size=(n, 4)), rng.normal(-2.5, 1.0, (n, 3)),
                          np.zeros(n), rng.normal(size=(n, 1, 3)))
    cam = Camera.look_at([0.5, -1.0, -5.0], [0, 0, 0], [0, -1, 0], 50, 64, 48)
    sigma3 = 3.0 * scene.scales.max(axis=1).astype(np.float64)
    got = extract_mod._cone_subset(scene, cam, roi, sigma3, far)
    want = _numpy_cone(scene, cam, roi, sigma3, far)
    np.testing.assert_array_equal(got, want)
    assert 0 < got.size < n
