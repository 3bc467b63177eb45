"""SAM3, OWL-ViT, external boxes, the QD-SAM3 selector and the models configuration."""

from __future__ import annotations

import json

import numpy as np
import pytest

import onnx_models as om
from seed2gs_inverse.errors import FormatError, ValidationError
from seed2gs_inverse.frontend.base import Candidate, Grounder
from seed2gs_inverse.frontend.config import ENV_VAR, load_models, resolve_models
from seed2gs_inverse.frontend.external import ExternalBoxes
from seed2gs_inverse.frontend.owlvit import OWLViT
from seed2gs_inverse.frontend.sam3 import SAM3
from seed2gs_inverse.frontend.selector import QDSAM3Selector, query_type

H, W = 48, 64
LEFT = np.array([0.1 * W, 0.3 * H, 0.4 * W, 0.7 * H])     # SAM3 query 0 box in pixels
RIGHT = np.array([0.55 * W, 0.2 * H, 0.85 * W, 0.8 * H])  # SAM3 query 1 box


@pytest.fixture(scope="module")
def d(tmp_path_factory):
    t = tmp_path_factory.mktemp("ground")
    files = om.sam3_set(t)
    files["owlvit"] = om.owlvit(t / "owlvit.onnx")
    files["gdino"] = om.grounding_dino(t / "gdino.onnx")
    files["bert"] = om.bert_tokenizer_json(t / "bert.json")
    files["sam2_enc"] = om.sam2_encoder(t / "sam2_enc.onnx")
    files["sam2_dec"] = om.sam2_decoder(t / "sam2_dec.onnx")
    files["dir"] = t
    return files


@pytest.fixture
def img(rng):
    return rng.random((H, W, 3)).astype(np.float32)


def box_mask(box):
    """Pixels whose centres fall inside ``box`` (reference for SAM3's 8x8 box masks)."""
    x = np.arange(W) + 0.5
    y = np.arange(H) + 0.5
    X, Y = np.meshgrid(x, y)
    return (X > box[0]) & (X < box[2]) & (Y > box[1]) & (Y < box[3])


def sam3(d, **kw):
    return SAM3(d["image_encoder"], d["decoder"], d["language_encoder"], d["tokenizer"], **kw)


# ------------------------------------------------------------------ SAM3 / OWL-ViT
def test_sam3_text_prompt_scores_and_masks(d, img):
    model = sam3(d)
    segs = model.segment_text(img, "chair")
    assert len(segs) == 1
    s = 1 / (1 + np.exp(-10.0))
    assert segs[0].score == pytest.approx(s * s)        # sigmoid(logit) * sigmoid(presence)
    np.testing.assert_allclose(segs[0].box, LEFT, atol=1e-4)
    ref = box_mask(LEFT)
    edge = box_mask(LEFT + [-4, -4, 4, 4]) & ~box_mask(LEFT + [4, 4, -4, -4])
    np.testing.assert_array_equal(segs[0].mask[~edge], ref[~edge])
    assert [round(float(b[0]), 3) for b in (x.box for x in model.segment_text(img, "table"))] == [round(RIGHT[0], 3)]
    assert model.segment_text(img, "red") == []
    with pytest.raises(ValidationError, match="empty"):
        model.segment_text(img, "  ")


def test_sam3_box_prompt_picks_overlapping_instance(d, img):
    model = sam3(d)
    mask, score = model.segment_box(img, RIGHT + [2, 1, -2, -1])
    assert mask[int(0.5 * H), int(0.7 * W)] and not mask[int(0.5 * H), int(0.25 * W)]
    mask, _ = model.segment_box(img, [5, 12, 26, 35])
    assert mask[int(0.5 * H), int(0.25 * W)] and not mask[int(0.5 * H), int(0.7 * W)]


