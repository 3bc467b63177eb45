"""The ``seed2gs`` command.

Each command group lives in a module of this package that defines
``register(subparsers)``; it adds its sub-commands and sets ``func`` on each
parser to a function ``func(args) -> int``. ``main`` turns every expected
error (bad input, missing file) into one line on stderr and exit status 2;
``--debug`` shows the traceback instead.

Start-up: building the parser imports every command module, so ``seed2gs
--help`` costs what those modules import at their top. They import the
scene, camera, I/O, solver and pipeline modules there, but never the
rasterizer (:mod:`seed2gs_inverse.raster`): importing it loads Numba and
its compiled kernels, which only a command that renders needs, so those
commands import it when they run; that deferral is deliberate. The heavy
optional libraries (pyvista, onnxruntime, tokenizers, dask, matplotlib,
OpenCV) are deferred inside the modules that use them.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import sys
import warnings

from .. import __version__
from ..errors import Seed2GSError

__all__ = ["main", "build_parser"]

# Command-group modules, in the order their commands appear in --help.
_COMMAND_MODULES = ("_extract", "_batch", "_eval", "_demo", "_scene", "_render", "_operators", "_solve", "_view",
                    "_models")


#: A negative number, or comma-separated numbers the first of which is negative ("-1,-2.5,3e-2").
_NUMBERS = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?(,-?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?)*$")


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors: ``seed2gs extract: error: ...`` (exit status 2).

    The full usage is one ``--help`` away; a wall of usage text before the
    one line that matters hides it (and differs from our other errors).
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # Values such as "-1,-2,-3" (--look-at, --up) are vectors, not options: argparse only takes
        # single negative numbers for values, so widen its test to comma-separated numbers.
        self._negative_number_matcher = _NUMBERS

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``seed2gs`` parser with every command group's sub-commands registered."""
    parser = _Parser(
        prog="seed2gs",
        description="Extract one object from a frozen 3D Gaussian Splatting scene.")
    parser.add_argument("--version", action="version", version=f"seed2gs-inverse {__version__}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _COMMAND_MODULES:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    _tag_leaves(parser)
    return parser


def _tag_leaves(parser) -> None:
    """Give every command's parser a default ``_parser`` = itself (for its own usage errors)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                child.set_defaults(_parser=child)
                _tag_leaves(child)


def main(argv=None) -> int:
    """Run ``seed2gs`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    # Numba's OpenMP threads busy-wait between parallel regions by default,
    # taking the cores from the other threads of a busy machine; a user's
    # own setting wins.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    parser = build_parser()
    try:
        args, extra = parser.parse_known_args(argv)
        if extra:  # reported by the command's own parser: "seed2gs extract: error: ..."
            getattr(args, "_parser", parser).error(f"unrecognized arguments: {' '.join(extra)}")
    except SystemExit as exc:  # --help, --version, usage errors: their status, no traceback
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    sub = getattr(args, f"{args.command}_command", None)  # e.g. "operators build"
    where = f"{args.command} {sub}" if isinstance(sub, str) else args.command

    def show_warning(message, category, filename, lineno, file=None, line=None):
        # One line in the command's voice, not Python's "file:line: UserWarning" form.
        print(f"seed2gs {where}: warning: {message}", file=sys.stderr)

    try:
        with warnings.catch_warnings():
            warnings.showwarning = show_warning
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("seed2gs: interrupted", file=sys.stderr)
        return 130
    except (Seed2GSError, ValueError, OSError) as exc:
        if args.debug:
            raise
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if isinstance(exc, FileNotFoundError) and exc.filename:
            msg = f"no such file: {exc.filename}"
        print(f"seed2gs {where}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
