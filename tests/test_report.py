"""report.png and the seed summary (issue 12 items 10 and 15), against hand-made known values."""

from types import SimpleNamespace

import numpy as np
import pytest

from seed2gs_inverse import Camera
from seed2gs_inverse.pipeline.report import _orbit_window, seed_summary


def _fake(seed, alpha):
    """An extraction-like object whose object rendering is given (the cache report.py keeps)."""
    ex = SimpleNamespace(seed_mask=seed)
    ex._object_rendering = (np.zeros(alpha.shape + (3,), np.float32), alpha)
    return ex


def test_seed_summary_known_values():
    alpha = np.zeros((40, 60), np.float32)
    alpha[10:30, 20:40] = 0.9          # object silhouette: 20 x 20 = 400 px, box (20, 10, 40, 30)
    seed = np.zeros((40, 60), bool)
    seed[10:15, 20:40] = True          # the top quarter of it: 100 px
    seed[0:2, 0:5] = True              # and 10 px outside
    s = seed_summary(_fake(seed, alpha))
    assert s["seed_pixels"] == 110 and s["object_pixels"] == 400
    assert s["object_box"] == (20, 10, 40, 30) and s["object_box_size"] == [20, 20]
    assert s["seed_box"] == (0, 0, 40, 15)
    assert s["share_of_object_box"] == pytest.approx(110 / 400)
    assert s["share_of_object"] == pytest.approx(100 / 400)
    assert s["share_outside_object"] == pytest.approx(10 / 110)
    # nothing extracted: no shares, no division by zero
    s = seed_summary(_fake(seed, np.zeros_like(alpha)))
    assert s["object_box"] is None and s["share_of_object"] is None and s["seed_pixels"] == 110


def test_orbit_windows_zoom_alike():
    """The window is the projected sphere (o, 2 r) whatever the view's resolution and distance."""
    o, r = np.array([0.0, 0.0, 0.0]), 0.5
    wins = []
    for dist, fov, (w, h) in [(3.0, 50, (96, 72)), (6.0, 30, (400, 300)), (2.0, 70, (64, 48))]:
        cam = Camera.look_at(np.array([0.0, -dist, 0.0]), o, np.array([0.0, 0.0, 1.0]), fov, w, h)
        x0, y0, x1, y1 = _orbit_window(cam, o, r)
        # independent: half-size = f * 2r / distance, centred on the principal point
        half = cam.fy * 2 * r / dist
        assert (x1 - x0) == pytest.approx(2 * half, abs=2) and (y1 - y0) == pytest.approx(2 * half, abs=2)
        assert 0.5 * (x0 + x1) == pytest.approx(cam.cx, abs=1) and 0.5 * (y0 + y1) == pytest.approx(cam.cy, abs=1)
        wins.append((x1 - x0) / (2 * half))
    assert max(wins) - min(wins) < 0.1  # the same zoom on the object in every panel


def test_report_figure_panels(tmp_path):
    from seed2gs_inverse.raster import build_operator
    from seed2gs_inverse.pipeline import extract
    from seed2gs_inverse.pipeline.report import report_figure
    from seed2gs_inverse.synthetic import make_scene

    syn = make_scene(seed=0)
    cam = syn.reference_camera(96, 72)
    seed = (build_operator(syn.scene, cam).W @ (syn.labels == 2).astype(np.float32)).reshape(72, 96) > 0.5
    ex = extract(syn.scene, cam, seed, n_views=4, progress=False)
    fig = report_figure(ex)
    axes = fig.get_axes()
    assert len(axes) == 3 + min(8, len(ex.views))
    # orbit panels are square and all the same size (same zoom, same display size)
    shapes = {ax.get_images()[0].get_array().shape for ax in axes[3:]}
    assert len(shapes) == 1 and next(iter(shapes))[:2] == (200, 200)
    # the object panel is cropped to the object: much smaller than the reference view
    crop = axes[1].get_images()[0].get_array().shape
    assert crop[0] < 72 and crop[1] < 96
    assert "of the object's box" in axes[0].get_title()
    fig.savefig(tmp_path / "r.png", dpi=100)
    assert fig.get_size_inches()[0] >= 13  # larger panels than the old 2.2-inch strip


def test_the_object_rendering_uses_the_runs_mode():
    """The seed summary and report.png rendered the object in the classic mode whatever ``mode`` the run used."""
    from seed2gs_inverse.pipeline.report import _object_rendering
    from seed2gs_inverse.raster import render

    cam = Camera.look_at(np.array([0.0, -3.0, 0.0]), np.zeros(3), np.array([0.0, 0.0, 1.0]), 50, 48, 36)
    rng = np.random.default_rng(0)
    from seed2gs_inverse.scene import GaussianScene

    n = 200
    scene = GaussianScene(rng.normal(0, 0.3, (n, 3)), rng.normal(size=(n, 4)), rng.normal(-4.0, 0.5, (n, 3)),
                          rng.normal(0.0, 1.0, n), rng.normal(size=(n, 1, 3)))
    for mode in ("classic", "antialiased"):
        ex = SimpleNamespace(reference_camera=cam, object_scene=lambda: scene,
                             settings=SimpleNamespace(mode=mode))
        np.testing.assert_array_equal(_object_rendering(ex)[1], render(scene, cam, mode=mode).alpha)
    assert not np.array_equal(render(scene, cam, mode="classic").alpha, render(scene, cam, mode="antialiased").alpha)