def test_sam3_preprocessing_uint8_and_capacity(d, tmp_path, img):
    model = sam3(d)
    t = model.preprocess(img)
    assert t.dtype == np.uint8 and t.shape == (3, om.S3, om.S3)
    fenc = om.sam3_image_encoder(tmp_path / "fenc.onnx", dtype=om.F32)
    t = SAM3(fenc, d["decoder"]).preprocess(np.ones((H, W, 3), np.float32))
    assert t.dtype == np.float32 and np.allclose(t, 1.0)   # (1 - 0.5) / 0.5
    capped = SAM3(d["image_encoder"], om.sam3_decoder(tmp_path / "cap.onnx", capacity=4),
                  d["language_encoder"], d["tokenizer"])
    mask, _ = capped.segment_box(img, LEFT)
    assert mask.any()


def test_sam3_errors(d, tmp_path):
    with pytest.raises(ValidationError, match="tokenizer"):
        SAM3(d["image_encoder"], d["decoder"], d["language_encoder"])
    with pytest.raises(FormatError, match="6 outputs"):
        SAM3(d["sam2_enc"], d["decoder"])
    with pytest.raises(ValidationError, match="language_encoder"):
        SAM3(d["image_encoder"], d["decoder"]).segment_text(np.zeros((H, W, 3), np.float32), "chair")


def test_owlvit_detects_by_token(d, img):
    det = OWLViT(d["owlvit"], d["tokenizer"])
    out = det.detect(img, "a chair")
    assert len(out) == 1 and out[0].score == pytest.approx(1 / (1 + np.exp(-10)))
    np.testing.assert_allclose(out[0].box, [0.2 * W, 0.2 * H, 0.4 * W, 0.4 * H], atol=1e-4)
    assert det.detect(img, "table")[0].box[0] == pytest.approx(0.4 * W)
    assert det.context == 16 and det.input_size == (32, 32)


# ------------------------------------------------------------------ external boxes
def test_external_boxes_file_and_callable(d, tmp_path, img):
    f = tmp_path / "vlm.json"
    f.write_text(json.dumps({"coords": "per-mille", "prompt": "Red chair",
                             "boxes": [{"box": [100, 250, 400, 750], "score": 0.7},
                                       {"box": [500, 0, 1000, 500], "score": 0.9, "label": "x"}]}))
    ext = ExternalBoxes(f)
    out = ext.detect(img, "red chair")
    assert [o.score for o in out] == [0.9, 0.7]
    np.testing.assert_allclose(out[1].box, [6.4, 12.0, 25.6, 36.0])
    assert ext.detect(img, "table") == []            # boxes were made for another prompt
    cb = ExternalBoxes(lambda image, prompt: [[1, 2, 30, 40]])
    got = cb.detect(img, "cup")
    assert got[0].score == 1.0 and got[0].label == "cup" and cb.source == "vlm"
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps([{"box": [1, 2, 3], "score": 0.5}]))
    with pytest.raises(FormatError, match=r"bad.json\[0\]"):  # entries are checked when the file is opened
        ExternalBoxes(bad)
    with pytest.raises(FormatError, match="not found"):
        ExternalBoxes(tmp_path / "missing.json")
    # A file without its own "coords" takes the configured convention (it was read as pixels whatever
    # models.toml said); a convention that does not exist is refused at once.
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps({"boxes": [{"box": [100, 250, 400, 750]}]}))
    np.testing.assert_allclose(ExternalBoxes(plain, coords="per-mille").detect(img, "cup")[0].box,
                               [6.4, 12.0, 25.6, 36.0])
    with pytest.raises(ValidationError, match="coords must be one of"):
        ExternalBoxes(plain, coords="percent")


# ------------------------------------------------------------------ selector terms
def cand(source, conf):
    return Candidate(mask=np.ones((2, 2), bool), box=None, score=conf, source=source)


def test_query_type_heuristic():
    assert query_type("the chair") == "noun"
    assert query_type("red wooden chair") == "attribute"
    assert query_type("cup left of the plate") == "relational"
    assert query_type("a bag of cookies") == "relational"
    assert query_type("big old shiny red metal kettle") == "relational"   # > 4 content words
    with pytest.raises(ValidationError):
        query_type("the")


