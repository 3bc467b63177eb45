"""Orbit views see the object past what stands close around it (ExtractSettings.near_margin).

The last tests put a level plate (a chair's seat) just above the object's
top instead: the reference sees the object's lower part under it, and the
upper part, banded in colours of its own, is revealed only in the orbit
views, where the tracker leaves it unknown. It must follow the body
(ExtractSettings.min_evidence) and not the few background labels that reach
it through the plate's pixels.

Posts (thin vertical cylinders of Gaussians, taller than the object) stand on
a ring around a small object, closer to it than its own height. The same
object is extracted with and without them, and both selections are scored on
the same held-out views of the scene *without* the posts (views the pipeline
never rendered, 10 and 35 degrees of elevation, all around), against the
exact truth: the posts must not cost the object its silhouette.
"""

import numpy as np
import pytest

from seed2gs_inverse import GaussianScene, build_operator, extract
from seed2gs_inverse.metrics import iou
from seed2gs_inverse.sh import rgb_to_sh
from seed2gs_inverse.pipeline import ExtractSettings
from seed2gs_inverse.synthetic.ground import make_ground_scene

from _pipeline_scenes import surface

RING = 0.35       # post axis to object axis; the object is 0.46 high, 0.2 in footprint radius
N_POSTS = 8


def _posts(gs, name, ring=RING, n_posts=N_POSTS, radius=0.03, height=0.7, n_per=120):
    """``n_posts`` vertical cylinders of surface Gaussians on a ring about the object's anchor."""
    a0 = gs.to_local(gs.anchors[name][None])[0]
    k = np.arange(n_per) + 0.5
    th = 2 * np.pi * ((k * 0.618034) % 1.0)
    nrm = np.stack([np.cos(th), np.sin(th), np.zeros_like(th)], 1)
    pts = []
    for j in range(n_posts):
        ang = np.radians(22.5 + 360.0 * j / n_posts)  # the reference (azimuth 0) looks between two posts
        c = a0[:2] + ring * np.array([np.cos(ang), np.sin(ang)])
        pts.append(np.column_stack([c + radius * nrm[:, :2], a0[2] - 0.02 + height * k / n_per]))
    pts = gs.to_world(np.concatenate(pts))
    normals = np.tile(nrm, (n_posts, 1)) @ gs.rotation.T
    spacing = np.sqrt(2 * np.pi * radius * height / n_per)
    return surface(pts, normals, spacing, np.tile([0.35, 0.3, 0.28], (len(pts), 1)))


def _held_out_ious(gs, name, scene, truth, held, **options):
    """Extract from a reference at 20 degrees; IoU of ``W(c) 1_sel > 0.5`` on each held-out view."""
    ref = gs.camera(name, 0.0, 20.0, 3.0 * gs.heights[name], 200, 150)
    seed = (build_operator(scene, ref).W @ truth.astype(np.float32)).reshape(ref.image_shape) > 0.5
    ex = extract(scene, ref, seed, progress=False, up=gs.up, **options)
    sel = ex.selected[:len(gs.scene)].astype(np.float32)  # the posts come last: held-out views are without them
    return np.array([iou((op.W @ sel).reshape(op.image_shape) > 0.5, t) for op, t in held]), ex


def _case(seed):
    gs = make_ground_scene(seed, objects=("plush",), clutter=(), density=0.25, n_per_object=700)
    truth = gs.object_mask("plush")
    held = []
    for el in (10.0, 35.0):
        for az in np.arange(20.0, 360.0, 45.0):
            op = build_operator(gs.scene, gs.camera("plush", az, el, 3.0 * gs.heights["plush"], 160, 120))
            held.append((op, (op.W @ truth.astype(np.float32)).reshape(op.image_shape) > 0.5))
    posts = _posts(gs, "plush")
    with_posts = GaussianScene.concat([gs.scene, posts])
    truth_posts = np.r_[truth, np.zeros(len(posts), bool)]
    return gs, truth, held, with_posts, truth_posts


