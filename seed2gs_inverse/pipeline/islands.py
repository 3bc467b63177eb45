r"""Islands of the selection: the post-solve rule that keeps what is connected to G0 in 3D.

After the solve and the threshold, :func:`seed_connected` removes the
components of the selection that the 3D neighbour graph leaves apart from
G0 (the lifted set of :func:`~seed2gs_inverse.pipeline.seed_lift.seed_lift`),
when they are large and the masks do not call them object. It runs in the
selection stage of :func:`~seed2gs_inverse.pipeline.extract.extract`
(``ExtractSettings.seed_connected``).
"""

from __future__ import annotations

import numpy as np

from ..errors import ValidationError
from .seed_lift import neighbour_components

__all__ = ["seed_connected", "ISLAND_FRACTION", "ISLAND_VOTE"]

#: Default of :func:`seed_connected`'s ``island_fraction``, chosen on
#: benchmarks/bench_extract.py: it lies between the share of the body's
#: Gaussians held by the object's own pieces that the neighbour graph leaves
#: apart (stray splats, small clusters at thin parts) and that of the
#: background islands the masks bring in.
ISLAND_FRACTION = 0.005

#: Default of :func:`seed_connected`'s ``island_vote``, chosen on
#: benchmarks/bench_extract.py: a background island (a seat or floor under
#: the object) draws a mixed share of its decided weight from object pixels,
#: while a real part of the object apart in the graph (the stand of a
#: guitar) draws nearly all of it, as the body does.
ISLAND_VOTE = 0.9


def seed_connected(means, selected, support, *, k_neighbors: int = 8, link_factor: float = 3.0,
                   island_fraction: float = ISLAND_FRACTION, votes=None,
                   island_vote: float = ISLAND_VOTE) -> np.ndarray:
    r"""The selection without the islands apart from G0 (the lifted set of the seed lift).

    The same neighbour graph as the lift's components
    (:func:`~seed2gs_inverse.pipeline.seed_lift.neighbour_components`),
    built over the *selected* Gaussians: each is linked to its
    ``k_neighbors`` nearest selected Gaussians closer than ``link_factor``
    times the median distance to the 4th-nearest one. Components holding a
    Gaussian of G0 form the body :math:`B`; any other component :math:`C`
    is an island and is removed when

    .. math::

        |C| \ge f\,|B|, \qquad f = \text{island\_fraction}.

    Smaller components stay: a real object's splats are not all linked (a
    stray splat at a silhouette, a small cluster at a thin part), and such
    pieces are a tiny fraction of the body (see :data:`ISLAND_FRACTION`).
    With ``votes`` an island also stays whatever its size when the masks
    call it object: when at least ``island_vote`` of its compositing weight
    on decided pixels lies on object pixels,

    .. math::

        \sum_{i \in C} o_i \ge v \sum_{i \in C} d_i, \qquad v = \text{island\_vote},

    with :math:`o_i` and :math:`d_i` Gaussian :math:`i`'s weight on object
    pixels and on all decided pixels. A large real part that the graph
    leaves apart (the stand of a guitar: thin, sparser than the body) is
    seen as object in view after view, while a background surface brought
    in by a few wrong pixels has a mixed vote (see :data:`ISLAND_VOTE`).
    The vote cannot tell a real part from a background surface that the
    masks label object wherever they decide it (a tracker error repeated in
    every view): such an island stays.

    Why: the solver decides each Gaussian from the masks, and a few wrong
    mask pixels can be all the evidence a mostly hidden background surface
    has (the seat and floor under an object resting on a chair, seen only
    through a band of pixels below the object's edge that the tracker
    labels as object). The solver selects that surface, the graph
    regulariser extends it to its hidden remainder, and the result is a
    coherent surface apart from the object, as large as the object or larger.

    Parameters
    ----------
    means : (N, 3) array
        Gaussian centres.
    selected : (N,) bool
        The selection (``q > tau``).
    support : (N,) bool
        G0 (``SeedLift.g0``).
    k_neighbors, link_factor : int, float
        As in :func:`~seed2gs_inverse.pipeline.seed_lift.seed_lift`.
    island_fraction : float
        :math:`f \ge 0`; 0 keeps only the body.
    votes : tuple of two (N,) arrays, or None
        :math:`(o, d)`: each Gaussian's compositing weight on object pixels
        and on all decided pixels of the supervision views (``A^T (k y)``
        and ``A^T k``, ``k`` the decided pixels, ``y`` the masks). None:
        the size rule alone.
    island_vote : float
        :math:`v` in [0, 1]; an island with a larger object share stays.

    Returns
    -------
    (N,) bool
        The selection less the removed islands. Unchanged when no selected
        Gaussian is in G0 (nothing to anchor on) or all are.

    Raises
    ------
    ValidationError
        Masks that are not boolean (N,), ``means`` not (N, 3), an option out
        of its range, or ``votes`` not two finite non-negative (N,) arrays.
    """
    means, selected, g0, votes = _check_inputs(means, selected, support, votes, k_neighbors=k_neighbors,
                                               link_factor=link_factor, island_fraction=island_fraction,
                                               island_vote=island_vote)
    n = len(selected)
    idx = np.nonzero(selected)[0]
    anchor = g0[idx]
    if not anchor.any() or anchor.all():
        return selected.copy()
    labels, ncomp = neighbour_components(np.asarray(means[idx], np.float64), int(k_neighbors), float(link_factor))
    sizes = np.bincount(labels, minlength=ncomp)
    body = np.zeros(ncomp, bool)
    body[labels[anchor]] = True
    keep = body | (sizes < island_fraction * sizes[body].sum())
    if votes is not None:
        obj = np.bincount(labels, weights=votes[0][idx], minlength=ncomp)
        decided = np.bincount(labels, weights=votes[1][idx], minlength=ncomp)
        keep |= (decided > 0) & (obj >= island_vote * decided)
    out = np.zeros(n, bool)
    out[idx[keep[labels]]] = True
    return out


