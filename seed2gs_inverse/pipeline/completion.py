r"""Evidence for surfaces no labelled view saw: 3D label completion on a Gaussian graph.

The model-free tracker (:class:`~seed2gs_inverse.frontend.model_free.GeometricTracker`)
copies labels only where a labelled view saw the surface, so the back and the
underside of an object stay unknown (NaN) in the orbit masks, and the
Gaussians there have no evidence. Two model-free additions decide them from
3D neighbourhoods, on the affinity graph ``G`` of
:func:`seed2gs_inverse.graph.gaussian_graph` (kNN of the means; weights from
distance, colour and normal similarity), built only around the object
(:func:`object_graph`).

**Graph-Laplacian regularisation after the solve** (the default,
:func:`seed2gs_inverse.solvers.smoothing.laplacian_smooth`):

.. math::

    q^\star = \arg\min_q \sum_i e_i (q_i - \hat q_i)^2 + \lambda\, q^T L q
              + \epsilon \lVert q - p \rVert^2,

with :math:`\hat q` the solver's membership, :math:`e_i` the Gaussian's
summed weight over known pixels of all views, :math:`L = D - G` and the
prior :math:`p = 1_{G_0}`: Gaussians with evidence keep the fit, those
without become the harmonic extension (random-walker probability) of their
evidenced neighbours, so the back of an object joins its front through the
object's own surface, and stops at the support surface where colour or
normal change and where the ground's own evidence (label 0) is.

**Completion of the orbit masks before the solve** (:func:`complete_membership`
and :func:`fill_unknown`): random-walker labels with Dirichlet seeds
:math:`q_i = 1` on :math:`G_0` (the seed lift) and :math:`q_i = 0` on the
Gaussians the reference shows outside the seed (reference weight
:math:`\sum_u w_{ui} \ge w_{min}`, membership :math:`\mu_i \le \mu_{bg}`),

.. math::

    L_{UU}\, q_U = -L_{UB}\, q_B,

rendered into each orbit view through its operator, :math:`P(c) = W(c) q`
normalised by the rendered opacity :math:`\alpha(c) = W(c) 1`; an unknown
pixel with :math:`\alpha \ge \alpha_{min}` takes 1 where
:math:`P/\alpha \ge 1 - \delta`, 0 where :math:`P/\alpha \le \delta`, and
stays unknown otherwise. It only uses the reference's labels, so it is
weaker than the regulariser, which also uses every orbit view's evidence;
both are options of :func:`~seed2gs_inverse.pipeline.extract.extract`.

**Faint Gaussians follow their opaque neighbours** (:func:`faint_follow_matrix`).
A Gaussian below the graph's ``min_opacity`` never dominates a pixel: its
evidence is a trace, and the graph leaves it out. Translucent shells, halos
and inner layers of a scanned object are made of such Gaussians; left to
the prior they stay in the remainder, where, rendered without the object in
front of them, they are a see-through copy of it. Each faint Gaussian of the
region takes the membership of its ``k`` nearest opaque ones,

.. math::

    q_i = \frac{\sum_{j \in N_k(i)} q_j / (d_{ij} + \epsilon)}{\sum_{j \in N_k(i)} 1 / (d_{ij} + \epsilon)},

with :math:`\epsilon` a hundredth of the median neighbour distance.

**Enclosed Gaussians follow the selection** (:func:`follow_enclosed`). The
views' operators keep only weights of at least ``min_weight``; behind an
opaque skin an inner splat's weights fall below it, so its only evidence
comes from where it reaches past the silhouette, on background pixels, and
the solver gives it 0. A Gaussian whose centre every view shows inside the
selection's footprint (:func:`enclosed_by_selection`: the selection's
visual hull, above its base) takes the membership of its nearest selected
Gaussian.

**Weak Gaussians follow their strong neighbours** (:func:`follow_weak`). A
Gaussian whose stored weight never reaches ``max_weight`` in any view never
dominates a pixel: behind the skin, on the back layers, or a long splat
crossing the surface. What its pixels say is decided by other Gaussians,
and past the silhouette it is the background. Left unselected, it takes
the inverse-distance mean of its ``k`` nearest strong Gaussians' ``q`` in
the object's region (those with a weight of at least ``max_weight``,
:func:`strong_columns`): the object's own where it lies among the
object's, the ground's where it lies among the ground's. Below the
selection's base it keeps its own (a large splat of the ground whose
centre lies under the object).

With user-supplied 2D trackers (SAM2) the masks have no unknown pixels where
the object is visible: the fill is a no-op and the regulariser only decides
Gaussians no view's pixels reach (Algorithm 1 is unchanged otherwise).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from .._threads import n_threads
from .._validation import check_real
from ..errors import ValidationError
from ..graph import _BLOCK, _followed, _nearest_entries, check_follow, follow_matrix, gaussian_graph
from ..solvers.smoothing import harmonic_extension
from ..operators import as_stack
from .local import neighbourhood

__all__ = ["object_graph", "complete_membership", "tracked_membership", "fill_unknown", "faint_follow_matrix",
           "enclosed_by_selection", "follow_enclosed", "strong_columns", "follow_weak", "GRAPH_DEFAULTS",
           "WEAK_DEFAULTS", "FOOTPRINT_MIN_ALPHA"]

#: Graph settings used by extract(): k neighbours, colour and normal sigmas,
#: and the region (multiples of the lift's radius about its centre).
GRAPH_DEFAULTS = {"k": 10, "sigma_color": 0.1, "sigma_normal": 0.2, "region": 3.0, "min_opacity": 0.05}


def _region(scene, center, radius: float, region: float) -> np.ndarray:
    """Indices of the Gaussians within ``region * radius`` of ``center`` (``region`` validated)."""
    if not (np.isfinite(region) and region > 0):
        raise ValidationError(f"region must be positive, got {region!r}")
    return neighbourhood(scene, center, float(region) * float(radius))


def object_graph(scene, center, radius: float, *, k: int = GRAPH_DEFAULTS["k"],
                 sigma_color: float | None = GRAPH_DEFAULTS["sigma_color"],
                 sigma_normal: float | None = GRAPH_DEFAULTS["sigma_normal"],
                 region: float = GRAPH_DEFAULTS["region"],
                 min_opacity: float = GRAPH_DEFAULTS["min_opacity"]) -> sp.csr_matrix:
    """:func:`~seed2gs_inverse.graph.gaussian_graph` among the Gaussians within ``region * radius`` of ``center``.

    The seed lift's extent is conservative (it sees only the front), hence a
    region of 3 radii by default.

    Returns
    -------
    (N, N) scipy.sparse.csr_matrix
        The weights over the whole scene (nodes outside the region are isolated).

    Raises
    ------
    ValidationError
        ``region`` is not a positive number.
    """
    idx = _region(scene, center, radius, region)
    return gaussian_graph(scene, k, subset=idx, sigma_color=sigma_color, sigma_normal=sigma_normal,
                          min_opacity=min_opacity)


def faint_follow_matrix(scene, center, radius: float, *, region: float = GRAPH_DEFAULTS["region"],
                        min_opacity: float = GRAPH_DEFAULTS["min_opacity"], k: int = 4) -> sp.csr_matrix:
    """:func:`~seed2gs_inverse.graph.follow_matrix` among the Gaussians within ``region * radius`` of ``center``.

    Applied to a membership by :func:`~seed2gs_inverse.graph.apply_follow`:
    each faint Gaussian near the object takes the inverse-distance weighted
    mean of its ``k`` nearest opaque neighbours (module docstring).

    Returns
    -------
    (N, N) scipy.sparse.csr_matrix
        Rows of the region's faint Gaussians (each summing to 1); the others empty.

    Raises
    ------
    ValidationError
        ``region`` is not a positive number, or a bad ``min_opacity`` / ``k``.
    """
    idx = _region(scene, center, radius, region)
    return follow_matrix(scene, k, subset=idx, min_opacity=min_opacity)


#: CG tolerance of the completions' random walker on graphs beyond
#: :data:`~seed2gs_inverse.solvers.smoothing.DIRECT_MAX` unknowns (smaller ones are factorised):
#: the regulariser's default. harmonic_extension's own 1e-10 costs many more CG iterations on large
#: graphs (chosen on ``benchmarks/bench_extract.py --extra``, whose real scans give the largest ones).
COMPLETION_RTOL = 1e-5


def complete_membership(graph, support, reference_weight, reference_membership, *,
                        min_weight: float = 0.1, max_background_membership: float = 0.1,
                        rtol: float = COMPLETION_RTOL) -> np.ndarray:
    r"""Random-walker membership from the reference view's labels alone.

    Parameters
    ----------
    graph : (N, N) sparse symmetric weights
    support : (N,) bool
        :math:`G_0`, the lifted set (``SeedLift.g0``): the foreground seeds.
    reference_weight : (N,) float
        Each Gaussian's summed compositing weight in the reference view,
        :math:`\sum_u w_{ui}`.
    reference_membership : (N,) float
        :math:`\mu_i = (W^T m^\star)_i / (W^T 1)_i` (``SeedLift.membership``).
    min_weight, max_background_membership : float
        Background seeds: visible in the reference (weight >= ``min_weight``)
        and outside the seed (membership <= ``max_background_membership``).
    rtol : float
        CG tolerance of :func:`~seed2gs_inverse.solvers.smoothing.harmonic_extension`
        (used beyond its ``DIRECT_MAX`` unknowns).

    Returns
    -------
    (N,) float64 in [0, 1]
        1 on G0, 0 on the background seeds.

    Raises
    ------
    ValidationError
        ``support`` is not a boolean (N,) mask, or the reference arrays are not (N,).
    """
    g0 = np.asarray(support)
    n = g0.shape[0] if g0.ndim == 1 else -1
    if g0.dtype != bool or g0.ndim != 1:
        raise ValidationError("support must be a boolean (N,) mask (the seed lift's G0)")
    w = np.asarray(reference_weight, np.float64).ravel()
    mu = np.asarray(reference_membership, np.float64).ravel()
    if w.shape != (n,) or mu.shape != (n,):
        raise ValidationError(f"reference_weight and reference_membership need shape ({n},), "
                              f"got {w.shape} and {mu.shape}")
    bg = ~g0 & (w >= min_weight) & (mu <= max_background_membership)
    fixed = g0 | bg
    return harmonic_extension(graph, fixed, g0.astype(np.float64), prior=g0.astype(np.float64),
                              rtol=rtol)


def fill_unknown(operators, masks, q, *, decisive: float = 0.2, alpha_min: float = 0.5) -> list:
    r"""Fill the unknown (NaN) pixels of each mask from a 3D membership rendered into the view.

    ``P = W q`` over ``alpha = W 1``: 1 where ``P / alpha >= 1 - decisive``,
    0 where ``<= decisive``, NaN elsewhere and where ``alpha < alpha_min``.
    Known pixels are kept.

    Parameters
    ----------
    operators : sequence of ViewOperator or sparse (P_c, N) matrices
    masks : sequence of float arrays
        One per operator, ``P_c`` pixels each, NaN where unknown.
    q : (N,) array
        The 3D membership.

    Returns
    -------
    list of float32 arrays
        New masks, of the shapes of ``masks``.

    Raises
    ------
    ValidationError
        As many masks as operators are needed, each matching its operator and ``q``.
    """
    q = np.asarray(q, np.float32).ravel()
    out = []
    ops = list(operators)
    if len(ops) != len(masks):
        raise ValidationError(f"got {len(masks)} masks for {len(ops)} views")
    for i, (op, m) in enumerate(zip(ops, masks)):
        W = getattr(op, "W", op)
        m = np.asarray(m, np.float32)
        if W.shape[1] != q.size or W.shape[0] != m.size:
            raise ValidationError(f"view {i}: operator {W.shape} does not match the mask {m.shape} "
                                  f"and q ({q.size},)")
        nan = np.isnan(m).ravel()
        if not nan.any():
            out.append(m)
            continue
        rows = np.flatnonzero(nan)
        Wr = W[rows]
        alpha = np.asarray(Wr.sum(axis=1)).ravel()
        p = Wr @ q
        with np.errstate(invalid="ignore", divide="ignore"):
            v = np.where(alpha >= alpha_min, p / np.maximum(alpha, 1e-12), np.nan)
        fill = np.full(rows.size, np.nan, np.float32)
        fill[v >= 1 - decisive] = 1.0
        fill[v <= decisive] = 0.0
        flat = m.ravel().copy()
        flat[rows] = fill
        out.append(flat.reshape(m.shape))
    return out


def tracked_membership(graph, operators, masks, prior=None, *, min_evidence: float = 0.5,
                       confident: float = 0.2, rtol: float = COMPLETION_RTOL) -> np.ndarray:
    r"""Random-walker membership seeded by every decided pixel of every view.

    Each Gaussian's label estimate from the known pixels,

    .. math::

        \hat q_i = \frac{\sum_c \sum_{u \in K(c)} w_{ui}(c)\, y_u(c)}{\sum_c \sum_{u \in K(c)} w_{ui}(c)},

    fixes the Gaussians with evidence :math:`e_i = \sum_c \sum_{u \in K(c)} w_{ui}(c) \ge`
    ``min_evidence`` and a confident estimate (:math:`\hat q_i \le` ``confident``
    or :math:`\ge 1 -` ``confident``); the others (unseen surfaces, and
    silhouette Gaussians whose pixels disagree) take the harmonic extension
    :math:`L_{UU} q_U = -L_{UB} \hat q_B`; those no fixed node reaches keep ``prior``.
    ``rtol``: as in :func:`complete_membership`.

    Returns
    -------
    (N,) float64 in [0, 1]

    Raises
    ------
    ValidationError
        As many masks as operators are needed, each matching its operator;
        ``confident`` in [0, 0.5).
    """
    ops = list(operators)
    if len(ops) != len(masks):
        raise ValidationError(f"got {len(masks)} masks for {len(ops)} views")
    if not 0 <= confident < 0.5:
        raise ValidationError(f"confident must be in [0, 0.5), got {confident!r}")
    n = getattr(ops[0], "W", ops[0]).shape[1]
    num, den = np.zeros(n), np.zeros(n)
    for i, (op, m) in enumerate(zip(ops, masks)):
        W = getattr(op, "W", op)
        y = np.asarray(m, np.float32).ravel()
        if W.shape != (y.size, n):
            raise ValidationError(f"view {i}: operator {W.shape} does not match its mask ({y.size} px) / N={n}")
        known = ~np.isnan(y)
        num += W.T @ np.where(known, y, 0.0).astype(np.float32)
        den += W.T @ known.astype(np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        qhat = np.where(den > 0, num / np.maximum(den, 1e-30), 0.0)
    qhat = np.clip(qhat, 0.0, 1.0)
    fixed = (den >= min_evidence) & ((qhat <= confident) | (qhat >= 1.0 - confident))
    return harmonic_extension(graph, fixed, qhat, prior=prior, rtol=rtol)


def enclosed_by_selection(stack, selected, means, *, up=None, footprint: float = 0.5,
                          base_quantile: float = 0.01) -> np.ndarray:
    r"""Bool (N,): unselected Gaussians whose centres every view shows inside the selection's footprint.

    Parameters
    ----------
    stack : OperatorStack or sequence of views
        The views (anything :func:`~seed2gs_inverse.operators.as_stack`
        accepts), each with its camera.
    selected : (N,) bool
        The selection ``S``.
    means : (N, 3) array
        Gaussian centres.
    up : (3,) array, optional
        The orbit axis. Given, a candidate must also lie at or above the
        selection's base: the ``base_quantile`` of the selected centres'
        heights along ``up``.
    footprint : float in (0, 1]
        A pixel is in the selection's footprint where the selection holds
        at least this share of its alpha: ``W(c) 1_S >= footprint *
        max(W(c) 1, FOOTPRINT_MIN_ALPHA)``.
    base_quantile : float in [0, 1)
        See ``up``.

    Returns
    -------
    (N,) bool
        The enclosed Gaussians (none of ``S``).

    Raises
    ------
    ValidationError
        Bad shapes or parameters, a view without a camera, or operators
        :func:`~seed2gs_inverse.operators.as_stack` refuses.

    Notes
    -----
    The candidates are the unselected Gaussians in the selection's
    axis-aligned bounding box. A candidate is enclosed when, in every view
    ``c``, its centre projects in front of the camera's near plane, inside
    the image, onto a pixel ``u`` where the selection holds the share
    :math:`f` (``footprint``) of the alpha,

    .. math:: (W(c) 1_S)(u) \ge f \max\big((W(c) 1)(u),\ \alpha_0\big),

    with :math:`\alpha_0` = ``FOOTPRINT_MIN_ALPHA``: it lies in the
    selection's visual hull over the views. The share, not the selection's
    own alpha, decides, so that a translucent object seen against nothing
    (a scan without its surroundings) has a footprint where it renders
    less than ``footprint``; :math:`\alpha_0` keeps out the nearly empty
    pixels around it.
    Such a Gaussian sits inside the object or behind it from every side,
    where it never dominates a pixel; what evidence it gets comes from the
    parts of its footprint that reach past the silhouette (a long or
    translucent splat), on background pixels. Anything standing apart from
    the object shows beside it in some view, and the ground under it lies
    below its base.
    """
    sel = np.asarray(selected)
    out = np.zeros(sel.shape, bool)
    out[_enclosed(stack, sel, means, up=up, footprint=footprint, base_quantile=base_quantile)] = True
    return out


def _enclosed(stack, sel, means, *, up=None, footprint: float = 0.5, base_quantile: float = 0.01) -> np.ndarray:
    """Ascending indices of :func:`enclosed_by_selection` (same arguments and checks)."""
    x = np.asarray(means)  # converted to float64 at the rows read: no (N, 3) float64 copy
    if sel.dtype != bool or sel.ndim != 1 or x.shape != (sel.size, 3):
        raise ValidationError(f"enclosed_by_selection: selected must be bool (N,) and means (N, 3), got "
                              f"{sel.dtype} {sel.shape} and {x.shape}")
    check_real("enclosed_by_selection: footprint", footprint, lo=0, hi=1, lo_open=True)
    check_real("enclosed_by_selection: base_quantile", base_quantile, lo=0, hi=1, hi_open=True)
    stack = as_stack(stack)
    if stack.n_gaussians != sel.size:
        raise ValidationError(f"enclosed_by_selection: the views have {stack.n_gaussians} columns, the selection "
                              f"{sel.size} Gaussians; pass the views of the same scene")
    if up is not None:
        up = _unit_up(up, "enclosed_by_selection")
    chosen = np.flatnonzero(sel)
    if chosen.size == 0:
        return chosen
    xs = x[chosen].astype(np.float64)
    idx = _in_box(x, xs.min(0), xs.max(0))
    idx = idx[~sel[idx]]
    xi = x[idx].astype(np.float64)
    if up is not None:
        keep = xi @ up >= np.quantile(xs @ up, base_quantile)
        idx, xi = idx[keep], xi[keep]
    # the footprints on the stack's compact columns: the same sums, with no (N,) weight vector
    cols, compact = stack.compact()
    s = sel[cols].astype(np.float32)
    for i, (view, alpha) in enumerate(_with_alpha(compact)):
        if idx.size == 0:
            break
        ok = _in_footprint(view, alpha, s, xi, footprint, f"enclosed_by_selection: view {i}")
        idx, xi = idx[ok], xi[ok]
    return idx


#: The least alpha a pixel counts with in the selection's footprint test
#: (:func:`enclosed_by_selection`): the selection must hold its share of at least this much,
#: so that a nearly empty pixel is in no footprint.
FOOTPRINT_MIN_ALPHA = 0.2


def _with_alpha(stack):
    """``(view, alpha)`` pairs: each view of ``stack`` with its (H*W,) rendered alpha ``W 1``.

    Read from the stack's row sums (:meth:`~seed2gs_inverse.operators.OperatorStack.row_sums`),
    cached on the stack: computed once for every footprint test, or not at all
    where the solver already read them from the same compact stack.
    """
    alpha, offsets = stack.row_sums(), stack.row_offsets()
    return ((view, alpha[offsets[i]:offsets[i + 1]]) for i, view in enumerate(stack))


def _in_footprint(view, alpha: np.ndarray, s: np.ndarray, x: np.ndarray, footprint: float,
                  label: str) -> np.ndarray:
    """Bool (M,): the centres ``x`` (M, 3) that ``view`` shows on a pixel of the selection's footprint.

    ``alpha`` is the view's (H*W,) rendered alpha ``W 1`` and ``s`` the
    selection as float32 over the view's columns; a pixel is in the
    footprint where ``W s >= footprint * max(W 1, FOOTPRINT_MIN_ALPHA)``
    (:func:`enclosed_by_selection`). A centre behind the near plane or
    outside the image is not in it. ``label`` names the view in the error a
    view without a camera raises.
    """
    cam = view.camera
    if cam is None:
        raise ValidationError(f"{label} has no camera")
    h, w = view.image_shape
    held = np.asarray(view.W @ s).ravel()
    fp = (held >= footprint * np.maximum(alpha, FOOTPRINT_MIN_ALPHA)).reshape(h, w)
    uv, z = cam.project(x)
    ok = np.isfinite(uv).all(1) & (z > cam.near)
    px = np.floor(np.where(ok[:, None], uv, -1.0)).astype(np.int64)
    ok &= (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    ok[ok] = fp[px[ok, 1], px[ok, 0]]
    return ok


def _share_in_footprint(stack, selected: np.ndarray, x: np.ndarray, footprint: float) -> np.ndarray:
    """Float (M,): the share of ``stack``'s views that show each centre ``x`` (M, 3) in the selection's footprint."""
    cols, compact = stack.compact()
    s = selected[cols].astype(np.float32)
    count = np.zeros(len(x), np.int64)
    for i, (view, alpha) in enumerate(_with_alpha(compact)):
        count += _in_footprint(view, alpha, s, x, footprint, f"follow_weak: view {i}")
    return count / max(len(compact), 1)


def follow_enclosed(stack, means, q, tau: float, follow, *, up=None) -> tuple[sp.csr_matrix, np.ndarray]:
    """``(follow, q)`` with a row for each Gaussian the selection ``q > tau`` encloses.

    Parameters
    ----------
    stack : OperatorStack or sequence of views
        The supervision views, each with its camera.
    means : (N, 3) array
    q : (N,) array
        The membership after ``follow`` was applied.
    tau : float
        The selection's threshold.
    follow : (N, N) sparse
        A follow matrix (:func:`~seed2gs_inverse.graph.check_follow`), e.g.
        :func:`faint_follow_matrix`'s.
    up : (3,) array, optional
        Passed to :func:`enclosed_by_selection`.

    Returns
    -------
    (N, N) scipy.sparse.csr_matrix, (N,) float32
        ``follow`` in which each enclosed Gaussian's row (any faint row it
        had replaced) holds weight 1 on its nearest Gaussian of the
        selection that has no row (its ``q`` is the solver's own), and
        ``q`` with that value; both unchanged when nothing is enclosed.

    Raises
    ------
    ValidationError
        A bad ``follow`` or ``q``, or what :func:`enclosed_by_selection` refuses.
    """
    qq = np.asarray(q, np.float32).ravel()
    follow = check_follow(follow, qq.size)
    rows, cols = _enclosed_rows(stack, means, qq, tau, lambda i: follow.indptr[i + 1] > follow.indptr[i], up=up)
    if rows.size == 0:
        return follow, qq
    qq = qq.copy()
    qq[rows] = qq[cols]
    return _replace_rows(follow, rows, rows, cols, np.ones(rows.size)), qq


def _enclosed_rows(stack, means, q: np.ndarray, tau: float, has_row, *, up=None) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, anchors)`` of :func:`follow_enclosed`: each enclosed Gaussian and the one whose ``q`` it takes.

    ``q`` is (N,) float32 (checked by the caller); ``has_row(i)`` tells, for
    indices ``i``, which Gaussians already follow others (a follow matrix's
    non-empty rows): they are no anchors. Both empty when nothing is
    enclosed or no selected Gaussian is free to be an anchor.
    """
    above = q > check_real("follow_enclosed: tau", tau)
    rows = _enclosed(stack, above, means, up=up)
    chosen = np.flatnonzero(above)
    anchors = chosen[~has_row(chosen)]
    if rows.size == 0 or anchors.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    x = np.asarray(means)
    _, nb = cKDTree(x[anchors].astype(np.float64)).query(x[rows].astype(np.float64), workers=n_threads())
    return rows, anchors[np.asarray(nb).ravel()]


#: The weak-evidence rule's settings (:func:`follow_weak`): the largest stored weight below which a
#: Gaussian never dominates a pixel, the strong neighbours each such Gaussian follows, and how far
#: its nearest one may lie: ``reach`` strong Gaussians' spacings, or up to ``extent`` of its own largest
#: standard deviations more where at least the share ``inside`` of the views show its centre in the
#: selection's footprint.
WEAK_DEFAULTS = {"max_weight": 0.3, "k": 8, "reach": 4.0, "extent": 2.0, "inside": 2 / 3}


def strong_columns(stack, max_weight: float = WEAK_DEFAULTS["max_weight"]) -> np.ndarray:
    """Ascending indices of the Gaussians with a stored weight of at least ``max_weight`` in some view.

    Parameters
    ----------
    stack : OperatorStack or sequence of views
        Anything :func:`~seed2gs_inverse.operators.as_stack` accepts.
    max_weight : float in (0, 1]

    Returns
    -------
    (M,) int64
        Read from each view's stored weights: nothing of length N is made.

    Raises
    ------
    ValidationError
        A bad ``max_weight``, or operators :func:`~seed2gs_inverse.operators.as_stack` refuses.
    """
    h = check_real("strong_columns: max_weight", max_weight, lo=0, hi=1, lo_open=True)
    found = [v.W.indices[v.W.data >= h] for v in as_stack(stack)]
    return np.unique(np.concatenate(found)).astype(np.int64) if found else np.zeros(0, np.int64)


def follow_weak(stack, means, q, tau: float, follow, candidates, *, up=None, scales=None,
                max_weight: float = WEAK_DEFAULTS["max_weight"], k: int = WEAK_DEFAULTS["k"],
                reach: float = WEAK_DEFAULTS["reach"], extent: float = WEAK_DEFAULTS["extent"],
                inside: float = WEAK_DEFAULTS["inside"], base_quantile: float = 0.01) -> tuple[sp.csr_matrix, np.ndarray]:
    r"""``(follow, q)`` with a row for each unselected Gaussian of ``candidates`` that never dominates a pixel.

    Parameters
    ----------
    stack : OperatorStack or sequence of views
        The supervision views.
    means : (N, 3) array
    q : (N,) array
        The membership after ``follow`` was applied.
    tau : float
        The selection's threshold.
    follow : (N, N) sparse or None
        A follow matrix (:func:`~seed2gs_inverse.graph.check_follow`), e.g.
        :func:`follow_enclosed`'s; None: none.
    candidates : int array
        The Gaussians the rule looks at (the object's region), ascending
        and unique.
    up : (3,) array, optional
        The orbit axis. Given, a weak Gaussian follows only at or above
        the selection's base: the ``base_quantile`` of the selected
        centres' heights along ``up`` (:func:`enclosed_by_selection`'s
        bound).
    scales : (N, 3) array, optional
        Per-axis standard deviations (:attr:`~seed2gs_inverse.GaussianScene.scales`).
        Given, a weak Gaussian's reach grows by ``extent`` times its
        largest one; None: by nothing.
    max_weight : float in (0, 1]
        A Gaussian is weak when none of its stored weights in any view
        reaches this (:func:`strong_columns`), strong otherwise.
    k : int
        Strong neighbours per weak Gaussian, >= 1.
    reach : float
        A weak Gaussian follows only when its nearest strong neighbour lies
        within ``reach`` times the strong neighbours' spacing (the median
        distance from each to its nearest other), > 0; or, with ``scales``,
        within that plus ``extent`` times its own largest standard
        deviation when at least the share ``inside`` of the views show its
        centre in the selection's footprint (:func:`enclosed_by_selection`'s
        test with ``footprint=0.5``).
    extent : float
        See ``reach``; >= 0.
    inside : float in [0, 1]
        See ``reach``.
    base_quantile : float in [0, 1)
        See ``up``.

    Returns
    -------
    (N, N) scipy.sparse.csr_matrix, (N,) float32
        ``follow`` in which the row of each weak candidate with
        ``q <= tau`` (any row it had replaced) holds the inverse-distance
        weights of its ``k`` nearest strong candidates that have no row
        (:func:`~seed2gs_inverse.graph.follow_matrix`'s weights), and ``q``
        with those averages; both unchanged (an empty ``follow`` for None)
        when there is no such row or no such neighbour.

    Raises
    ------
    ValidationError
        A bad ``follow``, ``q``, ``tau``, ``candidates``, ``scales``,
        ``max_weight``, ``k``, ``reach``, ``extent`` or ``inside``, or a
        view without a camera where ``inside`` is tested.

    Notes
    -----
    A Gaussian whose weight never reaches ``max_weight`` never dominates a
    pixel of any view: its label comes from pixels that other Gaussians
    decide, in front of it or beside it. Inner and back layers and the
    long splats that cross a surface and reach past the silhouette are
    such Gaussians; the solver gives them what those pixels say, often the
    background beyond the silhouette, and the remainder keeps them as a
    see-through copy of the object. Their strong neighbours' labels are
    their own pixels' and are reliable; a weak Gaussian among the ground's
    strong Gaussians follows the ground, and one below the selection's
    base (a large splat of the ground whose centre lies under the
    object) keeps its own ``q``, as does one far from every strong
    Gaussian (a neighbour's part hidden behind the object). A large splat
    centred deep inside the object lies several spacings from its skin
    and still spreads its alpha over the object's footprint: where most
    views show its centre inside the selection, its largest standard
    deviation :math:`\sigma_{\max}` counts towards the bound
    :math:`r\,s + e\,\sigma_{\max}` (``reach`` :math:`r`, the spacing
    :math:`s`, ``extent`` :math:`e`). A large splat of the surface beside
    the object shows beside it in most views and keeps its ``q``. Only
    unselected Gaussians follow:
    the rule adds what was left behind and takes nothing from the
    selection.
    """
    qq = np.asarray(q, np.float32).ravel()
    n = qq.size
    follow = sp.csr_matrix((n, n)) if follow is None else check_follow(follow, n)
    idx = np.asarray(candidates)
    if idx.ndim != 1 or idx.dtype.kind not in "ui" or (idx.size and (idx[0] < 0 or idx[-1] >= n
                                                                     or np.any(idx[1:] <= idx[:-1]))):
        raise ValidationError(f"follow_weak: candidates must be ascending unique indices in [0, {n})")
    scales_at = None if scales is None else _scales_at(scales, n)
    rows, entries = _weak_entries(stack, means, qq, tau, lambda i: follow.indptr[i + 1] > follow.indptr[i],
                                  idx.astype(np.int64, copy=False), up=up, scales_at=scales_at,
                                  max_weight=max_weight, k=k, reach=reach, extent=extent, inside=inside,
                                  base_quantile=base_quantile)
    if rows.size == 0:
        return follow, qq
    out = _replace_rows(follow, rows, *entries)
    qq = qq.copy()
    qq[rows] = _followed(out, rows, qq)
    return out, qq


def _weak_entries(stack, means, q: np.ndarray, tau: float, has_row, candidates: np.ndarray, *, up=None, scales_at=None,
                  max_weight: float = WEAK_DEFAULTS["max_weight"], k: int = WEAK_DEFAULTS["k"],
                  reach: float = WEAK_DEFAULTS["reach"], extent: float = WEAK_DEFAULTS["extent"],
                  inside: float = WEAK_DEFAULTS["inside"], base_quantile: float = 0.01) -> tuple:
    """``(rows, (row, col, weight))`` of :func:`follow_weak`: the weak rows and their entries (scene indices).

    ``q`` is (N,) float32 and ``candidates`` ascending unique int64 indices
    (checked by the caller); ``has_row(i)`` tells, for indices ``i``, which
    Gaussians already follow others: they are no anchors. ``scales_at(i)``
    gives the (M, 3) per-axis standard deviations at indices ``i``
    (:meth:`~seed2gs_inverse.GaussianScene.scales_at`); None: no extent.
    ``rows`` is empty
    when there is no weak row or no anchor. The other arguments are
    checked here, as :func:`follow_weak` documents them.
    """
    tau = check_real("follow_weak: tau", tau)
    reach = check_real("follow_weak: reach", reach, lo=0, lo_open=True)
    extent = check_real("follow_weak: extent", extent, lo=0)
    inside = check_real("follow_weak: inside", inside, lo=0, hi=1)
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or int(k) < 1:
        raise ValidationError(f"follow_weak: k must be a positive integer, got {k!r}")
    none = np.zeros(0, np.int64)
    stack = as_stack(stack)
    strong = np.isin(candidates, strong_columns(stack, max_weight), assume_unique=True)
    anchors = candidates[strong]
    anchors = anchors[~has_row(anchors)]  # their q is the solver's
    rows = candidates[~strong]
    rows = rows[q[rows] <= tau]
    x = np.asarray(means)
    selected = q > tau
    if up is not None and rows.size:
        rows = rows[_at_or_above_base(x, selected, rows, up, base_quantile, "follow_weak")]
    if rows.size and anchors.size > 1:
        xa = x[anchors].astype(np.float64)
        tree = cKDTree(xa)
        spacing = float(np.median(tree.query(xa, k=2, workers=n_threads())[0][:, 1]))
        xr = x[rows].astype(np.float64)
        d = tree.query(xr, workers=n_threads())[0]
        near = d <= reach * spacing
        if scales_at is not None:
            # reached by the splat's extent only: kept where most views show it inside the selection
            sigma = scales_at(rows).max(axis=1).astype(np.float64)
            far = np.flatnonzero(~near & (d <= reach * spacing + extent * sigma))
            if far.size:
                near[far] = _share_in_footprint(stack, selected, xr[far], 0.5) >= inside
        rows = rows[near]
    if rows.size == 0 or anchors.size == 0:
        return none, (none, none, np.zeros(0))
    return rows, _nearest_entries(x, rows, anchors, int(k))


def _scales_at(scales, n: int):
    """``scales`` checked as :func:`follow_weak` takes them: a function of scene indices giving their rows.

    ``scales`` must be (n, 3) finite non-negative floats.
    """
    sc = np.asarray(scales)
    if sc.shape != (n, 3) or sc.dtype.kind != "f" or not np.all(np.isfinite(sc)) or np.any(sc < 0):
        raise ValidationError(f"follow_weak: scales must be finite non-negative floats of shape ({n}, 3), got "
                              f"{sc.dtype} {sc.shape}")
    return lambda rows: sc[rows]


def _unit_up(up, where: str) -> np.ndarray:
    """``up`` as a float64 unit 3-vector; a ValidationError naming ``where`` unless it is a nonzero finite 3-vector."""
    u = np.asarray(up, np.float64).ravel()
    if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) == 0:
        raise ValidationError(f"{where}: up must be a nonzero finite 3-vector, got {up!r}")
    return u / np.linalg.norm(u)


