"""Prompts for the batch tests that misbehave on purpose (importable by Dask workers)."""

from __future__ import annotations

import os
import signal
from dataclasses import dataclass
from pathlib import Path

from seed2gs_inverse.frontend.prompts import MaskPrompt


def _in_worker() -> bool:
    try:
        from distributed import get_worker

        get_worker()
    except (ImportError, ValueError):
        return False
    return True


@dataclass
class KillWorkerMask(MaskPrompt):
    """A mask prompt that kills the Dask worker process running it.

    The first ``times`` runs on a worker each leave a mark in ``marker_dir``
    and SIGKILL their own process (as the kernel's OOM killer would); later
    runs are a plain :class:`MaskPrompt`. Outside a worker it never kills.
    """

    marker_dir: str = ""
    times: int = 1

    def to_mask(self, image, **kw):
        if _in_worker():
            d = Path(self.marker_dir)
            done = len(list(d.glob("killed-*")))
            if done < self.times:
                (d / f"killed-{done}").write_text(str(os.getpid()))
                os.kill(os.getpid(), signal.SIGKILL)
        return super().to_mask(image, **kw)
