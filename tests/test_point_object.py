"""Point prompts that return the whole object (issue 10, part 3)."""

from __future__ import annotations

import numpy as np
import pytest

from seed2gs_inverse.camera import Camera
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.frontend.prompts import PointPrompt
from seed2gs_inverse.synthetic.ground import make_ground_scene
from seed2gs_inverse.metrics import iou
from seed2gs_inverse.raster import build_operator
from seed2gs_inverse.pipeline.point_object import (depth_normals, grow_object, point_object_mask,
                                                   surface_patch)


@pytest.fixture(scope="module")
def table_view():
    g = make_ground_scene(1)
    cam = g.camera("table", 50, 30, 2.2, 320, 240)
    op = build_operator(g.scene, cam)
    table = g.object_mask("table")
    truth = (op.W @ table.astype(np.float32)).reshape(cam.image_shape) > 0.5
    # The skirt (and the rim under the top): table Gaussians below the top
    # surface and at the rim radius, found from the construction geometry.
    loc = g.to_local(g.scene.means) - g.to_local(g.anchors["table"][None])
    skirt = table & (np.hypot(loc[:, 0], loc[:, 1]) > 0.33) & (loc[:, 2] < 0.53) & (loc[:, 2] > 0.42)
    skirt_px = (op.W @ skirt.astype(np.float32)).reshape(cam.image_shape) > 0.5
    uv, _ = cam.project((g.anchors["table"] + 0.55 * g.up)[None])
    click = tuple(int(v) for v in uv[0])
    return g, cam, op.rendering, truth, skirt_px, click


def test_click_on_the_table_top_returns_top_and_skirt(table_view):
    g, cam, ref, truth, skirt_px, click = table_view
    assert skirt_px.sum() > 300
    po = point_object_mask(g.scene, cam, [click], rendering=ref)
    assert po.mask.shape == cam.image_shape and po.mask[click[1], click[0]]
    assert iou(po.mask, truth) >= 0.8
    assert (po.mask & skirt_px).sum() >= 0.9 * skirt_px.sum()
    # Nothing of the ground or of other objects in 3D either.
    table = g.object_mask("table")
    assert (po.selected & ~table).sum() <= 0.02 * po.selected.sum()
    assert po.info["support"]["source"] == "support_plane" and not po.info["fallback_to_patch"]
    # The colour region of today's PointPrompt misses the skirt: the test can fail.
    old = PointPrompt([click]).to_mask(ref.rgb, depth=ref.depth, alpha=ref.alpha)
    assert (old & skirt_px).sum() < 0.5 * skirt_px.sum()


def test_negative_click_on_the_skirt_keeps_it_out(table_view):
    g, cam, ref, truth, skirt_px, click = table_view
    ys, xs = np.nonzero(skirt_px & ~np.roll(skirt_px, -3, axis=0))  # a skirt pixel
    neg = (int(np.median(xs)), int(ys[np.argmin(np.abs(xs - np.median(xs)))]) - 2)
    po = point_object_mask(g.scene, cam, [click, neg], [1, 0], rendering=ref)
    assert po.mask[click[1], click[0]]
    assert (po.mask & skirt_px).sum() < (point_object_mask(g.scene, cam, [click], rendering=ref).mask
                                         & skirt_px).sum()


@pytest.mark.parametrize("fy_over_fx", [1.0, 1.6])
def test_depth_normals_of_a_plane_match_its_normal(fy_over_fx):
    g = make_ground_scene(2, objects=("box",), clutter=(), uneven=0.0)
    cam = g.camera(g.ground_point, 0, 40, 3.0, 120, 90)
    cam = Camera(cam.width, cam.height, cam.fx, cam.fx * fy_over_fx, cam.cx, cam.cy, cam.world_to_camera)
    # Analytic depth of the ground plane n.(X - p) = 0 along each pixel ray.
    xs = (np.arange(120) + 0.5 - cam.cx) / cam.fx
    ys = (np.arange(90) + 0.5 - cam.cy) / cam.fy
    rays = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None], 1.0), -1)
    n_cam = cam.rotation @ g.ground_normal
    p_cam = cam.world_to_view(g.ground_point[None])[0]
    depth = (n_cam @ p_cam) / (rays @ n_cam)
    n = depth_normals(cam, depth)
    assert np.abs(n.reshape(-1, 3) @ n_cam - 1).max() < 1e-6  # faces the camera (n . up_cam > 0)
    patch = surface_patch(cam, depth, np.ones_like(depth), (60, 45))
    assert patch.all()  # one smooth surface: nothing separates it


