"""Box prompts that return one object: the GrabCut seed cleaned to the box's main object in 3D."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from seed2gs_inverse import Camera, GaussianScene
from seed2gs_inverse.cli._extract import seed_summary_line
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.frontend.prompts import BoxPrompt, MaskPrompt
from seed2gs_inverse.pipeline import extract
from seed2gs_inverse.pipeline.box_object import box_object_mask
from seed2gs_inverse.pipeline.point_object import linked_components
from seed2gs_inverse.pipeline.report import seed_summary
from seed2gs_inverse.raster import build_operator, render
from seed2gs_inverse.synthetic.ground import make_ground_scene

from _pipeline_scenes import reference_camera, sphere_scene, surface


def _truth_pixels(op, selected, shape):
    return (op.W @ selected.astype(np.float32)).reshape(shape) > 0.5


@pytest.fixture(scope="module")
def table_and_box():
    """A table with a box behind it and to one side: the box around the table takes in part of the box."""
    g = make_ground_scene(0, objects=("table", "box"), clutter=())
    d = g.to_local(g.anchors["box"][None])[0] - g.to_local(g.anchors["table"][None])[0]
    cam = g.camera("table", np.degrees(np.arctan2(d[1], d[0])) + 190, 25, 2.5, 160, 120)
    op = build_operator(g.scene, cam)
    table, other = g.object_mask("table"), g.object_mask("box")
    a_px = _truth_pixels(op, table, cam.image_shape)
    b_px = _truth_pixels(op, other, cam.image_shape)
    ys, xs = np.nonzero(a_px)
    box = [int(xs.min()) - 3, int(ys.min()) - 3, int(xs.max()) + 4, int(ys.max()) + 4]
    return g, cam, op.rendering, box, table, other, a_px, b_px


def test_grabcut_seed_takes_in_the_neighbour_and_the_cleaning_drops_it(table_and_box):
    g, cam, ref, box, table, other, a_px, b_px = table_and_box
    grabcut = BoxPrompt(box).to_mask(ref.rgb, alpha=ref.alpha)
    # the premise: GrabCut alone keeps the neighbour's pixels inside the box
    assert (grabcut & b_px).sum() >= 40
    bo = box_object_mask(g.scene, cam, grabcut, ref.depth, box)
    assert bo.info["cleaned"] is True and bo.info["n_dropped_pixels"] == int((grabcut & ~bo.mask).sum())
    assert (bo.mask & b_px).sum() <= 0.3 * (grabcut & b_px).sum()  # what is left: pixels mixed at its edge
    assert (bo.mask & a_px).sum() >= 0.98 * (grabcut & a_px).sum()  # the table stays whole (legs too)
    assert not (bo.kept & other).any() and (bo.dropped & other).any()


def test_box_with_part_of_a_neighbour_returns_the_main_object_only(table_and_box):
    g, cam, ref, box, table, other, a_px, b_px = table_and_box
    ex = extract(g.scene, cam, BoxPrompt(box), progress=False)
    sel = ex.selected
    print("box prompt: selected", int(sel.sum()), "table", int((sel & table).sum()), "of", int(table.sum()),
          "neighbour", int((sel & other).sum()), "of", int(other.sum()))
    assert (sel & other).sum() <= 0.01 * other.sum()  # the neighbour is not selected
    assert (sel & table).sum() / sel.sum() >= 0.95  # precision against the truth
    assert (sel & table).sum() >= 0.8 * table.sum()
    assert ex.prompt_info["kind"] == "box" and ex.prompt_info["n_dropped_pixels"] > 0
    json.dumps(ex.prompt_info)  # report.json records it as it is


def test_box_around_a_single_object_is_unchanged():
    scene, labels, info = sphere_scene(seed=2)
    cam = reference_camera(info, width=128, height=96)
    op = build_operator(scene, cam)
    px = _truth_pixels(op, labels, cam.image_shape)
    ys, xs = np.nonzero(px)
    box = [int(xs.min()) - 4, int(ys.min()) - 4, int(xs.max()) + 5, int(ys.max()) + 5]
    ref = op.rendering
    grabcut = BoxPrompt(box).to_mask(ref.rgb, alpha=ref.alpha)
    bo = box_object_mask(scene, cam, grabcut, ref.depth, box)
    assert bo.info["cleaned"] is True and bo.info["n_dropped_pixels"] <= 0.01 * grabcut.sum()
    # the whole extraction as with the GrabCut seed given as a mask (what a box did before)
    a = extract(scene, cam, BoxPrompt(box), progress=False)
    b = extract(scene, cam, MaskPrompt(grabcut), progress=False)
    assert (a.selected != b.selected).sum() <= 0.01 * b.selected.sum()


def test_validation(table_and_box):
    g, cam, ref, box, *_ = table_and_box
    m = np.zeros(cam.image_shape, bool)
    m[50:60, 50:60] = True
    with pytest.raises(ValidationError, match="unknown options"):
        box_object_mask(g.scene, cam, m, ref.depth, spread=2)
    with pytest.raises(ValidationError, match="gap"):
        box_object_mask(g.scene, cam, m, ref.depth, gap=-1)
    with pytest.raises(ValidationError, match="k_neighbors"):
        box_object_mask(g.scene, cam, m, ref.depth, k_neighbors=0)
    with pytest.raises(ValidationError, match="shape"):
        box_object_mask(g.scene, cam, m[:-1], ref.depth)
    with pytest.raises(ValidationError, match="box"):
        box_object_mask(g.scene, cam, m, ref.depth, (5, 5, np.nan, 9))
    with pytest.raises(ValidationError, match="empty"):
        box_object_mask(g.scene, cam, np.zeros_like(m), ref.depth)
    # a seed on nothing is left as it is, saying why
    sky = np.zeros_like(m)
    sky[0, 0] = True
    bo = box_object_mask(g.scene, cam, sky, np.zeros(cam.image_shape))
    assert bo.mask is not None and bo.mask.sum() == 1 and bo.info["cleaned"].startswith("not cleaned")


def test_report_and_printed_line_say_what_the_box_seed_left_out():
    seed = np.zeros((40, 60), bool)
    seed[10:20, 20:40] = True
    ex = SimpleNamespace(seed_mask=seed, prompt_info={"kind": "box", "cleaned": True, "n_dropped_pixels": 85})
    ex._object_rendering = (np.zeros((40, 60, 3), np.float32), seed.astype(np.float32))
    s = seed_summary(ex)
    assert s["dropped_pixels"] == 85
    assert seed_summary_line(s).endswith("; 85 px of other objects and ground left out of the box's seed")
    ex.prompt_info = {"kind": "box", "cleaned": "not cleaned: it would leave nothing", "n_dropped_pixels": 0}
    assert seed_summary(ex)["dropped_pixels"] is None
    ex.prompt_info = {"kind": "mask"}
    assert "left out" not in seed_summary_line(seed_summary(ex))


def test_an_object_scanned_alone_keeps_its_detached_parts():
    """No ground, and a part apart from the body in 3D (a ball held above it): the box holds both, nothing leaves."""
    rng = np.random.default_rng(3)

    def ball(center, radius, n, color):
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return surface(np.asarray(center) + radius * d, d, radius * 2.2 / np.sqrt(n), np.tile(color, (n, 1)))

    body = ball((0.0, 0.0, 0.0), 0.5, 900, (0.8, 0.3, 0.2))
    part = ball((0.0, -0.45, 0.75), 0.18, 200, (0.8, 0.3, 0.2))  # beside the body, 0.2 from it
    scene = GaussianScene.concat([body, part])
    cam = Camera.look_at((2.6, -1.0, 0.4), (0.0, -0.2, 0.0), (0.0, -1.0, 0.0), 45, 128, 96)
    ref = render(scene, cam)
    ys, xs = np.nonzero(ref.alpha > 0.5)
    box = [int(xs.min()) - 4, int(ys.min()) - 4, int(xs.max()) + 5, int(ys.max()) + 5]
    grabcut = BoxPrompt(box).to_mask(ref.rgb, alpha=ref.alpha)
    bo = box_object_mask(scene, cam, grabcut, ref.depth, box)
    assert bo.info["n_components"] >= 2  # the part is apart in 3D
    assert bo.info["n_dropped_pixels"] == 0 and np.array_equal(bo.mask, grabcut)


def test_linked_components_checks_its_input():
    scene, _, _ = sphere_scene(seed=0, n_sphere=50, n_ground=100)
    with pytest.raises(ValidationError, match="idx"):
        linked_components(scene, np.array([3]), np.array([True]))
    with pytest.raises(ValidationError, match="idx"):
        linked_components(scene, np.array([0, len(scene)]), np.array([True, True]))
    with pytest.raises(ValidationError, match="ref_nodes"):
        linked_components(scene, np.array([0, 1, 2]), np.array([False, False, False]))
    labels, n, link = linked_components(scene, np.arange(len(scene)), np.ones(len(scene), bool))
    assert labels.shape == (len(scene),) and n >= 1 and link > 0


def _drum_and_neighbour_scene(grey_foot: float = 0.0):
    """A grey ground (z = 0, up +z), a brown drum (radius 0.4, 0.3 tall) and, behind it to the right, a
    taller white cylinder 0.15 from it. Labels: 0 ground, 1 drum, 2 the neighbour. The drum's wall below
    ``grey_foot`` has the ground's grey."""
    from seed2gs_inverse.sh import SH_C0

    rng = np.random.default_rng(1)

    def cylinder(n, r, z0, z1, cx, cy):
        a = rng.uniform(0, 2 * np.pi, n)
        return np.c_[cx + r * np.cos(a), cy + r * np.sin(a), rng.uniform(z0, z1, n)]

    def disk(n, r, z, cx, cy):
        a, rr = rng.uniform(0, 2 * np.pi, n), r * np.sqrt(rng.uniform(0, 1, n))
        return np.c_[cx + rr * np.cos(a), cy + rr * np.sin(a), np.full(n, z)]

    ground = rng.uniform([-2.5, -2.5, 0], [2.5, 2.5, 0], (12000, 3))
    drum = np.vstack([cylinder(6000, 0.4, 0.0, 0.3, 0, 0), disk(3000, 0.4, 0.3, 0, 0)])
    other = np.vstack([cylinder(5000, 0.35, 0.0, 0.9, 0.6, 0.8), disk(3000, 0.35, 0.9, 0.6, 0.8)])
    means = np.vstack([ground, drum, other]).astype(np.float32)
    ng, nd, no = len(ground), len(drum), len(other)
    scales = np.vstack([np.tile([0.03, 0.03, 0.003], (ng, 1)), np.full((nd + no, 3), 0.02)])
    rgb = np.vstack([np.full((ng, 3), 0.5), np.full((nd, 3), [0.55, 0.3, 0.15]), np.full((no, 3), 0.92)])
    rgb[ng:ng + nd][drum[:, 2] < grey_foot] = 0.5
    n = len(means)
    scene = GaussianScene(means, np.tile([1.0, 0, 0, 0], (n, 1)).astype(np.float32),
                          np.log(scales).astype(np.float32), np.full(n, 4.0, np.float32),
                          ((rgb - 0.5) / SH_C0)[:, None, :].astype(np.float32))
    return scene, np.r_[np.zeros(ng), np.ones(nd), np.full(no, 2)].astype(int)


