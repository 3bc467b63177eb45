"""Camera: OpenCV convention, look_at, projection and validation."""

import numpy as np
import pytest

from seed2gs_inverse import Camera, ValidationError


def test_look_at_projects_target_to_principal_point():
    cam = Camera.look_at([3.0, -2.0, 5.0], [0.5, 0.2, -1.0], [0, -1, 0], 50, 320, 240)
    uv, z = cam.project(np.array([[0.5, 0.2, -1.0]]))
    np.testing.assert_allclose(uv[0], [160, 120], atol=1e-9)
    assert z[0] > 0
    np.testing.assert_allclose(np.linalg.norm(cam.center - [3, -2, 5]), 0, atol=1e-12)


def test_look_at_up_appears_up_and_right_is_right():
    up = np.array([0.0, 0.0, 1.0])  # deliberately +z up
    cam = Camera.look_at([5.0, 0, 0], [0, 0, 0], up, 60, 100, 80)
    (u0, v0), (u_up, v_up) = cam.project(np.array([[0, 0, 0], [0, 0, 1.0]]))[0]
    assert v_up < v0 and abs(u_up - u0) < 1e-9          # image y grows downwards
    np.testing.assert_allclose(cam.up, up, atol=1e-12)
    np.testing.assert_allclose(cam.forward, [-1, 0, 0], atol=1e-12)
    # right-handed OpenCV frame: x = y cross z
    r = cam.rotation
    np.testing.assert_allclose(np.cross(r[1], r[2]), r[0], atol=1e-12)


def test_fov_and_intrinsics():
    cam = Camera.from_fov(200, 100, 90.0)
    assert np.isclose(cam.fy, 50.0) and np.isclose(np.degrees(cam.fov_y), 90.0)
    assert cam.image_shape == (100, 200)
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (100, 50)
    assert np.isclose(half.fx, 25.0) and np.isclose(half.cx, 50.0)
    # known values with unequal focal lengths, an odd size, and unequal scale factors
    assert Camera(200, 100, 50.0, 80.0, 100.0, 50.0).fov_x == pytest.approx(2 * np.arctan(2.0))
    assert Camera(200, 100, 50.0, 80.0, 100.0, 50.0).fov_y == pytest.approx(2 * np.arctan(100 / 160))
    odd = Camera.from_fov(201, 101, 60.0)
    assert (odd.cx, odd.cy) == (100.5, 50.5)
    c = Camera(1000, 3, 400.0, 300.0, 480.0, 1.2)
    s = c.scaled(0.5)  # 500 x 2 (1.5 rounds to 2): sx = 0.5, sy = 2/3
    assert (s.width, s.height) == (500, 2)
    np.testing.assert_allclose([s.fx, s.fy, s.cx, s.cy], [200.0, 200.0, 240.0, 0.8])


def test_pixel_centre_convention():
    # A point on the ray through the centre of pixel (0, 0) projects to (0.5, 0.5).
    cam = Camera(4, 4, 2.0, 2.0, 2.0, 2.0)
    uv, _ = cam.project(np.array([[(0.5 - 2.0) / 2.0, (0.5 - 2.0) / 2.0, 1.0]]))
    np.testing.assert_allclose(uv[0], [0.5, 0.5])


def test_dict_round_trip():
    cam = Camera.look_at([1, 2, 3], [0, 0, 0], [0, 1, 0], 40, 64, 48, name="ref")
    back = Camera.from_dict(cam.to_dict())
    np.testing.assert_array_equal(back.world_to_camera, cam.world_to_camera)
    assert back.name == "ref" and back.width == 64


def test_camera_to_world_inverse():
    cam = Camera.look_at([1, 2, 3], [0, 0, 0], [0, 1, 0], 40, 64, 48)
    np.testing.assert_allclose(cam.camera_to_world @ cam.world_to_camera, np.eye(4), atol=1e-12)
    again = Camera.from_camera_to_world(64, 48, cam.fx, cam.fy, cam.cx, cam.cy, cam.camera_to_world)
    np.testing.assert_allclose(again.world_to_camera, cam.world_to_camera, atol=1e-12)


