"""``seed2gs`` never prints a traceback for bad input (issue 12, "How it is checked").

A table of bad inputs (paths, numbers, options, cameras, masks, methods,
reports) goes through :func:`seed2gs_inverse.cli.main`; each must end with
exit status 2 and exactly one line on stderr, ``seed2gs <command>: error:
...``, naming what is wrong, and must leave no output behind. The
expensive-input cases (a bad output path with a valid everything else)
must fail before any work: they are timed against a full run.
"""

from __future__ import annotations

import json
import time

import cv2
import numpy as np
import pytest

import seed2gs_inverse.cli as cli
from seed2gs_inverse.io import write_cameras, write_scene
from seed2gs_inverse.operators import OperatorStack, scene_fingerprint
from seed2gs_inverse.raster import build_operator
from seed2gs_inverse.synthetic import make_scene


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad")
    syn = make_scene(seed=0)
    cam = syn.reference_camera(64, 48)
    write_scene(d / "scene.ply", syn.scene)
    write_cameras(d / "cameras.json", [cam])
    op = build_operator(syn.scene, cam)
    seed = (op.W @ (syn.labels == 2).astype(np.float32)).reshape(cam.image_shape) > 0.5
    cv2.imwrite(str(d / "mask.png"), seed.astype(np.uint8) * 255)
    OperatorStack([op, build_operator(syn.scene, cam.scaled(0.5))],
                  fingerprint=scene_fingerprint(syn.scene)).save(d / "ops")
    (d / "masks").mkdir()
    cv2.imwrite(str(d / "masks" / "view_000.png"), seed.astype(np.uint8) * 255)  # one of two views
    (d / "masks1").mkdir()
    np.save(d / "truth.npy", syn.labels == 2)
    (d / "afile").write_text("not a directory")
    (d / "exists").mkdir()
    (d / "userdir").mkdir()
    (d / "userdir" / "mine.txt").write_text("keep")
    (d / "deep").mkdir()
    (d / "deep" / "report.json").write_text("[" * 200_000)  # json's RecursionError, not a traceback
    for marker in ("report.json", "manifest.json", "comparison.json"):  # a marker's name is not enough
        (d / f"fake_{marker[:-5]}").mkdir()
        (d / f"fake_{marker[:-5]}" / marker).write_text("{}")
        (d / f"fake_{marker[:-5]}" / "thesis.tex").write_text("keep")
    (d / "exists.ply").write_bytes(b"")
    (d / "exists.png").write_bytes(b"")
    (d / "exists.npy").write_bytes(b"")
    bad_cam = json.loads((d / "cameras.json").read_text())
    bad_cam[0]["width"] = 0
    (d / "zero_width.json").write_text(json.dumps(bad_cam))
    (d / "garbage.json").write_text("{not json")
    (d / "garbage.ply").write_bytes(b"ply\nformat nonsense\n")
    (d / "not_a_report.json").write_text(json.dumps({"n_selected": 3}))
    (d / "edited_report.json").write_text(json.dumps({"run": {"scene": "scene.ply", "camera": {}}, "settings": {}}))
    (d / "batch_report.json").write_text(json.dumps({"batch": {"job": "chair", "fingerprint": "f"}, "settings": {}}))
    (d / "text.png").write_text("not an image")
    np.save(d / "objects.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)  # a pickle inside
    np.save(d / "short.npy", np.ones(3, bool))
    return d


def _fmt(d, args):
    return [str(a).format(d=d) for a in args]


# (command-line with {d} for the fixture directory, text the one-line message must contain)
EXTRACT = ["extract", "{d}/scene.ply", "--camera", "{d}/cameras.json:0", "--mask", "{d}/mask.png"]
BAD = [
    # bad paths
    (["extract", "{d}/missing.ply", "--camera", "{d}/cameras.json", "--box", 1, 1, 9, 9, "-o", "{d}/o"],
     "missing.ply: no such file"),
    (["extract", "{d}/scene.ply", "--camera", "{d}/nocams.json", "--box", 1, 1, 9, 9, "-o", "{d}/o"],
     "nocams.json"),
    (EXTRACT + ["-o", "/proc/seed2gs_out"], "-o /proc/seed2gs_out: cannot write in /proc"),
    (EXTRACT + ["-o", "{d}/afile/out"], "afile is a file, not a directory"),
    (EXTRACT + ["-o", "{d}/no/such/dir/out"], "the directory {d}/no/such/dir does not exist"),
    (EXTRACT + ["-o", "{d}/exists"], "-o {d}/exists exists; use --force"),
    (EXTRACT + ["-o", "{d}/exists.ply", "--force"], "exists and is not a directory"),
    # --force replaces an earlier output, never a folder of the user's files or the working directory
    (EXTRACT + ["-o", "{d}/userdir", "--force"], "-o {d}/userdir exists and it is not empty and is not an "
                                                 "earlier output (its report.json is missing or not the toolkit's)"),
    (EXTRACT + ["-o", "{d}/deep", "--force"], "-o {d}/deep exists and it is not empty and is not an earlier output"),
    (EXTRACT + ["-o", "{d}/fake_report", "--force"], "-o {d}/fake_report exists and it is not empty and is not "
                                                     "an earlier output"),
    (["operators", "build", "{d}/scene.ply", "--cameras", "{d}/cameras.json", "-o", "{d}/o", "--scale", 100],
     "--scale must be in (0, 4], got 100.0"),
    (["operators", "build", "{d}/scene.ply", "--cameras", "{d}/cameras.json", "-o", "{d}/o", "--scale", 1e-6],
     "each side must lie in 4..32768"),  # five 1x1 views were built
    (["operators", "build", "{d}/scene.ply", "--cameras", "{d}/cameras.json", "-o", "{d}/o", "--min-weight", -1],
     "--min-weight must be in [0, 1], got -1.0"),
    (["operators", "build", "{d}/scene.ply", "--cameras", "{d}/cameras.json", "-o", "{d}/fake_manifest",
      "--force"], "its manifest.json is missing or not the toolkit's"),
    (EXTRACT + ["-o", ".", "--force"], "-o . is the current directory or holds it"),
    (["compare", "{d}/ops", "{d}/masks", "--truth", "{d}/truth.npy", "-o", "{d}/userdir", "--force"],
     "its comparison.json is missing or not the toolkit's"),
    (["compare", "{d}/ops", "{d}/masks", "--truth", "{d}/truth.npy", "-o", "{d}/fake_comparison", "--force"],
     "its comparison.json is missing or not the toolkit's"),
    (["demo", "-o", "{d}/userdir", "--force"], "its report.json is missing or not the toolkit's"),
    (["demo", "--seed", -1], "--seed must be a whole number >= 0, got -1"),
    (["demo", "--size", 0, 0], "--size W H: each must be in 16..4096 pixels, got 0 0"),
    (["demo", "--size", 100000, 100000], "--size W H: each must be in 16..4096 pixels"),
    (["extract", "{d}/scene.ply", "--camera", "{d}/cameras.json", "--mask", "{d}/nomask.png", "-o", "{d}/o"],
     "--mask {d}/nomask.png: no such file"),
    (["extract", "{d}/exists", "--camera", "{d}/cameras.json", "--box", 1, 1, 9, 9, "-o", "{d}/o"],
     "scene {d}/exists: a directory, not a file"),
    (["extract", "{d}/scene.ply", "--camera", "{d}/cameras.json", "--mask", "{d}/text.png", "-o", "{d}/o"],
     "text.png"),
    (["extract", "{d}/garbage.ply", "--camera", "{d}/cameras.json", "--box", 1, 1, 9, 9, "-o", "{d}/o"],
     "garbage.ply"),
    # bad numbers
    (EXTRACT + ["--views", 0, "-o", "{d}/o"], "--views must be in 2..360, got 0"),
    (EXTRACT + ["--views", 10 ** 7, "-o", "{d}/o"], "--views must be in 2..360"),
    (EXTRACT + ["--views", "many", "-o", "{d}/o"], "argument --views: invalid int value"),
    (EXTRACT + ["--threshold", "nan", "-o", "{d}/o"], "--threshold must be finite"),
    (EXTRACT + ["--threshold", 2.0, "-o", "{d}/o"], "--threshold must be in [0, 1)"),
    (EXTRACT + ["--orbit-scale", -1, "-o", "{d}/o"], "--orbit-scale must be > 0"),
    (EXTRACT + ["--up", "0,0,0", "-o", "{d}/o"], "--up 0,0,0: must be a non-zero direction"),
    (EXTRACT + ["--up", "sideways", "-o", "{d}/o"], "--up 'sideways': expected 'auto', 'level', 'camera' or three numbers X,Y,Z"),
    (["extract", "{d}/scene.ply", "--camera", "{d}/cameras.json", "--box", 1, 1, "x", 9, "-o", "{d}/o"],
     "argument --box: invalid float value: 'x'"),
    (["extract", "{d}/scene.ply", "--camera", "{d}/cameras.json", "--box", 500, 500, 600, 600, "-o", "{d}/o"],
     "outside"),
    # bad options and methods
    (EXTRACT + ["--method", "vote", "-o", "{d}/o"], "invalid choice: 'vote' (choose from 'beta_bernoulli'"),
    (EXTRACT + ["--option", "max_iterations=3", "-o", "{d}/o"], "has no option(s) ['max_iterations']"),
    (EXTRACT + ["--option", "max_iter=1000000000", "-o", "{d}/o"], "max_iter must be in 1..100,000"),
    (EXTRACT + ["--option", "oops", "-o", "{d}/o"], "--option must look like NAME=VALUE"),
    (EXTRACT + ["--option", "lam=null", "-o", "{d}/o"], "option lam must be a finite number, got None"),
    (EXTRACT + ["--option", "reweight=\"no\"", "-o", "{d}/o"], "option reweight must be true or false"),
    (["solve", "{d}/ops", "{d}/masks", "--option", "ftol=-1", "-o", "{d}/q.npy"],
     "ftol must be a finite number >= 0"),
    (["solve", "{d}/ops", "{d}/masks", "--method", "least_squares", "--option", "tol=1e400", "-o", "{d}/q.npy"],
     "tol must be a positive finite number, got inf"),
    (EXTRACT + ["--frobnicate", "-o", "{d}/o"], "unrecognized arguments: --frobnicate"),
    (["extract", "{d}/scene.ply", "--camera", "{d}/cameras.json", "-o", "{d}/o"], "give a prompt"),
    (["extract", "{d}/scene.ply", "--mask", "{d}/mask.png", "-o", "{d}/o"], "--camera FILE[:NAME|INDEX]"),
    (["extract", "{d}/scene.ply", "--camera", "{d}/cameras.json", "--point", 3, 3, "--negative", 1, 1,
      "--box", 1, 1, 5, 5, "-o", "{d}/o"], "not allowed with argument"),
    # bad cameras
    (["extract", "{d}/scene.ply", "--camera", "{d}/cameras.json:nobody", "--mask", "{d}/mask.png", "-o",
      "{d}/o"], "no camera named 'nobody'"),
    (["extract", "{d}/scene.ply", "--camera", "{d}/cameras.json:7", "--mask", "{d}/mask.png", "-o", "{d}/o"],
     "index 7 is out of range"),
    (["extract", "{d}/scene.ply", "--camera", "{d}/zero_width.json", "--mask", "{d}/mask.png", "-o", "{d}/o"],
     "zero_width.json"),
    (["extract", "{d}/scene.ply", "--camera", "{d}/garbage.json", "--mask", "{d}/mask.png", "-o", "{d}/o"],
     "garbage.json"),
    (["render", "{d}/scene.ply", "--camera", "{d}/garbage.json", "-o", "{d}/r.png"], "garbage.json"),
    (["render", "{d}/scene.ply", "--look-at", "0,0,5", "0,0,0", "--up", "0,0,0", "-o", "{d}/r.png"],
     "--up 0,0,0: must be a non-zero direction"),
    (["render", "{d}/scene.ply", "--camera", "{d}/cameras.json", "--size", "640x480", "--fov", 20, "-o",
      "{d}/r.png"], "--size, --fov go with --look-at"),
    (["render", "{d}/scene.ply", "--camera", "{d}/cameras.json", "-o", "{d}/exists.png"],
     "-o {d}/exists.png exists; use --force"),
    (["render", "{d}/scene.ply", "--camera", "{d}/cameras.json", "-o", "/proc/r.png"],
     "-o /proc/r.png: cannot write in /proc"),
    (["view", "{d}/scene.ply", "--camera", "{d}/cameras.json:nobody", "--screenshot", "{d}/v.png"],
     "no camera named 'nobody'"),
    (["view", "{d}/scene.ply", "--up", "1,2", "--screenshot", "{d}/v.png"], "expected three numbers X,Y,Z"),
    (["view", "{d}/scene.ply", "--screenshot", "{d}/exists.png"], "exists; use --force"),
    # convert
    (["convert", "{d}/scene.ply", "{d}/exists.ply"], "OUT {d}/exists.ply exists; use --force"),
    (["convert", "{d}/scene.ply", "{d}/afile/x.ply"], "afile is a file, not a directory"),
    (["convert", "{d}/missing.ply", "{d}/new.ply"], "missing.ply"),
    # solve / compare: bad masks directories, unknown methods and options
    (["solve", "{d}/ops", "{d}/nomasks", "-o", "{d}/q.npy"], "nomasks"),
    (["solve", "{d}/ops", "{d}/masks", "-o", "{d}/q.npy"], "mask"),
    (["solve", "{d}/ops", "{d}/masks1", "-o", "{d}/q.npy"], "masks1"),
    (["solve", "{d}/ops", "{d}/masks", "--method", "newton", "-o", "{d}/q.npy"], "invalid choice: 'newton'"),
    (["solve", "{d}/ops", "{d}/masks", "--method", "voting", "--option", "bias=1", "--option", "tol=2",
      "-o", "{d}/q.npy"], "method 'voting' has no option(s) ['tol']; its options are ['bias']"),
    (["solve", "{d}/ops", "{d}/masks", "-o", "{d}/exists.npy"], "exists; use --force"),
    (["solve", "{d}/ops", "{d}/masks", "-o", "{d}/q.txt"], "the output must be a .npy file"),
    (["solve", "{d}/noops", "{d}/masks", "-o", "{d}/q.npy"], "noops"),
    (["compare", "{d}/ops", "{d}/masks", "--truth", "{d}/truth.npy", "--methods", "voting,nope"],
     "--methods: unknown method 'nope'"),
    (["compare", "{d}/ops", "{d}/masks", "--truth", "{d}/truth.npy", "-o", "{d}/exists"], "exists; use --force"),
    (["compare", "{d}/ops", "{d}/masks", "--truth", "{d}/mask.png"], "mask.png: not a .npy file"),
    (["solve", "{d}/ops", "{d}/masks", "--init", "{d}/short.npy", "-o", "{d}/q.npy"],
     "--init {d}/short.npy: a bool mask must have shape"),
    (["render", "{d}/scene.ply", "--look-at", "1,2,3", "1,2,3", "-o", "{d}/r.png"],
     "--look-at / --up / --fov: eye and target coincide"),
    (["compare", "{d}/ops", "{d}/masks", "--truth", "{d}/objects.npy"], "objects.npy: holds Python objects"),
    (["compare", "{d}/ops", "{d}/masks", "--truth", "{d}/short.npy"], "3 labels in shape (3,)"),
    (["compare", "{d}/ops", "{d}/masks", "--truth", "{d}/truth.npy", "--holdout-every", 1],
     "--holdout-every 1: must be 0 (none) or a whole number >= 2"),
    (["compare", "{d}/ops", "{d}/masks", "--truth", "{d}/nosuch.npy"], "--truth {d}/nosuch.npy: cannot read it"),
    (["compare", "{d}/ops", "{d}/masks", "--truth", "{d}/truth.npy", "--methods", "voting,voting"],
     "--methods: each method once"),
    (["solve", "{d}/ops", "{d}/masks", "-o", "{d}/q.npy", "--init", "{d}/nosuch.npy"],
     "--init {d}/nosuch.npy: cannot read it"),
    (["operators", "build", "{d}/scene.ply", "--cameras", "{d}/cameras.json", "-o", "/proc/ops"],
     "cannot write in /proc"),
    (["operators", "build", "{d}/scene.ply", "--cameras", "{d}/cameras.json", "-o", "{d}/exists"],
     "exists"),
    (["operators", "info", "{d}/afile"], "afile"),
    (["operators", "build", "{d}/scene.ply", "--cameras", "{d}/cameras.json:0", "-o", "{d}/ops3"],
     "every camera of a file is read: give the file alone"),
    # reports
    (["extract", "--from-report", "{d}/missing.json", "-o", "{d}/o"], "--from-report {d}/missing.json: no such file"),
    (["extract", "--from-report", "{d}/garbage.json", "-o", "{d}/o"], "not a JSON report"),
    (["extract", "--from-report", "{d}/not_a_report.json", "-o", "{d}/o"], "no 'run' and 'settings' sections"),
    # an edited report: with or without SCENE, one clear line instead of an AttributeError
    (["extract", "--from-report", "{d}/edited_report.json", "-o", "{d}/o"],
     'run.scene must be a section (a JSON object), got "scene.ply"'),
    (["extract", "{d}/scene.ply", "--from-report", "{d}/edited_report.json", "-o", "{d}/o"],
     'run.scene must be a section'),
    (["extract", "--from-report", "{d}/batch_report.json", "-o", "{d}/o"],
     "written by seed2gs batch (job 'chair'), which records the job, not a run of extract: repeat it by running "
     "the batch again"),
    (["extract", "--from-report", "{d}/not_a_report.json", "--views", 6, "-o", "{d}/o"],
     "cannot be combined with --views"),
    # demo
    (["demo", "--object", "0"], "label 0 is the ground"),
    (["demo", "--object", "unicorn"], "no object named 'unicorn'"),
    (["demo", "--views", 1], "n_views must be in 2..360"),
    (["demo", "-o", "{d}/exists"], "exists; use --force"),
]


@pytest.mark.parametrize("args,match", BAD, ids=[" ".join(map(str, a[:1] + a[-3:]))[:60] for a, _ in BAD])
def test_bad_input_is_one_line_and_exit_status_2(files, args, match, capsys):
    before = sorted(p.name for p in files.iterdir())
    rc = cli.main(_fmt(files, args))
    err = capsys.readouterr().err
    # the stages that ran before the error said so, one line each ("seed2gs: render 0.01 s")
    err = "".join(line for line in err.splitlines(keepends=True) if not line.startswith("seed2gs: "))
    command = args[0] if args[0] != "operators" else f"operators {args[1]}"
    assert rc == 2, err
    assert err.count("\n") == 1 and err.startswith(f"seed2gs {command}: error: "), err
    assert "Traceback" not in err
    assert match.format(d=files) in err, err
    assert sorted(p.name for p in files.iterdir()) == before  # nothing written, no temporary left


def test_bad_output_path_fails_before_any_work(files, capsys):
    """``-o /proc/x`` used to run the whole pipeline and then fail on a temporary name."""
    t0 = time.perf_counter()
    assert cli.main(_fmt(files, EXTRACT + ["-o", "/proc/seed2gs_out", "--views", 2, "--no-progress"])) == 2
    err = capsys.readouterr().err
    fast = time.perf_counter() - t0
    assert ".tmp" not in err and "/proc/seed2gs_out" in err
    # The same command with a good path does the work; the bad one must take a fraction of it.
    t0 = time.perf_counter()
    assert cli.main(_fmt(files, EXTRACT + ["-o", "{d}/ok", "--views", 2, "--no-progress"])) == 0
    full = time.perf_counter() - t0
    assert fast < 0.5 * full, (fast, full)


def test_every_positional_argument_has_help_and_options_are_listed():
    parser = cli.build_parser()
    seen = 0

    def walk(p, name):
        nonlocal seen
        for a in p._actions:
            if a.__class__.__name__ == "_SubParsersAction":
                for sub, sp in a.choices.items():
                    walk(sp, f"{name} {sub}")
            elif not a.option_strings:
                seen += 1
                assert a.help, f"{name}: positional {a.dest} has no help text"
    walk(parser, "seed2gs")
    assert seen >= 10
    from seed2gs_inverse.solvers import available_methods, method_options

    for command in (["solve"], ["extract"]):
        sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction").choices[command[0]]
        text = sub.format_help()
        for m in available_methods():
            assert m in text
            if command[0] == "solve":
                for opt in method_options(m):
                    assert opt in text, (m, opt)


def test_force_replaces_for_every_writing_command(files, tmp_path, capsys):
    """One overwrite rule: an existing output is refused without --force (the table) and replaced with it."""
    import shutil

    d = tmp_path
    for name in ("scene.ply", "cameras.json", "truth.npy"):
        shutil.copy(files / name, d / name)
    shutil.copytree(files / "ops", d / "ops")
    (d / "masks").mkdir()
    for k, shape in enumerate([(48, 64), (24, 32)]):
        np.save(d / "masks" / f"view_{k:03d}.npy", np.zeros(shape, np.float32))
    for name in ("out.ply", "out.png", "q.npy"):
        (d / name).write_bytes(b"old")
    (d / "cmp").mkdir()
    (d / "ops2").mkdir()
    cmds = [["convert", d / "scene.ply", d / "out.ply"],
            ["render", d / "scene.ply", "--camera", d / "cameras.json", "-o", d / "out.png"],
            ["solve", d / "ops", d / "masks", "--method", "voting", "-o", d / "q.npy"],
            ["compare", d / "ops", d / "masks", "--truth", d / "truth.npy", "--methods", "voting",
             "--holdout-every", 0, "-o", d / "cmp"],
            ["operators", "build", d / "scene.ply", "--cameras", d / "cameras.json", "--scale", 0.25,
             "-o", d / "ops2", "--no-progress"]]
    for cmd in cmds:
        assert cli.main([str(a) for a in cmd]) == 2, cmd
        assert "exists" in capsys.readouterr().err
        assert cli.main([str(a) for a in cmd] + ["--force"]) == 0, capsys.readouterr().err
    for name in ("out.ply", "out.png", "q.npy"):
        assert (d / name).read_bytes() != b"old"
    assert (d / "cmp" / "comparison.csv").is_file() and (d / "ops2" / "manifest.json").is_file()


def test_warnings_print_as_one_line_in_the_commands_voice(tmp_path, capsys, monkeypatch):
    """A warning raised while a command runs is one 'seed2gs CMD: warning: ...' line (no file:line)."""
    import warnings

    from seed2gs_inverse.cli import _scene

    def warn_and_succeed(args):
        warnings.warn("something to know", UserWarning)
        return 0

    monkeypatch.setattr(_scene, "info", warn_and_succeed)
    assert cli.main(["info", str(tmp_path / "any.ply")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["seed2gs info: warning: something to know"]
