"""Solvers against independent references: dense formulas, finite differences, scipy."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear
from scipy.stats import beta as beta_dist

from _solver_scenes import blob_stack, random_views as _random_problem
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.metrics import iou
from seed2gs_inverse.operators import ViewOperator
from seed2gs_inverse.solvers import (MethodResult, Problem, available_methods, get_method, method_options, prepare,
                                     register_method, solve)
from seed2gs_inverse.solvers.beta_bernoulli import beta_entropy
from seed2gs_inverse.solvers.voting import bias_to_threshold
from seed2gs_inverse.solvers.weighted_bce import BCEObjective, view_weights

METHODS = ("voting", "beta_bernoulli", "weighted_bce", "least_squares")


def test_registry_lists_all_methods():
    assert set(METHODS) <= set(available_methods())


# -- voting ------------------------------------------------------------------------
def test_voting_matches_dense_votes_and_bias_rule(rng):
    mats, masks = _random_problem(rng)
    A1 = np.zeros(40)
    A0 = np.zeros(40)
    for W, m in zip(mats, masks):
        D = W.toarray().astype(np.float64)
        y = m.ravel().astype(np.float64)
        for u in range(D.shape[0]):
            if np.isnan(y[u]):
                continue
            A1 += D[u] * y[u]
            A0 += D[u] * (1 - y[u])
    seen = (A0 + A1) > 0
    for bias in (0.0, 0.3, -0.2):
        r = solve(mats, masks, method="voting", bias=bias)
        np.testing.assert_allclose(r.q[seen], (A1 / (A0 + A1))[seen], rtol=1e-5)
        norm = np.hypot(A0, A1)
        rule = seen & (A1 / np.where(seen, norm, 1) - A0 / np.where(seen, norm, 1) > bias)
        np.testing.assert_array_equal(r.selected(), rule)
        np.testing.assert_array_equal(r.unobserved, ~seen)
    assert bias_to_threshold(0.0) == 0.5
    with pytest.raises(ValidationError, match="bias"):
        solve(mats, masks, method="voting", bias=1.5)


def test_voting_halves_on_two_threads_match_the_dense_votes_and_one_thread(rng, monkeypatch):
    """Above PARALLEL_MIN_GAUSSIANS the arithmetic after the pass runs in two halves on two threads: q is
    the same bit for bit as on one thread, and both are the dense vote (an odd N: halves of unequal size)."""
    from seed2gs_inverse import _threads
    from seed2gs_inverse.solvers import voting as voting_module

    mats, masks = _random_problem(rng, n=41)
    A = np.vstack([W.toarray() for W in mats]).astype(np.float64)
    y = np.concatenate([m.ravel() for m in masks]).astype(np.float64)
    k = ~np.isnan(y)
    a1 = A[k].T @ y[k]
    a0 = A[k].T @ (1 - y[k])
    monkeypatch.setattr(voting_module, "PARALLEL_MIN_GAUSSIANS", 1)
    calls = []
    real = voting_module.run_both
    monkeypatch.setattr(voting_module, "run_both", lambda fn, parallel: (calls.append(parallel), real(fn, parallel)))
    got = {}
    for threads in (1, 2):
        monkeypatch.setattr(_threads, "n_threads", lambda t=threads: t)
        got[threads] = solve(mats, masks, method="voting")
    assert calls == [True, True]
    np.testing.assert_array_equal(got[1].q, got[2].q)
    assert got[1].info["total_votes"] == got[2].info["total_votes"]
    seen = a0 + a1 > 0
    np.testing.assert_allclose(got[2].q[seen], (a1 / (a0 + a1))[seen], rtol=1e-5)
    assert np.all(got[2].q[~seen] == 0)
    assert got[2].info["total_votes"] == pytest.approx((a0 + a1).sum(), rel=1e-5)


def test_nan_pixels_carry_no_evidence(rng):
    mats, masks = _random_problem(rng)
    r1 = solve(mats, masks, method="voting")
    # Replacing the unknown pixels by anything must not change the result when they stay unknown,
    # and removing those rows from the operators gives the same votes.
    cut_mats, cut_masks = [], []
    for W, m in zip(mats, masks):
        keep = ~np.isnan(m.ravel())
        cut_mats.append(sp.csr_matrix(W[np.flatnonzero(keep)]))
        cut_masks.append(m.ravel()[keep][None, :])
    r2 = solve(cut_mats, cut_masks, method="voting")
    np.testing.assert_allclose(r1.q, r2.q, rtol=1e-5)


def test_mask_dtypes_are_equivalent(rng):
    mats, _ = _random_problem(rng, density=0.3)
    bools = [rng.random((5, 6)) > 0.5 for _ in mats]
    r_bool = solve(mats, bools, method="voting")
    r_u8 = solve(mats, [b.astype(np.uint8) * 255 for b in bools], method="voting")
    r_f = solve(mats, [b.astype(np.float64) for b in bools], method="voting")
    np.testing.assert_array_equal(r_bool.q, r_u8.q)
    np.testing.assert_array_equal(r_bool.q, r_f.q)


# -- beta-Bernoulli --------------------------------------------------------------------
def test_beta_entropy_matches_scipy():
    a = np.array([0.5, 1.0, 2.0, 7.5, 120.0, 3.0])
    b = np.array([0.5, 1.0, 5.0, 1.2, 80.0, 3000.0])
    np.testing.assert_allclose(beta_entropy(a, b), beta_dist(a, b).entropy(), rtol=1e-10, atol=1e-12)


def test_beta_bernoulli_posterior_and_order_independence(rng):
    mats, masks = _random_problem(rng)
    a = np.full(40, 2.0)
    b = np.full(40, 0.5)
    for W, m in zip(mats, masks):
        D = W.toarray().astype(np.float64)
        y = m.ravel().astype(np.float64)
        k = ~np.isnan(y)
        a += D[k].T @ y[k]
        b += D[k].T @ (1 - y[k])
    r = solve(mats, masks, method="beta_bernoulli", a0=2.0, b0=0.5)
    obs = ~r.unobserved
    np.testing.assert_allclose(r.q[obs], (a / (a + b))[obs], rtol=1e-5)
    perm = [2, 0, 3, 1]
    r2 = solve([mats[i] for i in perm], [masks[i] for i in perm], method="beta_bernoulli", a0=2.0, b0=0.5)
    np.testing.assert_allclose(r.q, r2.q, rtol=1e-5)
    assert r.iterations == 4 and r.info["order"] == [0, 1, 2, 3]
    # a budget in the given order absorbs the first views one by one: same posterior as the dense sum
    a3, b3 = np.full(40, 2.0), np.full(40, 0.5)
    for W, m in zip(mats[:3], masks[:3]):
        D = W.toarray().astype(np.float64)
        y = m.ravel().astype(np.float64)
        k = ~np.isnan(y)
        a3 += D[k].T @ y[k]
        b3 += D[k].T @ (1 - y[k])
    r3 = solve(mats, masks, method="beta_bernoulli", a0=2.0, b0=0.5, budget=3)
    np.testing.assert_allclose(r3.q[~r3.unobserved], (a3 / (a3 + b3))[~r3.unobserved], rtol=1e-6)
    assert r3.info["order"] == [0, 1, 2] and len(r3.history) == 3


def _eig_reference(mats, masks, a, b, view):
    """EIG of one view by a per-Gaussian loop with scipy.stats entropies."""
    W = mats[view].toarray().astype(np.float64)
    k = ~np.isnan(masks[view].ravel())
    e = W[k].sum(0)
    total = 0.0
    for i in np.flatnonzero(e > 0):
        q = a[i] / (a[i] + b[i])
        total += (beta_dist(a[i], b[i]).entropy() - q * beta_dist(a[i] + e[i], b[i]).entropy()
                  - (1 - q) * beta_dist(a[i], b[i] + e[i]).entropy())
    return total


def test_beta_bernoulli_eig_order_follows_reference_gains(rng):
    mats, masks = _random_problem(rng, n=25, views=4, density=0.2)
    r = solve(mats, masks, method="beta_bernoulli", order="eig", budget=3)
    a = np.ones(25)
    b = np.ones(25)
    remaining = [0, 1, 2, 3]
    for step in range(3):
        gains = {c: _eig_reference(mats, masks, a, b, c) for c in remaining}
        best = max(gains, key=gains.get)
        assert r.info["order"][step] == best
        assert r.history[step]["eig"] == pytest.approx(gains[best], rel=1e-8)
        W = mats[best].toarray().astype(np.float64)
        y = masks[best].ravel().astype(np.float64)
        k = ~np.isnan(y)
        a += W[k].T @ y[k]
        b += W[k].T @ (1 - y[k])
        remaining.remove(best)
    assert r.iterations == 3 and r.view_weights.sum() == 3 and r.view_weights[remaining[0]] == 0
    # Gaussians only the unused view sees keep the prior
    W_unused = mats[remaining[0]].toarray()
    used = np.zeros(25, bool)
    for c in r.info["order"]:
        used |= (mats[c].toarray()[~np.isnan(masks[c].ravel())] > 0).any(0)
    only = (W_unused > 0).any(0) & ~used
    assert np.all(r.unobserved[only]) and np.all(r.q[only] == 0)


def test_eig_prefers_new_evidence_over_a_duplicate(rng):
    n = 30
    base = sp.random(20, n, density=0.3, random_state=rng, format="csr", dtype=np.float32) * 0.2
    other = sp.csr_matrix(base[:, ::-1])  # the same evidence on other Gaussians
    mats = [base, sp.csr_matrix(base), other]
    m = (rng.random((4, 5)) > 0.5)
    r = solve(mats, [m, m, m], method="beta_bernoulli", order="eig", budget=2)
    assert sorted(r.info["order"]) != [0, 1]


# -- least squares --------------------------------------------------------------------
@pytest.mark.parametrize("target", ["alpha", "mask"])
def test_least_squares_fista_matches_scipy(rng, target):
    mats, masks = _random_problem(rng, n=30, views=4, density=0.3)
    r = solve(mats, masks, method="least_squares", target=target, tol=1e-7, max_iter=20000)
    A = np.vstack([W.toarray() for W in mats]).astype(np.float64)
    y = np.concatenate([m.ravel() for m in masks]).astype(np.float64)
    alpha = A.sum(1)
    keep = ~np.isnan(y) & (alpha > 0)
    rhs = (y * alpha if target == "alpha" else y)[keep]
    obs = (A[keep] > 0).any(0)
    ref = lsq_linear(A[keep][:, obs], rhs, bounds=(0, 1), method="bvls", tol=1e-12).x
    np.testing.assert_allclose(r.q[obs], ref, atol=2e-3)
    # lsq_linear at its default tolerance (not FISTA's 1e-4, which stopped it 0.01 away in q)
    r2 = solve(mats, masks, method="least_squares", target=target, algorithm="lsq_linear")
    np.testing.assert_allclose(r2.q[obs], ref, atol=1e-5)


# -- weighted BCE ------------------------------------------------------------------------
def _float64_problem(rng, n=30, views=3, binary=False):
    mats, masks = _random_problem(rng, n=n, views=views, density=0.3)
    if binary:  # 0/1 masks take the solver's fast path
        masks = [np.where(np.isnan(m), np.nan, (m > 0.5).astype(np.float32)) for m in masks]
    p = prepare(mats, masks)
    A = p.matrix().astype(np.float64)
    return Problem(A=A, AT=A.T.tocsr(), y=p.y, known=p.known, offsets=p.offsets, image_shapes=p.image_shapes,
                   names=p.names, known_weight=p.known_weight, prior=p.prior)


@pytest.mark.parametrize("binary", [False, True])
def test_weighted_bce_loss_matches_direct_sum(rng, binary):
    prob = _float64_problem(rng, binary=binary)
    eps = 1e-4
    obj = BCEObjective(prob, normalize=False, alpha_min=1e-3, eps=eps)
    omega = rng.uniform(0.5, 1.5, prob.n_views)
    q = rng.random(prob.n_gaussians)
    A = prob.A.toarray()
    total, Z = 0.0, 0.0
    for c in range(prob.n_views):
        rows = range(prob.offsets[c], prob.offsets[c + 1])
        for u in rows:
            if not prob.known[u] or A[u].sum() < 1e-3:
                continue
            p = min(max(A[u] @ q, eps), 1 - eps)
            y = float(prob.y[u])
            total += omega[c] * -(y * np.log(p) + (1 - y) * np.log(1 - p))
            Z += 1.0
    assert obj.loss_grad_q(q, omega)[0] == pytest.approx(total / Z, rel=1e-10)



@pytest.mark.parametrize("normalize", [False, True])
@pytest.mark.parametrize("lost_view", [None, 0, 1, 2])
def test_weighted_bce_residuals_match_direct_sums_also_after_q_changes_in_place(rng, normalize, lost_view):
    """D_c is the s-weighted mean BCE of view c's usable pixels (brute force from the formula; 0 for a
    view without any). The objective reuses its last evaluation for an equal q: changing the caller's
    q in place must not."""
    prob = _float64_problem(rng)
    if lost_view is not None:
        prob.known[prob.view_rows(lost_view)] = False
    eps = 1e-4
    obj = BCEObjective(prob, normalize=normalize, alpha_min=1e-3, eps=eps)
    A = prob.A.toarray()

    def direct(q):
        D = np.zeros(prob.n_views)
        for c in range(prob.n_views):
            num = den = 0.0
            for u in range(prob.offsets[c], prob.offsets[c + 1]):
                a = float(prob.alpha[u])  # the rendered opacity, as the solver sees it (float32)
                if not prob.known[u] or a < 1e-3:
                    continue
                p = min(max(A[u] @ q / (a if normalize else 1.0), eps), 1 - eps)
                y = float(prob.y[u])
                s = a if normalize else 1.0
                num += s * -(y * np.log(p) + (1 - y) * np.log(1 - p))
                den += s
            D[c] = num / den if den > 0 else 0.0
        return D

    q = rng.random(prob.n_gaussians)
    np.testing.assert_allclose(obj.residuals(q), direct(q), rtol=1e-12)
    if lost_view is not None:
        assert obj.residuals(q)[lost_view] == 0 and np.all(np.delete(obj.residuals(q), lost_view) > 0)
    np.testing.assert_allclose(obj.residuals(q), direct(q), rtol=1e-12)  # the reused evaluation
    q[::2] = rng.random(q[::2].size)  # in place, as the solver updates its q
    np.testing.assert_allclose(obj.residuals(q), direct(q), rtol=1e-12)
    assert np.any(obj.residuals(q) != direct(q * 0.5))

def test_view_weights_equal_eq6():
    D = np.array([0.10, 0.12, 0.11, 0.50, 0.09, 0.13, 0.30])
    r_min, lam = 0.2, 0.5
    m = np.median(D)
    s = 1.4826 * np.median(np.abs(D - m))
    raw = np.array([r_min + (1 - r_min) / (1 + np.exp(-(m + s - d) / (lam * s))) for d in D])
    np.testing.assert_allclose(view_weights(D, r_min, lam), raw / raw.mean(), rtol=1e-12)
    w = view_weights(D, r_min, lam)
    assert w.mean() == pytest.approx(1.0) and np.argmin(w) == 3
    # all views alike: MAD = 0 must not divide by zero, and every view keeps weight 1
    np.testing.assert_allclose(view_weights(np.full(5, 0.2)), np.ones(5))


def test_weighted_bce_respects_box_and_prior(rng):
    mats, masks = _random_problem(rng)
    support = np.zeros(40, bool)
    support[:5] = True
    r = solve(mats, masks, method="weighted_bce", init=support, max_iter=30)
    assert r.q.dtype == np.float32 and r.q.shape == (40,)
    assert np.all((r.q >= 0) & (r.q <= 1))
    np.testing.assert_array_equal(r.q[r.unobserved], support[r.unobserved].astype(np.float32))
    assert r.iterations <= 30 and r.history and r.view_weights.shape == (4,)
    assert r.view_weights.mean() == pytest.approx(1.0)


# -- recovery on a geometric scene ---------------------------------------------------------
@pytest.fixture(scope="module")
def blob():
    return blob_stack(seed=0, n_views=12)


def _heldout_miou(stack, q_selected, labels, views):
    ious = []
    for i in views:
        pred = stack[i].image(q_selected.astype(np.float32)) > 0.5
        truth = stack[i].image(labels.astype(np.float32)) > 0.5
        ious.append(iou(pred, truth))
    return float(np.mean(ious))


@pytest.mark.parametrize("method", METHODS)
def test_clean_masks_recover_the_object_on_heldout_views(blob, method):
    stack, labels, masks = blob
    held = [3, 7, 11]
    train = [i for i in range(12) if i not in held]
    r = solve(stack.subset(train), [masks[i] for i in train], method=method)
    assert _heldout_miou(stack, r.selected(), labels, held) >= 0.99


def test_weighted_bce_optimizers_agree(blob):
    # scipy's L-BFGS-B (the reference) and the built-in L-BFGS minimise the
    # same objective: same loss to a small tolerance and the same object.
    stack, labels, masks = blob
    held = [3, 7, 11]
    train = [i for i in range(12) if i not in held]
    fit = [masks[i] for i in train]
    ref = solve(stack.subset(train), fit, method="weighted_bce", optimizer="scipy", max_iter=150)
    fast = solve(stack.subset(train), fit, method="weighted_bce", optimizer="lbfgs", max_iter=150)
    assert abs(fast.history[-1]["loss"] - ref.history[-1]["loss"]) <= 0.05 * ref.history[-1]["loss"] + 1e-4
    assert np.mean(fast.selected() == ref.selected()) > 0.99
    assert _heldout_miou(stack, fast.selected(), labels, held) >= 0.99
    with pytest.raises(ValidationError, match="optimizer"):
        solve(stack.subset(train), fit, method="weighted_bce", optimizer="adam")


# -- bad input ----------------------------------------------------------------------------
def test_bad_inputs_name_the_view(rng):
    mats, masks = _random_problem(rng)
    with pytest.raises(ValidationError, match="empty"):
        solve([], [], method="voting")
    with pytest.raises(ValidationError, match="view 2.*35 pixels"):
        solve(mats, masks[:2] + [np.zeros((5, 7))] + masks[3:], method="voting")
    views = [ViewOperator(W, None, (5, 6)) for W in mats]
    with pytest.raises(ValidationError, match=r"view 2.*\(6, 5\).*\(5, 6\)"):
        solve(views, masks[:2] + [np.zeros((6, 5))] + masks[3:], method="voting")
    with pytest.raises(ValidationError, match="view 1.*different scenes"):
        solve([mats[0], sp.csr_matrix(mats[1][:, :-1])] + mats[2:], masks, method="voting")
    with pytest.raises(ValidationError, match="3 masks for 4 views"):
        solve(mats, masks[:3], method="voting")
    with pytest.raises(ValidationError, match="view 0.*\\[0, 1\\]"):
        solve(mats, [masks[0] * 3] + masks[1:], method="voting")
    with pytest.raises(ValidationError, match="view 3.*infinite"):
        solve(mats, masks[:3] + [np.full((5, 6), np.inf)], method="voting")
    with pytest.raises(ValidationError, match="entirely NaN"):
        solve(mats, [np.full((5, 6), np.nan)] * 4, method="voting")
    with pytest.raises(ValidationError, match="unknown method"):
        solve(mats, masks, method="magic")
    with pytest.raises(ValidationError, match="no option.*'bias'"):
        solve(mats, masks, method="voting", learning_rate=1)
    with pytest.raises(ValidationError, match="init"):
        solve(mats, masks, method="voting", init=np.zeros(3, bool))


def test_lost_view_carries_no_evidence(rng):
    mats, masks = _random_problem(rng)
    lost = [m.copy() for m in masks]
    lost[1][:] = np.nan
    r = solve(mats, lost, method="weighted_bce", max_iter=20)
    assert r.view_weights[1] == 0 and np.isfinite(r.q).all()
    np.testing.assert_allclose(solve(mats, lost, method="voting").q,
                               solve([mats[i] for i in (0, 2, 3)], [masks[i] for i in (0, 2, 3)],
                                     method="voting").q, rtol=1e-5)


def test_register_a_new_method(rng, monkeypatch):
    from seed2gs_inverse.solvers import _common

    monkeypatch.setattr(_common, "_METHODS", dict(_common._METHODS))  # keep the registry clean for others

    def half(problem, *, value: float = 0.5, note: str = "x"):
        return MethodResult(q=np.full(problem.n_gaussians, value), iterations=3, info={"note": note})

    register_method("constant_test", half)
    mats, masks = _random_problem(rng)
    r = solve(mats, masks, method="constant_test", value=0.7)
    assert "constant_test" in available_methods() and get_method("constant_test") is half
    assert method_options("constant_test") == {"value": 0.5, "note": "x"}
    assert np.all(r.q[~r.unobserved] == np.float32(0.7)) and np.all(r.q[r.unobserved] == 0)
    assert r.iterations == 3 and r.info["note"] == "x" and r.info["n_weak_evidence"] == 0
    # a method must return a MethodResult, not the old dict
    register_method("dict_test", lambda problem: {"q": np.zeros(problem.n_gaussians)})
    with pytest.raises(RuntimeError, match="MethodResult"):
        solve(mats, masks, method="dict_test")
    with pytest.raises(ValidationError, match="unknown method"):
        method_options("no_such_method")



def test_methods_run_with_one_blas_thread_and_the_limit_is_lifted_after(rng, monkeypatch):
    """Solvers call BLAS on (N,) vectors every iteration: one BLAS thread while a method runs, so
    OpenBLAS's spinning workers never compete with the two pass threads; the caller's setting after."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from seed2gs_inverse.solvers import _common

    monkeypatch.setattr(_common, "_METHODS", dict(_common._METHODS))
    seen = []

    def probe(problem):
        seen.append([lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"])
        return MethodResult(q=np.zeros(problem.n_gaussians))

    register_method("blas_probe", probe)
    mats, masks = _random_problem(rng)
    with threadpool_limits(limits=2, user_api="blas"):
        before = [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]
        for _ in range(2):
            solve(mats, masks, method="blas_probe")
        after = [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]
    assert seen and all(n == [1] * len(before) for n in seen) and before
    assert after == before

def test_method_options_list_every_builtin_option():
    import inspect

    for name in available_methods():
        opts = method_options(name)
        params = inspect.signature(get_method(name)).parameters
        assert list(opts) == [k for k, p in params.items() if p.kind == p.KEYWORD_ONLY]
        assert opts == {k: params[k].default for k in opts}
    assert method_options("voting") == {"bias": 0.0}
    assert method_options("weighted_bce")["max_iter"] == 200


def test_stack_and_matrix_list_give_the_same_answer(blob):
    stack, labels, masks = blob
    mats = [v.W for v in stack]
    for method in ("voting", "beta_bernoulli"):
        np.testing.assert_allclose(solve(stack, masks, method=method).q, solve(mats, masks, method=method).q,
                                   rtol=1e-5, atol=1e-7)
    holes = [m.astype(np.float32) for m in masks]
    holes[0][:10] = np.nan
    np.testing.assert_allclose(solve(stack, holes, method="voting").q, solve(mats, holes, method="voting").q,
                               rtol=1e-5, atol=1e-7)


# -- weighted BCE: kernel, optimiser, no-evidence cases -----------------------------------
@pytest.mark.parametrize("normalize", [False, True])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_bce_pixel_kernel_matches_numpy_formula(rng, normalize, dtype):
    from seed2gs_inverse.solvers.weighted_bce import bce_pixels

    n, eps = 500, 1e-3
    pred = rng.uniform(-0.01, 1.01, n).astype(dtype)
    pred[:20] = [0, eps / 2, 1, 1 - eps / 2] * 5  # clipped both sides
    y = rng.random(n)
    y[::3] = 1.0
    y[1::3] = 0.0
    w = rng.uniform(0.1, 2.0, n)
    w[::7] = 0.0
    alpha = rng.uniform(0.5, 1.0, n)
    inv_alpha = 1.0 / alpha if normalize else np.empty(0)
    bce, g = bce_pixels(pred, y, w, inv_alpha, eps)
    assert bce.dtype == np.float64 and g.dtype == dtype
    # binary targets are computed in the prediction's dtype: p = pred * (1 / alpha), each factor and the
    # product rounded to it, clipped at the dtype's nearest values to eps and 1 - eps; soft targets in
    # float64 (the formula, in float64)
    binary = (y == 0) | (y == 1)
    p = pred.astype(np.float64) / (alpha if normalize else 1.0)
    p_dtype = (pred * (1.0 / alpha).astype(dtype)).astype(np.float64) if normalize else pred.astype(np.float64)
    p = np.where(binary, p_dtype, p)
    lo = np.where(binary, float(dtype(eps)), eps)
    hi = np.where(binary, float(dtype(1 - eps)), 1 - eps)
    inside = (p > lo) & (p < hi)
    p = np.clip(p, lo, hi)
    ref_bce = np.where(w > 0, -(y * np.log(p) + (1 - y) * np.log1p(-p)), 0.0)
    ref_g = np.where(inside, w * (p - y) / (p * (1 - p)), 0.0) / (alpha if normalize else 1.0)
    tol = 1e-12 if dtype == np.float64 else 1e-6
    np.testing.assert_allclose(bce, ref_bce, rtol=tol, atol=0)
    np.testing.assert_allclose(g, ref_g, rtol=tol, atol=0)
    assert np.all(g[~inside] == 0) and np.all(g[w == 0] == 0) and np.any(g != 0)


def test_bce_halves_on_two_threads_match_the_formula_and_one_thread(rng, monkeypatch):
    """Above PARALLEL_MIN_PIXELS the two halves run on two threads: same loss and gradient as one thread,
    and as the formula."""
    from seed2gs_inverse import _threads
    from seed2gs_inverse.solvers import _bce

    n, eps = 2 * _bce.PARALLEL_MIN_PIXELS + 11, 1e-4
    pred = rng.uniform(-0.01, 1.01, n).astype(np.float32)
    y = rng.random(n)
    y[::3] = 1.0
    y[1::3] = 0.0
    w = rng.uniform(0.1, 2.0, n)
    w[::7] = 0.0
    got = {}
    for threads in (1, 2):
        monkeypatch.setattr(_threads, "n_threads", lambda t=threads: t)
        rows = np.flatnonzero(w)
        pixels = _bce.PixelBCE(rows, y[rows], w[rows], np.empty(0), eps, n, np.float32)
        pixels.evaluate(pred)
        loss, g = pixels.loss_grad(np.ones(1))  # one view of weight 1: w_u = s_u
        got[threads] = (loss, g.copy())
    assert got[1][0] == got[2][0]
    np.testing.assert_array_equal(got[1][1], got[2][1])
    lo, hi = float(np.float32(eps)), float(np.float32(1 - eps))  # binary targets: float32 arithmetic
    p64 = pred.astype(np.float64)
    p = np.where((y == 0) | (y == 1), np.clip(p64, lo, hi), np.clip(p64, eps, 1 - eps))
    ref = float(np.sum(w * -(y * np.log(p) + (1 - y) * np.log1p(-p))))
    assert got[2][0] == pytest.approx(ref, rel=1e-7)  # float32 terms, summed in float64
    inside = np.where((y == 0) | (y == 1), (pred > lo) & (pred < hi), (pred > eps) & (pred < 1 - eps))
    np.testing.assert_allclose(got[2][1], np.where(inside, w * (p - y) / (p * (1 - p)), 0.0), rtol=1e-6)


def test_lbfgs_finds_known_minimisers():
    from collections import deque

    from seed2gs_inverse.solvers.weighted_bce import _lbfgs

    # convex quadratic 0.5 x^T H x - b^T x: the minimiser solves H x = b
    r = np.random.default_rng(3)
    M = r.normal(size=(30, 30))
    H, b = M @ M.T + 0.5 * np.eye(30), r.normal(size=30)
    x, f, nit, status, _ = _lbfgs(lambda x: (0.5 * x @ H @ x - b @ x, H @ x - b), np.zeros(30), 500, 0.0, 1e-10,
                                  deque(maxlen=5))
    # f-based line searches resolve x to about sqrt(machine eps) relative to the loss scale
    np.testing.assert_allclose(x, np.linalg.solve(H, b), rtol=0, atol=1e-6)
    assert status == 0 and 0 < nit < 500 and np.abs(H @ x - b).max() < 1e-6

    # Rosenbrock: minimum at (1, 1), the classic test of the line search and the curvature pairs
    def rosen(v):
        a, c = v
        return (1 - a) ** 2 + 100 * (c - a * a) ** 2, np.array([-2 * (1 - a) - 400 * a * (c - a * a),
                                                                 200 * (c - a * a)])
    x, f, nit, status, _ = _lbfgs(rosen, np.array([-1.2, 1.0]), 500, 0.0, 1e-8, deque(maxlen=5))
    np.testing.assert_allclose(x, [1.0, 1.0], atol=1e-6)
    assert status == 0 and f < 1e-12
    # the iteration budget is honoured
    assert _lbfgs(rosen, np.array([-1.2, 1.0]), 3, 0.0, 1e-8, deque(maxlen=5))[2:4] == (3, 1)


def test_lbfgs_first_step_is_scipys():
    """Without curvature pairs the first trial step has unit length, as in scipy's L-BFGS-B.

    On a flat quadratic (``|g| = 1e-3`` at the start) both take the step
    ``-g / |g|``, which satisfies both line searches; a step capped at 1 in
    units of the gradient would move only 1e-3.
    """
    from collections import deque

    from scipy.optimize import minimize

    from seed2gs_inverse.solvers.weighted_bce import _lbfgs

    c = np.random.default_rng(5).normal(size=40)
    c *= 5.0 / np.linalg.norm(c)

    def fun(x):
        return 0.5e-4 * np.sum((x - c) ** 2), 1e-4 * (x - c)

    ours, theirs = [], []
    _lbfgs(fun, np.zeros(40), 1, 0.0, 0.0, deque(maxlen=5), callback=lambda x, f: ours.append(x.copy()))
    minimize(fun, np.zeros(40), jac=True, method="L-BFGS-B", options={"maxiter": 1},
             callback=lambda xk: theirs.append(np.array(xk)))
    np.testing.assert_allclose(ours[0], 0.2 * c, rtol=1e-12)  # x0 - g / |g|: unit length towards c
    np.testing.assert_allclose(theirs[0], ours[0], rtol=1e-9)


def test_lbfgs_extends_a_short_step_to_the_wolfe_conditions():
    """A step that leaves the slope nearly as steep is extended until it flattens (weak Wolfe)."""
    from collections import deque

    from seed2gs_inverse.solvers.weighted_bce import _lbfgs

    c = np.random.default_rng(6).normal(size=40)
    c *= 20.0 / np.linalg.norm(c)  # a unit step from 0 reaches only 5% of the way to the minimiser c

    def fun(x):
        return 0.5e-4 * np.sum((x - c) ** 2), 1e-4 * (x - c)

    steps = []
    _lbfgs(fun, np.zeros(40), 1, 0.0, 0.0, deque(maxlen=5), callback=lambda x, f: steps.append(x.copy()))
    f0, g0 = fun(np.zeros(40))
    d = steps[0]  # x1 - x0, along -g0
    f1, g1 = fun(steps[0])
    assert f1 <= f0 + 1e-4 * (g0 @ d)  # Armijo
    assert g1 @ d >= 0.9 * (g0 @ d)  # the slope flattened (a unit step leaves it at 0.95 of the start's)
    assert np.linalg.norm(d) > 1.0


def test_lbfgs_keeps_the_last_good_step_when_an_extension_overshoots():
    """A step that passes Armijo is kept when the longer one tried after it fails."""
    from collections import deque

    from seed2gs_inverse.solvers.weighted_bce import _lbfgs

    # slope -1 up to x = 1.5, then a steep wall: the unit step is short, four of them overshoot
    def fun(x):
        over = max(x[0] - 1.5, 0.0)
        return -x[0] + 50.0 * over ** 3, np.array([-1.0 + 150.0 * over ** 2])

    calls = []

    def counted(x):
        calls.append(float(x[0]))
        return fun(x)

    x, f, nit, status, _ = _lbfgs(counted, np.zeros(1), 1, 0.0, 0.0, deque(maxlen=5))
    assert (nit, status) == (1, 1) and x[0] == 1.0 and f == -1.0
    assert calls == [0.0, 1.0, 4.0]  # the start, the unit step, the overshooting extension


def test_lbfgs_extends_a_bounded_number_of_times():
    """On a loss unbounded below the extensions stop (10 of 4x each) instead of running away."""
    from collections import deque

    from seed2gs_inverse.solvers.weighted_bce import _lbfgs

    calls = []

    def linear(x):
        calls.append(float(x[0]))
        return -float(x.sum()), -np.ones_like(x)

    x, f, nit, status, _ = _lbfgs(linear, np.zeros(4), 1, 0.0, 0.0, deque(maxlen=5))
    assert (nit, status) == (1, 1)
    assert len(calls) == 1 + 11  # the start, the unit-length step and 10 extensions
    np.testing.assert_allclose(x, 0.5 * 4.0 ** 10)  # -g / |g| = (1/2, 1/2, 1/2, 1/2), times 4^10


def _faint_problem(rng, faint_views):
    """4 views; in ``faint_views`` every pixel's rendered opacity is below 1e-3."""
    mats, masks = _random_problem(rng)
    mats = [sp.csr_matrix(W * np.float32(1e-4)) if i in faint_views else W for i, W in enumerate(mats)]
    return mats, masks


def test_weighted_bce_without_usable_pixels_keeps_the_prior_cleanly(rng):
    import warnings

    mats, masks = _faint_problem(rng, faint_views=range(4))
    prior = np.linspace(0, 1, 40)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "Mean of empty slice" / invalid divide
        for init in (None, prior):
            r = solve(mats, masks, method="weighted_bce", init=init)
            np.testing.assert_array_equal(r.q, (np.zeros(40) if init is None else prior).astype(np.float32))
            assert r.unobserved.all() and r.iterations == 0
            np.testing.assert_array_equal(r.view_weights, np.zeros(4))


def test_weighted_bce_gaussians_seen_only_by_faint_pixels_keep_the_prior(rng):
    mats, masks = _faint_problem(rng, faint_views=[1])
    hide = sp.diags(np.r_[np.zeros(3), np.ones(37)].astype(np.float32))  # Gaussians 0-2: only in the faint view
    mats = [W if i == 1 else sp.csr_matrix(W @ hide) for i, W in enumerate(mats)]
    evidence = sum(np.asarray(mats[i].T @ ~np.isnan(masks[i].ravel())).ravel() for i in (0, 2, 3)) > 0
    assert not evidence[:3].any() and (np.asarray(mats[1].sum(0)).ravel()[:3] > 0).all()
    prior = np.full(40, 0.3)
    r = solve(mats, masks, method="weighted_bce", init=prior, max_iter=30)
    assert r.view_weights[1] == 0 and r.view_weights[[0, 2, 3]].mean() == pytest.approx(1.0)
    np.testing.assert_array_equal(r.unobserved, ~evidence)
    np.testing.assert_array_equal(r.q[~evidence], np.float32(0.3))
    assert np.all(r.q[evidence] != np.float32(0.3))  # the others moved


def test_weighted_bce_times_its_passes_and_pixel_work_apart(rng, monkeypatch):
    """info splits the method's seconds: set-up, sparse products, per-pixel work, the rest (the optimiser)."""
    import time

    from seed2gs_inverse.operators import _passes

    delay = 0.004
    calls = {"forward": 0, "adjoint": 0}
    for name in calls:  # every product of the stack sleeps: the passes' share is known from below
        def slow(*args, _f=getattr(_passes, name), _name=name):
            calls[_name] += 1
            time.sleep(delay)
            return _f(*args)
        monkeypatch.setattr(_passes, name, slow)
    mats, masks = _random_problem(rng)
    r = solve(mats, masks, method="weighted_bce", max_iter=15)
    info = r.info
    assert r.iterations > 0 and info["function_evaluations"] > 0
    # after the set-up: one adjoint per evaluation, and a forward pass for each new q
    assert info["seconds_passes"] >= delay * info["function_evaluations"]
    assert 0 < info["seconds_pixels"] < info["seconds_passes"]
    parts = info["seconds_setup"] + info["seconds_passes"] + info["seconds_pixels"]
    assert parts <= info["seconds_method"]
    assert calls["adjoint"] >= info["function_evaluations"] and calls["forward"] >= 1


def test_weighted_bce_accepts_numpy_integer_options(rng):
    mats, masks = _random_problem(rng)
    r = solve(mats, masks, method="weighted_bce", maxcor=np.int64(3), inner_iters=np.int32(10), max_iter=40)
    assert 0 < r.iterations <= 40 and np.isfinite(r.q).all()


# -- min_evidence (common to every method) and the typed method result ----------------------
@pytest.mark.parametrize("method", METHODS)
def test_min_evidence_gives_weakly_seen_gaussians_the_prior(blob, method):
    stack, labels, masks = blob
    holes = [m.astype(np.float32) for m in masks]
    for m in holes:
        m[: m.shape[0] // 2] = np.nan  # the upper half of every view is unknown
    prior = np.random.default_rng(0).random(stack.n_gaussians)
    # independent evidence: dense column sums over the known pixels, view by view
    evidence = sum(v.W.toarray().astype(np.float64).T @ (~np.isnan(m)).ravel() for v, m in zip(stack, holes))
    base = solve(stack, holes, method=method, init=prior)
    # min_evidence = 0: only the unobserved Gaussians (no known weight at all) take the prior
    assert base.info["n_weak_evidence"] == 0 and int(base.unobserved.sum()) == int((evidence <= 0).sum())
    # a threshold midway between two evidence values, so float32 sums cannot fall on its other side
    ev = np.unique(evidence[evidence > 0])
    k = int(np.argmax(np.diff(ev[ev.size // 4: ev.size // 2]))) + ev.size // 4
    thr = float(0.5 * (ev[k] + ev[k + 1]))
    weak = evidence < thr
    r = solve(stack, holes, method=method, init=prior, min_evidence=thr)
    assert 0 < weak.sum() < stack.n_gaussians and r.info["n_weak_evidence"] == int(weak.sum())
    np.testing.assert_array_equal(r.q[weak], prior[weak].astype(np.float32))
    np.testing.assert_array_equal(r.q[~weak], base.q[~weak])
    np.testing.assert_array_equal(r.unobserved, base.unobserved)  # unobserved keeps its meaning
    assert r.info["min_evidence"] == thr


@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf"), "0.05", True, None])
def test_min_evidence_is_validated(bad):
    mats, masks = _random_problem(np.random.default_rng(0))
    with pytest.raises(ValidationError, match="min_evidence"):
        solve(mats, masks, method="voting", min_evidence=bad)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("min_evidence", [0.0, 0.3])
def test_min_vote_holds_gaussians_against_their_masks_at_the_prior(rng, method, min_evidence):
    """q_i = min(q_i, q0_i) where the dense vote (A^T y)_i / k_i < min_vote and k_i >= min_evidence, k_i > 0."""
    mats, masks = _random_problem(rng)
    prior = 0.5 * rng.random(40)
    dense = [(W.toarray().astype(np.float64), m.ravel().astype(np.float64)) for W, m in zip(mats, masks)]
    k = sum(D.T @ ~np.isnan(y) for D, y in dense)
    a1 = sum(D.T @ np.nan_to_num(y) for D, y in dense)
    vote = np.where(k > 0, a1 / np.where(k > 0, k, 1.0), 1.0)
    votes = np.unique(vote[k > 0])
    thr = float(0.5 * (votes[votes.size // 2] + votes[votes.size // 2 + 1]))  # between two votes
    base = solve(mats, masks, method=method, init=prior, min_evidence=min_evidence)
    r = solve(mats, masks, method=method, init=prior, min_evidence=min_evidence, min_vote=thr)
    against = (k > 0) & (k >= min_evidence) & (vote < thr)
    capped = against & (base.q > prior)
    assert capped.sum() > 0 and (against & ~capped).sum() > 0  # the rule acts, and leaves q below q0 alone
    want = np.where(capped, prior.astype(np.float32), base.q)
    np.testing.assert_array_equal(r.q, want)
    assert r.info["n_vote_capped"] == int(capped.sum()) and r.info["min_vote"] == thr
    assert base.info["n_vote_capped"] == 0  # default 0: off


def test_min_vote_keeps_a_faint_splat_on_a_few_object_pixels_out():
    """Known values: a splat of weight 0.1 on 10 object pixels and 60 background pixels (vote 1/7) that
    nothing else fills. BCE's -log(0.1 q) has the gradient -1/q of any weight, so the fit takes it
    (q -> 1 against its own pixels); min_vote 0.2 holds it at its prior 0. The object splat stays."""
    rows = np.r_[np.arange(70), np.arange(70, 100)]
    cols = np.r_[np.zeros(70, int), np.ones(30, int)]  # Gaussian 0: the faint splat; 1: the object
    W = sp.csr_matrix((np.r_[np.full(70, 0.1), np.full(30, 0.9)], (rows, cols)), shape=(100, 2), dtype=np.float32)
    y = np.r_[np.ones(10), np.zeros(60), np.ones(30)].astype(np.float32).reshape(10, 10)
    init = np.array([False, True])
    fit = solve([W], [y], method="weighted_bce", init=init)
    held = solve([W], [y], method="weighted_bce", init=init, min_vote=0.2)
    assert fit.q[0] > 0.9 and fit.q[1] > 0.9
    assert held.q[0] == 0.0 and held.q[1] == fit.q[1] and held.info["n_vote_capped"] == 1


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan"), "0.2", True, None])
def test_min_vote_is_validated(bad):
    mats, masks = _random_problem(np.random.default_rng(0))
    with pytest.raises(ValidationError, match="min_vote"):
        solve(mats, masks, method="voting", min_vote=bad)


def test_methods_return_a_method_result(blob):
    stack, labels, masks = blob
    problem = prepare(stack, masks)
    for name in METHODS:
        out = get_method(name)(problem)
        assert isinstance(out, MethodResult) and out.q.shape == (stack.n_gaussians,)
        assert isinstance(out.info, dict) and isinstance(out.history, list)
    assert get_method("voting")(problem, bias=0.2).threshold > 0.5


def test_smoothing_takes_evidence_only_where_the_method_fitted_q():
    """A Gaussian seen only in a view beyond beta_bernoulli's budget is unobserved (q = prior): it entered the
    regulariser as evidence all the same, dragging its neighbours towards the prior."""
    W0 = sp.csr_matrix(np.array([[0.5, 0.4, 0.0]], np.float32))
    W1 = sp.csr_matrix(np.array([[0.0, 0.0, 0.9]], np.float32))
    G = sp.csr_matrix(np.ones((3, 3)) - np.eye(3))
    masks = [np.ones((1, 1)), np.ones((1, 1))]
    r = solve([W0, W1], masks, method="beta_bernoulli", budget=1, smoothness=1.0, graph=G)
    plain = solve([W0, W1], masks, method="beta_bernoulli", budget=1)
    assert list(r.unobserved) == [False, False, True]
    # the dense system with e = (k0, k1, 0), from the method's q (prior 0 for Gaussian 2)
    e = np.array([0.5, 0.4, 0.0])
    L = np.diag(G.toarray().sum(1)) - G.toarray()
    ref = np.linalg.solve(np.diag(e + 1e-6) + L, e * plain.q)
    np.testing.assert_allclose(r.q, ref, atol=1e-5)


def test_masks_may_be_a_generator_with_bare_matrices(rng):
    """as_stack used the generator up for the image shapes: "got 0 masks for 2 views"."""
    Ws = [sp.random(12, 5, density=0.5, format="csr", dtype=np.float32, random_state=k) for k in (0, 1)]
    masks = [rng.random((3, 4)) > 0.5 for _ in Ws]
    want = solve(Ws, masks, method="voting").q
    np.testing.assert_array_equal(solve(Ws, (m for m in masks), method="voting").q, want)


def test_solve_rejects_bad_requests_with_validation_errors(rng):
    """Issue 12 item 4: each of these raised TypeError, RuntimeError or a numpy ValueError."""
    W = sp.random(12, 5, density=0.5, format="csr", dtype=np.float32, random_state=0)
    m = np.ones((3, 4))
    with pytest.raises(ValidationError, match=r"method must be a method name \(str\), got \['voting'\]"):
        solve([W], [m], method=["voting"])
    empty = sp.csr_matrix((12, 0), dtype=np.float32)
    for init in (None, np.zeros(0)):
        with pytest.raises(ValidationError, match="view 0: the operator has no columns"):
            solve([empty], [m], init=init)
    for value in (np.nan, np.inf, -0.2, 2.0):  # compositing weights lie in [0, 1]
        bad = W.copy()
        bad.data[3] = value
        for method in available_methods():
            with pytest.raises(ValidationError, match=r"view 1: the operator's weights must be finite and lie in "
                                                      r"\[0, 1\]"):
                solve([W, bad], [m, m], method=method)
    with pytest.raises(ValidationError, match=r"max_iter must be in 1\.\.100,000, got 1000000000000"):
        solve([W], [m], method="least_squares", max_iter=10 ** 12)
    with pytest.raises(ValidationError, match="progress must be a callable"):
        solve([W], [m], progress=True)


@pytest.mark.parametrize("method,options", [("weighted_bce", {"optimizer": "scipy"}),
                                            ("weighted_bce", {"optimizer": "lbfgs"}),
                                            ("least_squares", {}),
                                            ("beta_bernoulli", {"order": "eig"})])
def test_progress_reports_every_iteration(blob, method, options):
    stack, _, masks = blob
    seen = []
    res = solve(stack, masks, method=method, progress=seen.append, **options)
    assert len(seen) == res.iterations > 0
    assert [p.iteration for p in seen] == list(range(1, res.iterations + 1))
    assert all(p.total is not None and p.iteration <= p.total for p in seen)
    assert all(p.loss is not None and np.isfinite(p.loss) for p in seen)
    if method == "least_squares":  # the reported loss is the method's own objective
        assert [p.loss for p in seen] == [h["objective"] for h in res.history]
    # without a callback nothing changes
    np.testing.assert_array_equal(solve(stack, masks, method=method, **options).q, res.q)


# -- issue 11: warm start from the vote, stop when the selection settles ------------------
@pytest.mark.parametrize("optimizer", ["scipy", "lbfgs"])
def test_weighted_bce_stops_when_the_selection_settles(blob, optimizer):
    """start="vote" + stable_iters ends early, and the object is still recovered on held-out views."""
    stack, labels, masks = blob
    held = [3, 7, 11]
    train = [i for i in range(12) if i not in held]
    fit = stack.subset(train), [masks[i] for i in train]
    support = labels & (np.arange(labels.size) % 3 == 0)  # a partial seed, as extract's G0
    full = solve(*fit, method="weighted_bce", init=support, max_iter=60, optimizer=optimizer)
    quick = solve(*fit, method="weighted_bce", init=support, max_iter=60, optimizer=optimizer,
                  start="vote", stable_iters=3)
    assert quick.iterations < full.iterations
    assert any(h["selection_settled"] for h in quick.history)
    assert _heldout_miou(stack, quick.selected(), labels, held) >= 0.99
    # defaults keep the behaviour from before: the prior start when init is given, no stability rule
    prior = solve(*fit, method="weighted_bce", init=support, max_iter=60, optimizer=optimizer, start="prior",
                  stable_iters=0)
    np.testing.assert_array_equal(prior.q, full.q)


def test_weighted_bce_start_and_stability_options_are_validated(rng):
    mats, masks = _random_problem(rng)
    for bad in ({"start": "random"}, {"stable_iters": -1}, {"stable_iters": 1.5}, {"stable_tol": 1.0}):
        with pytest.raises(ValidationError, match="weighted_bce"):
            solve(mats, masks, method="weighted_bce", **bad)


@pytest.mark.parametrize("method, bad", [
    ("weighted_bce", {"lam": None}), ("weighted_bce", {"r_min": "abc"}), ("weighted_bce", {"eps": [1]}),
    ("weighted_bce", {"alpha_min": float("inf")}), ("weighted_bce", {"alpha_min": 1.0}),
    ("weighted_bce", {"ftol": -1.0}), ("weighted_bce", {"gtol": float("nan")}), ("weighted_bce", {"weight_tol": -1}),
    ("weighted_bce", {"reweight": "no"}), ("weighted_bce", {"normalize": 1}), ("weighted_bce", {"max_iter": 2.0}),
    ("least_squares", {"tol": "small"}), ("least_squares", {"tol": -1.0}), ("least_squares", {"power_iters": 0}),
    ("least_squares", {"algorithm": 3}),
    ("beta_bernoulli", {"a0": None}), ("beta_bernoulli", {"b0": 0}), ("beta_bernoulli", {"budget": 2.5}),
    ("voting", {"bias": None}), ("voting", {"bias": True}), ("voting", {"bias": 1.0}),
])
def test_option_values_are_checked_before_any_work(rng, method, bad):
    """Every option value a method cannot take is a ValidationError naming it, from the up-front check that
    solve(), ExtractSettings and the CLI share: never a TypeError from inside the method."""
    from seed2gs_inverse.pipeline.settings import ExtractSettings
    from seed2gs_inverse.solvers import check_method_options

    name = next(iter(bad))
    with pytest.raises(ValidationError, match=name):
        check_method_options(method, bad)
    with pytest.raises(ValidationError, match=name):
        ExtractSettings(method=method, solver_options=bad)
    mats, masks = _random_problem(rng)
    with pytest.raises(ValidationError, match=name):
        solve(mats, masks, method=method, **bad)
    # the method checks its own arguments the same way when called directly
    from seed2gs_inverse.solvers import get_method, prepare

    with pytest.raises(ValidationError, match=name):
        get_method(method)(prepare(mats, masks), **bad)


def test_problem_refuses_weights_summing_above_one_and_ambiguous_inputs(rng):
    """Row sums above 1 are not compositing weights (weighted_bce's literal p = A q and least_squares'
    b = alpha Y rely on alpha <= 1); a single (H, W) mask and a scalar init are refused, not reinterpreted."""
    mats, masks = _random_problem(rng, views=3)
    bad = mats[1].tolil()
    bad[7, :] = 0.0
    bad[7, :3] = 0.9  # pixel 7 of view 1 sums to 2.7
    mats = [mats[0], bad.tocsr(), mats[2]]
    for method in ("weighted_bce", "least_squares"):
        with pytest.raises(ValidationError, match=r"view 1: the weights of pixel 7 sum to 2\.7"):
            solve(mats, masks, method=method)
    solve(mats, masks, method="voting")  # the vote reads no alpha
    ok, masks = _random_problem(rng, views=1)
    with pytest.raises(ValidationError, match=r"give a list with one mask per view \(\[mask\]"):
        solve(ok, masks[0], method="voting")
    with pytest.raises(ValidationError, match=r"single value 1; for one Gaussian's index give \[1\]"):
        solve(ok, masks, method="voting", init=1)
    with pytest.raises(ValidationError, match=r"single value 0\.5\)?$"):
        solve(ok, masks, method="voting", init=0.5)
    # a (V, H*W) array of flat masks, one row per view, is still read as such
    mats4, masks4 = _random_problem(rng, views=4)
    flat = solve(mats4, np.stack([m.ravel() for m in masks4]), method="voting")
    np.testing.assert_array_equal(flat.q, solve(mats4, masks4, method="voting").q)
    r = solve(ok, masks, method="voting", init=[1])  # one index in a list is a support set
    assert r.q.shape == (ok[0].shape[1],)
