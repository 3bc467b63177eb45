"""extract()'s stage functions one by one on a procedural scene, the tracker protocol, and q unchanged.

Each stage is checked against a direct computation from the lower-level API
(render / build_operator / seed_lift / solve) or from the formulas, not
against itself. ``data/extract_q_before_issue9.npz`` holds q from the code
before issue 9 (commit 85e770d, ``/work/main``), produced by::

    syn = make_scene(seed=0); cam = syn.reference_camera(96, 72)
    seed = W(cam) @ (labels == label) > 0.5          # label 2: weighted_bce, label 1: voting
    q = extract(syn.scene, cam, seed, n_views=6, progress=False[, method="voting"]).q
"""

from __future__ import annotations

import importlib
import inspect
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from seed2gs_inverse import Camera, ValidationError
from seed2gs_inverse.frontend.base import Tracker
from seed2gs_inverse.frontend.model_free import GeometricTracker
from seed2gs_inverse.pipeline.settings import SOLVER_DEFAULTS
from seed2gs_inverse.frontend.sam2 import SAM2VideoTracker
from seed2gs_inverse.operators import scene_fingerprint
from seed2gs_inverse.raster import build_operator, render
from seed2gs_inverse.pipeline import ExtractSettings, extract, seed_lift
from seed2gs_inverse.graph import apply_follow
from seed2gs_inverse.pipeline.completion import GRAPH_DEFAULTS, enclosed_by_selection, faint_follow_matrix
from seed2gs_inverse.progress import Progress, StageTimer
from seed2gs_inverse.solvers import solve
from seed2gs_inverse.synthetic import make_scene

ex_mod = importlib.import_module("seed2gs_inverse.pipeline.extract")
stages_mod = importlib.import_module("seed2gs_inverse.pipeline.stages")
DATA = Path(__file__).resolve().parent / "data"


class Counter:
    """Stands in for the progress bar: counts updates."""

    def __init__(self):
        self.n = 0

    def update(self, n=1):
        self.n += n


@pytest.fixture(scope="module")
def syn():
    return make_scene(seed=0)


@pytest.fixture(scope="module")
def setup(syn):
    cam = syn.reference_camera(96, 72)
    truth = syn.labels == 2
    seed = (build_operator(syn.scene, cam).W @ truth.astype(np.float32)).reshape(cam.image_shape) > 0.5
    return cam, seed


@pytest.fixture(scope="module")
def staged(syn, setup):
    """The stages run in order as extract() runs them (n_views=5)."""
    cam, seed = setup
    s = ExtractSettings(n_views=5, progress=False)
    r = ex_mod.Renderer(syn.scene, s.mode)
    ref_img = ex_mod.render_reference(r, cam)
    seed2, info = ex_mod.seed_from_prompt(seed, ref_img)
    ref = ex_mod.reference_view(r, cam, seed2, s.max_reference_pixels)
    lift = ex_mod.lift_seed(syn.scene, ref, s.lift_options)
    bar = Counter()
    orbits = ex_mod.orbit_views(r, cam, ref, lift, s, bar)
    surface, support_info = ex_mod.support_band(syn.scene, lift, orbits, s, GeometricTracker())
    # a mask prompt: the seed band of mask_tolerance, in the reference's pixels
    tracker = GeometricTracker(seed_band=int(np.ceil(s.mask_tolerance * ref.scale)))
    if surface is not None:
        tracker = tracker.with_support_plane(surface.axis, surface.point).with_contact_zone(*surface.contact_zone())
    labelled = ex_mod.track_clips(tracker, orbits, ref.seed)
    graph = ex_mod.evidence_graph(syn.scene, lift, s, ex_mod.MODEL_FREE_SMOOTHNESS)  # smoothness=None resolved
    masks = ex_mod.complete_masks(graph, labelled, lift, ref, s.completion)
    stack = ex_mod.stack_operators(labelled, syn.scene)
    sel = ex_mod.solve_selection(stack, masks, lift, s, graph=graph, smoothness=ex_mod.MODEL_FREE_SMOOTHNESS,
                                 scene=syn.scene, up=orbits.up)
    return SimpleNamespace(settings=s, ref_img=ref_img, seed=seed2, info=info, ref=ref, lift=lift, bar=bar,
                           orbits=orbits, support_info=support_info, labelled=labelled, stack=stack, sel=sel, renderer=r, graph=graph,
                           masks=masks)


