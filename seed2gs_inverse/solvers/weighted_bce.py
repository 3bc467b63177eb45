"""Reliability-weighted multi-view BCE on membership logits (Seed2GS, Eqs. 6-8).

Each Gaussian gets a logit ``l_i`` with ``q_i = sigmoid(l_i)`` (the box
constraint for free). View ``c`` renders the soft mask ``P(c) = W(c) q``
(Eq. 5). The objective (Eq. 7) is

    L(l) = (1/Z) sum_c omega_c sum_{u in K(c)} s_u BCE(Phat_u, Y_u),
    BCE(p, y) = -(y log p + (1 - y) log(1 - p)),  p clipped to [eps, 1 - eps],

over the usable pixels ``K(c)`` of view ``c`` (known, i.e. not NaN, and
with rendered opacity ``alpha_u = (W 1)_u >= alpha_min``), where
``Z = sum_u s_u`` only rescales (so tolerances do not depend on the image
count).

Prediction. ``P_u = (W q)_u <= alpha_u``, so a pixel the scene covers only
partly can never reach ``Y_u = 1``. ``normalize=False`` (the default, the
paper's literal Eq. 7) predicts ``Phat = W q`` with pixel weights
``s_u = 1``: it matches masks that mark where the object's rendered opacity
exceeds one half, which is what the front ends produce.
``normalize=True`` predicts the object's share of what the pixel shows,
``Phat_u = (W q)_u / alpha_u``, with weight ``s_u = alpha_u``: it matches
masks that mark object pixels regardless of opacity. Pixels with
``alpha_u < alpha_min`` are left out either way: ``P = 0`` against
``Y = 1`` would add a constant to the loss and to the view residuals
without any gradient.

Gradient (chain rule through the clip; per-pixel work in A's dtype, sums in
float64):

    dL/dPhat_u = omega_c s_u / Z * (p_u - Y_u) / (p_u (1 - p_u))   (0 where clipped)
    dL/dl = q (1 - q) * A^T g,   g_u = dL/dPhat_u / alpha_u (normalize) or dL/dPhat_u,

one pass of ``A`` and one of ``A^T`` per evaluation, with the per-pixel
work between them on the usable pixels only
(:class:`~seed2gs_inverse.solvers._bce.PixelBCE`). The view residuals
``D_c`` reuse the evaluation at the same ``q``, so reweighting costs no
extra pass.

View weights (Eq. 6). ``D_c`` is the running residual of view ``c``: the
weighted mean BCE of its pixels, an exponential moving average with
``momentum`` updated after every inner run of ``inner_iters`` L-BFGS
iterations. With ``m_D = median(D)`` and the robust scale
``s_D = 1.4826 median(|D - m_D|)``, floored at ``1e-3 |m_D| + 1e-9`` so a
tie of most views does not divide by zero,

    omega_c = Norm[ r_min + (1 - r_min) sigmoid((m_D + s_D - D_c) / (lambda s_D)) ],

where ``Norm`` divides by the mean (the weights average 1). Views that agree
with the current estimate keep a weight near 1; views whose residual lies
far above the median (occlusion, tracker drift, a wrong identity) fall to
the floor ``r_min``.

Optimisation (:class:`WeightedBCE`). Only the logits of the Gaussians with
evidence (weight on at least one usable pixel) move; the others keep the
prior and are reported unobserved. An outer loop alternates an inner
L-BFGS run under fixed weights ``omega`` with a weight update, and stops
when an inner run converged and the weights moved less than
``weight_tol`` (max abs), or after ``max_iter`` iterations in total.
``optimizer="scipy"`` runs ``scipy.optimize.minimize(method="L-BFGS-B")``
without bounds; ``optimizer="lbfgs"`` runs :func:`~._lbfgs.lbfgs`, whose
curvature pairs carry over between outer steps.

The start is the prior ``q0`` from ``init`` or, without ``init``, the
closed-form vote (one extra transposed pass: Gaussians with little
evidence start on the vote's side instead of at 0.5), clipped to
``[init_clip, 1 - init_clip]`` since saturated logits have vanishing
gradients.
"""

