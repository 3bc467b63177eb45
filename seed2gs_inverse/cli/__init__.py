"""The ``seed2gs`` command.

Each command group lives in a module of this package that defines
``register(subparsers)``; it adds its sub-commands and sets ``func`` on each
parser to a function ``func(args) -> int``. ``main`` turns every expected
error (bad input, missing file) into one line on stderr and exit status 2;
``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from ..errors import Seed2GSError

__all__ = ["main", "build_parser"]

# Command-group modules, in the order their commands appear in --help.
_COMMAND_MODULES = ("_extract", "_batch", "_eval", "_demo", "_scene", "_render", "_operators", "_solve", "_view",
                    "_models")


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = argparse.ArgumentParser(
        prog="seed2gs",
        description="Extract one object from a frozen 3D Gaussian Splatting scene.")
    parser.add_argument("--version", action="version", version=f"seed2gs-inverse {__version__}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _COMMAND_MODULES:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv=None) -> int:
    # Numba's OpenMP threads busy-wait between parallel regions by default,
    # which halves throughput on a loaded 2-core machine; a user's own
    # setting wins.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
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
        sub = getattr(args, f"{args.command}_command", None)  # e.g. "operators build"
        where = f"{args.command} {sub}" if isinstance(sub, str) else args.command
        print(f"seed2gs {where}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
