"""Selections given as bool masks or integer indices: Gaussians (init=, edits) and views (subset, holdout).

An integer 0/1 array of N labels used to be read as the indices 0 and 1 (a solve seeded from two Gaussians,
an edit moving two), and a bool view mask as the views 0 and 1: wrong results without a word.
"""

import numpy as np
import pytest
import scipy.sparse as sp

import seed2gs_inverse as sgi
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.operators import as_stack
from seed2gs_inverse.synthetic import make_scene


def _stack(rng, n=30, views=5, shape=(4, 5)):
    mats = [sp.random(shape[0] * shape[1], n, density=0.3, random_state=rng, format="csr", dtype=np.float32) * 0.2
            for _ in range(views)]
    masks = [(rng.random(shape) > 0.5).astype(np.float32) for _ in range(views)]
    return as_stack([(W, shape) for W in mats]), masks


def test_integer_zero_one_labels_are_refused_as_a_selection():
    rng = np.random.default_rng(0)
    stack, masks = _stack(rng)
    labels = (rng.random(30) > 0.5).astype(np.int64)
    with pytest.raises(ValidationError, match=r"init: 30 integers that are all 0 or 1 look like a 0/1 mask"):
        sgi.solve(stack, masks, method="voting", init=labels)
    ref = sgi.solve(stack, masks, method="voting", init=labels.astype(bool), min_evidence=1e9)
    assert np.array_equal(ref.selected(), labels.astype(bool))  # the bool mask is the prior everywhere
    idx = sgi.solve(stack, masks, method="voting", init=np.flatnonzero(labels), min_evidence=1e9)
    assert np.array_equal(idx.selected(), labels.astype(bool))  # indices still work
    scene = make_scene(seed=0, n_per_object=20).scene
    lab = np.zeros(len(scene), np.int64)
    lab[:5] = 1
    with pytest.raises(ValidationError, match="selected: .* look like a 0/1 mask"):
        sgi.move(scene, lab, translation=[1.0, 0.0, 0.0])
    moved = sgi.move(scene, lab.astype(bool), translation=[1.0, 0.0, 0.0])
    assert np.allclose(moved.means[:5] - scene.means[:5], [1.0, 0.0, 0.0])
    assert np.array_equal(moved.means[5:], scene.means[5:])


def test_view_selections_take_bool_masks_and_refuse_fractions():
    rng = np.random.default_rng(1)
    stack, masks = _stack(rng)
    pick = np.array([True, False, True, False, False])
    sub = stack.subset(pick)
    assert len(sub) == 2 and sub[1] is stack[2]
    assert stack.subset([-1])[0] is stack[4]
    for bad, words in (([1.7], "integer indices or a bool mask"), ([5], "index 5 is out of range"),
                       (np.ones(3, bool), r"shape \(5,\)")):
        with pytest.raises(ValidationError, match=words):
            stack.subset(bad)
    truth = rng.random(30) > 0.5
    held = np.zeros(5, bool)
    held[[3, 4]] = True
    res = sgi.compare(stack, masks, truth, methods=["voting"], holdout=held)
    assert res.holdout == [3, 4]
    with pytest.raises(ValidationError, match="holdout: index -1"):
        sgi.compare(stack, masks, truth, methods=["voting"], holdout=[-1])


def test_compare_refuses_arguments_it_would_ignore():
    rng = np.random.default_rng(2)
    stack, masks = _stack(rng)
    truth = rng.random(30) > 0.5
    for kwargs, words in (({"methods": "voting"}, "write \\['voting'\\]"),
                          ({"methods": ["voting", "voting"]}, "each method once"),
                          ({"methods": ["voting"], "options": {"votnig": {"bias": 0.2}}}, "votnig"),
                          ({"methods": ["voting"], "options": {"weighted_bce": {}}}, "not among the compared"),
                          ({"methods": ["voting"], "render_threshold": 2}, "render_threshold must be in")):
        with pytest.raises(ValidationError, match=words):
            sgi.compare(stack, masks, truth, **kwargs)


def test_edit_and_dottest_arguments_give_validation_errors():
    scene = make_scene(seed=0, n_per_object=20).scene
    sel = np.zeros(len(scene), bool)
    sel[:5] = True
    for kwargs, words in (({"rotation": np.eye(2)}, "rotation must be finite numbers of shape 3x3 or 4-vector"),
                          ({"rotation": [0, 0, 0, 0]}, "quaternion must not be zero"),
                          ({"scale": np.array([1, 2, 3])}, "scale must be a positive finite number"),
                          ({"scale": "2"}, "scale must be a positive finite number"),
                          ({"translation": [1, 2]}, "translation must be a finite 3-vector")):
        with pytest.raises(ValidationError, match=words):
            sgi.move(scene, sel, **kwargs)
    with pytest.raises(ValidationError, match=r"rgb must lie in \[0, 1\]"):
        sgi.recolour(scene, sel, [2.0, 0.0, 0.0])
    stack, _ = _stack(np.random.default_rng(3))
    with pytest.raises(ValidationError, match="rng must be"):
        sgi.dottest(stack, rng="x")


def test_option_checks_take_any_number_and_leave_unlisted_options_alone():
    """Review findings: a Python int beyond float range gave a raw TypeError; a method that takes **kwargs
    lost its extra options to a KeyError; an int default refused a fraction in a third-party method."""
    from seed2gs_inverse.solvers import check_method_options, register_method
    from seed2gs_inverse.solvers._common import MethodResult

    assert check_method_options("weighted_bce", {"lam": 10 ** 20})  # large, but a valid temperature
    for method, opts in (("weighted_bce", {"eps": 10 ** 400}), ("voting", {"bias": 10 ** 400}),
                         ("beta_bernoulli", {"a0": 10 ** 400}), ("least_squares", {"tol": -10 ** 400})):
        with pytest.raises(ValidationError, match=next(iter(opts))):
            check_method_options(method, opts)

    def mine(problem, *, scale=1, **extra):
        return MethodResult(q=np.full(problem.n_gaussians, 0.5 * scale))

    register_method("test_kwargs_method", mine)
    rng = np.random.default_rng(4)
    stack, masks = _stack(rng)
    res = sgi.solve(stack, masks, method="test_kwargs_method", scale=0.5, anything="goes")
    assert np.allclose(res.q[~res.unobserved], 0.25)


def test_recolour_with_a_callable_takes_colours_slightly_out_of_range():
    scene = make_scene(seed=0, n_per_object=20).scene
    sel = np.zeros(len(scene), bool)
    sel[:5] = True
    out = sgi.recolour(scene, sel, lambda c: c * 0.8 - 1e-8)  # real scenes hold colours a hair below 0
    assert np.all(np.isfinite(out.sh))


def test_a_box_changed_after_it_was_made_is_checked_when_used():
    p = sgi.BoxPrompt([1, 2, 30, 40])
    p.box = [np.nan] * 4
    with pytest.raises(ValidationError, match="4 finite numbers"):
        p.to_mask(np.zeros((48, 64, 3), np.uint8))
