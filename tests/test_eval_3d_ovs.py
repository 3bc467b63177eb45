"""``seed2gs eval 3d-ovs`` on a tiny dataset in the 3D-OVS layout with known answers (tests/_ovs_dataset.py).

Seeded by the ground truth, the extraction recovers the sphere and the rod
exactly (the predicted masks equal the rendered objects), so every score is
known from the masks alone: ``sphere top`` is partial off its seed frame,
the rod is not scored in the frame where its mask is empty, the empty
``lamp`` is no query, and the grey-200 block in one sphere mask is not
object (3D-OVS counts only 255; LERF-Mask's grey > 128 would count it).
"""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import _ovs_dataset
from _mask_scores import biou_reference, iou_reference
from seed2gs_inverse.errors import ValidationError


@pytest.fixture(scope="module")
def ovs(tmp_path_factory):
    root = tmp_path_factory.mktemp("ovs")
    return root, _ovs_dataset.build(root)


def test_eval_3d_ovs_reproduces_the_known_scores(ovs, capsys):
    from seed2gs_inverse.cli import main
    from seed2gs_inverse.evaluation import read_gt_mask

    root, info = ovs
    truth = info["truth"]
    out = root / "report"
    rc = main(["eval", "3d-ovs", str(root / "data"), "--scenes", str(root / "scenes"), "-o", str(out),
               "--oracle-seed", "--sequential", "--no-progress", "--views", "6"])
    assert rc == 0, capsys.readouterr().err
    report = json.loads((out / "report.json").read_text())
    exact = {"sphere": "sphere", "sphere top": "sphere", "rod": "rod"}  # what each extraction renders
    want = {}
    for (f, c), gt in truth.items():
        if c in exact and gt.any():
            pred = truth[(f, exact[c])]
            want.setdefault(c, {})[f] = (iou_reference(pred, gt), biou_reference(pred, gt))
    assert set(want["rod"]) == {"00", "08", "12"} and 0.2 < want["sphere top"]["08"][0] < 0.8
    got = {q["query"]: q for q in report["queries"]}
    assert set(got) == set(want)  # "lamp" is empty everywhere: no query
    for c, frames in want.items():
        assert got[c]["status"] == "done" and got[c]["seed_frame"] == "00"
        assert set(got[c]["frames"]) == set(frames)
        for f, (iou, biou) in frames.items():
            assert got[c]["frames"][f]["iou"] == pytest.approx(iou, abs=1e-12), (c, f)
            assert got[c]["frames"][f]["biou"] == pytest.approx(biou, abs=1e-12), (c, f)
    q_means = [np.mean([v[0] for v in fr.values()]) for fr in want.values()]
    assert report["overall"]["miou"] == pytest.approx(np.mean(q_means), abs=1e-12)
    assert report["protocol"]["dataset"] == "3D-OVS" and report["protocol"]["gt"] == "grey == 255"
    # the grey block matters: read as LERF-Mask reads masks, the sphere in frame 08 would score less
    lerf_gt = read_gt_mask(root / "data" / "room" / "segmentations" / "08" / "sphere.png")
    assert iou_reference(truth[("08", "sphere")], lerf_gt) < got["sphere"]["frames"]["08"]["iou"] == 1.0
    rows = list(csv.DictReader(open(out / "per_query.csv")))
    assert [r["query"] for r in rows] == ["rod", "sphere", "sphere top"] and rows[0]["prompt"] == "gt-mask"
    pred = read_gt_mask(out / "masks" / "room" / "12" / "rod.png")
    assert np.array_equal(pred, truth[("12", "rod")])


def test_3d_ovs_layout(ovs, tmp_path):
    from seed2gs_inverse.evaluation import lerf_jobs, read_3d_ovs

    root, info = ovs
    (sc,) = read_3d_ovs(root / "data", root / "scenes")
    assert sc.frames == ["00", "04", "08", "12"] and sc.queries == ["rod", "sphere", "sphere top"]
    assert ("04", "rod") not in sc.gt and ("00", "rod") in sc.gt
    (root / "data" / "room" / "images" / ".DS_Store").write_bytes(b"\0")  # the OS's, not an image
    try:
        again = read_3d_ovs(root / "data", root / "scenes")[0].cameras
        assert {f: c.name for f, c in again.items()} == {f: c.name for f, c in sc.cameras.items()}
    finally:
        (root / "data" / "room" / "images" / ".DS_Store").unlink()
    for f in sc.frames:  # frame NN is image NN of images/: its COLMAP camera
        assert sc.cameras[f].name == f"frame_{int(f):02d}.png"
        np.testing.assert_allclose(sc.cameras[f].world_to_camera, info["cameras"][int(f)].world_to_camera,
                                   atol=1e-6)
    jobs = {j.name: j for j in lerf_jobs([sc], models=tmp_path / "m.toml")}  # text: the class names
    assert jobs["room--sphere_top"].prompt.text == "sphere top"
    # a frame folder missing one class's mask names the file
    p = root / "data" / "room" / "segmentations" / "04" / "lamp.png"
    keep = p.read_bytes()
    p.unlink()
    try:
        with pytest.raises(ValidationError, match="04/lamp.png: missing"):
            read_3d_ovs(root / "data", root / "scenes")
    finally:
        p.write_bytes(keep)
    with pytest.raises(ValidationError, match="classes.txt"):
        read_3d_ovs(root / "data" / "room", root / "scenes")
    seg = root / "data" / "room" / "segmentations"
    (seg / ".ipynb_checkpoints").mkdir()  # a hidden folder is no frame
    try:
        assert read_3d_ovs(root / "data", root / "scenes")[0].frames == sc.frames
        (seg / "\u00b2").mkdir()  # str.isdigit() is True for "²", and int() refused it
        with pytest.raises(ValidationError, match="frame folders must be image numbers"):
            read_3d_ovs(root / "data", root / "scenes")
    finally:
        for d in (".ipynb_checkpoints", "\u00b2"):
            if (seg / d).exists():
                (seg / d).rmdir()
