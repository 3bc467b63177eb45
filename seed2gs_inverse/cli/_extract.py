"""``seed2gs extract``: one object out of a splat file, from one camera and a prompt.

``report.json`` records everything needed to repeat a run (its ``run``
section: toolkit version, scene path, file hash and fingerprint, the camera
as given and in full, the prompt, the models file, the format and the
seeds; ``settings`` holds every option), and ``seed2gs extract
--from-report report.json -o OUT`` repeats it.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from .. import __version__
from .._memory import peak_rss_mb
from .._output_paths import locks_outputs
from ..camera import Camera
from ..errors import FormatError, ValidationError
from ..frontend.config import resolve_models
from ..frontend.prompts import GRABCUT_SEED, TEXT_NEEDS_GROUNDER, BoxPrompt, MaskPrompt, PointPrompt, TextPrompt
from ..io import read_camera, read_cameras, read_scene
from ..io._common import check_regular
from ..io.images import image_shape
from ..io.tables import read_small_file
from ..operators import scene_fingerprint
from ..pipeline.settings import LIMITS, ExtractSettings
from ..progress import Feedback
from ._common import (DEFAULT_VIEWS, add_feedback_arguments, add_method_arguments, check_input_file, check_output,
                      feedback_progress, format_vector, look_at_camera, parse_options, parse_vector)

__all__ = ["register", "settings_from_args", "seed_summary_line", "axis_line", "cap_lines"]

#: Options that set ExtractSettings (None on the command line = not given).
_SETTING_FLAGS = {"method": "--method", "views": "--views", "orbit_scale": "--orbit-scale",
                  "max_view_pixels": "--max-view-pixels", "max_reference_pixels": "--max-reference-pixels",
                  "near_margin": "--near-margin", "threshold": "--threshold", "up": "--up", "option": "--option", "point_mode": "--point-mode",
                  "smoothness": "--smoothness", "completion": "--completion", "keep_islands": "--keep-islands",
                  "no_support_background": "--no-support-background", "no_follow_faint": "--no-follow-faint",
                  "no_follow_weak": "--no-follow-weak", "mask_tolerance": "--mask-tolerance"}
_PROMPT_FLAGS = {"mask": "--mask", "box": "--box", "point": "--point", "prompt": "--prompt",
                 "negative": "--negative", "camera": "--camera", "cameras": "--cameras", "look_at": "--look-at",
                 "look_up": "--look-up", "fov": "--fov", "size": "--size"}


def register(subparsers) -> None:
    """Add ``seed2gs extract`` to ``subparsers``."""
    p = subparsers.add_parser(
        "extract", help="extract one object from a 3DGS scene (Algorithm 1)",
        description="Extract the object a prompt points at in the view of one camera. Writes "
                    "object.ply, remainder.ply, q.npy, report.json, report.png (the object alone from six "
                    "directions, the remainder around the hole, the seed) and report_masks.png (the "
                    "supervision views with their masks) into OUTDIR. "
                    "report.json records the whole run; --from-report repeats it.")
    p.add_argument("scene", nargs="?", metavar="SCENE",
                   help="scene file (.ply, .splat, .spz, .compressed.ply); with --from-report, "
                        "optional: the scene to use instead of the recorded path (same content)")
    p.add_argument("--camera", metavar="FILE[:NAME|INDEX]",
                   help="reference camera: cameras.json / COLMAP / transforms.json, with :NAME or :INDEX")
    p.add_argument("--look-at", nargs=2, metavar=("EYE", "TARGET"),
                   help="reference camera without a camera file: its position and the point it looks at, "
                        "each 'x,y,z' (as seed2gs render --look-at; see --look-up, --fov, --size)")
    p.add_argument("--look-up", default=None, metavar="X,Y,Z",
                   help="with --look-at: the reference camera's up, the world direction shown upwards in its "
                        "image (default 0,-1,0, the usual up of COLMAP-trained scenes; seed2gs render calls it "
                        "--up); not the orbit axis, which is --up")
    p.add_argument("--fov", type=float, default=None, metavar="DEG",
                   help="with --look-at: vertical field of view in degrees (default 60)")
    p.add_argument("--size", default=None, metavar="WxH", help="with --look-at: image size (default 960x540)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--mask", metavar="PNG", help="seed mask PNG at the camera's resolution (non-zero = object; "
                                                 "with transparency, non-zero alpha)")
    g.add_argument("--box", nargs=4, type=float, metavar=("X0", "Y0", "X1", "Y1"),
                   help="box around the object in pixels (GrabCut turns it into the seed)")
    g.add_argument("--point", nargs=2, type=float, action="append", metavar=("X", "Y"),
                   help="click on the object (repeatable); see --negative")
    g.add_argument("--prompt", metavar="TEXT", help="text prompt (needs --models)")
    g.add_argument("--from-report", metavar="REPORT.json",
                   help="repeat the run recorded in a report.json (scene, camera, prompt, every setting)")
    p.add_argument("--negative", nargs=2, type=float, action="append", metavar=("X", "Y"), default=None,
                   help="click on what is NOT the object (with --point; repeatable)")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="output directory (created)")
    p.add_argument("--force", action="store_true", help="replace OUTDIR if it exists")
    p.add_argument("--models", metavar="FILE", default=None,
                   help="models configuration for text prompts / SAM2 tracking (else $SEED2GS_MODELS)")
    add_method_arguments(p, default="weighted_bce")
    p.set_defaults(method=None)  # None: not given (the default applies; --from-report may not override)
    p.add_argument("--views", type=int, default=None,
                   help=f"views per VAAS clip, 2..360 (default {DEFAULT_VIEWS})")
    p.add_argument("--orbit-scale", type=float, default=None,
                   help="orbit view resolution relative to the camera, in (0, 4] (default 0.5), up to "
                        "--max-view-pixels")
    p.add_argument("--max-view-pixels", type=int, default=None, metavar="N",
                   help=f"cap on the pixels of each orbit view, {LIMITS['max_view_pixels'][0]}.."
                        f"{LIMITS['max_view_pixels'][1]:,} (default 40,000): a larger --orbit-scale is lowered "
                        f"to it, and the run says so (report.json's resolved.caps)")
    p.add_argument("--max-reference-pixels", type=int, default=None, metavar="N",
                   help=f"cap on the pixels of the reference view the seed is lifted from, "
                        f"{LIMITS['max_reference_pixels'][0]}..{LIMITS['max_reference_pixels'][1]:,} (default "
                        f"1,000,000): a larger camera is rendered smaller for the lift, and the run says so")
    p.add_argument("--near-margin", default=None, metavar="R|off",
                   help="the orbit views leave out Gaussians more than R object radii in front of the object's "
                        "centre (what stands between them and the object; level ground stays), R > 0 (default "
                        "1); 'off' renders everything in front")
    p.add_argument("--threshold", type=float, default=None,
                   help="q threshold in [0, 1) (default: the solver's, 0.5)")
    p.add_argument("--up", default=None, metavar="auto|level|camera|X,Y,Z",
                   help="the orbit axis, the world direction the virtual cameras circle around (not the "
                        "reference camera's image up, which --look-up sets with --look-at); printed with the "
                        "result: 'auto' (default: the support plane under the object, the scene's "
                        "plane, the camera's roll and --cameras; report.json's 'up' says which and how "
                        "sure), 'level' (the camera's up, its pitch read from the dominant flat surface in view: "
                        "right when that is the ground), 'camera' (the image up: right for a level "
                        "view) or a world direction X,Y,Z")
    p.add_argument("--cameras", metavar="FILE", default=None,
                   help="the scene's capture cameras (cameras.json / COLMAP / transforms.json): with "
                        "--up auto their level right vectors fix the world up")
    p.add_argument("--point-mode", choices=("object", "region"), default=None,
                   help="--point: grow the click to the whole object in 3D (object, the default) or keep "
                        "its colour region (region)")
    p.add_argument("--mask-tolerance", type=int, default=None, metavar="PX",
                   help=f"how many pixels a --mask (or a --prompt's mask) may miss its object's edge by, "
                        f"{LIMITS['mask_tolerance'][0]}..{LIMITS['mask_tolerance'][1]} (default 3): the tracker "
                        f"copies no label from within PX of an edge of the mask that the scene does not show "
                        f"(no depth step, no colour step at the ground); 0 trusts the mask to the pixel")
    p.add_argument("--smoothness", type=float, default=None, metavar="LAMBDA",
                   help="graph-Laplacian regulariser of the solve: Gaussians no labelled view saw take their "
                        "neighbours' membership (0: off; default 1 with the model-free tracker, 0 with SAM2)")
    p.add_argument("--completion", choices=("reference", "tracked"), default=None,
                   help="fill the orbit masks' unknown pixels by 3D label completion before the solve, "
                        "seeded by the reference's labels or by every tracked label (default: off)")
    p.add_argument("--keep-islands", action="store_true",
                   help="keep parts of the selection apart from the seeded object (by default islands holding "
                        "at least 0.5%% as many Gaussians as the object are left out, unless the masks call "
                        "them object: background the masks brought in)")
    p.add_argument("--no-support-background", action="store_true",
                   help="do not label the surface the object rests on as background in the orbit views (by "
                        "default the model-free tracker does, where the orbit axis is trusted)")
    p.add_argument("--no-follow-faint", action="store_true",
                   help="leave faint Gaussians near the object to the solver (by default each takes the membership "
                        "of its nearest opaque neighbours, and each Gaussian every view shows inside the "
                        "selection's silhouette that of its nearest selected one, so translucent shells and inner "
                        "layers leave with the object instead of staying in the remainder)")
    p.add_argument("--no-follow-weak", action="store_true",
                   help="leave unselected Gaussians near the object that dominate no pixel of any view to the "
                        "solver (by default each takes the membership of its nearest Gaussians that do, so back "
                        "and inner layers leave with the object instead of staying in the remainder)")
    p.add_argument("--format", choices=("ply", "splat"), default=None, help="object/remainder format (default ply)")
    p.add_argument("--save-operators", action="store_true",
                   help="also write what the solve took into OUTDIR: operators/, masks/ (one view_NNN.npy per "
                        "view, NaN = unknown), init.npy, graph.npz, follow.npz, islands.npy and solve.json, from "
                        "which 'seed2gs solve OUTDIR/operators OUTDIR/masks --from-extraction OUTDIR' reproduces "
                        "q.npy and 'seed2gs compare OUTDIR/operators OUTDIR/masks' compares the solvers")
    add_feedback_arguments(p)
    p.set_defaults(func=run)


# -- prompts ---------------------------------------------------------------------------------
def _prompt_from_args(args):
    if args.negative and args.point is None:
        raise ValidationError("--negative clicks need at least one --point")
    if args.mask is not None:
        check_input_file(args.mask, "--mask")
        image_shape(args.mask, "--mask image")  # its header, within the image limits, before any work
        return MaskPrompt(args.mask)
    if args.box is not None:
        return BoxPrompt(args.box)
    if args.point is not None:
        neg = list(args.negative or [])
        return PointPrompt(list(args.point) + neg, [1] * len(args.point) + [0] * len(neg))
    if args.prompt is None:
        raise ValidationError("give a prompt: --mask PNG, --box X0 Y0 X1 Y1, --point X Y or --prompt TEXT "
                              "(or --from-report REPORT.json)")
    if not args.prompt.strip():
        raise ValidationError("--prompt is empty")
    if args.models is None and not os.environ.get("SEED2GS_MODELS"):
        raise ValidationError(TEXT_NEEDS_GROUNDER)
    return TextPrompt(args.prompt)


def _sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _prompt_record(prompt) -> dict:
    """JSON description of a prompt from which :func:`_prompt_from_record` rebuilds it."""
    if isinstance(prompt, MaskPrompt):
        path = os.path.abspath(os.fspath(prompt.mask))
        return {"kind": "mask", "path": path, "sha256": _sha256(path)}
    if isinstance(prompt, BoxPrompt):
        return {"kind": "box", "box": [float(v) for v in prompt.box], "iterations": prompt.iterations,
                "alpha_min": prompt.alpha_min}
    if isinstance(prompt, PointPrompt):
        return {"kind": "point", "points": np.asarray(prompt.points, float).tolist(),
                "labels": [int(v) for v in prompt.labels], "color_tol": prompt.color_tol,
                "depth_tol": prompt.depth_tol, "radius": prompt.radius, "iterations": prompt.iterations,
                "alpha_min": prompt.alpha_min}
    return {"kind": "text", "text": prompt.text}


def _prompt_from_record(rec, where: str):
    """The prompt of a report's ``run.prompt``, every field's type checked first (FormatError naming it)."""
    rec = _section(rec, "run.prompt", where)
    kind = rec.get("kind")
    if kind not in _PROMPT_KINDS:
        raise _bad(where, "run.prompt.kind", f"one of {', '.join(_PROMPT_KINDS)}", kind)
    field = _FieldReader(rec, "run.prompt", where)
    try:
        if kind == "mask":
            path = field.get("path", _is_path, _PATH)
            digest = field.get("sha256", _is_str, "a string", required=False)
            if not os.path.exists(path):
                raise ValidationError(f"{where}: the recorded mask {path} no longer exists")
            check_regular(path, "mask image")
            if digest and _sha256(path) != digest:
                raise ValidationError(f"{where}: the mask {path} changed since the recorded run (sha256 differs)")
            return MaskPrompt(path)
        if kind == "box":
            box = field.get("box", lambda v: _is_numbers(v, 4), "a list of 4 finite numbers [x0, y0, x1, y1]")
            return BoxPrompt(box, field.get("iterations", _is_int, _INT, default=5),
                             float(field.get("alpha_min", _is_number, _NUMBER, default=0.05)))
        if kind == "point":
            points = field.get("points", lambda v: isinstance(v, list) and v and all(_is_numbers(p, 2) for p in v),
                               "a list of clicks [x, y] of finite numbers")
            labels = field.get("labels", lambda v: isinstance(v, list) and len(v) == len(points)
                               and all(_is_int(x) and x in (0, 1) for x in v),
                               "a list of 0 or 1, one per click")
            return PointPrompt(points, labels, float(field.get("color_tol", _is_number, _NUMBER)),
                               float(field.get("depth_tol", _is_number, _NUMBER)),
                               field.get("radius", _is_int, _INT), field.get("iterations", _is_int, _INT),
                               float(field.get("alpha_min", _is_number, _NUMBER)))
        return TextPrompt(field.get("text", lambda v: isinstance(v, str) and v.strip() != "", "a non-empty string"))
    except ValidationError as exc:
        msg = str(exc)
        raise FormatError(msg if msg.startswith(where) else f"{where}: run.prompt: {msg}") from None


# -- a report's fields -----------------------------------------------------------------------
_PROMPT_KINDS = ("mask", "box", "point", "text")
_FORMATS = ("ply", "splat")
_PATH = "a file path (a non-empty string)"
_INT = "a whole number"
_NUMBER = "a finite number"


def _is_str(v) -> bool:
    return isinstance(v, str)


def _is_path(v) -> bool:
    return isinstance(v, str) and v != "" and "\0" not in v


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return _is_int(v) or (isinstance(v, float) and math.isfinite(v))


def _is_numbers(v, n: int) -> bool:
    return isinstance(v, list) and len(v) == n and all(_is_number(x) for x in v)


def _shown(value) -> str:
    """A short one-line rendering of a report's value for messages."""
    if isinstance(value, (dict, list)):
        return "a section" if isinstance(value, dict) else f"a list of {len(value)}"
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 10 ** 30:
        return "a number too large"
    text = json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _bad(where: str, key: str, what: str, value) -> FormatError:
    return FormatError(f"{where}: {key} must be {what}, got {_shown(value)}; repeat the run from an "
                       f"unedited report.json")


