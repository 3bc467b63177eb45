"""A solve's inputs saved beside its result: :func:`load_solve_inputs` and :class:`SolveInputs`.

``seed2gs extract --save-operators`` (and
:func:`~seed2gs_inverse.pipeline.outputs.save_extraction` with
``save_operators=True``) writes, with :func:`write_solve_inputs`, everything
the run's solve took, so that solving again reproduces its ``q``::

    DIR/solve.json      {"format": "seed2gs-solve-inputs", "version": 1,
                         "n_gaussians": N, "n_views": V, "fingerprint": "...",
                         "operators": "operators", "masks": "masks",
                         "method": "...", "options": {...},
                         "min_evidence": ..., "min_vote": ..., "smoothness": ..., "threshold": ...,
                         "init": "init.npy", "graph": "graph.npz" | null,
                         "follow": "follow.npz" | null, "islands": "islands.npy" | null}
    DIR/operators/      the OperatorStack (OperatorStack.save)
    DIR/masks/          view_000.npy ... float32 masks Y(c), NaN = unknown, in view order
    DIR/init.npy        the prior (bool support set, indices or float q)
    DIR/graph.npz       the regulariser's graph (scipy.sparse.save_npz, uncompressed), when smoothness > 0
    DIR/follow.npz      the faint Gaussians' follow matrix applied after the solve (graph.follow_matrix), when used
    DIR/islands.npy     int64 indices set to 0 after the solve (the run's post-solve rule), when any rule ran

After the solve, :meth:`SolveInputs.solve` applies the run's post-solve
rules in the run's order: the follow matrix
(:func:`~seed2gs_inverse.graph.apply_follow`), then the islands set to 0.
Nothing is unpickled when loading; every file is validated against the
operators (Gaussian count, view count, fingerprint) and errors name the file.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from .._selection import index_list
from .._validation import check_real
from ..errors import FormatError, ValidationError
from ..graph import apply_follow, check_follow, check_graph
from ..io import read_masks
from ..io._common import check_compression_ratio, check_regular, load_npy
from ..io.tables import read_small_file
from ..operators import OperatorStack
from . import check_method_options, solve
from ._common import SolveResult, normalize_mask, prior_from_init

__all__ = ["SolveInputs", "load_solve_inputs", "write_solve_inputs", "SETTINGS_FILE", "FORMAT_NAME",
           "FORMAT_VERSION", "FILES"]

FORMAT_NAME = "seed2gs-solve-inputs"
FORMAT_VERSION = 1
#: The settings file of a folder of solve inputs.
SETTINGS_FILE = "solve.json"
#: The names :func:`write_solve_inputs` may write, by role.
FILES = {"solve": SETTINGS_FILE, "operators": "operators", "masks": "masks", "init": "init.npy",
         "graph": "graph.npz", "follow": "follow.npz", "islands": "islands.npy"}


@dataclass
class SolveInputs:
    """Everything one solve took: operators, masks, prior, regulariser and settings.

    Attributes
    ----------
    operators : OperatorStack
    masks : list of (H, W) float32
        One mask per view, NaN = unknown.
    method : str
    options : dict
        The method's options as the run used them.
    init : ndarray or None
        The prior (``solve(init=)``).
    min_evidence, smoothness : float
        ``solve``'s options common to every method.
    graph : scipy.sparse (N, N) or None
        The regulariser's graph (needed when ``smoothness > 0``).
    follow : scipy.sparse (N, N) or None
        The faint Gaussians' rows the run applied to the solver's ``q``
        (:func:`~seed2gs_inverse.graph.apply_follow`; None when it did not).
    islands : (K,) int64
        Gaussians the run set to 0 after its solve and ``follow`` (the extraction's
        islands apart from the seeded object,
        ``ExtractSettings.seed_connected``); empty when none.
    threshold : float or None
        The threshold the run selected with (``q > threshold``).
    directory : Path or None
        Where the inputs were read from.
    min_vote : float
        ``solve``'s ``min_vote`` (0 in files written before it existed:
        those runs solved without it).
    """

    operators: OperatorStack
    masks: list
    method: str
    options: dict = field(default_factory=dict)
    init: np.ndarray | None = None
    min_evidence: float = 0.0
    smoothness: float = 0.0
    graph: sp.spmatrix | None = None
    follow: sp.spmatrix | None = None
    islands: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    threshold: float | None = None
    directory: Path | None = None
    min_vote: float = 0.0

    def solve(self, method: str | None = None, *, keep_islands: bool = False, progress=None,
              **options) -> SolveResult:
        """Solve again: the run's ``q`` for its own method and options.

        Parameters
        ----------
        method : str, optional
            Default: the run's :attr:`method`, with :attr:`options` updated
            by ``options``. Another method takes ``options`` alone (the
            run's options belong to its method). Every method gets the
            run's ``init``, ``min_evidence``, ``min_vote``, ``smoothness`` and ``graph``.
        keep_islands : bool
            False (default): apply :attr:`follow` and set :attr:`islands` to
            0, as the run did, so the run's own method gives the run's ``q``
            exactly. True: the solver's ``q`` with :attr:`follow` applied
            (the faint Gaussians' rule is part of the membership, not a
            clean-up).
        progress : callable, optional
            As for :func:`~seed2gs_inverse.solvers.solve`.
        **options
            Method options.

        Returns
        -------
        SolveResult
            With the run's method, ``threshold`` is the run's
            :attr:`threshold` (so ``selected()`` is the run's selection).

        Raises
        ------
        ValidationError
            As :func:`~seed2gs_inverse.solvers.solve`.
        """
        m = self.method if method is None else method
        opts = {**self.options, **options} if m == self.method else dict(options)
        result = solve(self.operators, self.masks, method=m, init=self.init, min_evidence=self.min_evidence,
                       min_vote=self.min_vote, smoothness=self.smoothness, graph=self.graph, progress=progress,
                       **opts)
        # the run's post-solve rules, in its order
        q = np.array(result.q, dtype=np.float32)
        if self.follow is not None:
            q = apply_follow(q, self.follow)
        if not keep_islands:
            q[self.islands] = np.float32(0)
        changes = {"q": q}
        if m == self.method and self.threshold is not None:
            changes["threshold"] = float(self.threshold)
        return dataclasses.replace(result, **changes)


def _plain(value):
    """``value`` with numpy scalars and tuples turned into JSON types."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_solve_inputs(directory, operators: OperatorStack, masks, *, method: str, options: dict | None = None,
                       init=None, min_evidence: float = 0.0, smoothness: float = 0.0, graph=None, follow=None,
                       islands=None, threshold: float | None = None, min_vote: float = 0.0) -> dict:
    """Write a solve's inputs into the existing folder ``directory`` (layout: the module docstring).

    Parameters
    ----------
    directory : path
        An existing folder holding none of :data:`FILES`. The files are
        written in place: write into a temporary folder renamed at the end
        for an all-or-nothing output (as
        :func:`~seed2gs_inverse.pipeline.outputs.save_extraction` does).
    operators : OperatorStack
    masks : sequence of arrays
        One mask per view (any form :func:`~seed2gs_inverse.solvers.solve`
        takes); written as float32 ``view_NNN.npy``, NaN = unknown.
    method : str
    options : dict, optional
        The method's options (JSON numbers, strings and booleans).
    init : optional
        The prior (``solve(init=)``); None writes no ``init.npy``.
    min_evidence, smoothness : float
        ``solve``'s common options, each >= 0.
    graph : scipy.sparse (N, N), optional
        Required when ``smoothness > 0``; written only then.
    follow : scipy.sparse (N, N), optional
        The follow matrix applied after the solve
        (:func:`~seed2gs_inverse.graph.follow_matrix`); None: none was.
    islands : int indices or bool (N,), optional
        Gaussians set to 0 after the solve and ``follow``; None: no post-solve rule ran.
    threshold : float, optional
        The selection threshold of the run, in [0, 1).
    min_vote : float
        ``solve``'s ``min_vote``, in [0, 1].

    Returns
    -------
    dict
        role -> name written (of :data:`FILES`).

    Raises
    ------
    ValidationError
        A bad argument (named), or a name of :data:`FILES` that exists.
    """
    d = Path(directory)
    if not d.is_dir():
        raise ValidationError(f"write_solve_inputs: {d} is not an existing folder")
    taken = [name for name in FILES.values() if os.path.lexists(d / name)]
    if taken:
        raise ValidationError(f"write_solve_inputs: {d} already holds {', '.join(taken)}")
    if not isinstance(operators, OperatorStack):
        raise ValidationError(f"write_solve_inputs: operators must be an OperatorStack, got {type(operators).__name__}")
    masks = list(masks)
    if len(masks) != len(operators):
        raise ValidationError(f"write_solve_inputs: {len(masks)} masks for {len(operators)} views")
    n = operators.n_gaussians
    options = _plain(dict(options or {}))
    check_method_options(method, options)
    min_evidence = check_real("min_evidence", min_evidence, lo=0.0)
    min_vote = check_real("min_vote", min_vote, lo=0.0, hi=1.0)
    smoothness = check_real("smoothness", smoothness, lo=0.0)
    threshold = check_real("threshold", threshold, lo=0.0, hi=1.0, hi_open=True, optional=True)
    if smoothness > 0 and graph is None:
        raise ValidationError("write_solve_inputs: smoothness > 0 needs the graph the solve used")
    ys = [normalize_mask(m, v.image_shape, f"mask {i}").reshape(v.image_shape) for i, (v, m) in
          enumerate(zip(operators, masks))]
    if init is not None:
        prior_from_init(init, n)  # checked before anything is written
    g = None if smoothness == 0 else check_graph(graph, n)
    fol = None if follow is None else check_follow(follow, n)
    isl = None if islands is None else index_list(islands, n, "islands")
    written = {"solve": SETTINGS_FILE, "operators": FILES["operators"], "masks": FILES["masks"]}
    operators.save(d / FILES["operators"])
    (d / FILES["masks"]).mkdir()
    for i, y in enumerate(ys):
        np.save(d / FILES["masks"] / f"view_{i:03d}.npy", y, allow_pickle=False)
    if init is not None:
        np.save(d / FILES["init"], np.asarray(init), allow_pickle=False)
        written["init"] = FILES["init"]
    if g is not None:
        sp.save_npz(d / FILES["graph"], sp.csr_matrix(graph), compressed=False)
        written["graph"] = FILES["graph"]
    if fol is not None:
        sp.save_npz(d / FILES["follow"], fol, compressed=False)
        written["follow"] = FILES["follow"]
    if isl is not None:
        np.save(d / FILES["islands"], isl.astype(np.int64), allow_pickle=False)
        written["islands"] = FILES["islands"]
    settings = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "n_gaussians": int(n),
                "n_views": len(operators), "fingerprint": operators.fingerprint,
                "operators": FILES["operators"], "masks": FILES["masks"], "method": method, "options": options,
                "min_evidence": min_evidence, "min_vote": min_vote, "smoothness": smoothness, "threshold": threshold,
                "init": written.get("init"), "graph": written.get("graph"), "follow": written.get("follow"),
                "islands": written.get("islands")}
    with open(d / SETTINGS_FILE, "w", encoding="utf-8") as fh:
        json.dump(settings, fh, indent=1)
    return written


