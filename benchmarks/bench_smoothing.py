"""Linear solvers of the graph-Laplacian regulariser on a real extraction.

``solve(..., smoothness=lambda, graph=G)`` ends with
:func:`~seed2gs_inverse.solvers.laplacian_smooth`, one sparse symmetric
positive definite system ``(E + lambda L + eps I) q = E q_hat + eps p`` over
the Gaussians of the object's graph region. This benchmark takes that system
from a real extraction (bench_speed's scene, ``_common.default_extraction``:
the firepit with the unicorn, default settings) and solves it with each linear solver of
``laplacian_smooth``: SuperLU (``direct``, exact) and CG on the
Jacobi-scaled system warm-started from the Dirichlet limit (``cg``). Larger systems come from
the same extraction with the graph region grown (``region`` x 1, 2, 3).

Printed per size: unknowns, seconds of each solver, and how many Gaussians
CG labels differently from the exact solve at the 0.5 threshold; the load
average at the start and the end.

Usage::

    python benchmarks/bench_smoothing.py [--regions 1,2,3] [--rtol 1e-6,1e-5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import default_extraction, load_average  # noqa: E402

from seed2gs_inverse.graph import graph_laplacian  # noqa: E402
from seed2gs_inverse.pipeline.completion import GRAPH_DEFAULTS, object_graph  # noqa: E402
from seed2gs_inverse.solvers import laplacian_smooth, solve  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--regions", default="1,2,3", help="graph region multipliers of the default region")
    p.add_argument("--rtol", default="1e-5,1e-6",
                   help="CG relative tolerances to compare (comma-separated; 1e-5 is laplacian_smooth's default)")
    args = p.parse_args(argv)
    extraction = default_extraction("bench_smoothing")
    if extraction is None:
        return 0
    scene, ex = extraction
    stack, masks = ex.operators, ex.masks
    lam = float(ex.result.info["smoothness"])
    # q_hat: the same solve without the regulariser; e: summed weight on known pixels.
    q_hat = solve(stack, masks, method=ex.settings.method, init=ex.lift.g0,
                  min_evidence=ex.settings.min_evidence, **ex.settings.solver_kwargs()).q
    known = np.concatenate([np.isfinite(np.asarray(m, np.float32)).ravel() for m in masks]).astype(np.float32)
    e = np.asarray(stack.rmatvec(known), dtype=np.float64)
    e[e < ex.settings.min_evidence] = 0.0  # weak evidence counts as none, as in solve()
    prior = ex.lift.g0.astype(np.float64)
    print(f"extraction: {len(stack)} views, smoothness {lam}, {int(ex.selected.sum())} selected")
    for mult in [float(s) for s in args.regions.split(",")]:
        g = object_graph(scene, ex.lift.center, ex.lift.radius,
                         **{**GRAPH_DEFAULTS, "region": GRAPH_DEFAULTS["region"] * mult})
        n = int((graph_laplacian(g).diagonal() > 0).sum())
        t0 = time.perf_counter()
        exact = laplacian_smooth(q_hat, e, g, lam, prior, solver="direct")
        t_direct = time.perf_counter() - t0
        cells = []
        for rtol in [float(r) for r in args.rtol.split(",")]:
            t0 = time.perf_counter()
            cg = laplacian_smooth(q_hat, e, g, lam, prior, solver="cg", rtol=rtol)
            t_cg = time.perf_counter() - t0
            flips = int(((cg > 0.5) != (exact > 0.5)).sum())
            cells.append(f"cg rtol {rtol:g} {t_cg:.2f} s ({t_cg / t_direct:.1f}x direct, {flips} labels differ)")
        print(f"region x{mult:g}: {n} coupled unknowns, {g.nnz} edges | direct {t_direct:.2f} s | "
              + " | ".join(cells) + f" | load {load_average():.1f}")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
