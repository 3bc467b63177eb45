"""Seed lift: mask + depth constraints and 3D connected components."""

import numpy as np
import pytest

from seed2gs_inverse import GaussianScene, ValidationError
from seed2gs_inverse.raster import build_operator
from seed2gs_inverse.pipeline.seed_lift import neighbour_components as _components, seed_lift

from _pipeline_scenes import reference_camera, sphere_scene, surface


@pytest.fixture(scope="module")
def setup():
    scene, labels, info = sphere_scene()
    cam = reference_camera(info, 96, 72)
    op = build_operator(scene, cam)
    truth2d = (op.W @ labels.astype(np.float32)).reshape(cam.image_shape) > 0.5
    return scene, labels, info, cam, op, truth2d


def _visible(op, labels):
    # Gaussians of the object that carry real weight in the reference view.
    w = np.asarray(op.W.sum(axis=0)).ravel()
    return labels & (w > 0.05)


@pytest.mark.parametrize("use_w", [True, False])
def test_lift_recovers_visible_object(setup, use_w):
    scene, labels, info, cam, op, truth2d = setup
    lift = seed_lift(scene, cam, truth2d, op.rendering.depth, op.W if use_w else None)
    sup = lift.g0
    assert lift.mode == ("contribution" if use_w else "center")
    precision = (sup & labels).sum() / sup.sum()
    recall_visible = (sup & _visible(op, labels)).sum() / _visible(op, labels).sum()
    assert precision > 0.97, precision
    assert recall_visible > 0.6, recall_visible
    # Centre within the sphere, radius of the sphere's order (front cap only: conservative).
    assert np.linalg.norm(lift.center - info["center"]) < info["radius"]
    assert 0.3 * info["radius"] < lift.radius < 2.0 * info["radius"]
    assert not (sup & ~lift.candidates).any()


def test_contribution_rule_is_sharper_at_the_silhouette(setup):
    # Centres of background splats fall inside the silhouette although
    # their weight lies outside it: the contribution rule rejects them.
    scene, labels, info, cam, op, truth2d = setup
    with_w = seed_lift(scene, cam, truth2d, op.rendering.depth, op.W).candidates
    centre = seed_lift(scene, cam, truth2d, op.rendering.depth).candidates
    assert (centre & ~labels).sum() > 0
    assert (with_w & ~labels).sum() < (centre & ~labels).sum()


def test_membership_matches_brute_force(setup):
    scene, labels, info, cam, op, truth2d = setup
    lift = seed_lift(scene, cam, truth2d, op.rendering.depth, op.W)
    dense = op.W.toarray().astype(np.float64)
    m = truth2d.ravel()
    for i in np.nonzero(dense.sum(0) > 1e-3)[0][::97]:
        expect = dense[m, i].sum() / dense[:, i].sum()
        assert lift.membership[i] == pytest.approx(expect, abs=1e-5)


def test_components_drop_a_detached_blob():
    scene, labels, info = sphere_scene(n_ground=400)
    cam = reference_camera(info, 96, 72)
    # A small blob beside the sphere (touching it in the image, 0.6 away in 3D).
    k = 25
    rng = np.random.default_rng(3)
    pts = info["center"] + 0.75 * info["e2"] + rng.normal(0, 0.02, (k, 3))
    blob = surface(pts, np.tile(info["e1"], (k, 1)), 0.02, np.tile([0.9, 0.2, 0.1], (k, 1)))
    scene2 = GaussianScene.concat([scene, blob])
    lab2 = np.r_[labels, np.zeros(k, bool)]
    op = build_operator(scene2, cam)
    both = (op.W @ np.r_[labels, np.ones(k, bool)].astype(np.float32)).reshape(cam.image_shape) > 0.3
    lift = seed_lift(scene2, cam, both, op.rendering.depth, op.W)
    assert lift.n_components >= 2 and lift.kept_components < lift.n_components
    assert not lift.g0[len(scene):].any()
    assert (lift.g0 & lab2).sum() / lift.g0.sum() > 0.97


def test_components_on_two_clusters():
    rng = np.random.default_rng(0)
    a = rng.normal(0, 0.05, (60, 3))
    b = rng.normal(0, 0.05, (40, 3)) + [3, 0, 0]
    labels, n = _components(np.vstack([a, b]), 8, 3.0)
    assert n == 2
    assert len(set(labels[:60])) == 1 and len(set(labels[60:])) == 1 and labels[0] != labels[60]