def test_confidence_term_decides():
    sel = QDSAM3Selector(None)
    ranked = sel.rank([cand("groundingdino", 0.4), cand("groundingdino", 0.9)], "chair")
    assert ranked[0].info["confidence"] == 0.9
    assert ranked[0].score > ranked[1].score


def test_source_term_decides():
    # 'attribute' query: vlm and groundingdino have the same S_lang (0.8), equal confidence
    sel = QDSAM3Selector(None)
    ranked = sel.rank([cand("groundingdino", 0.6), cand("vlm", 0.6)], "red chair")
    assert ranked[0].source == "vlm" and ranked[0].info["S_lang"] == ranked[1].info["S_lang"]
    flat = QDSAM3Selector(None, weights={"source": 0})
    assert flat.rank([cand("groundingdino", 0.6), cand("vlm", 0.6)], "red chair")[0].score == \
        pytest.approx(flat.rank([cand("vlm", 0.6)], "red chair")[0].score)


def test_language_term_decides():
    sel = QDSAM3Selector(None, source_prior={"vlm": 0.8, "groundingdino": 0.8})
    rel = sel.rank([cand("groundingdino", 0.7), cand("vlm", 0.7)], "the cup left of the plate")
    assert rel[0].source == "vlm" and rel[0].info["query_type"] == "relational"
    noun = sel.rank([cand("vlm", 0.7), cand("groundingdino", 0.7)], "cup")
    assert noun[0].source == "groundingdino"


def test_eq3_total_and_ablation_switches():
    sel = QDSAM3Selector(None, weights={"source": 1, "confidence": 2, "language": 1})
    c = sel.rank([cand("sam3_text", 0.5)], "chair")[0]
    assert c.score == pytest.approx((1 * 0.7 + 2 * 0.5 + 1 * 1.0) / 4)
    assert (c.info["S_src"], c.info["S_conf"], c.info["S_lang"]) == (0.7, 0.5, 1.0)
    # max-confidence baseline overrides the relational preference for the VLM
    maxconf = QDSAM3Selector(None, weights={"source": 0, "confidence": 1, "language": 0})
    assert maxconf.rank([cand("vlm", 0.6), cand("groundingdino", 0.8)], "cup left of plate")[0].source == \
        "groundingdino"
    # source removal
    drop = QDSAM3Selector(None, sources=["groundingdino"])
    assert [x.source for x in drop.rank([cand("vlm", 1.0), cand("groundingdino", 0.1)], "cup")] == \
        ["groundingdino"]
    with pytest.raises(ValidationError, match="unknown term"):
        QDSAM3Selector(None, weights={"lexical": 1})
    with pytest.raises(ValidationError, match="positive sum"):
        QDSAM3Selector(None, weights={"source": 0, "confidence": 0, "language": 0})


# ------------------------------------------------------------------ configuration + end to end
def write_config(d, tmp_path, extra=""):
    t = d["dir"]
    text = f"""
[sam3]
image_encoder = "{d['image_encoder']}"
decoder = "{d['decoder']}"
language_encoder = "{d['language_encoder']}"
tokenizer = "{d['tokenizer']}"

[groundingdino]
model = "{t / 'gdino.onnx'}"
tokenizer = "{t / 'bert.json'}"

[owlvit]
model = "owlvit.onnx"
tokenizer = "clip_tokenizer.json"
""" + extra
    p = t / "models.toml"
    p.write_text(text)
    return p


def test_models_config_grounder_end_to_end(d, tmp_path, img):
    ms = load_models(write_config(d, tmp_path))
    g = ms.grounder(external=lambda image, prompt: [{"box": list(RIGHT), "score": 0.8}])
    assert isinstance(g, Grounder) and ms.tracker() is None
    cands = g.ground(img, "chair")
    assert sorted(c.source for c in cands) == ["groundingdino", "owlvit", "sam3_text", "vlm"]
    assert [c.score for c in cands] == sorted((c.score for c in cands), reverse=True)
    by = {c.source: c for c in cands}
    # every cue became a mask with the same (SAM3) mask model
    for src in ("groundingdino", "sam3_text"):
        assert by[src].mask[int(0.5 * H), int(0.25 * W)] and not by[src].mask[int(0.5 * H), int(0.7 * W)]
    assert by["vlm"].mask[int(0.5 * H), int(0.7 * W)]
    for c in cands:
        t = g.terms(c.source, c.info["confidence"], "noun")
        assert c.score == pytest.approx(t["total"])
        assert {"S_src", "S_conf", "S_lang", "source", "confidence"} <= set(c.info)
    assert "sam3:" in ms.describe() and "gdino.onnx" in ms.describe()


