"""`seed2gs extract` and `seed2gs demo` from the command line."""

import json

import cv2
import numpy as np
import pytest

import seed2gs_inverse.cli as cli
from _cli_files import write_cli_files
from seed2gs_inverse.io import read_scene, write_cameras, write_scene
from seed2gs_inverse.raster import build_operator


@pytest.fixture(autouse=True)
def _commands(monkeypatch):
    mods = tuple(cli._COMMAND_MODULES)
    for m in ("_extract", "_demo"):
        if m not in mods:
            mods += (m,)
    monkeypatch.setattr(cli, "_COMMAND_MODULES", mods)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return write_cli_files(tmp_path_factory.mktemp("cli"))


def _run(args):
    return cli.main([str(a) for a in args])


def test_extract_mask_writes_all_outputs(files, capsys):
    d = files["dir"]
    out = d / "out_mask"
    rc = _run(["extract", d / "scene.ply", "--camera", f"{d / 'cameras.json'}:0", "--mask", d / "mask.png",
               "-o", out, "--views", 8, "--no-progress"])
    assert rc == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["object.ply", "q.npy", "remainder.ply",
                                                    "report.json", "report.png", "report_masks.png"]
    q = np.load(out / "q.npy", allow_pickle=False)
    obj = read_scene(out / "object.ply")
    rem = read_scene(out / "remainder.ply")
    n = len(files["syn"].scene)
    assert q.shape == (n,) and len(obj) + len(rem) == n and len(obj) == int((q > 0.5).sum())
    rep = json.loads((out / "report.json").read_text())
    assert rep["n_selected"] == len(obj) and set(rep["seconds"]) >= {"render", "lift", "vaas", "solve"}
    # report.json's settings are the ExtractSettings of the command line, and load back as such
    from seed2gs_inverse.pipeline import ExtractSettings

    # (--no-progress: stage lines instead of bars)
    assert ExtractSettings.from_dict(rep["settings"]) == ExtractSettings(n_views=8, progress="lines")
    assert rep["resolved"]["threshold"] == 0.5 and rep["resolved"]["tracker"] == "GeometricTracker"
    assert rep["resolved"]["solver_options"] == {"max_iter": 20} and rep["resolved"]["view_scale"] == 0.5
    sel = q > 0.5
    truth = files["truth"]
    assert (sel & truth).sum() / sel.sum() > 0.9 and (sel & truth).sum() / truth.sum() > 0.8
    # No temporary directories left next to the output.
    assert not [p for p in d.iterdir() if p.name.startswith(".out_mask")]
    # Existing output is refused without --force, replaced with it.
    assert _run(["extract", d / "scene.ply", "--camera", d / "cameras.json", "--mask", d / "mask.png",
                 "-o", out, "--views", 4]) == 2
    assert "exists" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["box", "point"])
def test_extract_box_and_point_prompts(files, kind, capsys):
    d = files["dir"]
    out = d / f"out_{kind}"
    prompt = ["--box", *files["box"]] if kind == "box" else ["--point", *files["point"]]
    rc = _run(["extract", d / "scene.ply", "--camera", d / "cameras.json", *prompt, "-o", out,
               "--views", 6, "--no-progress"])
    assert rc == 0, capsys.readouterr().err
    sel = np.load(out / "q.npy") > 0.5
    truth = files["truth"]
    assert (sel & truth).sum() / max(sel.sum(), 1) > 0.8


def _fails(args, capsys, match, out):
    rc = _run(args + ["--quiet"])  # quiet: the error is all stderr holds
    err = capsys.readouterr().err
    assert rc == 2 and match in err and err.count("\n") == 1, err
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}")]


