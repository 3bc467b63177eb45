"""Seed lift: mask + depth constraints and 3D connected components."""

import numpy as np
import pytest

from seed2gs_inverse import GaussianScene, ValidationError
from seed2gs_inverse.raster import build_operator
from seed2gs_inverse.pipeline.seed_lift import _components, seed_lift

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
    sup = lift.support
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
    assert not lift.support[len(scene):].any()
    assert (lift.support & lab2).sum() / lift.support.sum() > 0.97


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
