"""``seed2gs solve`` and ``seed2gs compare``: inverse solvers on saved operators.

A masks directory holds one file per view, in view order: ``view_000.png``
(8-bit greyscale; 0/255 become 0/1, colour images are converted to grey)
or ``view_000.npy`` (float in [0, 1] with NaN for unknown pixels, bool or
uint8), read by :func:`seed2gs_inverse.io.read_masks`. The count must equal
the operator directory's view count and each mask must have its view's size.
"""

from __future__ import annotations

import io
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from .._atomic import atomic_path, write_files
from .._output_paths import locks_outputs
from ..comparison import compare, holdout_views
from ..errors import ValidationError
from ..io import read_masks
from ..io._common import load_npy
from ..operators import OperatorStack
from ..progress import Progress as _Progress
from ..solvers import available_methods, solve
from ..solvers._common import prior_from_init
from ..solvers.inputs import load_solve_inputs
from ._common import SolveBar, add_method_arguments, check_output, parse_options, progress_enabled

__all__ = ["register", "solve_command", "compare_command"]


def register(subparsers) -> None:
    """Add the ``solve`` and ``compare`` commands to ``subparsers``."""
    p = subparsers.add_parser(
        "solve", help="recover per-Gaussian membership q from masks",
        description="Fit per-Gaussian foreground probabilities q to one mask per view with a solver "
                    "and save q (N,) float32 as .npy. With --from-extraction OUT (an output of seed2gs "
                    "extract --save-operators) the solve takes the run's prior, regulariser graph and "
                    "settings, and reproduces OUT/q.npy exactly.")
    p.add_argument("operators", metavar="OPS_DIR",
                   help="operator directory (seed2gs operators build, or OUT/operators of extract --save-operators)")
    p.add_argument("masks", metavar="MASKS_DIR", help="view_000.png|npy ... one mask per view")
    add_method_arguments(p)
    p.set_defaults(method=None)  # None: not given (weighted_bce, or the extraction's method)
    p.add_argument("-o", "--output", required=True, metavar="Q.npy", help="where to write q")
    p.add_argument("--force", action="store_true", help="replace Q.npy if it exists")
    p.add_argument("--init", metavar="FILE.npy", help="prior: bool support set, indices or float q")
    p.add_argument("--from-extraction", metavar="OUT",
                   help="solve as the extraction in OUT did (extract --save-operators): its prior (init.npy), "
                        "min_evidence, min_vote, smoothness and graph (graph.npz), its method and options unless "
                        "--method/--option say otherwise (solve.json), its faint Gaussians' rule (follow.npz) and its islands "
                        "set to 0 (islands.npy)")
    p.add_argument("--keep-islands", action="store_true",
                   help="with --from-extraction: keep the solver's q on the islands the extraction set to 0")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar (shown only when stderr is a terminal)")
    p.set_defaults(func=solve_command)

    c = subparsers.add_parser(
        "compare", help="compare solvers on held-out views (against labels, or the views' own masks)",
        description="Fit every solver on the same views (every k-th view held out) and score held-out "
                    "2D mIoU/mBIoU: against --truth labels rendered into those views (with 3D "
                    "precision/recall/IoU), or without --truth against the held-out views' own masks on "
                    "their known pixels (NaN pixels ignored). Print a table and optionally write "
                    "comparison.csv, comparison.json and comparison.png to -o DIR.")
    c.add_argument("operators", metavar="OPS_DIR",
                   help="operator directory (seed2gs operators build, or OUT/operators of extract --save-operators)")
    c.add_argument("masks", metavar="MASKS_DIR", help="view_000.png|npy ... one mask per view")
    c.add_argument("--truth", metavar="LABELS.npy",
                   help="(N,) bool ground-truth membership (default: score against the held-out masks)")
    c.add_argument("--methods", metavar="M1,M2,...",
                   help=f"comma-separated methods out of {', '.join(available_methods())} (default: all)")
    c.add_argument("--holdout-every", type=int, default=4, help="hold out every k-th view (0: none; default 4)")
    c.add_argument("-o", "--output", metavar="DIR", help="directory for comparison.{csv,json,png} (created)")
    c.add_argument("--force", action="store_true",
                   help="replace DIR when it is an earlier report of compare (a folder of other files is refused)")
    c.add_argument("--no-progress", action="store_true",
                   help="no progress bar (shown only when stderr is a terminal)")
    c.set_defaults(func=compare_command)


