"""`seed2gs extract --up / --cameras / --point-mode / --smoothness / --completion / --keep-islands` / `--no-follow-faint` / `--no-follow-weak` / `--mask-tolerance`."""

import json

import cv2
import numpy as np
import pytest

import seed2gs_inverse.cli as cli
from seed2gs_inverse.io import write_cameras, write_scene
from seed2gs_inverse.raster import build_operator
from seed2gs_inverse.synthetic import make_scene


@pytest.fixture(autouse=True)
def _commands(monkeypatch):
    mods = tuple(cli._COMMAND_MODULES)
    if "_extract" not in mods:
        mods += ("_extract",)
    monkeypatch.setattr(cli, "_COMMAND_MODULES", mods)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_up")
    syn = make_scene(seed=0)
    cam = syn.reference_camera(128, 96)
    write_scene(d / "scene.ply", syn.scene)
    write_cameras(d / "cameras.json", [cam])
    orbit = syn.orbit_cameras(6, 64, 48)
    write_cameras(d / "capture.json", orbit)
    seed = (build_operator(syn.scene, cam).W @ (syn.labels == 1).astype(np.float32)).reshape(cam.image_shape) > 0.5
    cv2.imwrite(str(d / "mask.png"), seed.astype(np.uint8) * 255)
    return d, syn


def _extract(d, out, *extra):
    return cli.main([str(a) for a in ["extract", d / "scene.ply", "--camera", f"{d / 'cameras.json'}:0",
                                      "--mask", d / "mask.png", "-o", out, "--views", 2, "--no-progress",
                                      *extra]])


def test_up_vector_reaches_the_report(files, capsys):
    d, syn = files
    assert _extract(d, d / "vec", "--up=0,-2,0") == 0, capsys.readouterr().err
    rep = json.loads((d / "vec" / "report.json").read_text())
    assert rep["up"]["method"] == "user" and np.allclose(rep["up"]["axis"], [0, -1, 0])


def test_auto_up_with_capture_cameras_reaches_the_report(files, capsys):
    d, syn = files
    assert _extract(d, d / "auto", "--cameras", d / "capture.json") == 0, capsys.readouterr().err
    rep = json.loads((d / "auto" / "report.json").read_text())
    assert rep["up"]["method"] in ("support-plane", "support-plane+scene-plane")
    assert 0.0 <= rep["up"]["confidence"] <= 1.0 and "cameras" in rep["up"]["details"]
    assert rep["resolved"]["up_method"] == rep["up"]["method"]
    assert rep["settings"]["up"] == "auto" and rep["run"]["up_cameras"]["n_cameras"] == 6


@pytest.mark.parametrize("bad", ["sideways", "0,0", "0,0,0", "1,x,2"])
def test_bad_up_is_refused_before_any_work(files, bad, capsys):
    d, _ = files
    assert _extract(d, d / "bad", "--up", bad) == 2
    assert "--up" in capsys.readouterr().err and not (d / "bad").exists()


def test_from_report_repeats_a_run_with_capture_cameras(files, capsys):
    d, _ = files
    assert _extract(d, d / "cams1", "--cameras", d / "capture.json") == 0, capsys.readouterr().err
    rep = d / "cams1" / "report.json"
    assert cli.main(["extract", "--from-report", str(rep), "-o", str(d / "cams2"), "--no-progress"]) == 0
    np.testing.assert_array_equal(np.load(d / "cams1" / "q.npy"), np.load(d / "cams2" / "q.npy"))
    again = json.loads((d / "cams2" / "report.json").read_text())
    assert again["up"]["axis"] == json.loads(rep.read_text())["up"]["axis"]
    assert cli.main(["extract", "--from-report", str(rep), "--cameras", str(d / "capture.json"),
                     "-o", str(d / "cams3")]) == 2
    assert "--cameras" in capsys.readouterr().err


def test_point_mode_reaches_the_settings(files, capsys):
    d, syn = files
    cam = syn.reference_camera(128, 96)
    seed = (build_operator(syn.scene, cam).W @ (syn.labels == 1).astype(np.float32)).reshape(cam.image_shape) > 0.5
    ys, xs = np.nonzero(seed)
    args = ["extract", d / "scene.ply", "--camera", f"{d / 'cameras.json'}:0", "--point", int(np.median(xs)),
            int(np.median(ys)), "--views", 2, "--no-progress", "--up", "level"]
    for mode in ("region", "object"):
        assert cli.main([str(a) for a in args + ["--point-mode", mode, "-o", d / f"pm_{mode}"]]) == 0, \
            capsys.readouterr().err
        rep = json.loads((d / f"pm_{mode}" / "report.json").read_text())
        assert rep["settings"]["point_mode"] == mode
        assert (rep["prompt"].get("mode") == "object") == (mode == "object")
    assert cli.main([str(a) for a in args + ["--point-mode", "blob", "-o", d / "pm_bad"]]) == 2


def test_smoothness_and_completion_reach_the_settings(files, capsys):
    d, _ = files
    assert _extract(d, d / "sm", "--smoothness", 0.5, "--completion", "tracked", "--up", "level") == 0, \
        capsys.readouterr().err
    rep = json.loads((d / "sm" / "report.json").read_text())
    assert rep["settings"]["smoothness"] == 0.5 and rep["settings"]["completion"] == "tracked"
    assert rep["resolved"]["smoothness"] == 0.5
    assert _extract(d, d / "sm_bad", "--smoothness", -1) == 2
    assert "--smoothness must be >= 0" in capsys.readouterr().err and not (d / "sm_bad").exists()


