"""``seed2gs demo``: the whole pipeline on a built-in procedural scene with known truth.

The pipeline, the rasterizer and the procedural scenes are imported where
they run, not at the top: they load Numba and its compiled kernels, which
building the ``seed2gs`` parser (every call, ``--help`` included) must not.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from .._output_paths import locks_outputs
from ..camera import Camera
from ..errors import ValidationError
from ..metrics import boundary_iou, iou, membership_scores
from ..pipeline.settings import ExtractSettings
from ..progress import Feedback, StageTimer
from ._common import DEFAULT_VIEWS, add_feedback_arguments, add_method_arguments, check_output, feedback_progress

if TYPE_CHECKING:
    from ..pipeline.extraction import Extraction

__all__ = ["register", "run_demo"]


def register(subparsers) -> None:
    """Add the ``demo`` command to ``subparsers``."""
    p = subparsers.add_parser(
        "demo", help="run the whole pipeline on a built-in procedural scene with a known object",
        description="Build the procedural scene of seed2gs_inverse.synthetic, extract one object "
                    "from a ground-truth seed mask in the reference view, and print its scores "
                    "against the truth on held-out views that the pipeline never rendered.")
    p.add_argument("--seed", type=int, default=0, help="scene seed, >= 0 (default 0)")
    p.add_argument("--object", default="box", help="object name or label to extract (default box)")
    p.add_argument("--views", type=int, default=DEFAULT_VIEWS,
                   help=f"views per VAAS clip, 2..360 (default {DEFAULT_VIEWS}, as seed2gs extract)")
    p.add_argument("--size", type=int, nargs=2, default=(192, 144), metavar=("W", "H"),
                   help="reference image size, each in 16..4096 (default 192 144)")
    add_method_arguments(p, options=False)
    p.add_argument("--summary", action="store_true", help="only print the scene summary")
    p.add_argument("-o", "--output", default=None, metavar="OUTDIR",
                   help="also write the extraction outputs (as seed2gs extract) here; report.json's demo "
                        "section holds these arguments (--from-report does not apply: the scene is generated)")
    p.add_argument("--force", action="store_true", help="replace OUTDIR if it exists")
    add_feedback_arguments(p)
    p.set_defaults(func=run)


def _rounded(values) -> str:
    """``[a, b, c]`` with three decimals (a float32 printed in full shows its binary noise)."""
    return "[" + ", ".join(f"{float(v):.3f}" for v in values) + "]"


def _summary(syn) -> list[str]:
    """Lines describing the procedural scene: size, bounds and every object's Gaussian count."""
    scene, labels = syn.scene, np.asarray(syn.labels)
    lo, hi = scene.bounds()
    lines = [f"procedural scene (seed {syn.seed}): N = {len(scene)} Gaussians, SH degree {scene.sh_degree}",
             f"bounds: min {_rounded(lo)}  max {_rounded(hi)}",
             "objects:"]
    for lab in np.unique(labels):
        name = dict(syn.names).get(int(lab), "background" if lab == 0 else f"object {lab}")
        lines.append(f"  {int(lab):3d}  {name:<20s} {int(np.sum(labels == lab)):7d} Gaussians")
    return lines


def held_out_cameras(center, frame, dist, width, height) -> list[Camera]:
    """Object-centric views at azimuths/elevations that no VAAS view uses."""
    up = frame[:, 2]
    cams = []
    for az, el in [(25, 20), (115, 50), (205, 30), (295, 60), (340, 10)]:
        a, e = np.radians(az), np.radians(el)
        d = np.cos(e) * (np.cos(a) * frame[:, 0] + np.sin(a) * frame[:, 1]) + np.sin(e) * up
        cams.append(Camera.look_at(center + dist * d, center, up, 50, width, height, name=f"held-out {az}/{el}"))
    return cams