def test_render_reference_is_the_full_rendering(syn, setup, staged):
    cam, _ = setup
    want = render(syn.scene, cam)
    for a in ("rgb", "depth", "alpha"):
        np.testing.assert_array_equal(getattr(staged.ref_img, a), getattr(want, a))
    away = Camera.look_at(cam.center, cam.center - 5 * (syn.origin - cam.center), syn.up, 50, 32, 24)
    r = ex_mod.Renderer(syn.scene)
    with pytest.raises(ValidationError, match="sees nothing"):
        ex_mod.render_reference(r, away)


def test_seed_from_prompt(setup, staged):
    _, seed = setup
    np.testing.assert_array_equal(staged.seed, seed)
    assert staged.info["kind"] == "mask"
    sky = np.zeros_like(seed)
    empty = np.flatnonzero(staged.ref_img.alpha.ravel() <= 0.05)
    if empty.size:
        sky.flat[empty[0]] = True
        with pytest.raises(ValidationError, match="does not touch the scene"):
            ex_mod.seed_from_prompt(sky, staged.ref_img)


def test_seed_from_prompt_point_modes(syn, setup, staged):
    """A click: point_mode="object" is point_object_mask's mask, "region" the click's colour region."""
    from seed2gs_inverse.frontend.prompts import PointPrompt
    from seed2gs_inverse.pipeline import point_object_mask

    cam, seed = setup
    ys, xs = np.nonzero(seed)
    click = (int(np.median(xs)), int(np.median(ys)))
    prompt = PointPrompt([click])
    ref = staged.ref_img
    obj, info = ex_mod.seed_from_prompt(prompt, ref, point_mode="object", scene=syn.scene, camera=cam)
    want = point_object_mask(syn.scene, cam, [click], [1], rendering=ref)
    np.testing.assert_array_equal(obj, want.mask)
    assert info["mode"] == "object" and info["n_seeds"] == want.info["n_seeds"]
    region, info = ex_mod.seed_from_prompt(prompt, ref, point_mode="region")
    np.testing.assert_array_equal(region, prompt.to_mask(ref.rgb, depth=ref.depth, alpha=ref.alpha))
    assert info["kind"] == "point"
    with pytest.raises(ValidationError, match="needs the scene"):
        ex_mod.seed_from_prompt(prompt, ref, point_mode="object")


def test_reference_view_full_and_capped(syn, setup, staged):
    cam, seed = setup
    ref = staged.ref
    assert ref.scale == 1.0 and ref.camera is cam
    ys, xs = np.nonzero(seed)
    x0, y0, x1, y1 = ref_box = stages_mod._mask_roi(seed)
    assert x0 <= xs.min() and xs.max() < x1 and y0 <= ys.min() and ys.max() < y1
    want = build_operator(syn.scene, cam, roi=ref_box)
    assert abs(ref.operator.W - want.W).max() == 0
    # capped at a quarter of the pixels: half the resolution, the seed area-averaged over 2x2 blocks
    r = ex_mod.Renderer(syn.scene)
    half = ex_mod.reference_view(r, cam, seed, 48 * 36)
    assert half.scale == pytest.approx(0.5) and half.camera.image_shape == (36, 48)
    blocks = seed.reshape(36, 2, 48, 2).mean(axis=(1, 3))
    np.testing.assert_array_equal(half.seed, blocks > 0.5)
    assert half.operator.camera.image_shape == (36, 48)
    r = ex_mod.Renderer(syn.scene)
    with pytest.raises(ValidationError, match="vanishes at the lift resolution"):
        one = np.zeros_like(seed)
        one[ys[0], xs[0]] = True
        ex_mod.reference_view(r, cam, one, 64)


