"""Orbit axis: axis error and held-out accuracy, ``up="level"`` vs ``up="auto"``.

Cases with exact truth:

* procedural ground-with-clutter scenes (:mod:`seed2gs_inverse.synthetic.ground`):
  grass, fence, wall and bushes of vertical flat Gaussians, objects resting
  on a gently uneven ground, random world rotation; the true up is known;
* the unicorn (``unicorn_49k_sh3.ply``) standing on the firepit patio
  (``firepit_562k_sh0.ply``); the true up is the normal of the patio
  around the anchor, fitted by trimmed least squares on the low points
  (independent of the estimator under test).

For each case the reference is a level look-at camera (no roll) at a given
pitch, the seed is the truth rendered into it, and ``extract()`` runs with
``up="level"`` (a level orbit about the reference camera's up) and ``up="auto"``. Scored on 8
held-out views all around the object (azimuth every 45 degrees, offset
from the pipeline's own, elevations alternating 10 and 40 degrees above the
true ground), never rendered by the pipeline: mIoU, min IoU per view, and
the angle between the orbit axis and the true up.

Usage: ``python benchmarks/bench_up_axis.py [--views 24] [--procedural 3] [--firepit 2] [--axis-only]``
(the firepit cases need ``../shared/data`` or ``$SEED2GS_DATA``; skipped when absent).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(_ROOT))  # this checkout's package, not whichever one is installed

from seed2gs_inverse import Camera  # noqa: E402
from seed2gs_inverse.io import read_camera, read_scene  # noqa: E402
from seed2gs_inverse.metrics import iou  # noqa: E402
from seed2gs_inverse.pipeline import extract  # noqa: E402
from seed2gs_inverse.pipeline.up_axis import estimate_up_axis  # noqa: E402
from seed2gs_inverse.pipeline.up_axis import estimate_up  # noqa: E402
from seed2gs_inverse.raster import build_operator, render  # noqa: E402
from seed2gs_inverse.synthetic import compose, pose_on_point  # noqa: E402
from seed2gs_inverse.synthetic.ground import make_ground_scene  # noqa: E402

DATA = Path(os.environ.get("SEED2GS_DATA", _ROOT.parent / "shared" / "data"))

#: Procedural cases: (seed, object, reference azimuth, reference pitch in degrees).
PROCEDURAL = [(3, "table", 30.0, 30.0), (4, "plush", 200.0, 15.0), (5, "vase", 120.0, 50.0),
              (6, "box", 300.0, 40.0)]
#: Firepit cases: (overview pixel on the patio, unicorn yaw, height, reference azimuth, pitch).
FIREPIT = [((400, 470), 20.0, 0.8, 200.0, 30.0), ((600, 490), -30.0, 0.8, 120.0, 15.0),
           ((340, 430), 60.0, 0.7, 300.0, 55.0)]


def _angle(u, v) -> float:
    u, v = np.asarray(u, float), np.asarray(v, float)
    return float(np.degrees(np.arccos(np.clip(u @ v / np.linalg.norm(u) / np.linalg.norm(v), -1, 1))))


def _basis(up):
    e1 = np.cross(up, np.eye(3)[int(np.argmin(np.abs(up)))])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(up, e1)


def _look(center, up, az, el, dist, w, h, fov=50.0):
    e1, e2 = _basis(up)
    a, e = np.radians(az), np.radians(el)
    d = np.cos(e) * (np.cos(a) * e1 + np.sin(a) * e2) + np.sin(e) * up
    return Camera.look_at(center + dist * d, center, up, fov, w, h)


def _held_out(center, up, dist, ref_az, w=320, h=240):
    return [_look(center, up, ref_az + 22.5 + 45 * k, 10.0 if k % 2 == 0 else 40.0, dist, w, h)
            for k in range(8)]


def _score(scene, truth, selected, cams):
    ious = []
    for c in cams:
        op = build_operator(scene, c)
        t = (op.W @ truth.astype(np.float32)).reshape(c.image_shape) > 0.5
        if t.sum() < 20:
            continue
        p = (op.W @ selected.astype(np.float32)).reshape(c.image_shape) > 0.5
        ious.append(iou(p, t))
    return float(np.mean(ious)), float(np.min(ious)), len(ious)


def _run_case(name, scene, truth, ref, true_up, center, dist, ref_az, args, rows):
    op = build_operator(scene, ref)
    seed = (op.W @ truth.astype(np.float32)).reshape(ref.image_shape) > 0.5
    if seed.sum() < 50:
        print(f"{name}: object hardly visible ({int(seed.sum())} px), skipped")
        return
    # Axis only (cheap): the estimators on the truth support as G0.
    vis = np.asarray(op.W.T @ seed.ravel().astype(np.float32)).ravel() > 0.05
    t0 = time.perf_counter()
    est = estimate_up_axis(scene, ref, support=truth & vis)
    t_est = time.perf_counter() - t0
    old_axis = estimate_up(scene, ref, weights=np.asarray(op.W.sum(axis=0)).ravel())
    line = (f"{name}: seed {int(seed.sum())} px | axis error level {_angle(old_axis, true_up):6.2f} deg, "
            f"auto {_angle(est.axis, true_up):5.2f} deg ({est.method}, confidence {est.confidence:.2f}, "
            f"{t_est:.2f} s)")
    if args.axis_only:
        print(line)
        sys.stdout.flush()
        rows.append((name, _angle(old_axis, true_up), _angle(est.axis, true_up), None, None, None, None))
        return
    held = _held_out(center, true_up, dist, ref_az)
    res = {}
    for up in ("level", "auto"):
        t0 = time.perf_counter()
        ex = extract(scene, ref, seed, n_views=args.views, progress=False, up=up)
        wall = time.perf_counter() - t0
        miou, mn, nv = _score(scene, truth, ex.selected, held)
        res[up] = (_angle(ex.up["axis"], true_up), miou, mn, wall, ex.up["method"])
    print(line + "\n  " + " | ".join(
        f"up={k}: axis {v[0]:5.2f} deg ({v[4]}), held-out mIoU {v[1]:.3f} min {v[2]:.3f}, {v[3]:.1f} s"
        for k, v in res.items()))
    sys.stdout.flush()
    rows.append((name, res["level"][0], res["auto"][0], res["level"][1], res["auto"][1],
                 res["level"][2], res["auto"][2]))


def _ground_normal(means, opac, anchor, rough_up, radius=1.0):
    """Trimmed least-squares plane of the low points around ``anchor`` (rough_up from the data README)."""
    d = means - anchor
    h = d @ rough_up
    lateral = np.linalg.norm(d - np.outer(h, rough_up), axis=1)
    pts = means[(lateral < radius) & (np.abs(h) < 0.15) & (opac > 0.5)]
    keep = np.ones(len(pts), bool)
    for _ in range(6):
        c = pts[keep].mean(axis=0)
        n = np.linalg.svd(pts[keep] - c, full_matrices=False)[2][2]
        res = np.abs((pts - c) @ n)
        keep = res <= max(0.02, np.percentile(res, 50))
    return n if n @ rough_up > 0 else -n, c


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--views", type=int, default=24)
    p.add_argument("--procedural", type=int, default=len(PROCEDURAL))
    p.add_argument("--firepit", type=int, default=len(FIREPIT))
    p.add_argument("--axis-only", action="store_true", help="only the axis errors (no extraction)")
    args = p.parse_args(argv)

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', 'default')}, "
          f"load average {os.getloadavg()[0]:.1f}")
    rows = []
    for seed, obj, az, pitch in PROCEDURAL[: args.procedural]:
        g = make_ground_scene(seed)
        dist = 2.0 + 4 * g.heights[obj]
        ref = g.camera(obj, az, pitch, dist, 480, 360)
        _run_case(f"ground{seed}-{obj} pitch {pitch:.0f}", g.scene, g.object_mask(obj), ref, g.up,
                  g.object_center(obj), dist, az, args, rows)

    if args.firepit and (DATA / "firepit_562k_sh0.ply").is_file():
        firepit = read_scene(DATA / "firepit_562k_sh0.ply")
        unicorn = read_scene(DATA / "unicorn_49k_sh3.ply")
        over = read_camera(str(DATA / "firepit_cameras.json") + ":overview")
        depth = render(firepit, over).depth
        means = firepit.means.astype(np.float64)
        opac = firepit.opacities
        for k, ((px, py), yaw, height, az, pitch) in enumerate(FIREPIT[: args.firepit]):
            ray = np.array([(px + 0.5 - over.cx) / over.fx, (py + 0.5 - over.cy) / over.fy, 1.0])
            anchor = over.rotation.T @ (ray * float(depth[py, px]) - over.translation)
            up, ground_pt = _ground_normal(means, opac, anchor, np.array([0.0, -1.0, 0.0]))
            anchor = anchor - ((anchor - ground_pt) @ up) * up  # onto the fitted ground
            pose = pose_on_point(unicorn, anchor, up, object_up=(0.0, -1.0, 0.0), height=height,
                                 yaw_deg=yaw, quantile=0.01)
            scene, labels = compose(firepit, [(unicorn, pose)], remove_overlap=True)
            truth = labels == 1
            center = anchor + 0.5 * height * up
            dist = 3.0 * height
            ref = _look(center, up, az, pitch, dist, 640, 360)
            _run_case(f"firepit+unicorn{k} pitch {pitch:.0f}", scene, truth, ref, up, center, dist, az,
                      args, rows)
    elif args.firepit:
        print(f"firepit cases skipped: real scenes not found in {DATA} (set SEED2GS_DATA)")

    if not rows:
        return 1
    lv = [r[1] for r in rows]
    au = [r[2] for r in rows]
    print(f"\naxis error over {len(rows)} cases: level mean {np.mean(lv):.2f} max {np.max(lv):.2f} deg; "
          f"auto mean {np.mean(au):.2f} max {np.max(au):.2f} deg")
    if not args.axis_only:
        print(f"held-out mIoU: level {np.mean([r[3] for r in rows]):.3f} (min view "
              f"{np.min([r[5] for r in rows]):.3f}); auto {np.mean([r[4] for r in rows]):.3f} "
              f"(min view {np.min([r[6] for r in rows]):.3f})")
    print(f"load average at the end: {os.getloadavg()[0]:.1f} (other work on the machine inflates wall times)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
