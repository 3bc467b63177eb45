"""Benchmark of the rasterizer on a real scene (firepit, 562k Gaussians, SH 0).

Reports, for the ``overview`` camera of ``firepit_cameras.json`` (sees the
whole patio; near plane 0.2 as the reference image):

* warm ``render`` time at 960x540 (median of --repeat runs) and its stages;
* ``build_operator`` time at 480x270, stored bytes per non-zero (data +
  indices) and the row pointers;
* Numba cold-compile time (empty cache, in a subprocess) versus a run that
  loads the cache;
* Gaussian-pixel evaluations per second in the compositing kernel;
* parity with the independent reference rendering (mean absolute difference);
* a baseline measured in the same run: one sparse product ``W @ colors``
  with the operator just built (what applying the operator costs), and the
  ratio of each figure to the project's marks (render < 1 s, operator < 1 s,
  <= 8 bytes per non-zero).

Usage::

    NUMBA_NUM_THREADS=2 python benchmarks/bench_render.py [--data DIR] [--repeat 5]

Exits 0 with a message when the data directory is absent.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

_COLD_SNIPPET = """
import time
t0 = time.perf_counter()
import numpy as np
from seed2gs_inverse.camera import Camera
from seed2gs_inverse.scene import GaussianScene
from seed2gs_inverse.operators.render import build_operator
rng = np.random.default_rng(0)
n = 50
scene = GaussianScene(rng.normal(0, 0.5, (n, 3)), rng.normal(size=(n, 4)), np.full((n, 3), -2.0),
                      np.zeros(n), rng.normal(size=(n, 4, 3)))
cam = Camera.look_at([0, 0, -4], [0, 0, 0], [0, -1, 0], 50, 32, 32)
build_operator(scene, cam)
print(time.perf_counter() - t0)
"""


def _data_dir(arg):
    if arg:
        return Path(arg)
    env = os.environ.get("SEED2GS_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


def _timeit(fn, repeat):
    """Median and best wall time, median CPU time (all threads) and the last result."""
    times, cpu = [], []
    out = None
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return float(np.median(times)), float(np.min(times)), float(np.median(cpu)), out


def _cold_compile():
    """Seconds for import + first tiny build: empty Numba cache, then cached."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        runs = []
        for _ in range(2):
            res = subprocess.run([sys.executable, "-c", _COLD_SNIPPET], env=env, capture_output=True,
                                 text=True, check=True)
            runs.append(float(res.stdout.strip().splitlines()[-1]))
    return runs[0], runs[1]


def _mark(value, target, unit, lower_is_better=True):
    ratio = value / target
    ok = ratio <= 1 if lower_is_better else ratio >= 1
    verdict = "meets" if ok else "misses"
    return f"{verdict} the {target:g} {unit} mark ({ratio:.2f}x of it)"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="directory of the shared scenes (default ../shared/data or $SEED2GS_DATA)")
    ap.add_argument("--repeat", type=int, default=5, help="timed repetitions (median reported)")
    ap.add_argument("--skip-cold", action="store_true", help="skip the cold-compile measurement")
    args = ap.parse_args(argv)
    data = _data_dir(args.data)
    if not (data / "firepit_562k_sh0.ply").is_file():
        print(f"bench_render: firepit_562k_sh0.ply not found in {data}; nothing to measure")
        return 0

    from seed2gs_inverse.camera import Camera
    from seed2gs_inverse.io import read_camera, read_scene
    from seed2gs_inverse.operators.render import _rasterize, build_operator, project_gaussians, render

    threads = os.environ.get("NUMBA_NUM_THREADS", "default")
    load = os.getloadavg()[0]
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"NUMBA_NUM_THREADS={threads}, python {platform.python_version()}, load average {load:.1f}")
    if load > (os.cpu_count() or 1):
        print("  (the machine is busy: wall times are inflated; CPU seconds are the steadier figure)")

    if not args.skip_cold:
        cold, cached = _cold_compile()
        print(f"numba cold compile: {cold:.1f} s (import + first tiny build, empty cache); "
              f"with the cache: {cached:.1f} s; compile cost ~{cold - cached:.1f} s")

    t0 = time.perf_counter()
    scene = read_scene(data / "firepit_562k_sh0.ply")
    c = read_camera(f"{data / 'firepit_cameras.json'}:overview")
    cam = Camera(c.width, c.height, c.fx, c.fy, c.cx, c.cy, c.world_to_camera, c.name, near=0.2)
    print(f"scene: {len(scene)} Gaussians (read in {time.perf_counter() - t0:.2f} s); camera {cam}")

    render(scene, cam)  # warm-up (compiles or loads the Numba cache)
    med, best, cpu, r = _timeit(lambda: render(scene, cam), args.repeat)
    stats = {}
    _rasterize(scene, cam, None, "classic", None, 0.0, False, stats)
    print(f"render 960x540: median {med:.3f} s, best {best:.3f} s ({cpu:.3f} CPU s) -> {_mark(med, 1.0, 's')}")
    print("  stages: project {project_s:.3f} s, depth sort {sort_s:.3f} s, tile binning {bin_s:.3f} s, "
          "composite {composite_s:.3f} s".format(**stats))
    print(f"  {stats['n_binned']} Gaussians binned, {stats['n_pairs']} tile-Gaussian pairs, "
          f"{stats['n_evals']:.3e} Gaussian-pixel evaluations = "
          f"{stats['n_evals'] / stats['composite_s']:.3e} evaluations/s in the compositing kernel")
    ref_path = data / "firepit_overview_reference_rgb.npy"
    if ref_path.is_file():
        ref = np.load(ref_path, allow_pickle=False)
        diff = np.abs(r.rgb - ref)
        print(f"parity with the independent reference: mean |diff| {diff.mean():.2e} "
              f"(aim < 5e-3), max {diff.max():.3f}, pixels off by > 1/255: {(diff.max(-1) > 1 / 255).mean():.3%}")

    small = cam.scaled(0.5)
    build_operator(scene, cam, scale=0.5)  # warm-up
    med_op, best_op, cpu_op, op = _timeit(lambda: build_operator(scene, cam, scale=0.5), args.repeat)
    W = op.W
    per_nnz = (W.data.nbytes + W.indices.nbytes) / W.nnz
    print(f"build_operator {small.width}x{small.height}: median {med_op:.3f} s, best {best_op:.3f} s "
          f"({cpu_op:.3f} CPU s) -> "
          f"{_mark(med_op, 1.0, 's')}")
    print(f"  nnz {W.nnz} ({W.nnz / W.shape[0]:.1f} per pixel), {per_nnz:.1f} bytes per non-zero "
          f"({W.data.dtype} data + {W.indices.dtype} indices) -> {_mark(per_nnz, 8, 'bytes')}; "
          f"row pointers {W.indptr.nbytes / 1e6:.2f} MB ({W.indptr.dtype})")
    colors = project_gaussians(scene, small).colors
    med_mv, _, _, _ = _timeit(lambda: W @ colors, args.repeat)
    print(f"baseline (same run): W @ colors (scipy CSR, {W.nnz} nnz x 3) {med_mv:.3f} s; "
          f"operator build = {med_op / med_mv:.1f} x that product, "
          f"render at 4x the pixels = {med / med_mv:.1f} x")
    print(f"load average at the end: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
