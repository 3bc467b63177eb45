"""The loop from an extraction: extract --save-operators -> solve / compare on its files -> split."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import plyfile
import pytest

import seed2gs_inverse.cli as cli
from _cli_files import write_cli_files
from _io_encoders import random_scene, write_ply_plyfile
from seed2gs_inverse import OperatorStack
from seed2gs_inverse._output_paths import check_output
from seed2gs_inverse.comparison import compare
from seed2gs_inverse.errors import FormatError, ValidationError
from seed2gs_inverse.io import read_scene
from seed2gs_inverse.metrics import known_boundary_iou, known_iou, mask_boundary
from seed2gs_inverse.solvers.inputs import load_solve_inputs


def _run(args, capsys):
    code = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One ``extract --save-operators`` of a procedural object, and its inputs."""
    f = write_cli_files(tmp_path_factory.mktemp("loop"))
    d, syn, seed, truth = f["dir"], f["syn"], f["seed"], f["truth"]
    code = cli.main([str(a) for a in ["extract", d / "scene.ply", "--camera", f"{d / 'cameras.json'}:0",
                                      "--mask", d / "mask.png", "-o", d / "out", "--views", 4, "--no-progress",
                                      "--save-operators"]])
    assert code == 0
    return {"dir": d, "out": d / "out", "syn": syn, "seed": seed, "truth": truth}


def test_save_operators_writes_the_solves_inputs(run, capsys):
    out = run["out"]
    assert sorted(p.name for p in out.iterdir()) == ["follow.npz", "graph.npz", "init.npy", "islands.npy", "masks",
                                                    "object.ply", "operators", "q.npy", "remainder.ply",
                                                    "report.json", "report.png", "report_masks.png", "solve.json"]
    rep = json.loads((out / "report.json").read_text())
    assert rep["outputs"] == {"object": "object.ply", "remainder": "remainder.ply", "q": "q.npy",
                              "solve": "solve.json", "operators": "operators", "masks": "masks", "init": "init.npy",
                              "graph": "graph.npz", "follow": "follow.npz", "islands": "islands.npy"}
    stack = OperatorStack.load(out / "operators")
    assert len(stack) == rep["n_views"] and stack.n_gaussians == len(run["syn"].scene)
    code, text, _ = _run(["operators", "info", out / "operators"], capsys)
    assert code == 0 and f"views:       {len(stack)}" in text
    masks = sorted((out / "masks").iterdir())
    assert [p.name for p in masks] == [f"view_{i:03d}.npy" for i in range(len(stack))]
    ys = [np.load(p, allow_pickle=False) for p in masks]
    assert all(y.dtype == np.float32 and y.shape == v.image_shape for y, v in zip(ys, stack))
    assert any(np.isnan(y).any() for y in ys)  # orbit views hold unknown pixels
    # view 0 is the reference view, whose mask is the seed of --mask (the order is the stack's)
    np.testing.assert_array_equal(ys[0], run["seed"].astype(np.float32))
    settings = json.loads((out / "solve.json").read_text())
    assert settings["method"] == "weighted_bce" and settings["options"] == {"max_iter": 20}
    assert settings["smoothness"] == rep["resolved"]["smoothness"] == 1.0 and settings["threshold"] == 0.5
    assert np.load(out / "init.npy").dtype == bool and np.load(out / "islands.npy").size == 0
    # an output with the solve's inputs is still extract's own: --force may replace it
    check_output(out, "-o", directory=True, force=True, kind="extract")