def test_lift_seed_is_seed_lift(syn, setup, staged):
    cam, _ = setup
    op = staged.ref.operator
    want = seed_lift(syn.scene, cam, staged.ref.seed, op.rendering.depth, op.W)
    np.testing.assert_array_equal(staged.lift.g0, want.g0)
    np.testing.assert_array_equal(staged.lift.center, want.center)
    assert staged.lift.radius == want.radius


def test_orbit_views_frames_carry_their_operators(syn, setup, staged):
    cam, _ = setup
    o = staged.orbits
    assert len(o.flat) == 5 and len(o.spiral) in (0, 5)
    assert [name for name, _ in o.clips()] == ["flat"] + (["spiral"] if o.spiral else [])
    assert staged.bar.n == len(o.flat) + len(o.spiral)  # one progress update per rendered view
    assert o.view_scale == pytest.approx(min(0.5, np.sqrt(40_000 / (96 * 72))))
    assert o.flat[0].operator is staged.ref.operator  # frame 0 is the reference view
    if o.spiral:
        assert o.spiral[0].operator is staged.ref.operator
    lift = staged.lift
    for f in o.flat[1:3]:
        op = f.operator
        assert op.camera is f.camera and f.clip == "flat"
        np.testing.assert_array_equal(f.rgb, op.rendering.rgb)
        np.testing.assert_array_equal(f.depth, op.rendering.depth)
        # the culled operator (cut at cull_far) equals the uncut one on the pixels that it keeps,
        # and the uncut culled one equals the plain build_operator (exact culling)
        roi = stages_mod._roi_box(f.camera, lift.center, lift.radius, 2.0)
        plain = build_operator(syn.scene, f.camera, roi=roi)
        r = ex_mod.Renderer(syn.scene)
        exact = r.operator(f.camera, roi=roi, cull=True, far=None)
        assert abs(exact.W - plain.W).max() == 0
        assert op.W.shape == plain.W.shape
    # the orbit axis of up="auto" (the default) is estimate_up_axis's, reported with its method
    from seed2gs_inverse.pipeline.up_axis import estimate_up_axis
    from seed2gs_inverse.pipeline.up_axis import estimate_up

    base = cam.scaled(o.view_scale)
    est = estimate_up_axis(syn.scene, base, support=lift.g0, center=lift.center, radius=lift.radius)
    np.testing.assert_array_equal(o.up, est.axis)
    assert o.up_info == {**est.summary(), "warning": est.warning()}
    # that of up="level" is estimate_up's from the reference weights; a vector is normalised
    want_up = estimate_up(syn.scene, base, weights=np.asarray(staged.ref.operator.W.sum(axis=0)).ravel())
    level = ex_mod.orbit_axis("level", syn.scene, base, staged.ref, lift)
    np.testing.assert_array_equal(level["axis"], want_up)
    assert level["method"] == "level" and level["confidence"] is None
    user = ex_mod.orbit_axis((0.0, 0.0, 2.0), syn.scene, base, staged.ref, lift)
    assert user["axis"] == [0.0, 0.0, 1.0] and user["method"] == "user"
    assert ex_mod.orbit_axis("camera", syn.scene, base, staged.ref, lift)["axis"] == base.up.tolist()


class Recorder:
    """A tracker that labels everything 1 and records what it was given."""

    def __init__(self, n_out=None, shape=None):
        self.calls = []
        self.n_out, self.shape = n_out, shape

    def track(self, frames, seed_mask, references=()):
        self.calls.append((list(frames), list(references)))
        n = len(frames) if self.n_out is None else self.n_out
        return [np.ones(self.shape or frames[min(k, len(frames) - 1)].camera.image_shape, np.float32)
                for k in range(n)]


