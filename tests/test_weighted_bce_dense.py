"""weighted_bce against dense references written from its formulas (Seed2GS Eqs. 6-8).

Each test recomputes, in float64 on dense matrices, what the solver must do:
the loss it descends, its minimum, the view weights it fits with, the start
it begins from, the moment its stability rule stops it, and the search
direction of the built-in L-BFGS. None of them reuses the solver's code.
"""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest
from scipy.optimize import minimize

import seed2gs_inverse.solvers.weighted_bce as wb
from seed2gs_inverse.solvers import prepare
from seed2gs_inverse.solvers.weighted_bce import BCEObjective, view_weights, weighted_bce

from _solver_scenes import blob_stack, random_views

ALPHA_MIN = 1e-3


class Dense:
    """The problem as dense float64 arrays, and Eq. 7 written out from the module docstring."""

    def __init__(self, mats, masks, eps=1e-4, normalize=False):
        self.A = np.vstack([W.toarray() for W in mats]).astype(np.float64)
        y = np.concatenate([m.ravel() for m in masks]).astype(np.float64)
        self.view = np.concatenate([np.full(W.shape[0], c) for c, W in enumerate(mats)])
        # the rendered opacity as the solver holds it: row sums rounded to float32 (documented)
        self.alpha = self.A.sum(1).astype(np.float32).astype(np.float64)
        self.known = ~np.isnan(y)
        self.y = np.where(self.known, y, 0.0)
        self.use = self.known & (self.alpha >= ALPHA_MIN)
        self.s = np.where(self.use, self.alpha if normalize else 1.0, 0.0)
        self.div = np.where(self.use, self.alpha, 1.0) if normalize else np.ones_like(self.alpha)
        self.eps, self.n_views = eps, len(mats)
        self.evidence = (self.A[self.use] > 0).any(0)
        yk = np.where(self.known, y, 0.0)[:, None]
        self.a1 = (self.A * yk * self.known[:, None]).sum(0)  # foreground votes, pixel by pixel
        self.a0 = (self.A * (1 - yk) * self.known[:, None]).sum(0)

    def vote(self, prior):
        seen = self.a0 + self.a1 > 0
        return np.where(seen, self.a1 / np.where(seen, self.a0 + self.a1, 1.0), prior)

    def _p(self, q):
        return np.clip(self.A @ q / self.div, self.eps, 1 - self.eps)

    def loss(self, q, omega):
        p = self._p(q)
        bce = -(self.y * np.log(p) + (1 - self.y) * np.log(1 - p))
        return float(np.sum(omega[self.view] * self.s * bce) / self.s.sum())

    def grad_q(self, q, omega):
        raw = self.A @ q / self.div
        p = np.clip(raw, self.eps, 1 - self.eps)
        g = omega[self.view] * self.s * (p - self.y) / (p * (1 - p)) * (raw == p) / self.div / self.s.sum()
        return self.A.T @ g

    def residuals(self, q):
        """D_c: the s-weighted mean BCE of view c's usable pixels."""
        p = self._p(q)
        bce = -(self.y * np.log(p) + (1 - self.y) * np.log(1 - p))
        num = np.bincount(self.view, self.s * bce, self.n_views)
        den = np.bincount(self.view, self.s, self.n_views)
        return num / den


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


def _logit(p):
    return np.log(p / (1 - p))


