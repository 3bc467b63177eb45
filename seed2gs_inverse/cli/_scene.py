"""``seed2gs info``, ``seed2gs convert`` and ``seed2gs split``: look at, convert and split scene files."""

from __future__ import annotations

import json
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from .._atomic import atomic_path
from .._output_paths import locks_outputs
from .._validation import check_real
from ..errors import ValidationError
from ..io import detect_format, read_cameras, read_scene, write_scene
from ..io._common import load_npy
from ..io.formats import output_format
from ..io.parts import PART_FORMATS, write_parts
from ..viz import check_membership
from ._common import check_input_file, check_output

__all__ = ["register", "info", "convert", "split"]

_CAMERA_FILES = ("cameras.txt", "images.txt", "cameras.bin", "images.bin")


def register(subparsers) -> None:
    """Add the ``info`` and ``convert`` commands to ``subparsers``."""
    p = subparsers.add_parser(
        "info", help="describe a scene or camera file",
        description="Print a scene file's format, Gaussian count, SH degree, bounds and extra "
                    "properties, or the cameras of a camera file (.json, COLMAP model).")
    p.add_argument("file", metavar="FILE",
                   help="scene (.ply, .compressed.ply, .splat, .spz) or cameras "
                        "(.json, COLMAP cameras/images file or model directory)")
    p.add_argument("--drop-nonfinite", action="store_true",
                   help="drop Gaussians with non-finite values instead of failing")
    p.set_defaults(func=info)

    p = subparsers.add_parser(
        "convert", help="convert a scene between formats",
        description="Read a scene (.ply, .compressed.ply, .splat, .spz) and write it as .ply "
                    "(lossless: a standard PLY input keeps its property list, order and types; "
                    "other inputs get the 3DGS trainer's layout, the 3DGS properties in float32) "
                    "or .splat (lossy: SH degree 0, 8-bit colour and rotation). The output "
                    "appears only once it is complete.")
    p.add_argument("input", metavar="IN", help="input scene file")
    p.add_argument("output", metavar="OUT", help="output scene file (.ply or .splat)")
    p.add_argument("--drop-nonfinite", action="store_true",
                   help="drop Gaussians with non-finite values instead of failing")
    p.add_argument("--force", action="store_true", help="replace OUT if it exists")
    p.set_defaults(func=convert)

    p = subparsers.add_parser(
        "split", help="write object and remainder scenes from a membership q",
        description="Split SCENE by a per-Gaussian membership q (a .npy of N values in [0, 1], e.g. "
                    "q.npy of seed2gs extract or solve): OUTDIR receives object.ply (the Gaussians "
                    "with q > --threshold) and remainder.ply (the others), each in the scene's order "
                    "(a PLY input's property list, order and types kept), and split.json (what was "
                    "split, by which rule). The directory appears only once everything is written.")
    p.add_argument("scene", metavar="SCENE", help="scene file (.ply, .splat, .spz, .compressed.ply)")
    p.add_argument("q", metavar="Q.npy", help="per-Gaussian membership, shape (N,), in [0, 1]")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="output directory (created)")
    p.add_argument("--threshold", type=float, default=0.5, metavar="T",
                   help="the object is q > T, T in [0, 1) (default 0.5, the solvers' default; an "
                        "extraction's own is report.json's threshold)")
    p.add_argument("--format", choices=PART_FORMATS, default="ply", help="object/remainder format (default ply)")
    p.add_argument("--force", action="store_true",
                   help="replace OUTDIR when it is an earlier output of split (a folder of other files is refused)")
    p.set_defaults(func=split)


def _is_camera_path(path: str) -> bool:
    """Whether ``seed2gs info FILE`` reads FILE as cameras: a directory, a .json or a COLMAP file name."""
    p = Path(path)
    return p.is_dir() or p.suffix.lower() == ".json" or p.name.lower() in _CAMERA_FILES


def _print_warnings(command: str, caught) -> None:
    """Each caught warning as one line in the command's voice."""
    for w in caught:
        print(f"seed2gs {command}: warning: {w.message}", file=sys.stderr)


def _fmt(v) -> str:
    """A number with 4 significant digits, as every summary line shows it."""
    return f"{v:.4g}"


