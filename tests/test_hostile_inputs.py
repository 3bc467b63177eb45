"""Small hostile files and out-of-range prompt parameters end in one-line toolkit errors.

A tiny PNG or ONNX file may declare an image or an input tensor of tens of
gigabytes; each reader refuses it from its header, naming the file and the
limit, before anything of that size is decoded or allocated. Mask values
follow one documented rule, and GrabCut's parameters are range-checked.
"""

from __future__ import annotations

import argparse
import os
import struct
import zlib

import numpy as np
import pytest
from PIL import Image, ImageFile

import onnx_models as om
import seed2gs_inverse.cli as cli
from seed2gs_inverse.camera import MAX_IMAGE_SIDE
from seed2gs_inverse.errors import FormatError, ValidationError
from seed2gs_inverse.evaluation.engine import read_gt_mask
from seed2gs_inverse.frontend._onnx import MAX_FIXED_DIM, OnnxModel
from seed2gs_inverse.frontend.prompts import (GRABCUT_MAX_ITERATIONS, BoxPrompt, MaskPrompt, PointPrompt,
                                              object_pixels, seed_mask_from_prompt)
from seed2gs_inverse.frontend.sam2 import SAM2ImagePredictor
from seed2gs_inverse.io import read_masks
from seed2gs_inverse.io.images import MAX_IMAGE_PIXELS, image_shape, read_image


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def bomb_png(path, side: int = 30000) -> os.PathLike:
    """A valid 1-bit greyscale PNG of ``side`` x ``side`` black pixels: about 100 kB that decode to 900 MB."""
    row = b"\0" * (1 + (side + 7) // 8)  # filter byte + packed bits
    z = zlib.compressobj(9)
    body = b"".join(z.compress(row * min(1000, side - k)) for k in range(0, side, 1000)) + z.flush()
    ihdr = struct.pack(">IIBBBBB", side, side, 1, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", body) + _chunk(b"IEND", b""))
    return path


@pytest.fixture(scope="module")
def bomb(tmp_path_factory):
    return bomb_png(tmp_path_factory.mktemp("bomb") / "bomb.png")


@pytest.fixture
def no_decoding(monkeypatch):
    """Fail the test if Pillow decodes any pixel."""
    def load(self):
        raise AssertionError(f"pixels of {self.size} image decoded")
    monkeypatch.setattr(ImageFile.ImageFile, "load", load)


def _limit_message(path) -> str:
    return rf"{os.fspath(path)}: .*{MAX_IMAGE_PIXELS} pixels"


# ---------------------------------------------------------------- image files (decompression bombs)
def test_bomb_is_small_and_declares_900_megapixels(bomb):
    data = bomb.read_bytes()
    assert len(data) < 200_000 and struct.unpack(">II", data[16:24]) == (30000, 30000)
    assert 30000 * 30000 > MAX_IMAGE_PIXELS


def test_read_image_refuses_a_bomb_from_its_header(bomb, no_decoding):
    with pytest.raises(FormatError, match=_limit_message(bomb)):
        read_image(bomb, lambda im: np.asarray(im))
    with pytest.raises(FormatError, match=_limit_message(bomb)):
        image_shape(bomb)


def test_limits_below_pillows_error_threshold_and_per_side(tmp_path, no_decoding):
    """Between Pillow's warning and error thresholds Pillow opens the file: the toolkit's limit refuses it.
    A side beyond the camera limit is refused even when the pixel count is small."""
    mid = bomb_png(tmp_path / "mid.png", 12000)  # 144 M pixels: Pillow only warns
    assert 12000 ** 2 < 2 * Image.MAX_IMAGE_PIXELS
    with pytest.raises(FormatError, match=r"mid\.png: the image declares a 12000x12000 image, beyond the limit"):
        read_image(mid, lambda im: np.asarray(im))
    wide = tmp_path / "wide.png"
    Image.new("L", (MAX_IMAGE_SIDE + 1, 1)).save(wide)
    with pytest.raises(FormatError, match=rf"wide\.png: the image declares a {MAX_IMAGE_SIDE + 1}x1 image, "
                                          rf"beyond the limit of {MAX_IMAGE_SIDE} pixels a side"):
        read_image(wide, lambda im: np.asarray(im))


def test_read_image_refuses_special_files(tmp_path):
    fifo = tmp_path / "mask.png"
    os.mkfifo(fifo)
    with pytest.raises(FormatError, match=r"mask\.png: not a regular file"):
        read_image(fifo, lambda im: np.asarray(im))
    with pytest.raises(FileNotFoundError):
        read_image(tmp_path / "gone.png", lambda im: np.asarray(im))


def test_truncated_and_junk_mask_files_are_format_errors(tmp_path):
    image = np.zeros((48, 64, 3), np.float32)
    full = tmp_path / "full.png"
    Image.fromarray(np.random.default_rng(0).integers(0, 256, (48, 64), np.uint8)).save(full)
    cut = tmp_path / "cut.png"
    cut.write_bytes(full.read_bytes()[:len(full.read_bytes()) // 2])
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image at all")
    for f in (cut, junk):
        with pytest.raises(FormatError, match=rf"{f.name}: not a readable mask image"):
            MaskPrompt(f).to_mask(image)


def test_mask_prompt_file_refused_before_decoding(bomb, no_decoding):
    image = np.zeros((48, 64, 3), np.float32)
    with pytest.raises(FormatError, match=_limit_message(bomb)):
        MaskPrompt(bomb).to_mask(image)


def test_mask_prompt_file_of_another_size_refused_before_decoding(tmp_path, no_decoding):
    p = tmp_path / "big.png"
    Image.new("L", (640, 480), 255).save(p)
    with pytest.raises(ValidationError, match=r"mask file .*big\.png has shape \(480, 640\) but the reference "
                                              r"view is 48x64"):
        MaskPrompt(p).to_mask(np.zeros((48, 64, 3), np.float32))


def test_mask_folder_and_ground_truth_refuse_a_bomb(bomb, tmp_path, no_decoding):
    (tmp_path / "masks").mkdir()
    os.symlink(bomb, tmp_path / "masks" / "view_000.png")
    with pytest.raises(FormatError, match=r"view_000\.png: .*134217728 pixels"):
        read_masks(tmp_path / "masks")
    with pytest.raises(FormatError, match=_limit_message(bomb)):
        read_gt_mask(bomb)


def _cli_files(d):
    from seed2gs_inverse.io import write_cameras, write_scene
    from seed2gs_inverse.synthetic import make_scene

    syn = make_scene(seed=0)
    write_scene(d / "scene.ply", syn.scene)
    write_cameras(d / "cameras.json", [syn.reference_camera(64, 48)])


def test_cli_extract_mask_bomb_is_one_line(bomb, tmp_path, capsys, no_decoding):
    _cli_files(tmp_path)
    out = tmp_path / "out"
    rc = cli.main(["extract", str(tmp_path / "scene.ply"), "--camera", f"{tmp_path / 'cameras.json'}:0",
                   "--mask", str(bomb), "-o", str(out), "--views", "3", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert str(bomb) in err and str(MAX_IMAGE_PIXELS) in err and "Traceback" not in err
    assert not out.exists()


class _Grounder:
    def __init__(self):
        self.images = []

    def available_sources(self):
        return ["stub"]

    def ground(self, image, prompt):
        self.images.append(image)
        return []


class _Models:
    path = "stub.toml"

    def __init__(self):
        for name in ("sam2", "sam", "sam2_video", "groundingdino", "sam3", "owlvit", "external"):
            setattr(self, name, None)
        self.g = _Grounder()

    def grounder(self):
        return self.g

    def tracker(self):
        return None


def _models_cli(monkeypatch, image):
    from seed2gs_inverse.cli import _models

    ms = _Models()
    monkeypatch.setattr(_models, "resolve_models", lambda path: ms)
    parser = argparse.ArgumentParser()
    _models.register(parser.add_subparsers())
    args = parser.parse_args(["models", "stub.toml", "--image", str(image), "--prompt", "chair"])
    return args, ms


def test_models_image_bomb_refused_before_decoding(bomb, monkeypatch, no_decoding):
    args, _ = _models_cli(monkeypatch, bomb)
    with pytest.raises(FormatError, match=_limit_message(bomb)):
        args.func(args)


def test_models_image_is_read_as_rgb(tmp_path, monkeypatch, capsys):
    rgb = np.zeros((6, 8, 3), np.uint8)
    rgb[..., 0], rgb[2, 3] = 255, (0, 51, 102)
    Image.fromarray(rgb).save(tmp_path / "img.png")
    args, ms = _models_cli(monkeypatch, tmp_path / "img.png")
    assert args.func(args) == 0
    (image,) = ms.g.images
    assert image.dtype == np.float32 and image.shape == (6, 8, 3)
    assert np.array_equal(image, rgb.astype(np.float32) / 255)


# ---------------------------------------------------------------- ONNX fixed input sizes
def test_onnx_encoder_declaring_a_huge_input_is_refused(tmp_path, capsys):
    """A tiny encoder fixing its input at 65536 x 65536 is refused when opened, naming the file and the cap."""
    enc = om.sam2_encoder(tmp_path / "enc.onnx", size=65536)
    dec = om.sam2_decoder(tmp_path / "dec.onnx")
    assert enc.stat().st_size < 2000
    with pytest.raises(FormatError, match=rf"enc\.onnx: input image of the sam2\.encoder model fixes axis 2 at "
                                          rf"65536, above the limit of {MAX_FIXED_DIM}"):
        SAM2ImagePredictor(enc, dec)
    cfg = tmp_path / "models.toml"
    cfg.write_text(f"[sam2]\nencoder = '{enc}'\ndecoder = '{dec}'\n")
    img = tmp_path / "img.png"
    Image.new("RGB", (8, 8)).save(img)
    rc = cli.main(["models", str(cfg), "--image", str(img), "--prompt", "chair"])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert str(enc) in err and str(MAX_FIXED_DIM) in err


def test_onnx_cap_holds_for_every_input_and_axis(tmp_path):
    from onnx import helper

    from seed2gs_inverse.frontend._onnx import Layout, Port

    def model(name, side):
        feats = om.vi("feats", om.F32, ["n", 1, side])
        return om.save(tmp_path / name, [helper.make_node("Identity", ["feats"], ["out"])],
                       [om.vi("ids", om.I64, [1, 16]), feats], [om.vi("out", om.F32, ["n", 1, side])])

    with pytest.raises(FormatError, match=rf"big\.onnx: input feats of the test model fixes axis 2 at "
                                          rf"{MAX_FIXED_DIM + 1}, above the limit of {MAX_FIXED_DIM}"):
        OnnxModel(model("big.onnx", MAX_FIXED_DIM + 1), "test", [])
    # at the cap the file opens, and is then checked against its layouts
    with pytest.raises(FormatError, match="does not match test"):
        OnnxModel(model("ok.onnx", MAX_FIXED_DIM), "test", [Layout("other", (Port("x"),), (Port("y"),))])


# ---------------------------------------------------------------- mask values
def _save(path, arr):
    Image.fromarray(arr).save(path)
    return path


@pytest.fixture
def obj():
    m = np.zeros((12, 16), bool)
    m[3:9, 4:12] = True
    return m


@pytest.mark.parametrize("values", [(1,), (255,), (100,), (100, 255), (1, 127)], ids=str)
def test_mask_png_non_zero_is_object(tmp_path, obj, values):
    """0/1, 0/255, value-100 and mixed 100/255 masks all select the whole object."""
    u8 = np.zeros(obj.shape, np.uint8)
    ys, xs = np.nonzero(obj)
    u8[ys, xs] = np.resize(np.asarray(values, np.uint8), len(ys))
    p = _save(tmp_path / "m.png", u8)
    image = np.zeros(obj.shape + (3,), np.float32)
    assert np.array_equal(MaskPrompt(p).to_mask(image), obj)
    mask, info = seed_mask_from_prompt(MaskPrompt(p), image)
    assert np.array_equal(mask, obj) and info == {"kind": "mask"}


def test_mask_png_16_bit_colour_and_cut_out(tmp_path, obj):
    image = np.zeros(obj.shape + (3,), np.float32)
    u16 = obj.astype(np.uint16) * 3  # a 16-bit mask of small labels
    p16 = tmp_path / "m16.png"
    Image.fromarray(u16).save(p16)
    assert np.array_equal(MaskPrompt(p16).to_mask(image), obj)
    rgb = np.zeros(obj.shape + (3,), np.uint8)
    rgb[obj] = (0, 0, 90)  # a dark blue object on black
    assert np.array_equal(MaskPrompt(_save(tmp_path / "rgb.png", rgb)).to_mask(image), obj)
    rgba = np.full(obj.shape + (4,), 200, np.uint8)  # grey everywhere; the alpha marks the object
    rgba[..., 3] = np.where(obj, 40, 0)
    assert np.array_equal(MaskPrompt(_save(tmp_path / "cut.png", rgba)).to_mask(image), obj)
    rgba[..., 3] = 255  # opaque: the colour is the mask
    rgba[..., :3] = obj[..., None] * 7
    assert np.array_equal(MaskPrompt(_save(tmp_path / "opaque.png", rgba)).to_mask(image), obj)


def test_mask_jpeg_refused_and_empty_mask_said(tmp_path, obj):
    image = np.zeros(obj.shape + (3,), np.float32)
    Image.fromarray(obj.astype(np.uint8) * 255).save(tmp_path / "m.jpg")
    with pytest.raises(FormatError, match=r"m\.jpg: a lossy JPEG image.*save the mask as PNG"):
        MaskPrompt(tmp_path / "m.jpg").to_mask(image)
    p = _save(tmp_path / "empty.png", np.zeros(obj.shape, np.uint8))
    with pytest.raises(ValidationError, match=r"empty\.png is empty: mark the object with non-zero pixels"):
        MaskPrompt(p).to_mask(image)


def test_mask_arrays_integers_non_zero_floats_above_half(obj):
    image = np.zeros(obj.shape + (3,), np.float32)
    for dtype, value in ((np.uint8, 100), (np.uint8, 1), (np.int32, -5), (np.uint16, 1000), (bool, True)):
        assert np.array_equal(MaskPrompt(obj.astype(dtype) * dtype(value)).to_mask(image), obj), dtype
    probs = np.where(obj, 0.7, 0.3)
    probs[0, 0] = np.nan
    assert np.array_equal(MaskPrompt(probs).to_mask(image), obj)
    assert np.array_equal(object_pixels(np.array([0.0, 0.5, 0.51, 1.0, np.nan])), [False, False, True, True, False])
    with pytest.raises(ValidationError, match="empty"):
        MaskPrompt(np.full(obj.shape, 0.4)).to_mask(image)


def test_cli_mask_option_reads_value_100(tmp_path, obj):
    """The --mask option of extract builds the prompt that turns a value-100 PNG into the whole object."""
    from seed2gs_inverse.cli import _extract

    u8 = obj.astype(np.uint8) * 100
    p = _save(tmp_path / "m.png", u8)
    sub = argparse.ArgumentParser().add_subparsers()
    _extract.register(sub)
    args = sub.choices["extract"].parse_args(["scene.ply", "--mask", str(p), "-o", str(tmp_path / "o")])
    prompt = _extract._prompt_from_args(args)
    mask, _ = seed_mask_from_prompt(prompt, np.zeros(obj.shape + (3,), np.float32))
    assert np.array_equal(mask, obj)
    assert "(non-zero = object;" in " ".join(sub.choices["extract"].format_help().split())


# ---------------------------------------------------------------- GrabCut parameters
BAD_COUNTS = [2 ** 40, -1, 10 ** 6, 5.0, True, None]


@pytest.mark.parametrize("value", BAD_COUNTS + [0], ids=repr)
def test_box_iterations_validated(value):
    with pytest.raises(ValidationError, match=rf"^BoxPrompt\(iterations=\) must be .*1\.\.{GRABCUT_MAX_ITERATIONS}"):
        BoxPrompt([1, 1, 10, 10], iterations=value)


@pytest.mark.parametrize("value", BAD_COUNTS, ids=repr)
def test_point_radius_and_iterations_validated(value):
    with pytest.raises(ValidationError, match=rf"^PointPrompt\(radius=\) must be .*0\.\.{MAX_IMAGE_SIDE:,}"):
        PointPrompt([(2, 2)], radius=value)
    with pytest.raises(ValidationError, match=r"^PointPrompt\(iterations=\)"):
        PointPrompt([(2, 2)], iterations=value)


def test_other_grabcut_parameters_validated():
    for kwargs, name in (({"alpha_min": 2.0}, "alpha_min"), ({"alpha_min": float("nan")}, "alpha_min")):
        with pytest.raises(ValidationError, match=rf"BoxPrompt\({name}=\)"):
            BoxPrompt([1, 1, 10, 10], **kwargs)
    for kwargs, name in (({"color_tol": -0.1}, "color_tol"), ({"depth_tol": float("inf")}, "depth_tol"),
                         ({"alpha_min": -1}, "alpha_min")):
        with pytest.raises(ValidationError, match=rf"PointPrompt\({name}=\)"):
            PointPrompt([(2, 2)], **kwargs)
    BoxPrompt([1, 1, 10, 10], iterations=GRABCUT_MAX_ITERATIONS)
    PointPrompt([(2, 2)], radius=0, iterations=1)


def test_parameters_changed_after_construction_are_checked_when_used(monkeypatch):
    """The prompts are mutable: a count set later is refused before OpenCV sees it."""
    from seed2gs_inverse.frontend import prompts

    monkeypatch.setattr(prompts, "_grabcut", lambda *a: pytest.fail("GrabCut ran"))
    image = np.zeros((16, 16, 3), np.float32)
    box = BoxPrompt([2, 2, 12, 12])
    box.iterations = 2 ** 40
    with pytest.raises(ValidationError, match=r"BoxPrompt\(iterations=\)"):
        box.to_mask(image)
    point = PointPrompt([(5, 5)])
    point.radius = 10 ** 6
    with pytest.raises(ValidationError, match=r"PointPrompt\(radius=\)"):
        point.to_mask(image)


def test_cli_from_report_with_bad_grabcut_counts_is_one_line(tmp_path, capsys):
    """A report whose box prompt records a hostile GrabCut count fails in one line, before any work."""
    import json

    from seed2gs_inverse.io import write_cameras, write_scene
    from seed2gs_inverse.synthetic import make_scene

    syn = make_scene(seed=0)
    write_scene(tmp_path / "scene.ply", syn.scene)
    write_cameras(tmp_path / "cameras.json", [syn.reference_camera(64, 48)])
    first = tmp_path / "first"
    assert cli.main(["extract", str(tmp_path / "scene.ply"), "--camera", f"{tmp_path / 'cameras.json'}:0",
                     "--box", "16", "10", "48", "38", "--views", "3", "--no-progress", "-o", str(first)]) == 0
    capsys.readouterr()
    rep = json.loads((first / "report.json").read_text())
    assert rep["run"]["prompt"]["kind"] == "box"
    for k, value in enumerate((2 ** 40, -1, 10 ** 6)):  # 10**6 would run GrabCut for minutes
        rep["run"]["prompt"]["iterations"] = value
        bad = tmp_path / f"bad{k}.json"
        bad.write_text(json.dumps(rep))
        rc = cli.main(["extract", "--from-report", str(bad), "-o", str(tmp_path / f"again{k}")])
        err = capsys.readouterr().err
        assert rc == 2 and len(err.strip().splitlines()) == 1, err
        assert "iterations" in err and f"1..{GRABCUT_MAX_ITERATIONS}" in err and "Traceback" not in err
        assert not (tmp_path / f"again{k}").exists()


# ---------------------------------------------------------------- model files that are not files
def test_model_and_tokenizer_paths_that_are_pipes_or_huge_are_refused(tmp_path, monkeypatch):
    """A FIFO given as an ONNX or tokenizer file is refused at once (reading it would block for ever),
    and a tokenizer file beyond the size cap is refused before it is read."""
    from seed2gs_inverse.frontend import tokenizer

    fifo = tmp_path / "model.onnx"
    os.mkfifo(fifo)
    with pytest.raises(FormatError, match=r"model\.onnx: not a regular file"):
        OnnxModel(fifo, "sam2.encoder", [])
    for name in ("tokenizer.json", "vocab.txt"):
        os.mkfifo(tmp_path / name)
        with pytest.raises(FormatError, match=rf"{name}: not a regular file"):
            tokenizer.BertTokenizer.from_file(tmp_path / name)
    big = tmp_path / "big" / "tokenizer.json"
    big.parent.mkdir()
    big.write_text('{"model": {"type": "BPE"}}' + " " * 100)
    monkeypatch.setattr(tokenizer, "MAX_TOKENIZER_BYTES", 64)
    with pytest.raises(FormatError, match=r"big/tokenizer\.json: 126 bytes, more than the 64"):
        tokenizer.ClipTokenizer.from_file(big)