# -- the gradient the solver descends -------------------------------------------------------
@pytest.mark.parametrize("normalize", [False, True])
@pytest.mark.parametrize("binary", [False, True])
def test_row_gradient_matches_finite_differences_of_the_dense_loss(rng, normalize, binary):
    """``loss_grad_rows`` (what weighted_bce calls: the logits of some Gaussians, the others fixed at their
    q) against central differences of Eq. 7 written densely, with the loss itself equal to it."""
    mats, masks = random_views(rng, n=30, density=0.3, binary=binary)
    prob = prepare(mats, masks)
    A = prob.matrix().astype(np.float64)  # float64 products: the comparison is not limited by float32
    prob = type(prob)(A=A, AT=A.T.tocsr(), y=prob.y, known=prob.known, offsets=prob.offsets,
                      image_shapes=prob.image_shapes, names=prob.names, known_weight=prob.known_weight,
                      prior=prob.prior)
    eps = 1e-6
    obj = BCEObjective(prob, normalize=normalize, alpha_min=ALPHA_MIN, eps=eps)
    dense = Dense(mats, masks, eps=eps, normalize=normalize)
    omega = rng.uniform(0.5, 1.5, len(mats))
    rows = np.flatnonzero(rng.random(A.shape[1]) < 0.6)
    q_fixed = rng.uniform(0.05, 0.95, A.shape[1])  # the Gaussians that do not move hold a nontrivial q
    x0 = rng.normal(scale=0.8, size=rows.size)

    def dense_loss(x):
        q = q_fixed.copy()
        q[rows] = _sigmoid(x)
        return dense.loss(q, omega)

    loss, g = obj.loss_grad_rows(x0, rows, q_fixed.copy(), omega)
    assert loss == pytest.approx(dense_loss(x0), rel=1e-10)
    h = 1e-6
    fd = np.array([(dense_loss(x0 + h * e) - dense_loss(x0 - h * e)) / (2 * h) for e in np.eye(rows.size)])
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-9)
    assert np.abs(g).max() > 1e-3


# -- what the optimiser reaches -------------------------------------------------------------
@pytest.mark.parametrize("optimizer", ["scipy", "lbfgs"])
def test_the_fit_reaches_the_minimum_of_the_loss(rng, optimizer):
    """With fixed view weights Eq. 7 is convex in q on the box [0, 1]^N. Its minimum, found by scipy's
    bounded L-BFGS-B on the dense loss, is what weighted_bce's fit reaches, far below its start's loss."""
    mats, masks = random_views(rng, n=40, density=0.3)
    dense = Dense(mats, masks)
    omega = np.ones(len(mats))
    ev = dense.evidence
    r = weighted_bce(prepare(mats, masks), reweight=False, max_iter=400, ftol=0.0, gtol=1e-9,
                     optimizer=optimizer)

    def fun(qe):
        q = np.zeros(ev.size)
        q[ev] = qe
        return dense.loss(q, omega), dense.grad_q(q, omega)[ev]

    ref = minimize(fun, np.full(ev.sum(), 0.5), jac=True, method="L-BFGS-B", bounds=[(0, 1)] * int(ev.sum()),
                   options={"ftol": 0, "gtol": 1e-12, "maxiter": 5000})
    start = np.clip(dense.vote(np.zeros(ev.size)), 0.1, 0.9)
    got = dense.loss(r.q.astype(np.float64), omega)
    assert dense.loss(start, omega) - ref.fun > 0.05 * ref.fun  # the start is far from the minimum
    assert got == pytest.approx(ref.fun, rel=2e-4)
    assert r.history[-1]["loss"] == pytest.approx(got, rel=1e-5)


