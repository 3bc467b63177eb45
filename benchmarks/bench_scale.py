"""How one extraction's cost grows with the scene's size and with the object's size.

Scene: the firepit patio with the unicorn composited as in ``bench_speed.py``
(:func:`_common.firepit_unicorn_problem`; about 0.6 M Gaussians; the seed is
the unicorn's mask in the overview camera, 960x540).

* Scene-size rows (``--sizes``, millions of Gaussians): the patio without
  the unicorn is copied and the copies stacked along the patio's up, the
  first one 60 units above the patio's top and each a patio's height plus
  60 units above the last, until the scene has about that many Gaussians.
  No copy is in any view the extraction renders (beside the 60 units, the
  views look down on the patio), so a selection that differs from the
  0.6 M one (``same``) comes from work over the whole scene, not from what
  the views see.
* Object-size rows (``--objects``, at 0.6 M): the unicorn thinned to every
  fifth Gaussian (about 10 k), as it is (about 50 k), or every Gaussian
  repeated with a jitter of half its smallest scale until there are about
  120 k; the seed is the same mask.

Each scene is frozen once (:class:`~seed2gs_inverse.raster.FrozenScene`,
its spatial index built with it: a per-scene cost, printed apart) and
extracted from as a frozen scene. Each row prints the extraction's wall
time and per-stage seconds
(``Extraction.seconds``), the extraction's own peak memory (the peak
resident size ``VmHWM``, reset through ``/proc/self/clear_refs`` just before
the extraction, minus the resident size at that moment, after memory freed
by earlier rows was handed back to the system: the scene's arrays do not
count; ``-`` where Linux does not allow the reset), the number of
Gaussians selected, whether the selection equals the 0.6 M one, a same-run
baseline (one 960x540 render of the 0.6 M scene, median of 3) and the load
average. One extraction of the 0.6 M scene runs first, untimed, so that
every kernel is compiled. A size whose scene would not fit in the memory
available now is skipped with a message.

Usage::

    python benchmarks/bench_scale.py [--sizes 0.6,1.7,4,10] [--objects 10k,50k,120k] [--repeat 1] [--views 24]
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import sys
import time

import numpy as np
from _common import DATA, firepit_unicorn_problem, load_average, median_time, reset_peak

from seed2gs_inverse import GaussianScene
from seed2gs_inverse.pipeline import extract
from seed2gs_inverse.raster import FrozenScene, render

OBJECTS = ("10k", "50k", "120k")
#: Gap between the patio and its first copy, and between copies (world units).
GAP = 60.0


def _proc_kb(field: str) -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    raise RuntimeError(f"{field} not in /proc/self/status")


def _release_free_memory() -> None:
    """Hand memory freed by earlier rows back to the system (glibc ``malloc_trim``; nothing elsewhere), so that
    a row's peak above its starting resident size does not depend on the rows before it."""
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _available_gb() -> float:
    with open("/proc/meminfo") as f:
        for line in f:
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) / 2**20
    return float("nan")


def _tiled(scene: GaussianScene, truth: np.ndarray, up: np.ndarray, millions: float):
    """``scene`` followed by copies of its background stacked along ``up``, about ``millions`` M Gaussians."""
    bg = scene.subset(~truth)
    k = max(0, int(round((millions * 1e6 - len(scene)) / len(bg))))
    if k == 0:
        return scene
    lo, hi = np.percentile(bg.means.astype(np.float64) @ up, [0.5, 99.5])
    step = (hi - lo) + GAP
    copies = [bg.transformed(np.eye(3), up * (step * (i + 1)), 1.0) for i in range(k)]
    return GaussianScene.concat([scene, *copies])


def _object_variant(scene: GaussianScene, truth: np.ndarray, name: str):
    """``(scene, truth)`` with the unicorn thinned (10k), as it is (50k) or repeated with a jitter (120k)."""
    if name == "50k":
        return scene, truth
    obj = np.flatnonzero(truth)
    if name == "10k":
        keep = ~truth
        keep[obj[::5]] = True
        return scene.subset(keep), truth[keep]
    rng = np.random.default_rng(0)
    extra = rng.choice(obj, 120_000 - obj.size, replace=True)
    dup = scene.subset(extra)
    jitter = rng.normal(size=dup.means.shape) * 0.5 * np.exp(dup.log_scales.min(axis=1, keepdims=True))
    dup = GaussianScene(dup.means + jitter, dup.quats, dup.log_scales, dup.opacity_logits, dup.sh,
                        dict(dup.extra), dup.layout)
    return GaussianScene.concat([scene, dup]), np.r_[truth, np.ones(len(dup), bool)]


def _frozen(scene: GaussianScene):
    """``(FrozenScene, seconds)``: the scene frozen with its spatial index built, once per scene."""
    t0 = time.perf_counter()
    frozen = FrozenScene(scene)
    frozen.spatial  # built now, as a per-scene cost, not inside the first extraction
    return frozen, time.perf_counter() - t0


def _run(label, scene, truth, cam, seed, views, base_sel, render_s):
    """One extraction of ``scene`` (a FrozenScene made by :func:`_frozen`): its row as a dict."""
    load0 = load_average()
    _release_free_memory()
    rss0 = _proc_kb("VmRSS")
    reset_ok = reset_peak()
    t0 = time.perf_counter()
    ex = extract(scene, cam, seed, n_views=views, progress=False)
    wall = time.perf_counter() - t0
    peak = (_proc_kb("VmHWM") - rss0) / 2**20 if reset_ok else None
    sel = ex.selected
    same = None
    if base_sel is not None and len(sel) >= len(base_sel) and label.startswith("size"):
        same = bool(np.array_equal(sel[:len(base_sel)], base_sel) and not sel[len(base_sel):].any())
    return {"label": label, "n": len(scene), "n_object": int(truth.sum()), "wall": wall, "freeze": None,
            "stages": dict(ex.seconds), "peak_gb": peak, "selected": int(sel.sum()),
            "true_pos": int((sel & truth).sum()), "same": same, "render_s": render_s,
            "load": (load0, load_average()), "sel": sel}


