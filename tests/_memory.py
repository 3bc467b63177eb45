"""Peak traced memory of one call (tests of the readers' memory bounds)."""

from __future__ import annotations

import tracemalloc


def traced(fn, *args, **kwargs):
    """``(fn(*args, **kwargs), peak)``: the result and tracemalloc's peak in bytes during the call.

    numpy registers its buffers with tracemalloc, so arrays are counted.
    """
    tracemalloc.start()
    try:
        result = fn(*args, **kwargs)
        return result, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
