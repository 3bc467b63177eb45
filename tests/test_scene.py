"""GaussianScene: validation, activations, edits, SH rotation (known values)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from seed2gs_inverse import GaussianScene, ValidationError
from seed2gs_inverse.sh import SH_C0, eval_sh, rotate_sh, sh_basis


def random_scene(rng, n=20, degree=3, extra=True):
    k = (degree + 1) ** 2
    return GaussianScene(
        rng.normal(size=(n, 3)), rng.normal(size=(n, 4)), rng.normal(size=(n, 3)) - 2,
        rng.normal(size=n), rng.normal(size=(n, k, 3)) * 0.3,
        {"nx": np.zeros(n, np.float32), "label": np.arange(n)} if extra else {})


def unit(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_arrays_are_float32_and_len(rng):
    s = random_scene(rng)
    assert len(s) == 20 and s.sh_degree == 3
    for arr in (s.means, s.quats, s.log_scales, s.opacity_logits, s.sh):
        assert arr.dtype == np.float32 and arr.flags.c_contiguous


def test_activations_known_values():
    s = GaussianScene(np.zeros((3, 3)), [[2, 0, 0, 0], [0, 0, 0, 3], [1, 1, 1, 1]],
                      np.log([[1, 2, 4]] * 3), [0.0, np.log(3.0), -np.log(3.0)], np.zeros((3, 1, 3)))
    np.testing.assert_allclose(s.opacities, [0.5, 0.75, 0.25], rtol=1e-6)
    np.testing.assert_allclose(s.scales, [[1, 2, 4]] * 3, rtol=1e-6)
    np.testing.assert_allclose(s.rotations, [[1, 0, 0, 0], [0, 0, 0, 1], [0.5] * 4], atol=1e-7)
    # at chosen rows (indices or a mask): the known values there, computed there alone
    np.testing.assert_allclose(s.opacities_at([2, 0]), [0.25, 0.5], rtol=1e-6)
    np.testing.assert_allclose(s.scales_at(np.array([False, True, False])), [[1, 2, 4]], rtol=1e-6)
    assert s.opacities_at([1]).dtype == np.float32 and s.scales_at([1]).shape == (1, 3)


def test_activations_at_rows_are_the_activations_rows(rng):
    s = random_scene(rng, n=200)
    rows = rng.choice(200, 50, replace=False)
    np.testing.assert_array_equal(s.opacities_at(rows), s.opacities[rows])
    np.testing.assert_array_equal(s.scales_at(rows), s.scales[rows])


def test_covariance_matches_scipy_rotation(rng):
    s = random_scene(rng, extra=False)
    q = s.quats.astype(np.float64)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    rot = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy is scalar-last
    sig = np.exp(2 * s.log_scales.astype(np.float64))
    expected = np.einsum("nij,nj,nkj->nik", rot, sig, rot)
    np.testing.assert_allclose(s.covariances(), expected, rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("field,value,match", [
    ("means", np.zeros((4, 2)), "means"),
    ("quats", np.zeros((4, 4)), "zero-length"),
    ("log_scales", np.full((4, 3), np.nan), "non-finite values in 4 of 4"),
    ("opacity_logits", np.zeros(3), "has 3 rows"),
    ("sh", np.zeros((4, 5, 3)), "sh"),
    ("means", np.array([["a"] * 3] * 4), "dtype"),
])
def test_validation_names_the_array(field, value, match):
    kw = dict(means=np.zeros((4, 3)), quats=np.tile([1.0, 0, 0, 0], (4, 1)),
              log_scales=np.zeros((4, 3)), opacity_logits=np.zeros(4), sh=np.zeros((4, 1, 3)))
    kw[field] = value
    with pytest.raises(ValidationError, match=match):
        GaussianScene(**kw)


def test_extra_length_checked():
    with pytest.raises(ValidationError, match="extra property 'foo'"):
        GaussianScene(np.zeros((2, 3)), np.tile([1.0, 0, 0, 0], (2, 1)), np.zeros((2, 3)),
                      np.zeros(2), np.zeros((2, 1, 3)), {"foo": np.zeros(3)})


def test_subset_and_concat(rng):
    a, b = random_scene(rng), random_scene(rng, n=5, degree=1, extra=False)
    sub = a.subset(np.arange(20) % 2 == 0)
    assert len(sub) == 10
    np.testing.assert_array_equal(sub.extra["label"], np.arange(0, 20, 2))
    np.testing.assert_array_equal(a.subset([3, 1]).means, a.means[[3, 1]])
    with pytest.raises(ValidationError):
        a.subset(np.ones(19, bool))
    with pytest.raises(ValidationError):
        a.subset([20])
    c = GaussianScene.concat([a, b])
    assert len(c) == 25 and c.sh_degree == 3
    np.testing.assert_array_equal(c.sh[20:, :4], b.sh)
    assert not c.sh[20:, 4:].any()
    assert c.extra == {}  # extras not present in every part are dropped
    d = GaussianScene.concat([a, a])
    np.testing.assert_array_equal(d.extra["label"], np.r_[np.arange(20), np.arange(20)])


def test_sh_degree1_rotation_known_value(rng):
    # Degree 1 is linear in d: C1 * (-y c1 + z c2 - x c3) = C1 v.d with
    # v = (-c3, -c1, c2). Rotating the object rotates v: v' = R v.
    rot = Rotation.random(random_state=3).as_matrix()
    sh = rng.normal(size=(4, 4, 3))
    out = rotate_sh(sh, rot)
    v = np.stack([-sh[:, 3], -sh[:, 1], sh[:, 2]], axis=1)  # (n, 3 xyz, 3 rgb)
    v_rot = np.einsum("ij,njc->nic", rot, v)
    np.testing.assert_allclose(out[:, 3], -v_rot[:, 0], atol=1e-12)
    np.testing.assert_allclose(out[:, 1], -v_rot[:, 1], atol=1e-12)
    np.testing.assert_allclose(out[:, 2], v_rot[:, 2], atol=1e-12)
    np.testing.assert_allclose(out[:, 0], sh[:, 0], atol=1e-12)


def test_transformed_scene_colour_follows_object(rng):
    # Rendering-free check: the moved scene seen along R d shows what the
    # original showed along d, for every SH degree.
    for degree in range(4):
        s = random_scene(rng, degree=degree)
        rot = Rotation.random(random_state=degree).as_matrix()
        moved = s.transformed(rot, [0.5, -1.0, 2.0], scale=1.7)
        d = unit(rng, len(s))
        np.testing.assert_allclose(eval_sh(moved.sh, d @ rot.T), eval_sh(s.sh, d), atol=2e-5)


def test_transformed_geometry(rng):
    s = random_scene(rng)
    rot = Rotation.random(random_state=7).as_matrix()
    t = np.array([1.0, 2.0, 3.0])
    m = s.transformed(rot, t, scale=2.0)
    np.testing.assert_allclose(m.means, 2.0 * s.means @ rot.T + t, atol=1e-5)
    np.testing.assert_allclose(m.covariances(), 4.0 * rot @ s.covariances() @ rot.T,
                               rtol=1e-4, atol=1e-6)
    np.testing.assert_array_equal(m.opacity_logits, s.opacity_logits)
    np.testing.assert_array_equal(m.extra["label"], s.extra["label"])
    with pytest.raises(ValidationError, match="rotation"):
        s.transformed(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValidationError, match="scale"):
        s.transformed(scale=0.0)


def test_sh_basis_normalisation():
    # Real SH are orthonormal on the sphere: (4 pi / M) sum Y_i Y_j ~ I.
    rng = np.random.default_rng(0)
    d = unit(rng, 200000)
    y = sh_basis(d, 3)
    gram = 4 * np.pi * (y.T @ y) / len(d)
    np.testing.assert_allclose(gram, np.eye(16), atol=0.03)
    assert np.isclose(y[0, 0], SH_C0)


# --------------------------------------------------------------------------
# a validated scene cannot be changed behind the checks' back (issue 12, item 6)

_FIELDS = ("means", "quats", "log_scales", "opacity_logits", "sh")


def test_arrays_are_read_only_after_validation(rng):
    s = random_scene(rng)
    for name in _FIELDS:
        arr = getattr(s, name)
        assert not arr.flags.writeable, name
        with pytest.raises(ValueError, match="read-only"):
            arr.flat[0] = np.nan
    with pytest.raises(ValueError, match="read-only"):
        s.means[3] = np.nan  # the reproducer: NaN written after construction
    with pytest.raises(ValueError, match="read-only"):
        s.extra["label"][0] = 7
    with pytest.raises(TypeError):
        s.extra["new"] = np.zeros(len(s))
    import dataclasses

    with pytest.raises(dataclasses.FrozenInstanceError):
        s.means = np.full((len(s), 3), np.nan)
    assert np.all(np.isfinite(s.means))


def test_changes_go_through_a_new_validated_scene(rng):
    import dataclasses

    s = random_scene(rng)
    means = s.means.copy()  # copies are writeable
    means[3] = np.nan
    with pytest.raises(ValidationError, match="'means' has non-finite values in 1 of 20"):
        dataclasses.replace(s, means=means)
    means[3] = 1.0
    moved = dataclasses.replace(s, means=means)
    assert moved.means[3].tolist() == [1, 1, 1] and not moved.means.flags.writeable
    assert np.array_equal(moved.extra["label"], s.extra["label"])
    # copy(), subset() and transformed() give read-only scenes too
    for other in (s.copy(), s.subset(np.arange(5)), s.transformed(translation=[1, 0, 0])):
        assert not any(getattr(other, n).flags.writeable for n in _FIELDS)


def test_caller_arrays_are_not_frozen(rng):
    means = rng.normal(size=(5, 3)).astype(np.float32)  # float32: held without a copy
    s = GaussianScene(means, np.tile([1.0, 0, 0, 0], (5, 1)), np.zeros((5, 3)), np.zeros(5),
                      np.zeros((5, 1, 3)))
    assert means.flags.writeable  # the caller's array keeps working as before
    assert not s.means.flags.writeable and np.shares_memory(s.means, means)


def test_read_scene_gives_read_only_arrays(tmp_path, rng):
    from seed2gs_inverse.io import read_scene, write_scene

    s = random_scene(rng)
    write_scene(tmp_path / "s.ply", GaussianScene(s.means, s.quats, s.log_scales, s.opacity_logits,
                                                  s.sh, {"tag": np.arange(len(s), dtype=np.int32)}))
    got = read_scene(tmp_path / "s.ply")
    assert not any(getattr(got, n).flags.writeable for n in _FIELDS)
    assert not any(v.flags.writeable for v in got.extra.values())


def test_edits_still_work_on_read_only_scenes(rng):
    from seed2gs_inverse import edit

    s = random_scene(rng)
    sel = np.arange(20) < 5
    moved = edit.move(s, sel, translation=[1.0, 0, 0])
    np.testing.assert_allclose(moved.means[:5], s.means[:5] + [1, 0, 0], atol=1e-6)
    np.testing.assert_array_equal(moved.means[5:], s.means[5:])
    np.testing.assert_array_equal(moved.extra["label"], s.extra["label"])
    red = edit.recolour(s, sel, [1.0, 0, 0])
    np.testing.assert_allclose(SH_C0 * red.sh[:5, 0] + 0.5, np.tile([1.0, 0, 0], (5, 1)), atol=1e-6)
    assert np.all(red.sh[:5, 1:] == 0) and np.array_equal(red.sh[5:], s.sh[5:])
    assert not red.sh.flags.writeable and s.sh.flags.writeable is False


def test_copy_module_works_on_frozen_scenes(rng):
    import copy

    s = random_scene(rng)
    assert copy.copy(s) is s
    d = copy.deepcopy(s)
    assert d is not s and not np.shares_memory(d.means, s.means)
    np.testing.assert_array_equal(d.sh, s.sh)
    np.testing.assert_array_equal(d.extra["label"], s.extra["label"])


def test_sh_basis_is_the_real_spherical_harmonics_of_scipy():
    """Every degree up to 3, in the 3DGS order ``l*l + l + m``: the real SH built from scipy's complex
    ``Y_l^|m|`` (Condon-Shortley phase included): ``Y`` for m = 0, ``sqrt(2) Re Y`` for m > 0 and
    ``sqrt(2) Im Y`` for m < 0. The orthonormality above cannot see a sign or an order within a band; this
    can, for numpy's basis and the rasterizer kernel's alike."""
    from scipy.special import sph_harm_y

    from seed2gs_inverse.raster._kernels import _sh_basis

    rng = np.random.default_rng(5)
    d = unit(rng, 64)
    theta, phi = np.arccos(np.clip(d[:, 2], -1, 1)), np.arctan2(d[:, 1], d[:, 0])
    want = np.empty((len(d), 16))
    for l in range(4):
        for m in range(-l, l + 1):
            Y = sph_harm_y(l, abs(m), theta, phi)
            want[:, l * l + l + m] = Y.real if m == 0 else np.sqrt(2) * (Y.real if m > 0 else Y.imag)
    np.testing.assert_allclose(sh_basis(d, 3), want, atol=1e-12)
    out = np.empty(16)
    for i in range(len(d)):
        _sh_basis(d[i, 0], d[i, 1], d[i, 2], 16, out)
        np.testing.assert_allclose(out, want[i], atol=1e-6)


def test_subset_of_an_empty_list_is_an_empty_scene():
    """numpy makes [] float64: it was refused, while the edits took it."""
    rng = np.random.default_rng(0)
    scene = GaussianScene(rng.normal(size=(5, 3)), rng.normal(size=(5, 4)), np.zeros((5, 3)), np.zeros(5),
                          np.zeros((5, 1, 3)))
    assert len(scene.subset([])) == 0 and len(scene.subset(np.array([], np.int64))) == 0
    with pytest.raises(ValidationError):
        scene.subset([0.5])


def test_rotation_columns_are_the_rotation_matrices_columns(rng):
    """Each column against scipy's rotation (w-first to scalar-last), and bit for bit against quat_to_rotmat."""
    from seed2gs_inverse.scene import quat_to_rotmat, rotation_columns

    q = (rng.normal(size=(500, 4)) * 3).astype(np.float32)  # not normalised: normalised inside
    cols = rng.integers(0, 3, size=500)
    got = rotation_columns(q, cols)
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]].astype(np.float64)).as_matrix()
    np.testing.assert_allclose(got, ref[np.arange(500), :, cols], atol=1e-12)
    np.testing.assert_array_equal(got, quat_to_rotmat(q)[np.arange(500), :, cols])
    assert rotation_columns(q[:0], cols[:0]).shape == (0, 3)


@pytest.mark.parametrize("quats, cols, what", [
    (np.ones((3, 4)), np.array([0, 1, 3]), "columns"),
    (np.ones((3, 4)), np.array([0, 1]), "columns"),
    (np.ones((3, 4)), np.array([0.0, 1.0, 2.0]), "columns"),
    (np.ones((3, 3)), np.array([0, 1, 2]), "quats"),
])
def test_rotation_columns_refuses_bad_input(quats, cols, what):
    from seed2gs_inverse.scene import rotation_columns

    with pytest.raises(ValidationError, match=what):
        rotation_columns(quats, cols)