def _check_inputs(means, selected, support, votes, *, k_neighbors, link_factor, island_fraction,
                  island_vote) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray] | None]:
    """:func:`seed_connected`'s arguments checked: ``(means (N, 3) as given, selected, support, votes)``.

    Raises
    ------
    ValidationError
        As :func:`seed_connected` documents; every message starts with ``seed_connected:``.
    """
    selected = np.asarray(selected)
    support = np.asarray(support)
    n = selected.shape[0] if selected.ndim == 1 else -1
    if selected.dtype != bool or selected.ndim != 1 or support.dtype != bool or support.shape != (n,):
        raise ValidationError("seed_connected: selected and support must be boolean (N,) masks of the same N, "
                              f"got {selected.dtype} {selected.shape} and {support.dtype} {support.shape}")
    means = np.asarray(means)  # converted where used: the selected Gaussians' alone
    if means.shape != (n, 3) or means.dtype.kind not in "fiu":
        raise ValidationError(f"seed_connected: means must have shape ({n}, 3) and a numeric dtype, got "
                              f"{means.shape} {means.dtype}")
    if int(k_neighbors) < 1 or not (np.isfinite(link_factor) and link_factor > 0):
        raise ValidationError(f"seed_connected: k_neighbors must be >= 1 and link_factor > 0, got "
                              f"{k_neighbors!r} and {link_factor!r}")
    if not (np.isfinite(island_fraction) and island_fraction >= 0):
        raise ValidationError(f"seed_connected: island_fraction must be a finite number >= 0, got "
                              f"{island_fraction!r}")
    if not 0 <= island_vote <= 1:
        raise ValidationError(f"seed_connected: island_vote must lie in [0, 1], got {island_vote!r}")
    if votes is not None:
        votes = [np.asarray(v, dtype=np.float64).reshape(-1) for v in votes]
        if len(votes) != 2 or any(v.shape != (n,) or not np.all(np.isfinite(v)) or v.min(initial=0) < 0
                                  for v in votes):
            raise ValidationError(f"seed_connected: votes must be two finite non-negative ({n},) arrays "
                                  "(object weight, decided weight)")
    return means, selected, support, votes