def test_bad_masks(setup):
    scene, labels, info, cam, op, truth2d = setup
    with pytest.raises(ValidationError, match="empty"):
        seed_lift(scene, cam, np.zeros(cam.image_shape, bool), op.rendering.depth, op.W)
    sky = op.rendering.alpha < 1e-3
    assert sky.any()
    for W in (op.W, None):
        with pytest.raises(ValidationError, match="touches no Gaussian"):
            seed_lift(scene, cam, sky, op.rendering.depth, W)
    with pytest.raises(ValidationError, match="shape"):
        seed_lift(scene, cam, truth2d[:-1], op.rendering.depth)


def _brute_candidates(scene, cam, mask, depth, W, eps_rel=0.02, eps_sigma=2.0, min_membership=0.5, min_weight=1e-3,
                      max_size_ratio=4.0, pixel=np.floor):
    """The candidate rule of seed_lift's docstring, Gaussian by Gaussian from a dense W and the camera's
    intrinsics: ``(candidates, before the size filter, passing all but the centre's depth test, sigma)``.
    ``pixel`` turns the projected centre into its pixel (floor: the pixel it lies in)."""
    D = W.toarray().astype(np.float64)
    h, w = cam.image_shape
    m, d = mask.ravel().astype(np.float64), depth.ravel().astype(np.float64)
    p = scene.means.astype(np.float64) @ cam.rotation.T + cam.translation
    sigma = scene.scales.astype(np.float64).max(1)
    n = len(scene)
    pre, all_but_centre = np.zeros(n, bool), np.zeros(n, bool)
    for i in range(n):
        x, y, z = p[i]
        tot = D[:, i].sum()
        if z <= cam.near or tot < min_weight or tot == 0:
            continue
        eps = eps_rel * abs(z) + eps_sigma * sigma[i]
        rest = (D[:, i] * m).sum() / tot >= min_membership and (D[:, i] * np.abs(z - d)).sum() / tot <= eps
        px, py = int(pixel(cam.fx * x / z + cam.cx)), int(pixel(cam.fy * y / z + cam.cy))
        centre = 0 <= px < w and 0 <= py < h and d[py * w + px] > 0 and abs(z - d[py * w + px]) <= eps
        pre[i] = rest and centre
        all_but_centre[i] = rest and not centre
    return pre & (sigma <= max_size_ratio * np.median(sigma[pre])), pre, all_but_centre


def test_candidates_equal_the_rule_written_out(setup):
    """A loose mask (the object dilated by 6 px) lets background splats peek into it: the candidates are
    exactly those of the rule computed Gaussian by Gaussian. The scene holds Gaussians that only the
    centre's depth test rejects, Gaussians whose fate the centre's pixel decides (rounding it instead
    changes them) and Gaussians only the size filter drops, so every part of the rule is exercised."""
    import cv2

    scene, labels, info, cam, op, truth2d = setup
    loose = cv2.dilate(truth2d.astype(np.uint8), np.ones((13, 13), np.uint8)) > 0
    depth = op.rendering.depth
    lift = seed_lift(scene, cam, loose, depth, op.W)
    want, pre, all_but_centre = _brute_candidates(scene, cam, loose, depth, op.W)
    np.testing.assert_array_equal(lift.candidates, want)
    assert all_but_centre.any()
    assert (_brute_candidates(scene, cam, loose, depth, op.W, pixel=np.round)[0] != want).any()
    # the size filter, at a ratio just below the largest candidate's: it drops that one alone
    sigma = scene.scales.astype(np.float64).max(1)
    ratio = 0.99 * sigma[pre].max() / np.median(sigma[pre])
    tight = seed_lift(scene, cam, loose, depth, op.W, max_size_ratio=ratio).candidates
    want, pre, _ = _brute_candidates(scene, cam, loose, depth, op.W, max_size_ratio=ratio)
    np.testing.assert_array_equal(tight, want)
    assert 0 < (pre & ~want).sum() < pre.sum()