def test_track_clips_passes_references_and_drops_spiral_frame_0(staged):
    o = staged.orbits
    rec = Recorder()
    bar = Counter()
    labelled = ex_mod.track_clips(rec, o, staged.ref.seed, bar)
    assert bar.n == len(o.clips())
    assert rec.calls[0][1] == []  # the flat clip has no labelled views yet
    assert [f for f, _ in labelled[:len(o.flat)]] == o.flat
    if o.spiral:
        refs = rec.calls[1][1]
        assert [f for f, _ in refs] == o.flat  # the spiral gets the whole tracked flat clip
        assert [f for f, _ in labelled[len(o.flat):]] == o.spiral[1:]
    assert all(m.dtype == np.float32 and m.shape == f.camera.image_shape for f, m in labelled)
    with pytest.raises(ValidationError, match="returned 1 masks for a flat clip of 5"):
        ex_mod.track_clips(Recorder(n_out=1), o, staged.ref.seed)
    with pytest.raises(ValidationError, match=r"tracker mask 0 of the flat clip has shape \(3, 3\)"):
        ex_mod.track_clips(Recorder(shape=(3, 3)), o, staged.ref.seed)

    class Old:
        def track(self, frames, seed_mask):
            return [seed_mask] * len(frames)

    with pytest.raises(ValidationError, match="must accept references"):
        ex_mod.track_clips(Old(), o, staged.ref.seed)


    class Silent:
        def track(self, frames, seed_mask, references=()):
            return None

    with pytest.raises(ValidationError, match=r"tracker Silent: track\(\) returned NoneType; it must return one"):
        ex_mod.track_clips(Silent(), o, staged.ref.seed)


def test_stack_operators(syn, staged):
    st = staged.stack
    assert len(st) == len(staged.labelled) and st.fingerprint == scene_fingerprint(syn.scene)
    assert all(v is f.operator for v, (f, _) in zip(st, staged.labelled))
    # the supervision frames are the labelled ones, in their order: the stack made from them before
    # the tracking is the one the solve gets
    early = ex_mod.stack_operators([(f, None) for f in ex_mod.supervision_frames(staged.orbits)], syn.scene)
    assert ex_mod.stack_operators(staged.labelled, syn.scene, built=early) is early
    # a stack of other operators (one view fewer, or another order) is not reused
    assert ex_mod.stack_operators(staged.labelled[:-1], syn.scene, built=early) is not early
    swapped = [staged.labelled[1], staged.labelled[0], *staged.labelled[2:]]
    other = ex_mod.stack_operators(swapped, syn.scene, built=early)
    assert other is not early and other[0] is staged.labelled[1][0].operator


def _evidence(syn, labelled):
    """e = sum_c W(c)^T k(c), with dense operators (independent of the sparse products)."""
    evidence = np.zeros(len(syn.scene))
    for (f, m) in labelled:
        W = f.operator.W.toarray().astype(np.float64)
        evidence += W.T @ (~np.isnan(m)).ravel()
    return evidence


def _against(syn, labelled, min_evidence, min_vote):
    """(N,) bool: evidence e >= min_evidence (> 0) and the dense vote sum_c W(c)^T (k y)(c) / e below min_vote."""
    e = np.zeros(len(syn.scene))
    a1 = np.zeros(len(syn.scene))
    for (f, m) in labelled:
        W = f.operator.W.toarray().astype(np.float64)
        y = np.asarray(m, np.float64).ravel()
        e += W.T @ ~np.isnan(y)
        a1 += W.T @ np.nan_to_num(y)
    return (e > 0) & (e >= min_evidence) & (a1 < min_vote * e)