def test_solve_from_the_extraction_reproduces_q_exactly(run, capsys, tmp_path):
    out = run["out"]
    q_run = np.load(out / "q.npy")
    code, text, err = _run(["solve", out / "operators", out / "masks", "--from-extraction", out,
                            "-o", tmp_path / "q.npy", "--no-progress"], capsys)
    assert code == 0, err
    assert "smoothness 1, graph" in err and "weighted_bce" in text
    q = np.load(tmp_path / "q.npy")
    assert q.dtype == np.float32 and np.array_equal(q, q_run)  # bit for bit, not to round-off
    # the Python path: the same files, the same q and selection
    inputs = load_solve_inputs(out)
    res = inputs.solve()
    assert np.array_equal(res.q, q_run) and np.array_equal(res.selected(), q_run > 0.5)
    # the prior alone, without the run's regulariser and min_evidence, is another problem
    code, _, err = _run(["solve", out / "operators", out / "masks", "--init", out / "init.npy",
                         "--option", "max_iter=20", "-o", tmp_path / "plain.npy", "--no-progress"], capsys)
    assert code == 0, err
    assert not np.array_equal(np.load(tmp_path / "plain.npy"), q_run)
    # another method on the same inputs runs with the run's prior and graph, its own options
    code, text, err = _run(["solve", out / "operators", out / "masks", "--from-extraction", out,
                            "--method", "voting", "-o", tmp_path / "v.npy", "--no-progress"], capsys)
    assert code == 0, err
    assert "method voting" in text
    np.testing.assert_array_equal(np.load(tmp_path / "v.npy"), inputs.solve("voting").q)


def test_islands_the_run_removed_are_removed_again(run, tmp_path):
    """The islands rule runs after the solve: its zeros are saved and applied, or kept with keep_islands."""
    from seed2gs_inverse.graph import apply_follow
    from seed2gs_inverse.pipeline import extract, save_extraction

    syn, seed = run["syn"], run["seed"]
    ex = extract(syn.scene, syn.reference_camera(128, 96), seed, n_views=4, progress=False, method="voting")
    solver_q = np.asarray(ex.result.q, np.float32)
    chosen = np.flatnonzero(ex.selected)[::7]  # stand-ins for islands the rule left out
    assert chosen.size
    q = ex.q.copy()
    q[chosen] = 0
    islanded = dataclasses.replace(ex, q=q, selected=q > ex.threshold)
    save_extraction(islanded, tmp_path / "out", save_operators=True, figure=False)
    np.testing.assert_array_equal(np.load(tmp_path / "out" / "islands.npy"), chosen)
    inputs = load_solve_inputs(tmp_path / "out")
    assert inputs.method == "voting" and np.array_equal(inputs.solve().q, q)
    # kept islands: the solver's q with the follow rules (faint, enclosed, weak) applied
    assert np.array_equal(inputs.solve(keep_islands=True).q, apply_follow(solver_q, ex.follow))
    # without the rule, nothing is saved as islands
    plain = dataclasses.replace(ex, settings=ex.settings.replace(seed_connected=False))
    save_extraction(plain, tmp_path / "plain", save_operators=True, figure=False)
    assert not (tmp_path / "plain" / "islands.npy").exists()
    assert json.loads((tmp_path / "plain" / "solve.json").read_text())["islands"] is None
    assert np.array_equal(load_solve_inputs(tmp_path / "plain").solve().q, ex.q)