# -- the view weights (Eq. 6) and the running residuals --------------------------------------
def test_view_weights_follow_the_running_residuals_and_weigh_the_fit(rng, monkeypatch):
    """Each outer step: ``D <- m D + (1 - m) D(q)``, ``omega = Eq. 6(D)`` with the caller's ``r_min`` and
    ``lam``, and the next inner run minimises the loss under those weights (its reported loss is the dense
    weighted loss at its q)."""
    mats, masks = random_views(rng, n=40, views=5, density=0.3)
    dense = Dense(mats, masks)
    r_min, lam, m = 0.1, 0.8, 0.3
    prob = prepare(mats, masks)
    runs = []
    real = wb.minimize

    def spy(fun, x0, **kw):
        res = real(fun, x0, **kw)
        runs.append(res.x.copy())
        return res

    monkeypatch.setattr(wb, "minimize", spy)
    r = weighted_bce(prob, r_min=r_min, lam=lam, momentum=m, inner_iters=4, max_iter=12, weight_tol=0.0)
    rows = np.flatnonzero(dense.evidence)
    assert len(r.history) == len(runs) >= 2
    start = np.clip(dense.vote(np.zeros(dense.A.shape[1])), 0.1, 0.9)
    D = dense.residuals(start)
    omega = view_weights(D, r_min, lam)
    for h, x in zip(r.history, runs):
        q = start.copy()
        q[rows] = _sigmoid(x)
        # the run's loss is the one under the weights it was given
        assert h["loss"] == pytest.approx(dense.loss(q, omega), rel=1e-5)
        D = m * D + (1 - m) * dense.residuals(q)
        np.testing.assert_allclose(h["residuals"], D, rtol=1e-5)
        omega = view_weights(D, r_min, lam)
        np.testing.assert_allclose(h["weights"], omega, rtol=1e-5)
    np.testing.assert_allclose(r.view_weights, omega, rtol=1e-5)
    assert np.ptp(omega) > 0.05  # the weights differ between views: the check above has something to see


def test_reweighting_recovers_the_object_despite_identity_switched_views():
    """Two of nine views follow background splats (a tracker's identity switch): the view weights push
    them down, and the weighted fit beats the unweighted one clearly on held-out views."""
    from seed2gs_inverse.metrics import iou
    from seed2gs_inverse.solvers import solve

    stack, labels, masks = blob_stack(seed=0, n_views=12)
    train, bad, held = list(range(9)), [2, 6], [9, 10, 11]
    other = np.zeros_like(labels)
    other[np.flatnonzero(~labels)[:60]] = True
    fit = [stack[i].image(other.astype(np.float32)) > 0.5 if i in bad else masks[i] for i in train]

    def held_out(sel):
        return np.mean([iou(stack[i].image(sel.astype(np.float32)) > 0.5,
                            stack[i].image(labels.astype(np.float32)) > 0.5) for i in held])

    r = solve(stack.subset(train), fit, method="weighted_bce", max_iter=80)
    plain = solve(stack.subset(train), fit, method="weighted_bce", reweight=False, max_iter=80)
    good = [i for i in train if i not in bad]
    assert r.view_weights[bad].max() < 0.5 * r.view_weights[good].min()
    assert held_out(r.selected()) >= held_out(plain.selected()) + 0.02
    assert held_out(r.selected()) >= 0.98


# -- the start -------------------------------------------------------------------------------
@pytest.mark.parametrize("start, init, expected", [
    ("auto", None, "vote"), ("vote", "support", "vote"), ("auto", "support", "prior"),
    ("prior", "support", "prior"), ("half", None, "half"), ("half", "support", "prior")])
def test_the_start_is_the_documented_one(rng, monkeypatch, start, init, expected):
    """The first logits L-BFGS-B receives: the clipped vote (observed Gaussians; the prior elsewhere), the
    clipped prior, or 0.5, on the Gaussians with evidence, computed densely."""
    mats, masks = random_views(rng, n=40, density=0.3)
    dense = Dense(mats, masks)
    support = np.zeros(40, bool)
    support[::3] = True
    prior = support.astype(np.float64) if init == "support" else np.zeros(40)
    q0 = {"vote": dense.vote(prior), "prior": prior, "half": np.full(40, 0.5)}[expected]
    seen = []
    real = wb.minimize

    def spy(fun, x0, **kw):
        seen.append(np.array(x0))
        return real(fun, x0, **kw)

    monkeypatch.setattr(wb, "minimize", spy)
    weighted_bce(prepare(mats, masks, init=support if init else None), start=start, max_iter=1)
    want = _logit(np.clip(q0, 0.1, 0.9))[dense.evidence]
    np.testing.assert_allclose(seen[0], want, rtol=1e-5, atol=1e-6)


