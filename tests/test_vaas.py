"""VAAS orbit geometry, visibility, amplitude (Eq. 5) and the skip rule."""

import dataclasses
import numpy as np
import pytest

from seed2gs_inverse import Camera, ValidationError
from seed2gs_inverse.pipeline.vaas import (ClipFrame, flat_orbit, orbit_cameras, run_vaas,
                                           spiral_elevations, spiral_orbit, support_visibility,
                                           vaas_amplitude)


def _reference(up=(0.3, -0.9, 0.2)):
    up = np.asarray(up) / np.linalg.norm(up)
    o = np.array([0.4, -0.2, 1.5])
    # Off-centre target: the reference does not look exactly at o.
    return Camera.look_at(o + np.array([2.5, -0.8, 1.0]), o + np.array([0.2, 0.1, 0.0]), up, 50, 80, 60), o


def _elev(cam, o, u):
    d = cam.center - o
    h = d @ u
    return np.degrees(np.arctan2(h, np.linalg.norm(d - h * u)))


@pytest.mark.parametrize("up", [(0, -1, 0), (0, 0, 1), (0.3, -0.9, 0.2)])
def test_flat_orbit_geometry(up):
    ref, o = _reference(up)
    u = ref.up
    cams = flat_orbit(ref, o, 12)
    assert len(cams) == 12 and cams[0] is ref
    d0 = ref.center - o
    h0 = d0 @ u
    r0 = np.linalg.norm(d0 - h0 * u)
    e1 = (d0 - h0 * u) / r0
    for k, cam in enumerate(cams):
        d = cam.center - o
        h = d @ u
        hor = d - h * u
        assert h == pytest.approx(h0, abs=1e-9)                 # height kept
        assert np.linalg.norm(hor) == pytest.approx(r0, rel=1e-9)  # radius kept
        ang = np.degrees(np.arctan2(np.cross(e1, hor / r0) @ u, e1 @ hor / r0)) % 360
        assert ang == pytest.approx(360 * k / 12, abs=1e-6)
        np.testing.assert_allclose(cam.K, ref.K)
        if k:
            uv, z = cam.project(o[None])
            assert z[0] > 0
            np.testing.assert_allclose(uv[0], [cam.cx, cam.cy], atol=1e-6)  # looks at o
            assert cam.right @ u == pytest.approx(0, abs=1e-9)  # no roll about the axis
            assert cam.up @ u > 0


def test_spiral_pitch_follows_amplitude():
    ref, o = _reference()
    u = ref.up
    e0 = _elev(ref, o, u)
    for amp in (10.0, 30.0):
        cams = spiral_orbit(ref, o, amp, 9)
        assert cams[0] is ref
        el = np.array([_elev(c, o, u) for c in cams])
        np.testing.assert_allclose(el, e0 + amp * np.arange(9) / 8, atol=1e-6)
        dist = [np.linalg.norm(c.center - o) for c in cams]
        np.testing.assert_allclose(dist, np.linalg.norm(ref.center - o), rtol=1e-9)
        for c in cams[1:]:
            np.testing.assert_allclose(c.project(o[None])[0][0], [c.cx, c.cy], atol=1e-6)
    sin = spiral_elevations(ref, o, 30.0, 9, profile="sin")
    np.testing.assert_allclose(sin, e0 + 30 * np.sin(np.pi / 2 * np.arange(9) / 8), atol=1e-9)
    capped = spiral_elevations(ref, o, 170.0, 5, max_elevation_deg=85.0)
    assert capped.max() == pytest.approx(85.0)


def test_orbit_rejects_degenerate_inputs():
    ref, o = _reference()
    with pytest.raises(ValidationError, match="n_views"):
        flat_orbit(ref, o, 1)
    with pytest.raises(ValidationError, match="centre"):
        flat_orbit(ref, ref.center, 4)
    above = ref.center - 2.0 * ref.up
    with pytest.raises(ValidationError, match="above or below"):
        flat_orbit(ref, above, 4)
    with pytest.raises(ValidationError, match="profile"):
        spiral_orbit(ref, o, 10, 4, profile="zigzag")
    with pytest.raises(ValidationError, match="elevations"):
        orbit_cameras(ref, o, [0, 10], [0])


def test_amplitude_equation():
    assert vaas_amplitude(0.0) == pytest.approx(60.0)
    assert vaas_amplitude(1.0) == 0.0
    assert vaas_amplitude(0.75, 40.0, 2.0) == pytest.approx(40 * 0.25 ** 2)
    assert vaas_amplitude(1.7) == 0.0
    with pytest.raises(ValidationError):
        vaas_amplitude(0.5, gamma=0)


def test_support_visibility_depth_test():
    cam = Camera.look_at([0, 0, -5.0], [0, 0, 0], [0, -1, 0], 60, 40, 30)
    pts = np.array([[0, 0, 0.0], [0.2, 0.1, 0.0], [0, 0, 1.0], [50, 0, 0.0]])
    depth = np.full(cam.image_shape, 5.0)  # a wall at the depth of the first two points
    vis = support_visibility(pts, np.full(4, 0.01), cam, depth)
    assert vis == pytest.approx(0.5)  # 3rd is behind the wall, 4th is out of the image
    # the tolerance 0.02 z + 2 sigma: 0.15 behind the wall at 5 is hidden for a point (0.10 < 0.15) and
    # visible for a Gaussian of sigma 0.1 (0.1 + 0.2 >= 0.15)
    behind = np.array([[0, 0, 0.15]])
    assert support_visibility(behind, np.zeros(1), cam, depth) == 0.0
    assert support_visibility(behind, np.full(1, 0.1), cam, depth) == 1.0