def test_extract_bad_input_leaves_nothing(files, capsys, tmp_path):
    d = files["dir"]
    scene, cams, out = d / "scene.ply", d / "cameras.json", tmp_path / "never"
    empty = tmp_path / "empty.png"
    cv2.imwrite(str(empty), np.zeros((96, 128), np.uint8))
    _fails(["extract", scene, "--camera", cams, "--mask", empty, "-o", out], capsys, "empty", out)
    _fails(["extract", scene, "--camera", cams, "--box", 500, 500, 600, 600, "-o", out], capsys,
           "outside", out)
    _fails(["extract", tmp_path / "nope.ply", "--camera", cams, "--mask", d / "mask.png", "-o", out],
           capsys, "no such file", out)
    _fails(["extract", scene, "--camera", cams, "--prompt", "red ball", "-o", out], capsys,
           "--box", out)
    _fails(["extract", scene, "--camera", cams, "--mask", d / "mask.png", "--threshold", 1.5, "-o", out],
           capsys, "threshold", out)
    # options the settings object rejects fail before any work, naming the option
    _fails(["extract", scene, "--camera", cams, "--mask", d / "mask.png", "--orbit-scale", 5, "-o", out],
           capsys, "--orbit-scale must be <= 4", out)
    _fails(["extract", scene, "--camera", cams, "--mask", d / "mask.png", "--views", 1, "-o", out],
           capsys, "--views must be in 2..360", out)
    _fails(["extract", scene, "--camera", cams, "--box", 1, 1, 50, 50, "--negative", 3, 3, "-o", out],
           capsys, "--point", out)
    # A mask on empty space (the sky) does not touch the scene.
    alpha = build_operator(files["syn"].scene, files["cam"]).rendering.alpha
    sky = tmp_path / "sky.png"
    cv2.imwrite(str(sky), (alpha < 1e-3).astype(np.uint8) * 255)
    _fails(["extract", scene, "--camera", cams, "--mask", sky, "-o", out], capsys, "touch", out)
    # A camera that looks away from everything.
    cam = files["cam"]
    away = cam.with_pose(np.diag([-1.0, 1.0, -1.0, 1.0]) @ cam.world_to_camera)
    write_cameras(tmp_path / "away.json", [away])
    _fails(["extract", scene, "--camera", tmp_path / "away.json", "--mask", d / "mask.png", "-o", out],
           capsys, "sees nothing", out)


def test_demo_prints_scores(capsys):
    assert _run(["demo", "--object", "sphere", "--views", 6, "--size", 128, 96]) == 0
    out = capsys.readouterr().out
    assert "mIoU" in out and "3D membership" in out and "sphere" in out
    miou = float(out.split("mIoU ")[1].split()[0])
    assert miou > 0.9
    assert _run(["demo", "--summary"]) == 0
    assert "Gaussians" in capsys.readouterr().out


