"""``seed2gs extract``: one object out of a splat file, from one camera and a prompt."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np

from .._atomic import atomic_path
from ..errors import ValidationError

__all__ = ["register", "write_outputs", "settings_from_args"]


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "extract", help="extract one object from a 3DGS scene (Algorithm 1)",
        description="Extract the object a prompt points at in the view of one camera. Writes "
                    "object.ply, remainder.ply, q.npy, report.json and report.png into OUTDIR.")
    p.add_argument("scene", help="scene file (.ply, .splat, .spz, .compressed.ply)")
    p.add_argument("--camera", required=True, metavar="FILE[:NAME|INDEX]",
                   help="reference camera: cameras.json / COLMAP / transforms.json, with :NAME or :INDEX")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--mask", metavar="PNG", help="seed mask image at the camera's resolution (non-zero = object)")
    g.add_argument("--box", nargs=4, type=float, metavar=("X0", "Y0", "X1", "Y1"),
                   help="box around the object in pixels (GrabCut turns it into the seed)")
    g.add_argument("--point", nargs=2, type=float, action="append", metavar=("X", "Y"),
                   help="click on the object (repeatable); see --negative")
    g.add_argument("--prompt", metavar="TEXT", help="text prompt (needs --models)")
    p.add_argument("--negative", nargs=2, type=float, action="append", metavar=("X", "Y"), default=[],
                   help="click on what is NOT the object (with --point; repeatable)")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="output directory (created)")
    p.add_argument("--force", action="store_true", help="replace OUTDIR if it exists")
    p.add_argument("--models", metavar="FILE", default=None,
                   help="models configuration for text prompts / SAM2 tracking (else $SEED2GS_MODELS)")
    p.add_argument("--method", default="weighted_bce", help="solver (default weighted_bce)")
    p.add_argument("--views", type=int, default=24, help="views per VAAS clip (default 24)")
    p.add_argument("--orbit-scale", type=float, default=0.5,
                   help="orbit view resolution relative to the camera (default 0.5)")
    p.add_argument("--threshold", type=float, default=None, help="q threshold (default: the solver's, 0.5)")
    p.add_argument("--format", choices=("ply", "splat"), default="ply", help="object/remainder format")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def _prompt_from_args(args):
    from ..frontend.prompts import TEXT_NEEDS_GROUNDER, BoxPrompt, MaskPrompt, PointPrompt, TextPrompt

    if args.negative and args.point is None:
        raise ValidationError("--negative clicks need at least one --point")
    if args.mask is not None:
        if not os.path.isfile(args.mask):
            raise FileNotFoundError(2, "No such file", args.mask)
        return MaskPrompt(args.mask)
    if args.box is not None:
        return BoxPrompt(args.box)
    if args.point is not None:
        pts = list(args.point) + list(args.negative)
        return PointPrompt(pts, [1] * len(args.point) + [0] * len(args.negative))
    if not args.prompt.strip():
        raise ValidationError("--prompt is empty")
    if args.models is None and not os.environ.get("SEED2GS_MODELS"):
        raise ValidationError(TEXT_NEEDS_GROUNDER)
    return TextPrompt(args.prompt)


def _models(args):
    try:
        from ..frontend.config import resolve_models
    except ImportError:  # pragma: no cover - the ONNX front end is optional
        if args.models is not None:
            raise ValidationError("--models needs the ONNX front end (seed2gs_inverse.frontend.config)")
        return None
    return resolve_models(args.models)


def write_outputs(extraction, outdir, fmt: str = "ply", force: bool = False, figure: bool = True) -> Path:
    """Write object/remainder scenes, q.npy, report.json (and report.png) into ``outdir``.

    Everything goes to a temporary directory next to ``outdir`` that is
    renamed at the end, so a failure leaves no partial output.
    """
    from ..io import write_scene

    out = Path(outdir)
    if out.exists() and not force:
        raise ValidationError(f"output directory {out} exists; use --force to replace it")
    parent = out.resolve().parent
    if not parent.is_dir():
        raise ValidationError(f"cannot create {out}: parent directory {parent} does not exist")
    with atomic_path(out, directory=True) as tmp:
        write_scene(tmp / f"object.{fmt}", extraction.object_scene())
        write_scene(tmp / f"remainder.{fmt}", extraction.remainder_scene())
        np.save(tmp / "q.npy", np.asarray(extraction.q, np.float32), allow_pickle=False)
        report = extraction.report()
        report["outputs"] = {"object": f"object.{fmt}", "remainder": f"remainder.{fmt}", "q": "q.npy"}
        with open(tmp / "report.json", "w") as fh:
            json.dump(report, fh, indent=2)
        if figure:
            from ..pipeline.report import report_figure

            report_figure(extraction).savefig(tmp / "report.png", dpi=100)
    return out


def settings_from_args(args):
    """The :class:`~seed2gs_inverse.pipeline.ExtractSettings` of the command line (validated)."""
    from ..pipeline import ExtractSettings

    if args.views < 2:
        raise ValidationError(f"--views must be >= 2, got {args.views}")
    if args.threshold is not None and not 0.0 <= args.threshold < 1.0:
        raise ValidationError(f"--threshold must be in [0, 1), got {args.threshold}")
    if not args.orbit_scale > 0:
        raise ValidationError(f"--orbit-scale must be positive, got {args.orbit_scale}")
    from ..solvers import available_methods

    if args.method not in available_methods():
        raise ValidationError(f"unknown --method {args.method!r}; available: {', '.join(available_methods())}")
    return ExtractSettings(method=args.method, n_views=args.views, orbit_scale=args.orbit_scale,
                           threshold=args.threshold, progress=False if args.no_progress else None)


def run(args) -> int:
    from ..io import read_camera, read_scene
    from ..pipeline import extract

    # Validate everything cheap before the expensive work.
    out = Path(args.output)
    if out.exists() and not args.force:
        raise ValidationError(f"output directory {out} exists; use --force to replace it")
    if not out.resolve().parent.is_dir():
        raise ValidationError(f"cannot create {out}: parent directory {out.resolve().parent} does not exist")
    settings = settings_from_args(args)
    if not os.path.isfile(args.scene):
        raise FileNotFoundError(2, "No such file", args.scene)
    prompt = _prompt_from_args(args)
    camera = read_camera(args.camera)
    models = _models(args)
    grounder = models.grounder() if models is not None else None
    tracker = models.tracker() if models is not None else None
    if grounder is None and args.prompt is not None:
        from ..frontend.prompts import TEXT_NEEDS_GROUNDER

        raise ValidationError(TEXT_NEEDS_GROUNDER)
    scene = read_scene(args.scene)
    ex = extract(scene, camera, prompt, grounder=grounder, tracker=tracker, settings=settings)
    write_outputs(ex, out, args.format, force=args.force)
    s = ex.seconds
    print(f"extracted {int(ex.selected.sum())} of {len(scene)} Gaussians -> {out}/object.{args.format} "
          f"({len(ex.views)} views, {ex.total_seconds:.1f} s: "
          + ", ".join(f"{k} {v:.2f}" for k, v in s.items()) + ")")
    if models is None:  # with models, SAM2 would have tracked even a mask/box/point seed
        print("note: no models configured; the seed was tracked by the model-free tracker",
              file=sys.stderr)
    return 0