def test_components_are_kept_by_their_mask_contribution_and_the_box_is_robust():
    """Three separate clusters inside the seed: 40 faint splats (most Gaussians, little weight), 6 opaque
    ones (the most weight) and 6 half-transparent ones. Components are scored by their summed mask
    contribution (W^T m, from the dense W): the opaque cluster is the best, the half-transparent one keeps
    more than keep_fraction of its score and stays, the faint one does not, although it has the most
    Gaussians. The centre and radius come from the 2nd-98th percentile box of the support."""
    from seed2gs_inverse.camera import Camera

    rng = np.random.default_rng(2)
    cam = Camera.from_fov(96, 72, 60.0)
    groups = {"faint": ((-0.8, 0.0, 3.0), 40, -3.5, 0.02), "opaque": ((0.8, 0.0, 3.0), 6, 4.0, 0.05),
              "half": ((0.0, 0.6, 3.0), 6, 0.0, 0.04)}
    means, logit, size, group = [], [], [], []
    for g, (c, k, a, s) in groups.items():
        means.append(np.asarray(c) + rng.uniform(-0.08, 0.08, (k, 3)) * [1, 1, 0.2])
        logit += [a] * k
        size += [s] * k
        group += [g] * k
    means, group = np.concatenate(means), np.array(group)
    n = len(group)
    scene = GaussianScene(means, np.tile([1.0, 0, 0, 0], (n, 1)), np.log(np.repeat(np.array(size)[:, None], 3, 1)),
                          np.array(logit), np.full((n, 1, 3), 1.0))
    op = build_operator(scene, cam)
    seed = np.ones(cam.image_shape, bool)
    lift = seed_lift(scene, cam, seed, op.rendering.depth, op.W, keep_fraction=0.2)
    assert lift.candidates.all()
    inside = op.W.toarray().astype(np.float64).T @ seed.ravel()
    score = {g: inside[group == g].sum() for g in groups}
    assert max(score, key=score.get) == "opaque"  # the construction: weight and count disagree
    assert 0.2 < score["half"] / score["opaque"] < 0.9 and score["faint"] / score["opaque"] < 0.2
    np.testing.assert_array_equal(lift.g0, group != "faint")
    assert (lift.n_components, lift.kept_components) == (3, 2)
    lo, hi = np.percentile(means[lift.g0], [2, 98], axis=0)
    np.testing.assert_allclose(lift.bbox, [lo, hi], atol=1e-6)
    np.testing.assert_allclose(lift.center, 0.5 * (lo + hi), atol=1e-6)
    assert lift.radius == pytest.approx(max(0.5 * np.linalg.norm(hi - lo), 3 * 0.05), rel=1e-6)
    # keep_fraction above the half-transparent cluster's share keeps the best component alone
    only = seed_lift(scene, cam, seed, op.rendering.depth, op.W, keep_fraction=0.95).g0
    np.testing.assert_array_equal(only, group == "opaque")


def test_support_is_a_deprecated_alias_of_g0(setup):
    scene, labels, info, cam, op, truth2d = setup
    lift = seed_lift(scene, cam, truth2d, op.rendering.depth, op.W)
    with pytest.warns(DeprecationWarning, match="SeedLift.g0"):
        assert lift.support is lift.g0
    with pytest.warns(DeprecationWarning, match="SeedLift.n_g0"):
        assert lift.n_support == lift.n_g0


# -- the lift examines only the Gaussians that can pass its constraints ------------------------------------

def _whole_scene_lift(scene, cam, mask, depth, W, *, eps_rel=0.02, eps_sigma=2.0, min_membership=0.5,
                      min_weight=1e-3, k_neighbors=8, link_factor=3.0, keep_fraction=0.2, max_size_ratio=4.0):
    """The lift of seed_lift's docstring computed over all N Gaussians, array by array:
    ``(g0, candidates, membership or None, eps_depth, center, radius)``."""
    h, w = cam.image_shape
    m, d = np.asarray(mask) > 0.5, np.asarray(depth, np.float64)
    means = scene.means.astype(np.float64)
    uv, z = cam.project(means)
    sigma = scene.scales.max(axis=1).astype(np.float64)
    eps = eps_rel * np.abs(z) + eps_sigma * sigma
    ok = np.isfinite(uv).all(axis=1) & (z > cam.near)
    px = np.floor(np.where(ok, uv[:, 0], -1)).astype(np.int64)
    py = np.floor(np.where(ok, uv[:, 1], -1)).astype(np.int64)
    ok &= (px >= 0) & (px < w) & (py >= 0) & (py < h)
    px, py = np.where(ok, px, 0), np.where(ok, py, 0)
    depth_ok = ok & (d[py, px] > 0) & (np.abs(z - d[py, px]) <= eps)
    membership = None
    if W is None:
        cand, score = ok & m[py, px] & depth_ok, np.ones(len(scene))
    else:
        W = W.tocsr()
        colsum = np.asarray(W.sum(axis=0)).ravel().astype(np.float64)
        inside = np.asarray(W.T @ m.ravel().astype(np.float64)).ravel()
        rows = np.repeat(np.arange(h * w), np.diff(W.indptr))
        resid = np.bincount(W.indices, weights=W.data * np.abs(z[W.indices] - d.ravel()[rows]), minlength=len(z))
        safe = np.maximum(colsum, 1e-30)
        membership = np.where(colsum > 0, inside / safe, 0.0)
        resid = np.where(colsum > 0, resid / safe, np.inf)
        cand = (colsum >= min_weight) & (membership >= min_membership) & depth_ok & (resid <= eps)
        score = inside
    if cand.any() and max_size_ratio is not None:
        cand &= sigma <= max_size_ratio * np.median(sigma[cand])
    idx = np.flatnonzero(cand)
    labels, ncomp = _components(means[idx], k_neighbors, link_factor)
    comp = np.bincount(labels, weights=score[idx], minlength=ncomp)
    keep = comp >= keep_fraction * comp.max()
    keep[np.argmax(comp)] = True
    g0 = np.zeros(len(scene), bool)
    g0[idx[keep[labels]]] = True
    lo, hi = np.percentile(means[g0], [2, 98], axis=0) if g0.sum() >= 10 else (means[g0].min(0), means[g0].max(0))
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 3.0 * float(sigma[g0].max()), 1e-6)
    return g0, cand, membership, eps.astype(np.float32), 0.5 * (lo + hi), radius