def _at_or_above_base(means: np.ndarray, selected: np.ndarray, rows: np.ndarray, up, base_quantile: float,
                      where: str) -> np.ndarray:
    """Bool over ``rows``: centres at or above the ``base_quantile`` of the selected centres' heights along ``up``.

    All True when nothing is selected.
    """
    u = _unit_up(up, where)
    check_real(f"{where}: base_quantile", base_quantile, lo=0, hi=1, hi_open=True)
    chosen = np.flatnonzero(selected)
    if chosen.size == 0:
        return np.ones(rows.size, bool)
    return means[rows].astype(np.float64) @ u >= np.quantile(means[chosen].astype(np.float64) @ u, base_quantile)


def _replace_rows(follow: sp.csr_matrix, rows: np.ndarray, new_rows: np.ndarray, new_cols: np.ndarray,
                  data: np.ndarray) -> sp.csr_matrix:
    """``follow`` (CSR) with its ``rows`` replaced by the entries ``(new_rows, new_cols, data)`` (on those rows only).

    Built from the entries, with no (N,) temporary.
    """
    old = follow.tocoo()
    kept = ~np.isin(old.row, rows)
    out = sp.csr_matrix((np.concatenate([old.data[kept], data]),
                         (np.concatenate([old.row[kept], new_rows]), np.concatenate([old.col[kept], new_cols]))),
                        shape=follow.shape)
    out.eliminate_zeros()
    out.sort_indices()
    return out


def _in_box(means: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Ascending indices of the (N, 3) ``means`` inside the box ``[lo, hi]``.

    A block at a time: no (N, 3) temporary, whatever the scene's size.
    """
    found = [np.flatnonzero(np.all((means[i:i + _BLOCK] >= lo) & (means[i:i + _BLOCK] <= hi), axis=1)) + i
             for i in range(0, len(means), _BLOCK)]
    return np.concatenate(found).astype(np.int64, copy=False) if found else np.zeros(0, np.int64)
