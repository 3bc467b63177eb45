"""``seed2gs eval lerf-mask --models FILE``: text queries end to end with tiny ONNX models.

The dataset is tests/_lerf_dataset.py's with its queries renamed to words
the tiny GroundingDINO (tests/onnx_models.py) knows: it fires on the token
"chair" with box 0 and on "table" with box 1, whatever the image, and on
nothing else. Box 0 is set to the ``blocks`` sphere's bounding box in the
first test frame and box 1 to the ``shelf`` sphere's, both widened by the
erosion of the tiny SAM2 decoder (4 encoder pixels), which turns the box
into the seed mask. So:

``blocks/red chair``  grounded to a known box; its mask file is missing
                      from the first frame, which must still be the frame
                      grounded in (text queries use the first test frame)
``blocks/dog``        no detection: the job fails and scores 0 per frame
``shelf/table``       grounded to a known box

The expected scores come from a direct ``extract()`` call with the same
models and prompt (no batch, no CLI), rendered into each test view, and the
IoU / boundary IoU formulas of tests/_mask_scores.py.
"""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import _lerf_dataset
import onnx_models as om
from _mask_scores import biou_reference, iou_reference
from seed2gs_inverse.errors import FormatError, ValidationError

NAMES = {("blocks", "sphere"): "red chair", ("blocks", "sphere top"): "dog", ("shelf", "sphere"): "table"}
FIRST = {"blocks": "orbit_001", "shelf": "0"}   # first test frame of each scene
N_VIEWS = 6


def _grounding_box(info, scene):
    """(x0, y0, x1, y1) pixels: the sphere's box in the first frame, widened by the tiny SAM2's erosion."""
    cam, m = info[scene]["frames"][FIRST[scene]], info[scene]["truth"][FIRST[scene]]
    ys, xs = np.nonzero(m)
    ex, ey = om.ERODE * cam.width / om.S, om.ERODE * cam.height / om.S
    return np.array([xs.min() - ex, ys.min() - ey, xs.max() + 1 + ex, ys.max() + 1 + ey]), cam


def _cxcywh(box, cam):
    x0, y0, x1, y1 = box
    return [(x0 + x1) / 2 / cam.width, (y0 + y1) / 2 / cam.height, (x1 - x0) / cam.width, (y1 - y0) / cam.height]


@pytest.fixture(scope="module")
def text_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("lerf_text")
    info = _lerf_dataset.build(root, names=NAMES)
    # "red chair" has no mask in the first frame (the frame stays: "dog" has one there)
    (root / "data" / "blocks" / "test_mask" / FIRST["blocks"] / "red chair.png").unlink()
    del info["blocks"]["gt"][(FIRST["blocks"], "red chair")]
    m = root / "models"
    m.mkdir()
    boxes = {s: _grounding_box(info, s) for s in ("blocks", "shelf")}
    om.grounding_dino(m / "gdino.onnx", boxes=[_cxcywh(*boxes["blocks"]), _cxcywh(*boxes["shelf"])])
    om.bert_tokenizer_json(m / "tokenizer.json")
    om.sam2_encoder(m / "enc.onnx")
    om.sam2_decoder(m / "dec.onnx")
    cfg = m / "models.toml"
    cfg.write_text("[sam2]\nencoder = 'enc.onnx'\ndecoder = 'dec.onnx'\n"
                   "[groundingdino]\nmodel = 'gdino.onnx'\ntokenizer = 'tokenizer.json'\n")
    return root, info, cfg, {s: b[0] for s, b in boxes.items()}


def _expected(root, info, cfg) -> dict:
    """(scene, query) -> {frame: (iou, biou)} of the done queries, from a direct extract() call."""
    from seed2gs_inverse.frontend.config import load_models
    from seed2gs_inverse.pipeline.extract import extract
    from seed2gs_inverse.raster import build_operator

    grounder = load_models(cfg).grounder()
    want = {}
    for scene, query in (("blocks", "red chair"), ("shelf", "table")):
        d = info[scene]
        # the scene and cameras as the files hold them (PLY and COLMAP round trips move the last bits)
        sc, cams = _from_files(root, scene)
        ex = extract(sc, cams[FIRST[scene]], query, grounder=grounder, n_views=N_VIEWS, progress=False)
        sel = ex.selected.astype(np.float32)
        for (frame, q), gt in d["gt"].items():
            if q != query:
                continue
            cam = cams[frame]
            pred = (np.asarray(build_operator(sc, cam).W @ sel) > 0.5).reshape(cam.image_shape)
            want.setdefault((scene, query), {})[frame] = (iou_reference(pred, gt), biou_reference(pred, gt))
    return want


def _from_files(root, scene):
    """(scene, {frame: Camera}) read back from the dataset's files; the frames as _lerf_dataset names them."""
    from seed2gs_inverse.io import read_cameras, read_scene

    if scene == "blocks":
        cams = {c.name: c for c in read_cameras(root / "data" / "blocks" / "cameras.json")}
        return read_scene(root / "scenes" / "blocks.ply"), cams
    by_image = {c.name: c for c in read_cameras(root / "data" / "shelf" / "sparse" / "0")}
    ply = root / "scenes" / "shelf" / "point_cloud" / "iteration_7000" / "point_cloud.ply"
    # frames 0 and 1 are test cameras 0 and 8 of the LLFF split: images 0 and 8
    return read_scene(ply), {"0": by_image["frame_00.png"], "1": by_image["frame_08.png"]}


