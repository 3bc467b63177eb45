"""What every ``seed2gs`` command shares: output checks, ``--up``, ``--method``/``--option``, progress.

One grammar for every command:

* ``--camera FILE[:NAME|INDEX]`` names one camera of a camera file;
* ``--up X,Y,Z`` is a world direction;
* a command that writes refuses to replace an existing output unless
  ``--force`` is given, and checks its output paths before any work
  (:func:`check_output`);
* ``--method`` lists its choices and ``--option NAME=VALUE`` the options of
  each method;
* progress bars go to stderr only when it is a terminal (never into logs);
  the long commands (``extract``, ``demo``, ``batch``, ``eval``) print one
  line per finished stage or job instead when it is not, or with
  ``--no-progress``, and nothing with ``--quiet``
  (:func:`add_feedback_arguments`, :func:`feedback_progress`).
"""

from __future__ import annotations

import json
import os
import sys

import numpy as np

from ..camera import MAX_IMAGE_SIDE, Camera
from .._output_paths import check_output
from ..errors import ValidationError
from ..progress import Progress as _Progress
from ..pipeline.vaas import DEFAULTS as VAAS_DEFAULTS
from ..solvers import available_methods, check_method_options, method_options

__all__ = ["check_output", "check_input_file", "parse_vector", "format_vector", "add_method_arguments", "parse_options",
           "progress_enabled", "add_feedback_arguments", "feedback_progress", "SolveBar", "DEFAULT_VIEWS"]


#: Views per VAAS clip used by default by ``extract``, ``demo`` and the examples (the paper's 24).
DEFAULT_VIEWS = int(VAAS_DEFAULTS["n_views"])


def check_input_file(path, label: str) -> None:
    """Raise a ValidationError ``"{label} {path}: no such file"`` (or ``": a directory, not a file"``)."""
    if os.path.isdir(path):
        raise ValidationError(f"{label} {path}: a directory, not a file")
    if not os.path.isfile(path):
        raise ValidationError(f"{label} {path}: no such file")


def parse_vector(option: str, values) -> np.ndarray:
    """A finite, non-zero 3-vector from ``X,Y,Z`` (or, deprecated, three separate numbers)."""
    items = [values] if isinstance(values, str) else list(values)
    text = ",".join(str(v) for v in items)
    try:
        vals = [float(v) for v in text.split(",") if v.strip() != ""]
    except ValueError:
        vals = []
    if len(vals) != 3 or not np.all(np.isfinite(vals)):
        raise ValidationError(f"{option} {' '.join(map(str, items))!r}: expected three numbers X,Y,Z, e.g. 0,-1,0")
    if len(items) == 3:
        print(f"seed2gs: note: '{option} X Y Z' is deprecated; write {option} {text}", file=sys.stderr)
    v = np.array(vals)
    if not np.any(v):
        raise ValidationError(f"{option} {text}: must be a non-zero direction")
    return v


def format_vector(v) -> str:
    """``x,y,z`` with three decimals: a direction as ``--up`` takes it."""
    return ",".join(f"{float(x):.3f}" for x in v)


