"""The support surface under the object (issue 10): its level, the tracker's rule, and the extraction."""

import numpy as np
import pytest

from seed2gs_inverse import build_operator, extract, render
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.frontend.model_free import GeometricTracker, _on_support, warp_labels
from seed2gs_inverse.metrics import iou
from seed2gs_inverse.pipeline.support import support_surface
from seed2gs_inverse.pipeline.vaas import ClipFrame
from seed2gs_inverse.synthetic.ground import make_ground_scene, place_object


@pytest.fixture(scope="module")
def yard():
    """A table in a yard (fence, wall, grass), resting on uneven ground; reference at 40 degrees pitch."""
    src = make_ground_scene(102, objects=("table",), clutter=())
    table = src.scene.subset(src.object_mask("table"))
    gs = make_ground_scene(8, objects=("box", "vase"), clutter=("fence", "wall", "grass"), n_per_object=700,
                           density=0.4)
    gs = place_object(gs, table, at=(1.1, 0.5), object_up=tuple(src.up), height=0.75, yaw_deg=98.0,
                      quantile=0.01, name="table")
    truth = gs.object_mask("table")
    pts = gs.scene.means[truth].astype(np.float64)
    center = 0.5 * (pts.min(0) + pts.max(0))
    size = float(np.linalg.norm(pts - center, axis=1).max())

    def seed_of(cam):
        return (build_operator(gs.scene, cam).W @ truth.astype(np.float32)).reshape(cam.image_shape) > 0.5

    dist = 4.0 * size
    for _ in range(3):  # a seed of about 1,500 px, as in bench_extract's yard-table-40
        dist *= np.sqrt(seed_of(gs.camera(center, 140.0, 40.0, dist, 640, 480)).sum() / 1500.0)
    ref = gs.camera(center, 140.0, 40.0, dist, 640, 480)
    hd = 1.25 * size / np.tan(np.radians(25.0))
    held_out = [gs.camera(center, 140.0 + az, el, hd, 320, 240) for az, el in
                ((187, 10), (97, 25), (263, 25), (143, 40), (327, 10))]
    return gs, truth, center, size, ref, seed_of(ref), held_out


def _held_out_ious(gs, truth, selected, cams):
    out = []
    for cam in cams:
        op = build_operator(gs.scene, cam)
        t = (op.W @ truth.astype(np.float32)).reshape(op.image_shape) > 0.5
        p = (op.W @ selected.astype(np.float32)).reshape(op.image_shape) > 0.5
        out.append(iou(p, t))
    return np.array(out)


def test_support_level_is_the_ground_under_the_object(yard):
    gs, truth, center, size, *_ = yard
    s = support_surface(gs.scene, truth, center, size, gs.up)
    assert s is not None and s.n_splats >= 20
    np.testing.assert_allclose(s.axis, gs.up, atol=1e-12)
    # the level is that of the true ground around the object (by its labels, not by shape): the
    # median height of the ground Gaussians in the same annulus
    rel = gs.scene.means.astype(np.float64) - center
    h = rel @ gs.up
    r = np.linalg.norm(rel - h[:, None] * gs.up, axis=1)
    ring = (gs.labels == 0) & (r >= size) & (r <= 2 * size)
    # (the ground undulates: within its spread there)
    assert 0 < s.spread < 0.1 * gs.heights["table"]
    assert abs(s.level - np.median(h[ring])) <= s.spread
    # the band's top: the margin (5 % of the radius) or twice the spread above the level; it holds
    # the ground of the annulus and stays below the lowest tenth of the table
    top = float((s.point - center) @ gs.up)
    assert top == pytest.approx(s.level + max(0.05 * size, 2 * s.spread), abs=1e-9)
    assert (h[ring] <= top).mean() > 0.9
    assert top < np.quantile(h[truth], 0.1)
    assert s.summary()["n_splats"] == s.n_splats


