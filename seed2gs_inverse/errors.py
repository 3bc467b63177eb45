"""Exception types.

Every error the toolkit raises on bad input is a ``Seed2GSError``. The two
concrete kinds are also ``ValueError`` so callers that only know the standard
library can still catch them:

``FormatError``
    a file could not be read or written (wrong format, truncated data,
    inconsistent header, non-finite values). The message names the file.
``ValidationError``
    an in-memory argument is wrong (array shape, dtype, degenerate camera,
    mask of the wrong size). The message names the argument or view.
"""

from __future__ import annotations

__all__ = ["Seed2GSError", "FormatError", "ValidationError"]


class Seed2GSError(Exception):
    """Base class of every error raised by seed2gs-inverse on bad input."""


class FormatError(Seed2GSError, ValueError):
    """A file is malformed, truncated, of an unknown format or inconsistent."""


class ValidationError(Seed2GSError, ValueError):
    """An argument (array, camera, mask, option) is invalid."""
