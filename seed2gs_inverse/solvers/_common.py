"""Shared machinery of the solvers: input validation, the stacked problem, results.

Solvers see only operators and masks (never the rasterizer, never Numba).
``prepare`` turns anything :func:`~seed2gs_inverse.operators.as_stack`
accepts (an :class:`~seed2gs_inverse.operators.OperatorStack`, or a list of
views / sparse matrices) and one mask per view into a :class:`Problem`: the
stack as the operator ``A`` (rows = all pixels of all views; its products run
view by view, so no stacked copy of the weights is made) and its transpose,
the flattened masks and which pixels are known. A method
returns a :class:`MethodResult`.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .._selection import support_mask
from .._validation import as_real
from ..errors import ValidationError
from ..operators import as_stack

if TYPE_CHECKING:
    import scipy.sparse as sp
    from scipy.sparse.linalg import LinearOperator

    from ..operators import OperatorStack

__all__ = ["Problem", "SolveResult", "MethodResult", "prepare", "stack_masks", "problem_of", "normalize_mask",
           "prior_from_init",
           "register_method", "available_methods", "get_method", "method_options", "get_check", "check_count", "check_range"]

_METHODS: dict = {}
_CHECKS: dict = {}

#: How far above 1 a pixel's summed weight may lie (float32 sums of many weights) before
#: :attr:`Problem.alpha` refuses the operator.
ALPHA_TOL = 1e-3


def register_method(name: str, fn, check=None) -> None:
    """Make ``fn`` available as ``solve(..., method=name)``.

    ``fn(problem, *, option=default, ...) -> MethodResult`` receives a
    :class:`Problem` and the method's keyword-only options (each with a
    documented default; :func:`method_options` lists them) and returns a
    :class:`MethodResult`: ``q`` ((N,) values in [0, 1]; entries of
    unobserved Gaussians are overwritten by the prior) and optionally
    ``iterations``, ``history``, ``view_weights``, ``threshold``, ``info``
    and ``observed`` ((N,) bool, when the method used fewer views than
    given).

    ``check(options)``, optional, receives every option by name (the
    defaults with the caller's values over them) and raises a
    ValidationError for values the method cannot take, so that
    :func:`~seed2gs_inverse.solvers.check_method_options` (and with it
    ``ExtractSettings`` and the CLI) rejects them before any work. The
    method should call it on its own arguments too.
    """
    if not isinstance(name, str) or not name.isidentifier():
        raise ValidationError(f"method name must be an identifier string, got {name!r}")
    if not callable(fn):
        raise ValidationError(f"method '{name}': fn must be callable")
    if check is not None and not callable(check):
        raise ValidationError(f"method '{name}': check must be callable or None")
    _METHODS[name] = fn
    _CHECKS[name] = check


def check_count(method: str, name: str, value, minimum: int = 1, none_ok: bool = False) -> None:
    """Raise a ValidationError unless option ``name`` of ``method`` is a whole number >= ``minimum``
    (not a bool; None too with ``none_ok``)."""
    if none_ok and value is None:
        return
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < minimum:
        what = {0: "a non-negative integer", 1: "a positive integer"}.get(minimum, f"an integer >= {minimum}")
        raise ValidationError(f"{method}: {name} must be {what}{' or None' if none_ok else ''}, got {value!r}")


def check_range(name: str, value, what: str, lo: float = -np.inf, hi: float = np.inf, lo_open: bool = False,
                hi_open: bool = False) -> float:
    """``value`` as a float when it is a finite real number (not a bool) within ``lo..hi``.

    Parameters
    ----------
    name : str
        The option as the user knows it (``"weighted_bce: r_min"``); it starts the message.
    value : object
    what : str
        The range in words (``"in [0, 1)"``, ``"a positive finite number"``).
    lo, hi : float
        Bounds, inclusive unless ``lo_open`` / ``hi_open``.

    Raises
    ------
    ValidationError
        ``"{name} must be {what}, got {value!r}"``.
    """
    v = as_real(value)
    if v is None or not ((v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)):
        raise ValidationError(f"{name} must be {what}, got {value!r}")
    return v


def get_check(name: str):
    """The value check registered with method ``name`` (None when there is none)."""
    return _CHECKS.get(name)


def available_methods() -> list:
    """Names of the registered solver methods, sorted."""
    return sorted(_METHODS)


def get_method(name: str):
    """The function registered as ``name`` (see :func:`register_method`).

    Raises
    ------
    ValidationError
        No such method (the message lists the available ones).
    """
    if not isinstance(name, str) or name not in _METHODS:
        raise ValidationError(f"unknown method {name!r}; available: {', '.join(available_methods())}")
    return _METHODS[name]


def method_options(name: str) -> dict:
    """The keyword options of method ``name`` with their defaults, in signature order.

    Examples
    --------
    >>> method_options("voting")                                  # doctest: +SKIP
    {'bias': 0.0}
    """
    params = inspect.signature(get_method(name)).parameters
    return {k: p.default for k, p in params.items() if p.kind == p.KEYWORD_ONLY}


def check_options(name: str, fn, options: dict) -> None:
    """Reject options the method does not take, listing those it does."""
    params = inspect.signature(fn).parameters
    if any(p.kind == p.VAR_KEYWORD for p in params.values()):
        return
    known = [k for k, p in params.items() if p.kind == p.KEYWORD_ONLY]
    bad = sorted(set(options) - set(known))
    if bad:
        raise ValidationError(f"method '{name}' has no option(s) {bad}; its options are {known}")


@dataclass
class MethodResult:
    """What a registered method returns to :func:`~seed2gs_inverse.solvers.solve`.

    Attributes
    ----------
    q : (N,) array
        Per-Gaussian foreground probability in [0, 1] (``solve`` clips it and
        gives unobserved Gaussians the prior).
    iterations : int
        Solver iterations (0 for closed forms).
    history : list of dict
        Per-iteration (or per-step) records, method specific.
    view_weights : (V,) array or None
        Final weight of each view; None means all ones.
    threshold : float
        Default selection threshold (0.5 unless the method says otherwise).
    info : dict
        Method-specific extras.
    observed : (N,) bool or None
        The Gaussians the method had evidence for, when it used fewer views
        (or pixels) than given; None means :attr:`Problem.observed`.
    evidence : (N,) float or None
        Each Gaussian's known weight in the views the method used, when
        fewer than given (the regulariser's ``e_i``); None means
        :attr:`Problem.known_weight`.
    """

    q: np.ndarray
    iterations: int = 0
    history: list = field(default_factory=list)
    view_weights: np.ndarray | None = None
    threshold: float = 0.5
    info: dict = field(default_factory=dict)
    observed: np.ndarray | None = None
    evidence: np.ndarray | None = None


@dataclass
class SolveResult:
    """What a solver returns.

    Attributes
    ----------
    q : (N,) float32
        Per-Gaussian foreground probability in [0, 1].
    method : str
    iterations : int
        Solver iterations (0 for closed forms; views absorbed for sequential
        Beta-Bernoulli; L-BFGS-B iterations for weighted_bce).
    history : list of dict
        Per-iteration (or per-step) records, method specific.
    view_weights : (V,) float64
        Final weight of each view (ones for methods that do not weight views).
    unobserved : (N,) bool
        Gaussians with no weight on any known pixel (or that the method did
        not fit, e.g. seen only in views beyond a budget); their ``q`` is the
        prior, or with ``smoothness > 0`` the harmonic extension of their
        neighbours. (Gaussians with some but too little evidence, below
        ``min_evidence``, are treated alike; ``info["n_weak_evidence"]``
        counts all of them.)
    seconds : float
        Wall-clock time of the solve.
    threshold : float
        Default threshold of :meth:`selected` (0.5 unless the method says
        otherwise, e.g. voting with a bias).
    info : dict
        Method-specific extras (e.g. the chosen view order), plus what
        ``solve`` adds for every method: ``min_evidence``,
        ``n_weak_evidence``, ``smoothness``, ``min_vote``,
        ``n_vote_capped``, and the wall-clock split of
        ``seconds`` into ``seconds_method`` (the method itself) and
        ``seconds_smoothing`` (the graph regulariser, or resetting the
        Gaussians without evidence to the prior).
    """

    q: np.ndarray
    method: str
    iterations: int = 0
    history: list = field(default_factory=list)
    view_weights: np.ndarray | None = None
    unobserved: np.ndarray | None = None
    seconds: float = 0.0
    threshold: float = 0.5
    info: dict = field(default_factory=dict)

    def selected(self, threshold: float | None = None) -> np.ndarray:
        """Bool (N,): ``q > threshold`` (default: ``self.threshold``), the threshold in [0, 1)."""
        t = self.threshold if threshold is None else float(threshold)
        if not (np.isfinite(t) and 0.0 <= t < 1.0):  # q lies in [0, 1]: beyond, all or nothing, silently
            raise ValidationError(f"threshold must be in [0, 1), got {threshold!r}")
        return self.q > t

    def __repr__(self) -> str:
        return (f"SolveResult(method={self.method!r}, n={self.q.size}, selected={int((self.q > self.threshold).sum())}, "
                f"iterations={self.iterations}, seconds={self.seconds:.3f})")


@dataclass(eq=False)
class Problem:
    """The stacked inverse problem ``A q ~ y`` over all views.

    Attributes
    ----------
    A : OperatorStack or sparse matrix, (P, N) float32
        All views' operators stacked vertically (P = total pixels), used
        only through ``A @ x``, ``A.shape`` and ``A.dtype``. :func:`prepare`
        gives the :class:`~seed2gs_inverse.operators.OperatorStack` itself,
        whose products run view by view without copying the weights.
    AT : (N, P) operator
        ``A.T`` for the adjoint products (``A.T`` of the stack: no copy).
    y : (P,) float32
        Masks, flattened view after view; 0 at unknown pixels.
    known : (P,) bool
        False where the mask is NaN (no evidence).
    offsets : (V+1,) int64
        View ``c`` is rows ``offsets[c]:offsets[c+1]``.
    image_shapes : list of (H, W)
    names : list of str
        View labels for messages (``view 3 ('orbit_03')``).
    known_weight : (N,) float64
        Each Gaussian's summed weight over the known pixels, ``A^T k``.
    observed : (N,) bool
        Gaussians with nonzero weight on at least one known pixel
        (``known_weight > 0``).
    prior : (N,) float64
        Prior ``q`` (from ``init``); the value of unobserved Gaussians.
    init_given : bool
        Whether the caller passed ``init``.
    """

    A: OperatorStack | sp.spmatrix  # a stack's products run view by view
    AT: LinearOperator | sp.spmatrix
    y: np.ndarray
    known: np.ndarray
    offsets: np.ndarray
    image_shapes: list
    names: list
    known_weight: np.ndarray
    prior: np.ndarray
    init_given: bool = False
    _alpha: np.ndarray | None = None

    @property
    def observed(self) -> np.ndarray:
        return self.known_weight > 0

    @property
    def n_views(self) -> int:
        return len(self.image_shapes)

    @property
    def n_gaussians(self) -> int:
        return int(self.A.shape[1])

    @property
    def alpha(self) -> np.ndarray:
        """(P,) float32 rendered opacity ``A 1`` (row sums), computed once.

        Raises a ValidationError naming the view when a row sums to more
        than 1 (beyond float32 rounding, :data:`ALPHA_TOL`): compositing
        weights cannot, and the methods that read alpha (``weighted_bce``,
        ``least_squares``) rely on ``A q <= alpha <= 1``.
        """
        if self._alpha is None:
            if hasattr(self.A, "row_sums"):
                alpha = self.A.row_sums()
            else:
                alpha = np.asarray(self.A.sum(axis=1), dtype=np.float32).ravel()
            if alpha.size and alpha.max() > 1.0 + ALPHA_TOL:
                u = int(np.argmax(alpha))
                c = int(np.searchsorted(self.offsets, u, side="right")) - 1
                raise ValidationError(
                    f"{_label(c, self.names[c])}: the weights of pixel {u - int(self.offsets[c])} sum to "
                    f"{float(alpha[u]):.6g} > 1; alpha-compositing weights of a pixel sum to its opacity, at "
                    "most 1 (build the operator with the rasterizer, or scale its rows)")
            self._alpha = alpha
        return self._alpha

    def matrix(self):
        """``A`` as one scipy sparse matrix (for a stack: ``stacked()``, a copy of every weight).

        Only for algorithms that need a matrix (``least_squares``'s
        ``lsq_linear``); products go through ``A @ x`` without it.
        """
        return self.A.stacked() if hasattr(self.A, "stacked") else self.A

    def view_matrix(self, c: int):
        """View ``c``'s rows of ``A`` as a sparse matrix (its ``W``: no copy for a stack)."""
        if hasattr(self.A, "views"):
            return self.A.views[c].W
        return self.A[self.view_rows(c)]

    def view_of_rows(self) -> np.ndarray:
        """(P,) int: view index of each row."""
        return np.repeat(np.arange(self.n_views), np.diff(self.offsets))

    def per_view_sum(self, values) -> np.ndarray:
        """Sum a per-pixel (P,) array within each view -> (V,) float64."""
        return np.add.reduceat(np.asarray(values, dtype=np.float64), self.offsets[:-1])

    def view_rows(self, c: int) -> slice:
        return slice(int(self.offsets[c]), int(self.offsets[c + 1]))


def _label(i: int, name: str) -> str:
    return f"view {i}" + (f" ('{name}')" if name else "")


def normalize_mask(mask, image_shape, label: str) -> np.ndarray:
    """One view's mask as float32 in [0, 1] with NaN for unknown pixels.

    Accepted: bool; uint8 0/255 (divided by 255 when any value exceeds 1) or
    0/1; other integers 0/1; floats in [0, 1] or NaN. Shape must be the view's
    ``(H, W)`` (or the flat ``(H*W,)``).
    """
    m = np.asarray(mask)
    h, w = image_shape
    if m.shape not in ((h, w), (h * w,)):
        raise ValidationError(f"{label}: mask has shape {m.shape} but the operator's image is {(h, w)}")
    if m.dtype == bool:
        out = m.astype(np.float32)
    elif m.dtype.kind in "ui":
        if m.dtype == np.uint8 and m.size and int(m.max()) > 1:
            out = m.astype(np.float32) / np.float32(255.0)
        else:
            if m.size and (int(m.min()) < 0 or int(m.max()) > 1):
                raise ValidationError(f"{label}: integer mask values must be 0/1 (or 0/255 as uint8), "
                                      f"got range [{int(m.min())}, {int(m.max())}]")
            out = m.astype(np.float32)
    elif m.dtype.kind == "f":
        out = m.astype(np.float32)
        fin = out[~np.isnan(out)]
        if np.any(np.isinf(fin)):
            raise ValidationError(f"{label}: mask has infinite values; use values in [0, 1] or NaN for unknown")
        if fin.size and (float(fin.min()) < 0 or float(fin.max()) > 1):
            raise ValidationError(f"{label}: mask values must lie in [0, 1] (NaN = unknown), got range "
                                  f"[{float(fin.min()):.4g}, {float(fin.max()):.4g}]")
    else:
        raise ValidationError(f"{label}: mask dtype {m.dtype} is not supported; use bool, uint8 or float")
    return out.reshape(-1)


def prior_from_init(init, n: int) -> np.ndarray:
    """The prior ``q0`` (N,) float64 from ``init``.

    ``None`` -> zeros; a bool (N,) support set -> 1 on the support, 0
    elsewhere; an integer index array -> support given by indices; a float
    (N,) array in [0, 1] -> used as is.
    """
    support, values = prior_parts(init, n)
    return values if support is None else support.astype(np.float64)


def prior_parts(init, n: int) -> tuple:
    """``(support, values)`` of :func:`prior_from_init`'s ``init``: exactly one of them is None.

    A support set (``None``, a bool mask or indices) gives its (N,) bool
    mask and None; a float prior gives None and the (N,) float64 values.
    The checks and messages are :func:`prior_from_init`'s.
    """
    if init is None:
        return np.zeros(n, bool), None
    a = np.asarray(init)
    if a.ndim == 0:  # init=1 would be read as "Gaussian 1", not "everything foreground"
        hint = f"; for one Gaussian's index give [{init!r}]" if a.dtype.kind in "ui" else ""
        raise ValidationError(f"init must be an array (a support mask, indices or a prior q of shape ({n},)), "
                              f"got the single value {init!r}{hint}")
    if a.dtype == bool or a.dtype.kind in "ui":
        return support_mask(a.reshape(-1) if a.dtype != bool else a, n, "init"), None
    if a.dtype.kind == "f":
        if a.shape != (n,):
            raise ValidationError(f"init: a prior q must have shape ({n},), got {a.shape}")
        if not np.all(np.isfinite(a)) or a.min() < 0 or a.max() > 1:
            raise ValidationError("init: prior q must be finite and lie in [0, 1]")
        return None, a.astype(np.float64)
    raise ValidationError(f"init must be None, a bool support mask, indices or a float prior, got dtype {a.dtype}")


def stack_masks(operators, masks) -> tuple[OperatorStack, list]:
    """``(stack, masks as a list)``: :func:`prepare`'s checks of the operators and the mask count.

    Raises
    ------
    ValidationError
        As :func:`prepare` (all but the masks' contents).
    """
    views = getattr(operators, "views", operators)
    if isinstance(masks, np.ndarray) and masks.ndim == 2 and isinstance(views, (list, tuple)) \
            and masks.shape[0] != len(views):
        # (a (V, H*W) array of flat masks is fine; one (H, W) mask would be read row by row)
        raise ValidationError(f"masks: got one {masks.shape} array for {len(views)} views; give a list with one "
                              "mask per view ([mask] for a single view) or a (V, H, W) array")
    try:  # a list once: a generator would be used up by as_stack (the image shapes of bare matrices)
        mask_list = list(masks) if not isinstance(masks, np.ndarray) or masks.ndim >= 2 else None
    except TypeError:
        mask_list = None
    if mask_list is None:
        raise ValidationError("masks must be a sequence with one array per view (or a (V, H, W) array)")
    stack = as_stack(operators, mask_list)
    if len(mask_list) != len(stack):
        raise ValidationError(f"got {len(mask_list)} masks for {len(stack)} views; give one mask per view")
    return stack, mask_list


def prepare(operators, masks, init=None) -> Problem:
    """Validate operators and masks and stack them into a :class:`Problem`.

    A view whose mask is entirely NaN (a lost view) simply carries no
    evidence.

    Raises
    ------
    ValidationError
        Empty stack, mismatched Gaussian counts (operators of different
        scenes), a mask whose shape differs from its view's image, masks of
        the wrong dtype/range, masks that are all NaN in every view, or a
        mask count different from the view count. Messages name the view.
    """
    stack, mask_list = stack_masks(operators, masks)
    return problem_of(stack, mask_list, init)


def problem_of(stack: OperatorStack, mask_list: list, init=None, prior: np.ndarray | None = None) -> Problem:
    """:func:`prepare` on a stack and mask list that :func:`stack_masks` returned.

    ``prior`` (the stack's columns, float64), when given, replaces the one
    of ``init`` (which then only says whether a prior was given).
    """
    n = stack.n_gaussians
    shapes = stack.image_shapes
    names = [v.name for v in stack]
    ys = [normalize_mask(m, shape, _label(i, names[i]))
          for i, (shape, m) in enumerate(zip(shapes, mask_list))]
    y = np.concatenate(ys)
    known = ~np.isnan(y)
    if not known.any():
        raise ValidationError(f"every mask is entirely NaN (views 0..{len(ys) - 1} carry no known pixel); "
                              "nothing to fit")
    y = np.where(known, y, np.float32(0)).astype(np.float32)
    A, AT = stack, stack.T  # products view by view: no stacked copy of the weights
    offsets = stack.row_offsets()
    if known.all():
        # every pixel known: the known weight is the stack's (cached) column sums
        known_weight = stack.column_sums()
    else:
        known_weight = np.asarray(AT @ known.astype(np.float32), dtype=np.float64).ravel()
    return Problem(A=A, AT=AT, y=y, known=known, offsets=offsets, image_shapes=list(shapes), names=names,
                   known_weight=known_weight, prior=prior_from_init(init, n) if prior is None else prior,
                   init_given=init is not None)
