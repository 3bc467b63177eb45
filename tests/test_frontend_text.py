"""Tokenizers and GroundingDINO against hand-computed ids and tiny generated models."""

from __future__ import annotations

import json

import numpy as np
import pytest

import onnx_models as om
from seed2gs_inverse.errors import FormatError, ValidationError
from seed2gs_inverse.frontend.grounding_dino import (
    GroundingDINO, generate_masks_with_special_tokens_and_transfer_map, preprocess_caption)
from seed2gs_inverse.frontend.tokenizer import BertTokenizer, ClipTokenizer, load_tokenizer


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("text")
    return {"bert": om.bert_tokenizer_json(d / "bert.json"), "clip": om.clip_tokenizer_json(d / "clip.json"),
            "gdino": om.grounding_dino(d / "gdino.onnx"), "dir": d}


def test_bert_wordpiece_hand_computed(files):
    tok = BertTokenizer.from_file(files["bert"])
    # the, run ##ning, dog, ., café -> cafe (accent stripped), ! unknown
    assert tok.encode("The Running\tdog. Café!") == [2, 5, 8, 9, 10, 4, 11, 1, 3]
    assert tok.tokenize("chairs") == ["chair", "##s"]
    assert tok.tokenize("xyz") == ["[UNK]"]
    assert tok.encode("red chair dog", max_length=4) == [2, 6, 7, 3]
    vocab_txt = files["dir"] / "vocab.txt"
    vocab_txt.write_text("\n".join(om.BERT_VOCAB))
    assert BertTokenizer.from_file(vocab_txt).encode("red chair") == [2, 6, 7, 3]
    assert isinstance(load_tokenizer(files["bert"]), BertTokenizer)


def test_clip_bpe_hand_computed(files):
    tok = ClipTokenizer.from_file(files["clip"])
    ids, mask = tok.encode("Red  chair")
    assert ids.tolist() == [26, 16, 14, 27] and mask.tolist() == [1, 1, 1, 1]
    # merge priority: 'a i' only applies where 'cha i' did not claim the pair
    assert tok.tokenize("hair") == ["h", "ai", "r</w>"]
    assert tok.tokenize("chair") == ["chair</w>"]
    ids, mask = tok.encode("red chair", context_length=8)
    assert ids.tolist() == [26, 16, 14, 27, 0, 0, 0, 0] and mask.tolist() == [1, 1, 1, 1, 0, 0, 0, 0]
    assert tok.encode("red chair", context_length=3)[0].tolist() == [26, 16, 27]
    assert tok.encode("a table")[0].tolist() == [26, 8, 25, 27]
    assert isinstance(load_tokenizer(files["clip"]), ClipTokenizer)


