"""How far a run is and how long each of its stages took: a progress bar and a stage timer.

:class:`Progress` draws a tqdm bar on stderr for the lifetime of a ``with``
block, or does nothing when disabled, so callers never test whether bars are
on; its :attr:`~Progress.solve_callback` is a
:func:`~seed2gs_inverse.solvers.solve` ``progress`` hook. :class:`StageTimer`
adds the wall time of named stages. Both are neutral: the pipeline, the
command line and the batch runner use them alike.
"""

from __future__ import annotations

import contextlib
import sys
import time
from typing import TYPE_CHECKING, Callable, Iterator, Sequence

from tqdm import tqdm

if TYPE_CHECKING:
    from .solvers import SolveProgress

__all__ = ["Progress", "StageTimer"]


class Progress:
    """A progress bar on stderr (tqdm) owned by a ``with`` block; a no-op when disabled.

    Parameters
    ----------
    desc : str
        The bar's label.
    enabled : bool
        False: no bar; :meth:`update` does nothing and :attr:`solve_callback`
        is None.
    total : int, optional
        Steps expected (None: a counter without a total).
    unit : str
        What a step is (``"it"``, ``"view"``).

    Notes
    -----
    ``update(n)`` counts steps. :attr:`solve_callback` shows a solver's
    iterations against the method's maximum and the current loss. The bar is
    drawn on the ``sys.stderr`` of the moment the block is entered (a
    captured or redirected stream included).
    """

    #: Seconds between redraws (tqdm's ``mininterval``).
    MININTERVAL = 0.1

    def __init__(self, desc: str, enabled: bool, total: int | None = None, unit: str = "it"):
        self.desc, self.enabled, self.total, self.unit = desc, bool(enabled), total, unit
        self._bar = None

    def __enter__(self) -> Progress:
        if self.enabled:
            self._bar = tqdm(total=self.total, desc=self.desc, unit=self.unit, leave=False, file=sys.stderr,
                             mininterval=self.MININTERVAL)
        return self

    def update(self, n: int = 1) -> None:
        """Count ``n`` more steps."""
        if self._bar is not None:
            self._bar.update(n)

    @property
    def solve_callback(self) -> Callable[[SolveProgress], None] | None:
        """The ``solve(..., progress=)`` hook drawing on this bar.

        None when disabled, so the solver skips its reports.
        """
        return self._solve_step if self._bar is not None else None

    def _solve_step(self, p: SolveProgress) -> None:
        if p.total is not None and self._bar.total != p.total:
            self._bar.total = p.total
        self._bar.update(p.iteration - self._bar.n)
        if p.loss is not None:
            self._bar.set_postfix_str(f"loss {p.loss:.5g}", refresh=False)

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class StageTimer:
    """Wall seconds per stage: ``with timer("lift"): ...`` adds to ``timer.seconds["lift"]``.

    Parameters
    ----------
    stages : sequence of str
        The stages, in the order ``seconds`` lists them (each starts at 0).
    """

    def __init__(self, stages: Sequence[str]):
        self.seconds = dict.fromkeys(stages, 0.0)

    @contextlib.contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] += time.perf_counter() - t0

    def move(self, src: str, dst: str, seconds: float) -> None:
        """Count ``seconds`` measured inside stage ``src`` under ``dst`` instead."""
        self.seconds[src] -= seconds
        self.seconds[dst] += seconds