def test_demo_outputs_say_how_to_repeat_them(capsys, tmp_path):
    out = tmp_path / "demo"
    assert _run(["demo", "--object", "sphere", "--views", 4, "--size", 96, 72, "-o", out]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["demo"] == {"seed": 0, "object": "sphere", "views": 4, "size": "96 72", "method": "weighted_bce"}
    capsys.readouterr()
    assert _run(["extract", "--from-report", out / "report.json", "-o", tmp_path / "again"]) == 2
    err = capsys.readouterr().err
    assert "written by seed2gs demo" in err and "seed2gs demo --seed 0 --object sphere --views 4 --size 96 72" in err


def test_from_report_repeats_the_run(files, capsys, tmp_path):
    """report.json alone reproduces a run: --from-report gives the same q (issue 12 item 14)."""
    import seed2gs_inverse
    from seed2gs_inverse.operators import scene_fingerprint

    d = files["dir"]
    first, again = tmp_path / "first", tmp_path / "again"
    box = [float(v) for v in files["box"]]
    assert _run(["extract", d / "scene.ply", "--camera", f"{d / 'cameras.json'}:0", "--box", *box,
                 "--views", 4, "--up", "camera", "--option", "max_iter=12", "-o", first]) == 0
    out = capsys.readouterr().out
    rep = json.loads((first / "report.json").read_text())
    run = rep["run"]
    # everything needed to repeat the run is recorded
    assert run["toolkit"] == f"seed2gs-inverse {seed2gs_inverse.__version__}"
    assert run["scene"]["path"] == str((d / "scene.ply").resolve())
    assert run["scene"]["fingerprint"] == scene_fingerprint(files["syn"].scene)
    assert run["camera"]["spec"] == f"{d / 'cameras.json'}:0"
    from seed2gs_inverse.io import read_camera

    assert run["camera"]["camera"] == json.loads(json.dumps(read_camera(f"{d / 'cameras.json'}:0").to_dict()))
    assert run["prompt"]["kind"] == "box" and run["prompt"]["box"] == box
    # the process's peak memory, as the kernel counts it (the extraction holds the scene and its operators)
    import resource

    assert 0 < run["peak_rss_mb"] <= resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    assert f"peak memory {run['peak_rss_mb'] / 1024:.2f} GB" in out
    assert rep["settings"]["n_views"] == 4 and rep["settings"]["up"] == "camera"
    assert rep["settings"]["solver_options"] == {"max_iter": 12}
    assert np.allclose(run["axis"], files["cam"].up)  # --up camera: the orbit axis is the image up
    assert run["seeds"]["grabcut_opencv_rng"] == -1
    # the seed's size is reported on the command line and in the report
    seed = rep["seed"]
    assert f"seed: {seed['seed_pixels']:,} px = {seed['share_of_object_box']:.0%} of the object's box" in out
    # ... and what the remainder keeps of the object's alpha
    rem = rep["remainder_share"]
    assert f"; the remainder keeps {rem['share']:.1%} of the object's alpha (worst view {rem['worst_view']:.1%})" in out
    # repeat it
    assert _run(["extract", "--from-report", first / "report.json", "-o", again]) == 0
    q1, q2 = np.load(first / "q.npy"), np.load(again / "q.npy")
    assert np.array_equal(q1, q2) and (q1 > 0.5).any()
    rep2 = json.loads((again / "report.json").read_text())
    assert rep2["settings"] == rep["settings"] and rep2["run"]["prompt"] == run["prompt"]
    capsys.readouterr()
    # a different scene under the recorded name is refused (geometry fingerprint)
    other = tmp_path / "other.ply"
    write_scene(other, files["syn"].scene.subset(np.arange(len(files["syn"].scene)) % 2 == 0))
    assert _run(["extract", other, "--from-report", first / "report.json", "-o", tmp_path / "x"]) == 2
    assert "not the recorded scene" in capsys.readouterr().err


def test_from_report_with_a_mask_prompt(files, capsys, tmp_path):
    d = files["dir"]
    mask = tmp_path / "seed.png"
    mask.write_bytes((d / "mask.png").read_bytes())
    a, b = tmp_path / "a", tmp_path / "b"
    assert _run(["extract", d / "scene.ply", "--camera", d / "cameras.json", "--mask", mask, "--views", 3,
                 "--method", "voting", "-o", a]) == 0
    assert _run(["extract", "--from-report", a / "report.json", "-o", b]) == 0
    assert np.array_equal(np.load(a / "q.npy"), np.load(b / "q.npy"))
    # the recorded mask must be the same file
    img = cv2.imread(str(mask), cv2.IMREAD_GRAYSCALE)
    img[0, 0] = 255 - img[0, 0]
    cv2.imwrite(str(mask), img)
    capsys.readouterr()
    assert _run(["extract", "--from-report", a / "report.json", "-o", tmp_path / "c"]) == 2
    assert "changed since the recorded run" in capsys.readouterr().err


def test_progress_bars_only_on_a_terminal(files, capsys, tmp_path, monkeypatch):
    """A log file (stderr not a terminal) gets no progress bars; a terminal gets a bar per stage, the solve's
    with the loss."""
    d = files["dir"]
    args = ["extract", d / "scene.ply", "--camera", d / "cameras.json", "--mask", d / "mask.png", "--views", 3]
    assert _run(args + ["-o", tmp_path / "log"]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and "it/s" not in err and "loss" not in err

    import sys

    from seed2gs_inverse.progress import Progress as _Progress

    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    monkeypatch.setattr(_Progress, "MININTERVAL", 0.0)  # redraw on every update: the loss shows however fast
    monkeypatch.setattr(_Progress, "DELAY", 0.0)  # and at once, however short the stage
    assert _run(args + ["-o", tmp_path / "tty"]) == 0
    err = capsys.readouterr().err
    assert "solve (weighted_bce)" in err and "loss" in err and "VAAS views" in err
    # every stage has its bar, the ones without steps to count with their time
    assert all(f"\r{name}" in err for name in ("render:", "grounding:", "reference view:", "lift:", "tracking:",
                                                "write:")), err
    assert "seed2gs: render" not in err  # bars, not stage lines
    assert _run(args + ["-o", tmp_path / "quiet", "--no-progress"]) == 0
    assert "loss" not in capsys.readouterr().err


def test_from_report_of_an_older_run_keeps_its_behaviour(files, capsys, tmp_path):
    """A report written before an option existed, or before a solver default changed, replays as it ran."""
    d = files["dir"]
    first, again = tmp_path / "first", tmp_path / "again"
    assert _run(["extract", d / "scene.ply", "--camera", f"{d / 'cameras.json'}:0", "--mask", d / "mask.png",
                 "--views", 3, "--up", "camera", "-o", first]) == 0
    rep = json.loads((first / "report.json").read_text())
    assert rep["resolved"]["solver_options"] == {"max_iter": 20} and rep["settings"]["solver_options"] == {}
    # as an older toolkit wrote it: no seed_connected / support_background, weighted_bce ran 30 iterations
    del rep["settings"]["seed_connected"], rep["settings"]["support_background"]
    rep["resolved"]["solver_options"] = {"max_iter": 30}
    old = tmp_path / "old.json"
    old.write_text(json.dumps(rep))
    assert _run(["extract", "--from-report", old, "-o", again]) == 0, capsys.readouterr().err
    rep2 = json.loads((again / "report.json").read_text())
    assert rep2["settings"]["seed_connected"] is False and rep2["settings"]["support_background"] is False
    assert rep2["settings"]["solver_options"] == {"max_iter": 30}
    assert rep2["resolved"]["solver_options"] == {"max_iter": 30}


def test_an_empty_selection_is_said_and_splat_outputs_skip_empty_parts(files, capsys, tmp_path):
    """Nothing selected: the run still writes q.npy and report.json, warns instead of calling the object
    invisible, and leaves out the .splat of the empty part (an empty .splat cannot be read back)."""
    from seed2gs_inverse.io import read_scene

    d = files["dir"]
    out = tmp_path / "empty"
    rc = _run(["extract", d / "scene.ply", "--camera", f"{d / 'cameras.json'}:0", "--mask", d / "mask.png",
               "-o", out, "--views", 4, "--threshold", 0.99999999, "--format", "splat", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "warning: nothing was selected" in err and "lower the threshold" in err
    assert "object is empty (0 Gaussians): object.splat is not written" in err
    assert sorted(p.name for p in out.iterdir()) == ["q.npy", "remainder.splat", "report.json", "report.png",
                                                    "report_masks.png"]
    rep = json.loads((out / "report.json").read_text())
    assert rep["outputs"] == {"object": None, "remainder": "remainder.splat", "q": "q.npy"}
    assert rep["n_selected"] == 0 and len(read_scene(out / "remainder.splat")) == len(files["syn"].scene)


def test_splat_output_warnings_name_the_users_path(files, capsys, tmp_path):
    """The .splat writer's warning (SH bands dropped) named the temporary directory the outputs are built in."""
    d = files["dir"]
    assert files["syn"].scene.sh_degree == 3
    out = tmp_path / "out"
    assert _run(["extract", d / "scene.ply", "--camera", f"{d / 'cameras.json'}:0", "--mask", d / "mask.png",
                 "-o", out, "--views", 4, "--format", "splat", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert f"{out / 'object.splat'}: the .splat format cannot store SH bands 1-3" in err, err
    assert ".tmp" not in err


def test_extract_from_a_look_at_camera(files, capsys, tmp_path):
    """A scene without a camera file: --look-at EYE TARGET (with --look-up, --fov, --size) makes the
    reference camera, report.json records it, and --from-report repeats the run."""
    d, cam = files["dir"], files["cam"]
    eye, target = cam.center, cam.center + cam.forward
    fov = float(np.degrees(2 * np.arctan(0.5 * cam.height / cam.fy)))
    look = ["--look-at", ",".join(map(str, eye)), ",".join(map(str, target)),
            "--look-up", ",".join(map(str, cam.up)), "--fov", fov, "--size", f"{cam.width}x{cam.height}"]
    first, again = tmp_path / "first", tmp_path / "again"
    assert _run(["extract", d / "scene.ply", *look, "--mask", d / "mask.png", "--views", 4, "--no-progress",
                 "--option", "max_iter=12", "-o", first]) == 0, capsys.readouterr().err
    rep = json.loads((first / "report.json").read_text())
    rec = rep["run"]["camera"]
    assert rec["spec"] is None and rec["camera"]["name"] == "look-at"
    assert (rec["camera"]["width"], rec["camera"]["height"]) == (cam.width, cam.height)
    np.testing.assert_allclose(rec["camera"]["fy"], cam.fy, rtol=1e-9)
    assert _run(["extract", "--from-report", first / "report.json", "-o", again]) == 0
    np.testing.assert_array_equal(np.load(first / "q.npy"), np.load(again / "q.npy"))
    capsys.readouterr()
    for args, msg in ((["--camera", f"{d / 'cameras.json'}:0", *look], "give the reference camera once"),
                      (["--camera", f"{d / 'cameras.json'}:0", "--fov", 40], "--fov go with --look-at"),
                      ([], "or --look-at EYE TARGET"),
                      (["--look-at", "0,0,0", "0,0,0"], "--look-at / --look-up / --fov"),
                      (["--look-at", "1,2", "0,0,0"], "expected three numbers")):
        assert _run(["extract", d / "scene.ply", *args, "--mask", d / "mask.png", "-o", tmp_path / "bad"]) == 2
        assert msg in capsys.readouterr().err and not (tmp_path / "bad").exists()
    assert _run(["extract", "--from-report", first / "report.json", "--fov", 30, "-o", tmp_path / "bad"]) == 2
    assert "cannot be combined with --fov" in capsys.readouterr().err
