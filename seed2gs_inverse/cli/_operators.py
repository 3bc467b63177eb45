"""``seed2gs operators build`` and ``seed2gs operators info``: saved per-view operators."""

from __future__ import annotations

import argparse
import sys

from tqdm import tqdm

from .._output_paths import locks_outputs
from .._validation import as_real
from ..errors import ValidationError
from ..io import read_cameras, read_scene
from ..operators import OperatorStack, scene_fingerprint
from ._common import check_output, progress_enabled, scaled_size

__all__ = ["register", "build", "info"]


class _DeprecatedOverwrite(argparse.Action):
    """``--overwrite``: the former spelling of ``--force``; sets it and says so on stderr."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest=argparse.SUPPRESS, nargs=0, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print("seed2gs operators build: note: '--overwrite' is deprecated; write --force", file=sys.stderr)
        namespace.force = True


def register(subparsers) -> None:
    """Add ``operators build`` and ``operators info`` to ``subparsers``."""
    p = subparsers.add_parser(
        "operators", help="build or describe saved per-view operators",
        description="Per-view sparse operators W (pixels x Gaussians) of a frozen scene, saved as a "
                    "directory (manifest.json + one .npy per array) that solvers load later.")
    sub = p.add_subparsers(dest="operators_command", metavar="SUBCOMMAND")
    sub.required = True

    b = sub.add_parser(
        "build", help="render every camera once and save the operators",
        description="Rasterize SCENE from every camera of --cameras, keep each view's compositing "
                    "weights W as a sparse operator and save the stack to DIR. The directory "
                    "appears only once it is complete.")
    b.add_argument("scene", metavar="SCENE", help="scene file (.ply, .compressed.ply, .splat, .spz)")
    b.add_argument("--cameras", required=True, metavar="FILE",
                   help="cameras (3DGS cameras.json, COLMAP model, nerfstudio transforms.json)")
    b.add_argument("-o", "--output", required=True, metavar="DIR", help="output operator directory")
    b.add_argument("--scale", type=float, default=1.0,
                   help="resolution factor relative to the cameras, in (0, 4] (default 1.0)")
    b.add_argument("--min-weight", type=float, default=0.0,
                   help="drop weights below this, in [0, 1] (default 0: keep all)")
    b.add_argument("--force", action="store_true", help="replace an existing operator directory")
    b.add_argument("--overwrite", action=_DeprecatedOverwrite, help=argparse.SUPPRESS)
    b.add_argument("--no-progress", action="store_true",
                   help="no progress bar (shown only when stderr is a terminal)")
    b.set_defaults(func=build)

    i = sub.add_parser("info", help="describe an operator directory",
                       description="Validate an operator directory and print its views.")
    i.add_argument("directory", metavar="DIR", help="operator directory (seed2gs operators build)")
    i.add_argument("--scene", metavar="SCENE", help="also check that the operators belong to this scene")
    i.set_defaults(func=info)


@locks_outputs(("output", "-o"))
def build(args) -> int:
    """``seed2gs operators build``: render every camera once and save the operator stack."""
    # Deferred: the rasterizer loads Numba and its compiled kernels, which `seed2gs --help`
    # (importing this module to build the parser) must not pay for.
    from ..raster import build_operator

    scale = as_real(args.scale)
    if scale is None or not 0 < scale <= 4:  # x4 already turns 1080p into 8K views
        raise ValidationError(f"--scale must be in (0, 4], got {args.scale}")
    if not 0 <= args.min_weight <= 1:  # NaN fails too; checked before anything is read
        raise ValidationError(f"--min-weight must be in [0, 1], got {args.min_weight}")
    check_output(args.output, "-o", directory=True, force=args.force, kind="operators")  # fail before rendering anything
    OperatorStack.check_target(args.output, args.force)
    cameras = read_cameras(args.cameras)
    if not cameras:
        raise ValidationError(f"{args.cameras}: no cameras")
    for cam in cameras:  # every view's size, before the scene is read
        scaled_size(cam, args.scale)
    scene = read_scene(args.scene)
    views = []
    items = cameras
    if progress_enabled(args.no_progress):
        items = tqdm(cameras, desc="operators", unit="view", file=sys.stderr, leave=False)
    for cam in items:
        views.append(build_operator(scene, cam, scale=args.scale, min_weight=args.min_weight))
    stack = OperatorStack(views, fingerprint=scene_fingerprint(scene))
    stack.save(args.output, overwrite=args.force)
    print(f"{args.output}: {len(stack)} views, {stack.n_gaussians:,} Gaussians, {stack.nnz:,} weights, "
          f"{int(stack.observed().sum()):,} Gaussians observed")
    return 0


def info(args) -> int:
    """``seed2gs operators info``: check an operator directory and print its views."""
    scene = None
    if args.scene:
        scene = read_scene(args.scene)
    stack = OperatorStack.load(args.directory, mmap=True, scene=scene)
    observed = stack.observed()
    lines = [f"directory:   {args.directory}",
             f"views:       {len(stack)}",
             f"gaussians:   {stack.n_gaussians:,} ({int(observed.sum()):,} observed)",
             f"weights:     {stack.nnz:,} ({stack.nnz * 8 / 2**20:.1f} MiB)",
             f"fingerprint: {stack.fingerprint}" + ("  (matches the scene)" if scene is not None else "")]
    for k, v in enumerate(stack):
        h, w = v.image_shape
        lines.append(f"  {k:3d}  {v.name or '-':<24s} {w}x{h}  nnz={v.nnz:,}  "
                     f"mean alpha={float(v.alpha().mean()):.3f}  observed={int(v.observed().sum()):,}")
    print("\n".join(lines))
    return 0