def test_grow_object_stops_at_the_plane_and_at_gaps():
    rng = np.random.default_rng(0)
    from seed2gs_inverse.scene import GaussianScene

    floor = np.column_stack([rng.uniform(-1, 1, (1500, 2)), np.zeros(1500)])
    block = rng.uniform([-0.2, -0.2, 0.0], [0.2, 0.2, 0.4], (800, 3))
    far = rng.uniform([0.5, 0.5, 0.0], [0.7, 0.7, 0.3], (300, 3))  # a separate object 0.3 away
    pts = np.concatenate([floor, block, far])
    n = len(pts)
    scene = GaussianScene(pts, np.tile([1.0, 0, 0, 0], (n, 1)), np.full((n, 3), np.log(0.01)),
                          np.full(n, 3.0), np.zeros((n, 1, 3)))
    seeds = np.zeros(n, bool)
    seeds[1500:1520] = True
    sel, info = grow_object(scene, seeds, center=pts[1500:1520].mean(0), radius=2.0,
                            plane=(np.array([0, 0, 1.0]), np.zeros(3), 0.03))
    assert sel[1500:2300][block[:, 2] >= 0.03].all()
    assert not sel[:1500].any() and not sel[2300:].any()
    # Without the plane the floor connects everything.
    sel2, _ = grow_object(scene, seeds, center=pts[1500:1520].mean(0), radius=2.0)
    assert sel2[:1500].mean() > 0.9
    # A plane with most clicked Gaussians below it cuts through the click (a wrong fit): it is set aside
    # instead of removing the seeds, which left nothing to grow from.
    sel3, info3 = grow_object(scene, seeds, center=pts[1500:1520].mean(0), radius=2.0,
                              plane=(np.array([0, 0, 1.0]), np.array([0, 0, 0.5]), 0.03))
    assert info3["plane_rejected"] and sel3[seeds].all() and sel3[1500:2300].all()
    assert "plane_rejected" not in info


def test_validation(table_view):
    g, cam, ref, *_ = table_view
    with pytest.raises(ValidationError, match="outside"):
        point_object_mask(g.scene, cam, [(999, 5)], rendering=ref)
    with pytest.raises(ValidationError, match="labels"):
        point_object_mask(g.scene, cam, [(5, 5)], [0], rendering=ref)
    with pytest.raises(ValidationError, match="unknown options"):
        point_object_mask(g.scene, cam, [(5, 5)], rendering=ref, radius=3)


@pytest.mark.shared_data
def test_firepit_table_click_returns_top_and_skirt(shared_data):
    from seed2gs_inverse.io import read_camera, read_scene
    from seed2gs_inverse.raster import render

    scene = read_scene(shared_data / "firepit_562k_sh0.ply")
    cam = read_camera(str(shared_data / "firepit_cameras.json") + ":overview").scaled(0.5)
    ref = render(scene, cam)
    click = (294, 157)  # the README's (589, 315) at half resolution
    po = point_object_mask(scene, cam, [click], rendering=ref)
    old = PointPrompt([click]).to_mask(ref.rgb, depth=ref.depth, alpha=ref.alpha)
    assert po.mask[click[1], click[0]] and po.info["support"]["source"] == "support_plane"
    ys_new, xs_new = np.nonzero(po.mask)
    ys_old, xs_old = np.nonzero(old)
    # The skirt hangs below the top in the image: the mask reaches further
    # down than the top's colour region, and covers that region.
    assert ys_new.max() >= ys_old.max() + 8
    assert (po.mask & old).sum() >= 0.9 * old.sum()
    # No leak into the patio or the chairs: about the table's size.
    assert po.mask.sum() <= 2.5 * old.sum()
    assert np.ptp(xs_new) <= 1.3 * np.ptp(xs_old)


def test_culling_for_the_projection_keeps_the_weights_exact(table_view):
    # point_object_mask rasterizes its back-projection from raster.cone_cull's subset
    from seed2gs_inverse.raster import cone_cull

    g, cam, *_ = table_view
    for roi in [(100, 60, 220, 180), (0, 0, 40, 30), (300, 200, 320, 240)]:
        full = build_operator(g.scene, cam, roi=roi)
        idx = cone_cull(g.scene, cam, roi)
        assert len(idx) < len(g.scene)
        part = build_operator(g.scene, cam, roi=roi, subset=idx)
        assert abs(full.W - part.W).max() == 0 and full.W.nnz == part.W.nnz


