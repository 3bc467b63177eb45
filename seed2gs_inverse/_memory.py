"""Peak resident memory of this process, for reports (``report.json``, batch summaries)."""

from __future__ import annotations

import sys

try:
    import resource
except ImportError:  # pragma: no cover - Windows
    resource = None

__all__ = ["peak_rss_mb"]


def peak_rss_mb() -> float | None:
    """The process's peak resident set size so far, in MiB; None where the platform has no ``resource`` (Windows).

    It is the peak of the whole process (a CLI run: reading the scene and the
    extraction), not of one call.
    """
    if resource is None:  # pragma: no cover - Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024.0  # macOS: bytes; Linux, BSD: KiB