def _section(value, key: str, where: str, required: bool = True):
    """``value`` if it is a section (a dict), None if absent and optional; else a FormatError naming ``key``."""
    if value is None and not required:
        return None
    if not isinstance(value, dict):
        raise _bad(where, key, "a section (a JSON object)", value)
    return value


class _FieldReader:
    """Type-checked values of one section of a report, each error naming ``section.key``."""

    def __init__(self, section: dict, name: str, where: str):
        self.section, self.name, self.where = section, name, where

    def get(self, key: str, ok, what: str, required: bool = True, default=None):
        value = self.section.get(key)
        if value is None:
            if required and default is None:
                raise FormatError(f"{self.where}: {self.name}.{key} is missing; repeat the run from an "
                                  f"unedited report.json")
            return default
        if not ok(value):
            raise _bad(self.where, f"{self.name}.{key}", what, value)
        return value


# -- outputs ---------------------------------------------------------------------------------
def seed_summary_line(summary: dict, remainder: dict | None = None) -> str:
    """The printed line about the seed: its size, and how the object it led to covers it in the reference view.

    ``seed: 412 px = 38% of the object's box (28x39 px); the selection
    rendered alone in the reference: 900 px, 45% of them under the seed,
    120% of the seed's area beyond it``. The figures are
    :func:`~seed2gs_inverse.pipeline.report.seed_summary`'s
    (``object_pixels``, ``share_of_object``, ``growth_beyond_seed``); a
    seed grown from a click (``grown_from_pixels``) adds ``; the seed
    itself grew in 3D from the click's 120 px region``; a box seed cleaned
    to the box's main object (``dropped_pixels``) adds ``; 85 px of other
    objects and ground left out of the box's seed``. With ``remainder``
    (:meth:`~seed2gs_inverse.pipeline.extraction.Extraction.remainder_summary`)
    the line goes on with ``; the remainder keeps 3.1% of the object's alpha (worst view 7.4%)``.
    """
    s = summary
    if not s.get("object_pixels"):
        line = f"seed: {s['seed_pixels']:,} px (the object is not visible in the reference view)"
    else:
        w, h = s["object_box_size"]
        line = (f"seed: {s['seed_pixels']:,} px = {s['share_of_object_box']:.0%} of the object's box "
                f"({w}x{h} px); the selection rendered alone in the reference: {s['object_pixels']:,} px, "
                f"{s['share_of_object']:.0%} of them under the seed")
        if s.get("growth_beyond_seed") is not None:
            line += f", {s['growth_beyond_seed']:.0%} of the seed's area beyond it"
    if s.get("grown_from_pixels") is not None:
        line += f"; the seed itself grew in 3D from the click's {s['grown_from_pixels']:,} px region"
    if s.get("dropped_pixels"):
        line += f"; {s['dropped_pixels']:,} px of other objects and ground left out of the box's seed"
    if remainder is not None and remainder.get("share") is not None:
        line += (f"; the remainder keeps {remainder['share']:.1%} of the object's alpha "
                 f"(worst view {remainder['worst_view']:.1%})")
    return line