def scene_summary(path, scene, fmt: str) -> list:
    """Lines describing a scene file (used by ``seed2gs info``)."""
    lines = [f"file:        {path}",
             f"format:      {fmt}",
             f"size:        {os.path.getsize(path):,} bytes",
             f"gaussians:   {len(scene):,}",
             f"sh degree:   {scene.sh_degree}"]
    if len(scene):
        lo, hi = scene.bounds()
        for axis, a, b in zip("xyz", lo, hi):
            lines.append(f"bounds {axis}:    [{_fmt(a)}, {_fmt(b)}]")
        op = scene.opacities
        lines.append(f"opacity:     median {_fmt(np.median(op))}, "
                     f"{int(np.sum(op < 1 / 255)):,} below 1/255")
    extras = ", ".join(f"{k} ({v.dtype})" for k, v in scene.extra.items()) or "(none)"
    lines.append(f"extra:       {extras}")
    return lines


def camera_summary(path, cams) -> list:
    """Lines describing a camera file (used by ``seed2gs info``)."""
    lines = [f"file:        {path}", f"cameras:     {len(cams)}"]
    for i, c in enumerate(cams):
        centre = ", ".join(_fmt(v) for v in c.center)
        lines.append(f"  {i:3d}  {c.name or '-':<24s} {c.width}x{c.height}  fx={_fmt(c.fx)} "
                     f"fy={_fmt(c.fy)} cx={_fmt(c.cx)} cy={_fmt(c.cy)}  centre=({centre})")
    return lines


def info(args) -> int:
    """``seed2gs info``: print the summary of a scene or camera file."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if _is_camera_path(args.file):
            lines = camera_summary(args.file, read_cameras(args.file))
        else:
            fmt = detect_format(args.file)
            scene = read_scene(args.file, drop_nonfinite=args.drop_nonfinite)
            lines = scene_summary(args.file, scene, fmt)
    _print_warnings("info", caught)
    print("\n".join(lines))
    return 0


@locks_outputs(("output", "OUT"))
def convert(args) -> int:
    """``seed2gs convert``: read a scene and write it in the format of OUT's extension."""
    fmt = output_format(args.output)  # fail before reading a large input
    check_output(args.output, "OUT", force=args.force)
    if os.path.exists(args.output) and os.path.exists(args.input) and os.path.samefile(args.input, args.output):
        raise ValidationError(f"OUT {args.output} is the input file; write the converted scene elsewhere")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = read_scene(args.input, drop_nonfinite=args.drop_nonfinite)
        write_scene(args.output, scene)
    _print_warnings("convert", caught)
    degree = scene.sh_degree if fmt == "ply" else 0
    print(f"wrote {args.output} ({fmt}): {len(scene):,} Gaussians, SH degree {degree}")
    return 0


@locks_outputs(("output", "-o"))
def split(args) -> int:
    """``seed2gs split``: write the object (q > T) and the remainder of a scene, and split.json."""
    threshold = check_real("--threshold", args.threshold, lo=0.0, hi=1.0, hi_open=True)
    out = check_output(args.output, "-o", directory=True, force=args.force, kind="split")
    check_input_file(args.scene, "SCENE")
    check_input_file(args.q, "Q")
    q = load_npy(args.q, f"Q {args.q}")  # a file that is no .npy fails before the scene is read
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = read_scene(args.scene)
    _print_warnings("split", caught)
    check_membership(q, len(scene), f"Q {args.q}")
    selected = q > threshold  # compared in q's own type, as extract selects (float32 q.npy)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with atomic_path(out, directory=True, replace=args.force) as tmp:  # all or nothing
            outputs = write_parts(tmp, scene, selected, args.format, shown=out)
            record = {"command": "split", "scene": os.path.abspath(args.scene), "q": os.path.abspath(args.q),
                      "threshold": threshold, "n_gaussians": len(scene), "n_object": int(selected.sum()),
                      "n_remainder": int(len(scene) - selected.sum()), "outputs": outputs}
            (tmp / "split.json").write_text(json.dumps(record, indent=2), encoding="utf-8")
    _print_warnings("split", caught)
    parts = [f"{out / name} ({record['n_' + part]:,} Gaussians)" for part, name in outputs.items() if name]
    print(f"wrote {' and '.join(parts)}: q > {threshold:g} from {args.q}")
    return 0