def test_models_config_json_sam2_mask_model(d, tmp_path, img):
    cfg = {"sam2": {"encoder": str(d["sam2_enc"]), "decoder": str(d["sam2_dec"])},
           "groundingdino": {"model": str(d["gdino"]), "tokenizer": str(d["bert"])},
           "selector": {"weights": {"language": 0.0}}}
    p = tmp_path / "models.json"
    p.write_text(json.dumps(cfg))
    ms = load_models(p)
    g = ms.grounder()
    assert g.mask_model is ms.sam2 and g.weights["language"] == 0.0
    cands = g.ground(img, "chair")
    assert [c.source for c in cands] == ["groundingdino"]
    assert cands[0].info["mask_score"] == pytest.approx(0.9)   # SAM2 multimask best IoU


def test_models_config_errors(d, tmp_path):
    def cfg(text, name="m.toml"):
        p = tmp_path / name
        p.write_text(text)
        return p

    with pytest.raises(FormatError, match="not found"):
        load_models(tmp_path / "none.toml")
    with pytest.raises(FormatError, match=r"unknown section \[sam4\]"):
        load_models(cfg("[sam4]\nmodel='x'\n"))
    with pytest.raises(FormatError, match="unknown key 'encodr'"):
        load_models(cfg("[sam2]\nencodr='x'\ndecoder='y'\n"))
    with pytest.raises(FormatError, match="needs the key 'tokenizer'"):
        load_models(cfg("[groundingdino]\nmodel='x.onnx'\n"))
    with pytest.raises(FormatError, match="not valid TOML"):
        load_models(cfg("[sam2\n"))
    with pytest.raises(FormatError, match="missing.onnx.*not found"):
        load_models(cfg(f"[groundingdino]\nmodel='missing.onnx'\ntokenizer='{d['bert']}'\n"))
    # a real ONNX file in the wrong role: expected vs found signature
    with pytest.raises(FormatError) as e:
        load_models(cfg(f"[groundingdino]\nmodel='{d['owlvit']}'\ntokenizer='{d['bert']}'\n"))
    assert "owlvit.onnx" in str(e.value) and "expected groundingdino" in str(e.value) and "found inputs" in str(e.value)
    with pytest.raises(FormatError, match="mask model"):
        load_models(cfg(f"[groundingdino]\nmodel='{d['gdino']}'\ntokenizer='{d['bert']}'\n"))
    with pytest.raises(FormatError, match="mask_model"):
        load_models(cfg(f"[sam2]\nencoder='{d['sam2_enc']}'\ndecoder='{d['sam2_dec']}'\n"
                        "[selector]\nmask_model='sam3'\n"))
    # values the models would take as given and then never find anything with, checked at load
    pair = f"[sam2]\nencoder='{d['sam2_enc']}'\ndecoder='{d['sam2_dec']}'\n"
    gdino = f"[groundingdino]\nmodel='{d['gdino']}'\ntokenizer='{d['bert']}'\n"
    with pytest.raises(FormatError, match=r"\[groundingdino\] box_threshold must be in \[0, 1\], got 5"):
        load_models(cfg(pair + gdino + "box_threshold=5\n"))
    with pytest.raises(FormatError, match=r"sources \['gdino'\] name no configured source; configured "
                                          r"sources: groundingdino, vlm"):
        load_models(cfg(pair + gdino + "[selector]\nsources=['groundingdino', 'gdino']\n"))
    # "vlm" may come from Python (grounder(external=...)), so a configuration may name it
    ms = load_models(cfg(pair + gdino + "[selector]\nsources=['vlm', 'groundingdino']\n"))
    assert ms.grounder(external=lambda image, prompt: []).sources == {"vlm", "groundingdino"}
    with pytest.raises(FormatError, match=r"providers \['FooProvider'\] not available"):
        load_models(cfg(pair + "[onnxruntime]\nproviders=['FooProvider']\n"))
    boxes = tmp_path / "boxes.json"
    boxes.write_text(json.dumps({"boxes": [{"bx": [1, 2, 3, 4]}]}))
    with pytest.raises(FormatError, match=r"boxes.json\[0\]"):
        load_models(cfg(pair + f"[external]\nboxes='{boxes}'\n"))
    boxes.write_text(json.dumps({"boxes": [[1, 2, 3, 4]]}))
    with pytest.raises(FormatError, match=r"m.toml: \[external\] coords must be one of"):
        load_models(cfg(pair + f"[external]\nboxes='{boxes}'\ncoords='percent'\n"))