def axis_line(resolved: dict, up_setting) -> str:
    """``orbit axis 0.000,-1.000,0.000 (--up auto: support-plane, confidence 0.93)``: the axis used and how.

    ``up_setting`` is the ``up`` setting of the run (a name or a vector).
    """
    given = up_setting if isinstance(up_setting, str) else format_vector(up_setting)
    how = resolved.get("up_method")
    conf = resolved.get("up_confidence")
    how = "as given" if how == "user" else how
    return (f"orbit axis {format_vector(resolved['up'])} (--up {given}: {how}"
            + ("" if conf is None else f", confidence {float(conf):.2f}") + ")")


def cap_lines(caps: dict) -> list[str]:
    """One line per view size a pixel cap lowered (``resolved["caps"]``, see ``pipeline.stages.view_caps``).

    ``orbit views 150x267: --orbit-scale 2 capped by --max-view-pixels 40000 (scale 0.28)``.
    """
    lines = []
    orbit = caps.get("orbit_views")
    if orbit:
        w, h = orbit["size"]
        lines.append(f"orbit views {w}x{h}: --orbit-scale {orbit['asked']:g} capped by "
                     f"{_SETTING_FLAGS[orbit['cap']]} {orbit['limit']} (scale {orbit['scale']:.3g})")
    ref = caps.get("reference_view")
    if ref:
        (w, h), (cw, ch) = ref["size"], ref["camera_size"]
        lines.append(f"reference view {w}x{h} for the seed lift: the camera's {cw}x{ch} capped by "
                     f"{_SETTING_FLAGS[ref['cap']]} {ref['limit']} (scale {ref['scale']:.3g})")
    return lines


