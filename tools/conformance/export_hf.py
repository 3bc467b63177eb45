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


def _phrase_masks(input_ids, special_tokens):
    """transformers' ``generate_masks_with_special_tokens_and_transfer_map`` without isin/cummax.

    The TorchScript ONNX exporter has no ``aten::isin`` (nor ``cummax``), and a
    boolean ``torch.eye`` exports to an EyeLike that onnxruntime cannot run:
    the same block-diagonal mask and position ids from pairwise
    comparisons (O(L^2), L <= 256). Checked equal to the original before
    every export.
    """
    batch_size, seq_len = input_ids.shape
    idx = torch.arange(seq_len, device=input_ids.device)
    special = (input_ids.unsqueeze(-1) == special_tokens.reshape(1, 1, -1)).any(-1)           # (B, N)
    j, i = idx.view(1, 1, -1), idx.view(1, -1, 1)
    before = special.unsqueeze(1) & (j < i)                                                   # (B, N, N)
    prev_special = torch.where(before, j.expand_as(before), torch.full_like(before, -1, dtype=torch.long)).amax(-1)
    after = special.unsqueeze(1) & (j >= i)
    next_special = torch.where(after, j.expand_as(after),
                               torch.full_like(after, seq_len, dtype=torch.long)).amin(-1)
    valid_block = (next_special != 0) & (next_special != seq_len - 1) & (next_special != seq_len)
    mask = (next_special.unsqueeze(2) == next_special.unsqueeze(1)) & valid_block.unsqueeze(1)
    mask = (j == i) | mask          # the identity; torch.eye(bool) becomes EyeLike(bool), absent in onnxruntime
    position_ids = idx.unsqueeze(0) - prev_special - 1
    position_ids = torch.where(valid_block, position_ids, torch.zeros_like(position_ids)).clamp(min=0).long()
    return mask, position_ids


def _patch_grounding_dino():
    import transformers.models.grounding_dino.modeling_grounding_dino as gd

    original = gd.generate_masks_with_special_tokens_and_transfer_map
    special = torch.tensor(gd.SPECIAL_TOKENS, dtype=torch.long)
    g = torch.Generator().manual_seed(0)
    for trial in range(20):
        ids = torch.randint(0, 2000, (2, 3 + trial), generator=g)
        ids[:, 0], ids[:, -1] = 101, 102
        ids[ids % 5 == 0] = 1012
        for a, b in zip(original(ids, special), _phrase_masks(ids, special)):
            assert torch.equal(a, b), "export-friendly phrase masks differ from transformers'"
    gd.generate_masks_with_special_tokens_and_transfer_map = _phrase_masks


def export(kind: str, model_dir: str, outdir: Path, opset: int = 17) -> Path:
    from transformers import AutoProcessor

    outdir.mkdir(parents=True, exist_ok=True)
    proc = AutoProcessor.from_pretrained(model_dir)
    image = np.full((480, 640, 3), 128, np.uint8)
    if kind == "groundingdino":
        from transformers import GroundingDinoForObjectDetection

        _patch_grounding_dino()
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
