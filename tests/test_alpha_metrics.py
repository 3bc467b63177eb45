"""Alpha-weighted scores over views and the remainder's share of the object's weight (metrics.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp

from seed2gs_inverse import Camera, GaussianScene
from seed2gs_inverse.cli._extract import seed_summary_line
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.metrics import alpha_scores, nearby_remainder, object_region, remainder_share
from seed2gs_inverse.operators import ViewOperator
from seed2gs_inverse.raster import build_operator, render


# -- references ---------------------------------------------------------------------------
def _dense_weight(mats, member):
    """sum over views, pixels and Gaussians in ``member`` of W[u, i], by loops over dense matrices."""
    total = 0.0
    for W in mats:
        D = W.toarray()
        for u in range(D.shape[0]):
            for i in range(D.shape[1]):
                if member[i]:
                    total += float(D[u, i])
    return total


def _random_views(rng, n=12, shapes=((4, 5), (3, 3), (2, 6))):
    mats = []
    for h, w in shapes:
        W = sp.random(h * w, n, density=0.4, random_state=rng, format="csr", dtype=np.float64)
        W = W.multiply(1.0 / np.maximum(np.asarray(W.sum(axis=1)), 1.0))  # rows sum to at most 1
        mats.append(sp.csr_matrix(W, dtype=np.float32))
    return mats


def test_alpha_scores_match_a_per_pixel_reference():
    rng = np.random.default_rng(3)
    mats = _random_views(rng)
    views = [ViewOperator(W, None, shape) for W, shape in zip(mats, ((4, 5), (3, 3), (2, 6)))]
    for _ in range(5):
        sel, truth = rng.random(12) < 0.5, rng.random(12) < 0.5
        got = alpha_scores(views, sel, truth)
        both = _dense_weight(mats, sel & truth)
        want = {"recall": both / _dense_weight(mats, truth), "precision": both / _dense_weight(mats, sel),
                "iou": both / _dense_weight(mats, sel | truth)}
        for k, v in want.items():
            assert got[k] == pytest.approx(v, rel=1e-5), k
    # bare sparse matrices are accepted too
    assert alpha_scores(mats, sel, truth)["iou"] == pytest.approx(got["iou"], rel=1e-6)


def test_front_layer_only_recall_is_its_share_of_the_weight():
    # one pixel, three Gaussians front to back: the object's front layer (alpha 0.6), its back layer
    # (alpha 0.5) and a wall (alpha 1): weights 0.6, 0.4 * 0.5 = 0.2, 0.2 * 1 = 0.2.
    W = sp.csr_matrix(np.array([[0.6, 0.2, 0.2]], np.float32))
    truth = np.array([True, True, False])
    front = np.array([True, False, False])
    s = alpha_scores([W], front, truth)
    assert s["recall"] == pytest.approx(0.6 / 0.8) and s["precision"] == pytest.approx(1.0)
    assert s["iou"] == pytest.approx(0.75)
    # the whole object and the wall: all of the object, 0.8 of the selection's weight
    s = alpha_scores([W], np.ones(3, bool), truth)
    assert s["recall"] == pytest.approx(1.0) and s["precision"] == pytest.approx(0.8)
    assert s["iou"] == pytest.approx(0.8)
    # nothing selected, an unseen truth: 0/0 is 1 as in membership_scores
    W0 = sp.csr_matrix((1, 3), dtype=np.float32)
    assert alpha_scores([W0], front, truth)["recall"] == 1.0
    assert alpha_scores([W], np.zeros(3, bool), truth)["recall"] == 0.0


def test_alpha_scores_refuse_bad_memberships():
    W = sp.csr_matrix(np.array([[0.6, 0.2, 0.2]], np.float32))
    with pytest.raises(ValidationError, match="selected must be a bool array of shape \\(3,\\)"):
        alpha_scores([W], np.array([1, 0, 0]), np.ones(3, bool))
    with pytest.raises(ValidationError, match="truth"):
        alpha_scores([W], np.ones(3, bool), np.ones(4, bool))


def test_object_region_is_the_robust_oriented_box():
    rng = np.random.default_rng(0)
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    local = rng.uniform(-1, 1, (2000, 3)) * [2.0, 1.0, 0.2]  # a rotated slab
    x = local @ R.T
    sel = np.ones(2000, bool)
    sel[0] = True
    x[0] = 50 * R[:, 0]  # a stray selected Gaussian far away does not stretch the box
    probes = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [3.0, 0.0, 0.0], [1.9, 0.9, 0.15]]) @ R.T
    region = object_region(np.vstack([x, probes]), np.concatenate([sel, np.zeros(4, bool)]))
    assert region[-4:].tolist() == [True, False, False, True]
    assert not region[0]


# -- rendered scenes ------------------------------------------------------------------------
def _sphere(n, radius, opacity, center=(0.0, 0.0, 0.0), sigma_scale=0.8):
    i = np.arange(n) + 0.5
    phi, theta = np.arccos(1 - 2 * i / n), np.pi * (3.0 - np.sqrt(5.0)) * i
    d = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)
    sigma = sigma_scale * radius * np.sqrt(4 * np.pi / n)
    return np.asarray(center) + radius * d, np.full(n, sigma), np.full(n, opacity)


def _wall(z, half, n_side, opacity=0.95):
    u = np.linspace(-half, half, n_side)
    xx, yy = np.meshgrid(u, u)
    pts = np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, z)], 1)
    return pts, np.full(xx.size, 1.2 * (u[1] - u[0])), np.full(xx.size, opacity)


def _scene(parts):
    """A scene of parts ``(means, sigma, opacity[, quats])``: sigma (n,) isotropic or (n, 3) per axis."""
    means = np.vstack([p[0] for p in parts])
    sig = np.vstack([np.broadcast_to(np.asarray(p[1], float).reshape(len(p[0]), -1), (len(p[0]), 3))
                     for p in parts])
    quats = np.vstack([p[3] if len(p) > 3 else np.tile([1.0, 0, 0, 0], (len(p[0]), 1)) for p in parts])
    op = np.clip(np.concatenate([p[2] for p in parts]), 1e-4, 1 - 1e-4)
    n = len(means)
    scene = GaussianScene(means, quats, np.log(sig), np.log(op / (1 - op)), np.full((n, 1, 3), 0.5))
    labels = np.concatenate([np.full(len(p[0]), k) for k, p in enumerate(parts)])
    return scene, labels


def _views(scene, azimuths, elevation=20.0, dist=4.0):
    ops = []
    for az in azimuths:
        a, e = np.radians(az), np.radians(elevation)
        eye = dist * np.array([np.cos(e) * np.sin(a), -np.sin(e), np.cos(e) * np.cos(a)])
        ops.append(build_operator(scene, Camera.look_at(eye, (0, 0, 0), (0, -1, 0), 45.0, 48, 40)))
    return ops


def test_an_unselected_inner_layer_behind_a_translucent_shell_is_a_large_share():
    scene, labels = _scene([_sphere(300, 1.0, 0.1), _sphere(200, 0.7, 0.95)])
    ops = _views(scene, [0, 90, 180, 270])
    shell = labels == 0
    r = remainder_share(ops, shell, scene.means)
    assert r["n_nearby"] == int((labels == 1).sum())  # the inner sphere lies in the shell's region
    assert r["share"] > 0.5 and r["worst_view"] >= r["share"] and len(r["per_view"]) == 4
    # the same against the truth: recall is what the selection holds of the object's weight
    s = alpha_scores(ops, shell, np.ones(len(labels), bool))
    assert s["recall"] < 0.7 and s["precision"] == pytest.approx(1.0)
    # the whole object selected: nothing left
    whole = remainder_share(ops, np.ones(len(labels), bool), scene.means)
    assert whole["share"] == 0.0 and whole["n_nearby"] == 0


def test_an_inner_layer_hidden_behind_an_opaque_front_still_counts():
    # the selected front layer covers the silhouette (the pixel rule sees a whole object), yet the
    # half-transparent layer behind it stays: removed, the object leaves a see-through copy
    scene, labels = _scene([_sphere(400, 1.0, 0.6), _sphere(300, 0.8, 0.35)])
    ops = _views(scene, [0, 90, 180, 270])
    front = labels == 0
    assert all(((op.W @ front.astype(np.float32)) > 0.5).sum() >= ((op.W @ np.ones(len(labels), np.float32))
                                                                  > 0.5).sum() * 0.95 for op in ops)
    r = remainder_share(ops, front, scene.means)
    assert r["share"] > 0.3
    # the compositing weight alone undersells it: what the views see of the inner layer
    seen = alpha_scores(ops, ~front, np.ones(len(labels), bool))["recall"]
    assert seen < 0.5 * r["share"]


def test_a_wall_seen_through_a_clean_selection_is_not_a_ghost():
    # a half-transparent ball in front of a wall: the wall shows through the ball (and fills the
    # footprint once the ball is removed), but it lies outside the ball's region
    scene, labels = _scene([_sphere(300, 0.6, 0.3), _wall(-1.5, 3.0, 40)])
    ops = _views(scene, [-20, 0, 20], elevation=10.0)
    ball = labels == 0
    r = remainder_share(ops, ball, scene.means)
    assert r["share"] == pytest.approx(0.0, abs=1e-6) and r["n_nearby"] == 0
    # the wall does hold weight in the ball's footprint: only the region keeps it out
    wall = obj = 0.0
    for op in ops:
        a, b = op.W @ ball.astype(np.float32), op.W @ (~ball).astype(np.float32)
        wall, obj = wall + float(b[a >= 0.25].sum()), obj + float(a[a >= 0.25].sum())
    assert wall > 0.1 * (wall + obj)


def _ground(y, half, n_side, opacity=0.95):
    """Flat surfels on the plane ``y`` (normal along y: local z turned onto y)."""
    u = np.linspace(-half, half, n_side)
    xx, zz = np.meshgrid(u, u)
    pts = np.stack([xx.ravel(), np.full(xx.size, y), zz.ravel()], 1)
    st = 0.7 * (u[1] - u[0])
    quat = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]
    return (pts, np.tile([st, st, 0.1 * st], (xx.size, 1)), np.full(xx.size, opacity),
            np.tile(quat, (xx.size, 1)))


def test_the_ground_under_a_clean_selection_is_not_a_ghost():
    # a half-transparent ball resting on the ground, seen from above: the ground under it lies in the
    # ball's region (the box's margin), shows through it, and shows where it was once removed; it is
    # behind the ball along every ray, so it is no ghost
    scene, labels = _scene([_sphere(300, 0.5, 0.3), _ground(0.52, 1.2, 60)])
    ops = _views(scene, [0, 90, 180, 270], elevation=50.0) + _views(scene, [45], elevation=10.0)
    ball = labels == 0
    r = remainder_share(ops, ball, scene.means)
    assert r["n_nearby"] == 0 and r["share"] == 0.0
    # the ball's box does hold ground, which rendered alone covers much of the ball's footprint
    in_box = object_region(scene.means, ball) & ~ball
    assert in_box.sum() > 100
    cover = [render(scene.subset(in_box), op.camera).alpha[(op.W @ ball.astype(np.float32)).reshape(
        op.image_shape) >= 0.25].mean() for op in ops]
    assert min(cover[:4]) > 0.2
    # an inner ball left unselected inside the same ball is found there, the ground still left out
    scene, labels = _scene([_sphere(300, 0.5, 0.3), _ground(0.52, 1.2, 60), _sphere(100, 0.3, 0.9)])
    nearby = nearby_remainder(scene.means, labels == 0)
    assert np.array_equal(nearby, labels == 2)
    assert remainder_share(_views(scene, [0, 180], elevation=50.0), labels == 0, scene.means)["share"] > 0.3


def _looped_share(ops, sel, nearby, means, footprint=0.25):
    """remainder_share's definition by loops over each pixel's entries, sorted by depth one by one."""
    g = o = 0.0
    for op in ops:
        z = op.camera.world_to_view(np.asarray(means, np.float64))[:, 2]
        D = op.W.toarray().astype(np.float64)
        for u in range(D.shape[0]):
            ids = list(np.flatnonzero(D[u]))
            if sum(D[u, i] for i in ids if sel[i]) < footprint:
                continue
            ids.sort(key=lambda i: z[i])
            keep_g = keep_sg = 1.0
            t = 1.0
            for i in ids:
                a = min(D[u, i] / t, 0.99)
                t -= D[u, i]
                if nearby[i]:
                    keep_g *= 1 - a
                    keep_sg *= 1 - a
                elif sel[i]:
                    keep_sg *= 1 - a
            g += 1 - keep_g
            o += 1 - keep_sg
    return g / o


def test_remainder_share_matches_a_per_pixel_loop():
    # both layers partly selected, at random
    scene, labels = _scene([_sphere(120, 0.6, 0.4), _sphere(80, 0.4, 0.6)])
    ops = _views(scene, [30, 200], elevation=35.0)
    rng = np.random.default_rng(4)
    sel = rng.random(len(labels)) < 0.6
    nearby = nearby_remainder(scene.means, sel, margin=0.3)  # a box that holds every Gaussian
    assert np.array_equal(nearby, ~sel)
    want = _looped_share(ops, sel, nearby, scene.means)
    got = remainder_share(ops, sel, scene.means, margin=0.3)["share"]
    assert want > 0.05 and got == pytest.approx(want, rel=1e-6)


def test_remainder_share_matches_renders_of_the_parts_alone():
    # the reference renders the nearby remainder and the object's region alone with the rasterizer;
    # opacities low enough that no pixel of the whole scene reaches the transmittance cut-off (a
    # Gaussian cut off there has no weight, so the operators cannot know its alpha)
    scene, labels = _scene([_sphere(150, 1.0, 0.2), _sphere(100, 0.6, 0.25), _wall(-3.5, 4.0, 12, opacity=0.3)])
    ops = _views(scene, [0, 45, -60])
    rng = np.random.default_rng(1)
    sel = (labels == 0) | ((labels == 1) & (rng.random(len(labels)) < 0.5))
    nearby = nearby_remainder(scene.means, sel)
    assert nearby.sum() > 10 and not nearby[labels == 2].any()
    g = o = 0.0
    per_view = []
    for op in ops:
        f = (op.W @ sel.astype(np.float32)).reshape(op.image_shape) >= 0.25
        gv = float(render(scene.subset(nearby), op.camera).alpha[f].sum())
        ov = float(render(scene.subset(sel | nearby), op.camera).alpha[f].sum())
        per_view.append(gv / ov)
        g, o = g + gv, o + ov
    r = remainder_share(ops, sel, scene.means)
    assert r["share"] == pytest.approx(g / o, rel=1e-5)
    assert np.allclose(r["per_view"], per_view, rtol=1e-4) and r["worst_view"] == pytest.approx(max(per_view))


def test_remainder_share_refuses_bad_input():
    W = sp.csr_matrix(np.array([[0.6, 0.2, 0.2]], np.float32))
    with pytest.raises(ValidationError, match="view 0 has no camera"):
        remainder_share([W], np.ones(3, bool), np.zeros((3, 3)))
    scene, labels = _scene([_sphere(60, 1.0, 0.5)])
    ops = _views(scene, [0])
    with pytest.raises(ValidationError, match="means must have shape \\(60, 3\\)"):
        remainder_share(ops, np.ones(60, bool), np.zeros((2, 3)))
    with pytest.raises(ValidationError, match="footprint"):
        remainder_share(ops, np.ones(60, bool), scene.means, footprint=0.0)
    empty = remainder_share(ops, np.zeros(60, bool), scene.means)
    assert np.isnan(empty["share"]) and empty["footprint_pixels"] == 0


def test_summary_line_reports_the_remainder_share():
    summary = {"seed_pixels": 412, "object_pixels": 900, "object_box_size": [28, 39],
               "share_of_object_box": 0.38, "share_of_object": 0.45}
    line = seed_summary_line(summary, {"share": 0.031, "worst_view": 0.074})
    assert line.endswith("; the remainder keeps 3.1% of the object's alpha (worst view 7.4%)")
    assert seed_summary_line(summary, {"share": None, "worst_view": None}) == seed_summary_line(summary)


def test_extraction_report_holds_the_remainder_share():
    from seed2gs_inverse.pipeline import extract

    scene, labels = _scene([_sphere(300, 1.0, 0.25), _sphere(200, 0.7, 0.95), _wall(-2.5, 4.0, 20)])
    cam = Camera.look_at((0.0, -1.0, 4.0), (0, 0, 0), (0, -1, 0), 45.0, 64, 48)
    seed = (build_operator(scene, cam).W @ (labels < 2).astype(np.float32)).reshape(cam.image_shape) > 0.5
    ex = extract(scene, cam, seed, n_views=4, up=(0.0, -1.0, 0.0), progress=False)
    rep = json.loads(json.dumps(ex.report()))
    want = remainder_share(ex.operators, ex.selected, scene.means)
    assert rep["remainder_share"]["share"] == pytest.approx(want["share"])
    assert rep["remainder_share"]["worst_view"] == pytest.approx(want["worst_view"])
    assert rep["remainder_share"]["n_nearby"] == want["n_nearby"]
    # the kept figure follows the selection: an edited selection is not reported with the old one
    ex.selected = ex.selected.copy()
    ex.selected[np.flatnonzero(ex.selected)[::2]] = False
    edited = remainder_share(ex.operators, ex.selected, scene.means)
    assert edited["share"] != pytest.approx(want["share"])
    assert ex.remainder_summary()["share"] == pytest.approx(edited["share"])