def test_keep_islands_reaches_the_settings(files, capsys):
    d, _ = files
    assert _extract(d, d / "isl", "--keep-islands", "--up", "level") == 0, capsys.readouterr().err
    rep = json.loads((d / "isl" / "report.json").read_text())
    assert rep["settings"]["seed_connected"] is False and rep["resolved"]["n_disconnected"] == 0
    assert _extract(d, d / "isl_default", "--up", "level") == 0, capsys.readouterr().err
    rep = json.loads((d / "isl_default" / "report.json").read_text())
    assert rep["settings"]["seed_connected"] is True and rep["resolved"]["n_disconnected"] >= 0
    rep_path = d / "isl" / "report.json"
    assert cli.main(["extract", "--from-report", str(rep_path), "--keep-islands", "-o", str(d / "isl_rep")]) == 2
    assert "cannot be combined with --keep-islands" in capsys.readouterr().err


def test_no_support_background_reaches_the_settings(files, capsys):
    d, _ = files
    assert _extract(d, d / "nsb", "--no-support-background", "--up", "level") == 0, capsys.readouterr().err
    rep = json.loads((d / "nsb" / "report.json").read_text())
    assert rep["settings"]["support_background"] is False
    assert rep["resolved"]["support"] == {"used": False, "reason": "support_background is off"}
    assert _extract(d, d / "sb_default", "--up", "level") == 0, capsys.readouterr().err
    rep = json.loads((d / "sb_default" / "report.json").read_text())
    # "level" is a heuristic axis: the support rule waits for a trusted one
    assert rep["settings"]["support_background"] is True and rep["resolved"]["support"]["used"] is False
    assert "not trusted" in rep["resolved"]["support"]["reason"]
    rep_path = d / "nsb" / "report.json"
    assert cli.main(["extract", "--from-report", str(rep_path), "--no-support-background", "-o",
                     str(d / "nsb_rep")]) == 2
    assert "cannot be combined with --no-support-background" in capsys.readouterr().err


def test_no_follow_faint_and_no_follow_weak_reach_the_settings(files, capsys):
    d, _ = files
    assert _extract(d, d / "nff", "--no-follow-faint", "--no-follow-weak", "--up", "level") == 0, \
        capsys.readouterr().err
    rep = json.loads((d / "nff" / "report.json").read_text())
    assert rep["settings"]["follow_faint"] is False and rep["settings"]["follow_weak"] is False
    assert _extract(d, d / "ff_default", "--up", "level") == 0, capsys.readouterr().err
    default = json.loads((d / "ff_default" / "report.json").read_text())["settings"]
    assert default["follow_faint"] is True and default["follow_weak"] is True
    # a report written before the options replays with them off, as it ran
    old = dict(json.loads((d / "ff_default" / "report.json").read_text()),
               settings={k: v for k, v in default.items() if k not in ("follow_faint", "follow_weak")})
    old_path = d / "old_report.json"
    old_path.write_text(json.dumps(old))
    assert cli.main(["extract", "--from-report", str(old_path), "-o", str(d / "old_rep")]) == 0, \
        capsys.readouterr().err
    replayed = json.loads((d / "old_rep" / "report.json").read_text())["settings"]
    assert replayed["follow_faint"] is False and replayed["follow_weak"] is False
    for flag in ("--no-follow-faint", "--no-follow-weak"):
        assert cli.main(["extract", "--from-report", str(d / "nff" / "report.json"), flag, "-o",
                         str(d / "nff_rep")]) == 2
        assert f"cannot be combined with {flag}" in capsys.readouterr().err


def test_near_margin_reaches_the_settings(files, capsys):
    d, _ = files
    assert _extract(d, d / "nm", "--near-margin", "off", "--up", "level") == 0, capsys.readouterr().err
    assert json.loads((d / "nm" / "report.json").read_text())["settings"]["near_margin"] is None
    assert _extract(d, d / "nm2", "--near-margin", "0.5", "--up", "level") == 0, capsys.readouterr().err
    assert json.loads((d / "nm2" / "report.json").read_text())["settings"]["near_margin"] == 0.5
    for bad, says in (("-1", "--near-margin must be > 0"), ("far", "--near-margin 'far': expected a number > 0")):
        assert _extract(d, d / "nm_bad", "--near-margin", bad) == 2
        err = capsys.readouterr().err
        assert says in err, err
        assert not (d / "nm_bad").exists()
    assert cli.main(["extract", "--from-report", str(d / "nm" / "report.json"), "--near-margin", "1", "-o",
                     str(d / "nm_rep")]) == 2
    assert "cannot be combined with --near-margin" in capsys.readouterr().err


def test_mask_tolerance_reaches_the_tracker_and_the_replay(files, capsys):
    d, _ = files
    assert _extract(d, d / "mt", "--mask-tolerance", "5", "--up", "level") == 0, capsys.readouterr().err
    rep = json.loads((d / "mt" / "report.json").read_text())
    assert rep["settings"]["mask_tolerance"] == 5 and rep["resolved"]["seed_band"] == 5
    assert cli.main(["extract", "--from-report", str(d / "mt" / "report.json"), "-o", str(d / "mt_rep")]) == 0, \
        capsys.readouterr().err
    replayed = json.loads((d / "mt_rep" / "report.json").read_text())
    assert replayed["settings"]["mask_tolerance"] == 5 and replayed["resolved"]["seed_band"] == 5
    assert cli.main(["extract", "--from-report", str(d / "mt" / "report.json"), "--mask-tolerance", "0", "-o",
                     str(d / "mt_rep2")]) == 2
    assert "cannot be combined with --mask-tolerance" in capsys.readouterr().err
    assert _extract(d, d / "mt_bad", "--mask-tolerance", "-1") == 2
    err = capsys.readouterr().err
    assert "--mask-tolerance must be" in err, err
    assert not (d / "mt_bad").exists()
