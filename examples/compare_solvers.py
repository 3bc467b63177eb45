"""Compare the inverse solvers on one saved operator stack, with corrupted masks.

A frozen scene turns every camera ``c`` into a fixed sparse operator
``W(c)`` (pixels x Gaussians); extraction is then the inverse problem of
finding ``q in [0, 1]^N`` with ``W(c) q ~ Y(c)`` for the masks ``Y(c)``.
This script:

1. builds one operator per orbit camera around the scene's objects,
2. saves the stack to a directory and loads it back memory-mapped (the
   "build once, solve many times" workflow; ``seed2gs operators build`` and
   ``seed2gs solve`` / ``seed2gs compare`` do the same from the shell),
3. makes exact masks of one object from its true labels, ``W(c) t > 0.5``,
4. corrupts them the way a 2D tracker fails: some views switch to another
   object (``identity_switch``), and the masks drift along the clip,
5. runs every solver with ``sgi.compare`` and prints 2D scores on held-out
   views plus 3D precision/recall against the labels.

No arguments: the built-in procedural scene (its two identical cylinders
make the identity switch realistic)::

    python examples/compare_solvers.py

Real data: insert an object file into a scene file (composites give exact
truth: the inserted Gaussians are the object) and orbit around it; here the
unicorn stands on the firepit's white table::

    python examples/compare_solvers.py --scene firepit.ply --insert unicorn.ply \
        --at 0.93 1.4 -1.22 --height 0.4
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

import seed2gs_inverse as sgi
from seed2gs_inverse import synthetic


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", help="background scene file; default: the procedural scene")
    p.add_argument("--insert", help="with --scene: object scene file to place into it (the truth)")
    p.add_argument("--at", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="with --insert: world point the object stands on (default: the scene's median)")
    p.add_argument("--up", default="0,-1,0", metavar="X,Y,Z",
                   help="world up of --scene and of --insert's own coordinates (default 0,-1,0, COLMAP-like)")
    p.add_argument("--height", type=float, default=0.5, help="with --insert: object height, world units")
    p.add_argument("--views", type=int, default=16, help="orbit cameras (default 16; every 4th is held out)")
    p.add_argument("--size", type=int, nargs=2, default=(128, 96), metavar=("W", "H"),
                   help="image size of each view (default 128 96)")
    p.add_argument("--drift", type=float, default=4.0, help="mask drift in px at the end of the clip (default 4)")
    p.add_argument("--switch", type=float, default=0.25,
                   help="fraction of views whose mask switches to another object (default 0.25)")
    p.add_argument("--methods", help="comma-separated solvers (default: all of sgi.available_methods())")
    p.add_argument("-o", "--output", help="directory for the operators (default: a temporary one, removed at exit)")
    p.add_argument("--plot", help="write the comparison bar chart here (PNG)")
    args = p.parse_args(argv)
    try:
        args.up = [float(v) for v in args.up.split(",")]
    except ValueError:
        args.up = []
    if len(args.up) != 3 or not np.all(np.isfinite(args.up)) or not np.any(args.up):
        p.error("--up must be a non-zero direction X,Y,Z, e.g. 0,-1,0")
    if args.scene and not args.insert:
        p.error("--scene needs --insert OBJECT (the object to find; its Gaussians are the truth)")
    return args


def orbit(center, up, radius, n, width, height, elevation_deg=30.0, fov_y_deg=50.0):
    """``n`` cameras on a circle about ``up`` through ``center``, framing a sphere of ``radius``."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    e1 = np.cross(up, [1.0, 0, 0] if abs(up[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    dist = 1.2 * radius / np.sin(np.radians(fov_y_deg) / 2)
    el = np.radians(elevation_deg)
    cams = []
    for i in range(n):
        az = 2 * np.pi * i / n
        d = np.cos(el) * (np.cos(az) * e1 + np.sin(az) * e2) + np.sin(el) * up
        cams.append(sgi.Camera.look_at(center + dist * d, center, up, fov_y_deg, width, height, name=f"orbit_{i:03d}"))
    return cams


