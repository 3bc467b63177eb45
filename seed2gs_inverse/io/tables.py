"""Small configuration files (TOML or JSON) read into a table, with errors naming the file.

Used for the models configuration (:mod:`seed2gs_inverse.frontend.config`),
the batch jobs file (:mod:`seed2gs_inverse.batch.jobs`) and the reports
that ``seed2gs extract --from-report`` repeats. Every such file is read
through :func:`read_small_file`: it must be a regular file (a pipe would
block the read for ever, a device such as ``/dev/zero`` never ends) no
larger than :data:`MAX_TABLE_BYTES`, both checked before anything is read.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the declared 'tomli' backport
    import tomli as tomllib

from ..errors import FormatError
from ._common import check_regular

__all__ = ["read_table", "read_small_file", "MAX_TABLE_BYTES"]

#: Largest configuration, jobs or report file read (bytes): far above what a
#: configuration, a report or a generated jobs file needs. Parsing holds
#: several times the file's size in memory, so the limit bounds that too.
MAX_TABLE_BYTES = 16 * 1024 * 1024


def read_small_file(path, what: str = "file", limit: int = MAX_TABLE_BYTES) -> bytes:
    """The bytes of ``path``, a regular file of at most ``limit`` bytes.

    The file's type and size are checked before it is read (and again on
    the open file, which is opened without blocking: a file replaced by a
    pipe in between cannot hang the read), and at most ``limit + 1`` bytes
    are ever read.

    Parameters
    ----------
    path : str or Path
    what : str
        What the file is, for messages (e.g. ``"jobs file"``).
    limit : int
        Largest accepted size in bytes.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    FormatError
        ``path`` is a directory, pipe, socket or device, is larger than
        ``limit``, or cannot be read. The message names the file.
    """
    p = Path(path)
    check_regular(p, what)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(p, flags)
    except FileNotFoundError:
        raise FileNotFoundError(2, f"No such {what}", str(p)) from None
    except (OSError, ValueError) as exc:
        raise FormatError(f"{p}: cannot read the {what} ({getattr(exc, 'strerror', None) or exc})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise FormatError(f"{p}: not a regular file (a directory, pipe or device); give the {what} itself")
        _check_size(p, st.st_size, what, limit)
        chunks, total = [], 0
        while total <= limit:
            piece = os.read(fd, min(1 << 20, limit + 1 - total))
            if not piece:
                break
            chunks.append(piece)
            total += len(piece)
        _check_size(p, total, what, limit)  # grew since the check
    except OSError as exc:
        raise FormatError(f"{p}: cannot read the {what} ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
    return b"".join(chunks)


def _check_size(path, size: int, what: str, limit: int) -> None:
    if size > limit:
        raise FormatError(f"{path}: the {what} holds {size} bytes, more than the {limit} bytes such a file "
                          f"may hold; give the {what} itself, not another file")


def read_table(path, what: str = "file", syntax: str | None = None) -> dict:
    """Parse ``path`` as JSON (``.json``) or TOML (anything else) into a dict.

    Parameters
    ----------
    path : str or Path
    what : str
        What the file is, for messages (e.g. ``"models configuration"``).
    syntax : {"json", "toml"}, optional
        Parse as this whatever the file's extension.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    FormatError
        The file is not a regular file, is larger than
        :data:`MAX_TABLE_BYTES`, cannot be read, is not valid JSON/TOML
        (including integers of more than 4300 digits and nesting too deep
        to parse), or is not a table at the top level. The message names
        the file.
    """
    p = Path(path)
    raw = read_small_file(p, what)
    json_syntax = syntax == "json" if syntax is not None else p.suffix.lower() == ".json"
    kind = "JSON" if json_syntax else "TOML"
    try:
        if json_syntax:
            data = json.loads(raw.decode("utf-8"))
        else:
            data = tomllib.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:  # JSONDecodeError and TOMLDecodeError are ValueErrors
        raise FormatError(f"{p}: not valid {kind} ({exc})") from None
    except RecursionError:
        raise FormatError(f"{p}: not a valid {what} (nested too deeply to read)") from None
    if not isinstance(data, dict):
        raise FormatError(f"{p}: the {what} must be a table at the top level")
    return data
