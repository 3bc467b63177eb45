"""Export a transformers GroundingDINO or OWL-ViT checkpoint to the ONNX layout seed2gs reads.

Usage (in an environment with torch, transformers, onnx; never needed at run time)::

    python tools/conformance/export_hf.py groundingdino IDEA-Research/grounding-dino-tiny gdino/
    python tools/conformance/export_hf.py owlvit google/owlvit-base-patch32 owlvit/

MODEL is a hub name or a local directory saved with ``save_pretrained``
(model + processor). OUTDIR receives ``model.onnx`` and the processor's
``tokenizer.json`` (with ``special_tokens_map.json``), the two files a
``[groundingdino]`` / ``[owlvit]`` section names. The conformance harness
runs this very script on random-weight checkpoints.

Tensor names (docs/models.md): GroundingDINO ``pixel_values, input_ids,
token_type_ids, attention_mask, pixel_mask -> logits, pred_boxes``; OWL-ViT
the names of ``optimum-cli export onnx --task zero-shot-object-detection``:
``input_ids, pixel_values, attention_mask -> logits, pred_boxes,
text_embeds, image_embeds``. The TorchScript exporter (``dynamo=False``) is
used with dynamic image size (GroundingDINO) and text length.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch


class GroundingDinoOnnx(torch.nn.Module):
    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, pixel_values, input_ids, token_type_ids, attention_mask, pixel_mask):
        out = self.model(pixel_values=pixel_values, input_ids=input_ids, token_type_ids=token_type_ids,
                         attention_mask=attention_mask, pixel_mask=pixel_mask, return_dict=True)
        return out.logits, out.pred_boxes


class OwlViTOnnx(torch.nn.Module):
    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, input_ids, pixel_values, attention_mask):
        out = self.model(input_ids=input_ids, pixel_values=pixel_values, attention_mask=attention_mask,
                         return_dict=True)
        return out.logits, out.pred_boxes, out.text_embeds, out.image_embeds


def export(kind: str, model_dir: str, outdir: Path, opset: int = 17) -> Path:
    from transformers import AutoProcessor

    outdir.mkdir(parents=True, exist_ok=True)
    proc = AutoProcessor.from_pretrained(model_dir)
    image = np.full((480, 640, 3), 128, np.uint8)
    if kind == "groundingdino":
        from transformers import GroundingDinoForObjectDetection

        model = GroundingDinoForObjectDetection.from_pretrained(model_dir).eval()
        x = proc(images=image, text="a cat. a remote control.", return_tensors="pt")
        names = ["pixel_values", "input_ids", "token_type_ids", "attention_mask", "pixel_mask"]
        args = tuple(x[n] for n in names)
        wrapper, outputs = GroundingDinoOnnx(model), ["logits", "pred_boxes"]
        axes = {"pixel_values": {2: "height", 3: "width"}, "pixel_mask": {1: "height", 2: "width"},
                "input_ids": {1: "tokens"}, "token_type_ids": {1: "tokens"}, "attention_mask": {1: "tokens"}}
    elif kind == "owlvit":
        from transformers import OwlViTForObjectDetection

        model = OwlViTForObjectDetection.from_pretrained(model_dir).eval()
        x = proc(text=["a cat"], images=image, return_tensors="pt")
        names = ["input_ids", "pixel_values", "attention_mask"]
        args = tuple(x[n] for n in names)
        wrapper, outputs = OwlViTOnnx(model), ["logits", "pred_boxes", "text_embeds", "image_embeds"]
        axes = {"input_ids": {0: "text_batch_size", 1: "sequence_length"},
                "attention_mask": {0: "text_batch_size", 1: "sequence_length"},
                "pixel_values": {0: "image_batch_size"}}
    else:
        raise SystemExit(f"unknown model kind {kind!r}: groundingdino or owlvit")
    path = outdir / "model.onnx"
    with torch.no_grad():
        torch.onnx.export(wrapper, args, str(path), dynamo=False, opset_version=opset,
                          input_names=names, output_names=outputs, dynamic_axes=axes)
    proc.tokenizer.save_pretrained(str(outdir))
    print(f"wrote {path} and {outdir / 'tokenizer.json'}")
    return path


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("kind", choices=("groundingdino", "owlvit"))
    p.add_argument("model", help="hub name or save_pretrained directory (model + processor)")
    p.add_argument("outdir", type=Path)
    p.add_argument("--opset", type=int, default=17)
    a = p.parse_args(argv)
    export(a.kind, a.model, a.outdir, a.opset)


if __name__ == "__main__":
    main()