def test_solve_from_extraction_bad_inputs_are_named(run, capsys, tmp_path):
    out = run["out"]
    base = ["solve", out / "operators", out / "masks", "-o", tmp_path / "q.npy"]
    code, _, err = _run(base + ["--from-extraction", out, "--init", out / "init.npy"], capsys)
    assert code == 2 and "give one of them" in err
    code, _, err = _run(base + ["--keep-islands"], capsys)
    assert code == 2 and "--keep-islands goes with --from-extraction" in err
    code, _, err = _run(base + ["--from-extraction", tmp_path], capsys)
    assert code == 2 and "no solve.json" in err
    assert not (tmp_path / "q.npy").exists()
    # a damaged copy: each file named in the message
    bad = tmp_path / "bad"
    bad.mkdir()
    for name in ("solve.json", "init.npy", "islands.npy"):
        (bad / name).write_bytes((out / name).read_bytes())
    with pytest.raises(ValidationError, match="graph.npz: no such file"):
        load_solve_inputs(bad, operators=out / "operators", masks=out / "masks")
    (bad / "graph.npz").write_bytes(b"not a zip")
    with pytest.raises(FormatError, match="graph.npz: not a sparse graph"):
        load_solve_inputs(bad, operators=out / "operators", masks=out / "masks")
    (bad / "graph.npz").write_bytes((out / "graph.npz").read_bytes())
    np.save(bad / "init.npy", np.zeros(5, bool))
    with pytest.raises(ValidationError, match=r"init.npy: a bool mask must have shape"):
        load_solve_inputs(bad, operators=out / "operators", masks=out / "masks")
    (bad / "init.npy").write_bytes((out / "init.npy").read_bytes())
    rec = json.loads((out / "solve.json").read_text())
    (bad / "solve.json").write_text(json.dumps({**rec, "method": "magic"}))
    with pytest.raises(FormatError, match=r"solve.json: .*magic"):
        load_solve_inputs(bad, operators=out / "operators", masks=out / "masks")
    (bad / "solve.json").write_text(json.dumps({**rec, "n_views": rec["n_views"] + 1}))
    with pytest.raises(ValidationError, match="saved for"):
        load_solve_inputs(bad, operators=out / "operators", masks=out / "masks")
    (bad / "solve.json").write_text(json.dumps({**rec, "fingerprint": "0" * 16}))
    with pytest.raises(ValidationError, match="another scene"):
        load_solve_inputs(bad, operators=out / "operators", masks=out / "masks")
    (bad / "solve.json").write_text(json.dumps({**rec, "min_vote": 1.5}))
    with pytest.raises(FormatError, match=r"'min_vote' must be a number in \[0, 1\]"):
        load_solve_inputs(bad, operators=out / "operators", masks=out / "masks")
    # a folder written before min_vote existed: those runs solved without it
    (bad / "follow.npz").write_bytes((out / "follow.npz").read_bytes())
    (bad / "solve.json").write_text(json.dumps({k: v for k, v in rec.items() if k != "min_vote"}))
    assert rec["min_vote"] == 0.2 and load_solve_inputs(bad, operators=out / "operators",
                                                         masks=out / "masks").min_vote == 0.0
    (bad / "solve.json").write_text(json.dumps({**rec, "masks": "../masks"}))
    with pytest.raises(FormatError, match="'masks' must be a file name inside the folder"):
        load_solve_inputs(bad)


# -- compare without labels ---------------------------------------------------------------------
def test_known_pixel_scores():
    rng = np.random.default_rng(1)
    obj = np.zeros((20, 30), bool)
    obj[5:15, 8:22] = True
    mask = obj.astype(np.float32)
    unknown = rng.random(obj.shape) < 0.3
    mask[unknown] = np.nan
    assert known_iou(obj, mask) == 1.0 and known_boundary_iou(obj, mask) == 1.0  # a hole of unknowns draws no band
    wrong = obj.copy()
    wrong[unknown] = ~wrong[unknown]  # disagreeing on unknown pixels only costs nothing
    assert known_iou(wrong, mask) == 1.0 and known_boundary_iou(wrong, mask) == 1.0
    nothing = np.zeros_like(obj)
    assert known_iou(nothing, mask) == 0.0 and known_boundary_iou(nothing, mask) == 0.0
    # against a per-pixel reference
    pred = rng.random(obj.shape) < 0.5
    k = ~unknown
    inter = sum(pred[i, j] and obj[i, j] for i, j in zip(*np.nonzero(k)))
    union = sum(pred[i, j] or obj[i, j] for i, j in zip(*np.nonzero(k)))
    assert known_iou(pred, mask) == pytest.approx(inter / union)
    filled = np.where(k, obj, pred)
    bp, bt = mask_boundary(pred)[k], mask_boundary(filled)[k]
    assert known_boundary_iou(pred, mask) == pytest.approx((bp & bt).sum() / (bp | bt).sum())
    assert np.isnan(known_iou(obj, np.full(obj.shape, np.nan, np.float32)))
    with pytest.raises(ValidationError, match="known_iou"):
        known_iou(obj, np.full(obj.shape, 2.0))