from __future__ import annotations

import time
from collections import deque

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit

from ..errors import ValidationError
from ._bce import PixelBCE, bce_pixels
from ._common import MethodResult, Problem, check_count, check_range, register_method
from ._lbfgs import lbfgs as _lbfgs
from ._progress import report as report_progress
from .voting import voting

__all__ = ["weighted_bce", "WeightedBCE", "view_weights", "BCEObjective", "bce_pixels"]

def view_weights(residuals, r_min: float = 0.05, lam: float = 0.5) -> np.ndarray:
    """View weights of Eq. 6 from per-view residuals, mean-normalised.

    Parameters
    ----------
    residuals : (V,) array_like
        The running residuals ``D_c`` (V >= 1).
    r_min : float, default 0.05
        Weight floor before normalisation, in [0, 1].
    lam : float, default 0.5
        Temperature ``lambda``, > 0.

    Returns
    -------
    (V,) float64
        ``omega``, with mean 1.

    Notes
    -----
    With ``m = median(D)`` and ``s = max(1.4826 median(|D - m|), 1e-3 |m| + 1e-9)``,

        omega_c = w_c / mean(w),   w_c = r_min + (1 - r_min) sigmoid((m + s - D_c) / (lam s)).
    """
    D = np.asarray(residuals, dtype=np.float64)
    m = np.median(D)
    s = max(1.4826 * np.median(np.abs(D - m)), 1e-3 * abs(m) + 1e-9)
    raw = r_min + (1.0 - r_min) * expit((m + s - D) / (lam * s))
    return raw / raw.mean()