# -- settings --------------------------------------------------------------------------------
def _up(text):
    if text is None or text in ("auto", "level", "camera"):
        return text
    try:
        return tuple(parse_vector("--up", text).tolist())
    except ValidationError as exc:
        if "expected three numbers" not in str(exc):
            raise
        raise ValidationError(f"--up {text!r}: expected 'auto', 'level', 'camera' or three numbers X,Y,Z "
                              f"(e.g. 0,-1,0)") from None


def _number(flag: str, text: str, what: str) -> float:
    """``text`` as a float, or a ValidationError naming ``flag`` and ``what`` it takes."""
    try:
        return float(text)
    except ValueError:
        raise ValidationError(f"{flag} {text!r}: expected {what}") from None


def settings_from_args(args):
    """The :class:`~seed2gs_inverse.pipeline.ExtractSettings` of the command line (validated)."""
    method = args.method or "weighted_bce"
    given = {"method": method, "n_views": args.views, "orbit_scale": args.orbit_scale,
             "max_view_pixels": getattr(args, "max_view_pixels", None),
             "max_reference_pixels": getattr(args, "max_reference_pixels", None),
             "threshold": args.threshold, "up": _up(args.up), "point_mode": args.point_mode,
             "smoothness": args.smoothness, "completion": args.completion,
             "mask_tolerance": getattr(args, "mask_tolerance", None),
             "seed_connected": False if getattr(args, "keep_islands", False) else None,
             "support_background": False if getattr(args, "no_support_background", False) else None,
             "follow_faint": False if getattr(args, "no_follow_faint", False) else None,
             "follow_weak": False if getattr(args, "no_follow_weak", False) else None,
             "solver_options": parse_options(args.option, method) if args.option else None}
    flags = {"n_views": "--views", "orbit_scale": "--orbit-scale", "threshold": "--threshold", "up": "--up",
             "max_view_pixels": "--max-view-pixels", "max_reference_pixels": "--max-reference-pixels",
             "method": "--method", "solver_options": "--option", "point_mode": "--point-mode",
             "smoothness": "--smoothness", "completion": "--completion", "near_margin": "--near-margin",
             "mask_tolerance": "--mask-tolerance"}
    kw = {k: v for k, v in given.items() if v is not None}
    near = getattr(args, "near_margin", None)
    if near is not None:
        kw["near_margin"] = None if near == "off" else _number("--near-margin", near, "a number > 0 or 'off'")
    kw["progress"] = feedback_progress(args)
    try:
        return ExtractSettings(**kw)
    except ValidationError as exc:
        # name the command-line flag, not the Python option
        msg = str(exc)
        for name, flag in flags.items():
            if msg.startswith(name + " ") or msg.startswith(name + ":"):
                msg = flag + msg[len(name):]
                break
        raise ValidationError(msg) from None