def test_a_neighbour_the_box_cuts_is_dropped_where_the_seed_stops_short_of_the_edge(monkeypatch):
    """GrabCut often stops a few pixels short of the box's edge on a neighbour that crosses it: its part
    in the seed then touched no edge pixel and stayed. The neighbour, followed over every Gaussian that
    renders in the box, crosses the edge and leaves the seed; the drum stays whole."""
    from seed2gs_inverse.pipeline import box_object

    scene, lab = _drum_and_neighbour_scene()
    cam = Camera.look_at([0.0, -2.6, 1.1], [0.0, 0.0, 0.2], [0, 0, 1], 50.0, 320, 240)
    op = build_operator(scene, cam)
    drum_px = _truth_pixels(op, lab == 1, cam.image_shape)
    other_px = _truth_pixels(op, lab == 2, cam.image_shape)
    ys, xs = np.nonzero(drum_px)
    box = (int(xs.min()) - 4, int(ys.min()) - 4, int(xs.max()) + 5, int(ys.max()) + 5)
    inner = np.zeros(cam.image_shape, bool)
    inner[box[1] + 6:box[3] - 6, box[0] + 6:box[2] - 6] = True
    seed = drum_px | (other_px & inner)  # a seed that stops 6 px short of the box's edge
    assert (seed & other_px).sum() >= 40 and other_px[box[1]:box[3], box[0]:box[2]].sum() > 200
    bo = box_object_mask(scene, cam, seed, op.rendering.depth, box)
    assert (bo.mask & other_px).sum() <= 0.05 * (seed & other_px).sum()
    assert (bo.mask & drum_px).sum() >= 0.98 * drum_px.sum()
    assert not (bo.kept & (lab == 2)).any()
    # Judged by the seed's own pixels at the edge, the neighbour stays: the test can fail.
    monkeypatch.setattr(box_object, "_cut_beyond_seed", lambda *args, **kw: np.zeros(args[3], bool))
    old = box_object_mask(scene, cam, seed, op.rendering.depth, box)
    assert (old.mask & other_px).sum() >= 0.9 * (seed & other_px).sum()