def run_demo(seed=0, obj="box", views=DEFAULT_VIEWS, size=(192, 144), method="weighted_bce",
             progress=False) -> tuple[Extraction, dict]:
    """Extract ``obj`` from the procedural scene; returns (extraction, scores dict).

    ``progress`` is :class:`~seed2gs_inverse.pipeline.ExtractSettings`'
    (default False: nothing on stderr); its stages are the scene and its
    seed (``scene``), extract's, and the held-out views (``scoring``).
    """
    from ..pipeline import extract  # deferred: see the module docstring
    from ..raster import build_operator, compile_seconds
    from ..synthetic import make_scene

    settings = ExtractSettings(method=method, n_views=views, progress=progress)  # checks progress too
    feedback = Feedback.of(progress)
    timer = StageTimer(("scene", "scoring"), compile_clock=compile_seconds, feedback=feedback)
    with feedback.active():
        with timer("scene"), feedback.bar("scene", steps=False):
            syn = make_scene(seed=seed)
            label = syn._check_label(obj if not str(obj).isdigit() else int(obj))
            if label == 0:
                raise ValidationError("--object: label 0 is the ground; pick an object")
            truth = syn.labels == label
            cam = syn.reference_camera(int(size[0]), int(size[1]))
            seed_mask = (build_operator(syn.scene, cam).W @ truth.astype(np.float32)).reshape(cam.image_shape) > 0.5
            if not seed_mask.any():
                raise ValidationError(f"--object: {syn.names[label]!r} is not visible in the reference view")
        ex = extract(syn.scene, cam, seed_mask, settings=settings)
        ious, bious = [], []
        held_out = held_out_cameras(syn.centers[label], syn.frame, 4.0 * syn.radii[label], 96, 72)
        with timer("scoring"), feedback.bar("held-out views", total=len(held_out), unit="view") as bar:
            for c in held_out:
                op = build_operator(syn.scene, c)
                t = (op.W @ truth.astype(np.float32)).reshape(op.image_shape) > 0.5
                p = (op.W @ ex.selected.astype(np.float32)).reshape(op.image_shape) > 0.5
                if t.sum() >= 10:
                    ious.append(iou(p, t))
                    bious.append(boundary_iou(p, t))
                bar.update()
    scores = {"object": syn.names[label], "miou": float(np.mean(ious)), "mbiou": float(np.mean(bious)),
              "n_held_out": len(ious), "3d": membership_scores(ex.selected, truth), "syn": syn}
    return ex, scores


@locks_outputs(("output", "-o"))
def run(args) -> int:
    """``seed2gs demo``: extract an object of the procedural scene and print its scores."""
    if args.seed < 0:
        raise ValidationError(f"--seed must be a whole number >= 0, got {args.seed}")
    if not all(16 <= v <= 4096 for v in args.size):  # the procedural scene is small: 16..4096 px suffice
        raise ValidationError(f"--size W H: each must be in 16..4096 pixels, got {args.size[0]} {args.size[1]}")
    if args.output and not args.summary:
        check_output(args.output, "-o", directory=True, force=args.force, kind="extract")  # before the work
    if args.summary:
        from ..synthetic import make_scene  # deferred: see the module docstring

        print("\n".join(_summary(make_scene(seed=args.seed))))
        return 0
    t0 = time.perf_counter()
    ex, sc = run_demo(args.seed, args.object, args.views, args.size, args.method, progress=feedback_progress(args))
    print("\n".join(_summary(sc["syn"])))
    m3 = sc["3d"]
    print(f"extracted '{sc['object']}' from a ground-truth seed ({int(ex.seed_mask.sum())} px) with "
          f"{ex.settings.method}: {int(ex.selected.sum())} Gaussians selected, "
          f"{len(ex.views)} views (V = {ex.vaas.visibility:.2f}, A = {ex.vaas.amplitude_deg:.1f} deg"
          f"{', spiral skipped' if ex.vaas.skipped_spiral else ''})")
    print(f"held-out views ({sc['n_held_out']}, never rendered by the pipeline): "
          f"mIoU {sc['miou']:.3f}  mBIoU {sc['mbiou']:.3f}")
    print(f"3D membership: IoU {m3['iou']:.3f}  precision {m3['precision']:.3f}  recall {m3['recall']:.3f}")
    print("seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in ex.seconds.items() if k != "compile" or v > 0)
          + f"  (extract {ex.total_seconds:.2f}, demo {time.perf_counter() - t0:.2f})")
    if args.output:
        demo = {"seed": args.seed, "object": args.object, "views": args.views,
                "size": f"{args.size[0]} {args.size[1]}", "method": args.method}
        from ..pipeline import save_extraction

        save_extraction(ex, args.output, force=args.force, sections={"demo": demo})
        print(f"wrote {args.output}/")
    return 0