def _bench_scene():
    """A grey ground (z = 0, up +z) and a brown bench 2.0 x 0.3 x 0.3 on it with a white end cap: a click on
    the cap seeds a region a seventh of the bench's length."""
    from seed2gs_inverse.scene import GaussianScene
    from seed2gs_inverse.sh import SH_C0

    rng = np.random.default_rng(0)
    ground = rng.uniform([-2, -2, 0], [2, 2, 0], (20000, 3))
    bench = rng.uniform([-1.0, -0.15, 0.05], [1.0, 0.15, 0.35], (12000, 3))
    cap = bench[:, 0] > 0.8
    means = np.vstack([ground, bench]).astype(np.float32)
    flat = np.tile([0.03, 0.03, 0.003], (20000, 1))
    log_scales = np.log(np.vstack([flat, np.full((12000, 3), 0.025)])).astype(np.float32)
    rgb = np.vstack([np.full((20000, 3), 0.5), np.where(cap[:, None], 0.95, [0.45, 0.25, 0.1])])
    n = len(means)
    scene = GaussianScene(means, np.tile([1.0, 0, 0, 0], (n, 1)).astype(np.float32), log_scales,
                          np.full(n, 4.0, np.float32), ((rgb - 0.5) / SH_C0)[:, None, :].astype(np.float32))
    return scene, np.r_[np.zeros(20000, bool), np.ones(12000, bool)]


def test_growth_region_doubles_until_the_object_closes():
    """A click on the bench's end cap: the first growth region (twice the cap's radius) holds a quarter of
    the bench; doubling it while the object reaches its edge returns most of the bench, and no ground."""
    from seed2gs_inverse.raster import render

    scene, bench = _bench_scene()
    cam = Camera.look_at([0.3, -3.0, 1.6], [0.0, 0.0, 0.2], [0, 0, 1], 50.0, 320, 240)
    ref = render(scene, cam)
    uv, _ = cam.project(np.array([[0.9, -0.15, 0.2]]))
    click = tuple(int(v) for v in uv[0])
    once = point_object_mask(scene, cam, [click], rendering=ref, max_expansions=0)
    po = point_object_mask(scene, cam, [click], rendering=ref)
    assert (once.selected & bench).sum() < 0.35 * bench.sum()
    assert po.info["growth"]["expansions"] >= 2 and (po.selected & bench).sum() >= 0.75 * bench.sum()
    assert not (po.selected & ~bench).any()
    with pytest.raises(ValidationError, match="max_expansions"):
        point_object_mask(scene, cam, [click], rendering=ref, max_expansions=-1)


def test_firepit_chair_click_returns_the_chair_and_the_fire_pit_does_not_leak(shared_data):
    """A click on the right chair's seat grew to a third of the chair before the growth region could
    double; a click on the fire pit returns the pit's ring and logs, not the table beside it (the plane
    fitted through its logs, with the pit under it, is passed over for the ground)."""
    from seed2gs_inverse.io import read_camera, read_scene
    from seed2gs_inverse.raster import render

    scene = read_scene(shared_data / "firepit_562k_sh0.ply")
    cam = read_camera(str(shared_data / "firepit_cameras.json") + ":overview")
    ref = render(scene, cam)
    chair = point_object_mask(scene, cam, [(750, 380)], rendering=ref)
    ys, xs = np.nonzero(chair.mask)
    # the chair-right box of benchmarks/bench_batch.py: (660, 330, 840, 440)
    assert xs.min() <= 670 and xs.max() >= 830 and ys.min() <= 340 and ys.max() >= 430
    assert xs.max() - xs.min() <= 200 and chair.info["growth"]["expansions"] >= 1
    pit = point_object_mask(scene, cam, [(475, 300)], rendering=ref)
    ys, xs = np.nonzero(pit.mask)
    # the ring spans about x 415-535, y 250-345 in this view; the table starts at x 540
    assert xs.min() <= 425 and xs.max() >= 525 and ys.min() <= 260 and ys.max() >= 335
    assert xs.max() <= 545 and xs.min() >= 405 and ys.min() >= 240 and ys.max() <= 350
    assert pit.mask.sum() >= 6000 and "support_plane" in pit.info["support"]["passed_over"]