def _with_far_copies(scene, info, cam):
    """``scene`` between copies of itself: one behind the camera, one far to the side (outside the view)
    and one far beyond the object along the view (inside it); returns the scene and the original's slice."""
    back = -cam.forward
    copies = [scene.transformed(np.eye(3), off, 1.0) for off in
              (40.0 * back, 50.0 * info["e2"] + 5.0 * info["e1"], -30.0 * back)]
    tiled = GaussianScene.concat([copies[0], scene, copies[1], copies[2]])
    return tiled, slice(len(scene), 2 * len(scene))


@pytest.mark.parametrize("frozen", [False, True])
@pytest.mark.parametrize("use_w", [True, False])
@pytest.mark.parametrize("loose", [False, True])
def test_lift_equals_the_whole_scene_computation(setup, frozen, use_w, loose):
    """G0, the candidates, the membership, the tolerance, the centre and the radius equal those computed over
    every Gaussian, with far copies of the scene around it (behind the camera, outside the view, beyond the
    object in it), from a plain or a frozen scene, with and without W, with a tight and a loose seed."""
    import cv2

    from seed2gs_inverse.raster import FrozenScene

    scene, labels, info, cam, op, truth2d = setup
    tiled, mine = _with_far_copies(scene, info, cam)
    top = build_operator(tiled, cam)
    assert np.asarray(top.W[:, mine.start:mine.stop].sum()) > 0  # the original is what the view shows
    seed = cv2.dilate(truth2d.astype(np.uint8), np.ones((13, 13), np.uint8)) > 0 if loose else truth2d
    W = top.W if use_w else None
    lift = seed_lift(FrozenScene(tiled) if frozen else tiled, cam, seed, top.rendering.depth, W)
    g0, cand, membership, eps, center, radius = _whole_scene_lift(tiled, cam, seed, top.rendering.depth, W)
    np.testing.assert_array_equal(lift.g0, g0)
    np.testing.assert_array_equal(lift.candidates, cand)
    np.testing.assert_array_equal(lift.center, center)
    assert lift.radius == radius
    assert lift.g0.any() and not lift.g0[:mine.start].any() and not lift.g0[mine.stop:].any()
    # the tolerance where it was computed, NaN elsewhere; every candidate among the examined
    inside = np.zeros(len(tiled), bool)
    inside[lift.index] = True
    assert not (cand & ~inside).any()
    np.testing.assert_array_equal(lift.eps_depth[inside], eps[inside])
    assert np.isnan(lift.eps_depth[~inside]).all()
    if use_w:
        np.testing.assert_array_equal(lift.membership, membership.astype(np.float32))
        np.testing.assert_array_equal(lift.index, np.unique(top.W.indices))  # W's columns
    else:
        assert lift.membership is None
    if frozen or use_w:  # the copies behind and beside the camera are not examined
        beside = (lift.index >= mine.stop) & (lift.index < mine.stop + len(scene))
        assert not (lift.index < mine.start).any() and not beside.any()
    else:
        assert len(lift.index) == len(tiled)


def test_lift_takes_w_in_any_sparse_format(setup):
    scene, labels, info, cam, op, truth2d = setup
    want = seed_lift(scene, cam, truth2d, op.rendering.depth, op.W)
    for fmt in ("coo", "csc"):
        got = seed_lift(scene, cam, truth2d, op.rendering.depth, op.W.asformat(fmt))
        np.testing.assert_array_equal(got.g0, want.g0)
        np.testing.assert_array_equal(got.membership, want.membership)
    with pytest.raises(ValidationError, match="sparse"):
        seed_lift(scene, cam, truth2d, op.rendering.depth, op.W.toarray())
    with pytest.raises(ValidationError, match="GaussianScene or FrozenScene"):
        seed_lift(scene.means, cam, truth2d, op.rendering.depth, op.W)
