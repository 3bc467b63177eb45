"""All-or-nothing output: write beside the target, then rename onto it.

Every writer of the toolkit (scene files, images, operator directories,
extraction outputs) goes through :func:`atomic_path`, so a failure at any
point leaves neither a partial file nor a half-written directory behind, and
an existing target is only replaced by a complete one.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "write_files", "check_output_parent"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(target, directory: bool = False):
    """Yield a temporary sibling of ``target``; move it onto ``target`` on success.

    Parameters
    ----------
    target : path-like
        Final file or directory. Its parent must exist.
    directory : bool
        Yield an empty temporary directory instead of a file path. An existing
        ``target`` directory is replaced only after the new one is complete.

    The temporary path gets the permissions a plain ``open``/``mkdir`` would
    (``mkstemp``/``mkdtemp`` create private ones). If the block raises, the
    temporary path is removed and the exception propagates.
    """
    target = Path(target)
    parent = target.parent if str(target.parent) else Path(".")
    prefix = f".{target.name}."
    if directory:
        tmp = Path(tempfile.mkdtemp(prefix=prefix, suffix=".tmp", dir=parent))
        mode = 0o777
    else:
        # keep the extension: some writers (image libraries) choose the format by it
        fd, name = tempfile.mkstemp(prefix=prefix, suffix=".tmp" + target.suffix, dir=parent)
        os.close(fd)
        tmp = Path(name)
        mode = 0o666
    try:
        yield tmp
        os.chmod(tmp, mode & ~_umask())
        if directory and target.exists():
            old = Path(tempfile.mkdtemp(prefix=prefix, suffix=".old", dir=parent))
            os.replace(target, old / "previous")
            os.replace(tmp, target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, target)
    except BaseException:
        if directory:
            shutil.rmtree(tmp, ignore_errors=True)
        elif tmp.exists():
            tmp.unlink()
        raise


def write_files(items) -> None:
    """Write every ``(path, bytes)`` pair or none of them.

    All payloads are written to temporary files first; only when every one
    is complete are they renamed onto their targets.
    """
    from contextlib import ExitStack

    items = [(Path(p), payload) for p, payload in items]
    with ExitStack() as stack:
        for path, payload in items:
            tmp = stack.enter_context(atomic_path(path))
            tmp.write_bytes(payload)


def check_output_parent(path, option: str) -> Path:
    """Raise unless ``path``'s directory exists (call before expensive work).

    Writers never create missing parent directories: a typo in a path should
    fail at once, not after minutes of work or by leaving new directories.
    """
    from .errors import ValidationError

    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ValidationError(f"{option} {path}: the directory {parent} does not exist")
    return path