def _read_report(path) -> dict:
    p = Path(path)
    try:
        raw = read_small_file(p, "report")
    except FileNotFoundError:
        raise ValidationError(f"--from-report {path}: no such file") from None
    except FormatError as exc:
        raise FormatError(f"--from-report {exc}") from None
    try:
        rep = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise FormatError(f"--from-report {path}: not a JSON report ({type(exc).__name__})") from None
    run = rep.get("run") if isinstance(rep, dict) else None
    if isinstance(rep, dict) and isinstance(rep.get("demo"), dict):
        d = rep["demo"]
        raise FormatError(f"--from-report {path}: written by seed2gs demo, whose scene is generated, not read; "
                          f"repeat it with: {_demo_command(d)}")
    if not isinstance(run, dict) and isinstance(rep, dict) and isinstance(rep.get("batch"), dict):
        raise FormatError(f"--from-report {path}: written by seed2gs batch (job {rep['batch'].get('job')!r}), "
                          f"which records the job, not a run of extract: repeat it by running the batch again")
    if not isinstance(run, dict) or not isinstance(rep.get("settings"), dict):
        raise FormatError(f"--from-report {path}: no 'run' and 'settings' sections; only report.json files "
                          f"written by seed2gs extract can be repeated")
    return rep


def _demo_command(args: dict) -> str:
    """The ``seed2gs demo`` command line of a demo report's ``demo`` section (``size`` is "W H")."""
    words = ["seed2gs", "demo"]
    for k, v in args.items():
        words += [f"--{k}", *(str(v).split() if k == "size" else [str(v)])]
    return " ".join(shlex.quote(w) for w in words)


