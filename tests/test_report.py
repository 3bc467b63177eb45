"""report.png, report_masks.png and the seed summary, against hand-made known values and independent renders."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from seed2gs_inverse import Camera, GaussianScene, ValidationError
from seed2gs_inverse.cli._extract import seed_summary_line
from seed2gs_inverse.pipeline import extract, save_extraction
from seed2gs_inverse.pipeline.report import (OBJECT_FILL, OBJECT_VIEWS, REMAINDER_FILL, _backdrop, _object_cameras,
                                             _orbit_window, masks_figure, report_figure, seed_summary)
from seed2gs_inverse.raster import build_operator, render
from seed2gs_inverse.sh import rgb_to_sh
from seed2gs_inverse.synthetic import make_scene

from _pipeline_scenes import reference_camera, sphere_scene


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
    assert s["growth_beyond_seed"] == pytest.approx(300 / 110)  # silhouette pixels outside the seed, per seed pixel
    assert s["grown_from_pixels"] is None
    # nothing extracted: no shares, no division by zero
    s = seed_summary(_fake(seed, np.zeros_like(alpha)))
    assert s["object_box"] is None and s["share_of_object"] is None and s["seed_pixels"] == 110
    assert s["growth_beyond_seed"] is None
    # a seed grown from a click says from how much
    ex = _fake(seed, alpha)
    ex.prompt_info = {"kind": "point", "mode": "object", "patch_pixels": 37}
    assert seed_summary(ex)["grown_from_pixels"] == 37
    ex.prompt_info = {"kind": "point", "mode": "region"}
    assert seed_summary(ex)["grown_from_pixels"] is None


def test_the_printed_seed_line_says_what_it_measures():
    summary = {"seed_pixels": 412, "object_pixels": 900, "object_box_size": [28, 39], "share_of_object_box": 0.38,
               "share_of_object": 0.45, "growth_beyond_seed": 495 / 412, "grown_from_pixels": None}
    line = seed_summary_line(summary)
    assert line == ("seed: 412 px = 38% of the object's box (28x39 px); the selection rendered alone in the "
                    "reference: 900 px, 45% of them under the seed, 120% of the seed's area beyond it")
    summary["grown_from_pixels"] = 120
    assert seed_summary_line(summary).endswith("; the seed itself grew in 3D from the click's 120 px region")


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


@pytest.fixture(scope="module")
def small_extraction():
    syn = make_scene(seed=0)
    cam = syn.reference_camera(96, 72)
    seed = (build_operator(syn.scene, cam).W @ (syn.labels == 2).astype(np.float32)).reshape(72, 96) > 0.5
    return extract(syn.scene, cam, seed, n_views=4, progress=False)


def test_report_figures_of_an_extraction(small_extraction, tmp_path):
    ex = small_extraction
    fig = report_figure(ex, size=64)
    axes = fig.get_axes()
    assert len(axes) == 3 + len(OBJECT_VIEWS)
    assert all(ax.get_images()[0].get_array().shape == (64, 64, 3) for ax in axes[3:])
    assert "of the object's silhouette" in fig._suptitle.get_text()
    # the masks picture keeps the supervision views, all at one zoom and one display size
    axes = masks_figure(ex).get_axes()
    assert len(axes) == min(8, len(ex.views))
    assert {ax.get_images()[0].get_array().shape for ax in axes} == {(200, 200, 3)}
    # both pictures are written, and a rerun with --force knows the folder as its own output
    out = save_extraction(ex, tmp_path / "out")
    assert {"report.png", "report_masks.png"} <= {p.name for p in out.iterdir()}
    before = json.loads((out / "report.json").read_text())
    assert before["seed"]["growth_beyond_seed"] is not None
    save_extraction(ex, out, force=True)
    assert (out / "report_masks.png").stat().st_size > 0
    with pytest.raises(ValidationError, match="size"):
        report_figure(ex, size=8)
    with pytest.raises(ValidationError, match="n_strip"):
        masks_figure(ex, n_strip=0)


def _blob(center, color, sigma=0.08):
    return GaussianScene(np.asarray(center, float)[None], np.array([[1.0, 0, 0, 0]]),
                         np.full((1, 3), np.log(sigma)), np.array([6.0]), rgb_to_sh(np.array([color]))[:, None, :])


def _sphere_extraction(selected_sphere=True):
    """An extraction-like record of the sphere scene with a pure green Gaussian between the sphere and the
    report's first camera; the selection is exactly the sphere (or nothing)."""
    base, labels, info = sphere_scene(n_sphere=500, n_ground=900)
    ref = reference_camera(info, 96, 72)

    def record(scene, sel):
        up = info["up"].tolist()
        return SimpleNamespace(
            scene=scene, selected=sel, seed_mask=np.zeros(ref.image_shape, bool), reference_camera=ref,
            reference=render(scene, ref), settings=SimpleNamespace(mode="classic", method="test"),
            resolved={"up": up}, views=[ref], total_seconds=0.0, prompt_info={"kind": "mask"},
            lift=SimpleNamespace(center=info["center"], radius=info["radius"]),
            object_scene=lambda: scene.subset(sel), remainder_scene=lambda: scene.subset(~sel))

    first = _object_cameras(record(base, labels), base.subset(labels), 96)[0]
    towards = first.center - info["center"]
    blob = _blob(info["center"] + 0.8 * towards / np.linalg.norm(towards), [0.0, 1.0, 0.0])
    scene = GaussianScene.concat([base, blob])
    sel = np.r_[labels, False] & selected_sphere
    return record(scene, sel), info