def _npy_bytes(arr) -> bytes:
    """The bytes of ``arr`` saved as a .npy file (no pickles)."""
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


@locks_outputs(("output", "-o"))
def solve_command(args) -> int:
    """``seed2gs solve``: fit q to the masks with one method and write it as ``.npy``."""
    if args.method is not None or not args.from_extraction:  # fail fast on a typo, before loading anything
        parse_options(args.option, args.method or "weighted_bce")
    if args.from_extraction and args.init:
        raise ValidationError(f"--init {args.init}: --from-extraction {args.from_extraction} gives the prior "
                              f"(its init.npy); give one of them")
    if args.keep_islands and not args.from_extraction:
        raise ValidationError("--keep-islands goes with --from-extraction (the islands an extraction set to 0)")
    if Path(args.output).suffix.lower() != ".npy":
        raise ValidationError(f"-o {args.output}: the output must be a .npy file")
    out = check_output(args.output, "-o", force=args.force)
    if args.from_extraction:
        result, note = _solve_as_extracted(args)
    else:
        method = args.method or "weighted_bce"
        stack = OperatorStack.load(args.operators, mmap=True)
        init = None
        if args.init:
            init = load_npy(args.init, f"--init {args.init}")
            try:  # checked here so that the message names the option and file
                prior_from_init(init, stack.n_gaussians)
            except ValidationError as exc:
                raise ValidationError(f"--init {args.init}: {str(exc).removeprefix('init: ')}") from None
        masks = read_masks(args.masks, len(stack), stack.image_shapes)
        _say_solving(stack, method)
        with SolveBar(method, progress_enabled(args.no_progress)) as bar:
            result = solve(stack, masks, method=method, init=init, progress=bar.solve_callback,
                           **parse_options(args.option, method))
        note = ""
    write_files([(out, _npy_bytes(result.q))], replace=args.force)
    sel = result.selected()
    print(f"{out}: method {result.method}, {int(sel.sum()):,} of {sel.size:,} Gaussians selected "
          f"(q > {result.threshold:.3g}), {int(result.unobserved.sum()):,} unobserved, "
          f"{result.iterations} iterations, {result.seconds:.2f} s{note}")
    return 0


def _say_solving(stack, method: str, extra: str = "") -> None:
    print(f"solving {len(stack)} views, {stack.n_gaussians:,} Gaussians with {method}{extra} ...",
          file=sys.stderr, flush=True)


def _solve_as_extracted(args):
    """``(result, note)`` of ``solve --from-extraction OUT``: the run's inputs and settings, and what the
    islands rule did (the end of the summary line)."""
    inputs = load_solve_inputs(args.from_extraction, operators=args.operators, masks=args.masks)
    method = args.method or inputs.method
    options = parse_options(args.option, method)
    where = f"--from-extraction {args.from_extraction}"
    said = (f" (as {where}: prior, min_evidence {inputs.min_evidence:g}, min_vote {inputs.min_vote:g}, "
            f"smoothness {inputs.smoothness:g}"
            + (", graph" if inputs.graph is not None else "") + ")")
    _say_solving(inputs.operators, method, said)
    with SolveBar(method, progress_enabled(args.no_progress)) as bar:
        result = inputs.solve(method if args.method else None, keep_islands=args.keep_islands,
                              progress=bar.solve_callback, **options)
    n = int(inputs.islands.size)
    note = ""
    if n:
        note = (f"; the extraction's {n:,} island Gaussian(s) kept as the solver gave them" if args.keep_islands
                else f"; {n:,} island Gaussian(s) set to 0 as the extraction did (--keep-islands keeps them)")
    return result, note


