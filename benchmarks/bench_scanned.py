"""Objects scanned alone, boxed whole: how much of the object the remainder keeps.

Every Gaussian of a scanned-alone object (the shared guitar on its stand,
the biker, the unicorn plush) is the object, so whatever the extraction
leaves unselected is a ghost. Each object is framed by a level camera at
20 degrees of pitch and 30 degrees of azimuth about its up, 2.6 radii away
(640x480); the prompt is the box around its rendered alpha > 0.3, and
``extract()`` runs with the options given (default settings: the orbit axis
is estimated, not given).

Scored on 8 views all around that the extraction never rendered (azimuths
13 + 45k degrees, elevations 5 and 20 degrees, 320x240):

* ``weight``: the remainder's share of the compositing weight of the whole
  scene, ``sum W(c) 1_rem / sum W(c) 1``, over the views (its worst view
  beside it): what the remainder holds where it is visible;
* ``alone``: the alpha of the remainder rendered alone over the alpha of
  the whole object, over the views: it also sees inner and back layers,
  which carry no weight while the object stands in front of them;
* ``est``: the extraction's own truth-free estimate
  (``Extraction.remainder_summary``, ``metrics.remainder_share``).

The machine load is printed at the start and the end.

Usage::

    python benchmarks/bench_scanned.py [--objects guitar,biker,unicorn] [--set KEY=VALUE ...]

``--set`` as in ``bench_extract.py`` (``tracker.NAME=VALUE`` builds a
``GeometricTracker`` with those keywords).
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

from _common import DATA, alone_alpha_share, extract_kwargs, parse_set  # noqa: E402

from seed2gs_inverse import Camera, build_operator, extract, read_scene, render  # noqa: E402
from seed2gs_inverse.frontend.prompts import BoxPrompt  # noqa: E402

#: file, up in the object's own coordinates
OBJECTS = {"guitar": ("guitar_90k.compressed.ply", (0.0, -1.0, 0.0)),
           "biker": ("biker_152k.spz", (0.0, 1.0, 0.0)),
           "unicorn": ("unicorn_49k_sh3.ply", (0.0, -1.0, 0.0))}
#: held-out views: azimuth offsets and elevations (degrees)
VIEWS = [(13 + 45 * k, 5 if k % 2 == 0 else 20) for k in range(8)]


class Framed:
    """An object with its frame (centre, radius, up and two horizontal axes) and look-at cameras about it."""

    def __init__(self, scene, up):
        self.scene = scene
        self.up = np.asarray(up, np.float64) / np.linalg.norm(up)
        m = scene.means.astype(np.float64)
        lo, hi = np.quantile(m, 0.005, axis=0), np.quantile(m, 0.995, axis=0)
        self.center, self.radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
        a = np.array([1.0, 0.0, 0.0]) if abs(self.up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        self.e1 = a - (a @ self.up) * self.up
        self.e1 /= np.linalg.norm(self.e1)
        self.e2 = np.cross(self.up, self.e1)

    def look(self, az: float, el: float, w: int, h: int) -> Camera:
        a, e = np.radians(az), np.radians(el)
        d = np.cos(e) * (np.cos(a) * self.e1 + np.sin(a) * self.e2) + np.sin(e) * self.up
        return Camera.look_at(self.center + 2.6 * self.radius * d, self.center, self.up, 50.0, w, h)


def run_object(name: str, options: dict) -> dict:
    path, up = OBJECTS[name]
    obj = Framed(read_scene(DATA / path), up)
    cam = obj.look(30.0, 20.0, 640, 480)
    ys, xs = np.nonzero(render(obj.scene, cam).alpha > 0.3)
    box = (int(xs.min()) - 5, int(ys.min()) - 5, int(xs.max()) + 6, int(ys.max()) + 6)
    t0 = time.perf_counter()
    ex = extract(obj.scene, cam, BoxPrompt(box), progress=False, **extract_kwargs(options, obj.up))
    seconds = time.perf_counter() - t0
    rem = ~ex.selected
    rem_w, all_w = [], []
    views = [obj.look(30.0 + daz, el, 320, 240) for daz, el in VIEWS]
    for view in views:
        w = np.asarray(build_operator(obj.scene, view).W.sum(axis=0)).ravel()
        rem_w.append(float(w[rem].sum()))
        all_w.append(float(w.sum()))
    weight = sum(rem_w) / sum(all_w)
    worst = max(r / a for r, a in zip(rem_w, all_w))
    alone, _ = alone_alpha_share(obj.scene, views, rem, np.ones(len(obj.scene), bool))
    return {"n": len(obj.scene), "selected": int(ex.selected.sum()), "weight": weight, "worst": worst,
            "alone": alone,
            "est": ex.remainder_summary()["share"], "seconds": seconds}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--objects", default=",".join(OBJECTS), help="comma-separated: " + ", ".join(OBJECTS))
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="extract() keyword (repeatable)")
    args = p.parse_args(argv)
    names = [s.strip() for s in args.objects.split(",") if s.strip()]
    bad = [n for n in names if n not in OBJECTS]
    if bad:
        print(f"bench_scanned: unknown object(s) {bad}; choose from {list(OBJECTS)}")
        return 2
    missing = [OBJECTS[n][0] for n in names if not (DATA / OBJECTS[n][0]).is_file()]
    if missing:
        print(f"bench_scanned: shared data not found in {DATA} ({', '.join(missing)}; set SEED2GS_DATA): skipped")
        return 0
    options = parse_set(args.set)
    load0 = os.getloadavg()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', 'default')}, load average at start "
          f"{load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}")
    print(f"extract options: {options or 'defaults'}")
    print(f"{'object':<8} {'N':>7} {'selected':>8}  remainder: {'weight':>7} {'(worst)':>8} {'alone':>7} "
          f"{'est':>7}  {'s':>6}")
    rows = []
    for name in names:
        r = run_object(name, options)
        rows.append(r)
        print(f"{name:<8} {r['n']:>7} {r['selected']:>8}             {r['weight']:7.1%} {r['worst']:8.1%} "
              f"{r['alone']:7.1%} {r['est']:7.1%}  {r['seconds']:6.1f}", flush=True)
    print(f"{'mean':<8} {'':>7} {'':>8}             {np.mean([r['weight'] for r in rows]):7.1%} "
          f"{np.mean([r['worst'] for r in rows]):8.1%} {np.mean([r['alone'] for r in rows]):7.1%}")
    print("aim: weight <= 2.0% per object, <= 5.0% in its worst view")
    load1 = os.getloadavg()
    print(f"load average at the end: {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