def _read_settings(d: Path) -> tuple[Path, dict]:
    path = d / SETTINGS_FILE
    if not d.is_dir():
        raise ValidationError(f"{d}: not a folder; give the output folder of seed2gs extract --save-operators")
    try:
        raw = read_small_file(path, "solve settings file")
    except FileNotFoundError:
        raise ValidationError(f"{d}: no {SETTINGS_FILE}; the folder holds no saved solve (write one with "
                              f"seed2gs extract --save-operators)") from None
    try:
        rec = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise FormatError(f"{path}: not a JSON file ({type(exc).__name__})") from None
    if not isinstance(rec, dict) or rec.get("format") != FORMAT_NAME:
        raise FormatError(f"{path}: not a seed2gs solve settings file (format must be '{FORMAT_NAME}')")
    if rec.get("version") != FORMAT_VERSION or isinstance(rec.get("version"), bool):
        raise FormatError(f"{path}: unsupported version {rec.get('version')!r}; this reader knows {FORMAT_VERSION}")
    return path, rec


def _field(path: Path, rec: dict, key: str, ok, what: str, default=None, required: bool = True):
    if key not in rec or (rec[key] is None and not required):
        if required:
            raise FormatError(f"{path}: no '{key}'; write the folder again with seed2gs extract --save-operators")
        return default
    if not ok(rec[key]):
        raise FormatError(f"{path}: '{key}' must be {what}, got {json.dumps(rec[key])[:60]}")
    return rec[key]