def test_compare_without_truth_scores_against_the_held_out_masks(run):
    stack = OperatorStack.load(run["out"] / "operators")
    masks = [np.load(run["out"] / "masks" / f"view_{i:03d}.npy") for i in range(len(stack))]
    res = compare(stack, masks, methods=["voting", "weighted_bce"], holdout_every=2,
                  options={"weighted_bce": {"max_iter": 10}})
    assert res.against == "masks" and res.holdout == list(range(1, len(stack), 2))
    for row in res.rows:
        assert all(row[k] is None for k in ("precision", "recall", "iou3d", "weighted_iou3d"))
        sel = res.results[row["method"]].selected().astype(np.float32)
        ious = []
        for i in res.holdout:  # per pixel: the rendered selection against the known pixels of the view's mask
            pred = stack[i].image(sel) > 0.5
            known = ~np.isnan(masks[i])
            target = masks[i][known] > 0.5
            union = np.sum(pred[known] | target)
            ious.append(1.0 if union == 0 else np.sum(pred[known] & target) / union)
        assert row["miou"] == pytest.approx(np.mean(ious)) and row["miou"] > 0.8
    text = res.format()
    assert "against those views' own masks (known pixels only; no ground truth)" in text and "IoU3d" not in text
    assert json.loads(res.to_json())["against"] == "masks"
    # masks that say nothing is there: the same fits score lower against them
    empty = [np.where(np.isnan(m), m, 0).astype(np.float32) if i in res.holdout else m for i, m in enumerate(masks)]
    worse = compare(stack, empty, methods=["voting"], holdout_every=2)
    assert worse.rows[0]["miou"] < res.rows[0]["miou"]


def test_compare_command_without_truth(run, capsys, tmp_path):
    out = run["out"]
    code, text, err = _run(["compare", out / "operators", out / "masks", "--methods", "voting,beta_bernoulli",
                            "-o", tmp_path / "cmp", "--no-progress"], capsys)
    assert code == 0, err
    assert "views' own masks" in err and "against those views' own masks" in text and "IoU3d" not in text
    rep = json.loads((tmp_path / "cmp" / "comparison.json").read_text())
    assert rep["against"] == "masks" and [r["method"] for r in rep["rows"]] == ["voting", "beta_bernoulli"]
    assert all(r["iou3d"] is None and 0.8 < r["miou"] <= 1 for r in rep["rows"])
    # with labels, the 3D columns come back
    np.save(tmp_path / "labels.npy", run["truth"])
    code, text, err = _run(["compare", out / "operators", out / "masks", "--methods", "voting",
                            "--truth", tmp_path / "labels.npy", "--no-progress"], capsys)
    assert code == 0, err
    assert "IoU3d" in text and "against the truth labels rendered into them" in text


# -- split ----------------------------------------------------------------------------------------
def _records(path) -> tuple:
    """(properties, records) of a PLY's vertex element, read by plyfile (not the package's reader)."""
    el = plyfile.PlyData.read(str(path))["vertex"]
    return [(p.name, np.dtype(p.val_dtype).str[1:]) for p in el.properties], el.data


@pytest.mark.parametrize("dtype", ["float32", "float64", "bool"])
def test_split_round_trips_the_scene(tmp_path, capsys, dtype):
    rng = np.random.default_rng(3)
    n = 57
    scene = random_scene(rng, n=n, degree=1, extra={"label": rng.integers(0, 9, n).astype(np.uint8)})
    write_ply_plyfile(tmp_path / "in.ply", scene, normals=False)  # a layout not the trainer's: no normals
    q = rng.random(n).astype(dtype) if dtype != "bool" else rng.random(n) < 0.4
    if dtype != "bool":
        q[:5] = 0.3  # on the threshold: not the object
    np.save(tmp_path / "q.npy", q)
    code, text, err = _run(["split", tmp_path / "in.ply", tmp_path / "q.npy", "-o", tmp_path / "parts",
                            "--threshold", 0.3], capsys)
    assert code == 0, err
    selected = np.load(tmp_path / "q.npy") > 0.3  # the rule, applied here to the file
    props, src = _records(tmp_path / "in.ply")
    obj_props, obj = _records(tmp_path / "parts" / "object.ply")
    rem_props, rem = _records(tmp_path / "parts" / "remainder.ply")
    assert obj_props == rem_props == props
    np.testing.assert_array_equal(obj, src[selected])
    np.testing.assert_array_equal(rem, src[~selected])
    assert len(obj) + len(rem) == n and 0 < len(obj) < n
    rec = json.loads((tmp_path / "parts" / "split.json").read_text())
    assert rec["n_object"] == int(selected.sum()) and rec["threshold"] == 0.3
    assert f"({int(selected.sum()):,} Gaussians)" in text
    # --force replaces split's own output, never a folder of other files
    code, _, err = _run(["split", tmp_path / "in.ply", tmp_path / "q.npy", "-o", tmp_path / "parts"], capsys)
    assert code == 2 and "--force" in err
    code, _, err = _run(["split", tmp_path / "in.ply", tmp_path / "q.npy", "-o", tmp_path / "parts", "--force"],
                        capsys)
    assert code == 0, err
    assert len(read_scene(tmp_path / "parts" / "object.ply")) == int((np.load(tmp_path / "q.npy") > 0.5).sum())
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    code, _, err = _run(["split", tmp_path / "in.ply", tmp_path / "q.npy", "-o", tmp_path / "mine", "--force"],
                        capsys)
    assert code == 2 and "not an earlier output" in err and (tmp_path / "mine" / "notes.txt").exists()


