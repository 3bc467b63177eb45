"""Model-free geometric tracker: warping geometry and propagation on rendered views."""

from types import SimpleNamespace

import numpy as np
import pytest

from seed2gs_inverse import Camera, ValidationError
from seed2gs_inverse.frontend.model_free import GeometricTracker, _pixel_rays, _world_points, warp_labels
from seed2gs_inverse.raster import build_operator
from seed2gs_inverse.pipeline.vaas import ClipFrame, flat_orbit

from _pipeline_scenes import reference_camera, sphere_scene


def _plane_frame(cam, z, alpha=1.0):
    h, w = cam.image_shape
    return SimpleNamespace(camera=cam, depth=np.full((h, w), z, np.float32),
                           alpha=np.full((h, w), alpha, np.float32),
                           rgb=np.zeros((h, w, 3), np.float32))


def test_warp_plane_translation_shifts_by_disparity():
    # Fronto-parallel plane at depth Z; the camera moves by tx along +x: a
    # point at pixel x in the source appears at x - fx tx / Z in the target.
    z, tx = 4.0, 0.5
    src_cam = Camera(40, 30, 20.0, 20.0, 20.0, 15.0)
    dst_pose = np.eye(4)
    dst_pose[0, 3] = -tx  # world_to_camera translation for a centre at +tx
    dst_cam = src_cam.with_pose(dst_pose)
    shift = 20.0 * tx / z  # 2.5 px
    src = _plane_frame(src_cam, z)
    dst = _plane_frame(dst_cam, z)
    lab = np.zeros((30, 40))
    lab[:, 10:20] = 1.0
    out = warp_labels(dst, src, lab)
    # dst pixel x sees the point at source x + shift (nearest pixel = floor).
    xs = np.arange(40)
    src_x = np.floor(xs + 0.5 + shift).astype(int)
    expect = np.where(src_x < 40, ((src_x >= 10) & (src_x < 20)).astype(float), np.nan)
    np.testing.assert_array_equal(out[0], expect)
    assert np.isnan(out[:, -3:]).all()  # those points are outside the source view
    # pixels=: the same labels at the asked pixels, NaN elsewhere
    ask = np.zeros((30, 40), bool)
    ask[::3, 5:30] = True
    part = warp_labels(dst, src, lab, pixels=ask)
    np.testing.assert_array_equal(part[ask], out[ask])
    assert np.isnan(part[~ask]).all()


