"""Benchmark of the learned front end's host-side work (everything but the networks).

With real ONNX models the networks dominate; this measures what the toolkit
adds around them per call, at the sizes the pipeline uses:

* SAM2 pre-processing of a 960x540 reference (bilinear resize to 1024x1024 +
  ImageNet normalisation, NCHW float32);
* mask post-processing: 256x256 logits upsampled to 960x540 and thresholded;
* GroundingDINO text inputs (WordPiece + sub-sentence masks, 256 tokens max)
  for a 3-phrase caption on a small vocabulary;
* the SAM2 memory-bank assembly for 7 memories of (64, 64, 64) features;
* QD-SAM3 ranking of 4 candidates.

Baseline measured in the same run: one copy of the (1, 3, 1024, 1024)
float32 encoder input (the least any pre-processing must write), and each
figure's ratio to it. The reference image is the firepit ``overview``
rendering of ``../shared/data`` when present, else a random image.

Usage::

    python benchmarks/bench_frontend.py [--repeat 20]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from seed2gs_inverse.frontend._imaging import IMAGENET_MEAN, IMAGENET_STD, resize_map, resize_normalize
from seed2gs_inverse.frontend.base import Candidate
from seed2gs_inverse.frontend.grounding_dino import MAX_TEXT_LEN, \
    generate_masks_with_special_tokens_and_transfer_map, preprocess_caption
from seed2gs_inverse.frontend.sam2 import _MemoryBank
from seed2gs_inverse.frontend.selector import QDSAM3Selector
from seed2gs_inverse.frontend.tokenizer import BertTokenizer


def timeit(fn, repeat):
    fn()
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args(argv)

    data = Path(os.environ.get("SEED2GS_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    ref = data / "firepit_overview_reference_rgb.npy"
    if ref.is_file():
        img = np.load(ref, allow_pickle=False).astype(np.float32)
        what = "firepit overview reference"
    else:
        img = np.random.default_rng(0).random((540, 960, 3)).astype(np.float32)
        what = "random 960x540 image (shared data absent)"
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cpus, "
          f"python {sys.version.split()[0]}; image: {what}")

    tensor = resize_normalize(img, (1024, 1024), IMAGENET_MEAN, IMAGENET_STD)
    base = timeit(lambda: tensor.copy(), args.repeat)
    rows = [("baseline: copy of the 1x3x1024x1024 input", base)]

    rows.append(("SAM2 preprocess 960x540 -> 1x3x1024x1024",
                 timeit(lambda: resize_normalize(img, (1024, 1024), IMAGENET_MEAN, IMAGENET_STD), args.repeat)))
    logits = np.random.default_rng(1).normal(size=(256, 256)).astype(np.float32)
    rows.append(("mask postprocess 256x256 -> 960x540 > 0",
                 timeit(lambda: resize_map(logits, img.shape[:2]) > 0, args.repeat)))

    vocab = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", ".", "?", "red", "chair", "white", "round", "table",
             "fire", "pit", "stone", "##s"]
    tok = BertTokenizer({t: i for i, t in enumerate(vocab)})
    special = [tok.token_id(t) for t in ("[CLS]", "[SEP]", ".", "?")]

    def text():
        ids = np.asarray([tok.encode(preprocess_caption("red chairs . white round table . stone fire pit"),
                                     MAX_TEXT_LEN)])
        return generate_masks_with_special_tokens_and_transfer_map(ids, special)

    rows.append(("GroundingDINO text inputs (3 phrases)", timeit(text, args.repeat)))

    bank = _MemoryBank(7)
    code = np.zeros((7, 1, 1, 64), np.float32)
    feat = np.zeros((1, 64, 64, 64), np.float32)
    pos = np.zeros((4096, 1, 64), np.float32)
    bank.set_conditioning(0, feat, pos, code)
    for i in range(1, 10):
        bank.push(i, feat, pos, code)
    rows.append(("SAM2 memory bank assembly (7 memories)", timeit(bank.assemble, args.repeat)))

    sel = QDSAM3Selector(None)
    cands = [Candidate(np.zeros((540, 960), bool), None, s, src)
             for s, src in ((0.9, "vlm"), (0.7, "groundingdino"), (0.6, "sam3_text"), (0.5, "owlvit"))]
    rows.append(("QD-SAM3 ranking of 4 candidates", timeit(lambda: sel.rank(cands, "red chair left of the table"),
                                                         args.repeat)))

    print(f"{'stage':<46} {'ms':>9} {'x baseline':>11}")
    for name, t in rows:
        print(f"{name:<46} {t * 1e3:9.3f} {t / base:11.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