def _count_model_loads(monkeypatch) -> list:
    import seed2gs_inverse.frontend.config as config

    calls, real = [], config.load_models

    def counting(path):
        calls.append(str(path))
        return real(path)

    monkeypatch.setattr(config, "load_models", counting)
    return calls


def test_eval_text_queries_through_the_cli(text_dataset, capsys, monkeypatch):
    from seed2gs_inverse.cli import main

    root, info, cfg, boxes = text_dataset
    want = _expected(root, info, cfg)
    # sanity of the construction: the tiny models find the sphere, not the ground
    assert min(v[0] for fr in want.values() for v in fr.values()) > 0.8
    out = root / "report"
    loads = _count_model_loads(monkeypatch)
    argv = ["eval", "lerf-mask", str(root / "data"), "--scenes", str(root / "scenes"), "-o", str(out),
            "--models", str(cfg), "--sequential", "--no-progress", "--views", str(N_VIEWS)]
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 1 and "blocks--dog" in err  # one query failed: the exit status says so
    assert len(loads) == 1, loads  # the models file is opened once for the whole evaluation
    report = json.loads((out / "report.json").read_text())
    got = {(q["scene"], q["query"]): q for q in report["queries"]}
    assert set(got) == {("blocks", "red chair"), ("blocks", "dog"), ("shelf", "table")}
    for key, frames in want.items():
        q = got[key]
        assert q["status"] == "done" and q["seed_frame"] == FIRST[key[0]], q
        assert set(q["frames"]) == set(frames)
        for f, (iou, biou) in frames.items():
            assert q["frames"][f]["iou"] == pytest.approx(iou, abs=1e-12), (key, f)
            assert q["frames"][f]["biou"] == pytest.approx(biou, abs=1e-12), (key, f)
        assert q["miou"] == pytest.approx(np.mean([v[0] for v in frames.values()]), abs=1e-12)
        assert q["prompt"] == key[1] and q["grounded_by"] == "groundingdino"
    # the seed frame of "red chair" has no mask of it: every scored frame is held out
    assert got[("blocks", "red chair")]["miou_heldout"] == pytest.approx(got[("blocks", "red chair")]["miou"])
    # the failed query: scored 0 on each of its annotated frames
    dog = got[("blocks", "dog")]
    assert dog["status"] == "failed" and "no candidate" in dog["error"] and "'dog'" in dog["error"]
    assert dog["miou"] == 0.0 and dog["n_frames"] == 3 and dog["grounded_by"] is None
    blocks = np.mean([np.mean([v[0] for v in want[("blocks", "red chair")].values()]), 0.0])
    shelf = np.mean([v[0] for v in want[("shelf", "table")].values()])
    assert {s["scene"]: s["miou"] for s in report["scenes"]} == pytest.approx({"blocks": blocks, "shelf": shelf},
                                                                             abs=1e-12)
    assert report["overall"]["miou"] == pytest.approx((blocks + shelf) / 2, abs=1e-12)
    assert report["protocol"]["seed"].startswith("query text") and report["protocol"]["models"] == str(cfg)
    assert set(report["failed"]) == {"blocks--dog"}
    # the seed came from the known box: the grounder's candidate in each job's report
    for scene, job in (("blocks", "blocks--red_chair"), ("shelf", "shelf--table")):
        prompt = json.loads((out / "jobs" / job / "report.json").read_text())["prompt"]
        assert prompt["kind"] == "text" and prompt["candidates"][0]["source"] == "groundingdino"
        np.testing.assert_allclose(prompt["candidates"][0]["box"], boxes[scene], atol=1e-3)
    # the tables carry the prompt and its grounding
    rows = {(r["scene"], r["query"]): r for r in csv.DictReader(open(out / "per_query.csv"))}
    assert rows[("shelf", "table")]["prompt"] == "table"
    assert rows[("shelf", "table")]["grounded_by"] == "groundingdino"
    assert 0.5 < float(rows[("shelf", "table")]["grounding_score"]) <= 1.0
    assert rows[("blocks", "dog")]["status"] == "failed" and rows[("blocks", "dog")]["grounded_by"] == ""
    summary = json.loads((out / "jobs" / "summary.json").read_text())
    assert summary["counts"] == {"jobs": 3, "done": 2, "failed": 1, "resumed": 0}
    assert {j["prompt"]["text"] for j in summary["jobs"]} == {"red chair", "dog", "table"}
    # a re-run resumes the done jobs; editing the models file re-runs them
    assert main(argv) == 1
    assert json.loads((out / "jobs" / "summary.json").read_text())["counts"]["resumed"] == 2
    cfg.write_text(cfg.read_text() + "# edited\n")
    assert main(argv) == 1
    assert json.loads((out / "jobs" / "summary.json").read_text())["counts"]["resumed"] == 0
    assert json.loads((out / "report.json").read_text())["overall"] == report["overall"]