@pytest.fixture(scope="module", params=[5, 11])
def case(request):
    return _case(request.param)


#: Ground seed 5 fails the 0.03 check since the tracker's fill stopped taking empty space as evidence
#: (GeometricTracker(fill_from_empty=False), the default): the ground disc of this scene borders
#: empty space, and revealed ground beside the object is filled as object, so a few large ground
#: splats join it (held-out loss 0.23; 0.011 with fill_from_empty=True). Strict: once it passes,
#: the mark must go.
_KNOWN_FAILURE = pytest.mark.xfail(strict=True, reason="revealed ground beside empty space is filled as object "
                                   "when empty space does not vote in the tracker's fill")


def test_posts_close_around_the_object_hide_it_in_the_reference(case):
    """Precondition: the posts are close (within the object's height) and hide a good part of it."""
    gs, truth, held, with_posts, truth_posts = case
    anchor = gs.to_local(gs.anchors["plush"][None])[0]
    post_xy = gs.to_local(with_posts.means[len(gs.scene):])[:, :2]
    assert np.linalg.norm(post_xy - anchor[:2], axis=1).max() < gs.heights["plush"]
    ref = gs.camera("plush", 0.0, 20.0, 3.0 * gs.heights["plush"], 200, 150)
    alone = (build_operator(gs.scene, ref).W @ truth.astype(np.float32)).sum()
    seen = (build_operator(with_posts, ref).W @ truth_posts.astype(np.float32)).sum()
    assert seen < 0.8 * alone


def test_posts_cost_the_held_out_views_at_most_003_iou(case, request):
    if request.node.callspec.params["case"] == 5:
        request.applymarker(_KNOWN_FAILURE)
    gs, truth, held, with_posts, truth_posts = case
    assert ExtractSettings().near_margin is not None  # the default setting is what is checked
    alone, _ = _held_out_ious(gs, "plush", gs.scene, truth, held)
    posts, ex = _held_out_ious(gs, "plush", with_posts, truth_posts, held)
    assert alone.mean() >= 0.9, np.round(alone, 2).tolist()
    assert alone.mean() - posts.mean() <= 0.03, (np.round(alone, 2).tolist(), np.round(posts, 2).tolist())
    assert ex.selected[len(gs.scene):].sum() <= 5  # the posts stay out of the object


def test_without_the_near_cut_the_posts_cost_more():
    """The check can fail: with ``near_margin=None`` the same posts cut the held-out silhouettes."""
    gs, truth, held, with_posts, truth_posts = _case(5)
    alone, _ = _held_out_ious(gs, "plush", gs.scene, truth, held, near_margin=None)
    posts, _ = _held_out_ious(gs, "plush", with_posts, truth_posts, held, near_margin=None)
    assert alone.mean() - posts.mean() > 0.1


BANDS = np.array([[0.2, 0.5, 0.95], [0.95, 0.85, 0.2], [0.6, 0.95, 0.6]])  # the upper half's colours


