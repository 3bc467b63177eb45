"""``seed2gs eval``: benchmark protocols in one command (``eval lerf-mask``, ``eval 3d-ovs``)."""

from __future__ import annotations

import sys
from pathlib import Path

from .._validation import check_int
from ..evaluation import evaluate_3d_ovs, evaluate_lerf_mask
from ..pipeline.settings import LIMITS
from ..solvers import available_methods
from ._batch import add_cluster_arguments, client_from_args
from ._common import add_feedback_arguments, feedback_progress

__all__ = ["register"]

_LAYOUTS = {
    "lerf-mask": "DATA_DIR/<scene>/test_mask/<frame>/<query>.png with the scene's COLMAP model or cameras.json",
    "3d-ovs": "DATA_DIR/<scene>/segmentations/classes.txt and segmentations/<NN>/<class>.png, NN the "
              "image's number in the sorted images/, with the scene's COLMAP model in sparse/",
}


def _add_arguments(q, name: str) -> None:
    """The arguments of one ``seed2gs eval BENCHMARK`` (``name``: its dataset layout)."""
    q.add_argument("data", metavar="DATA_DIR", help="dataset root (one folder per scene)")
    q.add_argument("--scenes", required=True, metavar="SCENE_DIR", help="trained 3DGS scenes")
    q.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="report directory (created)")
    seed = q.add_mutually_exclusive_group(required=True)
    seed.add_argument("--oracle-seed", action="store_true",
                      help="seed each query with its ground-truth mask in its first annotated frame")
    seed.add_argument("--models", metavar="FILE",
                      help="models configuration (docs/models.md): ground each query's text in the first "
                           "test frame; the file is checked before anything runs")
    q.add_argument("--only", nargs="+", metavar="SCENE", default=None, help="evaluate only these scenes")
    q.add_argument("--views", type=int, default=None, help="views per VAAS clip, 2..360 (default: extract's, 24)")
    methods = available_methods()
    q.add_argument("--method", default=None, choices=methods, metavar="METHOD",
                   help=f"solver: {', '.join(methods)} (default: extract's, weighted_bce)")
    add_cluster_arguments(q)
    q.add_argument("--no-resume", action="store_true", help="extract every query again")
    add_feedback_arguments(q, "job")
    q.set_defaults(func=run_eval, eval_layout=name)


def register(subparsers) -> None:
    """Add ``seed2gs eval lerf-mask`` and ``seed2gs eval 3d-ovs`` to the command's subparsers."""
    p = subparsers.add_parser("eval", help="evaluate on a benchmark (LERF-Mask, 3D-OVS)",
                              description="Score extraction on a benchmark dataset.")
    sub = p.add_subparsers(dest="eval_command", metavar="BENCHMARK")
    sub.required = True
    q = sub.add_parser(
        "lerf-mask", help="LERF-Mask: mIoU / mBIoU per query and scene (Gaussian Grouping protocol)",
        description="Extract every query of a LERF-Mask style dataset (" + _LAYOUTS["lerf-mask"] + ") from "
                    "the trained scenes in SCENE_DIR (<scene>.ply or the 3DGS trainer's output folder), "
                    "render it into every test view and write per-query and per-scene tables (CSV, "
                    "JSON) and a PNG grid into OUTDIR. Runs on the batch runner (Dask).")
    _add_arguments(q, "lerf-mask")
    q = sub.add_parser(
        "3d-ovs", help="3D-OVS layout: every class as one object, scored as LERF-Mask queries",
        description="The lerf-mask evaluation on a 3D-OVS style dataset (" + _LAYOUTS["3d-ovs"] + "). "
                    "Each class is extracted as one object and scored with IoU / boundary IoU in the "
                    "frames where its mask is not empty (not 3D-OVS's semantic-segmentation mIoU).")
    _add_arguments(q, "3d-ovs")


def run_eval(args) -> int:
    """Run ``seed2gs eval``: print the per-scene table, and each failed job on stderr; 1 when a job failed."""
    client = client_from_args(args)
    options = {}
    if args.views is not None:
        lo, hi = LIMITS["n_views"]  # ExtractSettings' range, said with the option's name
        options["n_views"] = check_int("--views", args.views, lo=lo, hi=hi)
    if args.method is not None:
        options["method"] = args.method
    evaluate = evaluate_3d_ovs if args.eval_layout == "3d-ovs" else evaluate_lerf_mask
    report = evaluate(args.data, args.scenes, args.output, oracle_seed=args.oracle_seed or None,
                      models=args.models, options=options, scenes=args.only, client=client,
                      n_workers=args.workers, resume=not args.no_resume,
                      progress=feedback_progress(args),
                      log=None if args.quiet else (lambda msg: print(msg, file=sys.stderr)))
    print(f"{'scene':<20} {'mIoU':>7} {'mBIoU':>7}  queries")
    for s in report["scenes"]:
        print(f"{s['scene']:<20} {100 * s['miou']:7.1f} {100 * s['mbiou']:7.1f}  {s['n_queries']}"
              + (f" ({s['n_failed']} failed)" if s["n_failed"] else ""))
    o = report["overall"]
    print(f"{'overall':<20} {100 * o['miou']:7.1f} {100 * o['mbiou']:7.1f}  -> {Path(args.output) / 'per_query.csv'}")
    for name, err in report["failed"].items():
        print(f"  failed {name}: {err}", file=sys.stderr)
    return 1 if report["failed"] else 0