def test_solve_selection_equals_the_old_evidence_reset(syn, staged):
    """q: the solver's q, Gaussians of evidence e = sum_c W(c)^T k(c) < min_evidence reset to G0 (the old loop)."""
    masks = [m for _, m in staged.labelled]
    off = staged.settings.replace(seed_connected=False, follow_faint=False, follow_weak=False)  # the solver's q
    sel = ex_mod.solve_selection(staged.stack, masks, staged.lift, off)  # smoothness 0: off
    raw = solve(staged.stack, masks, method="weighted_bce", init=staged.lift.g0,
                **SOLVER_DEFAULTS["weighted_bce"])
    weak = _evidence(syn, staged.labelled) < off.min_evidence
    assert 0 < weak.sum() < len(weak)
    want = np.asarray(raw.q, np.float32).copy()
    want[weak] = staged.lift.g0[weak]
    against = _against(syn, staged.labelled, off.min_evidence, off.min_vote)
    want[against] = np.minimum(want, staged.lift.g0)[against]  # min_vote: no higher than the prior
    np.testing.assert_array_equal(sel.q, want)
    assert sel.n_weak_evidence == int(weak.sum())
    assert sel.threshold == 0.5 and np.array_equal(sel.selected, sel.q > 0.5)
    t = ex_mod.solve_selection(staged.stack, masks, staged.lift, off.replace(threshold=0.3))
    assert t.threshold == 0.3 and np.array_equal(t.selected, t.q > 0.3)


def test_solve_selection_with_the_graph_regulariser(syn, staged):
    """smoothness > 0: q solves (E + lambda L + eps I) q = E q_hat + eps p (dense, from the formula).

    E = diag(e) with e the evidence (0 below min_evidence), q_hat the solver's
    q, p = G0, L = D - G on the graph around the object, eps = 1e-6.
    """
    assert staged.graph is not None and staged.graph.nnz > 0
    assert staged.masks is not None and len(staged.masks) == len(staged.labelled)
    raw = solve(staged.stack, staged.masks, method="weighted_bce", init=staged.lift.g0,
                **SOLVER_DEFAULTS["weighted_bce"])
    e = _evidence(syn, staged.labelled)
    e[e < staged.settings.min_evidence] = 0.0
    p = staged.lift.g0.astype(np.float64)
    G = staged.graph.tocsr()
    nodes = np.flatnonzero(np.asarray(G.sum(axis=1)).ravel() > 0)  # the graph's nodes; the rest decouple
    Gd = G[nodes][:, nodes].toarray()
    L = np.diag(Gd.sum(axis=1)) - Gd
    qh = np.asarray(raw.q, np.float64)
    eps, lam = 1e-6, ex_mod.MODEL_FREE_SMOOTHNESS
    want = (e * qh + eps * p) / (e + eps)
    want[nodes] = np.linalg.solve(np.diag(e[nodes] + eps) + lam * L, e[nodes] * qh[nodes] + eps * p[nodes])
    want = np.clip(want, 0.0, 1.0)
    against = _against(syn, staged.labelled, staged.settings.min_evidence, staged.settings.min_vote)
    want[against] = np.minimum(want, p)[against]  # min_vote, after the regulariser
    # CG to a relative residual of 1e-5 (laplacian_smooth's default): within about 1e-2 of the exact solve
    # (the most where fewest Gaussians carry evidence, as min_evidence leaves them)
    np.testing.assert_allclose(staged.sel.result.q, want, atol=2e-2)
    # follow_faint, follow_weak, then seed_connected: q is the regularised q, its faint Gaussians near the
    # object set by the follow matrix, the Gaussians the selection encloses by one selected Gaussian each,
    # the unselected weak ones near the object by strong ones, then what the grown selection encloses
    # (all checked on their own in test_object_layers.py), and 0 on islands apart from G0
    faint = faint_follow_matrix(syn.scene, staged.lift.center, staged.lift.radius)
    followed = apply_follow(staged.sel.result.q, faint)
    tau = staged.sel.threshold
    enc = enclosed_by_selection(staged.stack, followed > tau, syn.scene.means, up=staged.orbits.up)
    follow = staged.sel.follow.tocsr()
    rows = follow[enc]
    assert np.all(np.diff(rows.indptr) == 1) and np.all(rows.data == 1.0)
    assert np.all(followed[rows.indices] > tau) and faint[rows.indices].nnz == 0
    followed[enc] = followed[rows.indices]
    strong = np.max([v.W.toarray().max(axis=0) for v in staged.stack], axis=0) >= 0.3
    near = (np.linalg.norm(syn.scene.means - staged.lift.center, axis=1)
            <= GRAPH_DEFAULTS["region"] * staged.lift.radius)
    weak = near & ~strong & (followed <= tau)  # the rule's candidates (its base and reach bounds keep some out)
    changed = np.flatnonzero(np.asarray(abs(follow - faint).sum(axis=1)).ravel() > 0)
    changed = changed[~enc[changed]]
    # then the enclosed rule again: one weight of 1 each, exactly the Gaussians that the selection the
    # weak rule grew encloses (they were unselected before it: the final selection without them)
    one = (np.diff(follow.indptr)[changed] == 1) & (follow[changed].max(axis=1).toarray().ravel() == 1.0)
    again = np.zeros(len(followed), bool)
    again[changed[one]] = True
    grown = (apply_follow(staged.sel.result.q, follow) > tau) & ~again
    np.testing.assert_array_equal(enclosed_by_selection(staged.stack, grown, syn.scene.means, up=staged.orbits.up),
                                  again)
    changed = changed[~one]
    assert changed.size > 0 and weak[changed].all() and np.all(strong[follow[changed].indices])
    island = apply_follow(staged.sel.result.q, follow) != staged.sel.q
    assert island.sum() == staged.sel.n_disconnected and np.all(staged.sel.q[island] == 0)
    # unseen Gaussians on the graph are decided by their neighbours, not reset to G0
    free = nodes[e[nodes] == 0]
    assert free.size and np.abs(staged.sel.q[free] - p[free]).max() > 0.1
    with pytest.raises(ValidationError, match="smoothness > 0 needs graph"):
        ex_mod.solve_selection(staged.stack, staged.masks, staged.lift, staged.settings, smoothness=1.0)
    with pytest.raises(ValidationError, match="seed_connected, follow_faint and follow_weak need the scene"):
        ex_mod.solve_selection(staged.stack, staged.masks, staged.lift, staged.settings)