def test_the_prompts_region_settings_grow_each_click(table_view):
    """extract's object mode passes the PointPrompt itself: its colour_tol, radius, ... were ignored."""
    from seed2gs_inverse.pipeline.extract import seed_from_prompt

    g, cam, ref, truth, skirt_px, click = table_view
    default = point_object_mask(g.scene, cam, [click], rendering=ref)
    wide = point_object_mask(g.scene, cam, [click], rendering=ref,
                             region=PointPrompt([click], color_tol=0.5, radius=10))
    assert wide.info["patch_pixels"] > default.info["patch_pixels"]
    _, info = seed_from_prompt(PointPrompt([click], color_tol=0.5, radius=10), ref, point_mode="object",
                               scene=g.scene, camera=cam)
    assert info["patch_pixels"] == wide.info["patch_pixels"]
    with pytest.raises(ValidationError, match="region must be a PointPrompt"):
        point_object_mask(g.scene, cam, [click], rendering=ref, region={"color_tol": 0.5})


def _chair_scene():
    """A grey ground (z = 0, up +z) and a red chair on it: four legs, a dense seat at z 0.45-0.5 and a
    backrest striped white and blue, so that a click on the backrest seeds one stripe of it."""
    from seed2gs_inverse.scene import GaussianScene
    from seed2gs_inverse.sh import SH_C0

    rng = np.random.default_rng(0)
    ground = rng.uniform([-2, -2, 0], [2, 2, 0], (8000, 3))
    parts = [rng.uniform([-0.3, -0.3, 0.45], [0.3, 0.3, 0.5], (10000, 3))]
    for x in (-0.27, 0.27):
        for y in (-0.27, 0.27):
            parts.append(rng.uniform([x - 0.03, y - 0.03, 0.0], [x + 0.03, y + 0.03, 0.45], (600, 3)))
    back = rng.uniform([-0.3, 0.25, 0.5], [0.3, 0.3, 1.1], (4000, 3))
    chair = np.vstack(parts + [back])
    means = np.vstack([ground, chair]).astype(np.float32)
    flat = np.tile([0.03, 0.03, 0.003], (len(ground), 1))
    log_scales = np.log(np.vstack([flat, np.full((len(chair), 3), 0.02)])).astype(np.float32)
    stripe = (np.floor((back[:, 2] - 0.5) / 0.1) % 2 == 0)[:, None]
    rgb = np.vstack([np.full((len(ground), 3), 0.5), np.full((len(chair) - len(back), 3), [0.8, 0.1, 0.1]),
                     np.where(stripe, [0.9, 0.9, 0.9], [0.2, 0.3, 0.8])])
    n = len(means)
    scene = GaussianScene(means, np.tile([1.0, 0, 0, 0], (n, 1)).astype(np.float32), log_scales,
                          np.full(n, 4.0, np.float32), ((rgb - 0.5) / SH_C0)[:, None, :].astype(np.float32))
    return scene, np.r_[np.zeros(len(ground), bool), np.ones(len(chair), bool)]


def test_click_on_a_chairs_backrest_returns_the_chair_not_the_backrest_above_its_seat(monkeypatch):
    """The plane fitted under a click on the backrest is the seat: growing only above it returned the
    backrest. A plane with the chair's legs and the floor under the seed is no ground and is passed over
    for the floor."""
    from seed2gs_inverse.pipeline import point_object
    from seed2gs_inverse.raster import render

    scene, chair = _chair_scene()
    cam = Camera.look_at([1.2, -2.6, 1.7], [0.0, 0.0, 0.5], [0, 0, 1], 50.0, 320, 240)
    ref = render(scene, cam)
    uv, _ = cam.project(np.array([[0.0, 0.25, 0.9]]))
    click = tuple(int(v) for v in uv[0])
    po = point_object_mask(scene, cam, [click], rendering=ref)
    assert (po.selected & chair).sum() >= 0.95 * chair.sum() and not (po.selected & ~chair).any()
    assert "support_plane" in po.info["support"]["passed_over"]
    truth = (build_operator(scene, cam).W @ chair.astype(np.float32)).reshape(cam.image_shape) > 0.5
    assert iou(po.mask, truth) >= 0.9
    # Without the test the seat is the ground: the test can fail.
    monkeypatch.setattr(point_object, "MAX_BELOW_SHARE", 1.0)
    seat = point_object_mask(scene, cam, [click], rendering=ref)
    assert (seat.selected & chair).sum() < 0.5 * chair.sum()


