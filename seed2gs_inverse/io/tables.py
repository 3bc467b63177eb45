"""Small configuration files (TOML or JSON) read into a table, with errors naming the file.

Used for the models configuration (:mod:`seed2gs_inverse.frontend.config`)
and the batch jobs file (:mod:`seed2gs_inverse.batch.jobs`).
"""

from __future__ import annotations

import json
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the declared 'tomli' backport
    import tomli as tomllib

from ..errors import FormatError

__all__ = ["read_table"]


def read_table(path, what: str = "file") -> dict:
    """Parse ``path`` as JSON (``.json``) or TOML (anything else) into a dict.

    Parameters
    ----------
    path : str or Path
    what : str
        What the file is, for messages (e.g. ``"models configuration"``).

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    FormatError
        The file cannot be read, is not valid JSON/TOML (including integers of
        more than 4300 digits and nesting too deep to parse), or is not a
        table at the top level. The message names the file.
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(2, f"No such {what}", str(p)) from None
    except OSError as exc:
        raise FormatError(f"{p}: cannot read the {what} ({exc.strerror})") from None
    try:
        if p.suffix.lower() == ".json":
            kind = "JSON"
            data = json.loads(raw.decode("utf-8"))
        else:
            kind = "TOML"
            data = tomllib.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:  # JSONDecodeError and TOMLDecodeError are ValueErrors
        raise FormatError(f"{p}: not valid {kind} ({exc})") from None
    except RecursionError:
        raise FormatError(f"{p}: not a valid {what} (nested too deeply to read)") from None
    if not isinstance(data, dict):
        raise FormatError(f"{p}: the {what} must be a table at the top level")
    return data
