"""``seed2gs view``: look at a scene and a membership with pyvista."""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from .._atomic import atomic_path
from ..errors import ValidationError
from ..io import read_camera, read_cameras, read_scene
from ..io._common import load_npy
from .. import viz  # its functions are looked up when the command runs: tests replace them
from ._common import check_output, parse_size, parse_vector

__all__ = ["register"]


class _UsageFormatter(argparse.HelpFormatter):
    """Shows ``--up X,Y,Z``: it takes one vector (three numbers as three words only for the deprecated form)."""

    def _format_args(self, action, default_metavar):
        if action.dest == "up":
            return "X,Y,Z"
        return super()._format_args(action, default_metavar)


def register(subparsers) -> None:
    """Add the ``view`` command to ``subparsers``."""
    p = subparsers.add_parser(
        "view", help="show a scene's Gaussians coloured by membership (pyvista)", formatter_class=_UsageFormatter,
        description="Show the Gaussians of SCENE as points or ellipsoids, coloured by a "
                    "membership q (a .npy of N values in [0, 1]) or by their own colour. "
                    "Opens a window, or writes a PNG with --screenshot (required when there "
                    "is no display; rendering is then off-screen through EGL).")
    p.add_argument("scene", metavar="SCENE", help="scene file (.ply, .splat, .spz, .compressed.ply)")
    p.add_argument("--membership", metavar="Q.npy", help="per-Gaussian membership, shape (N,), in [0, 1]")
    p.add_argument("--threshold", type=float, default=None, metavar="T",
                   help="show only Gaussians with q > T (needs --membership)")
    p.add_argument("--mode", choices=("points", "ellipsoids"), default="points",
                   help="points (all Gaussians) or ellipsoid glyphs (capped by --max-glyphs)")
    p.add_argument("--max-glyphs", type=int, default=20000, metavar="N",
                   help="most ellipsoids to draw; a random subset beyond (default 20000)")
    p.add_argument("--point-size", type=float, default=3.0, help="point size in pixels (default 3)")
    p.add_argument("--min-opacity", type=float, default=0.0, metavar="O",
                   help="hide Gaussians with opacity below O (default 0: show all)")
    p.add_argument("--camera", metavar="FILE[:NAME|INDEX]", help="view from this camera of a camera file "
                   "(3DGS cameras.json, COLMAP, nerfstudio transforms.json); FILE alone: its first camera")
    p.add_argument("--view", default=None, metavar="NAME|INDEX",
                   help="deprecated: write --camera FILE:NAME")
    p.add_argument("--up", nargs="+", default=None, metavar="X,Y,Z",
                   help="without --camera: world direction shown upwards (default 0,-1,0, the usual up "
                        "of COLMAP-trained scenes, as in render --look-at)")
    p.add_argument("--size", default=None, metavar="WxH",
                   help="window/screenshot size (default: the camera's, else 1024x768)")
    p.add_argument("--screenshot", metavar="OUT.png", help="write a PNG instead of opening a window")
    p.add_argument("--force", action="store_true", help="replace OUT.png if it exists")
    p.set_defaults(func=run)


def _read_scene(path):
    """The scene of ``SCENE``; one function, so that tests can give ``run`` a scene in memory."""
    return read_scene(path)


def _camera(spec, view):
    """The camera of ``--camera FILE[:NAME|INDEX]`` (FILE alone: the first), or of the old ``--view``."""
    if view is not None:
        print(f"seed2gs view: note: '--camera FILE --view {view}' is deprecated; write --camera FILE:{view}",
              file=sys.stderr)
        return _pick_camera(read_cameras(spec), view)
    if os.path.exists(spec) or ":" not in spec:
        return _pick_camera(read_cameras(spec), None)
    return read_camera(spec)


def _load_membership(path, n: int) -> np.ndarray:
    """``--membership Q.npy`` as (n,) values in [0, 1], or a ValidationError naming the file."""
    return viz.check_membership(load_npy(path, f"--membership {path}"), n, f"--membership {path}")


def _pick_camera(cams, which):
    """The camera named or indexed by ``which`` in ``cams`` (the first when None)."""
    if not cams:
        raise ValidationError("--camera: the file holds no cameras")
    if which is None:
        return cams[0]
    for cam in cams:
        if cam.name == which:
            return cam
    if which.lstrip("-").isdigit() and -len(cams) <= int(which) < len(cams):
        return cams[int(which)]
    names = ", ".join(repr(c.name) for c in cams[:10])
    raise ValidationError(f"--view {which!r}: no such camera name or index; "
                          f"{len(cams)} cameras: {names}{', ...' if len(cams) > 10 else ''}")


def _plot(scene, q, **kw):
    """``viz.membership_plot``, its warnings naming the command's options instead of its arguments."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = viz.membership_plot(scene, q, **kw)
    for w in caught:
        warnings.warn(str(w.message).replace("max_glyphs", "--max-glyphs"), w.category, stacklevel=3)
    return result


def run(args) -> int:
    """``seed2gs view``: open a window, or write ``--screenshot`` off-screen."""
    if args.threshold is not None and args.membership is None:
        raise ValidationError("--threshold needs --membership")
    if args.view is not None and args.camera is None:
        raise ValidationError("--view needs --camera")
    if args.up is not None and args.camera is not None:
        raise ValidationError("--up applies without --camera only (a camera fixes the view's up); drop one")
    if args.screenshot is None and not viz.has_display():
        raise ValidationError("no display to open a window on; pass --screenshot OUT.png")
    if args.screenshot is not None and Path(args.screenshot).suffix.lower() != ".png":
        raise ValidationError(f"--screenshot {args.screenshot}: the file name must end in .png")
    out = None if args.screenshot is None else check_output(args.screenshot, "--screenshot", force=args.force)
    size = None if args.size is None else parse_size("--size", args.size, limit=8192)  # a window
    # without a camera, the same default up as render --look-at (VTK's own, +z, shows these scenes upside down)
    up = None if args.camera is not None else [0.0, -1.0, 0.0] if args.up is None else \
        parse_vector("--up", args.up[0] if len(args.up) == 1 else args.up).tolist()
    viz.require_pyvista()  # the 'view' extra: said before the scene is read
    camera = None if args.camera is None else _camera(args.camera, args.view)
    scene = _read_scene(args.scene)
    q = None if args.membership is None else _load_membership(args.membership, len(scene))
    kw = dict(mode=args.mode, threshold=args.threshold, camera=camera, max_glyphs=args.max_glyphs,
              point_size=args.point_size, min_opacity=args.min_opacity, window_size=size, up=up)
    if out is None:
        _plot(scene, q, off_screen=False, **kw).show()
        return 0
    with atomic_path(out, replace=args.force) as tmp:  # a failure leaves nothing behind
        img = _plot(scene, q, screenshot=str(tmp), off_screen=True, **kw)
    # the Gaussians membership_plot draws: above --min-opacity, with --threshold q above it, and as
    # ellipsoids at most --max-glyphs of those (a random subset, which it warns about)
    keep = scene.opacities >= args.min_opacity if args.min_opacity > 0 else np.ones(len(scene), bool)
    if q is not None and args.threshold is not None:
        keep &= q > args.threshold
    n = int(keep.sum()) if args.mode != "ellipsoids" else min(int(keep.sum()), int(args.max_glyphs))
    shown = "all" if n == len(scene) else f"{n:,}"
    print(f"wrote {out} ({img.shape[1]}x{img.shape[0]}, {len(scene)} Gaussians, shown: {shown})")
    return 0