def _soft_house_scene():
    """A grey ground (z = 0, up +z) and a house 1 x 1 x 0.6 with a dark red gable roof of solid splats and
    light red walls soft as in an aerial capture: nine in ten of their splats are faint (opacity 0.1), yet
    together they render opaque. Labels: 0 ground, 1 walls, 2 roof."""
    from seed2gs_inverse.scene import GaussianScene
    from seed2gs_inverse.sh import SH_C0

    rng = np.random.default_rng(3)
    ground = rng.uniform([-2.5, -2.5, 0], [2.5, 2.5, 0], (12000, 3))
    walls = []
    for side in range(4):
        t, z = rng.uniform(-0.5, 0.5, 6000), rng.uniform(0.02, 0.6, 6000)
        edge = np.full_like(t, -0.5 if side % 2 == 0 else 0.5)
        walls.append(np.c_[t, edge, z] if side < 2 else np.c_[edge, t, z])
    walls = np.vstack(walls)
    u = rng.uniform(-0.55, 0.55, (8000, 2))
    roof = np.c_[u[:, 0], u[:, 1], 0.6 + 0.3 * (1 - np.abs(u[:, 1]) / 0.55)]
    means = np.vstack([ground, walls, roof]).astype(np.float32)
    ng, nw, nr = len(ground), len(walls), len(roof)
    scales = np.vstack([np.tile([0.03, 0.03, 0.003], (ng, 1)), np.full((nw, 3), 0.025), np.full((nr, 3), 0.02)])
    opacity = np.r_[np.full(ng, 0.98), np.where(rng.uniform(size=nw) < 0.1, 0.5, 0.1), np.full(nr, 0.98)]
    rgb = np.vstack([np.full((ng, 3), 0.5), np.full((nw, 3), [0.7, 0.35, 0.25]), np.full((nr, 3), [0.35, 0.12, 0.1])])
    n = len(means)
    scene = GaussianScene(means, np.tile([1.0, 0, 0, 0], (n, 1)).astype(np.float32), np.log(scales).astype(np.float32),
                          np.log(opacity / (1 - opacity)).astype(np.float32),
                          ((rgb - 0.5) / SH_C0)[:, None, :].astype(np.float32))
    return scene, np.r_[np.zeros(ng), np.ones(nw), np.full(nr, 2)].astype(int)


def test_click_on_a_roof_returns_the_soft_walls_too_but_not_the_ground(monkeypatch):
    """The walls' faint splats are no nodes of the growth graph: the click on the roof returned the roof
    and the walls' few solid splats, which do not cover the walls. Each faint splat follows its nearest
    node."""
    from seed2gs_inverse.pipeline import point_object

    scene, lab = _soft_house_scene()
    cam = Camera.look_at([1.6, -2.4, 1.8], [0.0, 0.0, 0.35], [0, 0, 1], 50.0, 320, 240)
    op = build_operator(scene, cam)
    house_px = (op.W @ (lab > 0).astype(np.float32)).reshape(cam.image_shape) > 0.5
    wall_px = (op.W @ (lab == 1).astype(np.float32)).reshape(cam.image_shape) > 0.5
    uv, _ = cam.project(np.array([[0.0, -0.3, 0.6 + 0.3 * (1 - 0.3 / 0.55)]]))
    click = tuple(int(v) for v in uv[0])
    assert wall_px.sum() > 2000 and op.rendering.alpha[wall_px].min() > 0.9  # the walls render solid
    po = point_object_mask(scene, cam, [click], rendering=op.rendering)
    assert iou(po.mask, house_px) >= 0.95 and (po.mask & wall_px).sum() >= 0.95 * wall_px.sum()
    assert not (po.selected & (lab == 0)).any() and po.info["growth"]["n_faint"] > 0
    # Without the faint splats the walls are mostly missing: the test can fail.
    monkeypatch.setattr(point_object, "_attach_faint", lambda *args, **kw: 0)
    solid = point_object_mask(scene, cam, [click], rendering=op.rendering)
    assert (solid.mask & wall_px).sum() < 0.5 * wall_px.sum()