def test_eval_text_queries_on_the_dask_cluster(text_dataset, dask_client, tmp_path):
    from seed2gs_inverse.batch.worker import scene_cache_info
    from seed2gs_inverse.evaluation import evaluate_lerf_mask

    root, info, cfg, _ = text_dataset
    rep = evaluate_lerf_mask(root / "data", root / "scenes", tmp_path / "r", models=cfg,
                             options={"n_views": N_VIEWS}, client=dask_client, progress=False)
    want = _expected(root, info, cfg)
    got = {(q["scene"], q["query"]): q for q in rep["queries"]}
    for key, frames in want.items():
        for f, (iou, biou) in frames.items():
            assert got[key]["frames"][f]["iou"] == pytest.approx(iou, abs=1e-12), (key, f)
            assert got[key]["frames"][f]["biou"] == pytest.approx(biou, abs=1e-12), (key, f)
    assert got[("blocks", "dog")]["status"] == "failed"
    # each worker process opened the models file at most once, however many jobs it ran
    loads = dask_client.run(scene_cache_info)
    per_worker = [sum(p.endswith("models.toml") for p in v["model_loads"]) for v in loads.values()]
    assert max(per_worker) == 1 and sum(per_worker) <= len(per_worker)


@pytest.mark.parametrize("case", ["missing", "not toml", "unknown section", "missing onnx", "no grounder"])
def test_bad_models_file_is_one_error_before_any_work(text_dataset, tmp_path, capsys, case):
    from seed2gs_inverse.cli import main
    from seed2gs_inverse.evaluation import evaluate_lerf_mask

    root, _, cfg, _ = text_dataset
    bad = tmp_path / "bad.toml"
    text = {"not toml": "[sam2\nencoder = \n",
            "unknown section": "[grounding]\nmodel = 'x.onnx'\n",
            "missing onnx": f"[sam2]\nencoder = '{cfg.parent / 'enc.onnx'}'\ndecoder = '{tmp_path / 'nope.onnx'}'\n"
                            f"[groundingdino]\nmodel = '{cfg.parent / 'gdino.onnx'}'\n"
                            f"tokenizer = '{cfg.parent / 'tokenizer.json'}'\n",
            "no grounder": f"[sam2]\nencoder = '{cfg.parent / 'enc.onnx'}'\ndecoder = '{cfg.parent / 'dec.onnx'}'\n"}
    if case in text:
        bad.write_text(text[case])
    named = str(tmp_path / "nope.onnx") if case == "missing onnx" else str(bad)
    out = tmp_path / "report"
    rc = main(["eval", "lerf-mask", str(root / "data"), "--scenes", str(root / "scenes"), "-o", str(out),
               "--models", str(bad), "--sequential", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and named in err and err.count("error:") == 1, err
    assert not out.exists()  # nothing ran, nothing was written
    expected = ValidationError if case == "no grounder" else FormatError
    with pytest.raises(expected, match="text-grounding" if case == "no grounder" else "nope.onnx|bad.toml"):
        evaluate_lerf_mask(root / "data", root / "scenes", out, models=bad)
    assert not out.exists()


def test_seed_mode_arguments(text_dataset, tmp_path):
    from seed2gs_inverse.evaluation import evaluate_lerf_mask, lerf_jobs, read_lerf_mask

    root, _, cfg, _ = text_dataset
    with pytest.raises(ValidationError, match="one of the two"):
        evaluate_lerf_mask(root / "data", root / "scenes", tmp_path / "r", oracle_seed=True, models=cfg)
    scenes = read_lerf_mask(root / "data", root / "scenes", scenes=["blocks"])
    jobs = {j.name: j for j in lerf_jobs(scenes, models=cfg)}  # models given: text
    assert jobs["blocks--red_chair"].prompt.text == "red chair" and jobs["blocks--red_chair"].models == str(cfg)
    # the text reference is the first test frame even where the query has no mask
    assert jobs["blocks--red_chair"].camera.name == FIRST["blocks"]
    oracle = {j.name: j for j in lerf_jobs(scenes)}  # no models: oracle seed, from the first annotated frame
    assert oracle["blocks--red_chair"].camera.name == "orbit_002" and oracle["blocks--red_chair"].models is None


def test_batch_jobs_file_naming_a_missing_models_file(tmp_path, text_dataset):
    from seed2gs_inverse.batch import read_jobs

    root, _, _, _ = text_dataset
    jobs = tmp_path / "jobs.toml"
    jobs.write_text(f"[defaults]\nscene = '{root / 'scenes' / 'blocks.ply'}'\n"
                    f"camera = '{root / 'data' / 'blocks' / 'cameras.json'}:orbit_001'\n"
                    "models = 'no_such_models.toml'\n[[jobs]]\nname = 'a'\ntext = 'red chair'\n")
    with pytest.raises(ValidationError, match=r"jobs.toml: job 'a'.*no_such_models.toml not found"):
        read_jobs(jobs)
