"""Rotation helpers (geometry.py) against scipy's Rotation, and the shared orbit helpers of camera.py.

The VAAS and synthetic orbits now go through ``camera.look_at_orbit``; the tests at
the end recompute their poses with the formulas they used before the move
(copied here from the previous ``pipeline/vaas.py`` and ``synthetic.py``) and
require the same bits for VAAS.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from seed2gs_inverse import Camera, ValidationError
from seed2gs_inverse.camera import look_at_orbit, orbit_directions
from seed2gs_inverse.geometry import axis_angle, cross_matrix, frame_for_up, rotation_between, unit_vector

_vec = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).map(np.array).filter(
    lambda v: np.linalg.norm(v) > 1e-3)


def _proper(r, atol=1e-12):
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=atol)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=atol)


@given(_vec, st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3))
def test_cross_matrix_is_the_cross_product(v, w):
    np.testing.assert_allclose(cross_matrix(v) @ np.array(w), np.cross(v, w), atol=1e-15)


@settings(max_examples=200)
@given(_vec, st.floats(-2 * np.pi, 2 * np.pi))
def test_axis_angle_matches_scipy(axis, angle):
    k = axis / np.linalg.norm(axis)
    r = axis_angle(k, angle)
    np.testing.assert_allclose(r, Rotation.from_rotvec(k * angle).as_matrix(), atol=1e-12)
    _proper(r)


def test_axis_angle_known_values():
    # A quarter turn about +z takes x to y (right hand); a half turn about x flips y and z.
    np.testing.assert_allclose(axis_angle(np.array([0.0, 0, 1]), np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(axis_angle(np.array([1.0, 0, 0]), np.pi), np.diag([1.0, -1, -1]), atol=1e-15)


@settings(max_examples=200)
@given(_vec, _vec)
def test_rotation_between_matches_scipy(a, b):
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    c = float(a @ b)
    r = rotation_between(a, b)
    # The [v]x^2 / (1 + c) term loses digits as b nears -a: rounding grows like eps / (1 + c).
    _proper(r, atol=max(1e-12, 1e-14 / max(1 + c, 1e-12)))
    np.testing.assert_allclose(r @ a, b, atol=1e-9)
    axis = np.cross(a, b)
    if c > -1 + 1e-6 and np.linalg.norm(axis) > 1e-6:
        # The smallest rotation: about a x b by the angle between a and b.
        ref = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.arccos(np.clip(c, -1, 1))).as_matrix()
        np.testing.assert_allclose(r, ref, atol=1e-8)


@pytest.mark.parametrize("a", [[1.0, 0, 0], [0, 0, 1.0], [0.6, -0.8, 0], [1 / 3, 2 / 3, 2 / 3]])
def test_rotation_between_opposite_vectors_is_a_half_turn(a):
    a = np.array(a)
    r = rotation_between(a, -a)
    _proper(r)
    np.testing.assert_allclose(r @ a, -a, atol=1e-12)
    # A half turn: R^2 = I and the rotation angle is pi.
    np.testing.assert_allclose(r @ r, np.eye(3), atol=1e-12)
    assert np.linalg.norm(Rotation.from_matrix(r).as_rotvec()) == pytest.approx(np.pi)


def test_rotation_between_equal_vectors_is_identity():
    a = np.array([0.0, 0.6, 0.8])
    np.testing.assert_allclose(rotation_between(a, a), np.eye(3), atol=1e-15)


@given(_vec)
def test_frame_for_up_is_right_handed_with_up_third(up):
    up = up / np.linalg.norm(up)
    f = frame_for_up(up)
    _proper(f)
    np.testing.assert_allclose(f[:, 2], up, atol=1e-15)
    np.testing.assert_allclose(np.cross(f[:, 0], f[:, 1]), up, atol=1e-12)


def test_frame_for_up_minus_y_keeps_world_x():
    np.testing.assert_allclose(frame_for_up(np.array([0.0, -1, 0])),
                               [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-15)


@pytest.mark.parametrize("bad", [[0, 0, 0], [1, 2], [np.nan, 0, 1], "up"])
def test_unit_vector_rejects_bad_input_naming_it(bad):
    with pytest.raises(ValidationError, match="'object_up'"):
        unit_vector("object_up", bad)


def test_unit_vector_normalises():
    np.testing.assert_allclose(unit_vector("v", [3, 0, 4]), [0.6, 0, 0.8])
    np.testing.assert_allclose(unit_vector("v", [1e308] * 3), np.full(3, 3 ** -0.5))  # |v| overflows
    with pytest.raises(ValidationError, match=r"'v' must be a finite non-zero 3-vector, got \[1, \[2\], 3\]"):
        unit_vector("v", [1, [2], 3])  # ragged: the message shows it as given


# ---------------------------------------------------------------------------
# look_at_orbit
# ---------------------------------------------------------------------------
def test_orbit_directions_geometry():
    u = np.array([0.2, -0.9, 0.3])
    u /= np.linalg.norm(u)
    s = frame_for_up(u)[:, 0]
    az = np.radians([0.0, 30.0, 200.0, -75.0])
    el = np.radians([0.0, 15.0, -20.0, 60.0])
    d = orbit_directions(u, s, az, el)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(np.arcsin(d @ u), el, atol=1e-12)
    for dk, a in zip(d, az):
        horiz = dk - (dk @ u) * u
        np.testing.assert_allclose(horiz / np.linalg.norm(horiz), Rotation.from_rotvec(u * a).apply(s), atol=1e-12)
    with pytest.raises(ValidationError, match="azimuths"):
        orbit_directions(u, s, [0, 1], [0])


def test_look_at_orbit_geometry():
    o = np.array([0.5, -1.0, 2.0])
    u = np.array([0.2, -0.9, 0.3])
    u /= np.linalg.norm(u)
    d = orbit_directions(u, frame_for_up(u)[:, 0], np.radians([0.0, 30.0, 200.0]), np.radians([0.0, 15.0, -20.0]))
    cams = look_at_orbit(o, d, 3.0, u, 45.0, 64, 48, names=["a", "b", "c"])
    assert [c.name for c in cams] == ["a", "b", "c"]
    for c, dk in zip(cams, d):
        np.testing.assert_allclose(c.center, o + 3.0 * dk, atol=1e-12)
        uv, _ = c.project(o[None])
        np.testing.assert_allclose(uv[0], [c.cx, c.cy], atol=1e-9)  # looks at the centre
        assert c.up @ u > 0  # image up along the axis
        assert (c.width, c.height) == (64, 48) and np.degrees(c.fov_y) == pytest.approx(45.0)


def test_look_at_orbit_validates():
    with pytest.raises(ValidationError, match="names"):
        look_at_orbit(np.zeros(3), [[1.0, 0, 0], [0, 1.0, 0]], 2.0, [0, 0, 1.0], 40, 32, 32, names=["x"])
    with pytest.raises(ValidationError, match="center"):
        look_at_orbit([np.nan, 0, 0], [[1.0, 0, 0]], 2.0, [0, 0, 1.0], 40, 32, 32)


# ---------------------------------------------------------------------------
# The poses are those of the formulas before the move
# ---------------------------------------------------------------------------
def _old_rodrigues(axis, angle):
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def _old_vaas_poses(reference, center, azimuths_deg, elevations_deg=None, up=None):
    """The world_to_camera poses of pipeline.vaas.orbit_cameras before geometry.py (its loop, copied)."""
    from seed2gs_inverse.pipeline.vaas import _frame

    o, u, e1, dist, e0 = _frame(reference, center, up)
    az = np.radians(np.asarray(azimuths_deg, dtype=np.float64).ravel())
    el = np.full(az.shape, e0) if elevations_deg is None else np.radians(
        np.asarray(elevations_deg, dtype=np.float64).ravel())
    poses = []
    for a, e in zip(az, el):
        if abs(a) < 1e-12 and abs(e - e0) < 1e-12:
            poses.append(reference.world_to_camera)
            continue
        horiz = _old_rodrigues(u, a) @ e1
        eye = o + dist * (np.cos(e) * horiz + np.sin(e) * u)
        poses.append(Camera.look_at(eye, o, u, np.degrees(reference.fov_y), 8, 8).world_to_camera)
    return poses


@pytest.mark.parametrize("fit_radius", [None, 0.4])
@pytest.mark.parametrize("up", [None, (0.1, -1.0, 0.05)])
def test_vaas_orbit_poses_are_bit_identical_to_before(fit_radius, up):
    from seed2gs_inverse.pipeline.vaas import orbit_cameras

    o = np.array([0.4, -0.2, 1.5])
    u0 = np.array([0.3, -0.9, 0.2]) / np.linalg.norm([0.3, -0.9, 0.2])
    ref = Camera.look_at(o + [2.5, -0.8, 1.0], o + [0.2, 0.1, 0.0], u0, 50, 80, 60)
    az = np.concatenate([360.0 * np.arange(24) / 24, [-33.0, 100.0]])
    for el in (None, np.linspace(5.0, 80.0, az.size)):
        new = orbit_cameras(ref, o, az, el, fit_radius, up)
        old = _old_vaas_poses(ref, o, az, el, up)
        assert len(new) == len(old)
        for a, b in zip(new, old):
            assert np.array_equal(a.world_to_camera, b)
        if el is None:
            assert new[0] is ref
        if fit_radius is None:
            assert all(np.array_equal(c.K, ref.K) for c in new)


def test_synthetic_orbit_is_bit_identical_to_before():
    from seed2gs_inverse.synthetic import make_scene

    ss = make_scene(seed=5, n_per_object=40, up=(0.3, -1.0, 0.2))
    elev = np.array([10.0, 35.0, -5.0, 60.0, 0.0])
    cams = ss.orbit_cameras(5, 96, 64, elevation_deg=elev)
    # SyntheticScene.orbit_cameras before the move: eye = c + d F (cos e cos a, cos e sin a, sin e).
    c, r = ss._objects_sphere()
    probe = Camera.from_fov(96, 64, 50.0)
    dist = 1.1 * r / np.sin(0.5 * min(probe.fov_x, probe.fov_y))
    for i, cam in enumerate(cams):
        a, e = np.radians(-60.0 + 360.0 * i / 5), np.radians(elev[i])
        eye = c + dist * (ss.frame @ [np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        old = Camera.look_at(eye, c, ss.up, 50.0, 96, 64, name=f"orbit_{i:03d}")
        assert np.array_equal(cam.world_to_camera, old.world_to_camera)
        assert cam.name == old.name and np.array_equal(cam.K, old.K)
    # ... and it is the general orbit about the scene's up, from its local x axis, up to rounding.
    d = orbit_directions(ss.up, ss.frame[:, 0], np.radians(-60.0 + 72.0 * np.arange(5)), np.radians(elev))
    np.testing.assert_allclose([(cam.center - c) / dist for cam in cams], d, atol=1e-12)
