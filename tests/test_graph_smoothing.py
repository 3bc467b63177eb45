"""Gaussian affinity graph and the graph-Laplacian regulariser, against independent references."""

import numpy as np
import pytest
import scipy.sparse as sp

from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.graph import check_graph, gaussian_graph, graph_laplacian, region_subset
from seed2gs_inverse.scene import GaussianScene
from seed2gs_inverse.sh import SH_C0
from seed2gs_inverse.solvers.smoothing import harmonic_extension, laplacian_smooth


def _scene(n=60, seed=0, flat=True):
    rng = np.random.default_rng(seed)
    means = rng.normal(size=(n, 3))
    quats = rng.normal(size=(n, 4))
    ls = np.log(rng.uniform(0.05, 0.2, (n, 3)))
    if flat:
        ls[:, 2] = np.log(0.005)
    rgb = rng.uniform(0.1, 0.9, (n, 3))
    sh = ((rgb - 0.5) / SH_C0)[:, None, :]
    return GaussianScene(means, quats, ls, np.full(n, 2.0), sh)


def _rotmat(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def test_graph_weights_match_brute_force():
    sc = _scene(40)
    k, sc_c, sc_n = 5, 0.2, 0.3
    g = gaussian_graph(sc, k, sigma_color=sc_c, sigma_normal=sc_n).toarray()
    x = sc.means.astype(np.float64)
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    order = np.argsort(d, axis=1)[:, 1:k + 1]
    rho = d[np.arange(40), order[:, -1]]
    rgb = np.clip(0.5 + SH_C0 * sc.sh[:, 0].astype(np.float64), 0, 1)
    scales = np.exp(sc.log_scales.astype(np.float64))
    normals = np.array([_rotmat(sc.quats[i].astype(np.float64))[:, np.argmin(scales[i])] for i in range(40)])
    s = np.sort(scales, axis=1)
    flat = np.clip(1 - s[:, 0] / s[:, 1], 0, 1)
    ref = np.zeros((40, 40))
    for i in range(40):
        for j in order[i]:
            w = np.exp(-d[i, j] ** 2 / (rho[i] * rho[j]) - np.sum((rgb[i] - rgb[j]) ** 2) / (2 * sc_c ** 2)
                       - (1 - abs(normals[i] @ normals[j])) / sc_n * flat[i] * flat[j])
            ref[i, j] = ref[j, i] = w  # union of both directions, same weight
    np.testing.assert_allclose(g, ref, rtol=1e-6, atol=1e-12)


def test_graph_subset_and_laplacian_psd():
    sc = _scene(80, seed=1)
    sub = region_subset(sc, np.zeros(3), 1.2)
    g = gaussian_graph(sc, 6, subset=sub)
    assert g.shape == (80, 80)
    out = np.setdiff1d(np.arange(80), sub)
    assert g[out].nnz == 0 and g[:, out].nnz == 0
    check_graph(g, 80)
    L = graph_laplacian(g).toarray()
    np.testing.assert_allclose(L, L.T, atol=1e-12)
    assert np.linalg.eigvalsh(L).min() > -1e-10
    np.testing.assert_allclose(L.sum(1), 0, atol=1e-12)
    rng = np.random.default_rng(2)
    q = rng.uniform(size=80)
    gd = g.toarray()
    assert np.isclose(q @ L @ q, 0.5 * np.sum(gd * (q[:, None] - q[None]) ** 2))


def test_check_graph_rejects_asymmetric_and_wrong_size():
    g = sp.csr_matrix(np.array([[0, 1.0], [0.5, 0]]))
    with pytest.raises(ValidationError, match="symmetric"):
        check_graph(g)
    with pytest.raises(ValidationError, match="3 Gaussians"):
        check_graph(sp.csr_matrix((2, 2)), 3)
    with pytest.raises(ValidationError, match="scipy.sparse"):
        check_graph(np.zeros((2, 2)))


def _random_graph(n, seed, p=0.15):
    rng = np.random.default_rng(seed)
    w = rng.uniform(0.1, 1.0, (n, n)) * (rng.uniform(size=(n, n)) < p)
    w = np.triu(w, 1)
    return sp.csr_matrix(w + w.T)


@pytest.mark.parametrize("solver", ["direct", "cg"])
def test_laplacian_smooth_matches_dense_solve(solver):
    n = 50
    g = _random_graph(n, 3)
    rng = np.random.default_rng(4)
    qh = rng.uniform(size=n)
    e = rng.uniform(0, 3, n) * (rng.uniform(size=n) < 0.6)
    p = (rng.uniform(size=n) < 0.3).astype(float)
    lam, eps = 0.7, 1e-3
    gd = g.toarray()
    L = np.diag(gd.sum(1)) - gd
    ref = np.linalg.solve(np.diag(e + eps) + lam * L, e * qh + eps * p)
    out = laplacian_smooth(qh, e, g, lam, p, ridge=eps, solver=solver, rtol=1e-10)
    np.testing.assert_allclose(out, np.clip(ref, 0, 1), atol=1e-7)
    # the default CG tolerance (1e-5) is close, not exact
    loose = laplacian_smooth(qh, e, g, lam, p, ridge=eps, solver=solver)
    np.testing.assert_allclose(loose, np.clip(ref, 0, 1), atol=1e-4)


def test_default_cg_tolerance_does_not_loosen_with_the_evidence_scale():
    """Large evidence must not loosen the default CG at the Gaussians without evidence.

    CG used to stop on the unscaled residual, |r| <= rtol |b| with b = E q_hat
    dominated by the largest evidence, so the free nodes the regulariser
    decides were solved loosely at evidence 1e4, beyond the bound below
    (the bound at evidence 1 held before and holds now).
    """
    rng = np.random.default_rng(3)
    worst = {}
    for scale in (1.0, 1e4):
        gap = 0.0
        for _ in range(100):
            n = int(rng.integers(10, 80))
            w = rng.random((n, n)) * (rng.random((n, n)) < 0.15)
            w = np.triu(w, 1)
            g = sp.csr_matrix(w + w.T)
            qh, e = rng.random(n), scale * rng.random(n) * (rng.random(n) < 0.3)
            exact = laplacian_smooth(qh, e, g, 1.0, solver="direct")
            gap = max(gap, float(np.abs(laplacian_smooth(qh, e, g, 1.0) - exact).max()))
        worst[scale] = gap
    assert worst[1.0] < 1e-4 and worst[1e4] < 4e-3, worst


def test_cg_tolerance_and_values_are_checked():
    g = _random_graph(10, 1)
    for rtol in (0, -1, 1, float("nan"), "tight"):
        with pytest.raises(ValidationError, match="rtol"):
            laplacian_smooth(np.full(10, 0.5), np.ones(10), g, 1.0, rtol=rtol)
        with pytest.raises(ValidationError, match="rtol"):
            harmonic_extension(g, np.arange(10) < 3, np.ones(10), rtol=rtol)
    for values in (np.ones(1), np.ones(9), 1.0):  # one value was broadcast to every seed
        with pytest.raises(ValidationError, match=r"values must have shape \(10,\)"):
            harmonic_extension(g, np.arange(10) < 3, values)


@pytest.mark.parametrize("solver", ["direct", "cg"])
def test_laplacian_smooth_free_nodes_are_harmonic(solver):
    n = 60
    g = _random_graph(n, 5, p=0.2)
    rng = np.random.default_rng(6)
    e = np.where(rng.uniform(size=n) < 0.4, 1e3, 0.0)  # evidence only on some nodes
    qh = rng.uniform(size=n)
    out = laplacian_smooth(qh, e, g, 1.0, ridge=1e-12, solver=solver, rtol=1e-12)
    gd = g.toarray()
    free = (e == 0) & (gd.sum(1) > 0)
    assert free.sum() > 10
    mean_nb = gd @ out / gd.sum(1).clip(1e-300)
    np.testing.assert_allclose(out[free], mean_nb[free], atol=1e-6)
    np.testing.assert_allclose(out[e > 0], qh[e > 0], atol=2e-2)  # pulled by lam * degree / e


def test_laplacian_smooth_isolated_and_zero_smoothness():
    g = sp.csr_matrix((4, 4))
    qh = np.array([0.2, 0.9, 0.4, 0.0])
    e = np.array([1.0, 0.0, 2.0, 0.0])
    p = np.array([0.0, 1.0, 0.0, 0.0])
    out = laplacian_smooth(qh, e, g, 5.0, p)
    np.testing.assert_allclose(out, [0.2, 1.0, 0.4, 0.0], atol=1e-5)
    with pytest.raises(ValidationError, match="smoothness"):
        laplacian_smooth(qh, e, g, -1.0)
    with pytest.raises(ValidationError, match="evidence"):
        laplacian_smooth(qh, -e, g, 1.0)


@pytest.mark.parametrize("solver", ["direct", "cg"])
def test_a_component_without_evidence_keeps_its_prior_node_by_node(solver):
    """The ridge alone gave such a component its smoothed prior (about its mean): a seeded Gaussian (prior 1)
    beside an unseeded one came out at 0.5, on either side of the threshold depending on the solver."""
    a, b = _random_graph(30, 8, p=0.3), _random_graph(20, 9, p=0.3)  # two blocks: two sets of components
    g = sp.block_diag([a, b]).tocsr()
    n = 50
    rng = np.random.default_rng(10)
    qh = rng.uniform(size=n)
    e = np.r_[rng.uniform(0, 3, 30) * (rng.uniform(size=30) < 0.6), np.zeros(20)]  # no evidence in block b
    p = (rng.uniform(size=n) < 0.5).astype(float)
    lam, eps = 0.7, 1e-3
    out = laplacian_smooth(qh, e, g, lam, p, ridge=eps, solver=solver, rtol=1e-10)
    np.testing.assert_array_equal(out[30:], p[30:])
    ad = a.toarray()  # block a alone, against the dense solve of its own system
    ref = np.linalg.solve(np.diag(e[:30] + eps) + lam * (np.diag(ad.sum(1)) - ad), e[:30] * qh[:30] + eps * p[:30])
    np.testing.assert_allclose(out[:30], np.clip(ref, 0, 1), atol=1e-7)
    fixed = np.r_[e[:30] > 0, np.zeros(20, bool)]
    h = harmonic_extension(g, fixed, qh, prior=p, solver=solver)
    np.testing.assert_array_equal(h[30:], p[30:])


def test_harmonic_extension_on_a_path_is_linear():
    # Path 0-1-2-3-4 with unit weights, ends fixed to 1 and 0: q = 1 - i/4 exactly.
    n = 5
    w = np.zeros((n, n))
    for i in range(n - 1):
        w[i, i + 1] = w[i + 1, i] = 1.0
    fixed = np.array([True, False, False, False, True])
    q = harmonic_extension(sp.csr_matrix(w), fixed, np.array([1.0, 0, 0, 0, 0.0]))
    np.testing.assert_allclose(q, [1, 0.75, 0.5, 0.25, 0], atol=1e-7)


def test_graph_coincident_means_and_subset_forms():
    # Trained scenes hold splats with identical means: the k-d tree may list a twin before the
    # node itself, and the node must then not be joined to itself.
    sc = _scene(50, seed=3)
    means = sc.means.copy()
    means[10:20] = means[0:10]  # ten pairs of twins
    sc = GaussianScene(means, sc.quats, sc.log_scales, sc.opacity_logits, sc.sh)
    g = gaussian_graph(sc, 4)
    assert g.has_canonical_format
    assert np.all(g.diagonal() == 0)
    check_graph(g, 50)
    for i in range(10):  # each twin is a neighbour of the other at distance 0: weight from colour and normal only
        assert g[i, i + 10] > 0
    # the same subset as a boolean mask, as ascending indices and as shuffled indices with repeats
    mask = np.zeros(50, bool)
    mask[::2] = True
    ref = gaussian_graph(sc, 4, subset=mask)
    ids = np.flatnonzero(mask)
    shuffled = np.random.default_rng(0).permutation(np.r_[ids, ids[:5]])
    for sub in (ids, shuffled):
        other = gaussian_graph(sc, 4, subset=sub)
        assert (abs(other - ref)).nnz == 0
    # integer 0/1 labels would be read as the indices {0, 1}: a graph of two nodes
    with pytest.raises(ValidationError, match="look like a 0/1 mask"):
        gaussian_graph(sc, 4, subset=mask.astype(np.int64))


def test_stored_zero_weights_are_no_edges():
    """A stored 0 must not join two components: the evidence-free pair {2, 3} keeps its prior node by
    node, as it does once the zero is eliminated; the caller's matrix keeps its entries."""
    r, c, w = [0, 1, 2, 3, 1, 2], [1, 0, 3, 2, 2, 1], [1.0, 1.0, 1.0, 1.0, 0.0, 0.0]
    g = sp.csr_matrix((w, (r, c)), shape=(4, 4))
    prior = np.array([0.0, 0.0, 0.2, 0.8])
    for solver in ("direct", "cg"):
        q = laplacian_smooth(np.array([1.0, 1.0, 0.0, 0.0]), np.array([1.0, 1.0, 0.0, 0.0]), g, 1.0,
                             prior=prior, solver=solver)
        np.testing.assert_allclose(q[2:], [0.2, 0.8])
    h = harmonic_extension(g, np.array([True, True, False, False]), np.array([1.0, 1.0, 0.0, 0.0]), prior=prior)
    np.testing.assert_allclose(h, [1.0, 1.0, 0.2, 0.8])
    assert g.nnz == 6 and check_graph(g).nnz == 4


def test_solve_checks_the_graph_before_the_method_runs(monkeypatch):
    """A graph solve() cannot use is refused before any fitting (it used to be checked after the method)."""
    from _solver_scenes import random_views

    import seed2gs_inverse.solvers as solvers
    from seed2gs_inverse.solvers import solve

    mats, masks = random_views(np.random.default_rng(0))
    n = mats[0].shape[1]
    calls = []
    real = solvers.get_method("voting")

    def spy(problem, *, bias=0.0):
        calls.append(1)
        return real(problem, bias=bias)

    monkeypatch.setitem(solvers._common._METHODS, "voting", spy)
    bad = {"size": sp.identity(n + 1, format="csr"), "dense": np.zeros((n, n)),
           "asymmetric": sp.csr_matrix(([1.0], ([0], [1])), shape=(n, n))}
    for what, g in bad.items():
        with pytest.raises(ValidationError, match="graph"):
            solve(mats, masks, method="voting", smoothness=1.0, graph=g)
    assert not calls
    good = sp.csr_matrix(([1.0, 1.0], ([0, 1], [1, 0])), shape=(n, n))
    solve(mats, masks, method="voting", smoothness=1.0, graph=good)
    assert calls == [1]


def test_regulariser_evidence_comes_from_the_views_a_budget_used():
    """beta_bernoulli with budget=1 fits Gaussian 1 from a trace of weight (0.001) in view 0; view 1, beyond
    the budget, sees it strongly. Its evidence for the regulariser is what view 0 gave (it used to be the
    known weight of both views, which pinned its uninformed q to the fit instead of its neighbours)."""
    import scipy.sparse as sp

    from seed2gs_inverse.solvers import solve

    w0 = sp.csr_matrix(np.array([[0.9, 0, 0], [0, 0.001, 0], [0, 0, 0.9]], np.float32))
    w1 = sp.csr_matrix(np.tile(np.array([[0, 0.9, 0]], np.float32), (10, 1)))
    masks = [np.ones((1, 3), np.float32), np.ones((1, 10), np.float32)]
    g = sp.csr_matrix(np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], float))
    fit = solve([w0, w1], masks, method="beta_bernoulli", budget=1)
    r = solve([w0, w1], masks, method="beta_bernoulli", budget=1, smoothness=1.0, graph=g)
    e_used = np.asarray(w0.sum(axis=0), np.float64).ravel()  # every pixel known
    np.testing.assert_allclose(r.q, laplacian_smooth(fit.q, e_used, g, 1.0), atol=1e-6)
    assert abs(r.q[1] - r.q[0]) < 1e-3  # Gaussian 1 follows its neighbours