def test_solve_min_evidence_option_validation(staged):
    masks = [m for _, m in staged.labelled]
    for bad in (-1.0, float("nan"), "0.1", True):
        with pytest.raises(ValidationError, match="min_evidence"):
            solve(staged.stack, masks, method="voting", min_evidence=bad)
    r = solve(staged.stack, masks, method="voting")
    assert r.info["n_weak_evidence"] == 0  # default 0: off
    for bad in (-1.0, float("inf"), "1", True):
        with pytest.raises(ValidationError, match="smoothness must be a finite number"):
            solve(staged.stack, masks, method="voting", smoothness=bad)
    with pytest.raises(ValidationError, match="smoothness > 0 needs graph"):
        solve(staged.stack, masks, method="voting", smoothness=1.0)
    import scipy.sparse as sp

    with pytest.raises(ValidationError, match="build it from the same scene"):
        solve(staged.stack, masks, method="voting", smoothness=1.0, graph=sp.eye(3, format="csr"))
    r = solve(staged.stack, masks, method="voting", smoothness=0.5, graph=staged.graph)
    assert r.info["smoothness"] == 0.5


def test_extract_runs_the_stages(syn, setup, staged):
    cam, seed = setup
    ex = extract(syn.scene, cam, seed, n_views=5, progress=False)
    np.testing.assert_array_equal(ex.q, staged.sel.q)
    assert len(ex.views) == len(staged.labelled)
    for v, (f, _) in zip(ex.views, staged.labelled):
        np.testing.assert_array_equal(v.world_to_camera, f.camera.world_to_camera)
        assert v.image_shape == f.camera.image_shape
    assert ex.resolved["n_weak_evidence"] == staged.sel.n_weak_evidence
    assert ex.resolved["support"] == staged.support_info
    assert list(ex.seconds) == [*ex_mod.STAGES, "compile"] and all(v >= 0 for v in ex.seconds.values())


