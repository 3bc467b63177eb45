"""What a long run says on stderr while it runs: progress bars, stage lines, stage timers.

:class:`Feedback` is a run's choice of what to say: a bar per stage
(``"bars"``, for a terminal), one line per stage as it ends (``"lines"``,
for a log or a pipe), only the notices of a first run (``"notes"``) or
nothing (``"quiet"``). :class:`Progress` draws one tqdm bar on stderr for the
lifetime of a ``with`` block, or does nothing when disabled, so callers never
test whether bars are on; its :attr:`~Progress.solve_callback` is a
:func:`~seed2gs_inverse.solvers.solve` ``progress`` hook. :class:`StageTimer`
adds the wall time of named stages, leaving out the time a compile clock
counts, and tells a :class:`Feedback` when a stage ends. :func:`notice`
prints a notice through the feedback of the run in progress (the
rasterizer's "compiling the kernels" line goes through it, so a quiet run
says nothing). All are neutral: the pipeline, the command line and the
batch runner use them alike.
"""

from __future__ import annotations

import contextlib
import contextvars
import sys
import threading
import time
from typing import TYPE_CHECKING, Callable, Iterator, Sequence

import numpy as np
from tqdm import tqdm

from .errors import ValidationError

if TYPE_CHECKING:
    from .solvers import SolveProgress

__all__ = ["Progress", "StageTimer", "Feedback", "notice", "check_progress", "FEEDBACK_MODES", "PROGRESS_CHOICES",
           "COMPILE"]

#: What a :class:`Feedback` may say: bars, stage lines, only notices, or nothing.
FEEDBACK_MODES = ("bars", "lines", "notes", "quiet")
#: The values a ``progress`` argument takes (:meth:`Feedback.of`): None (by the terminal), a bool or a mode.
PROGRESS_CHOICES = (None, True, False, "bars", "lines")
#: The key under which :class:`StageTimer` counts the seconds its compile clock measured.
COMPILE = "compile"

_ACTIVE: contextvars.ContextVar = contextvars.ContextVar("seed2gs_feedback", default=None)


def check_progress(progress):
    """``progress`` in canonical form: None, a bool (a NumPy bool too), ``"bars"`` or ``"lines"``.

    Raises
    ------
    ValidationError
        Any other value (naming ``progress`` and the choices).
    """
    if isinstance(progress, (bool, np.bool_)):
        return bool(progress)
    if progress is None or (isinstance(progress, str) and progress in PROGRESS_CHOICES):
        return progress
    raise ValidationError(f"progress must be None, True, False, 'bars' or 'lines', got {progress!r}")


def _stderr_is_terminal() -> bool:
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