class BCEObjective:
    """The loss of Eq. 7 and its gradient with respect to ``q`` or the logits.

    One evaluation is one pass of ``A`` and one of ``A^T`` (in the dtype
    of ``A``: float32 in the solver, float64 in gradient checks) with the
    per-pixel work between them in numpy (:class:`~._bce.PixelBCE`).

    Parameters
    ----------
    problem : Problem
        The stacked problem; its ``alpha`` (row sums of ``A``) is computed here.
    normalize : bool, default False
        Predict ``W q / alpha`` with pixel weights ``alpha`` (True) or the
        literal ``W q`` with weights 1 (False); see the module docstring.
    alpha_min : float, default 1e-3
        Pixels with less rendered opacity are not usable.
    eps : float, default 1e-4
        Probability clip of the BCE, in (0, 0.5).

    Attributes
    ----------
    rows : (M,) int64
        The usable pixels: known, with ``alpha >= alpha_min``.
    s : (M,) float64, or None
        Their weights ``s_u`` (the others weigh 0); None for the literal
        prediction, whose weights are all 1.
    evidence : (N,) bool
        Gaussians with weight on at least one usable pixel (``s_u > 0``);
        the loss does not depend on the others.
    binary : bool
        Whether every known target is 0 or 1.
    seconds : dict
        Wall seconds spent so far in the sparse products (``"passes"``: ``A q``
        and ``A^T g``) and in the per-pixel work (``"pixels"``).
    """

    def __init__(self, problem: Problem, normalize: bool = False, alpha_min: float = 1e-3, eps: float = 1e-4):
        self.A, self.AT = problem.A, problem.AT
        self.dtype = self.A.dtype
        alpha = problem.alpha  # float32, the stack's cached row sums
        use = problem.known & (alpha >= alpha_min)
        # Everything per pixel lives on the usable pixels only (no P-sized float64 arrays).
        self.rows = np.flatnonzero(use)
        counts = np.diff(np.searchsorted(self.rows, problem.offsets))  # usable pixels per view
        if normalize:
            self.s = alpha[self.rows].astype(np.float64)
            self.s_view = np.bincount(np.repeat(np.arange(problem.n_views), counts), weights=self.s,
                                      minlength=problem.n_views)
            inv_alpha = 1.0 / self.s
        else:
            self.s, self.s_view = None, counts.astype(np.float64)
            inv_alpha = np.empty(0)  # the literal prediction p = A q
        self.binary = bool(np.all((problem.y == 0) | (problem.y == 1) | ~problem.known))
        self.eps = eps
        self.problem = problem
        self.Z = max(float(self.s_view.sum()), 1e-30)
        self.evidence = np.asarray(self.AT @ use.astype(self.dtype)).ravel() > 0
        self._pixels = PixelBCE(self.rows, problem.y[self.rows], self.s, inv_alpha, eps, problem.y.size, self.dtype,
                                offsets=problem.offsets)
        self._q_last = None
        self.seconds = {"passes": 0.0, "pixels": 0.0}

    def _timed(self, part: str, fn, *args):
        t0 = time.perf_counter()
        out = fn(*args)
        self.seconds[part] += time.perf_counter() - t0
        return out

    def _adjoint(self, g: np.ndarray) -> np.ndarray:
        return self._timed("passes", self.AT.__matmul__, g)

    def _evaluate(self, q: np.ndarray, weights=None) -> None:
        """The per-pixel BCE at ``q`` (N,), and the pixel gradient for ``weights`` (``omega / Z``) if given.

        One pass ``A q``, skipped when ``q`` is where it was last evaluated:
        the residuals of the start (and after each inner run) are taken at
        the point the optimiser evaluates next (or just evaluated), so each
        outer step saves a pass.
        """
        q = np.array(q, dtype=self.dtype)  # a copy: callers update their q in place
        if self._q_last is not None and np.array_equal(q, self._q_last):
            return
        pred = self._timed("passes", self.A.__matmul__, q)
        self._timed("pixels", self._pixels.evaluate, pred, weights)
        self._q_last = q

    def _forward(self, q: np.ndarray, omega: np.ndarray) -> tuple:
        """(loss ``sum_u omega_c s_u BCE_u / Z``, pixel gradient ``g`` (P,) in A's dtype) at ``q`` (N,)."""
        w = np.asarray(omega, dtype=np.float64) / self.Z
        self._evaluate(q, w)
        return self._timed("pixels", self._pixels.loss_grad, w)

    def pixel_bce(self, q: np.ndarray) -> np.ndarray:
        """BCE of every usable pixel (P,) at ``q`` (N,); 0 at the others."""
        self._evaluate(q)
        return self._pixels.bce()

    def residuals(self, q: np.ndarray) -> np.ndarray:
        """``D_c``: weighted mean BCE of each view (V,) at ``q``; 0 for a view with no usable pixel."""
        self._evaluate(q)
        num = self._pixels.view_sums()
        return np.divide(num, self.s_view, out=np.zeros_like(num), where=self.s_view > 0)

    def loss_grad_q(self, q: np.ndarray, omega: np.ndarray) -> tuple:
        """``(L, dL/dq)`` at ``q`` (N,) with view weights ``omega`` (V,)."""
        loss, g = self._forward(q, omega)
        return loss, np.asarray(self._adjoint(g), dtype=np.float64).ravel()

    def loss_grad_rows(self, x: np.ndarray, rows: np.ndarray, q_full: np.ndarray, omega: np.ndarray) -> tuple:
        """``(L, dL/dx)`` for the logits ``x`` of the Gaussians ``rows`` only.

        ``q_full`` (N,) holds ``q`` of every Gaussian; its entries at ``rows``
        are overwritten with ``q_rows = sigmoid(x)``, and
        ``dL/dx = q_rows (1 - q_rows) (dL/dq)_rows``.
        """
        qr = expit(x)
        q_full[rows] = qr
        loss, g = self._forward(q_full, omega)
        gq = self._adjoint(g)[rows]
        return loss, qr * (1.0 - qr) * gq



def _logit(p):
    """``log(p / (1 - p))``, the inverse of ``expit``."""
    return np.log(p) - np.log1p(-p)


