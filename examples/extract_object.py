"""Extract one object from a 3DGS scene with a box or click prompt.

The whole method (Algorithm 1 of the paper) is one call, ``sgi.extract``:
render the reference view, turn the prompt into a seed mask, lift it to 3D,
plan orbit views around it (VAAS), propagate the mask along them, build one
sparse operator per view and solve for a per-Gaussian probability ``q``.

Run it with no arguments on the built-in procedural scene (a box prompt is
drawn around a known object, so the result can be scored against the truth)::

    python examples/extract_object.py

or on your own scene and camera::

    python examples/extract_object.py --scene firepit.ply \
        --camera firepit_cameras.json:overview --box 533 276 645 368 -o out/

``--point X Y`` (repeatable) clicks on the object instead of a box, and
``--screenshot q.png`` draws the membership with pyvista (off-screen: set
VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow when there is no display).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

import seed2gs_inverse as sgi
from seed2gs_inverse.pipeline import ExtractSettings


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", help="scene file (.ply, .splat, .spz, .compressed.ply); "
                                   "default: the built-in procedural scene")
    p.add_argument("--camera", help="reference camera FILE:NAME or FILE:INDEX (needed with --scene)")
    p.add_argument("--box", type=float, nargs=4, metavar=("X0", "Y0", "X1", "Y1"),
                   help="box around the object, pixels of the reference camera")
    p.add_argument("--point", type=float, nargs=2, action="append", metavar=("X", "Y"),
                   help="click on the object (repeatable)")
    p.add_argument("--object", default="box", help="synthetic mode: which object to extract (default box)")
    p.add_argument("--size", type=int, nargs=2, default=(192, 144), metavar=("W", "H"),
                   help="synthetic mode: reference image size (default 192 144)")
    views = ExtractSettings().n_views  # the default of extract(), seed2gs extract and seed2gs demo
    p.add_argument("--views", type=int, default=views, help=f"views per VAAS clip (default {views}, the paper's)")
    p.add_argument("-o", "--output", help="directory for object.ply / remainder.ply / q.npy "
                                          "(default: a temporary directory, removed at exit)")
    p.add_argument("--screenshot", help="also write a pyvista PNG of the membership q")
    args = p.parse_args(argv)
    if args.scene and not args.camera:
        p.error("--scene needs --camera FILE:NAME")
    if args.scene and not (args.box or args.point):
        p.error("--scene needs a prompt: --box X0 Y0 X1 Y1 or --point X Y")
    return args


def synthetic_inputs(args):
    """The procedural scene, a reference camera and a box around one object.

    The box is what a user would drag: the bounding box of the object's
    pixels in the reference view. Those pixels are the exact ground truth,
    the object's rendered weight ``W(c) t > 0.5`` for the 0/1 labels ``t``.
    """
    syn = sgi.make_scene(seed=0)
    truth = syn.object_mask(args.object)
    camera = syn.reference_camera(*args.size)
    op = sgi.build_operator(syn.scene, camera)
    visible = op.image(truth.astype(np.float32)) > 0.5
    ys, xs = np.nonzero(visible)
    box = (xs.min() - 2, ys.min() - 2, xs.max() + 3, ys.max() + 3)  # exclusive max, a little slack
    print(f"procedural scene: {len(syn.scene)} Gaussians; extracting {args.object!r} "
          f"({int(truth.sum())} Gaussians) with box {[int(b) for b in box]}")
    return syn.scene, camera, sgi.BoxPrompt(box), truth


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.scene:
        t0 = time.perf_counter()
        scene = sgi.read_scene(args.scene)
        camera = sgi.read_camera(args.camera)
        print(f"read {len(scene)} Gaussians (SH degree {scene.sh_degree}) in {time.perf_counter() - t0:.1f} s; "
              f"camera {camera.name!r} {camera.width}x{camera.height}")
        # Clicks win over a box when both are given: they are the more specific prompt.
        prompt = sgi.PointPrompt(args.point) if args.point else sgi.BoxPrompt(args.box)
        truth = None
    else:
        scene, camera, prompt, truth = synthetic_inputs(args)
        if args.point:
            prompt = sgi.PointPrompt(args.point)

    # One call; every intermediate (seed mask, views, masks, operators,
    # solver result, per-stage seconds) comes back in the Extraction.
    ex = sgi.extract(scene, camera, prompt, n_views=args.views, progress=False)

    print("seconds per stage:")
    for stage, s in ex.seconds.items():
        print(f"  {stage:<10s} {s:7.2f}")
    print(f"  {'total':<10s} {ex.total_seconds:7.2f}")
    print(f"seed mask: {int(ex.seed_mask.sum())} px; {len(ex.views)} supervision views; "
          f"solver {ex.result.method} ({ex.result.iterations} iterations)")
    print(f"selected {int(ex.selected.sum())} of {len(scene)} Gaussians (q > {ex.threshold:g})")
    if truth is not None:
        # 3D scores against the procedural scene's exact labels.
        s = sgi.membership_scores(ex.selected, truth)
        print("3D vs truth: " + ", ".join(f"{k} {v:.3f}" for k, v in s.items()
                                          if isinstance(v, float)))

    # Without -o the files go to a temporary directory that is removed at
    # exit: an example leaves nothing behind unless asked to.
    with tempfile.TemporaryDirectory(prefix="seed2gs_extract_") as tmp:
        out = args.output or tmp
        os.makedirs(out, exist_ok=True)
        sgi.write_scene(os.path.join(out, "object.ply"), ex.object_scene())
        sgi.write_scene(os.path.join(out, "remainder.ply"), ex.remainder_scene())
        np.save(os.path.join(out, "q.npy"), ex.q)
        print(f"wrote object.ply, remainder.ply and q.npy to {out}"
              + ("" if args.output else " (temporary, removed at exit; pass -o DIR to keep them)"))

    if args.screenshot:
        from seed2gs_inverse import viz

        # Seen from the reference camera, so the picture matches the prompt.
        viz.membership_plot(scene, ex.q, screenshot=args.screenshot, camera=camera, min_opacity=0.05)
        print(f"wrote {args.screenshot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
