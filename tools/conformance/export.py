"""Stage 2 (the toolchain's own environment): random-weight models, exports, torch references.

For every family: build the model at its smallest size with random weights
(``torch.manual_seed``), save them as the checkpoint file the exporter
reads, run the exporter exactly as a user runs it on the real checkpoint
(the command is recorded), then run the package's own predictor on the
scene of stage 1 and save what it returns (boxes, scores, mask logits,
token ids) as ``.npz`` for stage 3. Nothing here imports seed2gs_inverse.

Usage: python tools/conformance/export.py WORK [family ...]
Writes WORK/models/<family>/..., WORK/ref/<family>.npz, WORK/export.json.
"""

from __future__ import annotations

import importlib.metadata as md
import json
import os
import shutil
import subprocess
import sys
import time
import traceback
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
SEED = 0
PACKAGES = ("torch", "torchvision", "sam2", "segment-anything", "samexporter", "transformers",
            "tokenizers", "onnx", "onnxruntime", "onnxscript", "timm", "numpy", "pillow",
            "hydra-core")


def versions() -> dict:
    out = {"python": sys.version.split()[0]}
    for p in PACKAGES:
        try:
            out[p] = md.version(p)
        except md.PackageNotFoundError:
            out[p] = "absent"
    return out


def run(cmd, cwd=None) -> str:
    """Run an exporter command line; its output is kept for the report."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed ({proc.returncode}):\n"
                           f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    print(f"    {' '.join(map(str, cmd))}  [{time.perf_counter() - t0:.0f} s]", flush=True)
    return proc.stdout


def scene(work: Path):
    clip = np.load(work / "scene" / "clip.npz")["frames"]   # (5, H, W, 3) uint8
    seed = np.load(work / "scene" / "seed.npy")
    ys, xs = np.nonzero(seed)
    box = np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], np.float32)
    return clip, seed, box


# ------------------------------------------------------------------ SAM2 image (samexporter)
def sam2_image(work: Path) -> dict:
    from sam2.build_sam import build_sam2
    from sam2.sam2_image_predictor import SAM2ImagePredictor

    out = work / "models" / "sam2_image"
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(SEED)
    model = build_sam2("configs/sam2/sam2_hiera_t.yaml", None, device="cpu")
    ckpt = work / "ckpt" / "sam2_hiera_tiny.pt"
    ckpt.parent.mkdir(exist_ok=True)
    torch.save({"model": model.state_dict()}, ckpt)
    cmd = [sys.executable, "-m", "samexporter.export_sam2", "--checkpoint", str(ckpt),
           "--output_encoder", str(out / "sam2_hiera_tiny.encoder.onnx"),
           "--output_decoder", str(out / "sam2_hiera_tiny.decoder.onnx"),
           "--model_type", "sam2_hiera_tiny"]
    run(cmd)
    clip, seed, box = scene(work)
    model = build_sam2("configs/sam2/sam2_hiera_t.yaml", str(ckpt), device="cpu")
    pred = SAM2ImagePredictor(model)
    pred.set_image(clip[0])
    ys, xs = np.nonzero(seed)
    point = np.array([[xs.mean(), ys.mean()]], np.float32)
    ref = {"box": box, "point": point}
    for name, kw in (("box", {"box": box}), ("point", {"point_coords": point, "point_labels": np.ones(1)})):
        logits, scores, low = pred.predict(multimask_output=True, return_logits=True, **kw)
        ref[f"{name}_logits"], ref[f"{name}_scores"] = logits.astype(np.float32), scores.astype(np.float32)
    np.savez(work / "ref" / "sam2_image.npz", **ref)
    return {"exporter": f"samexporter {md.version('samexporter')} (export_sam2)",
            "command": "python -m samexporter.export_sam2 --checkpoint sam2_hiera_tiny.pt "
                       "--output_encoder sam2_hiera_tiny.encoder.onnx --output_decoder "
                       "sam2_hiera_tiny.decoder.onnx --model_type sam2_hiera_tiny",
            "files": {"encoder": "sam2_image/sam2_hiera_tiny.encoder.onnx",
                      "decoder": "sam2_image/sam2_hiera_tiny.decoder.onnx"},
            "reference": "sam2.sam2_image_predictor.SAM2ImagePredictor"}


# ------------------------------------------------------------------ SAM (v1) vit-b (samexporter)
def sam_vitb(work: Path) -> dict:
    from segment_anything import SamPredictor, sam_model_registry

    out = work / "models" / "sam_vitb"
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(SEED)
    model = sam_model_registry["vit_b"](checkpoint=None)
    ckpt = work / "ckpt" / "sam_vit_b.pth"
    ckpt.parent.mkdir(exist_ok=True)
    torch.save(model.state_dict(), ckpt)
    enc = [sys.executable, "-m", "samexporter.export_encoder", "--checkpoint", str(ckpt),
           "--output", str(out / "sam_vit_b.encoder.onnx"), "--model-type", "vit_b", "--use-preprocess"]
    dec = [sys.executable, "-m", "samexporter.export_decoder", "--checkpoint", str(ckpt),
           "--output", str(out / "sam_vit_b.decoder.onnx"), "--model-type", "vit_b", "--return-single-mask"]
    run(enc)
    run(dec)
    clip, seed, box = scene(work)
    model = sam_model_registry["vit_b"](checkpoint=str(ckpt))
    pred = SamPredictor(model)
    pred.set_image(clip[0])
    ys, xs = np.nonzero(seed)
    point = np.array([[xs.mean(), ys.mean()]], np.float32)
    ref = {"box": box, "point": point}
    for name, kw in (("box", {"box": box}), ("point", {"point_coords": point, "point_labels": np.ones(1)})):
        logits, scores, _ = pred.predict(multimask_output=True, return_logits=True, **kw)
        ref[f"{name}_logits"], ref[f"{name}_scores"] = logits.astype(np.float32), scores.astype(np.float32)
    np.savez(work / "ref" / "sam_vitb.npz", **ref)
    return {"exporter": f"samexporter {md.version('samexporter')} (export_encoder --use-preprocess, "
                        "export_decoder --return-single-mask)",
            "command": "python -m samexporter.export_encoder --checkpoint sam_vit_b_01ec64.pth --output "
                       "sam_vit_b.encoder.onnx --model-type vit_b --use-preprocess && python -m "
                       "samexporter.export_decoder --checkpoint sam_vit_b_01ec64.pth --output "
                       "sam_vit_b.decoder.onnx --model-type vit_b --return-single-mask",
            "files": {"encoder": "sam_vitb/sam_vit_b.encoder.onnx", "decoder": "sam_vitb/sam_vit_b.decoder.onnx"},
            "reference": "segment_anything.SamPredictor"}


# ------------------------------------------------------------------ SAM2 video (sam2-onnx-cpp)
def sam2_video(work: Path) -> dict:
    from sam2.build_sam import build_sam2, build_sam2_video_predictor

    out = work / "models" / "sam2_video"
    if out.exists():
        shutil.rmtree(out)
    # The exporter is not on PyPI and is not copied into this repository: the
    # user points SAM2_ONNX_CPP at their own checkout of sam2-onnx-cpp.
    checkout = os.environ.get("SAM2_ONNX_CPP")
    if not checkout or not (Path(checkout) / "export" / "onnx_export.py").is_file():
        raise RuntimeError("sam2-onnx-cpp is not on PyPI: set SAM2_ONNX_CPP to a checkout of it "
                           "(with export/onnx_export.py) to run this family")
    tree = work / "sam2-onnx-cpp"
    if tree.exists():
        shutil.rmtree(tree)
    shutil.copytree(Path(checkout) / "export", tree / "export")
    torch.manual_seed(SEED)
    model = build_sam2("configs/sam2.1/sam2.1_hiera_t.yaml", None, device="cpu")
    (tree / "checkpoints").mkdir()
    ckpt = tree / "checkpoints" / "sam2.1_hiera_tiny.pt"
    torch.save({"model": model.state_dict()}, ckpt)
    run([sys.executable, "export/onnx_export.py", "--model_size", "tiny", "--skip_specialized"], cwd=tree)
    shutil.copytree(tree / "checkpoints" / "tiny", out)
    # reference: SAM2's own video predictor, seeded with the mask on frame 0
    clip, seed, _ = scene(work)
    frames_dir = work / "ref" / "sam2_video_frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    from PIL import Image
    for i, f in enumerate(clip):
        Image.fromarray(f).save(frames_dir / f"{i:05d}.jpg", quality=100)
    pred = build_sam2_video_predictor("configs/sam2.1/sam2.1_hiera_t.yaml", str(ckpt), device="cpu")
    with torch.inference_mode():
        state = pred.init_state(str(frames_dir))
        pred.add_new_mask(state, frame_idx=0, obj_id=1, mask=seed)
        logits = {}
        for idx, _, masks in pred.propagate_in_video(state):
            logits[idx] = masks[0, 0].float().numpy()
    np.savez(work / "ref" / "sam2_video.npz", logits=np.stack([logits[i] for i in range(len(clip))]))
    return {"exporter": "sam2-onnx-cpp export/onnx_export.py (legacy set; the user's checkout in $SAM2_ONNX_CPP)",
            "command": "python export/onnx_export.py --model_size tiny --skip_specialized "
                       "(in a pagarcia/sam2-onnx-cpp checkout, checkpoints/sam2.1_hiera_tiny.pt)",
            "files": {k: f"sam2_video/{k}.onnx" for k in
                      ("image_encoder", "image_decoder", "memory_attention", "memory_encoder")},
            "reference": "sam2.sam2_video_predictor.SAM2VideoPredictor (JPEG frames, add_new_mask)"}


# ------------------------------------------------------------------ tokenizers
def _bert_vocab(work: Path) -> Path:
    """A bert-base-uncased-shaped vocab.txt: 30522 ids, [CLS]=101, [SEP]=102, '.'=1012, '?'=1029.

    The real vocabulary cannot be downloaded here; transformers' GroundingDINO
    hard-codes those four ids, so a WordPiece vocabulary trained on a small
    corpus is laid out on bert-base-uncased's id grid.
    """
    from tokenizers import BertWordPieceTokenizer

    corpus = work / "ref" / "corpus.txt"
    corpus.write_text("\n".join(PHRASES * 20 + CORPUS))
    trainer = BertWordPieceTokenizer(lowercase=True)
    trainer.train([str(corpus)], vocab_size=3000, min_frequency=1, show_progress=False,
                  special_tokens=["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]"])
    learned = [t for t, _ in sorted(trainer.get_vocab().items(), key=lambda kv: kv[1])
               if t not in ("[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]", ".", "?")]
    vocab = ["[PAD]"] + [f"[unused{i}]" for i in range(99)] + ["[UNK]", "[CLS]", "[SEP]", "[MASK]"]
    fixed = {1012: ".", 1029: "?"}
    it = iter(learned)
    while len(vocab) < 30522:
        i = len(vocab)
        vocab.append(fixed[i] if i in fixed else next(it, f"[unused{i}]"))
    path = work / "tokenizers" / "bert" / "vocab.txt"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(vocab) + "\n")
    return path


def _clip_tokenizer(work: Path, pad_token: str) -> Path:
    """CLIPTokenizerFast over the real CLIP BPE (the vocabulary samexporter ships for SAM3)."""
    import gzip

    import samexporter
    from transformers import CLIPTokenizerFast

    bpe = Path(samexporter.__file__).parent / "assets" / "bpe_simple_vocab_16e6.txt.gz"
    merges = gzip.open(bpe).read().decode("utf-8").split("\n")[1:49152 - 256 - 2 + 1]
    merges = [tuple(m.split()) for m in merges]
    # OpenAI CLIP's vocabulary: bytes, bytes + </w>, merges, then the two specials
    b2u = _bytes_to_unicode()
    vocab = list(b2u.values())
    vocab = vocab + [v + "</w>" for v in vocab] + ["".join(m) for m in merges]
    vocab += ["<|startoftext|>", "<|endoftext|>"]
    d = work / "tokenizers" / f"clip_pad_{'bang' if pad_token == '!' else 'eos'}"
    d.mkdir(parents=True, exist_ok=True)
    (d / "vocab.json").write_text(json.dumps({t: i for i, t in enumerate(vocab)}))
    (d / "merges.txt").write_text("#version: 0.2\n" + "\n".join(" ".join(m) for m in merges) + "\n")
    fast = CLIPTokenizerFast(vocab={t: i for i, t in enumerate(vocab)}, merges=[tuple(m) for m in merges],
                             pad_token=pad_token)
    # OpenAI CLIP's ids for a known phrase: the vocabulary is the real one
    got = fast("a photo of a cat")["input_ids"]
    assert got == [49406, 320, 1125, 539, 320, 2368, 49407], got
    fast.save_pretrained(str(d))
    return d / "tokenizer.json"


def _bytes_to_unicode():
    bs = list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1)) + list(range(ord("®"), ord("ÿ") + 1))
    cs = bs[:]
    n = 0
    for b in range(256):
        if b not in bs:
            bs.append(b)
            cs.append(256 + n)
            n += 1
    return dict(zip(bs, map(chr, cs)))


PHRASES = [
    "red chair", "the box", "a chair", "blue box", "striped cylinder", "red ball", "ball", "sphere",
    "white cup", "cup on the table", "the stick", "wooden rod", "green striped can", "the can on the left",
    "left cylinder", "second can from the right", "the largest object", "checkered floor", "floor",
    "yellow and blue cube", "cube", "orange thing in the cup", "the thing behind the ball",
    "a photo of a cat", "Two dogs.", "CAFÉ sign", "naïve résumé", "don't touch", "it's a box!",
    "what is this?", "3 cans", "object #2", "x-ray machine", "state-of-the-art lamp",
    "the bowl, the plate and the spoon", "a very long description of a red chair standing next to "
    "a wooden table in a bright room with many windows", "tiny", "ÜBER chair", "日本 lamp",
    "mug/cup", "the object at (10, 20)", "left-most box", "top of the box", "under the table",
    "e-mail", "rock'n'roll", "  spaced   out  ", "UPPER case", "mixed Case Words", "a.b.c",
]
CORPUS = ["the quick brown fox jumps over the lazy dog", "a red chair and a blue table",
          "cylinders cans cups balls spheres cubes boxes rods sticks floors"]


def tokenizers(work: Path) -> dict:
    from transformers import BertTokenizerFast

    vocab = _bert_vocab(work)
    words = vocab.read_text().splitlines()
    bert = BertTokenizerFast(vocab={t: i for i, t in enumerate(words)}, do_lower_case=True)
    got = bert("red box. what?")["input_ids"]
    assert got[0] == 101 and got[-1] == 102 and 1012 in got and 1029 in got and 100 not in got, got
    bert.save_pretrained(str(vocab.parent))
    clip_owl = _clip_tokenizer(work, "!")
    from transformers import CLIPTokenizerFast
    owl = CLIPTokenizerFast.from_pretrained(str(clip_owl.parent))
    assert len(PHRASES) == 50
    bert_ids = [bert(p)["input_ids"] for p in PHRASES]
    owl_enc = owl(PHRASES, padding="max_length", max_length=16, truncation=True)
    # SAM3: samexporter's own CLIP tokenizer (its runtime's ids), context 32
    from samexporter.clip_tokenizer import CLIPTokenizer as SamexporterClip
    sx = SamexporterClip()
    sam3_ids = []
    for p in PHRASES:
        try:
            sam3_ids.append(sx.tokenize(p, context_length=32)[0])
        except Exception:  # too long for SAM3's 32 tokens: the runtime refuses it
            sam3_ids.append(np.full(32, -1, np.int64))
    n = max(len(b) for b in bert_ids)
    np.savez(work / "ref" / "tokenizers.npz",
             bert=np.array([b + [-1] * (n - len(b)) for b in bert_ids]),
             owl_ids=np.array(owl_enc["input_ids"]), owl_mask=np.array(owl_enc["attention_mask"]),
             sam3=np.stack(sam3_ids), phrases=np.array(PHRASES))
    return {"exporter": f"tokenizers {md.version('tokenizers')} / transformers {md.version('transformers')}",
            "files": {"bert": str(vocab.parent / "tokenizer.json"), "clip": str(clip_owl)},
            "reference": "BertTokenizerFast, CLIPTokenizerFast (OwlViTProcessor settings), "
                         "samexporter.clip_tokenizer"}


# ------------------------------------------------------------------ GroundingDINO tiny, OWL-ViT base (transformers)
def _hf(work: Path, kind: str, build) -> tuple:
    """Save a random-weight model + processor, export it with export_hf.py, return (model, processor)."""
    ckpt = work / "ckpt" / kind
    torch.manual_seed(SEED)
    model, proc = build()
    model.eval()
    model.save_pretrained(str(ckpt))
    proc.save_pretrained(str(ckpt))
    out = work / "models" / kind
    run([sys.executable, str(HERE / "export_hf.py"), kind, str(ckpt), str(out)])
    return model, proc


def groundingdino(work: Path) -> dict:
    from transformers import (BertTokenizerFast, GroundingDinoConfig, GroundingDinoForObjectDetection,
                              GroundingDinoImageProcessor, GroundingDinoProcessor)

    def build():   # default config = Swin-T backbone + BERT-base text encoder: grounding-dino-tiny
        tok = BertTokenizerFast.from_pretrained(str(work / "tokenizers" / "bert"))
        return (GroundingDinoForObjectDetection(GroundingDinoConfig()),
                GroundingDinoProcessor(GroundingDinoImageProcessor(), tok))

    model, proc = _hf(work, "groundingdino", build)
    clip, _, _ = scene(work)
    # the caption convention of the original code (and of seed2gs): lower case, ends with " ."
    inputs = proc(images=clip[0], text=PROMPT.lower().strip() + " .", return_tensors="pt")
    with torch.no_grad():
        res = model(**inputs)
    h, w = clip[0].shape[:2]
    post = proc.post_process_grounded_object_detection(res, inputs["input_ids"], threshold=0.35,
                                                       text_threshold=0.25, target_sizes=[(h, w)])[0]
    np.savez(work / "ref" / "groundingdino.npz", boxes=post["boxes"].numpy(), scores=post["scores"].numpy(),
             logits=res.logits[0].numpy(), pred_boxes=res.pred_boxes[0].numpy(),
             pixel_values=inputs["pixel_values"][0].numpy(), input_ids=inputs["input_ids"][0].numpy())
    return {"exporter": f"transformers {md.version('transformers')} + torch.onnx.export (TorchScript, opset 17) "
                        "via tools/conformance/export_hf.py",
            "command": "python tools/conformance/export_hf.py groundingdino IDEA-Research/grounding-dino-tiny gdino/",
            "files": {"model": "groundingdino/model.onnx", "tokenizer": "groundingdino/tokenizer.json"},
            "reference": "GroundingDinoProcessor + post_process_grounded_object_detection"}


def owlvit(work: Path) -> dict:
    from transformers import (CLIPTokenizerFast, OwlViTConfig, OwlViTForObjectDetection,
                              OwlViTImageProcessor, OwlViTProcessor)

    def build():   # default config = ViT-B/32 at 768 px: owlvit-base-patch32
        tok = CLIPTokenizerFast.from_pretrained(str(work / "tokenizers" / "clip_pad_bang"))
        return OwlViTForObjectDetection(OwlViTConfig()), OwlViTProcessor(OwlViTImageProcessor(), tok)

    model, proc = _hf(work, "owlvit", build)
    clip, _, _ = scene(work)
    inputs = proc(text=[PROMPT], images=clip[0], return_tensors="pt")
    with torch.no_grad():
        res = model(**inputs)
    h, w = clip[0].shape[:2]
    post = proc.image_processor.post_process_object_detection(res, threshold=0.1, target_sizes=[(h, w)])[0]
    np.savez(work / "ref" / "owlvit.npz", boxes=post["boxes"].numpy(), scores=post["scores"].numpy(),
             logits=res.logits[0].numpy(), pred_boxes=res.pred_boxes[0].numpy(),
             pixel_values=inputs["pixel_values"][0].numpy(), input_ids=inputs["input_ids"][0].numpy())
    return {"exporter": f"transformers {md.version('transformers')} + torch.onnx.export (TorchScript, opset 17) "
                        "via tools/conformance/export_hf.py, optimum's tensor names",
            "command": "python tools/conformance/export_hf.py owlvit google/owlvit-base-patch32 owlvit/",
            "files": {"model": "owlvit/model.onnx", "tokenizer": "owlvit/tokenizer.json"},
            "reference": "OwlViTProcessor + post_process_object_detection"}


PROMPT = "box"
FAMILIES = {"tokenizers": tokenizers, "sam2_image": sam2_image, "sam_vitb": sam_vitb,
            "sam2_video": sam2_video, "groundingdino": groundingdino, "owlvit": owlvit}


def main(work: Path, which) -> int:
    torch.set_num_threads(max(1, os.cpu_count() or 1))
    (work / "ref").mkdir(parents=True, exist_ok=True)
    report_path = work / "export.json"
    report = json.loads(report_path.read_text()) if report_path.exists() else {}
    report["versions"] = versions()
    report.setdefault("families", {})
    for name in which or FAMILIES:
        print(f"[export] {name}", flush=True)
        t0 = time.perf_counter()
        try:
            info = FAMILIES[name](work)
            info["ok"] = True
        except Exception as exc:  # one family failing must not hide the others
            info = {"ok": False, "error": f"{type(exc).__name__}: {exc}"[-4000:],
                    "trace": traceback.format_exc()[-4000:]}
            print(f"    FAILED: {info['error'][-1500:]}", flush=True)
        info["seconds"] = round(time.perf_counter() - t0, 1)
        report["families"][name] = info
        report_path.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]), sys.argv[2:]))
