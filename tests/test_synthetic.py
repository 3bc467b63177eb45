"""Procedural scenes, composites and mask noise models against independent references."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from seed2gs_inverse import GaussianScene, ValidationError
from seed2gs_inverse.scene import quat_to_rotmat
from seed2gs_inverse.sh import eval_sh
from seed2gs_inverse.synthetic import (NOISE_KINDS, compose, make_scene, masks_from_labels,
                                       parse_pose, perturb_masks, pose_on_point, render_label_masks,
                                       surface_point)

N_OBJ = 120  # small scenes keep the tests fast


@pytest.fixture(scope="module")
def syn():
    return make_scene(seed=3, n_per_object=N_OBJ)


def _random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _random_scene(rng, n=30, k=16):
    return GaussianScene(rng.normal(size=(n, 3)), rng.normal(size=(n, 4)),
                         rng.normal(-3, 0.3, size=(n, 3)), rng.normal(size=n),
                         rng.normal(0, 0.3, size=(n, k, 3)))


# -- scenes ------------------------------------------------------------------
def test_same_seed_gives_identical_arrays_and_other_seed_differs():
    a, b = make_scene(seed=7, n_per_object=60), make_scene(seed=7, n_per_object=60)
    c = make_scene(seed=8, n_per_object=60)
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        assert np.array_equal(getattr(a.scene, name), getattr(b.scene, name)), name
    assert np.array_equal(a.labels, b.labels)
    assert np.array_equal(a.centers, b.centers)
    assert len(c.scene) != len(a.scene) or not np.array_equal(a.scene.means, c.scene.means)


def test_labels_names_and_sizes(syn):
    assert syn.labels.dtype == np.int32 and syn.labels.shape == (len(syn.scene),)
    assert set(np.unique(syn.labels)) == set(syn.names) == set(range(8))
    assert syn.names[3] == "cup" and syn.names[4] == "cup contents" and syn.names[5] == "rod"
    counts = np.bincount(syn.labels)
    # Surface objects get about n_per_object Gaussians, the rod a few long ones.
    for lab in (1, 2, 3, 4, 6, 7):
        assert 0.8 * N_OBJ <= counts[lab] <= 1.25 * N_OBJ, (lab, counts[lab])
    assert counts[5] == max(8, N_OBJ // 8)
    assert syn.scene.sh_degree == 3
    assert np.allclose(syn.scene.opacities, 0.95, atol=1e-5)


@pytest.mark.parametrize("up,origin,scale", [
    ((0, -1, 0), (0, 0, 0), 1.0),
    ((0, 0, 1), (1.0, -2.0, 0.5), 2.5),
    ((1, 1, 0), (0, 0, 0), 0.3),
])
def test_every_gaussian_lies_in_its_declared_box(up, origin, scale):
    s = make_scene(seed=1, n_per_object=60, up=up, origin=origin, scale=scale)
    u = np.asarray(up, float) / np.linalg.norm(up)
    assert np.allclose(s.up, u) and np.allclose(s.frame[:, 2], u)
    assert np.allclose(s.frame.T @ s.frame, np.eye(3)) and np.isclose(np.linalg.det(s.frame), 1)
    for lab in range(8):
        m = s.scene.means[s.labels == lab].astype(np.float64)
        # Independent of .inside(): project on the frame axes directly.
        local = (m - s.centers[lab]) @ s.frame
        assert np.all(np.abs(local) <= s.half_extents[lab] + 1e-5 * scale), s.names[lab]
        assert s.inside(lab, m).all()
    # Everything stands on the ground: height above the origin along up >= 0.
    h = (s.scene.means - np.asarray(origin)) @ u
    assert h.min() > -1e-5 * scale
    assert np.allclose(h[s.labels == 0], 0, atol=1e-5 * scale)
    # Objects do not share space except the cup and its contents.
    for a in range(1, 8):
        for b in range(1, 8):
            if a != b and {a, b} != {3, 4}:
                assert not s.inside(a, s.scene.means[s.labels == b]).any(), (a, b)


def test_objects_and_their_boxes_never_overlap_for_any_seed():
    for seed in range(25):
        s = make_scene(seed=seed, n_per_object=20, ground=False)
        for a in range(1, 8):
            others = (s.labels != a) & ~np.isin(s.labels, [3, 4] if a in (3, 4) else [])
            assert not s.inside(a, s.scene.means[others]).any(), (seed, a)


def test_sphere_is_a_shell_of_normal_flattened_surfels(syn):
    on = syn.labels == 1
    c = syn.centers[1]
    d = syn.scene.means[on].astype(np.float64) - c
    assert np.allclose(np.linalg.norm(d, axis=1), 0.3, atol=1e-5)
    rot = quat_to_rotmat(syn.scene.quats[on])
    normal_axis = rot[:, :, 2]   # the flattened axis (log-scale index 2)
    cosang = np.abs(np.sum(normal_axis * d / np.linalg.norm(d, axis=1, keepdims=True), axis=1))
    assert cosang.min() > 1 - 1e-5
    sc = syn.scene.scales[on]
    assert np.allclose(sc[:, 2], 0.1 * sc[:, 0], rtol=1e-4) and np.allclose(sc[:, 0], sc[:, 1])


def test_rod_is_thin_and_anisotropic_along_its_axis(syn):
    on = syn.labels == 5
    m = syn.scene.means[on].astype(np.float64)
    axis = m[-1] - m[0]
    axis /= np.linalg.norm(axis)
    # Means are collinear.
    off = (m - m[0]) - np.outer((m - m[0]) @ axis, axis)
    assert np.abs(off).max() < 1e-5
    rot = quat_to_rotmat(syn.scene.quats[on])
    assert np.allclose(np.abs(rot[:, :, 0] @ axis), 1, atol=1e-5)   # long axis = rod axis
    sc = syn.scene.scales[on]
    assert np.all(sc[:, 0] >= 3 * sc[:, 1] - 1e-6)


def test_twin_cans_are_translated_copies_and_only_sphere_is_view_dependent(syn):
    a = syn.scene.subset(syn.labels == 6)
    b = syn.scene.subset(syn.labels == 7)
    shift = b.means[0] - a.means[0]
    assert np.linalg.norm(shift) > 0.3
    assert np.allclose(b.means - a.means, shift, atol=1e-5)
    assert np.array_equal(a.quats, b.quats) and np.array_equal(a.sh, b.sh)
    rest = np.abs(syn.scene.sh[:, 1:, :]).sum(axis=(1, 2))
    assert np.all(rest[syn.labels == 1] > 0) and np.all(rest[syn.labels != 1] == 0)
    # Textures: a two-colour checker box; cans with two stripe colours and a lid.
    for lab, n_colours in ((2, 2), (6, 3)):
        dc = np.round(syn.scene.sh[syn.labels == lab, 0, :], 3)
        assert len(np.unique(dc, axis=0)) == n_colours


def test_reference_and_orbit_cameras_see_every_object(syn):
    cams = syn.orbit_cameras(5, 64, 48, elevation_deg=[20, 30, 40, 50, 60])
    cams.append(syn.reference_camera(64, 48))
    for cam in cams:
        # Image up is the scene up: up . camera-up > 0 (camera-up = -y axis).
        assert cam.up @ syn.up > 0.3
        for lab in range(1, 8):
            uv, z = cam.project(syn.scene.means[syn.labels == lab])
            assert np.all(z > 0)
            inside = (uv[:, 0] >= 0) & (uv[:, 0] < 64) & (uv[:, 1] >= 0) & (uv[:, 1] < 48)
            assert inside.all(), (cam.name, syn.names[lab])
    assert cams[-1].name == "reference"
    assert np.allclose(cams[-1].world_to_camera, syn.orbit_cameras(1, 64, 48)[0].world_to_camera)


def test_make_scene_validates_arguments():
    with pytest.raises(ValidationError, match="n_per_object"):
        make_scene(n_per_object=5)
    with pytest.raises(ValidationError, match="up"):
        make_scene(up=(0, 0, 0))
    with pytest.raises(ValidationError, match="sh_degree"):
        make_scene(sh_degree=4)
    with pytest.raises(ValidationError, match="seed"):
        make_scene(seed=1.5)
    s = make_scene(seed=0, n_per_object=40, ground=False, sh_degree=0)
    assert 0 not in s.labels and s.scene.sh_degree == 0
    with pytest.raises(ValidationError, match="label"):
        s.object_mask(9)
    assert s.label_of("rod") == 5 and s.object_mask("rod").sum() == 8


# -- composites ----------------------------------------------------------------
def test_compose_labels_and_arrays_match_transformed(rng):
    bg, o1, o2 = _random_scene(rng, 25), _random_scene(rng, 10, 4), _random_scene(rng, 7)
    r1, r2 = _random_rotation(rng), _random_rotation(rng)
    m2 = np.eye(4)
    m2[:3, :3] = 1.7 * r2
    m2[:3, 3] = [0.5, -1, 2]
    scene, labels = compose(bg, [(o1, (r1, [1, 2, 3], 0.5)), (o2, m2)])
    assert labels.dtype == np.int32
    assert np.array_equal(labels, np.r_[np.zeros(25), np.ones(10), np.full(7, 2)])
    ref = GaussianScene.concat([bg, o1.transformed(r1, [1, 2, 3], 0.5), o2.transformed(r2, [0.5, -1, 2], 1.7)])
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        assert np.allclose(getattr(scene, name), getattr(ref, name), atol=1e-5), name


def test_compose_rotates_view_dependent_colour_with_the_object(rng):
    obj = _random_scene(rng, 12)
    rot = _random_rotation(rng)
    scene, labels = compose(None, [(obj, (rot, np.zeros(3)))])
    assert np.all(labels == 1)
    d = rng.normal(size=(12, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # Seen along R d, the moved object shows what the original showed along d.
    assert np.allclose(eval_sh(scene.sh, d @ rot.T), eval_sh(obj.sh, d), atol=1e-4)
    # Covariances: s^2 R Sigma R^T (s = 1).
    assert np.allclose(scene.covariances(), rot @ obj.covariances() @ rot.T, atol=1e-6)


def test_compose_remove_overlap_matches_brute_force(rng):
    bg = GaussianScene(rng.uniform(-2, 2, (400, 3)), np.tile([1.0, 0, 0, 0], (400, 1)),
                       np.full((400, 3), -3.0), np.zeros(400), np.zeros((400, 1, 3)))
    obj = GaussianScene(rng.uniform(-0.5, 0.5, (50, 3)) * [1, 2, 0.5], np.tile([1.0, 0, 0, 0], (50, 1)),
                        np.full((50, 3), -3.0), np.zeros(50), np.zeros((50, 1, 3)))
    rot, t, s = _random_rotation(rng), np.array([0.3, -0.2, 0.1]), 1.5
    scene, labels = compose(bg, [(obj, (rot, t, s))], remove_overlap=True, margin=0.1)
    lo, hi = obj.means.min(0), obj.means.max(0)
    expect_keep = []
    for p in bg.means.astype(np.float64):
        local = rot.T @ (p - t) / s          # per point, from the definition
        expect_keep.append(not np.all((local >= lo - 0.1 / s) & (local <= hi + 0.1 / s)))
    expect_keep = np.array(expect_keep)
    assert 0 < (~expect_keep).sum() < 400
    assert (labels == 0).sum() == expect_keep.sum()
    assert np.array_equal(scene.means[labels == 0], bg.means[expect_keep])


def test_parse_pose_forms_agree_and_reject_bad_poses(rng):
    rot = _random_rotation(rng)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = 2.0 * rot, [1, 2, 3]
    for pose in (m, (rot, [1, 2, 3], 2.0)):
        r, t, s = parse_pose(pose)
        assert np.allclose(r, rot) and np.allclose(t, [1, 2, 3]) and np.isclose(s, 2.0)
    bad = m.copy()
    bad[:3, :3] = np.diag([1.0, 2.0, 3.0])
    with pytest.raises(ValidationError, match="rotation"):
        parse_pose(bad)
    refl = m.copy()
    refl[:3, :3] = np.diag([1.0, 1.0, -1.0])
    with pytest.raises(ValidationError, match="determinant"):
        parse_pose(refl)
    with pytest.raises(ValidationError, match="4x4"):
        parse_pose(np.eye(3))
    with pytest.raises(ValidationError):
        compose(None, [])
    with pytest.raises(ValidationError, match="pair"):
        compose(None, [_random_scene(rng)])


def test_pose_on_point_stands_object_upright_at_anchor(rng):
    # An object whose own up is +x, placed into a world whose up is -y.
    obj = GaussianScene(rng.normal(size=(200, 3)) * [2.0, 0.5, 0.5] + [3, 1, -1],
                        np.tile([1.0, 0, 0, 0], (200, 1)), np.full((200, 3), -3.0),
                        np.zeros(200), np.zeros((200, 1, 3)))
    anchor = np.array([0.5, 1.0, -2.0])
    world_up = np.array([0.0, -1.0, 0.0])
    m = pose_on_point(obj, anchor, world_up, object_up=(1, 0, 0), height=0.8, yaw_deg=30)
    scene, labels = compose(None, [(obj, m)])
    h = scene.means.astype(np.float64) @ world_up
    assert np.isclose(h.min(), anchor @ world_up, atol=1e-5)
    assert np.isclose(h.max() - h.min(), 0.8, atol=1e-5)
    # The bottom centre (the median of the object's own means, moved) is on the anchor
    # in the ground plane.
    med = m[:3, :3] @ np.median(obj.means.astype(np.float64), axis=0) + m[:3, 3]
    horiz = lambda v: v - (v @ world_up) * world_up  # noqa: E731
    assert np.allclose(horiz(med), horiz(anchor), atol=1e-5)
    # The object's up (+x) now points along the world up.
    rot = m[:3, :3] / np.cbrt(np.linalg.det(m[:3, :3]))
    assert np.allclose(rot[:, 0], world_up, atol=1e-6)
    with pytest.raises(ValidationError, match="either"):
        pose_on_point(obj, anchor, world_up, height=1.0, scale=2.0)


def test_surface_point_inverts_the_projection(rng):
    s = make_scene(seed=2, n_per_object=40)
    cam = s.reference_camera(64, 48)
    depth = rng.uniform(0.5, 5.0, (48, 64)).astype(np.float32)
    for x, y in [(0, 0), (63, 47), (17, 30)]:
        p = surface_point(cam, depth, (x, y))
        (uv,), (z,) = cam.project(p[None])
        assert np.allclose(uv, [x + 0.5, y + 0.5], atol=1e-6) and np.isclose(z, depth[y, x], rtol=1e-6)
    with pytest.raises(ValidationError, match="outside"):
        surface_point(cam, depth, (64, 0))
    with pytest.raises(ValidationError, match="nothing is rendered"):
        surface_point(cam, np.zeros_like(depth), (3, 3))
    with pytest.raises(ValidationError, match="shape"):
        surface_point(cam, depth[:10], (3, 3))


def test_surface_point_on_a_rendered_ground_is_near_the_plane():
    from seed2gs_inverse.raster import render

    s = make_scene(seed=2, n_per_object=200, up=(0, 0, 1))
    cam = s.reference_camera(128, 96, azimuth_deg=180.0)
    # The ground centre is free and, from azimuth 180 degrees, no object hides it.
    (uv,), _ = cam.project(s.origin[None])
    p = surface_point(cam, render(s.scene, cam).depth, (int(uv[0]), int(uv[1])))
    # Expected depth averages Gaussian centres, which at this grazing angle sit
    # a few centimetres in front of the plane along the ray: a loose bound.
    assert abs((p - s.origin) @ s.up) < 0.06
    assert np.linalg.norm(p - s.origin) < 0.15


# -- masks ---------------------------------------------------------------------------
def test_masks_from_labels_on_a_hand_made_operator():
    # 2x2 image, 3 Gaussians; W[u, i] chosen by hand.
    W = np.array([[0.9, 0.0, 0.1], [0.2, 0.7, 0.0], [0.0, 0.0, 0.0], [0.3, 0.3, 0.3]], np.float32)
    sel = np.array([True, False, True])
    (m,) = masks_from_labels([(sp.csr_matrix(W), (2, 2))], sel)
    assert np.array_equal(m, np.array([[1, 0], [0, 1]], np.float32))   # 1.0, 0.2, 0, 0.6
    from seed2gs_inverse.operators import OperatorStack, ViewOperator

    stack = OperatorStack([ViewOperator(sp.csr_matrix(W), None, (2, 2))] * 2)
    assert all(np.array_equal(x, m) for x in masks_from_labels(stack, sel))
    (soft,) = masks_from_labels([(W, (2, 2))], sel, threshold=None)
    assert np.allclose(soft.ravel(), [1.0, 0.2, 0.0, 0.6])
    with pytest.raises(ValidationError, match="view 0"):
        masks_from_labels([(W, (3, 2))], sel)
    with pytest.raises(ValidationError, match="selected"):
        masks_from_labels([(W, (2, 2))], np.array([True, False]))


def test_masks_from_labels_of_everything_is_alpha_of_a_real_render():
    from seed2gs_inverse.raster import build_operator

    s = make_scene(seed=0, n_per_object=40)
    op = build_operator(s.scene, s.reference_camera(32, 24))
    (m,) = masks_from_labels([op], np.ones(len(s.scene), bool), threshold=None)
    assert np.allclose(m, op.rendering.alpha, atol=1e-5)
    # The convenience wrapper builds the same operator.
    (m2,) = render_label_masks(s.scene, [s.reference_camera(32, 24)], np.ones(len(s.scene), bool))
    assert np.array_equal(m2, (op.rendering.alpha > 0.5).astype(np.float32))
    with pytest.raises(ValidationError, match="camera"):
        render_label_masks(s.scene, [], s.labels == 1)
    # Per-object masks partition the covered pixels' weight.
    soft = [masks_from_labels([op], s.labels == k, threshold=None)[0] for k in range(8)]
    assert np.allclose(np.sum(soft, axis=0), op.rendering.alpha, atol=1e-5)


def _blob_masks(n=6, h=40, w=50):
    yy, xx = np.mgrid[:h, :w]
    return [((yy - 20) ** 2 + (xx - 22) ** 2 <= 64).astype(np.float32) for _ in range(n)]


def test_dilate_and_erode_grow_and_shrink_monotonically():
    masks = _blob_masks(1)
    areas_d = [perturb_masks(masks, "dilate", strength=r)[0].sum() for r in range(4)]
    areas_e = [perturb_masks(masks, "erode", strength=r)[0].sum() for r in range(4)]
    assert areas_d[0] == areas_e[0] == masks[0].sum()
    assert all(a < b for a, b in zip(areas_d, areas_d[1:]))
    assert all(a > b for a, b in zip(areas_e, areas_e[1:]))
    d2 = perturb_masks(masks, "dilate", strength=2)[0]
    e2 = perturb_masks(masks, "erode", strength=2)[0]
    assert np.all(d2 >= masks[0]) and np.all(e2 <= masks[0])
    # A single pixel dilates to the lattice disk of that radius.
    dot = np.zeros((15, 15), np.float32)
    dot[7, 7] = 1
    r = 3
    expect = sum(1 for i in range(-r, r + 1) for j in range(-r, r + 1) if i * i + j * j <= r * r)
    assert perturb_masks([dot], "dilate", strength=r)[0].sum() == expect
    # Unknown pixels stay unknown and do not spread.
    m = masks[0].copy()
    m[:5, :5] = np.nan
    out = perturb_masks([m], "dilate", strength=3)[0]
    assert np.isnan(out[:5, :5]).all() and not np.isnan(out[5:, 5:]).any()


@pytest.mark.parametrize("direction,shift", [(0.0, (5, 0)), (90.0, (0, 5)), ((-3, 4), (-3, 4))])
def test_drift_moves_centroid_by_requested_pixels(direction, shift):
    masks = _blob_masks(1)
    out = perturb_masks(masks, "drift", strength=5, direction=direction, growth="constant")[0]
    c0 = np.argwhere(masks[0] > 0).mean(0)
    c1 = np.argwhere(out > 0).mean(0)
    assert np.allclose(c1 - c0, [shift[1], shift[0]], atol=1e-9)   # (row, col) = (dy, dx)
    assert out.sum() == masks[0].sum()


def test_drift_grows_linearly_along_the_clip():
    masks = _blob_masks(5)
    out = perturb_masks(masks, "drift", strength=8, direction=0.0)
    c0 = np.argwhere(masks[0] > 0).mean(0)
    dx = [np.argwhere(o > 0).mean(0)[1] - c0[1] for o in out]
    assert np.allclose(dx, [0, 2, 4, 6, 8])


def test_drop_and_identity_switch_hit_the_requested_fraction():
    masks = _blob_masks(8)
    other = [np.full((40, 50), 0.25 * (i % 2), np.float32) for i in range(8)]
    out, views = perturb_masks(masks, "drop", rng=1, fraction=0.5, return_views=True)
    assert len(views) == 4
    for i in range(8):
        assert np.isnan(out[i]).all() == (i in views)
        if i not in views:
            assert np.array_equal(out[i], masks[i])
    out, views = perturb_masks(masks, "identity_switch", rng=2, fraction=0.25, other_masks=other,
                               return_views=True)
    assert len(views) == 2
    for i in range(8):
        assert np.array_equal(out[i], other[i] if i in views else masks[i])
    out, views = perturb_masks(masks, "drop", views=[0, -1], return_views=True)
    assert views == [0, 7] and np.isnan(out[7]).all()
    with pytest.raises(ValidationError, match="other_masks"):
        perturb_masks(masks, "identity_switch")


def test_salt_flip_rate_matches_probability_and_spares_unknown():
    rng = np.random.default_rng(0)
    m = (rng.random((200, 300)) < 0.3).astype(np.float32)
    m[:20] = np.nan
    out = perturb_masks([m], "salt", rng=np.random.default_rng(5), strength=0.1)[0]
    known = ~np.isnan(m)
    rate = np.mean(out[known] != m[known])
    n = known.sum()
    assert abs(rate - 0.1) < 5 * np.sqrt(0.1 * 0.9 / n)
    assert np.isnan(out[:20]).all()
    assert set(np.unique(out[known])) <= {0.0, 1.0}


def test_noise_is_deterministic_and_leaves_input_untouched():
    masks = _blob_masks(6)
    before = [m.copy() for m in masks]
    for kind in ("dilate", "erode", "drift", "drop", "salt"):
        a = perturb_masks(masks, kind, rng=11, fraction=0.5)
        b = perturb_masks(masks, kind, rng=np.random.default_rng(11), fraction=0.5)
        assert all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b)), kind
        assert all(x.dtype == np.float32 for x in a)
    assert all(np.array_equal(x, y) for x, y in zip(masks, before))
    assert set(NOISE_KINDS) == {"dilate", "erode", "drift", "drop", "identity_switch", "salt"}


def test_noise_rejects_bad_input():
    masks = _blob_masks(2)
    with pytest.raises(ValidationError, match="unknown noise kind"):
        perturb_masks(masks, "blur")
    with pytest.raises(ValidationError, match=r"masks\[1\]"):
        perturb_masks([masks[0], masks[1] * 2], "salt")
    with pytest.raises(ValidationError, match="fraction"):
        perturb_masks(masks, "drop", fraction=1.5)
    with pytest.raises(ValidationError, match="radius"):
        perturb_masks(masks, "dilate", strength=1.5)
    with pytest.raises(ValidationError, match="single 2-D"):
        perturb_masks(masks[0], "salt")


def test_real_composite_firepit_unicorn(shared_data):
    from seed2gs_inverse.io import read_scene

    fire = read_scene(shared_data / "firepit_562k_sh0.ply")
    uni = read_scene(shared_data / "unicorn_49k_sh3.ply")
    up = np.array([0.0, -1.0, 0.0])                      # both files are COLMAP-like
    anchor = np.array([-0.82, 1.88, -3.28])              # gravel, in front of the fire pit
    pose = pose_on_point(uni, anchor, up, object_up=up, height=0.9, quantile=0.002)
    scene, labels = compose(fire, [(uni, pose)], remove_overlap=True, margin=0.02)
    assert (labels == 1).sum() == len(uni) and scene.sh_degree == 3
    assert 0 <= len(fire) - (labels == 0).sum() < 1000  # only what sat inside the unicorn's box
    h = np.quantile(scene.means[labels == 1].astype(np.float64) @ up, [0.002, 0.998])
    assert np.isclose(h[0], anchor @ up, atol=1e-4) and np.isclose(h[1] - h[0], 0.9, atol=1e-3)
