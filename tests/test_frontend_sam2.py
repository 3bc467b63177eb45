"""SAM2 image predictor and video tracker on tiny generated ONNX models."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import onnx_models as om
from seed2gs_inverse.errors import FormatError, ValidationError
from seed2gs_inverse.frontend.sam2 import SAM2ImagePredictor, SAM2VideoTracker, _MemoryBank

H, W = 48, 64   # original image; the encoder squashes it to 64 x 64


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    d = tmp_path_factory.mktemp("sam2")
    return {
        "enc_se": om.sam2_encoder(d / "se_enc.onnx", "samexporter"),
        "dec_se": om.sam2_decoder(d / "se_dec.onnx", "samexporter"),
        "dec_se_orig": om.sam2_decoder(d / "se_dec_orig.onnx", "samexporter", with_orig=True),
        "dec_se_scores": om.sam2_decoder(d / "se_dec_scores.onnx", "samexporter", scores_name="scores"),
        "enc_ort": om.sam2_encoder(d / "ort_enc.onnx", "onnxruntime"),
        "dec_ort": om.sam2_decoder(d / "ort_dec.onnx", "onnxruntime"),
        "dir": d,
    }


def expected_mask(box, erode):
    """Brute force: pixel centre -> encoder coords, inside the box eroded by ``erode``."""
    sx, sy = om.S / W, om.S / H
    x = (np.arange(W) + 0.5) * sx
    y = (np.arange(H) + 0.5) * sy
    X, Y = np.meshgrid(x, y)
    d = np.minimum.reduce([X - box[0] * sx, box[2] * sx - X, Y - box[1] * sy, box[3] * sy - Y])
    return d - erode, d


def image(rng):
    return rng.random((H, W, 3)).astype(np.float32)


@pytest.mark.parametrize("pair", [("enc_se", "dec_se"), ("enc_se", "dec_se_orig"),
                                  ("enc_se", "dec_se_scores"), ("enc_ort", "dec_ort")])
def test_box_prompt_mask_scaling_and_multimask(models, rng, pair):
    pred = SAM2ImagePredictor(models[pair[0]], models[pair[1]])
    box = [16.0, 9.0, 52.0, 39.0]
    out = pred.predict(image(rng), box=box)
    assert out.index == 1 and out.score == pytest.approx(0.9)
    np.testing.assert_allclose(out.scores, om.IOU[0])
    want, _ = expected_mask(box, om.ERODE)
    # exact away from the boundary (bilinear upsampling of a piecewise-linear map)
    far = np.abs(want) > 1.5
    assert far.sum() > 0.8 * want.size
    np.testing.assert_array_equal(out.mask[far], want[far] > 0)
    assert out.mask.shape == (H, W)
    # without multimask the first mask (the plain box) is returned
    single = pred.predict(box=box, multimask=False)
    _, d = expected_mask(box, 0)
    far = np.abs(d) > 1.5
    np.testing.assert_array_equal(single.mask[far], d[far] > 0)
    assert single.score == pytest.approx(0.5)


def test_preprocessing_resize_and_imagenet_normalisation(models, rng):
    pred = SAM2ImagePredictor(models["enc_se"], models["dec_se"])
    img = image(rng)
    pred.set_image(img)
    # independent reference: per-pixel bilinear resize + (x - mean) / std, then 16x16 mean
    resized = cv2.resize(img, (om.S, om.S), interpolation=cv2.INTER_LINEAR)
    mean = np.array([0.485, 0.456, 0.406], np.float32)
    std = np.array([0.229, 0.224, 0.225], np.float32)
    norm = (resized - mean) / std
    ref = norm.reshape(4, 16, 4, 16, 3).mean(axis=(1, 3)).transpose(2, 0, 1)[None]
    np.testing.assert_allclose(pred.features["image_embed"], ref, rtol=1e-5, atol=1e-5)
    assert pred.input_size == (om.S, om.S)


def test_layout_detected_and_mixed_pair_rejected(models):
    assert SAM2ImagePredictor(models["enc_ort"], models["dec_ort"]).layout == "onnxruntime"
    with pytest.raises(ValidationError, match="matching pair"):
        SAM2ImagePredictor(models["enc_se"], models["dec_ort"])


def test_prompt_validation(models, rng):
    pred = SAM2ImagePredictor(models["enc_se"], models["dec_se"])
    with pytest.raises(ValidationError, match="set_image"):
        pred.predict(box=[0, 0, 5, 5])
    pred.set_image(image(rng))
    with pytest.raises(ValidationError, match="box"):
        pred.predict(box=[10, 10, 5, 20])
    with pytest.raises(ValidationError, match="prompt"):
        pred.predict()
    with pytest.raises(ValidationError, match="image"):
        pred.set_image(np.zeros((4, 4)))
    with pytest.raises(ValidationError, match="NaN"):
        pred.set_image(np.full((H, W, 3), np.nan, np.float32))


def test_renderings_brighter_than_one_are_clipped(models, rng):
    # 3DGS colours are clamped at 0 only; a rendering can exceed 1
    pred = SAM2ImagePredictor(models["enc_se"], models["dec_se"])
    img = image(rng)
    pred.set_image(np.where(img > 0.9, 1.0, img).astype(np.float32))
    ref = pred.features["image_embed"]
    bright = img.copy()
    bright[img > 0.9] = 1.7
    pred.set_image(bright)
    np.testing.assert_allclose(pred.features["image_embed"], ref, rtol=1e-6, atol=1e-6)
    pred.set_image((img * 255).astype(np.uint8))
    assert pred.features["image_embed"].shape == ref.shape


def test_bad_files_give_format_errors(models, tmp_path):
    with pytest.raises(FormatError, match="not found"):
        SAM2ImagePredictor(tmp_path / "nope.onnx", models["dec_se"])
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"\x00garbage, not a protobuf" * 10)
    with pytest.raises(FormatError, match="junk.onnx.*cannot load"):
        SAM2ImagePredictor(junk, models["dec_se"])
    # a valid model with the wrong input name: message shows expected and found
    wrong = om.save(tmp_path / "wrong.onnx", [om.pool("img", "image_embed", 16)],
                    [om.vi("img", om.F32, [1, 3, 64, 64])], [om.vi("image_embed", om.F32, [1, 3, 4, 4])])
    with pytest.raises(FormatError) as e:
        SAM2ImagePredictor(wrong, models["dec_se"])
    msg = str(e.value)
    assert "wrong.onnx" in msg and "missing input image" in msg and "found inputs (img:float32[1,3,64,64])" in msg
    # wrong fixed size: four colour channels
    four = om.save(tmp_path / "four.onnx", [om.pool("image", "image_embed", 16), om.pool("image", "high_res_feats_0", 4),
                                            om.pool("image", "high_res_feats_1", 8)],
                   [om.vi("image", om.F32, [1, 4, 64, 64])],
                   [om.vi("image_embed", om.F32, [1, 4, 4, 4]), om.vi("high_res_feats_0", om.F32, [1, 4, 16, 16]),
                    om.vi("high_res_feats_1", om.F32, [1, 4, 8, 8])])
    with pytest.raises(FormatError, match="four.onnx.*image axis 1 has size 4, expected 3"):
        SAM2ImagePredictor(four, models["dec_se"])
    # wrong dtype of point_labels
    bad = om.sam2_decoder(tmp_path / "bad_dtype.onnx", "samexporter", label_type=om.BOOL)
    with pytest.raises(FormatError, match="point_labels has dtype bool"):
        SAM2ImagePredictor(models["enc_se"], bad)


# ------------------------------------------------------------------ video
def test_memory_bank_keeps_conditioning_and_caps_recent():
    bank = _MemoryBank(3)
    code = np.arange(3, dtype=np.float32).reshape(3, 1, 1, 1) * 10
    feat = lambda v: np.full((1, 1, 2, 2), v, np.float32)
    pos = lambda v: np.full((4, 1, 1), v, np.float32)
    bank.set_conditioning(0, feat(0), pos(0), code)
    for i in range(1, 5):
        bank.push(i, feat(i), pos(i), code)
    m1, mp, ids = bank.assemble()
    assert ids == [0, 4, 3]                       # conditioning + 2 newest, newest first
    np.testing.assert_array_equal(m1[:, 0, 0, 0], [0, 4, 3])
    # temporal code index num_maskmem - t - 1: cond t=0 -> 2, t=1 -> 1, t=2 -> 0
    np.testing.assert_array_equal(mp[:, 0, 0], [20] * 4 + [4 + 10] * 4 + [3 + 0] * 4)


def _clip(n=6):
    frames, truth = [], []
    for i in range(n):
        img = np.full((H, W, 3), 0.1, np.float32)
        m = np.zeros((H, W), bool)
        x0, y0 = 8 + 4 * i, 6 + 3 * i      # aligned to the 4x4 pooling in encoder pixels
        m[y0:y0 + 18, x0:x0 + 20] = True
        img[m, 0] = 0.9
        frames.append(img)
        truth.append(m)
    return frames, truth


def test_video_tracker_follows_object_and_bank_is_capped(tmp_path):
    paths = om.video_set(tmp_path)
    tracker = SAM2VideoTracker(**paths, num_maskmem=3)
    frames, truth = _clip(6)

    class Frame:
        def __init__(self, rgb):
            self.rgb = rgb

    masks = tracker.track([Frame(f) for f in frames], truth[0].astype(np.float32))
    assert len(masks) == 6 and all(m.dtype == np.float32 and m.shape == (H, W) for m in masks)
    np.testing.assert_array_equal(masks[0], truth[0])
    for m, t in zip(masks[1:], truth[1:]):
        inter = np.logical_and(m > 0.5, t).sum()
        assert inter / np.logical_or(m > 0.5, t).sum() > 0.85
    assert tracker.bank_history == [[], [0], [0, 1], [0, 2, 1], [0, 3, 2], [0, 4, 3]]


def test_video_tracker_default_bank_size_from_temporal_code(tmp_path):
    tracker = SAM2VideoTracker(**om.video_set(tmp_path))
    frames, truth = _clip(9)
    tracker.track(frames, truth[0])
    assert tracker.bank_history[-1] == [0, 7, 6, 5, 4, 3, 2]   # frame 8 sees 0 + six newest


def test_video_tracker_validation(tmp_path):
    tracker = SAM2VideoTracker(**om.video_set(tmp_path))
    frames, truth = _clip(2)
    with pytest.raises(ValidationError, match="seed_mask"):
        tracker.track(frames, truth[0][:10])
    with pytest.raises(ValidationError, match="frames\\[1\\]"):
        tracker.track([frames[0], frames[1][:, :, :2]], truth[0])


def test_video_tracker_frames_of_different_sizes(tmp_path):
    # the pipeline gives the reference at full and the orbit at half resolution
    tracker = SAM2VideoTracker(**om.video_set(tmp_path))
    frames, truth = _clip(3)
    small = [cv2.resize(f, (W // 2, H // 2), interpolation=cv2.INTER_AREA) for f in frames[1:]]
    masks = tracker.track([frames[0]] + small, truth[0])
    assert [m.shape for m in masks] == [(H, W), (H // 2, W // 2), (H // 2, W // 2)]
    t = cv2.resize(truth[2].astype(np.uint8), (W // 2, H // 2), interpolation=cv2.INTER_NEAREST) > 0
    assert np.logical_and(masks[2] > 0.5, t).sum() / np.logical_or(masks[2] > 0.5, t).sum() > 0.8
    with pytest.raises(ValidationError, match="empty"):
        tracker.track([], truth[0])


def test_truncated_file_and_runtime_failure_are_format_errors(models, tmp_path):
    from seed2gs_inverse.frontend._onnx import OnnxModel
    from seed2gs_inverse.frontend.sam2 import SAM2_VIDEO_LAYOUTS

    data = models["enc_se"].read_bytes()
    cut = tmp_path / "cut.onnx"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError, match="cut.onnx"):
        SAM2ImagePredictor(cut, models["dec_se"])
    paths = om.video_set(tmp_path)
    att = OnnxModel(paths["memory_attention"], "sam2_video.memory_attention",
                    SAM2_VIDEO_LAYOUTS["memory_attention"])
    feeds = {"current_vision_feat": np.zeros((1, 3, 4, 4), np.float32),
             "current_vision_pos_embed": np.zeros((16, 1, 3), np.float32),
             "memory_0": np.zeros((0, 3), np.float32), "memory_1": np.zeros((2, 1, 4, 4), np.float32),
             "memory_pos_embed": np.zeros((33, 1, 1), np.float32)}     # 33 rows: not 2 x 16
    with pytest.raises(FormatError, match="memory_attention.onnx.*failed at run time"):
        att.run(feeds)
    feeds["memory_pos_embed"] = np.zeros((32, 1, 1), np.float32)
    assert att.run(feeds)["fused_feat"].shape == (1, 3, 4, 4)


def test_sam_v1_samexporter_layout(tmp_path, rng, monkeypatch):
    """SAM (v1): longest-side resize, box corners, padding point, best of masks 1..3,
    masks up-sampled from low_res_masks (S x S, crop, original size) on the host."""
    from seed2gs_inverse.frontend import _onnx

    pred = SAM2ImagePredictor(om.sam_encoder(tmp_path / "enc.onnx"), om.sam_decoder(tmp_path / "dec.onnx"))
    assert pred.layout == "sam-samexporter" and pred.input_size == (1024, 1024)
    pred.input_size = (om.S, om.S)      # the tiny graph's frame is S = 64 (no fixed size in the file)
    assert pred.resized_shape((H, W)) == (48, 64)
    img = image(rng)
    seen = {}
    real = _onnx.OnnxModel.run

    def spy(self, feeds, outputs=None):
        seen[self.role] = feeds
        return real(self, feeds, outputs)

    monkeypatch.setattr(_onnx.OnnxModel, "run", spy)
    box = [16.0, 9.0, 52.0, 39.0]
    out = pred.predict(img, box=box)
    enc = seen["sam2.encoder"]["input_image"]
    assert enc.shape == (48, 64, 3) and enc.max() <= 255.0 and np.allclose(enc, np.round(enc))
    # 0..255 8-bit values of the (already S-sized) image: no resize happened here
    np.testing.assert_array_equal(enc, np.round(img * 255.0))
    dec = seen["sam2.decoder"]
    np.testing.assert_array_equal(dec["point_labels"], [[2, 3]])
    np.testing.assert_array_equal(dec["orig_im_size"], [H, W])
    assert out.index == 2 and out.score == pytest.approx(0.9)        # 0.99 of mask 0 is ignored
    # brute force: pixel centre -> S-frame coordinates (scale S / max(H, W) = 1 here); mask 2 = dilated box
    x = (np.arange(W) + 0.5) * 64 / W
    y = (np.arange(H) + 0.5) * 48 / H
    X, Y = np.meshgrid(x, y)
    d = np.minimum.reduce([X - box[0], box[2] - X, Y - box[1], box[3] - Y]) + om.ERODE
    far = np.abs(d) > 1.5
    assert far.sum() > 0.7 * d.size
    np.testing.assert_array_equal(out.mask[far], d[far] > 0)
    # points alone get SAM's padding point (0, 0) with label -1
    pred.predict(points=[[30.0, 20.0]])
    np.testing.assert_array_equal(seen["sam2.decoder"]["point_labels"], [[1, -1]])
    np.testing.assert_array_equal(seen["sam2.decoder"]["point_coords"][0, 1], [0.0, 0.0])


def test_sam_v1_and_sam2_files_are_not_mixed(tmp_path, models):
    with pytest.raises(ValidationError, match="matching pair"):
        SAM2ImagePredictor(om.sam_encoder(tmp_path / "enc.onnx"), models["dec_se"])
