r"""Graph-Laplacian regularisation of a per-Gaussian membership.

Every solver method fits ``q`` to the pixels it is given. A Gaussian that
lies (almost) only under unknown pixels (NaN in every mask: a surface no
labelled view saw) has no evidence, and the fit leaves it at the prior or
anywhere a trace of weight drives it. :func:`laplacian_smooth` decides such
Gaussians from their neighbours on an affinity graph ``G``
(:func:`seed2gs_inverse.graph.gaussian_graph`) while Gaussians with evidence
keep the solver's value:

.. math::

    q^\star = \arg\min_q \; \sum_i e_i (q_i - \hat q_i)^2
              + \lambda\, q^T L q + \epsilon \sum_i (q_i - p_i)^2,
    \qquad L = D - G,

with :math:`\hat q` the solver's membership, :math:`e_i` the Gaussian's
evidence (its summed compositing weight over known pixels,
``Problem.known_weight``), :math:`\lambda` the smoothness, :math:`p` the
prior and :math:`\epsilon` a tiny ridge. A graph component without any
evidence keeps the prior, node by node (it is left out of the system: the
ridge alone would give it its smoothed prior, about the component's mean).
The minimiser solves the symmetric positive definite system

.. math::

    (E + \lambda L + \epsilon I)\, q = E \hat q + \epsilon p,
    \qquad E = \mathrm{diag}(e).

A Gaussian with :math:`e_i = 0` then satisfies
:math:`q_i = \sum_j w_{ij} q_j / \sum_j w_{ij}` (up to :math:`\epsilon`): the
harmonic extension of its neighbours, i.e. the probability that a random
walk on ``G`` started at ``i`` first meets an evidenced Gaussian labelled
foreground (Grady's random walker). Isolated nodes (no edges) decouple and
get :math:`(e_i \hat q_i + \epsilon p_i) / (e_i + \epsilon)`.

:func:`harmonic_extension` is the Dirichlet limit (:math:`e \to \infty` on
the fixed nodes, 0 elsewhere): :math:`L_{UU} q_U = -L_{UB} q_B`.

numpy/scipy only: no rasterizer, no Numba.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import connected_components

from ..errors import ValidationError
from ..graph import check_graph, laplacian_of_checked

__all__ = ["laplacian_smooth", "harmonic_extension"]

#: With ``solver="auto"``, systems up to this many unknowns are factorised
#: (SuperLU), larger ones use Jacobi-scaled conjugate gradients (the
#: factor of a 3D kNN graph grows faster than the graph).
DIRECT_MAX = 250_000

#: The default ridge :math:`\epsilon` of :func:`laplacian_smooth`.
RIDGE = 1e-6


def _vector(name, v, n, lo=None, hi=None) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (n,):
        raise ValidationError(f"{name} must have shape ({n},), one value per Gaussian, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValidationError(f"{name} must be finite")
    if lo is not None and a.min(initial=lo) < lo or hi is not None and a.max(initial=hi) > hi:
        raise ValidationError(f"{name} must lie in [{lo}, {hi if hi is not None else 'inf'}]")
    return a


def _reached(g: sp.spmatrix, linked: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """Indices of the ``linked`` nodes (with an edge) whose component of ``g`` holds a ``sources`` node."""
    _, label = connected_components(g, directed=False)
    hit = np.zeros(label.max(initial=0) + 1, bool)
    hit[label[sources]] = True
    return np.flatnonzero(linked & hit[label])


def _spd_solve(A: sp.spmatrix, b: np.ndarray, x0: np.ndarray, method: str, rtol: float) -> np.ndarray:
    n = A.shape[0]
    if method == "auto":
        method = "direct" if n <= DIRECT_MAX else "cg"
    if method == "direct":
        return np.asarray(spla.spsolve(A.tocsc(), b), dtype=np.float64)
    if method != "cg":
        raise ValidationError(f"linear solver must be 'auto', 'direct' or 'cg', got {method!r}")
    # CG on the Jacobi-scaled system S A S y = S b, x = S y, S = diag(A)^-1/2: the iterates of
    # Jacobi-preconditioned CG, stopped on the scaled residual |S r| <= rtol |S b|. Unscaled,
    # |r| <= rtol |b| would let the rows of large evidence set the tolerance of all, and solve
    # the Gaussians without evidence (what the regulariser decides) loosely.
    s = 1.0 / np.sqrt(A.diagonal())
    S = sp.diags(s)
    y, info = spla.cg((S @ A @ S).tocsr(), s * b, x0=x0 / s, rtol=rtol, maxiter=20 * n + 100)
    if info != 0:
        # Not converged within the budget: fall back to the exact factorisation.
        return np.asarray(spla.spsolve(A.tocsc(), b), dtype=np.float64)
    return np.asarray(s * y, dtype=np.float64)


def _rtol(rtol) -> float:
    """The CG tolerance as a float in (0, 1), else a ValidationError."""
    try:
        r = float(rtol)
    except (TypeError, ValueError):
        r = float("nan")
    if not 0.0 < r < 1.0:  # NaN fails too
        raise ValidationError(f"rtol must be a number in (0, 1), got {rtol!r}")
    return r


def laplacian_smooth(q_hat, evidence, graph, smoothness: float = 1.0, prior=None, *,
                     ridge: float = RIDGE, solver: str = "cg", rtol: float = 1e-5) -> np.ndarray:
    r"""Graph-regularised membership :math:`q^\star` (see the module docstring).

    Parameters
    ----------
    q_hat : (N,) array in [0, 1]
        The solver's membership.
    evidence : (N,) array >= 0
        :math:`e_i`, e.g. ``Problem.known_weight`` (summed weight on known pixels).
    graph : scipy.sparse (N, N)
        Symmetric non-negative weights, e.g. :func:`~seed2gs_inverse.graph.gaussian_graph`.
    smoothness : float
        :math:`\lambda \ge 0`; 0 returns :math:`(e_i \hat q_i + \epsilon p_i) / (e_i + \epsilon)`:
        :math:`\hat q` where :math:`e \gg \epsilon`, the prior where ``e = 0``.
    prior : (N,) array in [0, 1], optional
        :math:`p`, the value of Gaussians no evidence reaches; default 0.
    ridge : float
        :math:`\epsilon > 0`.
    solver : {"cg", "direct", "auto"}
        Linear solver for the coupled nodes: ``cg`` (default),
        conjugate gradients on the Jacobi-scaled system (the iterates of
        Jacobi-preconditioned CG) warm-started from the Dirichlet limit,
        to ``rtol``; ``direct`` factorises with SuperLU
        (exact, slower: ``benchmarks/bench_smoothing.py`` prints both);
        ``auto`` factorises up to :data:`DIRECT_MAX` unknowns and uses CG
        beyond.
    rtol : float
        CG relative tolerance, in (0, 1) (only used with CG), on the scaled
        residual: ``|S r| <= rtol |S b|`` with ``S = diag(A)^-1/2``, so
        large evidence does not loosen the solve where there is none.
        The default 1e-5 was chosen on ``benchmarks/bench_smoothing.py
        --rtol 1e-6,1e-5,1e-4``, which prints the time and the labels that
        fall on the other side of 0.5 than in the exact solve.

    Returns
    -------
    (N,) float64 in [0, 1]
    """
    q_hat = np.asarray(q_hat, dtype=np.float64).ravel()
    n = q_hat.size
    q_hat = _vector("q_hat", q_hat, n, 0.0, 1.0)
    e = _vector("evidence", evidence, n, 0.0)
    p = np.zeros(n) if prior is None else _vector("prior", prior, n, 0.0, 1.0)
    g = check_graph(graph, n)
    lam = float(smoothness)
    if not (np.isfinite(lam) and lam >= 0):
        raise ValidationError(f"smoothness must be a finite number >= 0, got {smoothness!r}")
    eps = float(ridge)
    if not (np.isfinite(eps) and eps > 0):
        raise ValidationError(f"ridge must be positive, got {ridge!r}")
    return smooth_checked(q_hat, e, g, lam, p, eps, solver, _rtol(rtol))


def smooth_checked(q_hat, e, g, lam, p, eps=RIDGE, solver="cg", rtol=1e-5) -> np.ndarray:
    """:func:`laplacian_smooth` on arguments already validated (float64 vectors, ``g`` from
    :func:`~seed2gs_inverse.graph.check_graph`); for :func:`~seed2gs_inverse.solvers.solve`,
    which checks the graph before the method runs."""
    # Closed form for every node first (exact for isolated nodes and for lam = 0).
    out = (e * q_hat + eps * p) / (e + eps)
    if lam == 0 or g.nnz == 0:
        return np.clip(out, 0.0, 1.0)
    L = laplacian_of_checked(g)
    # Nodes with at least one edge, in a graph component that holds evidence: the others keep the
    # closed form above (the prior where there is no evidence), not the ridge's smoothed prior.
    coupled = _reached(g, L.diagonal() > 0, e > 0)
    if coupled.size:
        Lc = L[coupled][:, coupled]  # edges only join coupled nodes, so this block is exact
        A = (lam * Lc + sp.diags(e[coupled] + eps)).tocsr()
        b = e[coupled] * q_hat[coupled] + eps * p[coupled]
        # Warm start: the Dirichlet limit (evidenced nodes pinned at q_hat, the
        # others harmonic) is a small system and already carries the slow,
        # long-range part of the solution that CG would need many steps for.
        ec = e[coupled]
        x0 = out[coupled]
        use_cg = solver == "cg" or (solver == "auto" and coupled.size > DIRECT_MAX)
        if use_cg and (ec > 0).any() and (ec == 0).any():
            # Only a starting point: a loose tolerance (the CG below converges to
            # rtol either way; a tight one costs thousands of CG steps on large
            # regions). Every component here holds evidence.
            x0 = _harmonic(Lc, ec > 0, q_hat[coupled], p[coupled], np.flatnonzero(ec == 0), 1e-9, "auto", 1e-4)
        out[coupled] = _spd_solve(A, b, x0, solver, rtol)
    return np.clip(out, 0.0, 1.0)


def harmonic_extension(graph, fixed, values, prior=None, *, ridge: float = 1e-9,
                       solver: str = "auto", rtol: float = 1e-10) -> np.ndarray:
    r"""Random-walker labels: fixed nodes keep ``values``, the rest are harmonic.

    Solves :math:`(L_{UU} + \epsilon I) q_U = -L_{UB} q_B + \epsilon p_U`;
    every free node connected to a fixed one then satisfies
    :math:`q_i = \sum_j w_{ij} q_j / \sum_j w_{ij}` (to :math:`O(\epsilon)`);
    free components without a fixed node keep the prior, node by node (they
    are left out of the system).

    Parameters
    ----------
    graph : scipy.sparse (N, N) symmetric weights
    fixed : (N,) bool
        The seeds (Dirichlet nodes).
    values : (N,) array in [0, 1]
        Their labels (read only where ``fixed``).
    prior : (N,) array in [0, 1], optional
        Value of free nodes no seed reaches (default 0).
    ridge : float
        :math:`\epsilon > 0`.
    solver : {"auto", "direct", "cg"}
        As in :func:`laplacian_smooth` (``auto``: SuperLU up to
        :data:`DIRECT_MAX` unknowns, else CG).
    rtol : float
        CG relative tolerance.

    Returns
    -------
    (N,) float64 in [0, 1]
    """
    g = check_graph(graph)
    n = g.shape[0]
    fixed = np.asarray(fixed)
    if fixed.dtype != bool or fixed.shape != (n,):
        raise ValidationError(f"fixed must be a boolean mask of shape ({n},), got {fixed.dtype} {fixed.shape}")
    values = np.asarray(values, dtype=np.float64)
    if values.shape != (n,):  # np.where would broadcast a single value to every seed
        raise ValidationError(f"values must have shape ({n},), one per node, got {values.shape}")
    v = _vector("values", np.where(fixed, values, 0.0), n, 0.0, 1.0)
    p = np.zeros(n) if prior is None else _vector("prior", prior, n, 0.0, 1.0)
    eps = float(ridge)
    if not (np.isfinite(eps) and eps > 0):
        raise ValidationError(f"ridge must be positive, got {ridge!r}")
    rtol = _rtol(rtol)
    L = laplacian_of_checked(g)
    reached = np.zeros(n, bool)
    reached[_reached(g, L.diagonal() > 0, fixed)] = True
    return _harmonic(L, fixed, v, p, np.flatnonzero(~fixed & reached), eps, solver, rtol)


def _harmonic(L, fixed, v, p, free, eps, solver, rtol) -> np.ndarray:
    """:func:`harmonic_extension` on the Laplacian ``L`` for the ``free`` nodes given (those in a component
    with a fixed node); the other nodes keep ``v`` (fixed) or ``p``."""
    out = np.where(fixed, v, p)
    if free.size == 0:
        return np.clip(out, 0.0, 1.0)
    bidx = np.flatnonzero(fixed)
    A = (L[free][:, free] + sp.diags(np.full(free.size, eps))).tocsr()
    b = -(L[free][:, bidx] @ v[bidx]) + eps * p[free]
    out[free] = _spd_solve(A, b, p[free], solver, rtol)
    return np.clip(out, 0.0, 1.0)
