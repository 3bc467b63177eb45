"""``seed2gs models``: check a models configuration, optionally ground a prompt in an image."""

from __future__ import annotations

import os

import numpy as np
from PIL import ImageOps

from ..errors import FormatError, ValidationError
from ..frontend.config import ENV_VAR, resolve_models
from ..io.images import read_image

__all__ = ["register"]


def register(subparsers) -> None:
    """Add the ``models`` command to ``subparsers``."""
    p = subparsers.add_parser(
        "models", help="check the ONNX models configuration (and try a text prompt)",
        description="Open every ONNX file of a models configuration (TOML or JSON), check each "
                    "against its supported export layout and print the roles, files and layouts. "
                    "With --image and --prompt, also run the QD-SAM3 selector on that image and "
                    "print every candidate with its Eq. 3 terms.")
    p.add_argument("config", nargs="?", metavar="FILE",
                   help="models configuration (default: $SEED2GS_MODELS)")
    p.add_argument("--image", metavar="IMAGE", help="RGB image (PNG/JPEG) to ground --prompt in")
    p.add_argument("--prompt", metavar="TEXT", help="text prompt for --image")
    p.set_defaults(func=run)


def _layouts(obj) -> list[str]:
    """One line per ONNX file of a configured model: its role, path and detected layout."""
    return [f"  {m.role}: {m.path} [{m.layout.name}]"
            for m in vars(obj).values() if hasattr(m, "session") and hasattr(m, "layout")]


def _rgb(im) -> np.ndarray:
    """(H, W, 3) float32 RGB in [0, 1] of an opened image (EXIF orientation applied, 16-bit grey scaled)."""
    im = ImageOps.exif_transpose(im)
    if im.mode.startswith("I"):  # 16-bit grey
        grey = np.asarray(im, np.float32) / 65535.0
    elif im.mode == "F":
        grey = np.asarray(im, np.float32)
    else:
        return np.asarray(im.convert("RGB"), np.float32) / 255.0
    return np.repeat(np.clip(grey, 0.0, 1.0)[..., None], 3, axis=2)


def run(args) -> int:
    """``seed2gs models``: open and describe every configured model; with --image, ground --prompt."""
    if (args.image is None) != (args.prompt is None):
        raise ValidationError("--image and --prompt go together")
    ms = resolve_models(args.config)
    if ms is None:
        raise ValidationError(f"no models configuration: give FILE or set {ENV_VAR}")
    print(f"models: {ms.path}")
    for name in ("sam2", "sam", "sam2_video", "groundingdino", "sam3", "owlvit", "external"):
        obj = getattr(ms, name)
        if obj is not None:
            print(f"{name}:")
            print("\n".join(_layouts(obj)) or f"  {type(obj).__name__}")
    grounder = ms.grounder()
    print("grounder: " + ("none (model-free prompts only)" if grounder is None else
                          f"QD-SAM3 over {', '.join(grounder.available_sources())}"))
    print("tracker: " + ("SAM2 video (memory bank)" if ms.tracker() is not None else "model-free"))
    if args.image is None:
        return 0
    if grounder is None:
        raise ValidationError("--prompt needs a grounding source in the configuration")
    if not os.path.exists(args.image):
        raise FormatError(f"{args.image}: no such image file (--image)")
    image = read_image(args.image, _rgb, "--image")
    cands = grounder.ground(image, args.prompt)
    if not cands:
        print(f"no candidate for {args.prompt!r}")
        return 0
    print(f"{'rank':>4} {'source':<14} {'total':>6} {'S_src':>6} {'S_conf':>6} {'S_lang':>6} {'pixels':>7}  box")
    for k, c in enumerate(cands):
        box = "-" if c.box is None else ",".join(f"{v:.0f}" for v in c.box)
        print(f"{k:>4} {c.source:<14} {c.score:6.3f} {c.info['S_src']:6.3f} {c.info['S_conf']:6.3f} "
              f"{c.info['S_lang']:6.3f} {int(np.count_nonzero(c.mask)):>7}  {box}")
    print(f"query type: {cands[0].info['query_type']}; seed: rank 0 ({cands[0].source})")
    return 0
