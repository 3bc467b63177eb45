"""render() and project_gaussians() against the brute-force reference and known values."""

from __future__ import annotations

import numpy as np
import pytest

from render_reference import random_scene, reference_projection, reference_render
from seed2gs_inverse.camera import Camera
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.operators import Rendering
from seed2gs_inverse.raster import _kernels, project_gaussians, render
from seed2gs_inverse.raster.frozen import FrozenScene
from seed2gs_inverse.raster.project import project
from seed2gs_inverse.scene import GaussianScene
from seed2gs_inverse.sh import rgb_to_sh


def make_camera(kind):
    if kind == "centred":
        return Camera.look_at([0.3, -0.4, -4.0], [0, 0, 0], [0, -1, 0], 50, 48, 40)
    if kind == "offcentre":  # principal point away from the centre, fx != fy, odd size
        base = Camera.look_at([1.0, 0.5, -3.5], [0, 0.2, 0], [0, -1, 0], 55, 50, 37)
        return Camera(50, 37, 44.0, 47.0, 21.3, 20.1, base.world_to_camera, near=0.05)
    raise AssertionError(kind)


CASES = [(0, "centred", "classic"), (1, "offcentre", "classic"), (2, "centred", "antialiased"),
         (3, "offcentre", "antialiased"), (4, "centred", "classic")]


@pytest.mark.parametrize("seed,camkind,mode", CASES)
def test_render_matches_brute_force(seed, camkind, mode):
    cam = make_camera(camkind)
    scene = random_scene(seed, n=60 + 35 * seed, cam=cam)
    rgb, alpha, depth, _ = reference_render(scene, cam, mode)
    r = render(scene, cam, mode=mode)
    assert isinstance(r, Rendering)
    assert r.rgb.dtype == np.float32 and r.rgb.shape == (cam.height, cam.width, 3)
    assert r.alpha.dtype == np.float32 and r.depth.dtype == np.float32 and r.n_contrib.dtype == np.int32
    assert alpha.max() > 0.5 and (r.n_contrib > 3).any()  # the scene is visible and layered
    np.testing.assert_allclose(r.rgb, rgb, atol=1e-5, rtol=0)
    np.testing.assert_allclose(r.alpha, alpha, atol=1e-5, rtol=0)
    np.testing.assert_allclose(r.depth, depth, atol=1e-5, rtol=1e-6)


def test_background_is_added_with_final_transmittance():
    cam = make_camera("centred")
    scene = random_scene(7, n=60, cam=cam)
    bg = np.array([0.2, 0.5, 0.9])
    rgb, alpha, _, _ = reference_render(scene, cam, background=bg)
    r = render(scene, cam, background=bg)
    np.testing.assert_allclose(r.rgb, rgb, atol=1e-5)
    r0 = render(scene, cam)
    np.testing.assert_allclose(r.rgb - r0.rgb, (1 - r0.alpha)[..., None] * bg, atol=1e-6)
    # a scalar background means grey
    np.testing.assert_allclose(render(scene, cam, background=0.5).rgb,
                               r0.rgb + 0.5 * (1 - r0.alpha)[..., None], atol=1e-6)