def _check(o: dict) -> None:
    """Raise a ValidationError for option values weighted_bce cannot take (``o``: every option by name)."""
    check_range("weighted_bce: r_min", o["r_min"], "in [0, 1]", lo=0.0, hi=1.0)
    check_range("weighted_bce: lam", o["lam"], "positive", lo=0.0, lo_open=True)
    check_range("weighted_bce: momentum", o["momentum"], "in [0, 1)", lo=0.0, hi=1.0, hi_open=True)
    check_range("weighted_bce: alpha_min", o["alpha_min"], "in [0, 1)", lo=0.0, hi=1.0, hi_open=True)
    check_range("weighted_bce: eps", o["eps"], "in (0, 0.5)", lo=0.0, hi=0.5, lo_open=True, hi_open=True)
    check_range("weighted_bce: init_clip", o["init_clip"], "in (0, 0.5)", lo=0.0, hi=0.5, lo_open=True,
                hi_open=True)
    check_range("weighted_bce: stable_tol", o["stable_tol"], "in [0, 1)", lo=0.0, hi=1.0, hi_open=True)
    for name in ("weight_tol", "ftol", "gtol"):
        check_range(f"weighted_bce: {name}", o[name], "a finite number >= 0", lo=0.0)
    for name in ("reweight", "normalize"):
        if not isinstance(o[name], (bool, np.bool_)):
            raise ValidationError(f"weighted_bce: {name} must be True or False, got {o[name]!r}")
    for name in ("max_iter", "inner_iters", "maxcor"):
        check_count("weighted_bce", name, o[name])
    if o["start"] not in ("auto", "vote", "prior", "half"):
        raise ValidationError(f"weighted_bce: start must be 'auto', 'vote', 'prior' or 'half', got {o['start']!r}")
    check_count("weighted_bce", "stable_iters", o["stable_iters"], minimum=0)
    if o["optimizer"] not in ("scipy", "lbfgs"):
        raise ValidationError(f"weighted_bce: optimizer must be 'scipy' or 'lbfgs', got {o['optimizer']!r}")


class _SelectionWatch:
    """Per-iteration callback that ends an inner run once the selection ``x > 0`` has settled.

    An iteration is calm when at most ``n_flip`` logits changed sign since the
    previous iteration; after ``stable_iters`` calm iterations in a row it sets
    ``fired`` and raises ``StopIteration`` (never when ``stable_iters`` is 0).
    """

    def __init__(self, x0: np.ndarray, n_flip: int, stable_iters: int):
        self.sel, self.calm, self.fired = x0 > 0, 0, False
        self.n_flip, self.stable_iters = n_flip, stable_iters

    def __call__(self, xk) -> None:
        sel = np.asarray(xk) > 0
        flips = int(np.count_nonzero(sel != self.sel))
        self.sel = sel
        self.calm = self.calm + 1 if flips <= self.n_flip else 0
        if self.stable_iters and self.calm >= self.stable_iters:
            self.fired = True
            raise StopIteration


