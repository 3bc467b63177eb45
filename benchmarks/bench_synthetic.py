"""Benchmark of the ground-truth machinery: procedural scenes, mask noise, composites.

Reports, each with a baseline measured in the same run:

* ``make_scene`` time for growing ``n_per_object``, against
  ``GaussianScene.transformed`` of the result (one vectorised pass over the
  same Gaussians, SH rotation included);
* ``perturb_masks`` time per view for every noise kind on V masks of
  960x540, against copying the masks (``np.copy`` per view);
* with the real data (``../shared/data`` or ``$SEED2GS_DATA``): the
  firepit + unicorn composite. The unicorn (its up is -y, like the firepit's)
  is stood on the gravel point seen at pixel (430, 456) of the ``overview``
  camera (found with ``surface_point`` on the rendered depth) at height 0.9,
  with ``remove_overlap``. Times ``compose`` against a bare
  ``GaussianScene.concat`` of the same parts, and counts the unicorn's
  ground-truth mask pixels at half resolution. ``--out DIR`` writes
  ``composite_overview.png`` to look at.

Usage::

    NUMBA_NUM_THREADS=2 python benchmarks/bench_synthetic.py [--data DIR] [--views 20] [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np
from PIL import Image

from seed2gs_inverse.io import read_cameras, read_scene
from seed2gs_inverse.raster import build_operator, render
from seed2gs_inverse.scene import GaussianScene
from seed2gs_inverse.synthetic import (NOISE_KINDS, compose, make_scene, masks_from_labels,
                                       perturb_masks, pose_on_point, surface_point)

REPO = Path(__file__).resolve().parents[1]


def _best(fn, repeat=3):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def bench_scenes():
    print("make_scene (best of 3) vs transformed() of the result")
    print(f"{'n_per_object':>13} {'N':>9} {'make_scene s':>13} {'transformed s':>14} {'ratio':>7}")
    rot = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    for n in (400, 4000, 40000):
        t_make, syn = _best(lambda: make_scene(seed=0, n_per_object=n))
        t_base, _ = _best(lambda: syn.scene.transformed(rot, [1, 2, 3], 1.5))
        print(f"{n:>13} {len(syn.scene):>9} {t_make:>13.3f} {t_base:>14.3f} {t_make / t_base:>7.1f}")


def bench_noise(n_views):
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:540, :960]
    masks = [(((yy - 270) / 150.0) ** 2 + ((xx - 480 - 3 * i) / 220.0) ** 2 <= 1).astype(np.float32)
             for i in range(n_views)]
    other = [np.roll(m, 200, axis=1) for m in masks]
    t_copy, _ = _best(lambda: [m.copy() for m in masks])
    print(f"\nperturb_masks on {n_views} masks of 960x540 (best of 3), baseline: copying them "
          f"({1e3 * t_copy / n_views:.3f} ms/view)")
    print(f"{'kind':>16} {'ms/view':>9} {'x copy':>8}")
    for kind in NOISE_KINDS:
        kw = {"other_masks": other} if kind == "identity_switch" else {}
        t, _ = _best(lambda: perturb_masks(masks, kind, rng=rng, fraction=1.0, **kw))
        print(f"{kind:>16} {1e3 * t / n_views:>9.3f} {t / t_copy:>8.1f}")


def bench_composite(data, out):
    fire = read_scene(data / "firepit_562k_sh0.ply")
    uni = read_scene(data / "unicorn_49k_sh3.ply")
    cam = next(c for c in read_cameras(data / "firepit_cameras.json") if c.name == "overview")
    depth = render(fire, cam).depth
    anchor = surface_point(cam, depth, (430, 456))
    up = np.array([0.0, -1.0, 0.0])
    pose = pose_on_point(uni, anchor, up, object_up=up, height=0.9, yaw_deg=200, quantile=0.002)
    t_comp, (scene, labels) = _best(lambda: compose(fire, [(uni, pose)], remove_overlap=True,
                                                    margin=0.02))
    s = np.cbrt(np.linalg.det(pose[:3, :3]))
    t_base, _ = _best(lambda: GaussianScene.concat([fire, uni.transformed(pose[:3, :3] / s, pose[:3, 3], s)]))
    print(f"\ncomposite firepit ({len(fire)}) + unicorn ({len(uni)}) at {np.round(anchor, 3).tolist()}, "
          f"height 0.9, scale {s:.3f}")
    print(f"  compose(remove_overlap=True): {t_comp:.3f} s; baseline transformed+concat: {t_base:.3f} s; "
          f"ratio {t_comp / t_base:.2f}; background Gaussians removed: {len(fire) - int(np.sum(labels == 0))}")
    half = cam.scaled(0.5)
    t0 = time.perf_counter()
    op = build_operator(scene, half)
    t_op = time.perf_counter() - t0
    (mask,) = masks_from_labels([op], labels == 1)
    print(f"  ground-truth unicorn mask at {half.width}x{half.height}: {int(mask.sum())} pixels "
          f"(operator built in {t_op:.2f} s, nnz {op.W.nnz})")
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        rgb = render(scene, cam).rgb
        Image.fromarray((np.clip(rgb, 0, 1) * 255).astype(np.uint8)).save(out / "composite_overview.png")
        print(f"  wrote {out / 'composite_overview.png'}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="directory of the real scenes")
    ap.add_argument("--views", type=int, default=20, help="masks in the noise benchmark")
    ap.add_argument("--out", default=None, help="directory for the composite image")
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', 'unset')}")
    bench_scenes()
    bench_noise(args.views)
    data = Path(args.data or os.environ.get("SEED2GS_DATA") or REPO.parent / "shared" / "data")
    if (data / "firepit_562k_sh0.ply").is_file() and (data / "unicorn_49k_sh3.ply").is_file():
        bench_composite(data, None if args.out is None else Path(args.out))
    else:
        print(f"\ncomposite skipped: real scenes not found in {data} (set --data or SEED2GS_DATA)")


if __name__ == "__main__":
    main()