def _is_name(v) -> bool:
    """A plain file name inside the folder (no separators, no parent)."""
    return isinstance(v, str) and v not in ("", ".", "..") and Path(v).name == v and "\0" not in v


def _is_real(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0


def _load_sparse(path: Path, n: int, what: str, check) -> sp.csr_matrix:
    """The matrix of ``path`` (``graph.npz``, ``follow.npz``): never unpickled, its declared size checked first,
    then ``check`` (:func:`check_graph`, :func:`check_follow`)."""
    check_regular(path, "graph file")
    try:
        with zipfile.ZipFile(path) as z:
            claimed = sum(info.file_size for info in z.infolist())
        check_compression_ratio(path, claimed, os.path.getsize(path), f"a {what}")
        g = sp.load_npz(path)
    except FileNotFoundError:
        raise ValidationError(f"{path}: no such file (solve.json names it)") from None
    except (zipfile.BadZipFile, ValueError, KeyError, OSError, EOFError) as exc:
        raise FormatError(f"{path}: not a sparse {what} written by scipy.sparse.save_npz ({exc})") from None
    return check(g, n, name=str(path))


def _npy(path: Path, label: str) -> np.ndarray:
    if not path.exists():
        raise ValidationError(f"{path}: no such file ({label})")
    return load_npy(path, f"{path}")


def load_solve_inputs(directory, operators=None, masks=None) -> SolveInputs:
    """Read the solve inputs of ``directory`` (an ``extract --save-operators`` output folder).

    Parameters
    ----------
    directory : path
        The folder holding ``solve.json``.
    operators : path, optional
        An operator directory to use instead of the one ``solve.json``
        names (it must hold as many views and Gaussians, and the same
        scene fingerprint).
    masks : path, optional
        A masks folder (:func:`~seed2gs_inverse.io.read_masks`) to use
        instead of the one ``solve.json`` names.

    Returns
    -------
    SolveInputs
        Its operators memory-mapped.

    Raises
    ------
    FormatError
        ``solve.json`` or a file it names is not what it should be (the
        message names the file).
    ValidationError
        The folder or a named file is missing, or a file does not fit the
        operators (Gaussian count, view count, scene fingerprint).
    """
    d = Path(directory)
    path, rec = _read_settings(d)
    n = _field(path, rec, "n_gaussians", lambda v: isinstance(v, int) and not isinstance(v, bool) and v > 0,
               "a positive whole number")
    n_views = _field(path, rec, "n_views", lambda v: isinstance(v, int) and not isinstance(v, bool) and v > 0,
                     "a positive whole number")
    fingerprint = _field(path, rec, "fingerprint", lambda v: isinstance(v, str), "a string", required=False)
    method = _field(path, rec, "method", lambda v: isinstance(v, str), "a method name")
    options = _field(path, rec, "options", lambda v: isinstance(v, dict), "a section (a JSON object)")
    try:
        check_method_options(method, options)
    except ValidationError as exc:
        raise FormatError(f"{path}: {exc}") from None
    min_evidence = float(_field(path, rec, "min_evidence", _is_real, "a finite number >= 0"))
    smoothness = float(_field(path, rec, "smoothness", _is_real, "a finite number >= 0"))
    # 0 for a folder written before min_vote existed: that run solved without it
    min_vote = float(_field(path, rec, "min_vote", lambda v: _is_real(v) and v <= 1, "a number in [0, 1]",
                            default=0.0, required=False))
    threshold = _field(path, rec, "threshold", lambda v: _is_real(v) and v < 1, "a number in [0, 1)",
                       required=False)
    names = {key: _field(path, rec, key, _is_name, "a file name inside the folder", required=key not in
                         ("init", "graph", "follow", "islands"))
             for key in ("operators", "masks", "init", "graph", "follow", "islands")}
    if smoothness > 0 and names["graph"] is None:
        raise FormatError(f"{path}: smoothness {smoothness:g} needs a 'graph' file")
    ops_dir = d / names["operators"] if operators is None else Path(operators)
    stack = OperatorStack.load(ops_dir, mmap=True)
    if stack.n_gaussians != n or len(stack) != n_views:
        raise ValidationError(f"{ops_dir}: {len(stack)} views of {stack.n_gaussians:,} Gaussians, but {path} was "
                              f"saved for {n_views} views of {n:,}; give the operators saved with it")
    if fingerprint is not None and stack.fingerprint is not None and stack.fingerprint != fingerprint:
        raise ValidationError(f"{ops_dir}: scene fingerprint {stack.fingerprint}, but {path} was saved for "
                              f"{fingerprint}; the operators belong to another scene")
    ys = read_masks(d / names["masks"] if masks is None else masks, len(stack), stack.image_shapes)
    init = None
    if names["init"] is not None:
        init = _npy(d / names["init"], "the prior solve.json names")
        try:
            prior_from_init(init, n)
        except ValidationError as exc:
            raise ValidationError(f"{d / names['init']}: {str(exc).removeprefix('init: ')}") from None
    graph = (None if names["graph"] is None or smoothness == 0 else
             _load_sparse(d / names["graph"], n, "graph", check_graph))
    follow = None if names["follow"] is None else _load_sparse(d / names["follow"], n, "follow matrix", check_follow)
    islands = np.zeros(0, np.int64)
    if names["islands"] is not None:
        arr = _npy(d / names["islands"], "the islands solve.json names")
        islands = index_list(arr, n, str(d / names["islands"]))
    return SolveInputs(stack, ys, method, dict(options), init, min_evidence, smoothness, graph, follow, islands,
                       None if threshold is None else float(threshold), d, min_vote=min_vote)