@pytest.mark.parametrize("seed,camkind,mode", CASES[:4])
def test_projection_matches_reference(seed, camkind, mode):
    cam = make_camera(camkind)
    scene = random_scene(seed, n=80, cam=cam)
    ref = reference_projection(scene, cam, mode)
    p = project_gaussians(scene, cam, mode)
    v = ref["valid"]
    assert v.sum() > 10 and (~v).sum() >= 3  # behind-camera ones are culled
    np.testing.assert_array_equal(p.radii > 0, v)
    np.testing.assert_array_equal(p.radii[v], ref["radius"][v])
    np.testing.assert_allclose(p.means2d[v], ref["mean2d"][v], rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(p.conics[v], ref["conic"][v], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(p.depths, ref["z"], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(p.colors, ref["color"], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(p.opacities[v], ref["opacity"][v], rtol=1e-6, atol=1e-7)
    assert p.means2d.dtype == p.conics.dtype == p.colors.dtype == np.float32
    assert p.radii.dtype == np.int32



def test_projection_over_many_chunks_matches_reference():
    """The projection claims Gaussians CHUNK at a time (dynamic scheduling): a scene of several chunks,
    projected as a whole and as a shuffled subset, gives the reference's values row by row."""
    cam = make_camera(CASES[0][1])
    n = 3 * _kernels.CHUNK + 17
    scene = random_scene(5, n=n, cam=cam)
    ref = reference_projection(scene, cam)
    p = project_gaussians(scene, cam)
    v = ref["valid"]
    assert v.sum() > _kernels.CHUNK
    np.testing.assert_array_equal(p.radii > 0, v)
    np.testing.assert_array_equal(p.radii[v], ref["radius"][v])
    np.testing.assert_allclose(p.means2d[v], ref["mean2d"][v], rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(p.depths, ref["z"], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(p.colors, ref["color"], rtol=1e-6, atol=1e-6)
    # a subset (rows in the subset's order) is the whole projection's rows, bit for bit
    idx = np.sort(np.random.default_rng(1).choice(n, 2 * _kernels.CHUNK + 5, replace=False)).astype(np.int64)
    whole = project(scene, None, cam, "classic")
    part = project(scene, None, cam, "classic", idx)
    part_frozen = project(scene, FrozenScene(scene), cam, "classic", idx)
    for a, b, c in zip(whole, part, part_frozen):
        np.testing.assert_array_equal(a[idx], b)
        np.testing.assert_array_equal(b, c)


def _single(mean, log_scale, logit, rgb=(1.0, 0.5, 0.25), quat=(1, 0, 0, 0)):
    return GaussianScene(np.array([mean], float), np.array([quat], float), np.full((1, 3), log_scale),
                         np.array([logit], float), rgb_to_sh(np.array([rgb]))[:, None, :])


def test_single_isotropic_gaussian_known_values():
    # An isotropic Gaussian of std s at depth z on the optical axis projects to
    # an isotropic 2D Gaussian of variance (f s / z)^2 + 0.3 centred at (cx, cy).
    # cx = 25.8 puts the 3-sigma disc's right edge just past the tile border
    # x = 32 where getRect's bound floor((mu + r + 15)/16) cuts it off.
    cx, cy = 25.8, 21.0
    cam = Camera(64, 48, 40.0, 40.0, cx, cy, np.eye(4))
    s, z, o = 0.1, 2.0, 0.99
    scene = _single([0, 0, z], np.log(s), np.log(o / (1 - o)))
    r = render(scene, cam)
    var = (40.0 * s / z) ** 2 + 0.3
    ys, xs = np.mgrid[0:48, 0:64] + 0.5
    a = o * np.exp(-0.5 * ((xs - cx) ** 2 + (ys - cy) ** 2) / var)
    radius = np.ceil(3 * np.sqrt(var + np.sqrt(0.01)))  # isotropic: lambda = var + 0.1
    assert radius == 7
    tx = (np.floor((cx - radius) / 16), np.floor((cx + radius + 15) / 16))
    ty = (np.floor((cy - radius) / 16), np.floor((cy + radius + 15) / 16))
    assert tx == (1, 2) and ty == (0, 2)
    in_tiles = (xs // 16 >= tx[0]) & (xs // 16 < tx[1]) & (ys // 16 >= ty[0]) & (ys // 16 < ty[1])
    assert a[21, 32] >= 1 / 255 and not in_tiles[21, 32]  # the tile rule truncates here
    expected = np.where(in_tiles & (a >= 1 / 255), np.minimum(a, 0.99), 0)
    np.testing.assert_allclose(r.alpha, expected, atol=1e-6)
    np.testing.assert_allclose(r.rgb, expected[..., None] * [1.0, 0.5, 0.25], atol=1e-6)
    np.testing.assert_allclose(r.depth[expected > 0], z, rtol=1e-6)
    assert np.all(r.depth[expected == 0] == 0)
    np.testing.assert_array_equal(r.n_contrib, (expected > 0).astype(np.int32))
    assert r.alpha[21, 25] == pytest.approx(o * np.exp(-0.5 * (0.3 ** 2 + 0.5 ** 2) / var), rel=1e-6)


def test_pixel_centre_convention_follows_gsplat():
    # A mean at u = cx lands exactly between pixels cx-1 and cx when cx is an
    # integer: both pixel centres are 0.5 away, so the image is symmetric.
    cam = Camera(32, 32, 30.0, 30.0, 16.0, 16.0, np.eye(4))
    r = render(_single([0, 0, 3], np.log(0.05), 3.0), cam)
    np.testing.assert_allclose(r.alpha[16, 15], r.alpha[16, 16], rtol=1e-6)
    np.testing.assert_allclose(r.alpha[15, 16], r.alpha[16, 16], rtol=1e-6)
    assert r.alpha[16, 16] > r.alpha[16, 17]


def test_alpha_cap_and_early_stop():
    # Ten identical opaque Gaussians centred on pixel (8, 8): alpha is capped
    # at 0.99; after two, T = (1 - 0.99)^2 = 1.0000000000000018e-4 (not
    # below 1e-4, so both count); the third would give 1e-6 < 1e-4 and stops.
    cam = Camera(16, 16, 20.0, 20.0, 8.5, 8.5, np.eye(4))
    one = _single([0, 0, 2], np.log(0.2), 20.0)
    r = render(GaussianScene.concat([one] * 10), cam)
    assert (1 - 0.99) ** 2 >= 1e-4
    assert r.n_contrib[8, 8] == 2
    assert r.alpha[8, 8] == pytest.approx(1 - (1 - 0.99) ** 2, abs=1e-7)


def test_equal_depth_ties_break_by_index():
    cam = Camera(16, 16, 20.0, 20.0, 8.0, 8.0, np.eye(4))
    red = _single([0, 0, 2], np.log(0.3), 0.0, rgb=(1, 0, 0))
    green = _single([0, 0, 2], np.log(0.3), 0.0, rgb=(0, 1, 0))
    rg = render(GaussianScene.concat([red, green]), cam).rgb[8, 8]
    gr = render(GaussianScene.concat([green, red]), cam).rgb[8, 8]
    assert rg[0] > rg[1] and gr[1] > gr[0]  # the lower index is in front
    np.testing.assert_allclose(rg, gr[[1, 0, 2]], atol=1e-7)


def test_near_plane_culling_uses_camera_near():
    scene = _single([0, 0, 0.5], np.log(0.01), 3.0)
    near = Camera(16, 16, 20.0, 20.0, 8.0, 8.0, np.eye(4), near=0.4)
    far = Camera(16, 16, 20.0, 20.0, 8.0, 8.0, np.eye(4), near=0.6)
    assert render(scene, near).alpha.max() > 0.5
    assert render(scene, far).alpha.max() == 0
    assert project_gaussians(scene, far).radii[0] == 0


def test_bad_input_raises_clear_errors():
    cam = Camera(16, 16, 20.0, 20.0, 8.0, 8.0, np.eye(4))
    scene = _single([0, 0, 2], 0.0, 0.0)
    empty = scene.subset(np.zeros(1, bool))
    with pytest.raises(ValidationError, match="empty"):
        render(empty, cam)
    with pytest.raises(ValidationError, match="mode"):
        render(scene, cam, mode="fast")
    with pytest.raises(ValidationError, match="background"):
        render(scene, cam, background=[0, np.nan, 0])
    with pytest.raises(ValidationError, match="background"):
        render(scene, cam, background=[0, 1])
    with pytest.raises(ValidationError, match="Camera"):
        render(scene, "cam.json")
    with pytest.raises(ValidationError, match="GaussianScene"):
        render(np.zeros((3, 3)), cam)
    bad_pose = np.eye(4)
    bad_pose[0, 3] = np.inf
    with pytest.raises(ValidationError, match="non-finite"):
        Camera(16, 16, 20.0, 20.0, 8.0, 8.0, bad_pose)
    with pytest.raises(ValidationError, match="positive"):
        Camera(0, 16, 20.0, 20.0, 8.0, 8.0, np.eye(4))
    with pytest.raises(ValidationError, match="empty"):
        project_gaussians(empty, cam)


def test_real_scene_matches_independent_reference(shared_data):
    from render_reference import load_firepit

    scene, cam = load_firepit(shared_data)
    ref = np.load(shared_data / "firepit_overview_reference_rgb.npy", allow_pickle=False)
    r = render(scene, cam)
    mad = float(np.abs(r.rgb - ref).mean())
    assert mad < 0.005, f"mean absolute difference {mad:.4f} to the reference rendering"


def test_depth_order_equals_stable_sort_with_ties():
    import importlib

    _render = importlib.import_module("seed2gs_inverse.raster.rasterize")
    rng = np.random.default_rng(1)
    for _ in range(100):
        n = int(rng.integers(1, 80))
        idx = np.sort(rng.choice(200, n, replace=False))
        depths = np.zeros(200)
        depths[idx] = rng.integers(0, 6, n) * 0.5  # many exact ties
        np.testing.assert_array_equal(_render._depth_order(depths, idx),
                                      idx[np.argsort(depths[idx], kind="stable")])


def test_extreme_values_do_not_break_the_rasterizer():
    # Huge and tiny scales, far and grazing positions, saturated opacities:
    # every output stays finite and within its range.
    cam = Camera(40, 30, 30.0, 30.0, 20.0, 15.0, np.eye(4), near=0.01)
    means = np.array([[0, 0, 2], [1e18, 0, 1], [0, 0, 1e30], [0.1, 0, 0.0100001], [-1, 2, 3],
                      [3e37, 3e37, 3e37], [0, 0, 5], [0.01, 0.01, 2]], float)
    n = len(means)
    log_scales = np.array([[40, 40, 40], [-40, -40, -40], [0, 0, 0], [-3, 5, -30], [20, -20, 0],
                           [1, 1, 1], [-80, -80, -80], [-2, -2, -2]], float)
    logits = np.array([80, -80, 5, 50, 3, 2, 90, -0.5])
    scene = GaussianScene(means, np.tile([1.0, 0, 0, 0], (n, 1)), log_scales, logits,
                          np.ones((n, 1, 3)))
    for mode in ("classic", "antialiased"):
        r = render(scene, cam, mode=mode)
        for arr in (r.rgb, r.alpha, r.depth):
            assert np.all(np.isfinite(arr))
        assert r.alpha.min() >= 0 and r.alpha.max() <= 1
        p = project_gaussians(scene, cam, mode)
        assert np.all(p.radii >= 0)


@pytest.mark.parametrize("n", [0, 7, 70_000])
def test_bin_tiles_equals_sequential_lists(n):
    """Parallel chunked binning gives each tile its Gaussians in the given order."""
    from seed2gs_inverse.raster import _kernels

    rng = np.random.default_rng(n)
    tiles_x, tiles_y = 9, 5
    x0 = rng.integers(0, tiles_x, n)
    y0 = rng.integers(0, tiles_y, n)
    rects = np.stack([x0, y0, np.minimum(x0 + rng.integers(0, 3, n), tiles_x),
                      np.minimum(y0 + rng.integers(0, 3, n), tiles_y)], 1).astype(np.int32)
    order = rng.permutation(n).astype(np.int64)
    start, gauss = _kernels.bin_tiles(order, rects, tiles_x, tiles_x * tiles_y)
    lists = [[] for _ in range(tiles_x * tiles_y)]
    for g in order:
        for ty in range(rects[g, 1], rects[g, 3]):
            for tx in range(rects[g, 0], rects[g, 2]):
                lists[ty * tiles_x + tx].append(g)
    assert start[0] == 0 and start[-1] == gauss.size
    for t, lst in enumerate(lists):
        np.testing.assert_array_equal(gauss[start[t]:start[t + 1]], lst)


def test_compilation_is_announced_once(monkeypatch, capsys):
    """Cold kernels are said once per process on stderr, counting only those the call runs; warm or unknown
    ones say nothing (a render said "1 of 6" on every run for the culling kernel it never runs)."""
    from seed2gs_inverse.raster import _kernels

    every = [k.py_func.__name__ for k in _kernels.ENTRY_KERNELS]
    monkeypatch.setattr(_kernels, "_announced", set())
    monkeypatch.setattr(_kernels, "_cold_kernels", lambda: ["_cone_cull"])
    assert _kernels.announce_compilation(_kernels.RENDER_KERNELS) is False  # a render: nothing of it is cold
    assert capsys.readouterr().err == ""
    assert _kernels.announce_compilation((_kernels._cone_cull,)) is True
    assert "(1 of 6)" in capsys.readouterr().err
    monkeypatch.setattr(_kernels, "_announced", set())
    monkeypatch.setattr(_kernels, "_cold_kernels", lambda: every)
    assert _kernels.announce_compilation(_kernels.RENDER_KERNELS) is True
    assert _kernels.announce_compilation(_kernels.RENDER_KERNELS) is False  # once per process
    assert _kernels.announce_compilation((_kernels._cone_cull,)) is True  # its first call: said then
    err = capsys.readouterr().err
    assert err.count("compiling the rasterizer kernels") == 2 and "(5 of 6)" in err
    assert f"about {_kernels.COMPILE_SECONDS} s" in err
    for cold in ([], None):
        monkeypatch.setattr(_kernels, "_announced", set())
        monkeypatch.setattr(_kernels, "_cold_kernels", lambda c=cold: c)
        assert _kernels.announce_compilation() is False
    assert capsys.readouterr().err == ""


def test_cold_cache_detected_without_compiling(tmp_path):
    """An empty Numba cache directory reads as cold (index files only; nothing is compiled)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path),
               PYTHONPATH=str(Path(__file__).resolve().parents[1]) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    code = "from seed2gs_inverse.raster import _kernels; print(_kernels.kernels_cached())"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
    assert not any(tmp_path.rglob("*.nbc"))  # reading the cache state compiled nothing


@pytest.mark.parametrize("preset", [None, "ACTIVE"])
def test_openmp_waiters_sleep_unless_the_user_chose(preset):
    """Importing the rasterizer makes OpenMP threads that wait at the end of a parallel loop sleep
    (OMP_WAIT_POLICY=PASSIVE) before the runtime loads; a policy the user set is kept, and the
    kernels run either way."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if preset is not None:
        env["OMP_WAIT_POLICY"] = preset
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1]) + os.pathsep + os.environ.get("PYTHONPATH", "")
    code = ("import json, os, numpy as np\n"
            "from seed2gs_inverse.raster import render\n"
            "from seed2gs_inverse.camera import Camera\n"
            "from seed2gs_inverse.scene import GaussianScene\n"
            "rng = np.random.default_rng(0)\n"
            "s = GaussianScene(rng.normal(size=(50, 3)) + [0, 0, 5], np.tile([1.0, 0, 0, 0], (50, 1)),\n"
            "                  np.full((50, 3), -3.0), np.zeros(50), rng.normal(size=(50, 1, 3)))\n"
            "r = render(s, Camera.from_fov(32, 24, 60.0))\n"
            "print(json.dumps([os.environ.get('OMP_WAIT_POLICY'), float(r.alpha.max())]))\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    policy, alpha = json.loads(out.stdout.strip().splitlines()[-1])
    assert policy == (preset or "PASSIVE") and alpha > 0
