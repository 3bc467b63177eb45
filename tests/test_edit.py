"""Scene edits: remove, duplicate, move (SH rotated), recolour; extras preserved."""

import numpy as np
import pytest

from seed2gs_inverse import GaussianScene, ValidationError
from seed2gs_inverse.edit import duplicate, move, recolour, remove
from seed2gs_inverse.scene import quat_to_rotmat
from seed2gs_inverse.sh import SH_C0, sh_to_rgb


def _scene(rng, n=40, k=16):
    return GaussianScene(rng.normal(size=(n, 3)), rng.normal(size=(n, 4)), rng.normal(-2, 0.3, (n, 3)),
                         rng.normal(size=n), rng.normal(0, 0.3, (n, k, 3)),
                         {"nx": rng.normal(size=n).astype(np.float32), "tag": np.arange(n, dtype=np.int32)})


def _rot(axis, deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = np.radians(deg)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K


def test_remove_keeps_order_and_extras(rng):
    s = _scene(rng)
    sel = np.zeros(len(s), bool)
    sel[[1, 5, 7]] = True
    out = remove(s, sel)
    assert len(out) == len(s) - 3
    np.testing.assert_array_equal(out.extra["tag"], np.delete(np.arange(len(s)), [1, 5, 7]))
    np.testing.assert_array_equal(remove(s, np.array([1, 5, 7])).means, out.means)


def test_move_rotates_about_pivot_and_sh(rng):
    s = _scene(rng)
    sel = np.arange(len(s)) < 10
    R = _rot([0.2, 1, 0.3], 70)
    t = np.array([0.5, -1.0, 2.0])
    pivot = np.array([1.0, 2.0, 3.0])
    out = move(s, sel, R, t, pivot=pivot)
    expect = (s.means[sel].astype(np.float64) - pivot) @ R.T + pivot + t
    np.testing.assert_allclose(out.means[sel], expect, atol=1e-5)
    np.testing.assert_array_equal(out.means[~sel], s.means[~sel])
    np.testing.assert_array_equal(out.sh[~sel], s.sh[~sel])
    # Covariances rotate: R Sigma R^T.
    np.testing.assert_allclose(out.covariances()[sel], R @ s.covariances()[sel] @ R.T, atol=1e-6)
    # View-dependent colour follows: the moved Gaussian seen along R d looks like the original along d.
    d = rng.normal(size=(len(s), 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(sh_to_rgb(out.sh[sel], d[sel] @ R.T), sh_to_rgb(s.sh[sel], d[sel]), atol=1e-4)
    np.testing.assert_array_equal(out.extra["tag"], s.extra["tag"])
    # Default pivot: the centroid, which a pure rotation leaves in place.
    c = s.means[sel].astype(np.float64).mean(0)
    np.testing.assert_allclose(move(s, sel, R).means[sel].astype(np.float64).mean(0), c, atol=1e-5)


def test_duplicate_appends_a_moved_copy(rng):
    s = _scene(rng)
    sel = np.zeros(len(s), bool)
    sel[3:9] = True
    out = duplicate(s, sel, translation=[1, 0, 0])
    assert len(out) == len(s) + 6
    np.testing.assert_array_equal(out.means[: len(s)], s.means)
    np.testing.assert_allclose(out.means[len(s):], s.means[sel] + [1, 0, 0], atol=1e-6)
    np.testing.assert_array_equal(out.extra["tag"][len(s):], s.extra["tag"][sel])
    np.testing.assert_array_equal(out.sh[len(s):], s.sh[sel])


def test_recolour(rng):
    s = _scene(rng)
    sel = np.arange(len(s)) % 2 == 0
    out = recolour(s, sel, [0.2, 0.5, 0.9])
    d = rng.normal(size=(len(s), 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(sh_to_rgb(out.sh[sel], d[sel]), np.tile([0.2, 0.5, 0.9], (sel.sum(), 1)), atol=1e-6)
    np.testing.assert_array_equal(out.sh[~sel], s.sh[~sel])
    keep = recolour(s, sel, lambda rgb: rgb * 0.5, keep_view_dependence=True)
    np.testing.assert_allclose(SH_C0 * keep.sh[sel, 0] + 0.5, 0.5 * (SH_C0 * s.sh[sel, 0] + 0.5), atol=1e-6)
    np.testing.assert_array_equal(keep.sh[sel, 1:], s.sh[sel, 1:])
    with pytest.raises(ValidationError, match="empty"):
        recolour(s, np.zeros(len(s), bool), [1, 0, 0])
    with pytest.raises(ValidationError, match="rgb"):
        recolour(s, sel, [1, 0])
    with pytest.raises(ValidationError, match="selected"):
        recolour(s, np.ones(3, bool), [1, 0, 0])


def test_recolour_rows_follow_the_given_indices_and_empty_lists_select_nothing(rng):
    s = _scene(rng)
    out = recolour(s, [7, 2], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # 7 red, 2 green
    np.testing.assert_allclose(SH_C0 * out.sh[[7, 2], 0].astype(np.float64) + 0.5, [[1, 0, 0], [0, 1, 0]], atol=1e-6)
    seen = []
    recolour(s, [7, 2], lambda rgb: seen.append(rgb.copy()) or rgb)
    np.testing.assert_array_equal(seen[0], SH_C0 * s.sh[[7, 2], 0].astype(np.float64) + 0.5)
    with pytest.raises(ValidationError, match="more than once"):
        recolour(s, [2, 2], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    np.testing.assert_array_equal(remove(s, []).means, s.means)  # [] is float64 to numpy
    with pytest.raises(ValidationError, match="empty"):
        recolour(s, [], [1.0, 0.0, 0.0])


def test_edits_round_trip_through_ply(rng, tmp_path):
    from seed2gs_inverse.io import read_scene, write_scene

    s = _scene(rng)
    out = move(s, np.arange(len(s)) < 5, _rot([0, 0, 1], 30), [0, 1, 0])
    write_scene(tmp_path / "e.ply", out)
    back = read_scene(tmp_path / "e.ply")
    np.testing.assert_allclose(back.means, out.means)
    np.testing.assert_allclose(back.sh, out.sh, atol=1e-6)
    assert set(back.extra) >= {"nx", "tag"}


def test_translation_only_keeps_the_stored_quaternions_and_scenes_pickle(rng):
    import pickle

    s = _scene(rng)  # unnormalised quaternions, as files may hold them
    log_scales, sh = s.log_scales.copy(), s.sh.copy()
    log_scales[0, 0], sh[0, 1, 0] = -0.0, -0.0  # kept bit for bit too (log(1) or a rotation would make +0.0)
    s = GaussianScene(s.means, s.quats, log_scales, s.opacity_logits, sh, dict(s.extra))
    out = move(s, np.arange(5), translation=[1.0, 0.0, 0.0])
    for name in ("quats", "log_scales", "sh"):
        np.testing.assert_array_equal(getattr(out, name).view(np.uint32), getattr(s, name).view(np.uint32))
    np.testing.assert_allclose(out.means[:5], s.means[:5] + np.float32([1, 0, 0]), atol=1e-6)
    back = pickle.loads(pickle.dumps(s))
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        np.testing.assert_array_equal(getattr(back, name), getattr(s, name))
        assert not getattr(back, name).flags.writeable
    assert dict(back.extra).keys() == dict(s.extra).keys() and not back.extra["tag"].flags.writeable
    np.testing.assert_array_equal(back.extra["tag"], s.extra["tag"])
