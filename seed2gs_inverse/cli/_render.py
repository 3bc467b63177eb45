"""``seed2gs render``: rasterize a scene from a camera to image files."""

from __future__ import annotations

import io as _io
import time
from pathlib import Path

import numpy as np
from PIL import Image

from .._atomic import write_files
from .._output_paths import locks_outputs
from .._validation import as_real
from ..camera import Camera
from ..errors import ValidationError
from ..io import read_camera, read_scene
from ._common import check_output, format_vector, look_at_camera, parse_point, scaled_size

__all__ = ["register"]

_EXTS = (".png", ".npy")


def register(subparsers) -> None:
    """Add the ``render`` command to ``subparsers``."""
    p = subparsers.add_parser(
        "render", help="render a scene from a camera (PNG or .npy)",
        description="Render SCENE with the tile rasterizer from a camera of a camera file "
                    "(--camera FILE[:NAME|INDEX]) or from --look-at EYE TARGET. Writes the "
                    "colour image and, on request, the expected depth and the alpha. PNG "
                    "files are 8-bit (depth: 16-bit, scaled linearly from the nearest to the "
                    "farthest covered pixel, 0 where nothing is drawn); .npy files hold the "
                    "float32 values.")
    p.add_argument("scene", metavar="SCENE", help="scene file (.ply, .splat, .spz, .compressed.ply)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--camera", metavar="FILE[:NAME|INDEX]",
                     help="camera file (3DGS cameras.json, COLMAP, nerfstudio) and which camera")
    src.add_argument("--look-at", nargs=2, metavar=("EYE", "TARGET"),
                     help="camera position and the point it looks at, each 'x,y,z'")
    p.add_argument("--up", default=None, metavar="X,Y,Z",
                   help="with --look-at: the camera's up, the world direction shown upwards in the image "
                        "(default 0,-1,0, the usual up of COLMAP-trained scenes; printed with the result). "
                        "Not an orbit axis: seed2gs extract calls this --look-up, and its --up is the axis "
                        "its virtual cameras circle around")
    p.add_argument("--fov", type=float, default=None, metavar="DEG",
                   help="with --look-at: vertical field of view in degrees (default 60)")
    p.add_argument("--size", default=None, metavar="WxH",
                   help="with --look-at: image size (default 960x540)")
    p.add_argument("--scale", type=float, default=1.0, metavar="F",
                   help="render at F times the camera's resolution (default 1)")
    p.add_argument("--near", type=float, default=None, metavar="Z",
                   help="near plane: Gaussians closer than Z are not drawn (default: the camera's, 0.01)")
    p.add_argument("--background", default="0,0,0", metavar="R,G,B",
                   help="background colour in [0, 1] (default black)")
    p.add_argument("--mode", choices=("classic", "antialiased"), default="classic",
                   help="rasterization mode (default classic = reference 3DGS)")
    p.add_argument("-o", "--output", required=True, metavar="IMAGE",
                   help="colour image, .png or .npy (float32 H x W x 3)")
    p.add_argument("--depth", metavar="FILE", help="also write the expected depth (.png or .npy)")
    p.add_argument("--alpha", metavar="FILE", help="also write the alpha (.png or .npy)")
    p.add_argument("--force", action="store_true", help="replace output files that exist")
    p.set_defaults(func=run)


def _camera(args) -> Camera:
    """The camera to render from: ``--camera`` or ``--look-at``, then ``--near`` and ``--scale``."""
    if args.camera is not None:
        given = [f"--{k}" for k in ("size", "fov", "up") if getattr(args, k) is not None]
        if given:  # they would be ignored: the camera file fixes size, field of view and orientation
            raise ValidationError(f"{', '.join(given)} go with --look-at; with --camera the camera file gives "
                                  f"them (--scale changes the resolution)")
        cam = read_camera(args.camera)
    else:
        cam = look_at_camera(args.look_at, args.up, args.fov, args.size)
    if args.near is not None:
        cam = Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, cam.world_to_camera,
                     cam.name, args.near)
    if args.scale != 1.0:
        scaled_size(cam, args.scale)
        cam = cam.scaled(args.scale)
    return cam


def _check_output(option, path, force=False):
    """``path`` as a Path ending in .png or .npy that the command may write (None stays None)."""
    if path is None:
        return None
    p = Path(path)
    if p.suffix.lower() not in _EXTS:
        raise ValidationError(f"{option} {path}: the file name must end in .png or .npy")
    return check_output(p, option, force=force)


def _encode(path, array, kind):
    """Bytes of the file for ``array``: .npy as is, .png quantised per ``kind``."""
    buf = _io.BytesIO()
    if path.suffix.lower() == ".npy":
        np.save(buf, np.ascontiguousarray(array, dtype=np.float32), allow_pickle=False)
        return buf.getvalue()
    if kind == "depth":
        depth, alpha = array
        covered = alpha > 0
        img = np.zeros(depth.shape, np.uint16)
        if covered.any():
            lo, hi = float(depth[covered].min()), float(depth[covered].max())
            span = hi - lo if hi > lo else 1.0
            img[covered] = np.round(1 + (depth[covered] - lo) / span * 65534).astype(np.uint16)
        Image.fromarray(img).save(buf, format="PNG")
    else:
        img = np.round(np.clip(array, 0, 1) * 255).astype(np.uint8)
        Image.fromarray(img).save(buf, format="PNG")
    return buf.getvalue()


@locks_outputs(("output", "-o"), ("depth", "--depth"), ("alpha", "--alpha"))
def run(args) -> int:
    """``seed2gs render``: rasterize the scene from one camera and write the requested images."""
    # Deferred: the rasterizer loads Numba and its compiled kernels, which `seed2gs --help`
    # (importing this module to build the parser) must not pay for.
    from ..raster import render

    out = _check_output("-o", args.output, args.force)
    depth_path = _check_output("--depth", args.depth, args.force)
    alpha_path = _check_output("--alpha", args.alpha, args.force)
    paths = [p for p in (out, depth_path, alpha_path) if p is not None]
    if len({p.resolve() for p in paths}) != len(paths):
        raise ValidationError("-o, --depth and --alpha must name different files")
    bg = parse_point("--background", args.background)
    if bg.min() < 0 or bg.max() > 1:
        raise ValidationError(f"--background {args.background!r}: values must be in [0, 1]")
    scale = as_real(args.scale)
    if scale is None or scale <= 0:
        raise ValidationError(f"--scale {args.scale}: must be a positive number")
    cam = _camera(args)
    scene = read_scene(args.scene)
    t0 = time.perf_counter()
    r = render(scene, cam, background=bg, mode=args.mode)
    seconds = time.perf_counter() - t0
    items = [(out, _encode(out, r.rgb, "rgb"))]
    if depth_path is not None:
        items.append((depth_path, _encode(depth_path, (r.depth, r.alpha) if depth_path.suffix.lower() == ".png"
                                          else r.depth, "depth")))
    if alpha_path is not None:
        items.append((alpha_path, _encode(alpha_path, r.alpha, "alpha")))
    write_files(items, replace=args.force)
    covered = float((r.alpha > 0).mean())
    print(f"rendered {len(scene)} Gaussians at {cam.width}x{cam.height} in {seconds:.2f} s "
          f"({covered:.0%} of pixels covered; camera's image up {format_vector(cam.up)}); "
          f"wrote {', '.join(str(p) for p, _ in items)}")
    return 0