#: The extraction the pinned q came from, run in a child process (see :func:`_avx2_arithmetic`). Pinned
#: to the options of the code that produced the file (up="level", no graph regulariser, exact
#: operators with min_weight=0, 30 L-BFGS-B iterations), so that it still proves the stage
#: refactor left q unchanged. Later rules are switched off: the tracker's empty pixels vote in its fill
#: and faint and weak Gaussians keep the solver's q, the evidence threshold is the old 0.05, and no
#: Gaussian is held at its prior against its masks' vote (min_vote 0); the seed mask is trusted to
#: the pixel (mask_tolerance 0).
_PINNED_RUN = """
import sys
import numpy as np
from seed2gs_inverse.frontend.model_free import GeometricTracker
from seed2gs_inverse.pipeline import extract
from seed2gs_inverse.raster import build_operator
from seed2gs_inverse.synthetic import make_scene
name, label, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
syn = make_scene(seed=0)
cam = syn.reference_camera(96, 72)
truth = syn.labels == label
seed = (build_operator(syn.scene, cam).W @ truth.astype(np.float32)).reshape(cam.image_shape) > 0.5
kw = {"solver_options": {"max_iter": 30}} if name == "weighted_bce" else {"method": "voting"}
ex = extract(syn.scene, cam, seed, tracker=GeometricTracker(fill_from_empty=True), n_views=6, progress=False,
             up="level", smoothness=0.0, min_weight=0.0, follow_faint=False, follow_weak=False,
             near_margin=None, min_evidence=0.05, min_vote=0.0, mask_tolerance=0, **kw)
np.savez(out, q=ex.q, n_weak=ex.resolved["n_weak_evidence"])
"""


def _avx2_arithmetic() -> dict:
    """Environment that makes NumPy and OpenBLAS round as on the AVX2 machine that made the pinned q.

    Thirty L-BFGS-B iterations on an unregularised problem carry last-bit
    differences (AVX-512 float32 sums in NumPy, another OpenBLAS kernel) into
    Gaussians that no view decides, so a pinned q is only comparable under
    the same arithmetic. Numba's kernels round the same on both.
    """
    from numpy._core import _multiarray_umath as umath

    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    if "avx2" not in flags:
        pytest.skip("the pinned q was computed with AVX2 kernels, which this processor lacks")
    wide = [f for f in umath.__cpu_dispatch__ if "512" in f or f == "X86_V4"]
    return {"OPENBLAS_CORETYPE": "Haswell", "NPY_DISABLE_CPU_FEATURES": " ".join(wide)}


