"""``seed2gs render``: outputs equal the library rendering; failures leave no files."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

import seed2gs_inverse.cli as cli
from render_reference import random_scene
from seed2gs_inverse.camera import Camera
from seed2gs_inverse.io import read_scene, write_cameras, write_scene
from seed2gs_inverse.raster import render


@pytest.fixture
def files(tmp_path, monkeypatch):
    monkeypatch.setattr(cli, "_COMMAND_MODULES", ("_render",))
    cams = [Camera.look_at([0.2, -0.5, -4.0], [0, 0, 0], [0, -1, 0], 50, 48, 40, name="front"),
            Camera.look_at([-3.0, -0.5, -2.5], [0, 0, 0], [0, -1, 0], 50, 40, 30, name="side")]
    scene = random_scene(5, n=120, sh_degree=1, cam=cams[0])
    write_scene(tmp_path / "scene.ply", scene)
    write_cameras(tmp_path / "cams.json", cams)
    # what the reader gives back (float32 round trip) is what the command renders
    return tmp_path, read_scene(tmp_path / "scene.ply"), cams


def test_camera_file_outputs(files, capsys):
    d, scene, cams = files
    rc = cli.main(["render", str(d / "scene.ply"), "--camera", f"{d / 'cams.json'}:side",
                   "-o", str(d / "rgb.npy"), "--depth", str(d / "depth.npy"), "--alpha", str(d / "a.png")])
    assert rc == 0, capsys.readouterr().err
    ref = render(scene, cams[1])
    np.testing.assert_allclose(np.load(d / "rgb.npy"), ref.rgb, atol=1e-6)
    np.testing.assert_allclose(np.load(d / "depth.npy"), ref.depth, atol=1e-5)
    a = np.asarray(Image.open(d / "a.png"))
    assert a.shape == (30, 40) and a.dtype == np.uint8
    assert np.abs(a.astype(int) - np.round(ref.alpha * 255)).max() <= 1
    assert "40x30" in capsys.readouterr().out


def test_look_at_takes_vectors_that_start_with_a_minus_sign(files, tmp_path):
    """argparse read "-0.2,-0.5,-4" as an unknown option ("expected 2 arguments")."""
    d, scene, _ = files
    for eye, target in (("-0.2,-0.5,-4", "0,0,0"), ("0.2,-0.5,-4", "-.1,0,0"), ("-2e-1,-0.5,-4", "-1E-1,0,0")):
        out = tmp_path / f"{eye}_{target}.npy"
        assert cli.main(["render", str(d / "scene.ply"), "--look-at", eye, target, "--fov", "50",
                         "--size", "24x20", "-o", str(out)]) == 0
        cam = Camera.look_at([float(v) for v in eye.split(",")], [float(v) for v in target.split(",")],
                             [0, -1, 0], 50, 24, 20)
        np.testing.assert_allclose(np.load(out), render(scene, cam).rgb, atol=1e-6)


def test_look_at_png_with_background_and_scale(files):
    d, scene, cams = files
    rc = cli.main(["render", str(d / "scene.ply"), "--look-at", "0.2,-0.5,-4", "0,0,0", "--fov", "50",
                   "--size", "48x40", "--scale", "0.5", "--background", "1,1,1", "-o", str(d / "img.png"),
                   "--depth", str(d / "depth.png")])
    assert rc == 0
    cam = cams[0].scaled(0.5)
    ref = render(scene, cam, background=[1, 1, 1])
    img = np.asarray(Image.open(d / "img.png"))
    assert img.shape == (20, 24, 3)
    assert np.abs(img.astype(int) - np.round(np.clip(ref.rgb, 0, 1) * 255)).max() <= 1
    dep = np.asarray(Image.open(d / "depth.png")).astype(np.int64)
    covered = ref.alpha > 0
    np.testing.assert_array_equal(dep > 0, covered)
    # 16-bit depth is monotone in the true depth
    order = np.argsort(ref.depth[covered])
    assert np.all(np.diff(dep[covered][order]) >= 0)


@pytest.mark.parametrize("extra,match", [
    (["--camera", "CAMS:nosuch"], "no camera named"),
    (["--camera", "CAMS:7"], "out of range"),
    (["--camera", "CAMS"], "pick one"),
    (["--look-at", "0,0", "0,0,1"], "three numbers"),
    (["--look-at", "0,0,-3", "0,0,0", "--size", "0x10"], "--size"),
    (["--camera", "CAMS:0", "--background", "2,0,0"], "background"),
    (["--camera", "CAMS:0", "--scale", "-1"], "scale"),
    (["--camera", "CAMS:0", "--scale", "1e-6"], "--scale 1e-06: camera"),  # a 1x1 image was written
    (["--camera", "CAMS:0", "--scale", "4000"], "each side must lie in 4..32768"),  # was 'a corrupt file?'
    (["--camera", "CAMS:0", "--depth", "OUT/missing/d.npy"], "does not exist"),
    (["--camera", "CAMS:0", "--alpha", "OUT/a.jpg"], ".png or .npy"),
])
def test_errors_are_one_line_and_leave_no_files(files, capsys, extra, match):
    d, _, _ = files
    extra = [e.replace("CAMS", str(d / "cams.json")).replace("OUT", str(d)) for e in extra]
    before = sorted(p.name for p in d.iterdir())
    rc = cli.main(["render", str(d / "scene.ply"), "-o", str(d / "out.png"), *extra])
    err = capsys.readouterr().err
    assert rc == 2 and match in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in d.iterdir()) == before


def test_unreadable_scene_leaves_no_files(files, capsys):
    d, _, _ = files
    (d / "bad.ply").write_bytes(b"ply\nformat ascii 1.0\nend_header\n")
    rc = cli.main(["render", str(d / "bad.ply"), "--camera", f"{d / 'cams.json'}:0", "-o", str(d / "o.png")])
    assert rc == 2 and "bad.ply" in capsys.readouterr().err
    assert not (d / "o.png").exists()