def test_no_level_surface_gives_none(yard):
    gs, truth, center, size, *_ = yard
    # without the ground and the objects (box and vase tops are level) only vertical clutter remains:
    # fence, wall, grass blades
    keep = gs.labels == 1
    sub = gs.scene.subset(keep)
    assert support_surface(sub, truth[keep], center, size, gs.up) is None
    for bad, match in (({"axis": (0, 0, 0)}, "axis"), ({"radius": -1.0}, "radius"),
                       ({"support": truth[:5]}, "support has 5 entries"), ({"inner": 3.0}, "inner < outer")):
        kw = {"support": truth, "center": center, "radius": size, "axis": gs.up, **bad}
        with pytest.raises(ValidationError, match=match):
            support_surface(gs.scene, **kw)


def _frame(scene, cam):
    r = render(scene, cam)
    return ClipFrame(r.rgb, r.depth, r.alpha, cam, "flat", 0)


def test_on_support_takes_level_surfaces_in_the_band_only(yard):
    gs, truth, center, size, *_ = yard
    cam = gs.camera(center, 20.0, 35.0, 3.0 * gs.heights["table"], 160, 120)
    f = _frame(gs.scene, cam)
    op = build_operator(gs.scene, cam)
    share = {name: (op.W @ (gs.labels == gs.label_of(name)).astype(np.float32)).reshape(cam.image_shape)
             for name in ("ground", "table")}
    ground, table = share["ground"] > 0.95, share["table"] > 0.95
    high = center + 10.0 * size * gs.up  # a band above everything: only the facing test decides
    on = _on_support(f, gs.up, high, 0.8)
    assert ground.sum() > 500 and on[ground].mean() > 0.9
    # the table's legs and skirt face sideways; its top faces up
    assert on[table].mean() < 0.9 and on[table].mean() > 0.1
    low = center - 10.0 * size * gs.up
    assert not _on_support(f, gs.up, low, 0.8).any()


def test_tracker_keeps_what_the_seed_frame_saw(yard):
    gs, truth, center, size, ref, seed, _ = yard
    frames = [_frame(gs.scene, ref)] + [_frame(gs.scene, gs.camera(center, 140.0 + d, 40.0,
                                                                   3.0 * gs.heights["table"], 200, 150))
                                        for d in (15.0, 30.0)]
    high = center + 10.0 * size * gs.up  # every level surface is "support", the table top included
    plain = GeometricTracker().track(frames, seed)
    ruled = GeometricTracker(support_plane=(gs.up, high)).track(frames, seed)
    np.testing.assert_array_equal(ruled[0], plain[0])  # the seed frame is never changed
    for k in (1, 2):
        from_seed = warp_labels(frames[k], frames[0], seed.astype(np.float64), color_tol=0.15) == 1
        on = _on_support(frames[k], gs.up, high, 0.8)
        assert from_seed.sum() > 100
        assert np.all(ruled[k][from_seed] == 1)
        assert np.all(ruled[k][on & ~from_seed] == 0) and (on & ~from_seed).sum() > 100
    with pytest.raises(ValidationError, match="support_plane"):
        GeometricTracker(support_plane=((0, 0, 0), (1, 2, 3)))
    with pytest.raises(ValidationError, match="support_alignment"):
        GeometricTracker(support_alignment=0.0)
    t = GeometricTracker()
    assert t.with_support_plane((0, 0, 2), (0, 0, 1)).support_plane[0].tolist() == [0, 0, 1.0]
    assert t.support_plane is None


def test_the_ground_under_a_table_stays_out(yard):
    """The contact-line drift of issue 10: with the default the ground under the table is not selected."""
    gs, truth, center, size, ref, seed, held_out = yard
    ex = extract(gs.scene, ref, seed, progress=False)
    assert ex.resolved["support"]["used"] is True
    ious = _held_out_ious(gs, truth, ex.selected, held_out)
    assert ious.min() >= 0.95, ious
    # precondition: without the rule the same scene loses a held-out view to the ground patch
    off = extract(gs.scene, ref, seed, progress=False, support_background=False)
    assert off.resolved["support"] == {"used": False, "reason": "support_background is off"}
    assert _held_out_ious(gs, truth, off.selected, held_out).min() < 0.9
    assert (off.selected & ~truth).sum() > (ex.selected & ~truth).sum()