def test_the_box_seed_takes_back_the_parts_of_its_object_grabcut_left_out(monkeypatch):
    """GrabCut separates by colour alone: the drum's foot, of the ground's grey, is left out of its seed.
    Linked to the drum in 3D (above the ground's band), it comes back; the ground and the neighbour do not."""
    from seed2gs_inverse.pipeline import box_object

    scene, lab = _drum_and_neighbour_scene(grey_foot=0.12)
    cam = Camera.look_at([0.0, -2.6, 1.1], [0.0, 0.0, 0.2], [0, 0, 1], 50.0, 320, 240)
    op = build_operator(scene, cam)
    drum_px = _truth_pixels(op, lab == 1, cam.image_shape)
    ys, xs = np.nonzero(drum_px)
    box = (int(xs.min()) - 4, int(ys.min()) - 4, int(xs.max()) + 5, int(ys.max()) + 5)
    ref = op.rendering
    grabcut = BoxPrompt(box).to_mask(ref.rgb, alpha=ref.alpha)
    missed = drum_px & ~grabcut
    assert missed.sum() >= 0.05 * drum_px.sum()  # the premise: GrabCut leaves the grey foot out
    bo = box_object_mask(scene, cam, grabcut, ref.depth, box)
    print("drum px", int(drum_px.sum()), "grabcut missed", int(missed.sum()), "now missed",
          int((drum_px & ~bo.mask).sum()), "added", bo.info["n_added_pixels"],
          "outside the drum", int((grabcut & ~drum_px).sum()), "->", int((bo.mask & ~drum_px).sum()))
    assert (drum_px & ~bo.mask).sum() <= 0.25 * missed.sum()
    assert (bo.mask & ~drum_px).sum() <= (grabcut & ~drum_px).sum() + 0.01 * drum_px.sum()
    assert bo.info["n_added_pixels"] == int((bo.mask & ~grabcut).sum())
    # Without taking back what the main object renders in the box, the foot stays out: the test can fail.
    with monkeypatch.context() as mp:
        mp.setattr(box_object, "_main_in_box", lambda W, box, shape, *a: np.zeros(shape, bool))
        old = box_object_mask(scene, cam, grabcut, ref.depth, box)
        assert (drum_px & ~old.mask).sum() >= 0.9 * missed.sum()
    # Without a ground plane the ground links the drum to all around it: nothing is taken back.
    monkeypatch.setattr(box_object, "support_plane", lambda *a: (None, {"source": None}))
    flat = box_object_mask(scene, cam, grabcut, ref.depth, box)
    assert flat.info["n_added_pixels"] == 0 and not (flat.mask & ~grabcut).any()