# -- the stability rule ----------------------------------------------------------------------
@pytest.mark.parametrize("stable_iters, stable_tol", [(3, 0.0), (2, 0.02)])
def test_the_stability_rule_stops_exactly_when_the_selection_held_still(monkeypatch, stable_iters, stable_tol):
    """Replaying the selection ``x > 0`` after every iteration: the inner run ends at the first iteration
    that ends ``stable_iters`` iterations in a row each flipping at most ``stable_tol`` of the optimised
    Gaussians, not before, and ``selection_settled`` says whether the whole run flipped so few."""
    stack, labels, masks = blob_stack(seed=0, n_views=12)
    train = [i for i in range(12) if i not in (3, 7, 11)]
    support = labels & (np.arange(labels.size) % 3 == 0)  # a partial prior: the selection has to move
    runs = []
    real = wb.minimize

    def spy(fun, x0, callback=None, **kw):
        xs = [np.array(x0)]

        def record(intermediate_result):  # the name scipy looks for to pass the whole result
            xs.append(np.array(intermediate_result.x))
            callback(intermediate_result)

        res = real(fun, x0, callback=record, **kw)
        runs.append((xs, "callback" in str(res.message)))  # scipy's message when the callback stopped it
        return res

    monkeypatch.setattr(wb, "minimize", spy)
    r = weighted_bce(prepare(stack.subset(train), [masks[i] for i in train], init=support), start="prior",
                     stable_iters=stable_iters, stable_tol=stable_tol, max_iter=60, inner_iters=30)
    fired_any = False
    for (xs, stopped), h in zip(runs, r.history):
        n_flip = int(stable_tol * xs[0].size)
        flips = [int(np.count_nonzero((a > 0) != (b > 0))) for a, b in zip(xs, xs[1:])]
        calm = [f <= n_flip for f in flips]
        stop = next((k + 1 for k in range(stable_iters - 1, len(calm)) if all(calm[k - stable_iters + 1:k + 1])),
                    None)
        assert h["iterations"] == len(flips)
        if stop is None:  # never calm enough: the run ended on its budget or by converging, not by the rule
            assert not stopped
        else:
            assert stopped and h["iterations"] == stop, (flips, h["iterations"])
            fired_any = True
            total = int(np.count_nonzero((xs[0] > 0) != (xs[-1] > 0)))
            assert h["selection_settled"] == (total <= n_flip)
    assert fired_any
    first = runs[0][0]
    assert max(int(np.count_nonzero((a > 0) != (b > 0))) for a, b in zip(first, first[1:])) > 0


# -- the built-in L-BFGS's direction ------------------------------------------------------------
def test_lbfgs_direction_is_the_bfgs_inverse_hessian_times_the_gradient():
    """With curvature pairs in memory, the first step of the built-in L-BFGS goes along ``-H g``, ``H`` the
    BFGS inverse-Hessian approximation built densely from those pairs (Nocedal & Wright, Eq. 6.17,
    started from ``gamma I``, ``gamma = s.y / y.y`` of the newest pair)."""
    rng = np.random.default_rng(11)
    n = 8
    M = rng.normal(size=(n, n))
    B = M @ M.T + np.eye(n)
    b = rng.normal(size=n)
    pairs = []
    for _ in range(3):
        s = rng.normal(size=n)
        y = B @ s
        pairs.append((s, y, 1.0 / (s @ y)))
    s, y, _ = pairs[-1]
    H = (s @ y) / (y @ y) * np.eye(n)
    for s, y, rho in pairs:
        V = np.eye(n) - rho * np.outer(y, s)
        H = V.T @ H @ V + rho * np.outer(s, s)
    x0 = rng.normal(size=n)
    g0 = B @ x0 - b
    steps = []
    wb._lbfgs(lambda x: (0.5 * x @ B @ x - b @ x, B @ x - b), x0.copy(), 1, 0.0, 0.0, deque(pairs, maxlen=5),
              callback=lambda x, f: steps.append(x - x0))
    d, want = steps[0], -H @ g0
    assert d @ want / (np.linalg.norm(d) * np.linalg.norm(want)) == pytest.approx(1.0, abs=1e-10)