def test_skip_rule_and_visibility_mean():
    ref, o = _reference()
    pts = o[None] + np.zeros((1, 3))
    calls = []

    def view(cam, clip, k):
        calls.append(clip)
        # o is on the optical axis at distance |c - o| in frames k >= 1; make it
        # visible in every other flat frame so that V = 0.5 exactly.
        z = cam.project(pts)[1][0]
        d = np.full(cam.image_shape, z if (k % 2 == 0) else z * 0.5, np.float32)
        if k == 0:
            d[:] = z
        return ClipFrame(np.zeros(cam.image_shape + (3,), np.float32), d,
                         np.ones(cam.image_shape, np.float32), cam, clip, k)

    plan, flat, spiral = run_vaas(pts, np.zeros(1), ref, o, view, n_views=8, a_max_deg=60, gamma=1)
    assert plan.visibility == pytest.approx(0.5)
    assert plan.amplitude_deg == pytest.approx(30.0)
    assert not plan.skipped_spiral and len(spiral) == 8 and calls.count("spiral") == 8
    e = np.array([_elev(c, o, ref.up) for c in plan.spiral])
    np.testing.assert_allclose(e - e[0], 30 * np.arange(8) / 7, atol=1e-6)
    # A = 9 (1 - 0.5) = 4.5 < 5 degrees: near-duplicate spiral is skipped, nothing rendered.
    calls.clear()
    plan, flat, spiral = run_vaas(pts, np.zeros(1), ref, o, view, n_views=8, a_max_deg=9.0)
    assert plan.skipped_spiral and plan.spiral == [] and spiral == [] and "spiral" not in calls
    assert plan.amplitude_deg == pytest.approx(4.5)


def test_estimate_up_removes_the_camera_pitch():
    from seed2gs_inverse.raster import build_operator
    from seed2gs_inverse.pipeline.up_axis import estimate_up
    from seed2gs_inverse.synthetic import make_scene

    for up in [(0, -1, 0), (0.3, 0.2, 0.93)]:
        syn = make_scene(seed=0, up=up)
        cam = syn.reference_camera(64, 48, elevation_deg=40)
        true_up = syn.up / np.linalg.norm(syn.up)
        assert np.degrees(np.arccos(np.clip(cam.up @ true_up, -1, 1))) > 30  # the camera is pitched
        w = np.asarray(build_operator(syn.scene, cam).W.sum(axis=0)).ravel()
        est = estimate_up(syn.scene, cam, weights=w)
        assert np.degrees(np.arccos(np.clip(est @ true_up, -1, 1))) < 3
        assert abs(est @ cam.right) < 1e-9  # no roll is introduced
    # No flat Gaussians: fall back to the camera's image-up.
    iso = dataclasses.replace(syn.scene, log_scales=np.full_like(syn.scene.log_scales, -3.0))
    np.testing.assert_allclose(estimate_up(iso, cam), cam.up)


def test_spiral_about_an_explicit_up_with_fitted_intrinsics():
    """What extract() asks for: an axis ``g`` that is not the reference's image-up, and ``fit_radius``.
    About ``g`` each view's signed azimuth is 360 k / n and its elevation the reference's plus the pitch,
    at the reference's distance; it looks at the centre upright (image-up along ``g``, no roll); its focal
    length puts the tangent rays of the sphere of radius r on the edges of the smaller image side,
    f tan(asin(r / d)) = min(W, H) / 2."""
    ref, o = _reference()
    g = np.array([0.1, -1.0, -0.25])
    g /= np.linalg.norm(g)
    assert abs(ref.up @ g) < 0.99
    n, amp, r = 8, 28.0, 0.6
    cams = spiral_orbit(ref, o, amp, n, fit_radius=r, up=g)
    d0 = ref.center - o
    dist = np.linalg.norm(d0)
    e1 = d0 - (d0 @ g) * g
    e1 /= np.linalg.norm(e1)
    e0 = _elev(ref, o, g)
    f = 0.5 * min(ref.width, ref.height) / np.tan(np.arcsin(r / dist))
    assert cams[0] is ref
    for k, cam in enumerate(cams[1:], start=1):
        d = cam.center - o
        hor = d - (d @ g) * g
        ang = np.degrees(np.arctan2(np.cross(e1, hor) @ g, e1 @ hor)) % 360
        assert ang == pytest.approx(360 * k / n, abs=1e-6)
        assert _elev(cam, o, g) == pytest.approx(e0 + amp * k / (n - 1), abs=1e-6)
        assert np.linalg.norm(d) == pytest.approx(dist, rel=1e-9)
        assert cam.up @ g > 0 and cam.right @ g == pytest.approx(0, abs=1e-9)
        np.testing.assert_allclose(cam.project(o[None])[0][0], [cam.cx, cam.cy], atol=1e-6)
        np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], [f, f, ref.width / 2, ref.height / 2])
