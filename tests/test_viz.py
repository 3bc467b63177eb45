"""pyvista membership views (off-screen), matplotlib view grids and ``seed2gs view``."""

from __future__ import annotations

import argparse
import os
import warnings

import numpy as np
import pytest

from seed2gs_inverse import Camera, GaussianScene, ValidationError
from seed2gs_inverse.cli import _view
from seed2gs_inverse.viz import membership_plot, view_grid

W, H = 64, 48
VIRIDIS_TOP = np.array([253, 231, 37])
VIRIDIS_BOTTOM = np.array([68, 1, 84])


def _has_display():
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


@pytest.fixture(scope="module")
def offscreen():
    """Skip the pyvista tests, with the reason, when off-screen rendering is impossible."""
    if not _has_display():
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    try:
        import pyvista as pv

        pl = pv.Plotter(off_screen=True, window_size=[16, 16])
        pl.add_mesh(pv.Sphere())
        img = pl.screenshot(None, return_img=True)
        pl.close()
        assert img.shape[:2] == (16, 16)
    except Exception as exc:  # noqa: BLE001 - any failure means: no off-screen OpenGL here
        pytest.skip(f"off-screen VTK rendering (EGL) is not available on this machine: {exc}")


def _cloud(rng, n=400, center=(0.0, 0.0, 0.0), rgb=(0.9, 0.1, 0.1)):
    sh = np.zeros((n, 1, 3))
    sh[:, 0] = (np.asarray(rgb) - 0.5) / 0.28209479177387814
    return GaussianScene(rng.normal(0, 0.15, (n, 3)) + center, np.tile([1.0, 0, 0, 0], (n, 1)),
                         np.full((n, 3), np.log(0.03)), np.full(n, 3.0), sh)


def _camera(cx=None, cy=None):
    # Looks along +z at the origin from z = -3; image up is world -y.
    cam = Camera.look_at([0, 0, -3.0], [0, 0, 0], [0, -1, 0], 50.0, W, H, name="test")
    return Camera(W, H, cam.fx, cam.fy, cam.cx if cx is None else cx, cam.cy if cy is None else cy,
                  cam.world_to_camera)


def _foreground(img, bg=255):
    return np.any(np.abs(img[:, :, :3].astype(int) - bg) > 30, axis=2)


def test_points_with_q_one_show_the_top_of_the_colormap(offscreen, rng, tmp_path):
    scene = _cloud(rng)
    out = tmp_path / "q1.png"
    img = membership_plot(scene, np.ones(len(scene)), screenshot=out, camera=_camera(),
                          point_size=4, scalar_bar=False)
    from PIL import Image

    png = np.asarray(Image.open(out))
    assert png.shape[:2] == (H, W) and img.shape == (H, W, 3)
    fg = _foreground(img)
    assert fg.mean() > 0.02
    colours = img[fg].astype(float)
    # Median: edge pixels blend with the white background (anti-aliasing).
    assert np.median(np.abs(colours - VIRIDIS_TOP).max(axis=1)) < 6
    img0 = membership_plot(scene, np.zeros(len(scene)), screenshot=tmp_path / "q0.png",
                           camera=_camera(), point_size=4, scalar_bar=False)
    fg0 = _foreground(img0)
    assert np.median(np.abs(img0[fg0].astype(float) - VIRIDIS_BOTTOM).max(axis=1)) < 6


@pytest.mark.parametrize("cx,cy", [(None, None), (20.0, 30.0)])
def test_camera_places_points_where_it_projects_them_and_threshold_hides(offscreen, rng, tmp_path, cx, cy):
    left, right = _cloud(rng, center=(-0.8, 0, 0)), _cloud(rng, center=(0.8, 0.3, 0))
    scene = GaussianScene.concat([left, right])
    q = np.r_[np.ones(len(left)), np.zeros(len(right))]
    cam = _camera(cx, cy)
    img = membership_plot(scene, q, threshold=0.5, screenshot=tmp_path / "t.png", camera=cam,
                          point_size=2, scalar_bar=False)
    ys, xs = np.nonzero(_foreground(img))
    uv, _ = cam.project(left.means)
    # Only the left cloud is drawn, centred where the pinhole model puts it.
    assert abs(xs.mean() + 0.5 - uv[:, 0].mean()) < 2.0
    assert abs(ys.mean() + 0.5 - uv[:, 1].mean()) < 2.0
    assert xs.max() < W / 2