def _composite(r):
    return np.clip(r.rgb + (1 - r.alpha[..., None]) * _backdrop(r.alpha.shape), 0, 1)


def _green(img):
    return int(((img[..., 1] > 0.6) & (img[..., 0] < 0.3) & (img[..., 2] < 0.3)).sum())


def test_report_tiles_are_the_object_alone():
    """Each object tile is an independent render of the selected subset, and no other Gaussian shows in it."""
    ex, info = _sphere_extraction()
    size = 80
    fig = report_figure(ex, size=size)
    axes = fig.get_axes()
    obj = ex.scene.subset(ex.selected)
    cams = _object_cameras(ex, obj, size)
    for ax, cam, view in zip(axes[3:], cams, OBJECT_VIEWS):
        tile = np.asarray(ax.get_images()[0].get_array())
        alone = render(obj, cam)
        np.testing.assert_allclose(tile, _composite(alone), atol=1e-6, err_msg=str(view))
        whole = _composite(render(ex.scene, cam))
        assert np.abs(whole - tile).max() > 0.2  # the whole scene's render (ground) would differ: a real check
        assert _green(tile) == 0
        # zoomed: the silhouette fills most of the tile and stays inside it
        ys, xs = np.nonzero(alone.alpha > 0.5)
        side = max(xs.max() - xs.min(), ys.max() - ys.min()) + 1
        assert 0.7 * OBJECT_FILL * size <= side <= size - 2 and xs.min() > 0 and ys.min() > 0
    # the green Gaussian is in the first tile's frame: the whole scene shows it there
    assert _green(_composite(render(ex.scene, cams[0]))) > 20
    # directions: one from behind the reference, one low, about the orbit axis through the sphere
    u, c = info["up"], info["center"]

    def direction(cam):
        d = cam.center - c
        return d / np.linalg.norm(d)

    ref_h = direction(ex.reference_camera) - (direction(ex.reference_camera) @ u) * u
    for cam, (az, el, label) in zip(cams, OBJECT_VIEWS):
        d = direction(cam)
        assert np.degrees(np.arcsin(d @ u)) == pytest.approx(el, abs=1.0)
        h = d - (d @ u) * u
        if label == "behind":
            assert h @ ref_h / np.linalg.norm(h) / np.linalg.norm(ref_h) < -0.99
    assert min(v[1] for v in OBJECT_VIEWS) <= 10.0 and len(OBJECT_VIEWS) >= 4


def test_report_remainder_panels_are_the_scene_without_the_object():
    ex, _ = _sphere_extraction()
    rem = ex.scene.subset(~ex.selected)
    axes = report_figure(ex, size=80).get_axes()
    np.testing.assert_array_equal(axes[0].get_images()[0].get_array(), np.clip(ex.reference.rgb, 0, 1))
    # from behind: the remainder alone, the object at REMAINDER_FILL of the tile
    wide = _object_cameras(ex, ex.scene.subset(ex.selected), 80, REMAINDER_FILL, views=(OBJECT_VIEWS[2],))[0]
    np.testing.assert_allclose(axes[2].get_images()[0].get_array(), _composite(render(rem, wide)), atol=1e-6)
    # around the hole: the reference render of the remainder, cut to the object's box grown by half its size
    # (at size 32 the window is not enlarged, so it is a crop of the full reference render)
    axes = report_figure(ex, size=32).get_axes()
    x0, y0, x1, y1 = seed_summary(ex)["object_box"]
    mx, my = (x1 - x0) // 2 + 8, (y1 - y0) // 2 + 8
    h, w = ex.reference_camera.image_shape
    x0, y0, x1, y1 = max(x0 - mx, 0), max(y0 - my, 0), min(x1 + mx, w), min(y1 + my, h)
    full = render(rem, ex.reference_camera)
    crop = SimpleNamespace(rgb=full.rgb[y0:y1, x0:x1], alpha=full.alpha[y0:y1, x0:x1])
    panel = np.asarray(axes[1].get_images()[0].get_array())
    assert panel.shape == (y1 - y0, x1 - x0, 3)
    # equal up to the 3-sigma tile cut of the classic rasterizer, which moves with the image's tile grid
    np.testing.assert_allclose(panel, _composite(crop), atol=0.01)
    assert np.abs(panel - _composite(crop)).mean() < 1e-3
    assert not np.allclose(panel, _composite(SimpleNamespace(
        rgb=ex.reference.rgb[y0:y1, x0:x1], alpha=ex.reference.alpha[y0:y1, x0:x1])), atol=0.05)  # not the scene


def test_report_of_an_empty_selection():
    ex, _ = _sphere_extraction(selected_sphere=False)
    fig = report_figure(ex, size=48)
    for ax in fig.get_axes()[3:]:
        np.testing.assert_array_equal(ax.get_images()[0].get_array(), _backdrop((48, 48)))


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