class WeightedBCE:
    """The reweighted BCE solve as separate steps: ``setup``, ``step``, ``run``, ``finalize``.

    :func:`weighted_bce` is ``WeightedBCE(problem, callbacks).solve(**options)``;
    the class exposes the outer loop so that each step can be run, inspected
    and tested on its own.

    Parameters
    ----------
    problem : Problem
        The stacked problem (:func:`~seed2gs_inverse.solvers.prepare`).
    callbacks : sequence of callable, optional
        Each is called as ``callback(solver, x, loss)`` after every L-BFGS
        iteration, in order, with ``x`` the logits (R,) float64 of the
        optimised Gaussians and ``loss`` the objective at ``x``; raising
        ``StopIteration`` ends the current inner run.

    Attributes
    ----------
    objective : BCEObjective
        The loss of Eq. 7 (after :meth:`setup`).
    rows : (R,) int64
        The optimised Gaussians: those with evidence.
    q_full : (N,) ndarray, A's dtype
        ``q`` of every Gaussian at the last evaluated logits.
    D, omega : (V,) float64
        Running view residuals and view weights (0 for a view without
        usable pixels).
    iterations : int
        L-BFGS iterations of all inner runs so far.
    iiter : int
        Iterations reported to the callbacks so far.
    nfev : int
        Objective evaluations so far.
    history : list of dict
        One record per outer step (see :func:`weighted_bce`).
    converged : bool
        Whether the last step met the stopping rule.
    message : str
        Why the last inner run stopped.
    """

    def __init__(self, problem: Problem, callbacks=None):
        self.problem = problem
        self.callbacks = list(callbacks) if callbacks is not None else []

    def setup(self, *, r_min: float = 0.05, lam: float = 0.5, momentum: float = 0.5, reweight: bool = True,
              normalize: bool = False, alpha_min: float = 1e-3, eps: float = 1e-4, max_iter: int = 200,
              inner_iters: int = 20, weight_tol: float = 1e-3, ftol: float = 1e-10, gtol: float = 1e-9,
              init_clip: float = 0.1, maxcor: int = 5, start: str = "auto", optimizer: str = "scipy",
              stable_iters: int = 0, stable_tol: float = 1e-4) -> np.ndarray:
        """Check the options, build the objective, the start and the first view weights.

        Parameters
        ----------
        r_min, lam, momentum, reweight, normalize, alpha_min, eps, max_iter, inner_iters, weight_tol, ftol, \
gtol, init_clip, maxcor, start, optimizer, stable_iters, stable_tol
            The options of :func:`weighted_bce`, with the same defaults.

        Returns
        -------
        x : (R,) float64
            The starting logits of the optimised Gaussians (empty when no
            pixel is usable: then :meth:`run` does nothing and
            :meth:`finalize` returns the prior).

        Raises
        ------
        ValidationError
            An option value the method cannot take.
        """
        _check(dict(r_min=r_min, lam=lam, momentum=momentum, reweight=reweight, normalize=normalize,
                    alpha_min=alpha_min, eps=eps, max_iter=max_iter, inner_iters=inner_iters, weight_tol=weight_tol,
                    ftol=ftol, gtol=gtol, init_clip=init_clip, maxcor=maxcor, start=start, optimizer=optimizer,
                    stable_iters=stable_iters, stable_tol=stable_tol))
        t_start = time.perf_counter()
        self.r_min, self.lam, self.momentum, self.reweight = r_min, lam, momentum, reweight
        self.alpha_min, self.max_iter, self.inner_iters, self.weight_tol = alpha_min, max_iter, inner_iters, weight_tol
        self.ftol, self.gtol, self.maxcor, self.optimizer = ftol, gtol, maxcor, optimizer
        self.stable_iters = stable_iters
        self.iterations, self.iiter, self.nfev, self.history = 0, 0, 0, []
        self.message, self.converged = "", False
        self.objective = obj = BCEObjective(self.problem, normalize=normalize, alpha_min=alpha_min, eps=eps)
        # Views without a usable pixel take no part in the weight statistics; Gaussians seen by no
        # usable pixel have no evidence and keep the prior.
        self.active = obj.s_view > 0
        self.rows = np.flatnonzero(obj.evidence)
        if self.rows.size == 0:
            self.seconds_setup = time.perf_counter() - t_start
            return np.empty(0)
        q_start = np.clip(self._start(start), init_clip, 1.0 - init_clip)
        x = _logit(q_start[self.rows])
        self.q_full = q_start.astype(obj.dtype)  # A's dtype: the products take it without a conversion
        self.q_full[self.rows] = expit(x)  # as every evaluation computes it, so the start's residuals are reused
        self.n_flip = max(int(stable_tol * self.rows.size), 0)
        self.D = obj.residuals(self._q(x))
        self.omega = self._weights(self.D)
        # The curvature pairs of optimizer="lbfgs" carry over between outer steps: a reweighting
        # changes the loss only mildly, and a fresh memory would restart with a steepest-descent step.
        self.memory = deque(maxlen=int(maxcor))
        self.seconds_setup = time.perf_counter() - t_start
        self._setup_seconds = dict(obj.seconds)
        return x

    def _start(self, start: str) -> np.ndarray:
        """The starting ``q`` (N,) for ``start`` (before the clip to ``[init_clip, 1 - init_clip]``)."""
        p = self.problem
        if start == "vote" or (start == "auto" and not p.init_given):
            # The closed-form answer of the same evidence: most Gaussians start on the side they end on.
            return np.where(p.observed, voting(p).q, p.prior)
        if start == "half" and not p.init_given:
            return np.full(p.n_gaussians, 0.5)
        return p.prior

    def _q(self, x: np.ndarray) -> np.ndarray:
        """``q`` of every Gaussian (a copy of :attr:`q_full`) with ``sigmoid(x)`` at the optimised ones."""
        self.q_full[self.rows] = expit(x)
        return self.q_full.copy()

    def _weights(self, D: np.ndarray) -> np.ndarray:
        """Eq. 6 over the active views (all ones without ``reweight``); 0 for the others."""
        omega = np.zeros(self.problem.n_views)
        omega[self.active] = view_weights(D[self.active], self.r_min, self.lam) if self.reweight else 1.0
        return omega

    def _minimize(self, fun, x: np.ndarray, n_iter: int, callback) -> tuple:
        """One inner run of the chosen optimiser: ``(x, loss, iterations, status, message)``."""
        if self.optimizer == "lbfgs":
            return _lbfgs(fun, x, n_iter, self.ftol, self.gtol, self.memory, callback=callback)

        def scipy_callback(intermediate_result):  # the parameter name selects scipy's result-object form
            callback(intermediate_result.x, intermediate_result.fun)

        res = minimize(fun, x, jac=True, method="L-BFGS-B", callback=scipy_callback,
                       options={"maxiter": n_iter, "maxcor": int(self.maxcor), "ftol": self.ftol, "gtol": self.gtol})
        return res.x, float(res.fun), int(res.nit), int(res.status), str(res.message)

    def step(self, x: np.ndarray) -> np.ndarray:
        """One outer step: an inner L-BFGS run under the current weights, then a weight update.

        Parameters
        ----------
        x : (R,) float64
            The current logits.

        Returns
        -------
        x : (R,) float64
            The logits after the inner run. The step appends a record to
            :attr:`history` and sets :attr:`converged`.

        Notes
        -----
        The inner run takes ``min(inner_iters, max_iter - iterations)``
        iterations at most. Then ``D <- momentum D + (1 - momentum) D(q)``
        and ``omega <- Eq. 6 (D)``. The step has converged when the inner
        run did (or took no iteration) and either the weights moved less than
        ``weight_tol`` or the selection settled: the inner run was ended by
        the ``stable_iters`` rule and changed the sign of at most
        ``stable_tol R`` logits in all.
        """
        omega, sel_before = self.omega, x > 0
        watch = _SelectionWatch(x, self.n_flip, self.stable_iters)

        def fun(xo):
            self.nfev += 1
            return self.objective.loss_grad_rows(xo, self.rows, self.q_full, omega)

        def after_iteration(xk, fk):
            self.iiter += 1
            for callback in self.callbacks:  # first: the iteration happened even if the selection settled
                callback(self, xk, fk)
            watch(xk)

        n_iter = min(self.inner_iters, self.max_iter - self.iterations)
        x, f, nit, status, self.message = self._minimize(fun, x, n_iter, after_iteration)
        if watch.fired:
            status, self.message = 0, f"selection unchanged for {self.stable_iters} iterations"
        self.iterations += nit
        self.D = self.momentum * self.D + (1.0 - self.momentum) * self.objective.residuals(self._q(x))
        new_omega = self._weights(self.D)
        change = float(np.max(np.abs(new_omega - omega)))
        settled = watch.fired and int(np.count_nonzero((x > 0) != sel_before)) <= self.n_flip
        self.history.append({"loss": float(f), "iterations": nit, "weights": new_omega.tolist(),
                             "residuals": self.D.tolist(), "weight_change": change, "selection_settled": settled})
        self.omega = new_omega
        self.converged = (status == 0 or nit == 0) and (change < self.weight_tol or settled)
        return x

    def run(self, x: np.ndarray) -> np.ndarray:
        """Outer steps from ``x`` (R,) until a step converges or ``max_iter`` iterations are spent.

        At most ``max_iter`` outer steps (each runs at least one iteration
        unless already optimal). Returns the final logits (R,).
        """
        if self.rows.size == 0:
            return x
        for _ in range(self.max_iter):
            if self.iterations >= self.max_iter:
                break
            x = self.step(x)
            if self.converged:
                break
        return x

    def finalize(self, x: np.ndarray) -> MethodResult:
        """The :class:`MethodResult` of the solve ending at logits ``x`` (R,); see :func:`weighted_bce`."""
        obj = self.objective
        if self.rows.size == 0:
            return MethodResult(q=self.problem.prior.copy(), iterations=0, view_weights=np.zeros(self.problem.n_views),
                                history=[], observed=obj.evidence,
                                info={"function_evaluations": 0, "message": "no usable pixel (every known pixel has "
                                         f"alpha < alpha_min = {self.alpha_min:g})", "outer_steps": 0,
                                      "seconds_setup": self.seconds_setup, "seconds_passes": 0.0,
                                      "seconds_pixels": 0.0})
        return MethodResult(q=self._q(x), iterations=self.iterations, view_weights=self.omega, history=self.history,
                            observed=obj.evidence,
                            info={"function_evaluations": self.nfev, "message": self.message,
                                  "outer_steps": len(self.history), "seconds_setup": self.seconds_setup,
                                  "seconds_passes": obj.seconds["passes"] - self._setup_seconds["passes"],
                                  "seconds_pixels": obj.seconds["pixels"] - self._setup_seconds["pixels"]})

    def solve(self, **options) -> MethodResult:
        """``finalize(run(setup(**options)))``: the whole solve; ``options`` as for :meth:`setup`."""
        x = self.setup(**options)
        x = self.run(x)
        return self.finalize(x)