def _up_cameras(path, where: str):
    """The capture cameras of ``--cameras`` (or of a recorded run), read and validated; None without."""
    if path is None:
        return None
    if not os.path.exists(path):
        raise ValidationError(f"{where} {path}: no such file")
    return read_cameras(path)


#: Options a recorded report may lack, with the value that replays such a
#: report as it ran (the option off).
_ADDED_OPTIONS = {"seed_connected": False, "support_background": False, "follow_faint": False,
                  "follow_weak": False, "near_margin": None, "min_vote": 0.0}


def _recorded_settings(rep: dict, progress: bool, where: str):
    """The settings of a recorded run as it ran.

    Options the report lacks take their :data:`_ADDED_OPTIONS` value, and
    solver options that differ from today's defaults are pinned to the
    recorded ``resolved.solver_options``. A value that is not a valid
    setting is a FormatError naming ``settings`` or ``resolved``.
    """
    resolved = _section(rep.get("resolved"), "resolved", where, required=False) or {}
    ran = _section(resolved.get("solver_options"), "resolved.solver_options", where, required=False)
    try:
        settings = ExtractSettings.from_dict({**_ADDED_OPTIONS, **rep["settings"], "progress": progress})
    except ValidationError as exc:
        raise FormatError(f"{where}: settings: {exc}") from None
    now = {k: v for k, v in settings.solver_kwargs().items() if isinstance(v, (int, float, str, bool))}
    if ran is not None and ran != now:
        try:
            settings = settings.replace(solver_options={**ran, **settings.solver_options})
        except ValidationError as exc:
            raise FormatError(f"{where}: resolved.solver_options: {exc}") from None
    return settings


def _is_given(value) -> bool:
    """Whether a parsed flag was given: None, False and [] mean not; 0 is a value (though ``0 == False``)."""
    return value is not None and value is not False and value != []