def test_world_points_of_chosen_pixels_are_those_of_the_whole_grid():
    # the chosen pixels' rays are made alone; the reference is the whole grid's rays, then the choice
    rng = np.random.default_rng(4)
    pose = np.eye(4)
    pose[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    pose[:3, 3] = rng.normal(size=3)
    cam = Camera(23, 17, 19.0, 27.0, 11.3, 7.9).with_pose(pose)
    depth = rng.random((17, 23)).astype(np.float32) + 0.5
    where = rng.random((17, 23)) < 0.4
    d = depth.astype(np.float64)
    expect = (_pixel_rays(cam)[where] * d[where][:, None] - cam.translation) @ cam.rotation
    np.testing.assert_array_equal(_world_points(cam, depth, where), expect)
    np.testing.assert_array_equal(_world_points(cam, depth)[where], expect)


@pytest.mark.parametrize("axis", [0, 1])
def test_warp_with_non_square_pixels_shifts_by_each_axis_focal_length(axis):
    """fx = 20, fy = 32: a camera moved by t along x (y) shifts a fronto-parallel plane at depth Z by
    fx t / Z (fy t / Z) pixels along that axis only."""
    z, t = 4.0, 0.5
    src_cam = Camera(40, 30, 20.0, 32.0, 20.0, 15.0)
    pose = np.eye(4)
    pose[axis, 3] = -t
    dst = _plane_frame(src_cam.with_pose(pose), z)
    src = _plane_frame(src_cam, z)
    lab = np.zeros((30, 40))
    if axis == 0:
        lab[:, 10:20] = 1.0
    else:
        lab[8:16, :] = 1.0
    out = warp_labels(dst, src, lab)
    shift = (20.0 if axis == 0 else 32.0) * t / z  # 2.5 or 4 px
    n = 40 if axis == 0 else 30
    s = np.floor(np.arange(n) + 0.5 + shift).astype(int)
    lo, hi = (10, 20) if axis == 0 else (8, 16)
    expect = np.where(s < n, ((s >= lo) & (s < hi)).astype(float), np.nan)
    np.testing.assert_array_equal(out[0] if axis == 0 else out[:, 0], expect)
    # nothing moves along the other axis
    other = out[:, 25] if axis == 0 else out[5, :]  # source column 28 (outside the band), source row 9 (in it)
    assert np.all(other[~np.isnan(other)] == (0.0 if axis == 0 else 1.0))


def test_warp_z_test_marks_occluded_points_unknown():
    cam = Camera(20, 10, 10.0, 10.0, 10.0, 5.0)
    src = _plane_frame(cam, 2.0)  # something in front in the source
    dst = _plane_frame(cam, 5.0)
    out = warp_labels(dst, src, np.ones((10, 20)))
    assert np.isnan(out).all()
    empty = _plane_frame(cam, 5.0, alpha=0.1)
    assert np.isnan(warp_labels(empty, _plane_frame(cam, 5.0), np.ones((10, 20)))).all()


@pytest.fixture(scope="module")
def clip():
    scene, labels, info = sphere_scene()
    ref = reference_camera(info, 96, 72)
    cams = flat_orbit(ref, info["center"], 12)[:4]
    frames, truth = [], []
    for k, cam in enumerate(cams):
        op = build_operator(scene, cam)
        r = op.rendering
        frames.append(ClipFrame(r.rgb, r.depth, r.alpha, cam, "flat", k))
        truth.append((op.W @ labels.astype(np.float32)).reshape(cam.image_shape) > 0.5)
    return frames, truth


def test_tracker_follows_the_object(clip):
    frames, truth = clip
    masks = GeometricTracker().track(frames, truth[0])
    assert len(masks) == len(frames)
    np.testing.assert_array_equal(masks[0], truth[0].astype(np.float32))
    for k in range(1, len(frames)):
        m, t = masks[k], truth[k]
        assert m.dtype == np.float32 and m.shape == t.shape
        known = ~np.isnan(m)
        assert set(np.unique(m[known])) <= {0.0, 1.0}
        agree = (m[known] > 0.5) == t[known]
        assert agree.mean() > 0.98, (k, agree.mean())
        assert known.mean() > 0.75  # disoccluded ground behind the sphere stays unknown
        # Most of the object is decided, and decided right.
        assert np.isnan(m[t]).mean() < 0.25
        inter = ((m > 0.5) & t & known).sum()
        assert inter / (((m > 0.5) | t) & known).sum() > 0.9
        # Empty space is decided (0), never unknown.
        assert not np.isnan(m[frames[k].alpha < 0.5]).any()


def test_tracker_leaves_unseen_pixels_unknown_without_fill(clip):
    frames, truth = clip
    masks = GeometricTracker(fill=False).track(frames, truth[0])
    filled = GeometricTracker().track(frames, truth[0])
    for k in range(1, len(frames)):
        n_raw, n_fill = np.isnan(masks[k]).sum(), np.isnan(filled[k]).sum()
        assert n_raw > 0 and n_fill <= n_raw
        # Filling only decides unknown pixels, never overrides warped labels.
        known = ~np.isnan(masks[k])
        np.testing.assert_array_equal(filled[k][known], masks[k][known])


def test_tracker_validates(clip):
    frames, truth = clip
    with pytest.raises(ValidationError, match="seed mask"):
        GeometricTracker().track(frames, truth[0][:-1])
    with pytest.raises(ValidationError, match="no frames"):
        GeometricTracker().track([], truth[0])
    with pytest.raises(ValidationError, match="alpha_min"):
        GeometricTracker(alpha_min=2)


def test_warp_does_not_see_through_a_silhouette():
    # Source: a near wall on the left half (z = 2), far background on the
    # right (z = 5). Target (same camera): the wall is gone, background at
    # z = 5 everywhere. Background points left of the silhouette were hidden
    # in the source: unknown, even next to the edge, where the 2x2 depth
    # range spans both surfaces.
    cam = Camera(40, 10, 20.0, 20.0, 20.0, 5.0)
    src = _plane_frame(cam, 5.0)
    src.depth[:, :20] = 2.0
    dst = _plane_frame(cam, 5.0)
    lab = np.zeros((10, 40))
    lab[:, :20] = 1.0  # the wall is "the object"
    out = warp_labels(dst, src, lab)
    assert np.isnan(out[:, :20]).all()
    assert (out[:, 21:] == 0).all()


def _low_orbit(seed):
    """A full flat orbit at 10 degrees around a table standing in grass, with the exact truth per view."""
    from seed2gs_inverse.synthetic.ground import make_ground_scene

    gs = make_ground_scene(seed, objects=("table",), clutter=("grass",), density=0.5, n_per_object=800)
    obj = gs.object_mask("table").astype(np.float32)
    frames, truth = [], []
    for k, az in enumerate(range(0, 360, 15)):
        cam = gs.camera("table", az, 10.0, 2.2, 160, 120)
        op = build_operator(gs.scene, cam)
        r = op.rendering
        frames.append(ClipFrame(r.rgb, r.depth, r.alpha, cam, "flat", k))
        truth.append((op.W @ obj).reshape(cam.image_shape) > 0.5)
    return frames, truth


def _scores(masks, truth):
    """(wrong, right): decided object/background pixels labelled against / with the truth (seed frame excluded)."""
    wrong = sum(int(((m == 0) & t).sum() + ((m == 1) & ~t).sum()) for m, t in zip(masks[1:], truth[1:]))
    right = sum(int(((m == 1) & t).sum()) for m, t in zip(masks[1:], truth[1:]))
    return wrong, right


def test_fill_decisions_do_not_drift_along_a_low_orbit():
    # At 10 degrees a table's legs meet the grass at equal depth and similar
    # colour: the 2D fill labels some foot pixels 0 (or the ground between
    # the legs 1). Copied on as if observed, such errors seed the next view's
    # fill, which grows them, view after view around the orbit. With refill
    # (and its second pass) each view's observed labels first re-decide the
    # copied fill decisions. Scored against the exact truth over four scenes.
    wrong = {True: 0, False: 0}
    right = {True: 0, False: 0}
    n_obj = 0
    for seed in (2, 3, 4, 5):
        frames, truth = _low_orbit(seed)
        n_obj += sum(int(t.sum()) for t in truth[1:])
        for refill in (True, False):
            tr = GeometricTracker(refill=True, fill_passes=2) if refill else GeometricTracker()
            w, r = _scores(tr.track(frames, truth[0]), truth)
            wrong[refill] += w
            right[refill] += r
    assert wrong[True] < 0.92 * wrong[False], wrong
    # The share of wrong pixels depends on the processor's float rounding (AVX2 against AVX-512
    # NumPy/OpenBLAS kernels move depth-tolerance decisions on the knife edge), by about 4 %
    # of itself; the bound holds for both and stays below the drift without refill.
    assert wrong[True] < 0.11 * n_obj, (wrong, n_obj)
    assert right[True] > right[False], right  # and more of the table is decided, not less


def test_refill_records_which_labels_were_filled(clip):
    frames, truth = clip
    tr = GeometricTracker(refill=True, fill_passes=2)
    masks = tr.track(frames, truth[0])
    raw_tr = GeometricTracker(fill=False, refill=True)
    raw = raw_tr.track(frames, truth[0])
    n_filled = 0
    for f, m, r in zip(frames[1:], masks[1:], raw[1:]):
        filled = tr._filled_mask(f)
        assert filled is not None and filled.shape == m.shape
        assert not np.isnan(m[filled]).any()  # a filled label is a decided one
        n_filled += int(filled.sum())
        assert not raw_tr._filled_mask(f).any()  # without the fill nothing is filled
    assert n_filled > 0
    # Frames this tracker did not label, and refill=False: every label counts as observed.
    assert GeometricTracker(refill=True)._filled_mask(frames[1]) is None
    assert GeometricTracker()._filled_mask(frames[1]) is None  # refill off: all observed
    with pytest.raises(ValidationError, match="fill_passes"):
        GeometricTracker(fill_passes=0)
