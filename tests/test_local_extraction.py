"""Extraction local to the object: the stages after the orbit views see the object's neighbourhood, not the scene.

The reference for each check is the same computation over the whole scene:
``solve`` with every method solving over all N columns, and ``extract``
with its stages given no neighbourhood (the whole scene, as before).
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest
import scipy.sparse as sp

import seed2gs_inverse.solvers as solvers
from seed2gs_inverse.batch import worker
from _pipeline_scenes import reference_camera, sphere_scene
from _solver_scenes import random_views
from seed2gs_inverse import GaussianScene
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.graph import check_graph, graph_on_nodes
from seed2gs_inverse.operators import OperatorStack, ViewOperator
from seed2gs_inverse.pipeline import extract
from seed2gs_inverse.pipeline.local import Neighbourhood, neighbourhood
from seed2gs_inverse.raster import FrozenScene, build_operator

extract_module = importlib.import_module("seed2gs_inverse.pipeline.extract")  # (the package exports the function)


def _with_empty_columns(rng, n_extra=60):
    """Random views over 40 Gaussians, widened by ``n_extra`` empty columns placed among them."""
    ops, masks = random_views(rng, n=40)
    n = 40 + n_extra
    where = np.sort(rng.choice(n, 40, replace=False))  # the seen Gaussians' columns in the wide problem
    wide = []
    for W in ops:
        W = sp.csr_matrix(W)
        wide.append(sp.csr_matrix((W.data, where[W.indices], W.indptr), shape=(W.shape[0], n)))
    return wide, masks, where, n


def _graph(rng, n, nodes):
    """A symmetric random graph among ``nodes`` (some of them seen by no view)."""
    i = rng.choice(nodes, 80)
    j = rng.choice(nodes, 80)
    keep = i != j
    g = sp.csr_matrix((rng.random(keep.sum()) + 0.1, (i[keep], j[keep])), shape=(n, n))
    return g.maximum(g.T).tocsr()


@pytest.mark.parametrize("method", ["weighted_bce", "voting"])
@pytest.mark.parametrize("smooth", [0.0, 2.0])
@pytest.mark.parametrize("prior", ["support", "float"])
def test_solve_on_the_touched_columns_gives_the_full_problems_q_bit_for_bit(monkeypatch, method, smooth, prior):
    rng = np.random.default_rng(3)
    ops, masks, seen, n = _with_empty_columns(rng)
    unseen = np.setdiff1d(np.arange(n), seen)
    # the graph reaches Gaussians no view sees (they take their neighbours' values), not all of them
    graph = _graph(rng, n, np.r_[seen[:20], unseen[:15]])
    init = np.zeros(n, bool)
    init[seen[:10]] = True
    init[unseen[:5]] = True  # a prior of 1 on unseen Gaussians, inside and outside the graph
    if prior == "float":
        init = np.where(init, 0.8, 0.3) * rng.random(n)
    kw = dict(method=method, init=init, min_evidence=0.05, smoothness=smooth, graph=graph if smooth else None)
    calls = []
    real = solvers.problem_of
    monkeypatch.setattr(solvers, "problem_of", lambda stack, *a, **k: calls.append(stack.n_gaussians)
                        or real(stack, *a, **k))
    local = solvers.solve(ops, masks, **kw)
    assert calls and calls[-1] < n  # it did solve on fewer columns
    monkeypatch.setattr(solvers, "LOCAL_METHODS", frozenset())
    full = solvers.solve(ops, masks, **kw)
    assert calls[-1] == n
    np.testing.assert_array_equal(local.q, full.q)
    assert local.q.dtype == full.q.dtype and local.q.shape == (n,)
    np.testing.assert_array_equal(local.unobserved, full.unobserved)
    assert local.info["n_weak_evidence"] == full.info["n_weak_evidence"]
    assert local.threshold == full.threshold and local.iterations == full.iterations
    np.testing.assert_array_equal(local.view_weights, full.view_weights)


def test_neighbourhood_is_the_ball_and_checks_its_arguments():
    rng = np.random.default_rng(0)
    scene, _, _ = sphere_scene(n_sphere=100, n_ground=100)
    c = np.array([0.2, -0.1, 0.3])
    idx = neighbourhood(scene, c, 0.7)
    d = np.linalg.norm(scene.means.astype(np.float64) - c, axis=1)
    np.testing.assert_array_equal(idx, np.flatnonzero(d <= 0.7))
    assert idx.dtype == np.int64 and np.all(np.diff(idx) > 0)
    assert neighbourhood(scene, c, 0.0).size == 0
    for bad in [(c, -1.0), (c, np.nan), ((0, 0), 1.0), ((0, 0, np.inf), 1.0)]:
        with pytest.raises(ValidationError, match="neighbourhood"):
            neighbourhood(scene, *bad)
    nb = Neighbourhood.of(scene, rng.choice(len(scene), 30))  # unsorted, repeated: sorted and unique
    assert np.all(np.diff(nb.index) > 0) and len(nb.scene) == len(nb)
    m = sp.random(len(nb), len(nb), density=0.2, format="csr", random_state=1)
    big = nb.expand(m)
    assert big.shape == (len(scene), len(scene))
    np.testing.assert_array_equal(big[nb.index][:, nb.index].toarray(), m.toarray())
    assert big.nnz == m.nnz
    np.testing.assert_array_equal(nb.scatter(np.ones(len(nb)), 0)[nb.index], 1)
    probe = np.r_[nb.index[::3], np.setdiff1d(np.arange(len(scene)), nb.index)[:50], len(scene) + 5]
    at, inside = nb.find(probe)
    where = {int(g): j for j, g in enumerate(nb.index)}
    np.testing.assert_array_equal(inside, [int(g) in where for g in probe])
    np.testing.assert_array_equal(at, [where.get(int(g), 0) for g in probe])
    at, inside = Neighbourhood.of(scene, []).find(probe)
    assert not inside.any() and not at.any()
    assert nb.scatter(np.ones(len(nb)), 0).sum() == len(nb)


def _problem():
    scene, labels, info = sphere_scene(n_sphere=500, n_ground=900)
    cam = reference_camera(info)
    seed = (build_operator(scene, cam).W @ labels.astype(np.float32)).reshape(cam.image_shape) > 0.5
    return scene, labels, info, cam, seed


def _same_matrix(a, b):
    assert a.shape == b.shape and (a != b).nnz == 0


def test_extract_on_the_neighbourhood_is_extract_on_the_scene(monkeypatch):
    scene, _, _, cam, seed = _problem()
    kw = dict(n_views=6, progress=False)
    sizes = []
    real = extract_module._neighbourhood
    monkeypatch.setattr(extract_module, "_neighbourhood", lambda *a: sizes.append(len(real(*a))) or real(*a))
    local = extract(scene, cam, seed, **kw)
    assert sizes and 0 < sizes[0] < len(scene)  # the ground far from the sphere is outside it
    monkeypatch.setattr(extract_module, "_neighbourhood", lambda *a: None)
    monkeypatch.setattr(solvers, "LOCAL_METHODS", frozenset())
    whole = extract(scene, cam, seed, **kw)
    np.testing.assert_array_equal(local.q, whole.q)
    np.testing.assert_array_equal(local.selected, whole.selected)
    np.testing.assert_array_equal(local.result.q, whole.result.q)
    assert local.selected.any()
    _same_matrix(local.graph, whole.graph)
    _same_matrix(local.follow, whole.follow)
    assert local.resolved["support"] == whole.resolved["support"]
    assert local.resolved["n_disconnected"] == whole.resolved["n_disconnected"]
    assert local.resolved["n_weak_evidence"] == whole.resolved["n_weak_evidence"]


def test_a_far_copy_of_the_scene_changes_nothing_and_the_stages_do_not_see_it(monkeypatch):
    scene, _, info, cam, seed = _problem()
    n0 = len(scene)
    far = 200.0 * info["e1"]  # along the ground: the same planes, outside every view
    copy = GaussianScene(scene.means + far.astype(np.float32), scene.quats, scene.log_scales,
                         scene.opacity_logits, scene.sh)
    big = GaussianScene.concat([scene, copy, copy.subset(np.arange(n0)[::-1])])
    # the up axis given (tests/test_up_axis.py checks that up="auto" ignores far copies too)
    kw = dict(n_views=6, progress=False, up=tuple(info["up"]))
    base = extract(scene, cam, seed, **kw)
    sizes, solved = [], []
    real_nb, real_problem = extract_module._neighbourhood, solvers.problem_of
    monkeypatch.setattr(extract_module, "_neighbourhood", lambda *a: sizes.append(len(real_nb(*a))) or real_nb(*a))
    monkeypatch.setattr(solvers, "problem_of", lambda stack, *a, **k: solved.append(stack.n_gaussians)
                        or real_problem(stack, *a, **k))
    tiled = extract(big, cam, seed, **kw)
    assert tiled.q.shape == (3 * n0,) and tiled.operators.n_gaussians == 3 * n0
    np.testing.assert_array_equal(tiled.selected[:n0], base.selected)
    assert not tiled.selected[n0:].any()
    np.testing.assert_array_equal(tiled.q[:n0], base.q)
    assert sizes[0] < n0 and solved[0] < n0  # neither the neighbourhood nor the solve holds the copies


def test_the_frozen_scenes_index_finds_the_same_ball():
    """``neighbourhood`` through a FrozenScene's spatial index against the brute-force scan, at many radii."""
    scene, _, _ = sphere_scene(n_sphere=400, n_ground=900)
    frozen = FrozenScene(scene)
    rng = np.random.default_rng(3)
    for _ in range(20):
        c = rng.normal(0, 1.0, 3)
        r = float(rng.uniform(0, 2.5))
        np.testing.assert_array_equal(neighbourhood(frozen, c, r), neighbourhood(scene, c, r))
    # a radius exactly at a Gaussian's distance keeps it both ways (the boundary is included)
    d = np.sqrt(np.sum((scene.means[17].astype(np.float64) - c) ** 2))
    assert 17 in neighbourhood(frozen, c, d) and 17 in neighbourhood(scene, c, d)