def test_tokenizer_bad_files(tmp_path, files):
    with pytest.raises(FormatError, match="not found"):
        BertTokenizer.from_file(tmp_path / "none.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(FormatError, match="bad.json"):
        load_tokenizer(bad)
    with pytest.raises(FormatError, match="expected a WordPiece"):
        BertTokenizer.from_file(files["clip"])
    with pytest.raises(FormatError, match="expected a BPE"):
        ClipTokenizer.from_file(files["bert"])
    data = json.loads(files["bert"].read_text())
    del data["model"]["vocab"]["[CLS]"]
    nocls = tmp_path / "nocls.json"
    nocls.write_text(json.dumps(data))
    with pytest.raises(FormatError, match=r"\[CLS\]"):
        BertTokenizer.from_file(nocls)
    # a hand-trimmed file the tokenizers library rejects: named, with what to do
    partial = tmp_path / "partial.json"
    partial.write_text(json.dumps({"model": {"type": "WordPiece", "vocab": {"[UNK]": 0}}}))
    with pytest.raises(FormatError, match="partial.json.*cannot read.*save_pretrained"):
        BertTokenizer.from_file(partial)


def test_subsentence_masks_match_the_original_export_example():
    # "[CLS] the running dog . [SEP]" with bert-base-uncased ids; the expected
    # position ids and mask are the example tensors of the public ONNX export script.
    ids = np.array([[101, 1996, 2770, 3899, 1012, 102]])
    mask, pos = generate_masks_with_special_tokens_and_transfer_map(ids, [101, 102, 1012, 1029])
    assert pos.tolist() == [[0, 0, 1, 2, 3, 0]]
    want = np.zeros((6, 6), bool)
    want[0, 0] = want[5, 5] = True
    want[1:5, 1:5] = True
    np.testing.assert_array_equal(mask[0], want)
    # two phrases: each attends within itself, positions restart
    ids = np.array([[101, 1, 2, 1012, 3, 1012, 102]])
    mask, pos = generate_masks_with_special_tokens_and_transfer_map(ids, [101, 102, 1012])
    assert pos.tolist() == [[0, 0, 1, 2, 0, 1, 0]]
    assert mask[0, 1, 3] and not mask[0, 1, 4] and mask[0, 4, 5] and not mask[0, 5, 2]


def test_caption_preprocessing():
    assert preprocess_caption("  Red Chair ") == "red chair ."
    assert preprocess_caption("chair.") == "chair."
    with pytest.raises(ValidationError, match="empty"):
        preprocess_caption("   ")


@pytest.mark.parametrize("layout", ["groundingdino", "transformers"])
def test_grounding_dino_detects_by_token(files, rng, layout):
    model = files["gdino"] if layout == "groundingdino" else om.grounding_dino(
        files["dir"] / "gdino_hf.onnx", layout="transformers")
    det = GroundingDINO(model, files["bert"])
    assert det.layout == layout
    img = rng.random((48, 64, 3)).astype(np.float32)
    out = det.detect(img, "Red chair")
    assert len(out) == 1 and out[0].label == "chair"      # only 'chair' is above text_threshold
    assert out[0].score == pytest.approx(1 / (1 + np.exp(-10)), rel=1e-6)
    np.testing.assert_allclose(out[0].box, [9.6, 14.4, 22.4, 33.6], atol=1e-4)
    both = det.detect(img, "chair . table")
    assert sorted(d.label for d in both) == ["chair", "table"]
    np.testing.assert_allclose([d for d in both if d.label == "table"][0].box,
                               [(0.75 - 0.15) * 64, (0.5 - 0.3) * 48, (0.75 + 0.15) * 64, (0.5 + 0.3) * 48],
                               atol=1e-4)
    assert det.detect(img, "dog") == []
    low = GroundingDINO(model, files["bert"], text_threshold=0.0)
    assert low.detect(img, "red chair")[0].label == "red chair"
    text = det.encode_text("red chair")
    assert text["input_ids"].tolist() == [[2, 6, 7, 4, 3]]
    assert text["position_ids"].tolist() == [[0, 0, 1, 2, 0]]


def test_grounding_dino_score_is_the_best_caption_token(files, rng, tmp_path):
    """As the original predict() and transformers: a query firing only on a separator
    token ('.', id 4) still scores sigmoid(10), not only queries on phrase tokens."""
    det = GroundingDINO(om.grounding_dino(tmp_path / "dot.onnx", chair_id=4), files["bert"])
    out = det.detect(rng.random((48, 64, 3)).astype(np.float32), "table")
    assert len(out) == 2
    assert all(d.score == pytest.approx(1 / (1 + np.exp(-10)), rel=1e-6) for d in out)


def test_grounding_dino_resize_rule(files):
    det = GroundingDINO(files["gdino"], files["bert"])
    assert det.input_size((48, 64)) == (800, 1066)
    assert det.input_size((64, 48)) == (1066, 800)
    assert det.input_size((100, 1000)) == (133, 1330)   # longer side capped at 1333


def test_grounding_dino_signature_errors(files, tmp_path):
    wrong = om.sam2_encoder(tmp_path / "not_gdino.onnx")
    with pytest.raises(FormatError) as e:
        GroundingDINO(wrong, files["bert"])
    assert "not_gdino.onnx" in str(e.value) and "missing input img" in str(e.value)
    assert "found inputs (image:float32[1,3,64,64])" in str(e.value)


def test_image_inputs_fed_to_the_detectors(files, rng, monkeypatch, tmp_path):
    """Spy on the feeds: resize + normalisation against Pillow, as the reference processors.

    GroundingDINO (original code and transformers) and OWL-ViT's processor
    resize the 8-bit image with Pillow (bilinear / bicubic, anti-aliased);
    Pillow rounds each of its two passes with fixed-point taps: up to 2 grey levels apart.
    """
    from PIL import Image

    from seed2gs_inverse.frontend import _onnx
    from seed2gs_inverse.frontend.owlvit import OWLViT

    seen = {}
    real = _onnx.OnnxModel.run

    def spy(self, feeds, outputs=None):
        seen.update(feeds)
        return real(self, feeds, outputs)

    def pil(img, size_wh, how, mean, std):
        u8 = Image.fromarray(np.round(img * 255).astype(np.uint8))
        return (np.asarray(u8.resize(size_wh, how), np.float64) / 255 - mean) / std

    monkeypatch.setattr(_onnx.OnnxModel, "run", spy)
    img = rng.random((48, 64, 3)).astype(np.float32)
    GroundingDINO(files["gdino"], files["bert"]).detect(img, "chair")
    ref = pil(img, (1066, 800), Image.BILINEAR, [0.485, 0.456, 0.406], [0.229, 0.224, 0.225])
    np.testing.assert_allclose(seen["img"][0].transpose(1, 2, 0), ref, atol=2.01 / 255 / 0.224)
    seen.clear()
    clip = om.clip_tokenizer_json(tmp_path / "clip.json")
    OWLViT(om.owlvit(tmp_path / "owl.onnx"), clip).detect(img, "red chair")
    ref = pil(img, (32, 32), Image.BICUBIC, [0.48145466, 0.4578275, 0.40821073],
              [0.26862954, 0.26130258, 0.27577711])
    np.testing.assert_allclose(seen["pixel_values"][0].transpose(1, 2, 0), ref, atol=2.01 / 255 / 0.26)
    assert seen["input_ids"].tolist() == [[26, 16, 14, 27] + [0] * 12]
    assert seen["attention_mask"].tolist() == [[1] * 4 + [0] * 12]