def test_split_of_an_extractions_q_gives_its_object(run, capsys, tmp_path):
    d, out = run["dir"], run["out"]
    code, _, err = _run(["split", d / "scene.ply", out / "q.npy", "-o", tmp_path / "parts"], capsys)
    assert code == 0, err
    for part in ("object.ply", "remainder.ply"):
        assert (tmp_path / "parts" / part).read_bytes() == (out / part).read_bytes()


def test_split_bad_inputs_are_named(tmp_path, capsys):
    rng = np.random.default_rng(4)
    write_ply_plyfile(tmp_path / "in.ply", random_scene(rng, n=12))
    cases = [(np.zeros(11, np.float32), "Q {q} has shape (11,); the scene has 12 Gaussians"),
             (np.zeros((12, 1), np.float32), "Q {q} has shape (12, 1)"),
             (np.full(12, 1.5, np.float32), "Q {q}: values must be finite and in [0, 1]"),
             (np.full(12, np.nan, np.float32), "Q {q}: values must be finite and in [0, 1]"),
             (np.array(["a"] * 12), "Q {q} has dtype <U1")]
    out = tmp_path / "parts"
    for k, (q, message) in enumerate(cases):
        path = tmp_path / f"q{k}.npy"
        np.save(path, q)
        code, _, err = _run(["split", tmp_path / "in.ply", path, "-o", out], capsys)
        assert code == 2 and message.format(q=path) in err, err
    (tmp_path / "text.npy").write_text("0.5\n" * 12)
    np.save(tmp_path / "q.npy", np.zeros(12, np.float32))
    for args, message in [([tmp_path / "text.npy"], "not a .npy file"),
                          ([tmp_path / "none.npy"], f"Q {tmp_path / 'none.npy'}: no such file"),
                          ([tmp_path / "q.npy", "--threshold", 1], "--threshold must be < 1.0"),
                          ([tmp_path / "q.npy", "--threshold", "nan"], "--threshold must be finite")]:
        code, _, err = _run(["split", tmp_path / "in.ply", *args, "-o", out], capsys)
        assert code == 2 and message in err and err.count("\n") == 1, err
    code, _, err = _run(["split", tmp_path / "none.ply", tmp_path / "q.npy", "-o", out], capsys)
    assert code == 2 and f"SCENE {tmp_path / 'none.ply'}: no such file" in err
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".parts")]


def test_loading_and_solving_saved_inputs_needs_no_rasterizer(run):
    """The solve inputs load and solve with NumPy and SciPy alone, as saved operators do."""
    import subprocess
    import sys

    code = ("import sys, numpy as np\n"
            "from seed2gs_inverse.solvers.inputs import load_solve_inputs\n"
            "q = load_solve_inputs(sys.argv[1]).solve().q\n"
            "assert np.array_equal(q, np.load(sys.argv[2]))\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'llvmlite')\n"
            "             or m.startswith('seed2gs_inverse.raster') or m.startswith('seed2gs_inverse.pipeline')))")
    repo = Path(__file__).resolve().parents[1]  # python -c imports this checkout's package
    out = subprocess.run([sys.executable, "-c", code, str(run["out"]), str(run["out"] / "q.npy")],
                         capture_output=True, text=True, timeout=300, cwd=repo)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