def test_resolve_models_argument_env_and_none(d, tmp_path, monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert resolve_models(None) is None
    p = tmp_path / "only_sam2.toml"
    p.write_text(f"[sam2]\nencoder='{d['sam2_enc']}'\ndecoder='{d['sam2_dec']}'\n")
    ms = resolve_models(p)
    assert ms.sam2 is not None and ms.grounder() is None
    monkeypatch.setenv(ENV_VAR, str(p))
    assert resolve_models(None).path == p
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "gone.toml"))
    with pytest.raises(FormatError, match="gone.toml"):
        resolve_models(None)


def test_models_cli_check_and_ground(d, tmp_path, capsys, monkeypatch):
    import argparse

    import cv2

    from seed2gs_inverse.cli import _models

    parser = argparse.ArgumentParser()
    _models.register(parser.add_subparsers())
    p = write_config(d, tmp_path)
    args = parser.parse_args(["models", str(p)])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "groundingdino.model" in out and "[samexporter-raw]" in out and "QD-SAM3 over" in out
    img = tmp_path / "ref.png"
    cv2.imwrite(str(img), np.full((H, W, 3), 128, np.uint8))
    args = parser.parse_args(["models", str(p), "--image", str(img), "--prompt", "chair"])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "query type: noun" in out and "sam3_text" in out
    monkeypatch.delenv(ENV_VAR, raising=False)
    args = parser.parse_args(["models"])
    with pytest.raises(ValidationError, match=ENV_VAR):
        args.func(args)
    args = parser.parse_args(["models", str(p), "--image", str(tmp_path / "no.png"), "--prompt", "x"])
    with pytest.raises(FormatError, match="no.png"):
        args.func(args)


def test_selector_skips_boxes_without_area(img):
    """A detector's best box collapsed to a point (random-weight exports do this; a real one
    may clip a box to nothing at the image edge) must not fail the prompt: the next box
    of the source prompts the mask model instead."""
    try:  # Detection moves to frontend/base.py (issue 9)
        from seed2gs_inverse.frontend.base import Detection
    except ImportError:
        from seed2gs_inverse.frontend.grounding_dino import Detection

    class Boxes:
        source = "groundingdino"

        def detect(self, image, prompt):
            return [Detection(np.zeros(4), 0.99, "x"), Detection(np.array([70.0, 5, 90, 20]), 0.9, "x"),
                    Detection(np.array([10.0, 8, 30, 40]), 0.8, "x")]

    class Masks:
        def __init__(self):
            self.boxes = []

        def segment_box(self, image, box):
            self.boxes.append(list(box))
            m = np.zeros(image.shape[:2], bool)
            m[int(box[1]):int(box[3]), int(box[0]):int(box[2])] = True
            return m, 0.5

    masks = Masks()
    got = QDSAM3Selector(masks, [Boxes()]).ground(img, "chair")
    # the all-zero box is dropped, the box right of the 64-px-wide image has no area inside it
    assert masks.boxes == [[10.0, 8.0, 30.0, 40.0]]
    assert len(got) == 1 and got[0].info["cue_box"] == [10.0, 8.0, 30.0, 40.0]