def test_scene_colours_and_ellipsoid_cap(offscreen, rng, tmp_path):
    scene = _cloud(rng, rgb=(0.1, 0.2, 0.9))
    img = membership_plot(scene, screenshot=tmp_path / "c.png", camera=_camera(), point_size=4)
    c = img[_foreground(img)].astype(float).mean(0)
    assert c[2] > 150 and c[0] < 80   # blue, as stored in the SH DC term
    with pytest.warns(UserWarning, match="50 of 400"):
        img = membership_plot(scene, rng.random(len(scene)), mode="ellipsoids", max_glyphs=50,
                              screenshot=tmp_path / "e.png", camera=_camera())
    assert img.shape == (H, W, 3) and _foreground(img).any()


def test_membership_plot_validates(rng, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a check that regressed would write its screenshot here
    scene = _cloud(rng, n=10)
    with pytest.raises(ValidationError, match=r"shape \(10,\)"):
        membership_plot(scene, np.ones(9), screenshot="x.png")
    with pytest.raises(ValidationError, match=r"\[0, 1\]"):
        membership_plot(scene, np.full(10, 2.0), screenshot="x.png")
    with pytest.raises(ValidationError, match="threshold needs"):
        membership_plot(scene, threshold=0.5, screenshot="x.png")
    with pytest.raises(ValidationError, match="mode"):
        membership_plot(scene, mode="voxels", screenshot="x.png")
    assert not os.path.exists("x.png")

    for size in [(0, 0), (-5, 10), (10,), (9000, 10), (1.5, 2), (True, True), ("64", "48"), 7]:
        with pytest.raises(ValidationError, match="window_size"):
            membership_plot(scene, screenshot="x.png", window_size=size)
    for up in [(0, 0, 0), (np.nan, 0, 0), (0, 1)]:
        with pytest.raises(ValidationError, match="'up' must be a finite non-zero 3-vector"):
            membership_plot(scene, screenshot="x.png", up=up)
    for path in ["x.jpg", "shot", ".png"]:
        with pytest.raises(ValidationError, match=r"\.png path"):
            membership_plot(scene, screenshot=path)
    assert not os.path.exists("x.png") and not os.path.exists("shot.png")


def test_membership_plot_empty_scene_and_no_plotter_left_after_an_error(offscreen, rng, tmp_path):
    from pyvista.plotting.plotter import _ALL_PLOTTERS

    empty = _cloud(rng, n=5).subset(np.zeros(5, bool))
    img = membership_plot(empty, np.zeros(0), screenshot=tmp_path / "e.png", window_size=(32.0, np.int64(24)))
    assert img.shape == (24, 32, 3) and (tmp_path / "e.png").is_file()  # the "no Gaussians" caption
    open_before = sum(not pl._closed for pl in _ALL_PLOTTERS.values())
    with pytest.raises(ValueError):
        membership_plot(_cloud(rng, n=5), np.zeros(5), cmap="no-such-colormap", screenshot=tmp_path / "f.png")
    assert sum(not pl._closed for pl in _ALL_PLOTTERS.values()) == open_before
    assert not (tmp_path / "f.png").exists()


def test_view_grid_overlays_masks():
    img = np.full((8, 10, 3), 0.5)
    mask = np.zeros((8, 10))
    mask[2:5, 3:7] = 1
    mask[0, 0] = np.nan
    fig = view_grid([img, (img * 255).astype(np.uint8), img[:, :, 0]], [mask, None, mask],
                    titles=["a", "b", "c"], mask_alpha=0.5)
    axes = fig.get_axes()
    assert len(axes) == 3 and axes[0].get_title() == "a"
    shown = np.asarray(axes[0].images[0].get_array())
    # Inside: 0.5 img + 0.5 red; outside unchanged; unknown greyed (0.5*0.5 + 0.25).
    assert np.allclose(shown[3, 4], [0.75, 0.3, 0.3])
    assert np.allclose(shown[6, 8], [0.5, 0.5, 0.5])
    assert np.allclose(shown[0, 0], [0.5, 0.5, 0.5])
    assert np.allclose(np.asarray(axes[1].images[0].get_array()), 0.5, atol=1 / 255)
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    assert buf.getvalue()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(ValidationError, match="masks"):
        view_grid([img], [mask, mask])
    with pytest.raises(ValidationError, match="mask 0"):
        view_grid([img], [mask[:4]])


# -- seed2gs view ------------------------------------------------------------------
def _parser():
    p = argparse.ArgumentParser(prog="seed2gs")
    _view.register(p.add_subparsers(dest="command"))
    return p


@pytest.fixture
def fake_reader(monkeypatch, rng):
    scene = _cloud(rng, n=50)
    monkeypatch.setattr(_view, "_read_scene", lambda path: scene)
    return scene


def test_cli_view_writes_screenshot(offscreen, fake_reader, tmp_path, capsys):
    q = tmp_path / "q.npy"
    np.save(q, np.linspace(0, 1, len(fake_reader)).astype(np.float32))
    out = tmp_path / "shot.png"
    args = _parser().parse_args(["view", "scene.ply", "--membership", str(q), "--threshold", "0.2",
                                 "--size", "64x48", "--screenshot", str(out)])
    assert args.func(args) == 0
    from PIL import Image

    assert Image.open(out).size == (64, 48)
    assert "wrote" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["q.npy", "shot.png"]


def test_cli_view_errors_exit_2_and_leave_nothing(fake_reader, tmp_path, monkeypatch, capsys):
    from seed2gs_inverse import cli, viz

    monkeypatch.setattr(cli, "_COMMAND_MODULES", ("_view",))
    q = tmp_path / "q.npy"
    np.save(q, np.ones(7))
    out = tmp_path / "shot.png"
    assert cli.main(["view", "s.ply", "--membership", str(q), "--screenshot", str(out)]) == 2
    assert "shape (7,)" in capsys.readouterr().err
    text = tmp_path / "q.txt"  # numpy calls a text file "pickled data"
    text.write_text("0.1 0.9\n")
    assert cli.main(["view", "s.ply", "--membership", str(text), "--screenshot", str(out)]) == 2
    assert f"--membership {text}: not a .npy file (write the array with numpy.save)" in capsys.readouterr().err
    text.unlink()
    assert cli.main(["view", "s.ply", "--threshold", "0.5", "--screenshot", str(out)]) == 2
    assert "--threshold needs --membership" in capsys.readouterr().err
    assert cli.main(["view", "s.ply", "--screenshot", str(tmp_path / "a.jpg")]) == 2

    def broken(scene, q, screenshot=None, **kw):
        with open(screenshot, "wb") as f:
            f.write(b"partial")
        raise ValidationError("renderer failed")
    monkeypatch.setattr(viz, "membership_plot", broken)
    assert cli.main(["view", "s.ply", "--screenshot", str(out)]) == 2
    assert "renderer failed" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["q.npy"]


def test_cli_view_reads_a_real_file(offscreen, rng, tmp_path):
    io = pytest.importorskip("seed2gs_inverse.io")
    if not hasattr(io, "write_scene"):
        pytest.skip("seed2gs_inverse.io.write_scene is not available yet")
    scene = _cloud(rng, n=30)
    io.write_scene(tmp_path / "s.ply", scene)
    out = tmp_path / "s.png"
    args = _parser().parse_args(["view", str(tmp_path / "s.ply"), "--mode", "ellipsoids",
                                 "--size", "32x24", "--screenshot", str(out)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert args.func(args) == 0
    assert out.stat().st_size > 0


def test_up_direction_without_camera(offscreen, rng, tmp_path):
    # A red cloud "above" a blue one along world -y: with up = -y the red
    # cloud must be drawn higher in the image than the blue one.
    scene = GaussianScene.concat([_cloud(rng, center=(0.0, -1.0, 0.0)),
                                  _cloud(rng, center=(0.0, 1.0, 0.0), rgb=(0.1, 0.1, 0.9))])
    img = membership_plot(scene, screenshot=tmp_path / "up.png", up=(0.0, -1.0, 0.0),
                          window_size=(W, H), point_size=4, scalar_bar=False).astype(int)
    red = (img[:, :, 0] > 150) & (img[:, :, 2] < 100)
    blue = (img[:, :, 2] > 150) & (img[:, :, 0] < 100)
    assert red.any() and blue.any()
    assert np.nonzero(red)[0].mean() < np.nonzero(blue)[0].mean()


def test_check_membership_is_public_and_names_the_source():
    from seed2gs_inverse.viz import check_membership

    q = check_membership(np.array([True, False, True]), 3)
    assert q.dtype == np.float64 and q.tolist() == [1.0, 0.0, 1.0]
    with pytest.raises(ValidationError, match=r"--membership q\.npy has shape \(2,\).*\(3,\)"):
        check_membership(np.zeros(2), 3, "--membership q.npy")
    with pytest.raises(ValidationError, match=r"q\.npy: values must be finite and in \[0, 1\]"):
        check_membership(np.array([0.0, 1.5, np.nan]), 3, "q.npy")
    with pytest.raises(ValidationError, match="dtype"):
        check_membership(np.array(["a", "b", "c"]), 3)


def test_cli_view_camera_grammar(offscreen, fake_reader, tmp_path, monkeypatch, capsys):
    """``--camera FILE:NAME`` as everywhere; the old ``--camera FILE --view NAME`` still works, with a note."""
    from seed2gs_inverse import Camera, cli
    from seed2gs_inverse.io import write_cameras

    monkeypatch.setattr(cli, "_COMMAND_MODULES", ("_view",))
    cams = [Camera.look_at(np.array([0.0, -3.0, 0.0]), np.zeros(3), np.array([0.0, 0.0, 1.0]), 50, 40, 30,
                           name=n) for n in ("a", "b")]
    write_cameras(tmp_path / "cams.json", cams)
    new, old = tmp_path / "new.png", tmp_path / "old.png"
    assert cli.main(["view", "s.ply", "--camera", f"{tmp_path / 'cams.json'}:b", "--screenshot", str(new)]) == 0
    assert "deprecated" not in capsys.readouterr().err
    assert cli.main(["view", "s.ply", "--camera", str(tmp_path / "cams.json"), "--view", "b",
                     "--screenshot", str(old)]) == 0
    assert "'--camera FILE --view b' is deprecated; write --camera FILE:b" in capsys.readouterr().err
    from PIL import Image

    assert Image.open(new).size == Image.open(old).size == (40, 30)
    # existing output: refused without --force, replaced with it
    assert cli.main(["view", "s.ply", "--screenshot", str(new)]) == 2
    assert "exists; use --force" in capsys.readouterr().err
    assert cli.main(["view", "s.ply", "--screenshot", str(new), "--force", "--up", "0,0,1"]) == 0
    # the old three-number --up still works, with a note
    assert cli.main(["view", "s.ply", "--screenshot", str(new), "--force", "--up", "0", "0", "1"]) == 0
    assert "'--up X Y Z' is deprecated; write --up 0,0,1" in capsys.readouterr().err


def test_cli_view_counts_what_it_draws_and_refuses_up_with_a_camera(offscreen, fake_reader, tmp_path,
                                                                     monkeypatch, capsys):
    """``shown:`` counted only --threshold (``shown: all`` for an empty picture); --up was ignored with --camera."""
    from seed2gs_inverse import Camera, cli
    from seed2gs_inverse.io import write_cameras

    monkeypatch.setattr(cli, "_COMMAND_MODULES", ("_view",))
    out = tmp_path / "v.png"
    assert cli.main(["view", "s.ply", "--screenshot", str(out), "--min-opacity", "0.999999"]) == 0
    assert "shown: 0)" in capsys.readouterr().out
    assert cli.main(["view", "s.ply", "--screenshot", str(out), "--force"]) == 0
    assert "shown: all)" in capsys.readouterr().out
    assert cli.main(["view", "s.ply", "--screenshot", str(out), "--force", "--mode", "ellipsoids",
                     "--max-glyphs", "10"]) == 0
    printed = capsys.readouterr()
    assert "shown: 10)" in printed.out and "ellipsoids for 10 of 50" in printed.err
    assert "raise --max-glyphs" in printed.err and " max_glyphs" not in printed.err  # the option's name
    write_cameras(tmp_path / "cams.json", [Camera.look_at(np.array([0.0, -3.0, 0.0]), np.zeros(3),
                                                          np.array([0.0, 0.0, 1.0]), 50, 40, 30)])
    assert cli.main(["view", "s.ply", "--camera", str(tmp_path / "cams.json"), "--up", "1,0,0",
                     "--screenshot", str(out), "--force"]) == 2
    assert "--up applies without --camera only" in capsys.readouterr().err


def test_cli_view_usage_shows_one_up_vector(monkeypatch, capsys):
    """The usage read ``--up X,Y,Z [X,Y,Z ...]``, though two directions are an error."""
    from seed2gs_inverse import cli

    monkeypatch.setattr(cli, "_COMMAND_MODULES", ("_view",))
    assert cli.main(["view", "--help"]) == 0
    out = capsys.readouterr().out
    assert "[--up X,Y,Z]" in out and "X,Y,Z ..." not in out


def test_cli_view_shows_minus_y_up_by_default(offscreen, rng, tmp_path, monkeypatch):
    """Without --camera and --up the command uses render --look-at's default up, -y (VTK's own +z showed
    COLMAP-trained scenes from under the floor); with --camera it passes no up."""
    io = pytest.importorskip("seed2gs_inverse.io")
    io.write_scene(tmp_path / "s.ply", _cloud(rng, n=30))
    io.write_cameras(tmp_path / "cams.json", [Camera.look_at([0, 0, -3], [0, 0, 0], [0, -1, 0], 50.0, 32, 24)])
    seen = []
    import seed2gs_inverse.viz as viz

    monkeypatch.setattr(viz, "membership_plot", lambda *a, **k: seen.append(k.get("up")) or np.zeros((2, 2, 3)))
    for i, extra in enumerate(([], ["--up", "0,0,1"], ["--camera", str(tmp_path / "cams.json")])):
        args = _parser().parse_args(["view", str(tmp_path / "s.ply"), "--screenshot", str(tmp_path / f"v{i}.png")]
                                    + extra)
        args.func(args)
    assert seen == [[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], None]