def test_min_evidence_and_method_evidence_under_a_budget(monkeypatch):
    """min_evidence measures the views a budget used, as the regulariser does; a method's evidence of the
    wrong shape, negative or not finite is refused."""
    import scipy.sparse as sp

    import seed2gs_inverse.solvers as solvers
    from seed2gs_inverse.solvers import MethodResult, get_method, solve

    w0 = sp.csr_matrix(np.array([[0.9, 0, 0], [0, 0.001, 0], [0, 0, 0.9]], np.float32))
    w1 = sp.csr_matrix(np.tile(np.array([[0, 0.9, 0]], np.float32), (10, 1)))
    masks = [np.ones((1, 3), np.float32), np.ones((1, 10), np.float32)]
    r = solve([w0, w1], masks, method="beta_bernoulli", budget=1, min_evidence=0.01)
    one = solve([w0], masks[:1], method="beta_bernoulli", min_evidence=0.01)  # the same fit, no budget
    np.testing.assert_array_equal(r.q, one.q)
    assert r.q[1] == 0.0 and r.info["n_weak_evidence"] == 1
    real = get_method("voting")
    for bad in (np.array([5.0]), -np.ones(3), np.full(3, np.nan)):
        def method(problem, *, bias=0.0, bad=bad):
            return MethodResult(q=real(problem).q, evidence=bad)

        monkeypatch.setitem(solvers._common._METHODS, "voting", method)
        with pytest.raises(RuntimeError, match="invalid evidence"):
            solve([w0, w1], masks, method="voting")


def test_subset_ascending_with_repeats_is_deduplicated():
    sc = _scene(40, seed=4)
    ids = np.arange(0, 40, 3)
    ref = gaussian_graph(sc, 4, subset=ids)
    repeated = np.sort(np.r_[ids, ids[:4]])  # ascending, with repeats: must not be taken as unique
    assert abs(gaussian_graph(sc, 4, subset=repeated) - ref).nnz == 0


def test_laplacian_ignores_self_loops():
    g = sp.csr_matrix(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 2.0], [0.0, 2.0, 0.0]]))
    loops = g + sp.diags([0.5, 0.0, 3.0])
    np.testing.assert_array_equal(graph_laplacian(loops).toarray(), graph_laplacian(g).toarray())
    np.testing.assert_array_equal(graph_laplacian(g).toarray(), [[1, -1, 0], [-1, 3, -2], [0, -2, 2]])
