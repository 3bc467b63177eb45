"""The optional parts of the toolkit (pip extras) and the error that says which one to install.

The core install (``pip install seed2gs-inverse``) renders, extracts,
builds operators and solves. Three parts that only some commands use are
extras, each listed in ``pyproject.toml``'s ``[project.optional-dependencies]``:

``view``
    pyvista (and VTK): ``seed2gs view`` and :func:`seed2gs_inverse.viz.membership_plot`.
``models``
    onnxruntime and tokenizers: the learned front end (``--models``, ``seed2gs models``).
``batch``
    dask.distributed: several worker processes or a cluster for ``seed2gs batch`` and
    ``seed2gs eval`` (their sequential layout needs no extra).

``all`` installs the three; ``test`` installs them and what the test suite needs.
Each place that imports one of these packages does so inside a function
(docs/architecture.md, "Imports") and turns an ``ImportError`` into
:func:`missing_extra`'s error.
"""

from __future__ import annotations

from .errors import Seed2GSError

__all__ = ["EXTRAS", "MissingExtraError", "missing_extra", "install_command"]

#: Each extra and the packages (import names) it brings.
EXTRAS = {"view": ("pyvista",), "models": ("onnxruntime", "tokenizers"), "batch": ("dask", "distributed")}

#: The distribution's name on PyPI.
DISTRIBUTION = "seed2gs-inverse"


class MissingExtraError(Seed2GSError, ImportError):
    """An optional part of the toolkit is not installed; the message names the ``pip install`` that brings it."""


def install_command(extra: str) -> str:
    """The shell command that installs ``extra``: ``pip install "seed2gs-inverse[EXTRA]"``.

    Raises
    ------
    KeyError
        ``extra`` is not one of :data:`EXTRAS` (a programming error).
    """
    if extra not in EXTRAS:
        raise KeyError(f"unknown extra {extra!r}; the extras are {', '.join(EXTRAS)}")
    return f'pip install "{DISTRIBUTION}[{extra}]"'


def missing_extra(extra: str, purpose: str, exc: ImportError | None = None) -> MissingExtraError:
    """The error to raise when ``purpose`` needs the packages of ``extra`` and importing one failed.

    Parameters
    ----------
    extra : str
        A key of :data:`EXTRAS`.
    purpose : str
        What needs it, in the user's words (``"seed2gs view"``, ``"a models configuration"``).
    exc : ImportError, optional
        The failed import; its message is quoted, so an installed package
        that fails to load (a missing system library) is not mistaken for
        an absent one.

    Returns
    -------
    MissingExtraError
        To be raised by the caller (``raise missing_extra(...) from None``).
    """
    reason = f" ({str(exc).strip().splitlines()[0]})" if exc is not None and str(exc).strip() else ""
    return MissingExtraError(f"{purpose} needs the '{extra}' extra ({', '.join(EXTRAS[extra])}), which is not "
                             f"installed{reason}: {install_command(extra)}")