def _from_report(args):
    """(scene path, camera, camera spec, prompt, settings, models path, format, run) of a recorded run.

    The whole report is checked before anything is done with it: every
    field used, its type, the format name and the paths (FormatError or
    ValidationError naming the key).
    """
    given = [flag for name, flag in {**_SETTING_FLAGS, **_PROMPT_FLAGS}.items()
             if _is_given(getattr(args, name, None))]
    if given:
        raise ValidationError(f"--from-report repeats a recorded run; it cannot be combined with {', '.join(given)}")
    rep = _read_report(args.from_report)
    where = f"--from-report {args.from_report}"
    run = rep["run"]
    scene = _FieldReader(_section(run.get("scene"), "run.scene", where), "run.scene", where)
    recorded_path = scene.get("path", _is_path, _PATH, required=args.scene is None)
    scene.get("sha256", _is_str, "a string", required=False)
    scene.get("fingerprint", _is_str, "a string", required=False)
    cam = _FieldReader(_section(run.get("camera"), "run.camera", where), "run.camera", where)
    spec = cam.get("spec", _is_str, "a camera spec FILE[:NAME|INDEX] (a string)", required=False)
    try:
        camera = Camera.from_dict(cam.get("camera", lambda v: isinstance(v, dict), "a section (a JSON object)"))
    except ValidationError as exc:
        raise FormatError(f"{where}: run.camera.camera: {exc}") from None
    up = _section(run.get("up_cameras"), "run.up_cameras", where, required=False)
    if up is not None:
        _FieldReader(up, "run.up_cameras", where).get("path", _is_path, _PATH)
    top = _FieldReader(run, "run", where)
    models = top.get("models", _is_path, _PATH, required=False)
    fmt = top.get("format", lambda v: v in _FORMATS, f"one of {', '.join(_FORMATS)}", default="ply")
    prompt = _prompt_from_record(run.get("prompt"), where)
    settings = _recorded_settings(rep, feedback_progress(args), where)
    scene_path = args.scene or recorded_path
    check_regular(scene_path, "scene")
    if not os.path.isfile(scene_path):
        raise ValidationError(f"scene {scene_path}: no such file (give the scene's new path as SCENE)")
    return scene_path, camera, spec, prompt, settings, args.models or models, args.format or fmt, run


def _reference_camera(args):
    """The camera of ``--look-at`` (None with ``--camera``, read later with the other inputs)."""
    look = [flag for name, flag in (("look_up", "--look-up"), ("fov", "--fov"), ("size", "--size"))
            if getattr(args, name) is not None]
    if args.camera is not None and args.look_at is not None:
        raise ValidationError("give the reference camera once: --camera FILE[:NAME|INDEX] or --look-at EYE TARGET")
    if args.look_at is None:
        if args.camera is None:
            raise ValidationError("give the reference camera: --camera FILE[:NAME|INDEX], or --look-at EYE TARGET "
                                  "for a scene without a camera file")
        if look:
            raise ValidationError(f"{', '.join(look)} go with --look-at; with --camera the camera file gives them")
        return None
    return look_at_camera(args.look_at, args.look_up, args.fov, args.size, up_option="--look-up")