def test_extract_on_a_frozen_scene_is_extract_on_the_scene_and_keeps_its_index():
    """A FrozenScene passed to extract: the same result, the plain scene in Extraction.scene, and one
    spatial index for every extraction from it."""
    scene, _, info, cam, seed = _problem()
    kw = dict(n_views=6, progress=False, up=tuple(info["up"]))
    plain = extract(scene, cam, seed, **kw)
    frozen = FrozenScene(scene)
    first = extract(frozen, cam, seed, **kw)
    index = frozen._spatial
    assert index is not None  # built by the first extraction...
    again = extract(frozen, cam, seed, **kw)
    assert frozen._spatial is index  # ...and kept for the next
    for ex in (first, again):
        assert ex.scene is scene
        np.testing.assert_array_equal(ex.q, plain.q)
        np.testing.assert_array_equal(ex.selected, plain.selected)
    with pytest.raises(ValidationError, match="GaussianScene or FrozenScene"):
        extract(scene.means, cam, seed, **kw)


def test_the_stacks_fingerprint_is_the_scenes_computed_when_first_read(monkeypatch):
    import seed2gs_inverse.operators.store as store
    from seed2gs_inverse.operators import OperatorStack, scene_fingerprint

    scene, _, _, cam, _ = _problem()
    want = scene_fingerprint(scene)
    calls = []
    real = store.scene_fingerprint
    monkeypatch.setattr(store, "scene_fingerprint", lambda s: calls.append(1) or real(s))
    stack = OperatorStack([build_operator(scene, cam), build_operator(scene, cam)], scene=scene)
    sub = stack.subset([1])
    assert not calls  # neither made nor subset hashes the scene
    assert stack.fingerprint == want and sub.fingerprint == want
    assert stack.fingerprint == want and len(calls) == 2  # once per stack
    assert OperatorStack([build_operator(scene, cam)], "given", scene=scene).fingerprint == "given"
    with pytest.raises(ValidationError, match="scene must be the GaussianScene"):
        OperatorStack([build_operator(scene, cam)], scene=scene.subset(np.arange(10)))


