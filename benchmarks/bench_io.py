"""Read time and peak memory of the scene readers on the real scenes.

Usage::

    python benchmarks/bench_io.py [--repeat 3] [--data DIR]

For each file of ``../shared/data`` (or ``$SEED2GS_DATA``) it prints the best
read time of ``read_scene`` over ``--repeat`` runs, the peak memory traced
during one read (tracemalloc, which sees numpy's buffers; also as a multiple
of the decoded scene's size) and, measured in
the same run, the time of ``np.fromfile`` on the raw bytes: the floor any
reader has to pay for I/O. For the standard PLY files it also times plyfile
(an independent reader) and ``write_scene``. Exits with a message when the
data is absent.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
import plyfile

from seed2gs_inverse.io import read_scene, write_scene

FILES = ["firepit_562k_sh0.ply", "unicorn_49k_sh3.ply", "guitar_90k.compressed.ply", "biker_152k.spz"]


def data_dir(arg) -> Path | None:
    if arg:
        return Path(arg)
    env = os.environ.get("SEED2GS_DATA")
    cand = Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "data"
    return cand if cand.is_dir() else None


def best_time(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def peak_bytes(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--data", help="directory of the real scenes")
    args = ap.parse_args(argv)
    d = data_dir(args.data)
    if d is None or not all((d / f).is_file() for f in FILES):
        print("bench_io: real scenes not found (put them in ../shared/data or set SEED2GS_DATA); "
              "nothing to measure")
        return 0
    print(f"machine: {os.cpu_count()} CPUs, numpy {np.__version__}, best of {args.repeat}")
    head = (f"{'file':<28s} {'MB':>6s} {'Gaussians':>10s} {'read s':>8s} {'raw s':>7s} "
            f"{'ratio':>6s} {'peak MB':>8s} {'peak/scene':>10s}")
    print(head)
    print("-" * len(head))
    extra = []
    for name in FILES:
        path = d / name
        size = path.stat().st_size
        read_scene(path)  # warm the page cache and imports
        t_read = best_time(lambda: read_scene(path), args.repeat)
        t_raw = best_time(lambda: np.fromfile(path, dtype=np.uint8), args.repeat)
        peak = peak_bytes(lambda: read_scene(path))
        scene = read_scene(path)
        n = len(scene)
        decoded = sum(a.nbytes for a in (scene.means, scene.quats, scene.log_scales,
                                         scene.opacity_logits, scene.sh))
        print(f"{name:<28s} {size / 1e6:6.1f} {n:10,d} {t_read:8.3f} {t_raw:7.4f} "
              f"{t_read / t_raw:6.1f} {peak / 1e6:8.1f} {peak / decoded:10.2f}")
        if name.endswith(".ply") and not name.endswith(".compressed.ply"):
            # plyfile memory-maps by default; np.array forces the data to be read.
            t_ply = best_time(lambda: np.array(plyfile.PlyData.read(str(path))["vertex"].data),
                              args.repeat)
            scene = read_scene(path)
            with tempfile.TemporaryDirectory() as tmp:
                out = Path(tmp) / "out.ply"
                t_write = best_time(lambda: write_scene(out, scene), args.repeat)
            extra.append(f"{name}: plyfile read to a structured array {t_ply:.3f} s "
                         f"({t_ply / t_read:.2f}x read_scene's time, which also validates and "
                         f"builds the scene); write_scene {t_write:.3f} s")
    print()
    print("\n".join(extra))
    return 0


if __name__ == "__main__":
    sys.exit(main())
