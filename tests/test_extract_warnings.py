"""extract() says when a finished run is not to be trusted although every stage ran.

Cases from a robustness review: a seed of a few pixels whose object no orbit view found (nothing selected,
with no word), a camera so close that the seed fills the image and lifts to two Gaussians, and settings
that leave the orbit views without a single weight.
"""

import warnings

import numpy as np
import pytest

import seed2gs_inverse as sgi

from _pipeline_scenes import reference_camera, sphere_scene


@pytest.fixture(scope="module")
def sphere():
    return sphere_scene()


def _object_mask(scene, labels, cam):
    op = sgi.build_operator(scene, cam)
    return (op.W @ (labels == 1).astype(np.float32)).reshape(cam.image_shape) > 0.5


def _run(scene, cam, mask, info, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ex = sgi.extract(scene, cam, mask, n_views=4, up=tuple(info["up"]), progress=False, **kw)
    return ex, [str(w.message) for w in caught]


def test_a_sound_run_warns_nothing(sphere):
    scene, labels, info = sphere
    cam = reference_camera(info)
    ex, said = _run(scene, cam, _object_mask(scene, labels, cam), info)
    assert ex.resolved["warnings"] == [] and not [s for s in said if "orbit" in s or "selected" in s]


def test_a_far_few_pixel_seed_that_no_orbit_view_found_is_said(sphere):
    scene, labels, info = sphere
    cam = reference_camera(info, dist=120.0)
    mask = _object_mask(scene, labels, cam)
    assert 0 < mask.sum() <= 6
    ex, said = _run(scene, cam, mask, info)
    found = [m for m in ex.resolved["warnings"] if "found in none of the orbit views" in m]
    assert found and found[0] in said
    if not ex.selected.any():
        assert any("nothing was selected" in m for m in ex.resolved["warnings"])


def test_a_camera_inside_the_object_s_surface_is_said(sphere):
    scene, labels, info = sphere
    cam = reference_camera(info, dist=0.6)
    ex, _ = _run(scene, cam, _object_mask(scene, labels, cam), info)
    notes = " | ".join(ex.resolved["warnings"])
    assert "touches every border of the reference image" in notes
    assert "lifted to only" in notes and ex.lift.n_g0 < 10


def test_orbit_views_without_weights_are_said(sphere):
    scene, labels, info = sphere
    cam = reference_camera(info)
    ex, _ = _run(scene, cam, _object_mask(scene, labels, cam), info, min_weight=0.99)
    assert all(ex.operators[i].W.nnz == 0 for i in range(1, len(ex.operators)))
    assert any("orbit views hold no weights" in m for m in ex.resolved["warnings"])


def test_a_seed_smaller_than_the_splats_says_so(sphere):
    scene, labels, info = sphere
    cam = reference_camera(info)
    full = _object_mask(scene, labels, cam)
    ys, xs = np.nonzero(full)
    dot = np.zeros_like(full)
    dot[int(np.median(ys)), int(np.median(xs))] = True  # one pixel in the middle of the sphere
    with pytest.raises(sgi.ValidationError, match=r"seed mask \(1 px\) is smaller than the footprint"):
        sgi.extract(scene, cam, dot, n_views=4, up=tuple(info["up"]), progress=False)


def test_extreme_but_valid_inputs_stay_quiet_and_finite():
    import dataclasses

    from seed2gs_inverse.synthetic import make_scene

    for up in ((1e-300, -1e-300, 0.0), (1e300, -1e300, 0.0)):  # a direction, whatever its length
        assert sgi.ExtractSettings(up=up).up == (1.0, -1.0, 0.0)
    assert sgi.ExtractSettings(up=(0, -2, 0)).up == (0.0, -2.0, 0.0)  # ordinary lengths are kept as given
    scene = make_scene(seed=0, n_per_object=20).scene
    logits = scene.opacity_logits.copy()
    logits[:3] = -1e4  # how some exporters write pruned splats
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        op = dataclasses.replace(scene, opacity_logits=logits).opacities
    assert np.all(op[:3] == 0.0) and np.all(np.isfinite(op))


def test_the_seed_size_message_only_when_membership_alone_failed(sphere):
    scene, labels, info = sphere
    cam = reference_camera(info)
    with pytest.raises(sgi.ValidationError, match="touches no Gaussian") as exc:
        sgi.extract(scene, cam, _object_mask(scene, labels, cam), n_views=4, up=tuple(info["up"]),
                    progress=False, lift_options={"min_weight": 1e6})
    assert "smaller than the footprint" not in str(exc.value)