#: The issue's aims for a tiled scene against the 0.6 M one: extraction time and own peak memory.
SCALE_AIM = 1.3


def _print(r, base=None):
    """Print row ``r``; with ``base`` (the 0.6 M row) also its time and own peak as multiples of the base's."""
    st = ", ".join(f"{k} {v:.2f}" for k, v in r["stages"].items())
    peak = "-" if r["peak_gb"] is None else f"{r['peak_gb']:.2f} GB"
    same = {None: "-", True: "yes", False: "NO"}[r["same"]]
    freeze = "" if r["freeze"] is None else f"freeze + index {r['freeze']:.2f} s (once per scene) | "
    print(f"{r['label']:>10} | N {r['n'] / 1e6:5.2f} M, object {r['n_object'] / 1e3:5.1f} k | {freeze}extraction "
          f"{r['wall']:6.2f} s = {r['wall'] / r['render_s']:5.1f} renders (render {r['render_s']:.3f} s) | {st} | "
          f"peak {peak} | selected {r['selected']} ({r['true_pos']} of the object), same as 0.6 M: {same} | "
          f"load {r['load'][0]:.1f} -> {r['load'][1]:.1f}")
    if base is not None and base is not r:
        mem = ("-" if r["peak_gb"] is None or not base["peak_gb"] else f"{r['peak_gb'] / base['peak_gb']:.2f}x")
        print(f"{'':>10} | against 0.6 M: extraction {r['wall'] / base['wall']:.2f}x, own peak {mem} "
              f"[aims <= {SCALE_AIM}x each]")
    sys.stdout.flush()


def _floats(text: str) -> list:
    try:
        out = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise SystemExit(f"--sizes must be numbers (millions of Gaussians) separated by commas, got {text!r}")
    if not out or any(not (v > 0) for v in out):
        raise SystemExit(f"--sizes must be positive numbers, got {text!r}")
    return out


def _objects(text: str) -> list:
    out = [v.strip() for v in text.split(",") if v.strip()]
    bad = [v for v in out if v not in OBJECTS]
    if bad:
        raise SystemExit(f"--objects takes {', '.join(OBJECTS)} (or ''), got {', '.join(bad)}")
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="0.6,1.7,4,10", help="scene sizes in millions of Gaussians (commas)")
    p.add_argument("--objects", default=",".join(OBJECTS), help="object sizes at 0.6 M: 10k, 50k, 120k ('' none)")
    p.add_argument("--repeat", type=int, default=1, help="extractions per row (each printed)")
    p.add_argument("--views", type=int, default=24, help="n_views of extract()")
    a = p.parse_args(argv)
    sizes, objects = _floats(a.sizes), _objects(a.objects)
    if a.repeat < 1 or a.views < 1:
        raise SystemExit("--repeat and --views must be >= 1")
    if not (DATA / "firepit_562k_sh0.ply").is_file():
        print(f"bench_scale: real scenes not found in {DATA}; set SEED2GS_DATA. Skipped.")
        return 0
    scene, truth, cam, seed, up, _ = firepit_unicorn_problem(a.views)
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    print(f"machine: load average {load_average():.1f}, {_available_gb():.1f} GB available; base scene "
          f"{len(scene)} Gaussians ({int(truth.sum())} of the unicorn)")
    extract(scene, cam, seed, n_views=a.views, progress=False)  # warm-up: every kernel compiled
    base_sel, base_row = None, None
    bytes_per = sum(arr.nbytes for arr in (scene.means, scene.quats, scene.log_scales, scene.opacity_logits,
                                           scene.sh)) / len(scene)
    for size in sorted(sizes):
        # The tiled scene, the concatenation's temporaries and the frozen scene's activations (72 B each).
        need = size * 1e6 * (2.5 * bytes_per + 72) / 2**30
        if need > 0.8 * _available_gb():
            print(f"{'size ' + str(size):>10} | skipped: needs about {need:.1f} GB, {_available_gb():.1f} GB "
                  "available")
            continue
        tiled = _tiled(scene, truth, up, size)
        t_truth = np.r_[truth, np.zeros(len(tiled) - len(scene), bool)]
        frozen, freeze_s = _frozen(tiled)
        for k in range(a.repeat):
            render_s = median_time(lambda: render(scene, cam), 3)
            r = _run(f"size {size:g}", frozen, t_truth, cam, seed, a.views, base_sel, render_s)
            r["freeze"] = freeze_s if k == 0 else None
            if base_sel is None and len(tiled) == len(scene):
                base_sel, base_row = r["sel"], r
            _print(r, base_row)
        del tiled, frozen
    for name in objects:
        o_scene, o_truth = _object_variant(scene, truth, name)
        frozen, freeze_s = _frozen(o_scene)
        for k in range(a.repeat):
            render_s = median_time(lambda: render(scene, cam), 3)
            r = _run(f"object {name}", frozen, o_truth, cam, seed, a.views, None, render_s)
            r["freeze"] = freeze_s if k == 0 else None
            _print(r)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