@pytest.mark.parametrize("name,label", [("weighted_bce", 2), ("voting", 1)])
def test_q_unchanged_from_before_issue_9(tmp_path, name, label):
    ref = np.load(DATA / "extract_q_before_issue9.npz", allow_pickle=False)
    out = tmp_path / "q.npz"
    env = {**os.environ, **_avx2_arithmetic(), "PYTHONPATH": os.pathsep.join(
        [str(Path(__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, "-c", _PINNED_RUN, name, str(label), str(out)], env=env,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    got = np.load(out, allow_pickle=False)
    q, q0 = got["q"], ref[f"q_{name}"]
    # Since the stack's adjoint adds two runs of views (operators/_passes.py)
    # its float32 sums round differently, and since the per-pixel BCE of
    # binary targets runs in float32 (solvers/_bce.py) its terms do too; 30
    # L-BFGS-B iterations carry that to about 1e-4 in q (3.6e-4 on one
    # Gaussian; other BLAS builds, too), never into the selection.
    assert float(np.abs(q - q0).max()) <= 5e-4
    clear = np.abs(q0 - 0.5) > 1e-3
    np.testing.assert_array_equal((q > 0.5)[clear], (q0 > 0.5)[clear])
    assert int(got["n_weak"]) == int(ref[f"n_weak_{name}"])


def test_every_tracker_takes_references():
    for cls in (Tracker, GeometricTracker, SAM2VideoTracker):
        p = inspect.signature(cls.track).parameters
        assert "references" in p and p["references"].default == (), cls.__name__
    assert isinstance(GeometricTracker(), Tracker)
    from seed2gs_inverse.frontend import external

    for obj in vars(external).values():
        if inspect.isclass(obj) and callable(getattr(obj, "track", None)):
            assert "references" in inspect.signature(obj.track).parameters, obj.__name__


def test_geometric_tracker_uses_references(syn, staged):
    """The spiral tracked with the flat clip as references differs from without, where the flat clip sees more."""
    o = staged.orbits
    if not o.spiral:
        pytest.skip("spiral skipped on this scene")
    t = GeometricTracker()
    flat = t.track(o.flat, staged.ref.seed)
    with_refs = t.track(o.spiral, staged.ref.seed, references=list(zip(o.flat, flat)))
    without = t.track(o.spiral, staged.ref.seed)
    known = lambda ms: sum(int((~np.isnan(m)).sum()) for m in ms)  # noqa: E731
    assert known(with_refs) >= known(without)


def test_progress_bar_is_owned_by_its_with_block(capsys, monkeypatch):
    monkeypatch.setattr(Progress, "DELAY", 0.0)  # drawn at once, however short the block
    with Progress("views", True, total=3) as bar:
        for _ in range(3):
            bar.update()
        assert bar._bar is not None and bar._bar.n == 3
    assert bar._bar is None  # closed on leaving the block
    assert "views" in capsys.readouterr().err
    with Progress("quiet", False) as off:
        off.update()
    assert off._bar is None and capsys.readouterr().err == ""


def test_stage_timer_moves_seconds_between_stages():
    t = StageTimer(ex_mod.STAGES)
    with t("vaas"):
        pass
    t.seconds["vaas"] = 1.0
    t.move("vaas", "operators", 0.25)
    assert t.seconds["vaas"] == 0.75 and t.seconds["operators"] == 0.25
    assert list(t.seconds) == list(ex_mod.STAGES)


def test_solve_selection_reads_masks_as_the_solver_does(syn, staged):
    """The islands' votes read the masks by the solver's rule: uint8 0/255 masks voted 255 times too much for
    object (keeping every island), a generator of masks was empty by the time of the vote, and a list of
    views (which solve takes) had no rmatvec."""
    from seed2gs_inverse.pipeline.stages import _votes

    binary = [np.asarray(m) > 0.5 for m in staged.masks]  # every pixel decided (NaN > 0.5 is False)
    obj, decided = _votes(staged.stack, [b.astype(np.float32) for b in binary])
    obj8, decided8 = _votes(staged.stack, [255 * b.astype(np.uint8) for b in binary])
    np.testing.assert_allclose(obj8, obj, rtol=1e-6)
    np.testing.assert_allclose(decided8, decided, rtol=1e-6)
    assert 0 < obj.sum() < decided.sum()
    want = ex_mod.solve_selection(staged.stack, staged.masks, staged.lift, staged.settings, graph=staged.graph,
                                  smoothness=ex_mod.MODEL_FREE_SMOOTHNESS, scene=syn.scene)
    got = ex_mod.solve_selection(list(staged.stack), (m for m in staged.masks), staged.lift, staged.settings,
                                 graph=staged.graph, smoothness=ex_mod.MODEL_FREE_SMOOTHNESS, scene=syn.scene)
    np.testing.assert_array_equal(got.q, want.q)