@locks_outputs(("output", "-o"))
def compare_command(args) -> int:
    """``seed2gs compare``: fit every method, print the score table, optionally write the report."""
    methods = [m.strip() for m in args.methods.split(",") if m.strip()] if args.methods else None
    for m in methods or []:
        if m not in available_methods():
            raise ValidationError(f"--methods: unknown method {m!r}; available: {', '.join(available_methods())}")
    if methods is not None and not methods:
        raise ValidationError("--methods: give at least one method")
    if methods is not None and len(set(methods)) != len(methods):
        raise ValidationError(f"--methods: each method once, got {args.methods}")
    if args.output:
        check_output(args.output, "-o", directory=True, force=args.force, kind="compare")  # DIR is written at the end
    truth = None if args.truth is None else _read_truth(args.truth)
    stack = OperatorStack.load(args.operators, mmap=True)
    if truth is not None and truth.shape != (stack.n_gaussians,):
        raise ValidationError(f"--truth {args.truth}: {truth.size:,} labels in shape {truth.shape}, the operators' "
                              f"scene has {stack.n_gaussians:,} Gaussians; give one label per Gaussian")
    try:  # before any solve
        holdout_views(len(stack), args.holdout_every)
    except ValidationError:
        raise ValidationError(f"--holdout-every {args.holdout_every}: must be 0 (none) or a whole number >= 2") from None
    masks = read_masks(args.masks, len(stack), stack.image_shapes)
    against = "the truth labels" if truth is not None else "the views' own masks (no --truth)"
    print(f"comparing {', '.join(methods) if methods else 'every method'} on {len(stack)} views, scored against "
          f"{against} ...", file=sys.stderr, flush=True)
    with _CompareBar(progress_enabled(args.no_progress), len(methods or available_methods())) as bar:
        result = compare(stack, masks, truth, methods=methods, holdout_every=args.holdout_every,
                         progress=bar.callback)
    print(result.format())
    if args.output:
        d = Path(args.output)
        png = io.BytesIO()
        result.plot(png)
        with atomic_path(d, directory=True, replace=args.force) as tmp:  # all or nothing; only --force replaces
            (tmp / "comparison.csv").write_bytes(result.to_csv().encode())
            (tmp / "comparison.json").write_bytes(result.to_json().encode())
            (tmp / "comparison.png").write_bytes(png.getvalue())
        print(f"wrote {d / 'comparison.csv'}, {d / 'comparison.json'}, {d / 'comparison.png'}")
    return 0


def _read_truth(path) -> np.ndarray:
    """``--truth LABELS.npy`` as bool labels (0/1 integers accepted), or a ValidationError naming the file."""
    truth = load_npy(path, f"--truth {path}")
    if truth.dtype != bool:
        if truth.dtype.kind in "ui" and truth.size and set(np.unique(truth).tolist()) <= {0, 1}:
            truth = truth.astype(bool)
        else:
            raise ValidationError(f"--truth {path}: labels must be bool (or 0/1 integers), got {truth.dtype}")
    return truth


class _CompareBar:
    """One tqdm bar over the methods of ``compare``, showing the current method's iteration and loss."""

    def __init__(self, enabled: bool, n_methods: int):
        self.enabled, self.n = bool(enabled), int(n_methods)
        self._bar = None

    def __enter__(self):
        if self.enabled:
            self._bar = tqdm(total=self.n, desc="compare", unit="method", leave=False, file=sys.stderr,
                             mininterval=_Progress.MININTERVAL)
        return self

    @property
    def callback(self):
        """The ``compare(progress=...)`` callback, or None when the bar is disabled."""
        return self._update if self._bar is not None else None

    def _update(self, method, k, n, step) -> None:
        """Advance on a finished method; otherwise show its iteration and loss."""
        if step is None:
            self._bar.update(1)
            self._bar.set_postfix_str(f"{method} done", refresh=True)
        else:
            total = "" if step.total is None else f"/{step.total}"
            loss = "" if step.loss is None else f", loss {step.loss:.5g}"
            self._bar.set_postfix_str(f"{method} it {step.iteration}{total}{loss}", refresh=False)

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