class Feedback:
    """What a run says on stderr while it runs.

    Parameters
    ----------
    mode : {"bars", "lines", "notes", "quiet"}
        ``"bars"``: a progress bar for every stage (:meth:`bar`) and the
        notices; ``"lines"``: no bars, one line per finished stage or job
        (:meth:`step`) and the notices; ``"notes"``: only the notices
        (:meth:`note`: the compilation of the rasterizer's kernels on a first
        run); ``"quiet"``: nothing.
    prefix : str
        What every line starts with (``"seed2gs"``).

    Raises
    ------
    ValidationError
        ``mode`` is not one of :data:`FEEDBACK_MODES`.

    Notes
    -----
    Lines go to the ``sys.stderr`` of the moment they are printed (a
    captured or redirected stream included); in ``"bars"`` mode through
    ``tqdm.write``, so that they do not tear a bar being drawn. Errors and
    warnings are not feedback: they are raised and warned whatever the mode.
    """

    def __init__(self, mode: str = "notes", prefix: str = "seed2gs"):
        if mode not in FEEDBACK_MODES:
            raise ValidationError(f"feedback mode must be one of {', '.join(FEEDBACK_MODES)}, got {mode!r}")
        self.mode, self.prefix = mode, str(prefix)

    @classmethod
    def of(cls, progress, prefix: str = "seed2gs") -> Feedback:
        """The feedback a ``progress`` argument asks for.

        Parameters
        ----------
        progress : None, bool, "bars", "lines" or Feedback
            None: bars when stderr is a terminal, else only the notices;
            True or ``"bars"``: bars; ``"lines"``: stage lines; False: nothing
            (``"quiet"``); a Feedback: itself.
        prefix : str
            As :class:`Feedback`.

        Raises
        ------
        ValidationError
            Any other value (naming ``progress`` and the choices).
        """
        if isinstance(progress, Feedback):
            return progress
        progress = check_progress(progress)
        if progress is None:
            return cls("bars" if _stderr_is_terminal() else "notes", prefix)
        if isinstance(progress, bool):
            return cls("bars" if progress else "quiet", prefix)
        return cls(progress, prefix)

    @property
    def bars(self) -> bool:
        """Whether stages draw progress bars."""
        return self.mode == "bars"

    @property
    def lines(self) -> bool:
        """Whether finished stages and jobs are said in one line each."""
        return self.mode == "lines"

    @property
    def quiet(self) -> bool:
        """Whether nothing at all is said."""
        return self.mode == "quiet"

    def bar(self, desc: str, total: int | None = None, unit: str = "it", steps: bool = True) -> Progress:
        """A :class:`Progress` bar for a ``with`` block, drawn only in ``"bars"`` mode (arguments as its)."""
        return Progress(desc, self.bars, total=total, unit=unit, steps=steps)

    def _print(self, text: str) -> None:
        line = f"{self.prefix}: {text}"
        if self.bars:
            tqdm.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr, flush=True)

    def step(self, text: str) -> None:
        """Say that a stage or job finished (``"lines"`` mode only)."""
        if self.lines:
            self._print(text)

    def stage(self, name: str, seconds: float) -> None:
        """Say that stage ``name`` ended after ``seconds`` (``"lines"`` mode only)."""
        self.step(f"{name} {seconds:.2f} s")

    def note(self, text: str) -> None:
        """Say ``text`` unless quiet (a notice such as a first-run compilation)."""
        if not self.quiet:
            self._print(text)

    def compiled(self, seconds: float, stage: str) -> None:
        """Say that compiling took ``seconds`` during ``stage``, which does not count them (unless quiet)."""
        self.note(f"compiled the rasterizer kernels in {seconds:.1f} s (cached for later runs; not counted "
                  f"in the {stage} stage's seconds)")

    @contextlib.contextmanager
    def active(self) -> Iterator[Feedback]:
        """Make this the feedback of :func:`notice` for the ``with`` block (in this thread or task)."""
        token = _ACTIVE.set(self)
        try:
            yield self
        finally:
            _ACTIVE.reset(token)