def parse_size(option: str, text: str, limit: int = 16384) -> tuple[int, int]:
    """``(width, height)`` from ``WxH``, each in 1..``limit``."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValidationError(f"{option} {text!r}: expected WIDTHxHEIGHT, e.g. 960x540") from None
    if not (0 < w <= limit and 0 < h <= limit):
        raise ValidationError(f"{option} {text!r}: width and height must be in 1..{limit}")
    return w, h


def look_at_camera(look_at, up=None, fov=None, size=None, *, up_option: str = "--up",
                   size_option: str = "--size") -> Camera:
    """The camera of ``--look-at EYE TARGET`` (each ``x,y,z``): up ``0,-1,0`` (the usual up of
    COLMAP-trained scenes), a 60 degree vertical field of view and 960x540 unless given."""
    w, h = parse_size(size_option, size or "960x540")
    eye, target = (parse_point("--look-at", v) for v in look_at)
    try:
        return Camera.look_at(eye, target, parse_vector(up_option, up or "0,-1,0"), 60.0 if fov is None else fov,
                              w, h, name="look-at")
    except ValidationError as exc:
        raise ValidationError(f"--look-at / {up_option} / --fov: {str(exc).removeprefix('look_at: ')}") from None


#: The smallest image side a --scale may give: below it a view holds no picture worth rendering.
MIN_SCALED_SIDE = 4


def scaled_size(camera, scale: float, option: str = "--scale") -> tuple[int, int]:
    """``(width, height)`` of ``camera.scaled(scale)``, or a ValidationError naming ``option``.

    Each side must lie between :data:`MIN_SCALED_SIDE` and the camera limit
    :data:`~seed2gs_inverse.camera.MAX_IMAGE_SIDE`, so that a tiny or huge
    ``--scale`` is refused here, naming the option, rather than giving
    empty images or failing later as a bad camera.
    """
    w, h = (max(1, int(round(side * scale))) for side in (camera.width, camera.height))
    if min(w, h) < MIN_SCALED_SIDE or max(w, h) > MAX_IMAGE_SIDE:
        name = f" '{camera.name}'" if camera.name else ""
        raise ValidationError(f"{option} {scale:g}: camera{name} ({camera.width}x{camera.height}) would give "
                              f"{w}x{h} images; each side must lie in {MIN_SCALED_SIDE}..{MAX_IMAGE_SIDE}")
    return w, h


def parse_point(option: str, text) -> np.ndarray:
    """Three finite numbers from ``x,y,z`` (a point or a colour; zero allowed)."""
    try:
        vals = [float(v) for v in str(text).split(",")]
    except ValueError:
        vals = []
    if len(vals) != 3 or not np.all(np.isfinite(vals)):
        raise ValidationError(f"{option} {text!r}: expected three numbers 'x,y,z'")
    return np.array(vals)


def _method_lines() -> str:
    """``method: option, option; ...`` for every registered method (the --option help)."""
    return "; ".join(f"{m}: {', '.join(method_options(m)) or '(none)'}" for m in available_methods())


def add_method_arguments(parser, *, options: bool = True, default: str = "weighted_bce") -> None:
    """``--method`` (with its choices) and, with ``options``, ``--option NAME=VALUE`` (listing each method's)."""
    methods = available_methods()
    parser.add_argument("--method", default=default, choices=methods, metavar="METHOD",
                        help=f"solver: {', '.join(methods)} (default {default})")
    if options:
        parser.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                            help="solver option (VALUE read as JSON, else as a string); repeatable. "
                                 "Options per method: " + _method_lines().replace("%", "%%"))


def parse_options(items, method: str) -> dict:
    """``--option NAME=VALUE`` items as a dict, checked against the method's options."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.isidentifier():
            raise ValidationError(f"--option must look like NAME=VALUE, got {item!r}")
        try:
            out[name] = json.loads(value)
        except json.JSONDecodeError:
            out[name] = value
    check_method_options(method, out)
    return out


def progress_enabled(no_progress: bool = False) -> bool:
    """Progress bars only on a terminal: a redirected stderr (a log file) gets none."""
    return not no_progress and bool(getattr(sys.stderr, "isatty", lambda: False)())


def add_feedback_arguments(parser, steps: str = "stage") -> None:
    """``--no-progress`` and ``--quiet`` of a long command whose ``steps`` (stages, jobs) end one by one."""
    parser.add_argument("--no-progress", action="store_true",
                        help=f"no progress bars: one line per finished {steps} on stderr instead (what stderr "
                             f"gets anyway when it is not a terminal)")
    parser.add_argument("--quiet", action="store_true",
                        help=f"nothing on stderr while it runs: no bars, no {steps} lines, no compile notices "
                             f"(errors and warnings are still printed)")


def feedback_progress(args):
    """The ``progress`` of :func:`add_feedback_arguments`' options: False, ``"bars"`` or ``"lines"``.

    ``--quiet``: False (nothing); otherwise ``"bars"`` when stderr is a
    terminal and ``--no-progress`` is not given, else ``"lines"``.
    """
    if getattr(args, "quiet", False):
        return False
    return "bars" if progress_enabled(getattr(args, "no_progress", False)) else "lines"


def SolveBar(desc: str, enabled: bool):
    """A progress bar for one solve: ``with SolveBar(...) as bar: solve(..., progress=bar.solve_callback)``.

    Iterations against the method's maximum and the current loss, on stderr;
    disabled, ``bar.solve_callback`` is None and the solver reports nothing.
    """
    return _Progress(desc, enabled)
