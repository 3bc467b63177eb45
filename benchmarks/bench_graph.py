"""Building the Gaussian affinity graph, against the straightforward formula in the same run.

The model-free pipeline builds :func:`~seed2gs_inverse.graph.gaussian_graph`
over the Gaussians within three lift radii of the object (on a second
thread, beside the tracker). For a large object that is most of the scene:
the fire pit of the firepit scene (``seed2gs extract --box 415 250 535 338``
in the overview camera) gives a graph of about 514k nodes and 5 M edges,
and the graph was the longest part of that extraction's tracking stage.

Printed for regions of growing size about the fire pit (the whole scene
last): nodes, edges, the median seconds of ``gaussian_graph`` and of
:func:`reference_graph` (the formula written out directly, one temporary
per operation, a median-split k-d tree and a COO assembly: the library's
implementation before it was rewritten in place), their ratio, and the
largest relative difference of the weights (the edges must be the same).
The load average is printed at the start and the end.

Usage::

    python benchmarks/bench_graph.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from seed2gs_inverse.graph import gaussian_graph
from seed2gs_inverse.io import read_scene
from seed2gs_inverse.scene import quat_to_rotmat
from seed2gs_inverse.sh import SH_C0

DATA = Path(os.environ.get("SEED2GS_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
# the fire pit's centre in the firepit scene's frame (the seed lift of the box prompt above)
FIRE_PIT = (-0.372, 1.530, -0.687)


def reference_graph(scene, k, subset, sigma_color=0.1, sigma_normal=0.2):
    """The graph of the module docstring of :mod:`seed2gs_inverse.graph`, written out directly."""
    n, idx = len(scene), np.asarray(subset)
    m = idx.size
    x = scene.means[idx].astype(np.float64)
    dist, nb = cKDTree(x).query(x, k=k + 1, workers=2)
    dist, nb = dist[:, 1:], nb[:, 1:]
    rho = np.maximum(dist[:, -1], 1e-12 + 1e-6 * float(np.median(dist[:, -1])))
    rows, cols, d = np.repeat(np.arange(m), k), nb.ravel(), dist.ravel()
    logw = -(d ** 2) / (rho[rows] * rho[cols])
    rgb = np.clip(0.5 + SH_C0 * scene.sh[idx, 0, :].astype(np.float64), 0.0, 1.0)
    logw -= np.sum((rgb[rows] - rgb[cols]) ** 2, axis=1) / (2.0 * sigma_color ** 2)
    s = np.sort(scene.scales[idx].astype(np.float64), axis=1)
    flat = np.clip(1.0 - s[:, 0] / np.maximum(s[:, 1], 1e-30), 0.0, 1.0)
    rot = quat_to_rotmat(scene.quats[idx])
    normal = rot[np.arange(m), :, np.argmin(scene.log_scales[idx], axis=1)]
    cos = np.abs(np.sum(normal[rows] * normal[cols], axis=1))
    logw -= (1.0 - cos) / sigma_normal * flat[rows] * flat[cols]
    g = sp.csr_matrix((np.exp(logw), (idx[rows], idx[cols])), shape=(n, n))
    g = g.maximum(g.T).tocsr()
    g.setdiag(0.0)
    g.eliminate_zeros()
    return g


def _medians(fns, repeat):
    """The last results and the median seconds of each of ``fns``, called in turn ``repeat`` times
    (interleaved, so that a change of the machine's state touches both alike)."""
    outs, times = [None] * len(fns), [[] for _ in fns]
    for _ in range(repeat):
        for i, fn in enumerate(fns):
            t0 = time.perf_counter()
            outs[i] = fn()
            times[i].append(time.perf_counter() - t0)
    return outs, [float(np.median(t)) for t in times]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args(argv)
    path = DATA / "firepit_562k_sh0.ply"
    if not path.is_file():
        print(f"bench_graph: {path} not found; set SEED2GS_DATA. Skipped.")
        return 0
    scene = read_scene(path)
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}; {path.name}, k = 10, "
          f"min_opacity 0.05, median of {args.repeat}")
    visible = np.flatnonzero(scene.opacities >= 0.05)
    dist = np.linalg.norm(scene.means[visible].astype(np.float64) - np.asarray(FIRE_PIT), axis=1)
    for share in (0.1, 0.4, 1.0):
        sub = np.sort(visible[dist <= np.quantile(dist, share)])
        (new, ref), (t_new, t_ref) = _medians([lambda: gaussian_graph(scene, 10, subset=sub),
                                               lambda: reference_graph(scene, 10, sub)], args.repeat)
        ref.sort_indices()
        same = np.array_equal(new.indptr, ref.indptr) and np.array_equal(new.indices, ref.indices)
        rel = float(np.max(np.abs(new.data - ref.data) / ref.data)) if same and ref.nnz else float("nan")
        print(f"{sub.size:>7} nodes, {new.nnz:>8} edges: gaussian_graph {t_new:.2f} s, reference {t_ref:.2f} s "
              f"= x{t_ref / t_new:.2f}; same edges: {'yes' if same else 'NO'}, weights within {rel:.1e}")
    print(f"load average {os.getloadavg()[0]:.1f} at the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
