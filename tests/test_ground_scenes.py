"""Procedural ground-with-clutter scenes: labels, contact, world rotation, cameras."""

from __future__ import annotations

import time

import numpy as np
import pytest

from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.synthetic.ground import (CLUTTER_KINDS, OBJECT_KINDS, GroundScene, make_ground_scene,
                                           place_object)
from seed2gs_inverse.scene import GaussianScene, quat_to_rotmat


def _normals(scene: GaussianScene) -> np.ndarray:
    """Axis of the smallest scale of each Gaussian (brute force from the rotation matrices)."""
    rot = quat_to_rotmat(scene.quats)
    k = np.argmin(scene.scales, axis=1)
    return rot[np.arange(len(scene)), :, k]


def test_labels_and_names_are_consistent():
    g = make_ground_scene(1)
    assert g.names[:2] == ("ground", "clutter")
    assert set(g.object_names) == set(OBJECT_KINDS)
    assert g.labels.shape == (len(g.scene),) and g.labels.dtype == np.int32
    assert np.array_equal(np.unique(g.labels), np.arange(len(g.names)))
    for name in g.names:
        assert g.object_mask(name).sum() > 40
    with pytest.raises(ValidationError, match="no part named"):
        g.label_of("chair")


def test_deterministic_by_seed_and_fast():
    t0 = time.perf_counter()
    a = make_ground_scene(7)
    assert time.perf_counter() - t0 < 1.0
    b = make_ground_scene(7)
    c = make_ground_scene(8)
    assert np.array_equal(a.scene.means, b.scene.means) and np.array_equal(a.labels, b.labels)
    assert not np.allclose(a.up, c.up)


def test_rotation_applied_and_ground_normals_follow_up():
    g = make_ground_scene(3, uneven=0.0)
    assert np.allclose(g.rotation @ g.rotation.T, np.eye(3), atol=1e-9)
    assert np.allclose(g.up, g.rotation[:, 2]) and np.isclose(np.linalg.norm(g.up), 1)
    assert abs(g.up @ np.array([0, 0, 1.0])) < 0.999  # not left at an axis
    n = _normals(g.scene)
    ground = g.object_mask("ground")
    # Flat ground: every ground Gaussian is centred on the plane and faces up.
    assert np.abs((g.scene.means[ground] - g.ground_point) @ g.ground_normal).max() < 1e-5
    assert np.abs(n[ground] @ g.up).min() > 0.999
    # Clutter is vertical: its flat Gaussians' normals are within 25 degrees of horizontal.
    cl = g.object_mask("clutter")
    assert np.abs(n[cl] @ g.up).max() < np.sin(np.radians(25))
    # ... and there are more of them than ground ones (they dominate normal statistics).
    assert cl.sum() > 1.5 * ground.sum()


@pytest.mark.parametrize("uneven", [0.0, 0.05])
def test_objects_rest_on_the_ground(uneven):
    g = make_ground_scene(5, uneven=uneven)
    gm = g.scene.means[g.object_mask("ground")].astype(np.float64)
    for name in g.object_names:
        pts = g.scene.means[g.object_mask(name)].astype(np.float64)
        gap = g.ground_height(pts)
        assert abs(gap.min()) < 1e-4, name          # touching ...
        assert gap.min() > -1e-4                   # ... and not sunk
        # Independent of the height field: the nearest ground Gaussians below the
        # lowest object point are within a ground sample spacing of it.
        low = pts[np.argmin(gap)]
        d = np.linalg.norm(gm - low, axis=1)
        assert d.min() < 0.08, name
        assert np.isclose(g.ground_height(g.anchors[name][None])[0], 0, atol=1e-6)


def test_camera_elevation_is_measured_from_the_ground_plane():
    g = make_ground_scene(2)
    target = g.object_center("table")
    for az, el in [(0, 10), (135, 45), (-60, 70)]:
        cam = g.camera("table", az, el, 3.0, 64, 48)
        d = cam.center - target
        assert np.isclose(np.linalg.norm(d), 3.0)
        assert np.isclose(np.degrees(np.arcsin(d @ g.up / 3.0)), el, atol=1e-6)
        assert abs(cam.right @ g.up) < 1e-9            # no roll
        assert np.allclose(cam.forward, -d / 3.0)     # looks at the target
    a, b = g.camera("table", 0, 20, 3.0), g.camera("table", 90, 20, 3.0)
    da, db = a.center - target, b.center - target
    ha, hb = da - (da @ g.up) * g.up, db - (db @ g.up) * g.up
    assert np.isclose(np.degrees(np.arccos(ha @ hb / np.linalg.norm(ha) / np.linalg.norm(hb))), 90, atol=1e-6)
    # right-handed about up: the cross product of the horizontals points up
    assert np.cross(ha, hb) @ g.up > 0


def test_place_object_stands_a_file_object_in_contact():
    g = make_ground_scene(4, objects=("box",), uneven=0.05)
    # An "object file": a tilted ellipsoid of random Gaussians whose own up is -y.
    rng = np.random.default_rng(0)
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    obj = GaussianScene(d * [0.1, 0.3, 0.15] + [5, 5, 5], rng.normal(size=(400, 4)),
                        np.full((400, 3), np.log(0.01)), np.zeros(400), np.zeros((400, 1, 3)))
    out = place_object(g, obj, at=(1.2, -0.4), object_up=(0, -1, 0), height=0.5, name="egg")
    assert isinstance(out, GroundScene) and out.names[-1] == "egg"
    m = out.object_mask("egg")
    assert m.sum() == 400 and np.array_equal(out.labels[~m][: 10], g.labels[: 10])
    pts = out.scene.means[m].astype(np.float64)
    gap = out.ground_height(pts)
    assert abs(gap.min()) < 1e-4
    assert np.isclose(np.ptp(pts @ out.up), 0.5, rtol=1e-4)  # height along the true up
    loc = out.to_local(pts)
    assert np.allclose(np.median(loc[:, :2], axis=0), [1.2, -0.4], atol=1e-4)
    # The object's own up (-y, its long axis of 0.3) now lies along the world up.
    assert np.allclose(np.abs(np.linalg.svd(pts - pts.mean(0))[2][0] @ out.up), 1, atol=0.05)
    # No clutter left inside its footprint; the other objects keep their labels.
    cl = out.object_mask("clutter")
    r = np.linalg.norm(out.to_local(out.scene.means[cl])[:, :2] - [1.2, -0.4], axis=1)
    assert r.min() > np.max(np.linalg.norm(loc[:, :2] - [1.2, -0.4], axis=1))
    assert out.object_mask("box").sum() == g.object_mask("box").sum()
    with pytest.raises(ValidationError, match="already exists"):
        place_object(out, obj, name="egg")


def test_validation():
    with pytest.raises(ValidationError, match="unknown object kind"):
        make_ground_scene(0, objects=("chair",))
    with pytest.raises(ValidationError, match="unknown clutter kind"):
        make_ground_scene(0, clutter=("tree",))
    with pytest.raises(ValidationError, match="extent"):
        make_ground_scene(0, extent=-1)
    g = make_ground_scene(0, objects=("box",), clutter=())
    assert set(CLUTTER_KINDS) and g.object_mask("clutter").sum() == 0
    with pytest.raises(ValidationError, match="elevation"):
        g.camera("box", 0, 95, 2.0)