def _report(solver: WeightedBCE, x: np.ndarray, loss: float) -> None:
    """Callback forwarding each iteration to the progress of :func:`~seed2gs_inverse.solvers.solve`."""
    report_progress(solver.iiter, solver.max_iter, loss)


def weighted_bce(problem: Problem, *, r_min: float = 0.05, lam: float = 0.5, momentum: float = 0.5,
                 reweight: bool = True, normalize: bool = False, alpha_min: float = 1e-3, eps: float = 1e-4,
                 max_iter: int = 200, inner_iters: int = 20, weight_tol: float = 1e-3, ftol: float = 1e-10,
                 gtol: float = 1e-9, init_clip: float = 0.1, maxcor: int = 5, start: str = "auto",
                 optimizer: str = "scipy", stable_iters: int = 0, stable_tol: float = 1e-4) -> MethodResult:
    """Seed2GS reliability-weighted BCE (Eqs. 6-8), registered as ``solve(method="weighted_bce")``.

    Runs :class:`WeightedBCE` with the progress of
    :func:`~seed2gs_inverse.solvers.solve` as its callback; the module
    docstring gives the objective, its gradient and the view weights.

    Parameters
    ----------
    problem : Problem
    r_min : float, default 0.05
        Weight floor of Eq. 6 (before mean normalisation), in [0, 1]; chosen
        on benchmarks/bench_solvers.py, whose masks include views with
        switched identities.
    lam : float, default 0.5
        Temperature ``lambda`` of Eq. 6, > 0.
    momentum : float, default 0.5
        Running residual ``D <- momentum D + (1 - momentum) D(q)``, in [0, 1).
    reweight : bool, default True
        False fixes all view weights at 1 (the unweighted ablation).
    normalize : bool, default False
        Predict the literal ``W q`` with pixel weights 1 (False) or
        ``W q / alpha`` with pixel weights ``alpha`` (True).
    alpha_min : float, default 1e-3
        Pixels with less rendered opacity are left out, in [0, 1).
    eps : float, default 1e-4
        Probability clip of the BCE, in (0, 0.5).
    max_iter : int, default 200
        Total L-BFGS iterations, >= 1.
    inner_iters : int, default 20
        L-BFGS iterations between view-weight updates, >= 1.
    weight_tol : float, default 1e-3
        Stop when the weights change less than this (max abs) and the inner
        run converged.
    ftol, gtol : float, default 1e-10, 1e-9
        L-BFGS tolerances, as in scipy's L-BFGS-B: stop when the relative
        loss decrease is at most ``ftol`` or ``max |dL/dl| <= gtol`` (the
        loss is a per-pixel mean, O(1)).
    init_clip : float, default 0.1
        The starting ``q`` is clipped to ``[init_clip, 1 - init_clip]``, in (0, 0.5).
    maxcor : int, default 5
        L-BFGS memory (pairs kept); the update costs O(maxcor N).
    start : {"auto", "vote", "prior", "half"}, default "auto"
        Starting point: ``"vote"`` the closed-form vote ``A1 / (A0 + A1)``
        for every Gaussian with known weight and the prior (``init``, default
        0) for the others, also when ``init`` is given; ``"prior"`` the prior
        alone; ``"half"`` 0.5 where no ``init`` is given (the prior
        otherwise); ``"auto"`` the prior when ``init`` is given, else the vote.
    optimizer : {"scipy", "lbfgs"}, default "scipy"
        scipy's L-BFGS-B (the reference), or :func:`~._lbfgs.lbfgs`, whose
        curvature memory carries over between outer steps; scipy is the
        default because neither wins on the selections of
        benchmarks/bench_solvers.py and benchmarks/bench_extract.py.
    stable_iters : int, default 0 (off)
        An inner run also ends when the selection ``q > 1/2`` of the
        optimised Gaussians has changed for at most ``stable_tol`` of them
        in each of the last ``stable_iters`` iterations, and the solve ends
        when a whole inner run left the selection so unchanged. 0 disables
        the rule (only the loss tolerances and ``max_iter`` stop); off by
        default because it trades held-out accuracy on eroded masks for
        time (benchmarks/bench_extract.py).
    stable_tol : float, default 1e-4
        Fraction of the optimised Gaussians allowed to flip per iteration
        while the selection counts as unchanged, in [0, 1).

    Returns
    -------
    MethodResult
        ``q`` (N,) in A's dtype; ``iterations`` (L-BFGS iterations in all);
        ``view_weights`` (V,) float64, the final ``omega`` (0 for a view
        without usable pixels); ``history``, one record per outer step with
        ``loss``, ``iterations``, ``weights``, ``residuals``,
        ``weight_change`` and ``selection_settled``; ``observed`` (N,) bool,
        the Gaussians with weight on a usable pixel (:func:`solve` gives the
        others the prior); ``info`` with ``function_evaluations``, the
        convergence ``message``, ``outer_steps``, ``seconds_setup`` (the
        objective, the start and the first view weights) and, after the
        setup, ``seconds_passes`` and ``seconds_pixels`` (the sparse
        products and the per-pixel work of the evaluations). Without any
        usable pixel nothing is fitted: ``q`` is the prior and every view
        weight 0.

    Raises
    ------
    ValidationError
        An option value outside the ranges above.
    """
    solver = WeightedBCE(problem, callbacks=[_report])
    return solver.solve(r_min=r_min, lam=lam, momentum=momentum, reweight=reweight, normalize=normalize,
                        alpha_min=alpha_min, eps=eps, max_iter=max_iter, inner_iters=inner_iters,
                        weight_tol=weight_tol, ftol=ftol, gtol=gtol, init_clip=init_clip, maxcor=maxcor,
                        start=start, optimizer=optimizer, stable_iters=stable_iters, stable_tol=stable_tol)


register_method("weighted_bce", weighted_bce, check=_check)
