"""``seed2gs eval lerf-mask`` on a tiny dataset in the exact LERF-Mask layout with known answers.

The dataset (tests/_lerf_dataset.py) holds two procedural scenes: ``blocks``
(cameras.json, frames named after cameras) with the queries ``sphere`` and
``sphere top``, and ``shelf`` (COLMAP text model, frames ``0`` and ``1`` =
test cameras 0 and 8 of the LLFF split) with ``sphere``. Seeded by the
ground-truth mask of the first frame, the extraction recovers each sphere
exactly in every test view (the predicted masks equal the rendered truth).
``sphere top`` keeps the truth in its seed frame but only the upper half of
the sphere in the other frames, so its scores there are known: IoU =
|top| / |sphere| and the boundary IoU of the two masks, both computed here
from first principles, independently of metrics.py.
"""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from seed2gs_inverse.errors import FormatError, ValidationError

import _lerf_dataset
from _mask_scores import biou_reference, iou_reference

OPTS = ["--views", "6"]


def _known_scores(info) -> dict:
    """(scene, query) -> {frame: (iou, biou)} expected from the truth masks alone."""
    want = {}
    for scene, d in info.items():
        for (frame, query), gt in d["gt"].items():
            pred = d["truth"][frame]  # what an exact extraction renders
            want.setdefault((scene, query), {})[frame] = (iou_reference(pred, gt), biou_reference(pred, gt))
    return want


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("lerf")
    return root, _lerf_dataset.build(root)