@pytest.mark.parametrize("kw,match", [
    (dict(width=0), "width must be positive"),
    (dict(width=1e308), r"width must be at most 32768 pixels \(a corrupt file\?\), got 1e\+308"),
    (dict(height=10 ** 400), "height must be at most 32768"),
    (dict(width=32769), "width"),
    (dict(width=True), "integer"),
    (dict(fx=-1.0), "focal lengths must be positive"),
    (dict(fy=10 ** 400), "fy is not finite"),
    (dict(cx=np.inf), "cx is not finite"),
    (dict(cy="5"), "cy must be a number"),
    (dict(near=0.0), "near"),
    (dict(world_to_camera=[[10 ** 400] * 4] * 4), "world_to_camera"),
    (dict(height=-3), "height"),
    (dict(fx=0.0), "focal"),
    (dict(fy=np.nan), "not finite"),
    (dict(world_to_camera=np.diag([1.0, 1, 1, 1]) * 2), "orthonormal"),
    (dict(world_to_camera=np.diag([1.0, 1, -1, 1])), "orthonormal"),
    (dict(world_to_camera=np.full((4, 4), np.inf)), "non-finite"),
    (dict(world_to_camera=np.eye(3)), "4x4"),
    (dict(width=2.5), "integer"),
])
def test_degenerate_cameras_rejected(kw, match):
    # every path that builds a Camera (readers, from_dict, scaled) goes through these checks
    args = dict(width=10, height=10, fx=5.0, fy=5.0, cx=5.0, cy=5.0, world_to_camera=np.eye(4))
    args.update(kw)
    with pytest.raises(ValidationError, match=match):
        Camera(**args)


def test_look_at_degenerate():
    with pytest.raises(ValidationError, match="coincide"):
        Camera.look_at([0, 0, 0], [0, 0, 0], [0, 1, 0], 60, 10, 10)
    with pytest.raises(ValidationError, match="parallel"):
        Camera.look_at([0, 0, 0], [0, 1, 0], [0, 1, 0], 60, 10, 10)
    with pytest.raises(ValidationError, match="fov"):
        Camera.look_at([0, 0, 1], [0, 0, 0], [0, 1, 0], 180, 10, 10)


def test_largest_image_side_is_accepted():
    cam = Camera(32768, 1, 5.0, 5.0, 0.0, 0.0, name="wide")
    assert cam.width == 32768 and isinstance(cam.width, int)
    with pytest.raises(ValidationError, match="camera 'wide': width"):
        cam.scaled(2.0)


def test_from_dict_overflow_is_validation_error():
    d = Camera(10, 10, 5.0, 5.0, 5.0, 5.0).to_dict()
    with pytest.raises(ValidationError, match="near is not finite"):
        Camera.from_dict({**d, "near": 10 ** 400})


def test_look_at_judges_up_by_its_direction_not_its_length():
    short = Camera.look_at([0, 0, 5], [0, 0, 0], [0, 1e-10, 0], 60, 64, 48)  # was "parallel"
    unit = Camera.look_at([0, 0, 5], [0, 0, 0], [0, 1, 0], 60, 64, 48)
    np.testing.assert_allclose(short.world_to_camera, unit.world_to_camera, atol=1e-15)
    with pytest.raises(ValidationError, match="parallel"):  # a long up nearly along the view was taken
        Camera.look_at([0, 0, 5], [0, 0, 0], [1e-8, 0, -1e3], 60, 64, 48)


def test_camera_to_world_needs_a_rigid_last_row_and_points_are_m_by_3():
    c2w = np.eye(4)
    c2w[3] = [0.3, 0, 0, 7]
    with pytest.raises(ValidationError, match="last row"):
        Camera.from_camera_to_world(64, 48, 50, 50, 32, 24, c2w)
    cam = Camera.from_camera_to_world(64, 48, 50, 50, 32, 24, np.eye(4))
    with pytest.raises(ValidationError, match=r"\(M, 3\) array.*\[point\]"):
        cam.project([0, 0, 1])
    uv, z = cam.project([[0, 0, 1]])
    np.testing.assert_allclose(uv, [[32, 24]])
    np.testing.assert_allclose(z, [1])


def test_orbit_helpers_check_their_unit_vectors():
    from seed2gs_inverse.camera import orbit_directions
    from seed2gs_inverse.geometry import frame_for_up

    d = orbit_directions([0, 0, 1], [1, 0, 0], [0.0, 1.0], [0.0, 0.5])
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    for axis, start in (([0, 0, 2], [1, 0, 0]), ([0, 0, 1], [1, 0, 0.1]), ([0, 0, 1], [2, 0, 0])):
        with pytest.raises(ValidationError, match="unit vectors"):  # axis [0, 0, 2] gave a direction of length 3.6
            orbit_directions(axis, start, [1.0], [1.0])
    with pytest.raises(ValidationError, match="unit 3-vector"):
        frame_for_up([0, 0, 2])