def _seat_case(seed=5, gap=0.02, reach=0.15, half=0.5, spacing=0.02):
    """The plush, its upper half in bands of colour, under a level plate of radius 0.5 at ``gap`` above its top.

    The plate's centre lies ``reach`` from the object's axis towards the
    reference (azimuth 0). Returns the ground scene, the reference, the
    scene without and with the plate (last), the truth, the mask of the
    object's top 30 % (ears and crown, closest under the plate) and the
    held-out views of the scene without the plate, with their truth.
    """
    gs = make_ground_scene(seed, objects=("plush",), clutter=(), density=0.25, n_per_object=700)
    truth = gs.object_mask("plush")
    h = gs.to_local(gs.scene.means)[:, 2]
    h = h - h[truth].min()
    banded = truth & (h > half * h[truth].max())
    sh = np.array(gs.scene.sh, copy=True)
    sh[banded, 0, :] = rgb_to_sh(BANDS[(h[banded] / (0.05 * h[truth].max())).astype(int) % 3])
    upper = truth & (h > 0.7 * h[truth].max())
    scene = GaussianScene(gs.scene.means, gs.scene.quats, gs.scene.log_scales, gs.scene.opacity_logits, sh)
    a0 = gs.to_local(gs.anchors["plush"][None])[0]
    ref = gs.camera("plush", 0.0, 20.0, 3.0 * gs.heights["plush"], 200, 150)
    toward = gs.to_local(ref.center[None])[0][:2] - a0[:2]
    g = np.arange(-0.5, 0.5 + 1e-9, spacing)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    xy = a0[:2] + reach * toward / np.linalg.norm(toward) + xy[np.linalg.norm(xy, axis=1) <= 0.5]
    top = gs.to_local(gs.scene.means[truth])[:, 2].max()
    pts = gs.to_world(np.column_stack([xy, np.full(len(xy), top + gap)]))
    plate = surface(pts, np.tile(gs.up, (len(pts), 1)), spacing, np.tile([0.8, 0.15, 0.15], (len(pts), 1)))
    held = []
    for el in (10.0, 35.0):
        for az in np.arange(20.0, 360.0, 45.0):
            op = build_operator(scene, gs.camera("plush", az, el, 3.0 * gs.heights["plush"], 160, 120))
            held.append((op, (op.W @ truth.astype(np.float32)).reshape(op.image_shape) > 0.5))
    return gs, ref, scene, GaussianScene.concat([scene, plate]), truth, upper, held


@pytest.fixture(scope="module")
def seat():
    return _seat_case()


def _under_seat(seat, **options):
    """Extract under the plate; (held-out IoUs without the plate, share of the top 30 % selected, extraction)."""
    gs, ref, scene, with_seat, truth, upper, held = seat
    tp = np.r_[truth, np.zeros(len(with_seat) - len(scene), bool)]
    seed = (build_operator(with_seat, ref).W @ tp.astype(np.float32)).reshape(ref.image_shape) > 0.5
    ex = extract(with_seat, ref, seed, progress=False, up=gs.up, **options)
    sel = ex.selected[:len(scene)]
    ious = np.array([iou((op.W @ sel.astype(np.float32)).reshape(op.image_shape) > 0.5, t) for op, t in held])
    return ious, float(sel[upper].mean()), ex


def test_the_seat_hides_the_upper_part_in_the_reference(seat):
    """Precondition: the plate is close above the object and hides a good part of it in the reference."""
    gs, ref, scene, with_seat, truth, upper, held = seat
    tp = np.r_[truth, np.zeros(len(with_seat) - len(scene), bool)]
    alone = (build_operator(scene, ref).W @ truth.astype(np.float32)).sum()
    seen = (build_operator(with_seat, ref).W @ tp.astype(np.float32)).sum()
    assert seen < 0.7 * alone
    ious, share, _ = _under_seat((gs, ref, scene, scene, truth, upper, held))  # no plate: the same object
    assert ious.mean() >= 0.97 and share >= 0.97, (np.round(ious, 2).tolist(), share)


def test_the_upper_part_under_a_seat_follows_the_body(seat):
    assert ExtractSettings().min_evidence >= 1.0  # the default setting is what is checked
    ious, share, ex = _under_seat(seat)
    assert share >= 0.95, f"only {share:.3f} of the object's top 30 % is selected"
    assert ious.mean() >= 0.95, np.round(ious, 2).tolist()
    assert ex.selected[len(seat[2]):].sum() <= 5  # the plate stays out of the object


def test_with_a_twentieth_of_a_pixel_as_evidence_the_upper_part_is_lost(seat):
    """The check can fail: with ``min_evidence=0.05`` a trace of background weight decides the upper part."""
    _, share, _ = _under_seat(seat, min_evidence=0.05)
    assert share < 0.92, share