def test_a_stage_refuses_the_neighbourhood_of_another_scene():
    from seed2gs_inverse.pipeline.settings import ExtractSettings
    from seed2gs_inverse.pipeline.stages import evidence_graph

    scene, _, _ = sphere_scene(n_sphere=100, n_ground=100)
    other = Neighbourhood.of(scene.subset(np.arange(50)), np.arange(10))
    with pytest.raises(ValidationError, match="Neighbourhood of the scene's"):
        evidence_graph(scene, None, ExtractSettings(), 1.0, local=other)
    with pytest.raises(ValidationError, match="Neighbourhood of the scene's"):
        evidence_graph(scene, None, ExtractSettings(), 1.0, local=np.arange(10))


def test_a_batch_worker_freezes_each_cached_scene_once():
    a, _, _ = sphere_scene(n_sphere=50, n_ground=50)
    b, _, _ = sphere_scene(n_sphere=60, n_ground=50)
    worker.clear_scene_cache()
    fa = worker._frozen_scene(a)
    assert isinstance(fa, FrozenScene) and fa.scene is a
    assert worker._frozen_scene(a) is fa  # the next job on the scene shares it
    assert worker._frozen_scene(b) is not fa
    worker.clear_scene_cache()
    assert worker._frozen_scene(a) is not fa  # forgotten with the scenes
    worker.clear_scene_cache()


