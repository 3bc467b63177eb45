"""pipeline.completion on hand-made graphs, operators and masks whose answers are worked out by hand.

The end-to-end tests (test_unseen_surfaces.py) show that completion helps; these pin down what each
function computes: the thresholds of fill_unknown (with ``decisive`` != 0.5, where ``d`` and ``1 - d``
differ), the background seeds of complete_membership, and the evidence, confidence and harmonic
extension of tracked_membership.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from seed2gs_inverse.pipeline.completion import complete_membership, fill_unknown, tracked_membership


def _path_graph(n):
    """Unit weights between i and i + 1: the harmonic extension between fixed ends is linear."""
    i = np.arange(n - 1)
    G = sp.coo_matrix((np.ones(n - 1), (i, i + 1)), shape=(n, n))
    return (G + G.T).tocsr()


def test_fill_unknown_thresholds_the_rendered_share_of_each_unknown_pixel():
    q = np.array([1.0, 0.0, 1.0])
    # unknown pixels (share P / alpha, alpha): 0.75 of 0.8 -> 1 (>= 1 - 0.3); 0.625 of 0.8 -> unknown
    # (between 0.3 and 0.7, though above d); 0.25 of 0.8 -> 0; 1.0 of 0.3 -> unknown (alpha < 0.5);
    # the last pixel is known and kept
    W = sp.csr_matrix(np.array([[0.6, 0.2, 0.0],
                                [0.5, 0.3, 0.0],
                                [0.2, 0.6, 0.0],
                                [0.0, 0.0, 0.3],
                                [0.9, 0.0, 0.0]], np.float32))
    mask = np.array([np.nan, np.nan, np.nan, np.nan, 0.0], np.float32).reshape(1, 5)
    (out,) = fill_unknown([W], [mask], q, decisive=0.3, alpha_min=0.5)
    np.testing.assert_array_equal(out.ravel(), [1.0, np.nan, 0.0, np.nan, 0.0])
    assert out.dtype == np.float32 and out.shape == (1, 5)
    assert np.isnan(mask).sum() == 4  # the caller's mask is not changed


def test_complete_membership_seeds_only_confident_background():
    """Path 0 - 1 - 2 - 3 - 4: G0 = {0}; node 3 is seen outside the seed (mu 0.05 <= 0.1, weight 1) and
    becomes a 0 seed; node 2 (mu 0.3) and node 4 (weight 0.05 < 0.1) do not. Harmonic in between: node 1
    2/3, node 2 1/3; node 4 hangs off the 0 seed alone and takes 0."""
    support = np.array([True, False, False, False, False])
    weight = np.array([1.0, 1.0, 1.0, 1.0, 0.05])
    mu = np.array([1.0, 0.5, 0.3, 0.05, 0.0])
    q = complete_membership(_path_graph(5), support, weight, mu, min_weight=0.1, max_background_membership=0.1)
    np.testing.assert_allclose(q, [1.0, 2 / 3, 1 / 3, 0.0, 0.0], atol=1e-12)


def test_tracked_membership_fixes_confident_evidence_and_extends_it():
    """Two views over five Gaussians on a path 0 - 1 - 2 - 3, and 4 on its own.

    Per Gaussian, from known pixels only: evidence e = (1 + 0.5, 0.6 + 0.6, 0, 1, 0) and estimate
    q^ = (1, 0.5, -, 0, -). Fixed: 0 (1) and 3 (0); Gaussian 1 has evidence but an estimate of 0.5 (not
    confident), Gaussian 2 only an unknown pixel. Harmonic: 2/3 and 1/3; Gaussian 4, reached by no fixed
    node, keeps its prior."""
    v1 = sp.csr_matrix(np.array([[1.0, 0, 0, 0, 0],
                                 [0, 0, 0, 1.0, 0],
                                 [0, 0.6, 0, 0, 0],
                                 [0, 0.6, 0, 0, 0],
                                 [0, 0, 1.0, 0, 0]], np.float32))
    m1 = np.array([1.0, 0.0, 1.0, 0.0, np.nan], np.float32)
    v2 = sp.csr_matrix(np.array([[0.5, 0, 0, 0, 0], [0, 0, 0, 0, 0]], np.float32))
    m2 = np.array([1.0, 0.0], np.float32)
    prior = np.array([0.0, 0.0, 0.0, 0.0, 0.7])
    G = _path_graph(5).tolil()
    G[3, 4] = G[4, 3] = 0.0
    G = G.tocsr()
    G.eliminate_zeros()
    q = tracked_membership(G, [v1, v2], [m1, m2], prior, min_evidence=0.5, confident=0.2)
    np.testing.assert_allclose(q, [1.0, 2 / 3, 1 / 3, 0.0, 0.7], atol=1e-12)
    q = tracked_membership(G, [v1, v2], [m1, m2], prior, min_evidence=2.0, confident=0.2)
    np.testing.assert_allclose(q, prior, atol=1e-12)  # no Gaussian has evidence 2: nothing fixed
    with pytest.raises(Exception, match="confident"):
        tracked_membership(G, [v1, v2], [m1, m2], prior, confident=0.5)


def test_completions_stop_their_cg_at_the_regularisers_tolerance(monkeypatch):
    """harmonic_extension's own rtol (1e-10) kept CG running for many minutes on a large graph."""
    from seed2gs_inverse.pipeline import completion
    from seed2gs_inverse.solvers import smoothing

    seen = []
    real_cg = smoothing.spla.cg

    def cg(*args, **kw):
        seen.append(kw["rtol"])
        return real_cg(*args, **kw)

    monkeypatch.setattr(smoothing.spla, "cg", cg)
    monkeypatch.setattr(smoothing, "DIRECT_MAX", 2)  # CG for this small graph too
    n = 12
    w = np.zeros((n, n))
    for i in range(n - 1):
        w[i, i + 1] = w[i + 1, i] = 1.0
    support = np.arange(n) < 2
    q = completion.complete_membership(sp.csr_matrix(w), support, np.r_[np.ones(2), np.zeros(n - 3), 1.0],
                                       np.r_[np.ones(2), np.zeros(n - 2)])
    assert seen == [completion.COMPLETION_RTOL] and q[0] == 1.0 and q[-1] == 0.0
