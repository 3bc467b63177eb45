"""Benchmark of the inverse solvers: cost per iteration and accuracy under mask noise.

Scene: the firepit (562k Gaussians) with the unicorn (49.6k) composited onto
the gravel (as in bench_synthetic.py), so the ground truth is exact. Views:
an orbit around the unicorn (alternating 20 and 40 degrees of elevation,
"up" = -y as in the scene's cameras) rendered by ``build_operator``.
Without the real data a procedural scene (``make_scene``) stands in.

Reports, each with a baseline measured in the same run on the same stack:

* cost: one sparse pass ``A q`` and one transposed pass ``A^T r`` over the
  stack (its own view-by-view passes, which the solvers use; best of 5);
  ``voting`` against one transposed pass;
  ``weighted_bce`` and ``least_squares`` seconds per iteration (and per
  function evaluation) against two passes (load averages printed beside); ``beta_bernoulli`` total time.
  Ratios and per-iteration figures use each method's own seconds
  (``info["seconds_method"]``); the whole ``solve()`` call, which also
  validates the masks and makes the known-weight pass, is printed beside.
* accuracy: for clean masks and every noise model of ``perturb_masks``
  (identity switches jump to a group of background Gaussians next to the
  unicorn), every method side by side: held-out 2D mIoU / mBIoU (every 4th
  view held out, scored against clean truth masks) and 3D IoU (plain and
  visibility-weighted).

Usage::

    NUMBA_NUM_THREADS=2 python benchmarks/bench_solvers.py [--data DIR] [--views 32] [--width 160]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

from seed2gs_inverse.camera import Camera
from seed2gs_inverse.comparison import compare
from seed2gs_inverse.io import read_cameras, read_scene
from seed2gs_inverse.operators import OperatorStack
from seed2gs_inverse.raster import build_operator, render
from seed2gs_inverse.solvers import available_methods, solve
from seed2gs_inverse.synthetic import (NOISE_KINDS, compose, make_scene, masks_from_labels, perturb_masks,
                                       pose_on_point, surface_point)

REPO = Path(__file__).resolve().parents[1]
UP = np.array([0.0, -1.0, 0.0])


def _best(fn, repeat=5):
    times = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def _load() -> str:
    """The 1/5/15-minute load averages: timings on a shared machine need them beside."""
    try:
        return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())
    except (AttributeError, OSError):
        return "load average unknown"


def _orbit(center, radius, n_views, width, height, fov=50.0):
    """Cameras around ``center`` on the ground plane of ``UP``, elevations 20/40 degrees."""
    e1 = np.cross(UP, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(UP, e1)
    cams = []
    for k in range(n_views):
        az = 2 * np.pi * k / n_views
        el = np.radians(20.0 if k % 2 == 0 else 40.0)
        d = np.cos(el) * (np.cos(az) * e1 + np.sin(az) * e2) + np.sin(el) * UP
        cams.append(Camera.look_at(center + radius * d, center, UP, fov, width, height, name=f"orbit_{k:02d}"))
    return cams


def composite_problem(data: Path, n_views: int, width: int):
    fire = read_scene(data / "firepit_562k_sh0.ply")
    uni = read_scene(data / "unicorn_49k_sh3.ply")
    cam = next(c for c in read_cameras(data / "firepit_cameras.json") if c.name == "overview")
    anchor = surface_point(cam, render(fire, cam).depth, (430, 456))
    pose = pose_on_point(uni, anchor, UP, object_up=UP, height=0.9, yaw_deg=200, quantile=0.002)
    scene, labels = compose(fire, [(uni, pose)], remove_overlap=True, margin=0.02)
    truth = labels == 1
    center = anchor + 0.45 * UP
    # "another object" for identity switches: the 30k background Gaussians nearest to a point
    # on the ground one unicorn-height beside it
    side = np.cross(UP, center - cam.center)
    side /= np.linalg.norm(side)
    dist = np.linalg.norm(scene.means - (anchor + 1.0 * side), axis=1)
    dist[truth] = np.inf
    other = np.zeros(len(scene), bool)
    other[np.argsort(dist)[:30000]] = True
    cams = _orbit(center, 2.2, n_views, width, int(round(width * 0.75)))
    return f"firepit+unicorn ({len(scene):,} Gaussians, unicorn {int(truth.sum()):,})", scene, truth, other, cams


def synthetic_problem(n_views: int, width: int):
    s = make_scene(0, n_per_object=4000)
    truth, other = s.object_mask("sphere"), s.object_mask("box")
    cams = s.orbit_cameras(n_views, width, int(round(width * 0.75)), elevation_deg=[20.0, 40.0] * (n_views // 2)
                           + [20.0] * (n_views % 2))
    return f"procedural scene ({len(s.scene):,} Gaussians, sphere {int(truth.sum()):,})", s.scene, truth, other, cams


def bench_cost(stack: OperatorStack, masks):
    # The stack's own passes (view by view, no stacked copy): the path every solver uses.
    rng = np.random.default_rng(0)
    q = rng.random(stack.shape[1]).astype(np.float32)
    r = rng.random(stack.shape[0]).astype(np.float32)
    t_fwd, _ = _best(lambda: stack.matvec(q))
    t_adj, _ = _best(lambda: stack.rmatvec(r))
    two = t_fwd + t_adj
    print(f"\ncost on {len(stack)} views, {stack.shape[0]:,} pixels x {stack.shape[1]:,} Gaussians, "
          f"nnz {stack.nnz:,}")
    print(f"  baseline: A q {1e3 * t_fwd:.1f} ms, A^T r {1e3 * t_adj:.1f} ms, two passes {1e3 * two:.1f} ms")
    print(f"{'method':>15} {'solve s':>8} {'own s':>8} {'iters':>6} {'fevals':>7} {'ms/iter':>8} {'ms/feval':>9} "
          f"{'ratio':>22}")
    variants = [(m, {}) for m in available_methods()] + [("weighted_bce", {"optimizer": "lbfgs"})]
    for m, opts in variants:
        res = solve(stack, masks, method=m, **opts)
        # time the method alone (the second run: caches such as the column sums are warm)
        t0 = time.perf_counter()
        res = solve(stack, masks, method=m, **opts)
        total = time.perf_counter() - t0
        own = float(res.info["seconds_method"])  # the method alone: not the masks' validation in solve()
        it = max(res.iterations, 1)
        fev = res.info.get("function_evaluations", it)
        if m == "voting":
            ratio = f"{own / t_adj:.2f} x one A^T pass"
        elif m in ("weighted_bce", "least_squares"):
            ratio = f"{own / it / two:.2f} x two passes/iter"
        else:
            ratio = f"{own / two:.1f} x two passes total"
        label = m if not opts else "wbce/" + opts["optimizer"]
        print(f"{label:>15} {total:>8.3f} {own:>8.3f} {res.iterations:>6} {fev:>7} {1e3 * own / it:>8.1f} "
              f"{1e3 * own / max(fev, 1):>9.1f} {ratio:>22}")
    print(f"  ({_load()} after the per-iteration timings; the machine may be shared)")
    budget = min(8, len(stack))
    t0 = time.perf_counter()
    res = solve(stack, masks, method="beta_bernoulli", order="eig", budget=budget)
    total = time.perf_counter() - t0
    print(f"beta_bernoulli order='eig', budget {budget}: {total:.2f} s ({total / two:.0f} x two passes), "
          f"order {res.info['order']}")


def bench_noise(stack, truth, other, seed=0):
    clean = masks_from_labels(stack, truth)
    other_masks = masks_from_labels(stack, other)
    methods = available_methods()
    labels = methods + ["wbce/lbfgs"]  # weighted_bce again, with the built-in L-BFGS
    print("\naccuracy (every 4th view held out; 2D scores against clean truth masks)")
    header = f"{'noise':>16} " + " ".join(f"{m[:14]:>30}" for m in labels)
    print(header)
    print(f"{'':>16} " + " ".join(f"{'mIoU  mBIoU  IoU3d wIoU3d':>30}" for _ in labels))
    for kind in ("clean",) + tuple(NOISE_KINDS):
        rng = np.random.default_rng(seed)
        if kind == "clean":
            masks = clean
        elif kind == "identity_switch":
            masks = perturb_masks(clean, kind, rng=rng, other_masks=other_masks)
        else:
            masks = perturb_masks(clean, kind, rng=rng)
        rows = compare(stack, masks, truth, methods=methods, holdout_every=4).rows
        rows += compare(stack, masks, truth, methods=["weighted_bce"], holdout_every=4,
                        options={"weighted_bce": {"optimizer": "lbfgs"}}).rows
        cells = [f"{r['miou']:.3f} {r['mbiou']:.3f} {r['iou3d']:.3f} {r['weighted_iou3d']:.3f}" for r in rows]
        print(f"{kind:>16} " + " ".join(f"{x:>30}" for x in cells))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="directory of the real scenes")
    ap.add_argument("--views", type=int, default=32)
    ap.add_argument("--width", type=int, default=160, help="image width (height = 3/4 of it)")
    ap.add_argument("--synthetic", action="store_true", help="use the procedural scene even with real data")
    ap.add_argument("--cost-only", action="store_true", help="skip the accuracy part")
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', 'unset')}, {_load()}")
    data = Path(args.data or os.environ.get("SEED2GS_DATA") or REPO.parent / "shared" / "data")
    if not args.synthetic and (data / "firepit_562k_sh0.ply").is_file() and (data / "unicorn_49k_sh3.ply").is_file():
        name, scene, truth, other, cams = composite_problem(data, args.views, args.width)
    else:
        if not args.synthetic:
            print(f"real scenes not found in {data}; using the procedural scene")
        name, scene, truth, other, cams = synthetic_problem(args.views, args.width)
    t0 = time.perf_counter()
    stack = OperatorStack([build_operator(scene, c) for c in cams])
    print(f"{name}: {len(cams)} views of {cams[0].width}x{cams[0].height}, operators built in "
          f"{time.perf_counter() - t0:.1f} s; other object for identity switches: {int(other.sum()):,} Gaussians")
    masks = masks_from_labels(stack, truth)
    print(f"unicorn/object mask coverage: {np.mean([m.mean() for m in masks]):.3f} of each view on average")
    bench_cost(stack, masks)
    if not args.cost_only:
        bench_noise(stack, truth, other)


if __name__ == "__main__":
    main()