def test_eval_lerf_mask_reproduces_the_known_scores(dataset, capsys):
    from seed2gs_inverse.cli import main
    from seed2gs_inverse.evaluation import read_gt_mask

    root, info = dataset
    out = root / "report"
    rc = main(["eval", "lerf-mask", str(root / "data"), "--scenes", str(root / "scenes"), "-o", str(out),
               "--oracle-seed", "--sequential", "--no-progress", *OPTS])
    assert rc == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    want = _known_scores(info)
    # sanity of the construction: "sphere top" really is a partial answer off its seed frame
    assert 0.2 < want[("blocks", "sphere top")]["orbit_002"][0] < 0.8
    got = {(q["scene"], q["query"]): q for q in report["queries"]}
    assert set(got) == set(want)
    for key, frames in want.items():
        q = got[key]
        assert q["status"] == "done" and set(q["frames"]) == set(frames)
        for f, (iou, biou) in frames.items():
            assert q["frames"][f]["iou"] == pytest.approx(iou, abs=1e-12), (key, f)
            assert q["frames"][f]["biou"] == pytest.approx(biou, abs=1e-12), (key, f)
        assert q["miou"] == pytest.approx(np.mean([v[0] for v in frames.values()]), abs=1e-12)
        assert q["mbiou"] == pytest.approx(np.mean([v[1] for v in frames.values()]), abs=1e-12)
    # protocol means: views -> query -> scene -> overall (scenes weigh equally)
    scene_miou = {s: np.mean([np.mean([v[0] for v in fr.values()]) for (sc, _), fr in want.items() if sc == s])
                  for s in info}
    assert {s["scene"]: s["miou"] for s in report["scenes"]} == pytest.approx(scene_miou, abs=1e-12)
    assert report["overall"]["miou"] == pytest.approx(np.mean(list(scene_miou.values())), abs=1e-12)
    assert got[("blocks", "sphere top")]["seed_frame"] == "orbit_001"
    assert got[("blocks", "sphere top")]["miou_heldout"] == pytest.approx(
        np.mean([want[("blocks", "sphere top")][f][0] for f in ("orbit_002", "orbit_003")]), abs=1e-12)
    # tables, grid and the predicted masks in the dataset's own layout
    rows = list(csv.DictReader(open(out / "per_query.csv")))
    assert [(r["scene"], r["query"]) for r in rows] == [("blocks", "sphere"), ("blocks", "sphere top"),
                                                        ("shelf", "sphere")]
    assert float(rows[1]["miou"]) == pytest.approx(got[("blocks", "sphere top")]["miou"], abs=1e-6)
    scenes = list(csv.DictReader(open(out / "per_scene.csv")))
    assert [r["scene"] for r in scenes] == ["blocks", "shelf"]
    assert (out / "grid.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for (scene, q), frames in want.items():
        for f in frames:
            pred = read_gt_mask(out / "masks" / scene / f / f"{q}.png")
            assert np.array_equal(pred, info[scene]["truth"][f])
    assert "overall" in printed and f"{100 * report['overall']['miou']:.1f}" in printed
    # the extractions went through the batch runner: a re-run resumes them
    summary = json.loads((out / "jobs" / "summary.json").read_text())
    assert summary["counts"]["done"] == 3
    (out / ".DS_Store").write_bytes(b"\0")  # a file of the user's (or the OS's) next to the report stays
    rc = main(["eval", "lerf-mask", str(root / "data"), "--scenes", str(root / "scenes"), "-o", str(out),
               "--oracle-seed", "--sequential", "--no-progress", *OPTS])
    assert rc == 0
    assert json.loads((out / "jobs" / "summary.json").read_text())["counts"]["resumed"] == 3
    assert (out / ".DS_Store").read_bytes() == b"\0"
    assert json.loads((out / "report.json").read_text())["overall"] == report["overall"]
    # A run over one scene says that its report replaces a fuller one; the other scene's extractions
    # stay listed, so the next full run still resumes all three.
    capsys.readouterr()
    rc = main(["eval", "lerf-mask", str(root / "data"), "--scenes", str(root / "scenes"), "-o", str(out),
               "--oracle-seed", "--sequential", "--no-progress", "--only", "shelf", *OPTS])
    assert rc == 0
    assert "the report now covers shelf only; the earlier one also had blocks" in capsys.readouterr().err
    assert len(json.loads((out / "jobs" / "summary.json").read_text())["jobs"]) == 3
    rc = main(["eval", "lerf-mask", str(root / "data"), "--scenes", str(root / "scenes"), "-o", str(out),
               "--oracle-seed", "--sequential", "--no-progress", *OPTS])
    assert rc == 0
    assert json.loads((out / "jobs" / "summary.json").read_text())["counts"]["resumed"] == 3


def test_eval_on_the_dask_cluster_matches(dataset, dask_client, tmp_path):
    from seed2gs_inverse.evaluation import evaluate_lerf_mask

    root, info = dataset
    rep = evaluate_lerf_mask(root / "data", root / "scenes", tmp_path / "r", oracle_seed=True,
                             options={"n_views": 6}, scenes=["shelf"], client=dask_client, progress=False)
    want = _known_scores({"shelf": info["shelf"]})
    assert rep["overall"]["miou"] == pytest.approx(np.mean([v[0] for v in want[("shelf", "sphere")].values()]),
                                                   abs=1e-12)
    assert [s["scene"] for s in rep["scenes"]] == ["shelf"]


def test_eval_layout_errors(dataset, tmp_path, capsys):
    from seed2gs_inverse.evaluation import evaluate_lerf_mask, read_lerf_mask

    root, _ = dataset
    with pytest.raises(ValidationError, match="grounding model"):
        evaluate_lerf_mask(root / "data", root / "scenes", tmp_path / "r", oracle_seed=False)
    from seed2gs_inverse.cli import main

    for views in (1, 400):  # the range with the option's name, not the job's "options: n_views ..."
        assert main(["eval", "lerf-mask", str(root / "data"), "--scenes", str(root / "scenes"), "-o",
                     str(tmp_path / "v"), "--oracle-seed", "--views", str(views)]) == 2
        assert f"--views must be in 2..360, got {views}" in capsys.readouterr().err
    assert not (tmp_path / "v").exists()
    mine = tmp_path / "mine"  # a user's folder: the report must not overwrite its files
    mine.mkdir()
    (mine / "per_query.csv").write_text("my,own\n")
    (mine / "notes.txt").write_text("keep")
    for report in (None, "{}", "[" * 100_000):  # no report.json, one that is not an evaluation's, a deep one
        if report is not None:
            (mine / "report.json").write_text(report)
        with pytest.raises(ValidationError, match=f"output {mine} holds (report.json, )?per_query.csv of no "
                                                  "earlier evaluation"):
            evaluate_lerf_mask(root / "data", root / "scenes", mine, oracle_seed=True)
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt", "per_query.csv", "report.json"]
    assert (mine / "per_query.csv").read_text() == "my,own\n"
    # a batch's jobs/ beside them proves nothing: only masks/ (an interrupted scoring) may go with it
    (mine / "report.json").unlink()
    (mine / "jobs").mkdir()
    (mine / "jobs" / "summary.json").write_text(json.dumps({"jobs": [{"name": "x", "status": "done"}]}))
    with pytest.raises(ValidationError, match="holds per_query.csv of no earlier evaluation"):
        evaluate_lerf_mask(root / "data", root / "scenes", mine, oracle_seed=True)
    from seed2gs_inverse.evaluation.engine import check_output as _check_output

    (mine / "per_query.csv").unlink()
    (mine / "masks").mkdir()
    assert _check_output(mine) == mine
    (mine / "jobs" / "summary.json").write_text("[" * 200_000)  # one clear line, no RecursionError
    with pytest.raises(ValidationError, match="holds masks of no earlier evaluation"):
        _check_output(mine)
    with pytest.raises(ValidationError, match="no trained scene for 'blocks'"):
        read_lerf_mask(root / "data", tmp_path)
    with pytest.raises(ValidationError, match="nowhere"):
        read_lerf_mask(root / "data", root / "scenes", scenes=["nowhere"])
    bad = root / "data" / "blocks" / "test_mask" / "no_such_camera"
    bad.mkdir()
    (bad / "sphere.png").write_bytes((root / "data" / "blocks" / "test_mask" / "orbit_001" / "sphere.png")
                                     .read_bytes())
    try:
        with pytest.raises(ValidationError, match="no_such_camera"):
            read_lerf_mask(root / "data", root / "scenes")
    finally:
        (bad / "sphere.png").unlink()
        bad.rmdir()
    junk = root / "data" / "blocks" / "test_mask" / "orbit_001" / "junk.png"  # empty, or not an image
    try:
        for content in (b"", b"not a png"):
            junk.write_bytes(content)
            with pytest.raises(FormatError, match=r"orbit_001/junk\.png: not a readable mask image"):
                read_lerf_mask(root / "data", root / "scenes")
    finally:
        junk.unlink()


def test_eval_layout_warnings_and_the_oracle_seed_of_empty_masks(dataset, tmp_path):
    import shutil

    import cv2

    from seed2gs_inverse.evaluation import read_lerf_mask
    from seed2gs_inverse.evaluation import lerf_jobs

    root, _ = dataset
    data = tmp_path / "data"
    shutil.copytree(root / "data", data)
    blocks = data / "blocks" / "test_mask"
    frames = sorted(p.name for p in blocks.iterdir())
    # A scene folder without test_mask/ is named, not skipped in silence.
    (data / "shelf" / "test_mask").rename(data / "shelf" / "test_masks")
    with pytest.warns(UserWarning, match="skipping shelf: no test_mask"):
        scenes = read_lerf_mask(data, root / "scenes")
    assert [s.name for s in scenes] == ["blocks"]
    # Query names that differ only in case are two objects to the protocol: said so.
    (blocks / frames[1] / "sphere.png").rename(blocks / frames[1] / "Sphere.png")
    with pytest.warns(UserWarning, match="'Sphere' and 'sphere' differ only in case"):
        cased = read_lerf_mask(data, root / "scenes", scenes=["blocks"])
    names = [j.name for j in lerf_jobs(cased, oracle_seed=True)]  # their folders must differ, also ignoring case
    assert len({n.casefold() for n in names}) == len(names) == 3
    (blocks / frames[1] / "Sphere.png").rename(blocks / frames[1] / "sphere.png")
    # The oracle seed comes from the first frame whose mask marks the object.
    first = blocks / frames[0] / "sphere.png"
    shape = cv2.imread(str(first), cv2.IMREAD_GRAYSCALE).shape
    cv2.imwrite(str(first), np.zeros(shape, np.uint8))
    sc, = read_lerf_mask(data, root / "scenes", scenes=["blocks"])
    assert sc.seed_frame("sphere") == frames[1]
    for f in frames:
        cv2.imwrite(str(blocks / f / "sphere.png"), np.zeros(shape, np.uint8))
    sc, = read_lerf_mask(data, root / "scenes", scenes=["blocks"])
    with pytest.raises(ValidationError, match=r"every ground-truth mask of 'sphere' is empty \(.*sphere\.png"):
        sc.seed_frame("sphere")
    with pytest.raises(ValidationError, match="is itself a scene"):
        read_lerf_mask(data / "blocks", root / "scenes")


def test_a_scene_without_mask_images_is_refused_before_any_extraction(dataset, tmp_path):
    """Masks the reader skips are named; a scene left with none, or a query given twice, is an error.

    A scene whose frame folders held no readable mask was accepted with no
    query, and the evaluation crashed with a KeyError after every other
    scene's extractions.
    """
    import shutil

    from seed2gs_inverse.evaluation import read_lerf_mask

    root, _ = dataset
    data = tmp_path / "data"
    shutil.copytree(root / "data", data)
    blocks = data / "blocks" / "test_mask"
    frame = sorted(p for p in blocks.iterdir())[0]
    (frame / "notes.txt").write_text("x")
    (frame / ".DS_Store").write_bytes(b"\0")  # hidden: the OS's, skipped without a word
    with pytest.warns(UserWarning, match=r"1 file\(s\) skipped, not a mask image \(.png, .jpg, .jpeg\): notes.txt$"):
        read_lerf_mask(data, root / "scenes", scenes=["blocks"])
    (frame / "notes.txt").unlink()
    shutil.copy(frame / "sphere.png", frame / "sphere.jpg")
    with pytest.raises(ValidationError, match=r"two masks for the query 'sphere' \(sphere.jpg and sphere.png\)"):
        read_lerf_mask(data, root / "scenes", scenes=["blocks"])
    (frame / "sphere.jpg").unlink()
    for f in blocks.iterdir():  # masks in a format the protocol does not read: none left
        for m in f.glob("*.png"):
            m.rename(m.with_suffix(".bmp"))
    with pytest.warns(UserWarning, match="skipped"), \
            pytest.raises(ValidationError, match=r"blocks/test_mask: no mask images in its frame folders"):
        read_lerf_mask(data, root / "scenes")
    shutil.rmtree(blocks)
    blocks.write_text("not a folder")
    with pytest.raises(ValidationError, match=r"blocks/test_mask: not a folder"):
        read_lerf_mask(data, root / "scenes", scenes=["blocks"])


def test_a_rerun_scores_its_own_extractions_and_leaves_no_stale_prediction(dataset, tmp_path, monkeypatch):
    """A copied report directory scores its own job folders (not those its summary was written from); a
    query that fails on a re-run loses its earlier predicted masks and is titled as failed in the grid."""
    import shutil

    import cv2
    import matplotlib.axes

    from seed2gs_inverse.evaluation import evaluate_lerf_mask

    root, info = dataset
    data = tmp_path / "data"
    shutil.copytree(root / "data", data)
    run = dict(oracle_seed=True, options={"n_views": 6}, scenes=["blocks"], client="sequential", progress=False)
    first = evaluate_lerf_mask(data, root / "scenes", tmp_path / "a", **run)
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    q = tmp_path / "a" / "jobs" / "blocks--sphere" / "q.npy"
    np.save(q, np.zeros_like(np.load(q)))  # the original's extraction changes after the copy
    copied = evaluate_lerf_mask(data, root / "scenes", tmp_path / "b", **run)
    assert copied["overall"] == first["overall"] and copied["overall"]["miou"] > 0.5
    # "sphere top" now fails: its seed mask marks an empty corner of the image
    seed = next(r["seed_frame"] for r in first["queries"] if r["query"] == "sphere top")
    corner = np.zeros(info["blocks"]["truth"][seed].shape, np.uint8)
    corner[:4, :4] = 255
    cv2.imwrite(str(data / "blocks" / "test_mask" / seed / "sphere top.png"), corner)
    masks = tmp_path / "b" / "masks" / "blocks"
    assert sorted(p.name for p in masks.glob("*/sphere top.png"))
    titles = []
    real = matplotlib.axes.Axes.set_title
    monkeypatch.setattr(matplotlib.axes.Axes, "set_title",
                        lambda self, label, *a, **k: (titles.append(label), real(self, label, *a, **k))[1])
    again = evaluate_lerf_mask(data, root / "scenes", tmp_path / "b", **run)
    top = next(r for r in again["queries"] if r["query"] == "sphere top")
    assert top["status"] == "failed" and top["miou"] == 0.0
    assert not list(masks.glob("*/sphere top.png"))  # no earlier prediction left for another scorer
    assert len(list(masks.glob("*/sphere.png"))) == len(info["blocks"]["frames"])
    frames = sorted(info["blocks"]["frames"])
    assert [t for t in titles if "failed" in t] == [f"{f}: failed, IoU 0" for f in frames]


def test_masks_smaller_than_the_cameras_and_frames_numbered_past_nine(dataset, tmp_path):
    """Ground truth stored at half the cameras' resolution is scored with the cameras scaled to it (the
    prediction rendered at the masks' size), and frames ``2`` and ``10`` come in natural order, so the
    oracle seed is frame 2's mask."""
    import cv2

    from seed2gs_inverse.camera import Camera
    from seed2gs_inverse.evaluation import evaluate_lerf_mask, read_gt_mask, read_lerf_mask
    from seed2gs_inverse.io import write_cameras
    from seed2gs_inverse.synthetic import render_label_masks

    root, info = dataset
    syn = info["blocks"]["synthetic"]
    full = {name: info["blocks"]["frames"][f] for name, f in (("2", "orbit_002"), ("10", "orbit_003"))}
    named = {k: Camera(c.width, c.height, c.fx, c.fy, c.cx, c.cy, c.world_to_camera, name=k)
             for k, c in full.items()}
    scene_dir = tmp_path / "data" / "half"
    scene_dir.mkdir(parents=True)
    write_cameras(scene_dir / "cameras.json", list(named.values()))
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    (scenes / "half.ply").write_bytes((root / "scenes" / "blocks.ply").read_bytes())
    truth = {}
    for k, c in named.items():
        truth[k] = render_label_masks(syn.scene, [c.scaled(0.5)], syn.object_mask("sphere"))[0] > 0.5
        (scene_dir / "test_mask" / k).mkdir(parents=True)
        cv2.imwrite(str(scene_dir / "test_mask" / k / "sphere.png"), truth[k].astype(np.uint8) * 255)
    (sc,) = read_lerf_mask(tmp_path / "data", scenes)
    assert sc.frames == ["2", "10"] and sc.seed_frame("sphere") == "2"
    for k, c in named.items():
        half = c.scaled(0.5)
        got = sc.cameras[k]
        assert (got.width, got.height) == (half.width, half.height) == (48, 36)
        np.testing.assert_allclose([got.fx, got.fy, got.cx, got.cy], [half.fx, half.fy, half.cx, half.cy])
    rep = evaluate_lerf_mask(tmp_path / "data", scenes, tmp_path / "r", oracle_seed=True, options={"n_views": 6},
                             client="sequential", progress=False)
    (row,) = rep["queries"]
    assert row["seed_frame"] == "2" and row["status"] == "done"
    for k in named:
        pred = read_gt_mask(tmp_path / "r" / "masks" / "half" / k / "sphere.png")
        assert pred.shape == (36, 48)
        assert row["frames"][k]["iou"] > 0.9, (k, row["frames"][k])


def test_a_query_selects_q_strictly_above_its_threshold(dataset, tmp_path):
    """score_frame renders the Gaussians with ``q > threshold`` of the job's report: q exactly at the
    threshold (where a solver leaves Gaussians without evidence) selects nothing."""
    from seed2gs_inverse.batch.worker import clear_scene_cache
    from seed2gs_inverse.evaluation import score_frame

    root, info = dataset
    sphere = info["blocks"]["synthetic"].object_mask("sphere")
    frame = "orbit_002"
    job = tmp_path / "job"
    job.mkdir()
    (job / "report.json").write_text(json.dumps({"threshold": 0.25}))
    try:
        for value, want in ((0.25, np.zeros_like(info["blocks"]["truth"][frame])),
                            (np.nextafter(np.float32(0.25), np.float32(1)), info["blocks"]["truth"][frame])):
            np.save(job / "q.npy", np.where(sphere, np.float32(value), np.float32(0)))
            (rec,) = score_frame(root / "scenes" / "blocks.ply", info["blocks"]["frames"][frame], ["sphere"], [job],
                                 [None])
            assert np.array_equal(rec["pred"], want) and rec["iou"] is None
        assert want.any()
    finally:
        clear_scene_cache()


def test_ground_truth_is_grey_above_128(tmp_path):
    """The LERF-Mask evaluator's rule: a pixel is the object where its grey level exceeds 128."""
    import cv2

    from seed2gs_inverse.evaluation import read_gt_mask

    grey = np.array([[0, 127, 128, 129, 255]], np.uint8)
    cv2.imwrite(str(tmp_path / "m.png"), grey)
    np.testing.assert_array_equal(read_gt_mask(tmp_path / "m.png"), [[False, False, False, True, True]])
    np.testing.assert_array_equal(read_gt_mask(tmp_path / "m.png", threshold=127), [[False, False, True, True, True]])