@locks_outputs(("output", "-o"))
def run(args) -> int:
    """``seed2gs extract``: read the inputs, run :func:`~seed2gs_inverse.pipeline.extract`, write OUTDIR."""
    # The pipeline imports the rasterizer, and so Numba: imported here, not at the top, so that
    # building the command line's parser (every `seed2gs` call, --help included) does not load it.
    from ..pipeline import extract, report, save_extraction

    # Everything cheap first: outputs, settings, inputs; the expensive work last.
    out = check_output(args.output, "-o", directory=True, force=args.force, kind="extract")
    recorded = None
    if args.from_report is not None:
        scene_path, camera, spec, prompt, settings, models_path, fmt, recorded = _from_report(args)
    else:
        if args.scene is None:
            raise ValidationError("give the SCENE file (or --from-report REPORT.json)")
        camera = _reference_camera(args)
        settings = settings_from_args(args)
        scene_path, spec, fmt, models_path = args.scene, args.camera, args.format or "ply", args.models
        check_input_file(scene_path, "scene")
        prompt = _prompt_from_args(args)
        if camera is None:
            camera = read_camera(args.camera)
    cameras_path = args.cameras if recorded is None else (recorded.get("up_cameras") or {}).get("path")
    up_cameras = _up_cameras(cameras_path, "--cameras" if recorded is None else "run.up_cameras:")
    models = resolve_models(models_path)
    grounder = models.grounder() if models is not None else None
    tracker = models.tracker() if models is not None else None
    if grounder is None and isinstance(prompt, TextPrompt):
        raise ValidationError(TEXT_NEEDS_GROUNDER)
    scene_sha = _sha256(scene_path)
    scene = read_scene(scene_path)
    fingerprint = scene_fingerprint(scene)
    if recorded is not None:
        _check_recorded_scene(recorded["scene"], scene_path, scene_sha, fingerprint)
    feedback = Feedback.of(settings.progress)
    with feedback.active():  # what the outputs' renderings may compile says so too, or nothing when quiet
        ex = extract(scene, camera, prompt, grounder=grounder, tracker=tracker, settings=settings,
                     up_cameras=up_cameras)
        run_info = {
            "toolkit": f"seed2gs-inverse {__version__}",
            "command": "extract",
            "scene": {"path": os.path.abspath(scene_path), "sha256": scene_sha, "fingerprint": fingerprint,
                      "n_gaussians": len(scene)},
            "camera": {"spec": spec, "camera": camera.to_dict()},
            "prompt": _prompt_record(prompt),
            "models": None if models_path is None else os.path.abspath(models_path),
            "format": fmt,
            "axis": ex.resolved.get("up"),
            "up_cameras": None if cameras_path is None else {"path": os.path.abspath(cameras_path),
                                                              "n_cameras": len(up_cameras)},
            "seeds": {"grabcut_opencv_rng": GRABCUT_SEED},
            "numba_threads": _numba_threads(),
            "peak_rss_mb": peak_rss_mb(),  # of this process: reading the scene and the extraction
        }
        t0 = time.perf_counter()
        with feedback.bar("write", steps=False):
            save_extraction(ex, out, fmt, force=args.force, run_info=run_info,
                            save_operators=args.save_operators)
        feedback.stage("write", time.perf_counter() - t0)
    s = ex.seconds
    print(f"extracted {int(ex.selected.sum())} of {len(scene)} Gaussians -> {out}/object.{fmt} "
          f"({len(ex.views)} views, {ex.total_seconds:.1f} s: "
          + ", ".join(f"{k} {v:.2f}" for k, v in s.items() if k != "compile" or v > 0)
          + ("" if run_info["peak_rss_mb"] is None else f"; peak memory {run_info['peak_rss_mb'] / 1024:.2f} GB")
          + ")")
    if int(ex.selected.sum()):  # (an empty selection was warned about by extract)
        print(seed_summary_line(report.seed_summary(ex), ex.remainder_summary()))
    print(axis_line(ex.resolved, ex.settings.up))
    for line in cap_lines(ex.resolved.get("caps", {})):
        print(line)
    if models is None:  # with models, SAM2 would have tracked even a mask/box/point seed
        feedback.note("note: no models configured; the seed was tracked by the model-free tracker")
    return 0


def _check_recorded_scene(want: dict, scene_path, scene_sha: str, fingerprint: str) -> None:
    """Compare the scene with the report's record; a warning says what could not be checked.

    A recorded geometry fingerprint that differs is a ValidationError. The
    warning names what was compared: bytes (sha256) and geometry
    (fingerprint), and what the report lacked.
    """
    recorded_fp, recorded_sha = want.get("fingerprint"), want.get("sha256")
    if recorded_fp not in (None, fingerprint):
        raise ValidationError(f"scene {scene_path}: not the recorded scene (fingerprint {fingerprint}, "
                              f"recorded {recorded_fp})")
    same_bytes = recorded_sha == scene_sha
    if recorded_fp is not None and recorded_sha not in (None, scene_sha):
        note = ("differs from the recorded file (same geometry, other bytes: colours or format); "
                "q may differ")
    elif recorded_fp is None and recorded_sha is None:
        note = ("cannot be compared with the recorded scene: the report records neither its sha256 nor "
                "its geometry fingerprint; q may differ")
    elif recorded_fp is None and not same_bytes:
        note = ("differs from the recorded file (sha256) and the report records no geometry fingerprint, "
                "so whether the geometry is the same was not checked; q may differ")
    elif recorded_fp is not None and recorded_sha is None:
        note = None  # same geometry; the bytes were not recorded
    else:
        note = None  # the very bytes recorded
    if note is not None:
        print(f"seed2gs extract: warning: {scene_path} {note}", file=sys.stderr)


def _numba_threads():
    try:
        import numba  # loaded by the extraction already; deferred for the parser's sake (see run)

        return int(numba.get_num_threads())
    except Exception:  # pragma: no cover - numba is a dependency; report what we can
        return None