def synthetic_setup(args):
    """Procedural scene; the target is one of a same-class pair, the decoy its twin."""
    syn = sgi.make_scene(seed=0)
    a, b = syn.meta["same_class"][0]  # two identical objects: the classic identity switch
    print(f"procedural scene: {len(syn.scene)} Gaussians; target {syn.names[a]!r}, decoy {syn.names[b]!r}")
    cams = syn.orbit_cameras(args.views, *args.size)
    return syn.scene, cams, syn.labels == a, syn.labels == b


def real_setup(args):
    """Composite: ``--insert`` placed upright on ``--at``; the decoy is a copy beside it."""
    bg, obj = sgi.read_scene(args.scene), sgi.read_scene(args.insert)
    anchor = np.median(bg.means, axis=0) if args.at is None else np.asarray(args.at, float)
    up = np.asarray(args.up, float) / np.linalg.norm(args.up)  # parse_args made it a non-zero 3-vector
    pose = synthetic.pose_on_point(obj, anchor, up, object_up=up, height=args.height, quantile=0.01)
    side = np.cross(up, [1.0, 0, 0] if abs(up[0]) < 0.9 else [0, 1.0, 0])
    side /= np.linalg.norm(side)
    pose2 = synthetic.pose_on_point(obj, anchor + 1.5 * args.height * side, up, object_up=up,
                                    height=args.height, quantile=0.01, yaw_deg=90)
    # remove_overlap clears what the background had where the objects now stand.
    scene, labels = sgi.compose(bg, [(obj, pose), (obj, pose2)], remove_overlap=True)
    print(f"composite: {len(scene)} Gaussians, object {int((labels == 1).sum())}, decoy {int((labels == 2).sum())}")
    center = anchor + 0.5 * args.height * up
    cams = orbit(center, up, 2.0 * args.height, args.views, *args.size)
    return scene, cams, labels == 1, labels == 2


def main(argv=None) -> int:
    args = parse_args(argv)
    scene, cams, truth, decoy = real_setup(args) if args.scene else synthetic_setup(args)

    # 1. One rendering pass per camera gives W(c) (CSR, float32).
    t0 = time.perf_counter()
    views = [sgi.build_operator(scene, c) for c in cams]
    stack = sgi.OperatorStack(views, fingerprint=sgi.scene_fingerprint(scene))
    print(f"built {len(stack)} operators, {stack.n_pixels} pixels x {stack.n_gaussians} Gaussians, "
          f"{stack.nnz} non-zeros, in {time.perf_counter() - t0:.2f} s")

    # 2. Save and reload. Loading validates everything and never unpickles;
    # mmap=True maps the arrays instead of reading them, and scene= checks
    # the operators belong to this scene (fingerprint).
    # Without -o, a temporary directory removed at exit: an example leaves nothing behind.
    tmp = tempfile.TemporaryDirectory(prefix="seed2gs_ops_")
    out = args.output or tmp.name
    stack.save(out, overwrite=True)
    stack = sgi.OperatorStack.load(out, mmap=True, scene=scene)
    print(f"saved and reloaded the stack from {out}")

    # 3. Exact masks: the object's share of each pixel, W(c) t, above 0.5.
    masks = sgi.masks_from_labels(stack, truth)
    decoy_masks = sgi.masks_from_labels(stack, decoy)

    # 4. Tracker failures: identity switches on a fraction of views, then a
    # drift growing linearly along the clip (view 0 exact, the last off by
    # --drift px).
    rng = np.random.default_rng(0)
    noisy, switched = sgi.perturb_masks(masks, "identity_switch", rng=rng, fraction=args.switch,
                                        other_masks=decoy_masks, return_views=True)
    noisy = sgi.perturb_masks(noisy, "drift", rng=rng, strength=args.drift)
    print(f"corrupted masks: identity switch in views {[int(v) for v in switched]}, drift up to {args.drift:g} px")

    # 5. Every solver on the same training views; every 4th view is held out
    # and scored against the exact masks of the labels.
    methods = args.methods.split(",") if args.methods else None
    cmp = sgi.compare(stack, noisy, truth, methods=methods, holdout_every=4)
    print(cmp.format())
    if args.plot:
        cmp.plot(args.plot)
        print(f"wrote {args.plot}")
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
