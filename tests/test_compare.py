"""compare() and the operators / solve / compare commands."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest
from PIL import Image

import seed2gs_inverse.cli as cli
from _solver_scenes import blob_stack
from seed2gs_inverse.comparison import compare, holdout_views
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.metrics import boundary_iou, iou, membership_scores


@pytest.fixture(scope="module")
def blob():
    return blob_stack(seed=1, n_views=8)


def test_holdout_views():
    np.testing.assert_array_equal(holdout_views(10, 4), [3, 7])
    assert holdout_views(10, 0).size == 0 and holdout_views(10, None).size == 0
    with pytest.raises(ValidationError, match="holdout_every"):
        holdout_views(10, 1)


def test_compare_scores_match_direct_evaluation(blob):
    stack, labels, masks = blob
    c = compare(stack, masks, labels, methods=["voting", "least_squares"], holdout_every=4)
    assert c.holdout == [3, 7] and [r["method"] for r in c.rows] == ["voting", "least_squares"]
    for row in c.rows:
        res = c.results[row["method"]]
        sel = res.selected()
        ious, bious = [], []
        for i in (3, 7):
            pred = stack[i].image(sel.astype(np.float32)) > 0.5
            truth = stack[i].image(labels.astype(np.float32)) > 0.5
            ious.append(iou(pred, truth))
            bious.append(boundary_iou(pred, truth))
        assert row["miou"] == pytest.approx(np.mean(ious)) and row["mbiou"] == pytest.approx(np.mean(bious))
        vis = sum(v.rmatvec(np.ones(v.image_shape)) for v in stack)
        s3 = membership_scores(sel, labels, weights=vis)
        assert row["iou3d"] == s3["iou"] and row["weighted_iou3d"] == pytest.approx(s3["weighted_iou"])
        assert row["seconds"] > 0 and row["peak_mb"] > 0 and row["n_selected"] == int(sel.sum())
        assert row["miou"] >= 0.95  # 6 fitting views only; recovery proper is tested in test_solvers
    # the fitting used only the training views: masks of held-out views can be garbage
    junk = [m if i not in (3, 7) else np.ones_like(m) for i, m in enumerate(masks)]
    c2 = compare(stack, junk, labels, methods=["voting"], holdout_every=4)
    assert c2.rows[0]["miou"] == c.rows[0]["miou"]
    text = c.format()
    assert "voting" in text and "held-out" in text
    rows = list(csv.DictReader(io.StringIO(c.to_csv())))
    assert rows[1]["method"] == "least_squares" and float(rows[1]["miou"]) == pytest.approx(c.rows[1]["miou"])
    assert json.loads(c.to_json())["holdout"] == [3, 7]
    buf = io.BytesIO()
    c.plot(buf)
    assert buf.getvalue()[:8] == b"\x89PNG\r\n\x1a\n"


def test_compare_bad_input(blob):
    stack, labels, masks = blob
    with pytest.raises(ValidationError, match="truth"):
        compare(stack, masks, labels[:-1])
    with pytest.raises(ValidationError, match="unknown method"):
        compare(stack, masks, labels, methods=["nope"])
    with pytest.raises(ValidationError, match="masks for"):
        compare(stack, masks[:-1], labels)
    with pytest.raises(ValidationError, match="every view is held out"):
        compare(stack, masks, labels, holdout=list(range(8)))
    with pytest.raises(ValidationError, match="truth selects no Gaussian"):  # recall 1.0, IoU 0: no comparison
        compare(stack, masks, np.zeros_like(labels))
    with pytest.warns(UserWarning, match=f"holdout_every=9 holds out no view of {len(stack)}"):
        cmp = compare(stack, masks, labels, methods=["voting"], holdout_every=9)
    assert cmp.per_view["voting"]["views"] == list(range(len(stack)))


# -- command line -------------------------------------------------------------------
@pytest.fixture
def run_cli(monkeypatch):
    monkeypatch.setattr(cli, "_COMMAND_MODULES", ("_operators", "_solve"))

    def run(*argv):
        return cli.main([str(a) for a in argv])

    return run


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory):
    from seed2gs_inverse.io import write_cameras, write_scene
    from seed2gs_inverse.synthetic import make_scene

    d = tmp_path_factory.mktemp("scene")
    s = make_scene(0, n_per_object=60)
    write_scene(d / "scene.ply", s.scene)
    write_cameras(d / "cameras.json", s.orbit_cameras(5, 40, 30))
    np.save(d / "truth.npy", s.object_mask(1))
    return d, s


def test_cli_build_info_solve_compare(run_cli, scene_files, tmp_path, capsys):
    d, s = scene_files
    ops = tmp_path / "ops"
    assert run_cli("operators", "build", d / "scene.ply", "--cameras", d / "cameras.json", "-o", ops,
                   "--no-progress") == 0
    from seed2gs_inverse.operators import OperatorStack, scene_fingerprint

    stack = OperatorStack.load(ops, scene=s.scene)
    assert len(stack) == 5 and stack.fingerprint == scene_fingerprint(s.scene)
    assert run_cli("operators", "info", ops, "--scene", d / "scene.ply") == 0
    out = capsys.readouterr().out
    assert "views:       5" in out and "matches the scene" in out
    masks = tmp_path / "masks"
    masks.mkdir()
    truth = s.object_mask(1)
    for k, v in enumerate(stack):
        m = v.image(truth.astype(np.float32)) > 0.5
        if k % 2:
            Image.fromarray(m.astype(np.uint8) * 255).save(masks / f"view_{k:03d}.png")
        else:
            np.save(masks / f"view_{k:03d}.npy", m.astype(np.float32))
    assert run_cli("solve", ops, masks, "--method", "voting", "-o", tmp_path / "q.npy", "--option", "bias=0.1") == 0
    q = np.load(tmp_path / "q.npy")
    assert q.shape == (len(s.scene),) and q.dtype == np.float32
    from seed2gs_inverse.solvers import solve

    np.testing.assert_array_equal(q, solve(stack, [np.asarray(v.image(truth.astype(np.float32)) > 0.5)
                                                   for v in stack], method="voting", bias=0.1).q)
    assert run_cli("compare", ops, masks, "--truth", d / "truth.npy", "--methods", "voting,beta_bernoulli",
                   "--holdout-every", "3", "-o", tmp_path / "cmp") == 0
    out = capsys.readouterr().out
    assert "beta_bernoulli" in out and "held-out" in out
    assert sorted(p.name for p in (tmp_path / "cmp").iterdir()) == ["comparison.csv", "comparison.json",
                                                                     "comparison.png"]


def test_cli_errors_are_one_line_and_leave_nothing(run_cli, scene_files, tmp_path, capsys):
    d, s = scene_files
    ops = tmp_path / "ops"
    assert run_cli("operators", "info", tmp_path) == 2
    assert "manifest" in capsys.readouterr().err
    assert run_cli("operators", "build", d / "scene.ply", "--cameras", d / "cameras.json", "-o", ops,
                   "--scale", "-1", "--no-progress") == 2
    assert not ops.exists()
    assert run_cli("operators", "build", d / "scene.ply", "--cameras", d / "cameras.json", "-o", ops,
                   "--scale", "0.5", "--no-progress") == 0
    capsys.readouterr()
    assert run_cli("operators", "build", d / "scene.ply", "--cameras", d / "cameras.json", "-o", ops,
                   "--scale", "0.5", "--no-progress") == 2
    err = capsys.readouterr().err
    assert "--force" in err and err.startswith("seed2gs operators build: error:")
    assert run_cli("operators", "build", d / "scene.ply", "--cameras", d / "cameras.json", "-o", ops,
                   "--scale", "0.5", "--no-progress", "--overwrite") == 0
    masks = tmp_path / "masks"
    masks.mkdir()
    for k in range(4):
        np.save(masks / f"view_{k:03d}.npy", np.zeros((15, 20), np.float32))
    capsys.readouterr()
    assert run_cli("solve", ops, masks, "-o", tmp_path / "q.npy") == 2
    err = capsys.readouterr().err
    assert "4 masks for 5" in err and len(err.strip().splitlines()) == 1
    np.save(masks / "view_004.npy", np.zeros((16, 20), np.float32))
    assert run_cli("solve", ops, masks, "-o", tmp_path / "q.npy") == 2
    assert "view 4" in capsys.readouterr().err
    np.save(masks / "view_004.npy", np.zeros((15, 20), np.float32))
    assert run_cli("solve", ops, masks, "--method", "nope", "-o", tmp_path / "q.npy") == 2
    capsys.readouterr()
    assert run_cli("solve", ops, masks, "-o", tmp_path / "missing" / "q.npy") == 2
    assert "does not exist" in capsys.readouterr().err and not (tmp_path / "missing").exists()
    assert run_cli("solve", ops, masks, "-o", tmp_path / "q.npy", "--option", "r_min=7") == 2
    assert "r_min" in capsys.readouterr().err
    (masks / "view_002.npy").write_bytes(b"garbage")
    assert run_cli("solve", ops, masks, "-o", tmp_path / "q.npy") == 2
    assert "view_002.npy" in capsys.readouterr().err
    assert not (tmp_path / "q.npy").exists()
    # operators of another scene are refused when the scene is given
    other = tmp_path / "other.ply"
    from seed2gs_inverse.io import write_scene
    from seed2gs_inverse.synthetic import make_scene

    write_scene(other, make_scene(1, n_per_object=60).scene)
    assert run_cli("operators", "info", ops, "--scene", other) == 2
    assert "scene" in capsys.readouterr().err


def test_compare_progress_reports_each_method(blob):
    stack, labels, masks = blob
    calls = []
    res = compare(stack, masks, labels, methods=["voting", "least_squares"], holdout_every=4,
                  progress=lambda m, k, n, step: calls.append((m, k, n, step)))
    done = [(m, k, n) for m, k, n, step in calls if step is None]
    assert done == [("voting", 0, 2), ("least_squares", 1, 2)]  # one "done" per method, in order
    steps = [step for m, k, n, step in calls if m == "least_squares" and step is not None]
    assert len(steps) == res.results["least_squares"].iterations  # every solver iteration reported
    assert not [c for c in calls if c[0] == "voting" and c[3] is not None]  # a closed form reports none
    with pytest.raises(ValidationError, match="progress must be a callable"):
        compare(stack, masks, labels, methods=["voting"], progress=1)


def test_cli_solve_and_compare_show_progress_only_on_a_terminal(run_cli, scene_files, tmp_path, capsys,
                                                                  monkeypatch):
    import sys

    d, s = scene_files
    ops, masks = tmp_path / "ops", tmp_path / "masks"
    assert run_cli("operators", "build", d / "scene.ply", "--cameras", d / "cameras.json", "-o", ops) == 0
    from seed2gs_inverse.operators import OperatorStack

    masks.mkdir()
    for k, v in enumerate(OperatorStack.load(ops)):
        np.save(masks / f"view_{k:03d}.npy", (v.matvec(s.object_mask(1).astype(np.float32)) > 0.5)
                .astype(np.float32).reshape(v.image_shape))
    solve_args = ["solve", ops, masks, "--method", "least_squares"]
    cmp_args = ["compare", ops, masks, "--truth", d / "truth.npy", "--methods", "voting,least_squares"]
    assert run_cli(*solve_args, "-o", tmp_path / "a.npy") == 0
    assert run_cli(*cmp_args) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and "loss" not in err  # stderr is not a terminal here: no bars
    from seed2gs_inverse.progress import Progress as _Progress

    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    monkeypatch.setattr(_Progress, "MININTERVAL", 0.0)  # redraw on every update: the loss shows however fast
    monkeypatch.setattr(_Progress, "DELAY", 0.0)  # and draw at once: this solve is shorter than the bars' delay
    assert run_cli(*solve_args, "-o", tmp_path / "b.npy") == 0
    assert "least_squares" in (err := capsys.readouterr().err) and "loss" in err and "it" in err
    assert run_cli(*cmp_args) == 0
    err = capsys.readouterr().err
    assert "compare" in err and "method" in err