def test_the_lean_n_long_arrays_are_those_of_the_whole_computation():
    """What the extraction keeps (N,)-long, it builds without the (N,)-long temporaries: the same arrays."""
    from seed2gs_inverse.graph import check_graph
    from seed2gs_inverse.operators import OperatorStack, ViewOperator
    from seed2gs_inverse.solvers._common import prior_from_init
    from seed2gs_inverse.solvers._local import SupportPrior

    rng = np.random.default_rng(5)
    n = 500
    index = np.sort(rng.choice(n, 60, replace=False))
    nb = Neighbourhood(index, None, n)
    m = sp.random(60, 60, density=0.2, format="csr", random_state=2)
    big = nb.expand(m)
    coo = m.tocoo()
    ref = sp.csr_matrix((coo.data, (index[coo.row], index[coo.col])), shape=(n, n))  # scipy's own build
    for name in ("indptr", "indices", "data"):
        a, b = getattr(big, name), getattr(ref, name)
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)
    # the symmetry check looks among the nodes with an entry: an edge whose mirror row is empty is found
    g = nb.expand(m + m.T)
    assert check_graph(g, n).nnz == g.nnz
    one_way = sp.csr_matrix(([1.0], ([index[3]], [index[7]])), shape=(n, n))
    with pytest.raises(ValidationError, match="symmetric"):
        check_graph(g + one_way, n)
    # a support-set prior kept as its mask: the float64 prior's values, where taken and mapped
    cols = np.sort(rng.choice(n, 100, replace=False))
    for init in (None, rng.random(n) < 0.2, index[:9], rng.random(n)):
        full = prior_from_init(init, n)
        p = SupportPrior(init, n)
        np.testing.assert_array_equal(p.at(cols), full[cols])
        fn = lambda v: np.clip((0.0 * v + 1e-3 * v) / (0.0 + 1e-3), 0.0, 1.0)  # noqa: E731
        got = p.map(fn)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, fn(full).astype(np.float32))
    # the adjoint adds its two runs at the stack's columns alone: the same product
    views = [ViewOperator(sp.csr_matrix(((0.2 * rng.random(40)).astype(np.float32),
                                         (rng.integers(0, 30, 40), rng.choice(index, 40))), shape=(30, n)),
                          image_shape=(5, 6)) for _ in range(6)]
    y = rng.random(6 * 30).astype(np.float32)
    plain = OperatorStack(views).rmatvec(y)
    stack = OperatorStack(views)
    stack.columns()  # cached: the adjoint now adds at these alone
    np.testing.assert_array_equal(stack.rmatvec(y), plain)


def test_touched_columns_hold_both_ends_of_an_edge_stored_one_way():
    """check_graph accepts a graph symmetric within its tolerance whose stored pattern is not: (1, 3) = 1e-12 alone.

    The solve on the touched columns must then hold node 3, and the restricted graph must be a valid matrix.
    """
    W = sp.csr_matrix(np.array([[0.5, 0.2, 0.0, 0.0, 0.0], [0.0, 0.7, 0.0, 0.0, 0.0]], np.float32))
    stack = OperatorStack([ViewOperator(W, None, (1, 2))])
    for entries in ([(0, 1, 1.0), (1, 0, 1.0), (1, 3, 1e-12)], [(0, 1, 1.0), (1, 0, 1.0), (3, 1, 1e-12)]):
        r, c, v = zip(*entries)
        graph = check_graph(sp.csr_matrix((v, (r, c)), shape=(5, 5)), 5)
        cols = solvers.touched_columns(stack, graph)
        np.testing.assert_array_equal(cols, [0, 1, 3])
        graph_on_nodes(graph, cols).check_format(full_check=True)
        with pytest.raises(ValidationError, match="both ends"):  # the nodes the old shortcut returned
            graph_on_nodes(graph, np.array([0, 1]))
    with pytest.raises(ValidationError, match="ascending"):
        graph_on_nodes(graph, np.array([3, 1, 0]))
    q = solvers.solve(stack, [np.array([1.0, 1.0])], "voting", smoothness=1.0, graph=graph).q
    assert q.shape == (5,) and np.all(np.isfinite(q))