def test_support_level_from_hand_placed_splats():
    """Splats placed by hand, one of each kind just outside a filter of the module docstring: the level and
    spread are the median and normalised MAD of exactly the ones that pass every filter."""
    from seed2gs_inverse.scene import GaussianScene

    rng = np.random.default_rng(4)
    R, o, up = 1.0, np.array([0.5, -0.2, 2.0]), np.array([0.0, 0.0, 1.0])
    flat = np.log([0.05, 0.04, 0.002])  # flat: the smallest scale (z) < 0.3 x the middle one; normal = up
    n_good = 31
    ang = rng.uniform(0, 2 * np.pi, n_good)
    rad = rng.uniform(1.05, 1.95, n_good) * R
    hs = -0.8 + rng.normal(0, 0.03, n_good)
    means = [o + np.c_[rad * np.cos(ang), rad * np.sin(ang), hs]]
    scales = [np.tile(flat, (n_good, 1))]
    quats = [np.tile([1.0, 0, 0, 0], (n_good, 1))]
    opac = [np.full(n_good, 3.0)]
    tilt = np.array([np.cos(np.radians(15)), np.sin(np.radians(15)), 0, 0])  # normal 30 degrees off: 0.87 < 0.9

    def one(mean, log_s=flat, quat=(1.0, 0, 0, 0), logit=3.0):
        means.append(o + np.asarray(mean, float)[None])
        scales.append(np.asarray(log_s, float)[None])
        quats.append(np.asarray(quat, float)[None])
        opac.append(np.array([logit]))

    one([0.95 * R, 0, -0.5])  # inside the inner radius
    one([2.05 * R, 0, -0.5])  # beyond the outer radius
    one([1.5 * R, 0, -2.05 * R])  # below the height window |h| <= 2R
    one([0, 1.5 * R, -0.2], logit=-1.0)  # opacity 0.27 < 0.3
    one([0, -1.5 * R, -0.2], log_s=np.log([0.05, 0.04, 0.03]))  # not flat
    one([-1.5 * R, 0, -0.2], quat=tilt)  # tilted
    one([1.2 * R, 0.3, -0.2])  # would pass, but is in G0
    n = n_good + 7
    scene = GaussianScene(np.concatenate(means), np.concatenate(quats), np.concatenate(scales),
                          np.concatenate(opac), np.zeros((n, 1, 3)))
    g0 = np.zeros(n, bool)
    g0[-1] = True
    s = support_surface(scene, g0, o, R, 2.0 * up, min_splats=20)
    level = np.median(hs)
    spread = 1.4826 * np.median(np.abs(hs - level))
    assert s.n_splats == n_good
    assert s.level == pytest.approx(level, abs=1e-6) and s.spread == pytest.approx(spread, rel=1e-5)
    np.testing.assert_allclose(s.point, o + (level + max(0.05 * R, 2 * spread)) * up, atol=1e-6)
    assert support_surface(scene, g0, o, R, up, min_splats=n_good + 1) is None


@pytest.mark.parametrize("spread, found", [(0.05, True), (0.5, False)])
def test_a_band_reaching_the_object_centre_is_no_support(spread, found):
    """Level splats around the object at a median height 0.8 R below its centre: with a spread of 0.05 R the
    band stops 0.7 R below the centre; spread over 0.5 R (roofs and treetops around a house seen from above)
    the band 2 s would reach past the centre and take in the object's lower half: no support."""
    from seed2gs_inverse.scene import GaussianScene

    rng = np.random.default_rng(5)
    n, o, up = 200, np.zeros(3), np.array([0.0, 0.0, 1.0])
    ang, rad = rng.uniform(0, 2 * np.pi, n), rng.uniform(1.1, 1.9, n)
    hs = -0.8 + rng.uniform(-1.0, 1.0, n) * spread / 0.74  # a uniform on [-w, w]: normalised MAD 0.74 w
    hs = np.clip(hs, -1.95, 1.95)
    scene = GaussianScene(np.c_[rad * np.cos(ang), rad * np.sin(ang), hs], np.tile([1.0, 0, 0, 0], (n, 1)),
                          np.tile(np.log([0.05, 0.04, 0.002]), (n, 1)), np.full(n, 3.0), np.zeros((n, 1, 3)))
    s = support_surface(scene, np.zeros(n, bool), o, 1.0, up)
    if found:
        assert s is not None and s.level == pytest.approx(-0.8, abs=0.02) and (s.point - o) @ up < 0
    else:
        assert s is None