def notice(text: str) -> None:
    """Say ``text`` on stderr through the active :class:`Feedback` (``"notes"`` when none is; quiet: nothing)."""
    feedback = _ACTIVE.get()
    (feedback if feedback is not None else Feedback("notes")).note(text)


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
        Steps expected (None: a counter without a total, which still shows
        the seconds elapsed).
    unit : str
        What a step is (``"it"``, ``"view"``).
    steps : bool
        False: a stage without steps to count; the bar shows its label and
        the time elapsed only.

    Notes
    -----
    ``update(n)`` counts steps. :attr:`solve_callback` shows a solver's
    iterations against the method's maximum and the current loss. The bar
    appears once the block has run :attr:`DELAY` seconds, so quick stages
    leave no trace, and a thread redraws it every :attr:`TICK` seconds, so its
    elapsed time runs on between steps. It is drawn on the ``sys.stderr`` of
    the moment the block is entered (a captured or redirected stream
    included).
    """

    #: Seconds between redraws on updates (tqdm's ``mininterval``).
    MININTERVAL = 0.1
    #: Seconds a block runs before its bar appears (tqdm's ``delay``).
    DELAY = 1.0
    #: Seconds between redraws without updates.
    TICK = 0.5

    def __init__(self, desc: str, enabled: bool, total: int | None = None, unit: str = "it", steps: bool = True):
        self.desc, self.enabled, self.total, self.unit, self.steps = desc, bool(enabled), total, unit, bool(steps)
        self._bar = None
        self._stop = None
        self._ticker = None
        self._lock = threading.Lock()  # the ticker's redraws and the caller's updates, one at a time

    def __enter__(self) -> Progress:
        if self.enabled:
            # miniters=0: every update may redraw (at most every MININTERVAL), also an update(0) of the ticker
            self._bar = tqdm(total=self.total, desc=self.desc, unit=self.unit, leave=False, file=sys.stderr,
                             mininterval=self.MININTERVAL, miniters=0, delay=self.DELAY,
                             bar_format=None if self.steps else "{desc}: {elapsed}")
            self._stop = threading.Event()
            self._ticker = threading.Thread(target=self._tick, name="seed2gs-progress", daemon=True)
            self._ticker.start()
        return self

    def _tick(self) -> None:
        """Redraw the bar every :attr:`TICK` seconds until the block ends.

        An ``update(0)`` rather than a bare redraw, so that tqdm knows the bar
        was drawn and clears it on closing.
        """
        bar, stop = self._bar, self._stop
        while not stop.wait(self.TICK):
            with self._lock:
                bar.update(0)

    def update(self, n: int = 1) -> None:
        """Count ``n`` more steps."""
        if self._bar is not None:
            with self._lock:
                self._bar.update(n)

    @property
    def solve_callback(self) -> Callable[[SolveProgress], None] | None:
        """The ``solve(..., progress=)`` hook drawing on this bar.

        None when disabled, so the solver skips its reports.
        """
        return self._solve_step if self._bar is not None else None

    def _solve_step(self, p: SolveProgress) -> None:
        with self._lock:
            if p.total is not None and self._bar.total != p.total:
                self._bar.total = p.total
            if p.loss is not None:
                self._bar.set_postfix_str(f"loss {p.loss:.5g}", refresh=False)
            self._bar.update(p.iteration - self._bar.n)

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._stop.set()
            self._ticker.join()
            self._bar.close()
            self._bar = self._stop = self._ticker = None


class StageTimer:
    """Wall seconds per stage: ``with timer("lift"): ...`` adds to ``timer.seconds["lift"]``.

    Parameters
    ----------
    stages : sequence of str
        The stages, in the order ``seconds`` lists them (each starts at 0).
    compile_clock : callable, optional
        ``compile_clock() -> float``: seconds spent compiling so far (in the
        calling thread). The time it counts during a stage is left out of the
        stage and added to ``seconds["compile"]`` (:data:`COMPILE`, listed
        after the stages), and said by ``feedback``.
    feedback : Feedback, optional
        Told when a stage ends (:meth:`Feedback.stage`) and when compiling
        took time (:meth:`Feedback.compiled`); default: says nothing.

    Notes
    -----
    A stage timed in several blocks says its line once: every block but its
    last is entered with ``last=False``, and :meth:`finish` says it after
    time has been moved into or out of it (:meth:`move`). A block that
    raises says no line.
    """

    def __init__(self, stages: Sequence[str], compile_clock: Callable[[], float] | None = None,
                 feedback: Feedback | None = None):
        self.seconds = dict.fromkeys(stages, 0.0)
        if compile_clock is not None:
            self.seconds[COMPILE] = 0.0
        self._clock = compile_clock
        self._feedback = feedback if feedback is not None else Feedback("quiet")

    @contextlib.contextmanager
    def __call__(self, stage: str, *, last: bool = True) -> Iterator[None]:
        t0 = time.perf_counter()
        c0 = self._clock() if self._clock is not None else 0.0
        try:
            yield
        finally:
            compiling = self._clock() - c0 if self._clock is not None else 0.0
            self.seconds[stage] += time.perf_counter() - t0 - compiling
            if compiling > 0:
                self.seconds[COMPILE] += compiling
                self._feedback.compiled(compiling, stage)
        if last:  # not reached when the block raised
            self.finish(stage)

    def finish(self, stage: str) -> None:
        """Say that ``stage`` ended, with its seconds (its feedback's :meth:`~Feedback.stage`)."""
        self._feedback.stage(stage, self.seconds[stage])

    def move(self, src: str, dst: str, seconds: float) -> None:
        """Count ``seconds`` measured inside stage ``src`` under ``dst`` instead."""
        self.seconds[src] -= seconds
        self.seconds[dst] += seconds
