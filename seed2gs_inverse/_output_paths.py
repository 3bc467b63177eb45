"""Output paths checked before any expensive work: :func:`check_output`.

The ``seed2gs`` commands and
:func:`~seed2gs_inverse.pipeline.outputs.save_extraction` (and through it
the batch workers) call it first, so a typo fails at once and never after
minutes of work. A command that writes outputs holds their locks for its
whole run (:func:`locks_outputs`), so a second process writing the same
output stops at once.
"""

from __future__ import annotations

import functools
import os
from contextlib import ExitStack
from pathlib import Path

from ._atomic import check_writable, not_an_earlier_output, output_lock
from .errors import ValidationError

__all__ = ["check_output", "locks_outputs"]


def check_output(path, option: str, *, directory: bool = False, force: bool = False, kind: str | None = None) -> Path:
    """``path`` as a Path once it is known that the command can write it; else a ValidationError.

    Called before any expensive work, so that a typo fails at once and the
    message names the user's path (never a temporary name):

    * the parent directory must exist and be a directory (``-o afile/out``
      says that ``afile`` is a file);
    * a file can be created in it (``-o /proc/x`` fails here, not after
      the whole pipeline), checked by creating and removing a probe file;
    * an existing ``path`` is replaced only with ``force`` (the same rule for
      every command), and only by the same kind (file or directory);
    * a directory is never replaced when it is the current directory or
      holds it, nor, when the command names the ``kind`` of its output
      (``"extract"``, ``"operators"``, ``"compare"``,
      ``"split"``), when it is neither
      empty nor an earlier output of that kind holding only what the command
      writes (:func:`~seed2gs_inverse._atomic.not_an_earlier_output`):
      ``--force`` replaces the command's own output, never a user's files.

    Raises
    ------
    ValidationError
        One of the conditions above fails; the message starts with
        ``option`` and the path as given.
    """
    p = Path(os.fspath(path))
    if not str(path):
        raise ValidationError(f"{option}: the output path is empty")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        probe = parent
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        if probe.exists() and not probe.is_dir():
            raise ValidationError(f"{option} {path}: {probe} is a file, not a directory")
        raise ValidationError(f"{option} {path}: the directory {parent} does not exist (create it first)")
    check_writable(parent, f"{option} {path}")
    if p.exists() or p.is_symlink():
        if directory and not p.is_dir():
            raise ValidationError(f"{option} {path} exists and is not a directory")
        if not directory and p.is_dir():
            raise ValidationError(f"{option} {path} is a directory; give a file name")
        if not force:
            raise ValidationError(f"{option} {path} exists; use --force to replace it")
        if directory:
            target, here = p.resolve(), Path.cwd().resolve()
            if target == here or target in here.parents:
                raise ValidationError(f"{option} {path} is the current directory or holds it; "
                                      f"give a new directory")
            why = None if kind is None else not_an_earlier_output(p, kind)
            if why is not None:
                raise ValidationError(f"{option} {path} exists and {why}; --force only replaces an empty "
                                      f"directory or this command's own earlier output: remove it yourself or "
                                      f"choose another path")
    return p



def locks_outputs(*options, force: str = "force"):
    """Decorator of a command's ``run(args)``: hold the lock of each output it names for the whole run.

    Parameters
    ----------
    *options : (str, str)
        ``(attribute of args, option name)`` of each output path, e.g.
        ``("output", "-o")``; a None or empty attribute is skipped.
    force : str
        The attribute of args that allows replacing an existing output.

    Notes
    -----
    Each output gets :func:`~seed2gs_inverse._atomic.output_lock` with
    ``replace`` set by ``force``: another process writing it makes the
    command fail at once with an error naming that process, and the
    command's writes of it never replace an existing target without
    ``force``, even one that appears while the command runs. An output
    whose directory is missing or cannot take the lock file is left to the
    command's own checks (:func:`check_output`), which say so.
    """
    def decorate(run):
        @functools.wraps(run)
        def locked(args):
            with ExitStack() as held:
                for attr, option in options:
                    path = getattr(args, attr, None)
                    if not path or not (Path(path).parent if str(Path(path).parent) else Path(".")).is_dir():
                        continue
                    try:
                        held.enter_context(output_lock(path, f"{option} {path}",
                                                       replace=bool(getattr(args, force, False))))
                    except OSError:
                        continue
                return run(args)
        return locked
    return decorate
