"""The real scenes of ../shared/data (skipped when absent)."""

from __future__ import annotations

import numpy as np
import plyfile
import pytest

from seed2gs_inverse.io import detect_format, read_scene, write_scene

pytestmark = pytest.mark.shared_data

FILES = [("firepit_562k_sh0.ply", "ply", 561_997, 0),
         ("unicorn_49k_sh3.ply", "ply", 49_602, 3),
         ("guitar_90k.compressed.ply", "compressed_ply", 90_854, 0),
         ("biker_152k.spz", "spz", 152_746, 0)]


@pytest.mark.parametrize("name, fmt, count, degree", FILES)
def test_counts_finite_and_normalised(shared_data, name, fmt, count, degree):
    path = shared_data / name
    assert detect_format(path) == fmt
    scene = read_scene(path)
    assert len(scene) == count and scene.sh_degree == degree
    for arr in (scene.means, scene.quats, scene.log_scales, scene.opacity_logits, scene.sh):
        assert np.all(np.isfinite(arr))
    norms = np.linalg.norm(scene.quats.astype(np.float64), axis=1)
    np.testing.assert_allclose(norms, 1, atol=1e-3)
    op = scene.opacities
    assert op.min() >= 0 and op.max() <= 1 and np.std(op) > 0.1  # opacities are spread out
    assert np.all(scene.log_scales < 3)  # no Gaussian larger than ~20 units


@pytest.mark.parametrize("name", ["firepit_562k_sh0.ply", "unicorn_49k_sh3.ply"])
def test_standard_ply_matches_plyfile(shared_data, name):
    path = shared_data / name
    scene = read_scene(path)
    v = plyfile.PlyData.read(str(path))["vertex"].data
    np.testing.assert_array_equal(scene.means, np.stack([v["x"], v["y"], v["z"]], 1))
    np.testing.assert_array_equal(scene.quats, np.stack([v[f"rot_{i}"] for i in range(4)], 1))
    np.testing.assert_array_equal(scene.opacity_logits, v["opacity"])
    k = scene.sh.shape[1]
    for c in range(3):
        np.testing.assert_array_equal(scene.sh[:, 0, c], v[f"f_dc_{c}"])
        for j in range(k - 1):
            np.testing.assert_array_equal(scene.sh[:, 1 + j, c], v[f"f_rest_{c * (k - 1) + j}"])


def test_unicorn_round_trip(shared_data, tmp_path):
    scene = read_scene(shared_data / "unicorn_49k_sh3.ply")
    write_scene(tmp_path / "u.ply", scene)
    back = read_scene(tmp_path / "u.ply")
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        np.testing.assert_array_equal(getattr(back, name), getattr(scene, name))
    assert (tmp_path / "u.ply").stat().st_size == (shared_data / "unicorn_49k_sh3.ply").stat().st_size


def test_compressed_and_spz_values_are_sensible(shared_data):
    guitar = read_scene(shared_data / "guitar_90k.compressed.ply")
    rgb = guitar.sh[:, 0] * 0.28209479177387814 + 0.5
    # The chunk colour ranges themselves extend a little beyond [0, 1] (trained DC terms do)
    assert np.percentile(rgb, 1) > -0.1 and np.percentile(rgb, 99) < 1.5
    assert np.median(rgb) > 0.1
    biker = read_scene(shared_data / "biker_152k.spz")
    rgb = biker.sh[:, 0] * 0.28209479177387814 + 0.5
    assert rgb.min() > -0.1 and rgb.max() < 1.1
    lo, hi = biker.bounds()
    assert np.all(hi - lo < 5) and np.all(hi - lo > 0.5)  # a person-sized object
